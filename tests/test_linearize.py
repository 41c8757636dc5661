"""Linearization on the constraint manifold (``mb.linearize``, ``ConstrainedSystem.linearize``).

Closed forms where they exist (a cart-pole at its upright equilibrium, a free body spinning about an
axis of inertia, the Chaplygin sleigh gliding straight), and otherwise differences of the nonlinear
dynamics along admissible perturbations: a perturbed state ``q ⊕ P s``, ``v + V u + D s`` projected onto
the constraints, whose coordinates in the linearization's bases, ``lin.coordinates(q(t) ⊖ q_ε(t), v_ε(t) −
v(t))``, are differentiated in time at ``t = 0`` and then in the perturbation ``ε``, each by the
five-point stencil (``constraint_helpers.fd_derivative``). The configurations move as ``q ⊕ v t``, exact
to first order in ``t``, and the velocities as ``v + a t`` with the nonlinear constrained accelerations.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

import multibody as mb

from constraint_helpers import fd_derivative
from dyn_helpers import central_differences, central_differences_vector
from rolling_helpers import SLEIGH_B, SLEIGH_INERTIA, SLEIGH_MASS, coin, lean_rotation, quat, sleigh

EPS = np.finfo(float).eps

# ----------------------------------------------------------------------------- systems


def cart_pole(cart_mass=1.5, pole_mass=0.4, com=0.6, pole_inertia=0.05):
    """A cart on a prismatic joint along x carrying a pole on a revolute joint about y; the pole's centre of
    mass at ``com`` (m) along its z axis, its inertia about y through the centre of mass ``pole_inertia``.
    ``q = [x, θ]``, θ = 0 upright, positive tipping the pole towards +x."""
    builder = mb.ModelBuilder("cart_pole")
    builder.add_body("cart", mb.joints.Prismatic([1.0, 0.0, 0.0]), joint_name="slide",
                     inertia=mb.Inertia(cart_mass, [0, 0, 0], 0.01 * np.eye(3)))
    builder.add_body("pole", mb.joints.Revolute([0.0, 1.0, 0.0]), parent="cart", joint_name="hinge",
                     inertia=mb.Inertia(pole_mass, [0, 0, com], np.diag([pole_inertia, pole_inertia, 1e-4])))
    return builder.build()


def four_bar():
    """The four-bar of the demos (robots/four_bar.urdf closed by a planar LoopClosure), at rest."""
    setup = mb.demos.four_bar_setup()
    return setup.system, setup.q0, setup.v0


def rolling_coin(speed=0.0, lean=0.0, yaw=0.0, turn=0.0):
    """The tests' coin (1 kg, radius 0.5 m, axis body z) on z = 0: leaned by ``lean`` from upright,
    heading ``yaw``, rolling at ``speed`` (m/s) along its heading and turning at ``turn`` rad/s about the
    vertical; projected onto the rolling constraint."""
    model, radius = coin(), 0.5
    system = mb.ConstrainedSystem(model, [mb.RollingDisc("coin", radius, axis=[0.0, 0.0, 1.0])])
    R = lean_rotation(yaw, lean, 0.0)
    q = np.concatenate([[0.1, -0.2, radius * np.cos(lean)], quat(R)])
    # body-frame velocity: spin about the axis (body z) for the speed, plus the turn about the world vertical
    omega = np.array([0.0, 0.0, -speed / radius]) + R.T @ np.array([0.0, 0.0, turn])
    contact_offset = R.T @ np.array([0.0, 0.0, -radius * np.cos(lean)])  # centre to contact, body axes
    v_lin = -np.cross(omega, contact_offset)  # the contact point at rest
    return system, *system.project(q, np.concatenate([v_lin, omega]), tolerance=1e-15)


# ----------------------------------------------------------------------------- differences

def _constrained(system):
    return isinstance(system, mb.ConstrainedSystem)


def _model(system):
    return system.model if _constrained(system) else system


def _accelerations(system, q, v, tau, t):
    if _constrained(system):
        return system.forward_dynamics(q, v, tau, t)[0]
    return mb.forward_dynamics(system, q, v, tau)


def nonlinear_rates(system, lin, x, dtau=None, h=1e-3):
    """``d[s; u]/dt`` at ``t = 0`` of the perturbed state of coordinates ``x`` (and joint forces ``τ + dtau``),
    from the nonlinear dynamics (module docstring)."""
    model, q, v, t = _model(system), lin.q, lin.v, lin.t
    dq, dv = lin.perturbation(x)
    q_e, v_e = model.integrate(q, dq), v + dv
    if _constrained(system) and system.num_rows:
        q_e, v_e = system.project(q_e, v_e, t, tolerance=1e-15)
    a = _accelerations(system, q, v, lin.tau, t)
    a_e = _accelerations(system, q_e, v_e, lin.tau + (0.0 if dtau is None else dtau), t)

    def coordinates(time):
        return lin.coordinates(model.difference(model.integrate(q, v * time), model.integrate(q_e, v_e * time)),
                               v_e - v + (a_e - a) * time)

    return fd_derivative(coordinates, h)


def rates_by_differences(system, lin, h=1e-3):
    """``(A, B)`` by five-point differences in each coordinate of ``[s; u]`` and ``δτ`` of
    :func:`nonlinear_rates`."""
    n, nv = lin.p + lin.k, lin.B.shape[-1]
    A = np.stack([fd_derivative(lambda e, j=j: nonlinear_rates(system, lin, e * np.eye(n)[j]), h) for j in range(n)],
                 axis=-1)
    B = np.stack([fd_derivative(lambda e, j=j: nonlinear_rates(system, lin, np.zeros(n), e * np.eye(nv)[j]), h)
                  for j in range(nv)], axis=-1)
    return A, B


#: Nested five-point differences (steps h = 1e-3 in time and in ε): the rounding of the coordinates,
#: about ε max(1, |q|, |v|), is divided by both steps, ≈ 3e-10 per unit of state (the stencil's weights
#: sum to 1.5/h); the truncation, h⁴ times fifth derivatives of rates of order one, stays below 1e-11; the
#: analytic side differentiates the rows by five-point steps too (about 1e-11). Ten times that rounding:
DIFFERENCE_TOL = 3e-9


def assert_matches_differences(system, lin, what):
    A, B = rates_by_differences(system, lin)
    scale = max(1.0, float(np.abs(lin.q).max()), float(np.abs(lin.v).max()))
    for name, ours, reference in (("A", lin.A, A), ("B", lin.B, B)):
        error = np.abs(ours - reference).max() / (scale * max(1.0, np.abs(reference).max()))
        assert error <= DIFFERENCE_TOL, f"{what}: {name} differs from the differences by {error:.2e} (relative)"


# ----------------------------------------------------------------------------- unconstrained models

def test_cart_pole_upright_matches_closed_form():
    """``[[M + m, m l], [m l, J]] [ẍ; θ̈] = [F; τ + m g l θ]`` at θ = 0 (``J = I_c + m l²``), so with
    ``Δ = (M + m) J − m² l²``: ``ẍ = (J F − m l (τ + m g l θ)) / Δ``, ``θ̈ = ((M + m)(τ + m g l θ) − m l F) / Δ``."""
    M, m, l, I_c = 1.5, 0.4, 0.6, 0.05
    model = cart_pole(M, m, l, I_c)
    g = -model.gravity[2]
    J = I_c + m * l**2
    delta = (M + m) * J - m**2 * l**2
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 1] = -m * l * m * g * l / delta
    A[3, 1] = (M + m) * m * g * l / delta
    B = np.array([[0.0, 0.0], [0.0, 0.0], [J / delta, -m * l / delta], [-m * l / delta, (M + m) / delta]])

    lin = mb.linearize(model, np.zeros(2), np.zeros(2), np.zeros(2))
    assert (lin.p, lin.k) == (2, 2) and lin.dt is None
    np.testing.assert_array_equal(lin.position_basis, np.eye(2))
    np.testing.assert_array_equal(lin.velocity_basis, np.eye(2))
    np.testing.assert_array_equal(lin.dependent_rates, np.zeros((2, 2)))
    np.testing.assert_allclose(lin.A, A, rtol=0, atol=1e-10 * np.abs(A).max())
    np.testing.assert_allclose(lin.B, B, rtol=0, atol=1e-10 * np.abs(B).max())
    # the upright pole is unstable: eigenvalues ±sqrt((M + m) m g l / Δ) and a double zero
    rate = np.sqrt((M + m) * m * g * l / delta)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(lin.A).real), [-rate, 0.0, 0.0, rate], atol=1e-7)


def test_double_pendulum_matches_forward_dynamics_differences():
    """``A = [[0, I], [∂a/∂q, ∂a/∂v]]`` and ``B = [[0], [∂a/∂τ]]`` against central differences of
    ``mb.forward_dynamics`` (steps 1e-6: rounding about 1e-9 of the entries; 1e-7 leaves a margin of 10
    over it and over the step's truncation)."""
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(3)
    q, v, tau = model.random_configuration(rng), rng.standard_normal(2), rng.standard_normal(2)
    lin = mb.linearize(model, q, v, tau)
    da_dq = central_differences(lambda x: mb.forward_dynamics(model, x, v, tau), model, q)
    da_dv = central_differences_vector(lambda x: mb.forward_dynamics(model, q, x, tau), v)
    da_dtau = central_differences_vector(lambda x: mb.forward_dynamics(model, q, v, x), tau)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [da_dq, da_dv]])
    B = np.concatenate([np.zeros((2, 2)), da_dtau])
    np.testing.assert_allclose(lin.A, A, rtol=0, atol=1e-7 * np.abs(A).max())
    np.testing.assert_allclose(lin.B, B, rtol=0, atol=1e-7 * np.abs(B).max())
    assert_matches_differences(model, lin, "double pendulum")
