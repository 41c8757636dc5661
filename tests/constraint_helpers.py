"""Helpers shared by ``test_constraints.py`` and ``test_simulation.py``.

* ``particle_model``: point masses, each on a 3-dof ``Translation`` joint from the world;
* ``pendulum_state`` / ``pendulum_tension``: the particle pendulum held by ``Distance(p, None, l)``;
* ``Helix`` / ``Parabola``: parametric wires ``r(s)`` with analytic ``r'``, ``r''``;
* ``CurveCoordinateSystem``: the seed's bead on a wire in its minimal coordinate ``s``, written as a
  user-defined mechanical system (the ``ConstrainedSystem`` / ``simulate`` protocol);
* ``four_bar``: a planar four-bar (three revolute joints about y closed to a world pivot);
* ``fd_derivative``, ``fd_constraint_jacobian``, ``fd_gamma``: central finite differences;
* ``assert_close``: max-norm comparison with a readable message.
"""

from __future__ import annotations

import numpy as np

import multibody as mb
from multibody.spatial import pose_from_xyz_rpy

G = 9.81
GRAVITY = np.array([0.0, 0.0, -G])


# ----------------------------------------------------------------------------- comparisons

def assert_close(actual, expected, tol, *, scale=None, what=""):
    """``max|actual − expected| ≤ tol · scale``; ``scale`` defaults to ``max(max|expected|, tiny)``.

    With ``scale=1`` the tolerance is absolute.
    """
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    assert np.all(np.isfinite(actual)), f"{what}: non-finite values {actual}"
    if scale is None:
        scale = max(float(np.abs(expected).max(initial=0.0)), 1e-300)
    error = float(np.abs(actual - expected).max(initial=0.0))
    assert error <= tol * scale, f"{what}: error {error:.3e} > {tol:.1e} x scale {scale:.3e} (relative {error / scale:.3e})"
    return error / scale


# ----------------------------------------------------------------------------- particles

def particle_model(*masses, names=None, gravity=GRAVITY):
    """Point masses ``masses`` on ``Translation`` joints (q = world position, v = world velocity)."""
    names = names or [f"p{k + 1}" for k in range(len(masses))]
    builder = mb.ModelBuilder("particles", gravity=gravity)
    for name, mass in zip(names, masses):
        builder.add_body(name, mb.joints.Translation(), inertia=mb.inertia.point_mass(mass))
    return builder.build()


def pendulum_state(length, theta, theta_dot, azimuth=0.0):
    """Particle pendulum hanging from the world origin: angle θ from the downward vertical in the
    vertical plane of azimuth ``azimuth`` (0: the x–z plane), rate θ̇. Returns ``(q, v)``."""
    c, s = np.cos(azimuth), np.sin(azimuth)
    radial = np.array([np.sin(theta) * c, np.sin(theta) * s, -np.cos(theta)])
    tangent = np.array([np.cos(theta) * c, np.cos(theta) * s, np.sin(theta)])
    return length * radial, length * theta_dot * tangent


def pendulum_tension(mass, length, q, v, g=G):
    """Rod tension of the particle pendulum: ``λ = m g cos θ + m l θ̇²`` with ``cos θ = −z/l`` and
    ``l θ̇ = |v|`` (the speed; the velocity is tangent to the sphere)."""
    cos_theta = -q[..., 2] / length
    return mass * g * cos_theta + mass * np.sum(v * v, axis=-1) / length


# ----------------------------------------------------------------------------- wires

class Helix:
    """``r(s) = (R cos s, R sin s, c s)``: a vertical helix (|r'|² = R² + c², r'·r'' = 0)."""

    def __init__(self, radius=1.0, pitch=0.3):
        self.R, self.c = radius, pitch

    def r(self, s):
        s = np.asarray(s, dtype=float)
        return np.stack([self.R * np.cos(s), self.R * np.sin(s), self.c * s], axis=-1)

    def d1(self, s):
        s = np.asarray(s, dtype=float)
        return np.stack([-self.R * np.sin(s), self.R * np.cos(s), np.full_like(s, self.c)], axis=-1)

    def d2(self, s):
        s = np.asarray(s, dtype=float)
        return np.stack([-self.R * np.cos(s), -self.R * np.sin(s), np.zeros_like(s)], axis=-1)


class Parabola:
    """``r(s) = s u + a s² e_z`` with ``u = (cos β, sin β, 0)``: a vertical parabolic valley."""

    def __init__(self, a=0.6, beta=0.4):
        self.a, self.u = a, np.array([np.cos(beta), np.sin(beta), 0.0])

    def r(self, s):
        s = np.asarray(s, dtype=float)[..., None]
        return s * self.u + self.a * s**2 * np.array([0.0, 0.0, 1.0])

    def d1(self, s):
        s = np.asarray(s, dtype=float)[..., None]
        return self.u + 2.0 * self.a * s * np.array([0.0, 0.0, 1.0])

    def d2(self, s):
        s = np.asarray(s, dtype=float)[..., None]
        return np.broadcast_to(np.array([0.0, 0.0, 2.0 * self.a]), s.shape[:-1] + (3,)).copy()


class CurveCoordinateSystem:
    """The bead on the wire ``curve`` in its minimal coordinate ``s`` (q = [s], v = [ṡ]).

    Lagrangian ``L = ½ m |r'(s)|² ṡ² − m g z(s)`` gives ``M(s) s̈ + h = 0`` with
    ``M = m |r'|²`` and ``h = m (r'·r'') ṡ² + m g z'(s)``.
    """

    nq = nv = 1

    def __init__(self, curve, mass, g=G):
        self.curve, self.m, self.g = curve, mass, g

    def mass_matrix(self, q):
        d1 = self.curve.d1(q[0])
        return np.array([[self.m * d1 @ d1]])

    def bias_forces(self, q, v):
        d1, d2 = self.curve.d1(q[0]), self.curve.d2(q[0])
        return np.array([self.m * (d1 @ d2) * v[0] ** 2 + self.m * self.g * d1[2]])

    def integrate(self, q, v, dt=1.0):
        return np.asarray(q, dtype=float) + dt * np.asarray(v, dtype=float)

    def energy(self, q, v):
        d1 = self.curve.d1(q[0])
        return 0.5 * self.m * (d1 @ d1) * v[0] ** 2 + self.m * self.g * self.curve.r(q[0])[2]

    # Closed-form consequences of the minimal solution, for the comparisons.
    def s_ddot(self, s, s_dot):
        q, v = np.array([s]), np.array([s_dot])
        return -self.bias_forces(q, v)[0] / self.mass_matrix(q)[0, 0]

    def cartesian_acceleration(self, s, s_dot):
        """``r̈ = r' s̈ + r'' ṡ²``."""
        return self.curve.d1(s) * self.s_ddot(s, s_dot) + self.curve.d2(s) * s_dot**2

    def normal_force(self, s, s_dot):
        """The force the wire exerts on the bead: ``N = m r̈ − m g_vec`` (world axes, N)."""
        return self.m * self.cartesian_acceleration(s, s_dot) - self.m * np.array([0.0, 0.0, -self.g])


# ----------------------------------------------------------------------------- four-bar

FOUR_BAR = dict(L1=0.6, L2=1.0, L3=0.8, D=1.1)


def four_bar():
    """Three links in a chain, revolute joints about y (mechanism plane x–z), link k along its x axis.

    The tip of link3 (``FOUR_BAR['L3']`` along its x) is to be pinned at the world point
    ``(D, 0, 0)``: the ground link is the fourth bar. Returns ``(model, tip_placement, pivot)``.
    """
    L1, L2, L3 = FOUR_BAR["L1"], FOUR_BAR["L2"], FOUR_BAR["L3"]
    y = [0.0, 1.0, 0.0]
    b = mb.ModelBuilder("four_bar")
    b.add_body("link1", mb.joints.Revolute(y), inertia=mb.inertia.box(1.0, [L1, 0.05, 0.05], center=[L1 / 2, 0, 0]))
    b.add_body("link2", mb.joints.Revolute(y), parent="link1", placement=pose_from_xyz_rpy([L1, 0, 0]),
               inertia=mb.inertia.box(1.5, [L2, 0.05, 0.05], center=[L2 / 2, 0, 0]))
    b.add_body("link3", mb.joints.Revolute(y), parent="link2", placement=pose_from_xyz_rpy([L2, 0, 0]),
               inertia=mb.inertia.box(0.8, [L3, 0.05, 0.05], center=[L3 / 2, 0, 0]))
    tip = pose_from_xyz_rpy([L3, 0, 0])
    pivot = np.array([FOUR_BAR["D"], 0.0, 0.0])
    return b.build(), tip, pivot


# ----------------------------------------------------------------------------- finite differences

def fd_derivative(f, h=1e-3):
    """``f'(0)`` by the fourth-order central stencil ``(8 (f(h) − f(−h)) − (f(2h) − f(−2h))) / 12h``.

    Error: truncation ``h⁴ |f⁽⁵⁾| / 30`` plus rounding about ``1.5 ε max|f| / h``; with h = 1e-3 and
    the smooth O(1) functions of these tests both are below 1e-11.
    """
    return (8.0 * (f(h) - f(-h)) - (f(2.0 * h) - f(-2.0 * h))) / (12.0 * h)


def fd_constraint_jacobian(constraint, system, model, q, t=0.0):
    """Column k: ``d/dε φ(q ⊕ ε e_k, t)`` at ε = 0 (derivative with respect to ``v``)."""
    eye = np.eye(model.nv)
    return np.stack([fd_derivative(lambda s, e=e: constraint.position(system, model.integrate(q, e, s), t))
                     for e in eye], axis=-1)


def fd_gamma(constraint, system, model, q, v, t=0.0):
    """``−d/ds [A(q(s), t + s) v + b(q(s), t + s)]`` at s = 0 along ``q(s) = q ⊕ v s`` (a = 0)."""
    def velocity_level(s):
        qs = model.integrate(q, v, s)
        return constraint.jacobian(system, qs, t + s) @ v + constraint.velocity_bias(system, qs, t + s)
    return -fd_derivative(velocity_level)


def null_space(A, rtol=1e-10):
    """Orthonormal basis (columns) of the null space of ``A``."""
    _, sigma, Vt = np.linalg.svd(A)
    rank = int(np.sum(sigma > rtol * max(sigma.max(initial=0.0), 1e-300)))
    return Vt[rank:].T


# ----------------------------------------------------------------------------- chains of parallelograms
# (tests/test_singular_chains.py; benchmarks/run.py times one evaluation of the 40-cell chain)

Y = (0.0, 1.0, 0.0)
LENGTH, MASS, THICKNESS = 1.0, 1.0, 0.05


def parallelogram_chain(cells):
    """The chain of ``cells`` parallelograms; joints ``V0 … VN`` (cranks), then ``H1 … HN`` (bars)."""
    bar = mb.inertia.box(MASS, [LENGTH, THICKNESS, THICKNESS], center=[LENGTH / 2, 0.0, 0.0])
    builder = mb.ModelBuilder(f"{cells} parallelograms")
    for k in range(cells + 1):
        builder.add_body(f"V{k}", mb.joints.Revolute(Y), placement=pose_from_xyz_rpy([k * LENGTH, 0, 0]), inertia=bar)
    for k in range(1, cells + 1):
        builder.add_body(f"H{k}", mb.joints.Revolute(Y), parent=f"V{k - 1}",
                         placement=pose_from_xyz_rpy([LENGTH, 0, 0]), inertia=bar)
    return builder.build()


def planar_closures(cells):
    """The planar loop closures ``Hk`` tip ↔ ``Vk`` tip; frame A's x and y are the world's x and z while
    ``Hk`` is horizontal."""
    tip = pose_from_xyz_rpy([LENGTH, 0, 0])
    plane = pose_from_xyz_rpy([LENGTH, 0, 0], [np.pi / 2, 0, 0])
    return [mb.LoopClosure(f"H{k}", f"V{k}", frame_a=plane, frame_b=tip, kind="planar") for k in range(1, cells + 1)]


def crank_state(cells, phi, phi_rate=0.0):
    """``(q, v)`` of the parallelogram motion at crank angle ``φ`` and rate ``φ̇``."""
    q = np.concatenate([np.full(cells + 1, -phi), np.full(cells, phi)])
    v = np.concatenate([np.full(cells + 1, -phi_rate), np.full(cells, phi_rate)])
    return q, v
