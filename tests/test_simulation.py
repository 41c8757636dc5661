"""``mb.simulate`` on constrained and unconstrained systems: conservation, projection and stabilisation,
cross-checks between Cartesian (constrained) and minimal coordinates, closed-form motions, the
``Trajectory`` it returns, and its failures.

Runtime: every simulation here costs about one millisecond per right-hand-side evaluation, so
output intervals (``dt``, also the projection interval) are 0.05–0.25 s rather than the default
``T/500``; the required tolerances are never traded for speed.
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import axis_angle_rotation, rotation_to_quat

from conftest import random_tree_model
from constraint_helpers import (
    GRAVITY,
    CurveCoordinateSystem,
    Helix,
    Parabola,
    assert_close,
    particle_model,
    pendulum_state,
    pendulum_tension,
)

TIGHT = dict(method="DOP853", rtol=1e-10, atol=1e-12)


def relative_energy_drift(trajectory):
    """``max|E(t) − E(0)| / |E(0)|`` (the states below are chosen with |E(0)| of the order of the
    energy exchanged between kinetic and potential)."""
    energy = trajectory.energy
    assert np.all(np.isfinite(energy))
    return float(np.abs(energy - energy[0]).max() / abs(energy[0]))


# ============================================================================= 1, 3, 4: the particle pendulum

M_PEND, L_PEND = 2.0, 1.5


def pendulum_system(**kwargs):
    model = particle_model(M_PEND, names=["p"])
    return mb.ConstrainedSystem(model, [mb.Distance("p", None, L_PEND)], **kwargs)


@pytest.fixture(scope="module")
def pendulum_run():
    """10 s of the particle pendulum (θ₀ = 1.2 rad, θ̇₀ = 1.5 rad/s: it swings past θ = 1.8 rad),
    DOP853 at rtol 1e-10, projected every 0.1 s. E(0) ≈ −5.6 J, kinetic energy up to ≈ 25 J."""
    q0, v0 = pendulum_state(L_PEND, 1.2, 1.5)
    return mb.simulate(pendulum_system(), q0, v0, 10.0, dt=0.1, **TIGHT)


def test_pendulum_energy_is_conserved(pendulum_run):
    assert pendulum_run.status == "completed" and pendulum_run.t[-1] == 10.0
    assert relative_energy_drift(pendulum_run) <= 1e-8


def test_pendulum_residual_with_projection(pendulum_run):
    assert pendulum_run.residual.max() <= 1e-10
    radius = np.linalg.norm(pendulum_run.q, axis=1)
    assert_close(radius, np.full_like(radius, L_PEND), 1e-10, scale=L_PEND, what="|x| = l")


def test_pendulum_tension_along_trajectory(pendulum_run):
    """λ(t) = m g cos θ + m l θ̇² (cos θ = −z/l, l θ̇ = |v|) at every output, to 1e-8 relative."""
    expected = pendulum_tension(M_PEND, L_PEND, pendulum_run.q, pendulum_run.v)
    assert pendulum_run.lam.shape == (len(pendulum_run), 1)
    assert_close(pendulum_run.lam[:, 0], expected, 1e-8, what="tension")
    assert expected.min() < 0.5 * expected.max()  # the tension really varies along the swing


@pytest.mark.parametrize("form", ["array", "callable"])
def test_pendulum_tension_with_applied_force(form):
    """A constant force F on the bob (``tau`` of the Translation joint is a world force): from
    ``m a = m g − λ u + F`` and ``u·a = −|v|²/l``, ``λ = m g cos θ + m |v|²/l + u·F``. The recorded
    multipliers must include the applied force, at every output, to 1e-8."""
    force = np.array([3.0, -1.0, 4.0])
    tau = force if form == "array" else (lambda t, q, v: force.copy())
    q0, v0 = pendulum_state(L_PEND, 0.8, -0.5, azimuth=0.3)
    trajectory = mb.simulate(pendulum_system(), q0, v0, 1.0, dt=0.1, tau=tau, **TIGHT)
    u = trajectory.q / L_PEND
    expected = pendulum_tension(M_PEND, L_PEND, trajectory.q, trajectory.v) + u @ force
    assert_close(trajectory.lam[:, 0], expected, 1e-8, what="tension with applied force")
    assert trajectory.residual.max() <= 1e-10
    assert np.abs(u @ force).min() > 0.5  # the applied force's share of the tension is far above tolerance


def test_particle_pendulum_matches_revolute_pendulum():
    """The shipped pendulum (1 kg at 1 m on a revolute joint about y, minimal coordinate θ) and the
    particle held by ``Distance(p, None, 1)``: same motion, ``x = (−sin θ, 0, −cos θ)`` (rotation about
    y by θ of the bob at (0, 0, −1)), to 1e-8 over 3 s."""
    revolute = mb.robots.load("pendulum")
    theta0, theta_dot0 = 0.9, -1.1
    minimal = mb.simulate(revolute, np.array([theta0]), np.array([theta_dot0]), 3.0, dt=0.25, **TIGHT)
    particle = mb.ConstrainedSystem(particle_model(1.0, names=["p"]), [mb.Distance("p", None, 1.0)])
    # θ about +y moves the bob towards −x: the particle's state is the mirror of pendulum_state's
    q0, v0 = pendulum_state(1.0, -theta0, -theta_dot0)
    cartesian = mb.simulate(particle, q0, v0, 3.0, dt=0.25, **TIGHT)
    theta = minimal.q[:, 0]
    expected = np.stack([-np.sin(theta), np.zeros_like(theta), -np.cos(theta)], axis=1)
    assert_close(cartesian.t, minimal.t, 0.0, scale=1.0, what="times")
    assert_close(cartesian.q, expected, 1e-8, scale=1.0, what="bob position")
    assert_close(cartesian.energy, minimal.energy, 1e-8, scale=abs(minimal.energy[0]), what="energy")


def test_double_pendulum_of_particles_conserves_energy():
    """Two particles, rods pivot–p1 (1 m) and p1–p2 (0.8 m): chaotic from θ₁ = 1, θ₂ = 2 at rest.
    DOP853 at rtol 1e-10 over 10 s: energy to 1e-8 relative, both rods held to 1e-10."""
    model = particle_model(1.0, 0.5)
    cs = mb.ConstrainedSystem(model, [mb.Distance("p1", None, 1.0), mb.Distance("p1", "p2", 0.8)])
    p1, _ = pendulum_state(1.0, 1.0, 0.0)
    p2 = p1 + pendulum_state(0.8, 2.0, 0.0)[0]
    trajectory = mb.simulate(cs, np.concatenate([p1, p2]), np.zeros(6), 10.0, dt=0.2, **TIGHT)
    assert relative_energy_drift(trajectory) <= 1e-8
    assert trajectory.residual.max() <= 1e-10
    assert trajectory.lam.shape == (len(trajectory), 2)
    q = trajectory.q
    assert_close(np.linalg.norm(q[:, 3:] - q[:, :3], axis=1), np.full(len(q), 0.8), 1e-10, scale=1.0, what="rod 2")
    # it does move a lot: the lower particle swings over more than a metre
    assert np.ptp(q[:, 3]) > 1.0


def test_projection_matters_for_long_rk4_runs():
    """RK4 (dt = 0.05 s) over 10 s of a large swing of the pendulum:

    * with projection at every step (default) the constraints hold to 1e-10;
    * without projection (``project=False``) the drift of the index-1 formulation accumulates: the
      residual grows by orders of magnitude over the run;
    * Baumgarte stabilisation (``baumgarte=5`` 1/s, critically damped) keeps it bounded, far below
      the unstabilised one.
    """
    q0, v0 = pendulum_state(L_PEND, 2.0, 2.0)
    projected = mb.simulate(pendulum_system(), q0, v0, 10.0, dt=0.05, method="RK4")
    free = mb.simulate(pendulum_system(), q0, v0, 10.0, dt=0.05, method="RK4", project=False)
    baumgarte = mb.simulate(pendulum_system(baumgarte=5.0), q0, v0, 10.0, dt=0.05, method="RK4", project=False)
    n = len(projected)
    assert n == 201 and len(free) == n and len(baumgarte) == n
    assert projected.residual.max() <= 1e-10
    early, late = slice(1, n // 10), slice(n // 2, n)
    # without projection: a real drift that keeps growing
    assert free.residual[late].max() > 1e-4
    assert free.residual[late].max() > 20.0 * free.residual[early].max()
    assert free.residual[-1] > 0.5 * free.residual.max()
    # Baumgarte: bounded (no growth from the first tenth to the second half), and much smaller
    assert baumgarte.residual[late].max() < 5.0 * baumgarte.residual[early].max()
    assert baumgarte.residual[late].max() < 0.1 * free.residual[late].max()


# ============================================================================= 2. bead on a wire, both ways

BEAD_MASS = 0.7


@pytest.mark.parametrize("case", ["helix", "parabola"])
def test_bead_on_wire_cartesian_matches_minimal_coordinate(case):
    """Cartesian: a Translation particle + ``PointOnCurve`` (3 rows of rank 2). Minimal: the seed's
    coordinate s as a user-defined system (M = m|r'|², h = m (r'·r'') ṡ² + m g z'). Both with DOP853
    at rtol 1e-11 (the 1e-8 comparison needs both integrations well below it), outputs every 0.1 s.

    * helix (R = 1, pitch 0.3, r', r'' by the constraint's own stencils): the bead slides down
      with constant s̈ = −g c / (R² + c²) from s = 0.5 to s ≈ −8, inside s_range = (−12, 8);
    * parabola r = s u + 0.6 s² e_z (analytic r', r''): oscillates in |s| ≤ 1.3, s_range = (−3, 3).

    Positions and velocities agree to 1e-8. The Cartesian multipliers are the normal force
    ``N = m r̈ − m g_vec`` computed from the minimal solution at its own states: the two states differ
    by ~1e-10 and N depends on them with O(m |r''| ṡ) ≈ 10 N/(m/s) sensitivity, plus the stencil error
    of the numerical r'' (≈ 1e-9 |r|), so |ΔN| ≲ 1e-8 N against |N| up to ~30 N: asserted to 1e-7 of max|N|.
    """
    if case == "helix":
        curve, s0, s_dot0, s_range = Helix(1.0, 0.3), 0.5, 1.2, (-12.0, 8.0)
        constraint = mb.PointOnCurve("bead", curve.r, s_range=s_range, samples=4001)
    else:
        curve, s0, s_dot0, s_range = Parabola(0.6, 0.4), 1.2, -0.8, (-3.0, 3.0)
        constraint = mb.PointOnCurve("bead", curve.r, s_range=s_range, samples=2001,
                                     derivative=curve.d1, second_derivative=curve.d2)
    tight = dict(method="DOP853", rtol=1e-11, atol=1e-12)
    cartesian = mb.simulate(mb.ConstrainedSystem(particle_model(BEAD_MASS, names=["bead"]), [constraint]),
                            curve.r(s0), curve.d1(s0) * s_dot0, 3.0, dt=0.1, **tight)
    minimal_system = CurveCoordinateSystem(curve, BEAD_MASS)
    minimal = mb.simulate(minimal_system, np.array([s0]), np.array([s_dot0]), 3.0, dt=0.1, **tight)
    assert cartesian.status == minimal.status == "completed"
    s, s_dot = minimal.q[:, 0], minimal.v[:, 0]
    assert s_range[0] + 1.0 < s.min() and s.max() < s_range[1] - 1.0  # never near the ends of s_range
    if case == "helix":
        s_ddot = -9.81 * 0.3 / (1.0 + 0.09)
        assert_close(s, s0 + s_dot0 * minimal.t + 0.5 * s_ddot * minimal.t**2, 1e-9, scale=1.0, what="helix s(t)")
    else:
        assert np.sum(np.diff(np.sign(s_dot)) != 0) >= 2  # oscillates
    assert_close(cartesian.q, curve.r(s), 1e-8, scale=max(1.0, np.abs(cartesian.q).max()), what=f"{case}: position")
    velocity = curve.d1(s) * s_dot[:, None]
    assert_close(cartesian.v, velocity, 1e-8, scale=max(1.0, np.abs(velocity).max()), what=f"{case}: velocity")
    assert cartesian.residual.max() <= 1e-10
    normal = np.array([minimal_system.normal_force(a, b) for a, b in zip(s, s_dot)])
    assert cartesian.lam.shape == (len(cartesian), 3)
    assert_close(cartesian.lam, normal, 1e-7, scale=np.abs(normal).max(), what=f"{case}: normal force")
    # energies agree too (same mass, same gravity): the user system's energy() is recorded
    assert_close(minimal.energy, cartesian.energy, 1e-8, scale=np.abs(cartesian.energy).max(), what="energy")
    assert relative_energy_drift(cartesian) <= 1e-8


# ============================================================================= 9. rheonomic: rotating wire

OMEGA, M_BEAD = 1.3, 0.5


def rotating_wire(analytic):
    w = OMEGA

    def phi(q, t):
        return np.array([q[0] * np.sin(w * t) - q[1] * np.cos(w * t), q[2]])

    if not analytic:
        return mb.Holonomic(phi)

    def gamma(q, v, t):
        c, s = np.cos(w * t), np.sin(w * t)
        return -np.array([2.0 * w * (v[0] * c + v[1] * s) + w * w * (q[1] * c - q[0] * s), 0.0])

    return mb.Holonomic(
        phi, jacobian=lambda q, t: np.array([[np.sin(w * t), -np.cos(w * t), 0.0], [0.0, 0.0, 1.0]]),
        dphi_dt=lambda q, t: np.array([w * (q[0] * np.cos(w * t) + q[1] * np.sin(w * t)), 0.0]), gamma=gamma)


@pytest.mark.parametrize("analytic, t0, method", [(False, 0.0, "DOP853"), (True, 0.3, "DOP853"), (True, 0.3, "RK4")])
def test_bead_on_rotating_wire_closed_form(analytic, t0, method):
    """Horizontal wire through the origin turning about z at ω (time-dependent φ), gravity along −z
    carried by the z row. Along the wire ``r̈ = ω² r``: ``r = r₀ cosh ω(t−t₀) + (ṙ₀/ω) sinh ω(t−t₀)``,
    ``x = r (cos ωt, sin ωt, 0)``; multipliers ``λ₁ = −2 m ω ṙ`` (Coriolis), ``λ₂ = m g``.

    Numerical derivatives (A, b, γ by stencils; γ error ≈ 3e-10|φ|, see test_constraints) or analytic
    ones, started at t₀ = 0 or 0.3 s (the constraint sees the absolute time): to 1e-8 relative.
    DOP853 at rtol 1e-11; RK4 with h = 0.01 s (global error ≈ 1e-9 here: (ωh)⁴ ≈ 3e-8 per unit
    ωt, and it evaluates the constraint at the mid-step times).
    """
    options = dict(dt=0.01) if method == "RK4" else dict(dt=0.1, rtol=1e-11, atol=1e-12)
    r0, r_dot0 = 0.4, 0.2
    u0 = np.array([np.cos(OMEGA * t0), np.sin(OMEGA * t0), 0.0])
    u0_perp = np.array([-np.sin(OMEGA * t0), np.cos(OMEGA * t0), 0.0])
    cs = mb.ConstrainedSystem(particle_model(M_BEAD, names=["bead"]), [rotating_wire(analytic)])
    trajectory = mb.simulate(cs, r0 * u0, r_dot0 * u0 + OMEGA * r0 * u0_perp, t0 + 2.0, t0=t0, method=method,
                             **options)
    t = trajectory.t
    assert t[0] == t0 and t[-1] == pytest.approx(t0 + 2.0, abs=1e-12)
    tau = OMEGA * (t - t0)
    r = r0 * np.cosh(tau) + r_dot0 / OMEGA * np.sinh(tau)
    r_dot = r0 * OMEGA * np.sinh(tau) + r_dot0 * np.cosh(tau)
    expected = np.stack([r * np.cos(OMEGA * t), r * np.sin(OMEGA * t), np.zeros_like(r)], axis=1)
    assert_close(trajectory.q, expected, 1e-8, scale=np.abs(r).max(), what="position")
    lam_expected = np.stack([-2.0 * M_BEAD * OMEGA * r_dot, np.full_like(r, M_BEAD * 9.81)], axis=1)
    assert_close(trajectory.lam, lam_expected, 1e-8, scale=np.abs(lam_expected).max(), what="multipliers")
    assert trajectory.residual.max() <= 1e-10
    # A moving constraint does work: the energy is not conserved (it grows with r²ω²).
    assert trajectory.energy[-1] - trajectory.energy[0] > 0.1


# ============================================================================= 10. the simulate API

def test_trajectory_fields_and_shapes():
    cs = mb.ConstrainedSystem(particle_model(1.0, 0.5), [mb.Distance("p1", None, 1.0), mb.Distance("p1", "p2", 0.8)])
    q0 = np.array([0.0, 0.0, -1.0, 0.8, 0.0, -1.0])
    trajectory = mb.simulate(cs, q0, np.zeros(6), 0.2, dt=0.05)
    n = 5
    assert isinstance(trajectory, mb.Trajectory) and len(trajectory) == n
    assert_close(trajectory.t, np.linspace(0.0, 0.2, n), 1e-15, scale=1.0, what="output times")
    assert trajectory.q.shape == (n, 6) and trajectory.v.shape == (n, 6)
    assert trajectory.lam.shape == (n, 2)
    assert trajectory.energy.shape == (n,) and trajectory.residual.shape == (n,)
    assert trajectory.row_names == cs.row_names and len(trajectory.row_names) == 2
    assert trajectory.status == "completed"
    # the recorded state is the one given (it was consistent), the energy is the model's
    assert_close(trajectory.q[0], q0, 0.0, scale=1.0, what="q[0]")
    model = cs.model
    assert trajectory.energy[0] == pytest.approx(mb.potential_energy(model, q0), abs=1e-12)
    # the recorded multipliers are those of the KKT solve at each recorded state
    assert_close(trajectory.lam[-1], cs.forward_dynamics(trajectory.q[-1], trajectory.v[-1])[1], 1e-12,
                 what="λ at the last output")
    # a final time that is not a multiple of dt ends exactly at t_final
    short = mb.simulate(cs, q0, np.zeros(6), 0.12, dt=0.05)
    assert_close(short.t, [0.0, 0.05, 0.1, 0.12], 1e-15, scale=1.0, what="last interval shortened")


def test_simulate_plain_model_has_no_multipliers():
    model = mb.robots.load("double_pendulum")
    trajectory = mb.simulate(model, np.array([0.5, -0.3]), np.zeros(2), 0.5, dt=0.1)
    assert trajectory.lam.shape == (6, 0) and trajectory.row_names == []
    assert np.all(trajectory.residual == 0.0)
    assert relative_energy_drift(trajectory) <= 1e-6  # default rtol 1e-8


@pytest.fixture(scope="module")
def revolute_pendulum():
    return mb.robots.load("pendulum")


def test_tau_none_array_and_callable(revolute_pendulum):
    """``tau`` as None, an array, or ``tau(t, q, v)``.

    * None and a zero array give the same motion;
    * a constant torque τ₀ as an array and as a callable give the same motion, and the work–energy
      theorem holds: ``E(t) − E(0) = τ₀ (θ(t) − θ(0))``;
    * a damping callable ``τ = −c θ̇`` dissipates energy monotonically, and is called with
      ``(t, q (nq,), v (nv,))``, ``t`` within the simulated interval.
    """
    model = revolute_pendulum
    q0, v0 = np.array([0.7]), np.array([0.0])
    opts = dict(dt=0.25, **TIGHT)
    free = mb.simulate(model, q0, v0, 2.0, tau=None, **opts)
    zero = mb.simulate(model, q0, v0, 2.0, tau=np.zeros(1), **opts)
    assert_close(zero.q, free.q, 1e-14, scale=1.0, what="tau=0 vs None")
    tau0 = 1.5
    array = mb.simulate(model, q0, v0, 2.0, tau=np.array([tau0]), **opts)
    function = mb.simulate(model, q0, v0, 2.0, tau=lambda t, q, v: np.array([tau0]), **opts)
    assert_close(function.q, array.q, 1e-14, scale=1.0, what="constant torque: callable vs array")
    assert np.abs(array.q - free.q).max() > 0.1  # the torque matters
    work = tau0 * (array.q[:, 0] - q0[0])
    assert_close(array.energy - array.energy[0], work, 1e-8, scale=np.abs(work).max(), what="work-energy")
    calls = []

    def damping(t, q, v):
        calls.append((t, np.shape(q), np.shape(v)))
        return -0.8 * v

    damped = mb.simulate(model, q0, v0, 2.0, tau=damping, **opts)
    assert np.all(np.diff(damped.energy) < 0.0)
    assert calls and all(0.0 <= t <= 2.0 and sq == (1,) and sv == (1,) for t, sq, sv in calls)


@pytest.fixture(scope="module")
def reference_swing(revolute_pendulum):
    return mb.simulate(revolute_pendulum, np.array([1.0]), np.array([0.5]), 2.0, dt=0.25,
                       method="DOP853", rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("method, options", [
    ("RK45", dict(rtol=1e-8, atol=1e-10)),
    ("DOP853", dict(rtol=1e-8, atol=1e-10)),
    ("Radau", dict(rtol=1e-8, atol=1e-10)),
    ("RK4", dict(dt=0.01)),
])
def test_integration_methods_agree(revolute_pendulum, reference_swing, method, options):
    """Each method against DOP853 at rtol 1e-13, at the reference's output times: the adaptive ones at
    rtol 1e-8 to 1e-6 (global error ~ a few rtol over a swing), RK4 with h = 0.01 s (error ~ h⁴ ≈ 1e-8)."""
    options = {"dt": 0.25, **options}
    trajectory = mb.simulate(revolute_pendulum, np.array([1.0]), np.array([0.5]), 2.0, method=method, **options)
    assert trajectory.status == "completed"
    keep = np.isin(np.round(trajectory.t, 9), np.round(reference_swing.t, 9))
    assert keep.sum() == len(reference_swing)
    assert_close(trajectory.q[keep], reference_swing.q, 1e-6, scale=1.0, what=f"{method}: q")
    assert_close(trajectory.v[keep], reference_swing.v, 1e-6, scale=1.0, what=f"{method}: v")


def test_rk4_default_step_on_a_user_system():
    """RK4 without ``dt``: the default ``(t_final − t0)/500``. On the minimal helix bead (constant
    s̈, a quadratic s(t)) RK4 is exact up to rounding."""
    system = CurveCoordinateSystem(Helix(1.0, 0.3), 0.7)
    trajectory = mb.simulate(system, np.array([0.5]), np.array([1.2]), 1.0, method="RK4")
    assert len(trajectory) == 501
    assert_close(np.diff(trajectory.t), np.full(500, 1.0 / 500), 1e-12, scale=1.0, what="step")
    s_ddot = -9.81 * 0.3 / 1.09
    t = trajectory.t
    assert_close(trajectory.q[:, 0], 0.5 + 1.2 * t + 0.5 * s_ddot * t**2, 1e-12, scale=1.0, what="s(t)")
    assert trajectory.lam.shape == (501, 0)
    assert relative_energy_drift(trajectory) <= 1e-12


def _free_flyers():
    ball = mb.robots.load("ball", floating_base=True)
    builder = mb.ModelBuilder("box")
    builder.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.4, 0.3, 0.1]))
    return {"ball": (ball, np.array([2.0, -1.0, 4.0])),
            # the box spins about its principal axis of largest inertia (body z): stable, ω constant
            "box": (builder.build(), np.array([0.0, 0.0, 5.0]))}


@pytest.mark.parametrize("name", ["ball", "box"])
def test_free_flyer_falls_and_spins_in_closed_form(name):
    """Free-flyer (``v = [v_lin; ω]`` in the body frame): torque-free rotation about a principal axis
    keeps ω constant (``R(t) = R₀ exp(ω̂ t)``) while the centre of mass falls freely
    (``p = p₀ + v₀ t + ½ g t²``, world axes; body-frame linear velocity ``R(t)ᵀ v_world(t)``).
    The ball is isotropic, so any ω is about a principal axis. The quaternion stays unit.

    The tolerance of each quantity comes from an estimate of the run's error: its largest distance from a run
    at tolerances a thousand times tighter (rtol 1e-13, atol 1e-15), whose own error is far below it, taken no
    smaller than 1000 ulps of the largest value compared (the rounding that both runs share, which their
    distance cannot show), with a margin of 10. Measured on the box: orientation error 1.6e-13 against an
    estimate of 2.7e-13, position 1.1e-14 against 2.0e-14, v 2.4e-12 against 3.3e-12."""
    model, omega = _free_flyers()[name]
    R0 = axis_angle_rotation(np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0), 0.8)
    p0, velocity0 = np.array([0.1, -0.2, 3.0]), np.array([1.0, 0.5, 2.0])
    q0 = np.concatenate([p0, rotation_to_quat(R0)])
    v0 = np.concatenate([R0.T @ velocity0, omega])
    trajectory = mb.simulate(model, q0, v0, 2.0, dt=0.1, **TIGHT)
    reference = mb.simulate(model, q0, v0, 2.0, dt=0.1, method="DOP853", rtol=1e-13, atol=1e-15)
    quaternion_norm = np.linalg.norm(trajectory.q[:, 3:], axis=1)
    assert_close(quaternion_norm, np.ones(len(trajectory)), 1e-12, scale=1.0, what="|quaternion|")
    body = model.body_index(model.body_names[0])
    axis, rate = omega / np.linalg.norm(omega), np.linalg.norm(omega)
    t = trajectory.t
    R = np.array([R0 @ axis_angle_rotation(axis, rate * t_k) for t_k in t])
    closed_form = {"position": p0 + velocity0 * t[:, None] + 0.5 * GRAVITY * t[:, None] ** 2, "orientation": R,
                   "v": np.concatenate([np.einsum("kji,kj->ki", R, velocity0 + GRAVITY * t[:, None]),
                                        np.broadcast_to(omega, (len(t), 3))], axis=1)}

    def quantities(run):
        poses = mb.forward_kinematics(model, run.q)[:, body]
        return {"position": poses[:, :3, 3], "orientation": poses[:, :3, :3], "v": run.v}

    simulated, tighter = quantities(trajectory), quantities(reference)
    for what, exact in closed_form.items():
        rounding = 1e3 * np.finfo(float).eps * np.abs(exact).max()
        estimate = max(float(np.abs(simulated[what] - tighter[what]).max()), rounding)
        assert_close(simulated[what], exact, 10.0 * estimate, scale=1.0, what=what)
    assert relative_energy_drift(trajectory) <= 1e-8


def _spinning_bodies():
    """A box on a free flyer (falling) and on a spherical joint at its centre, each spinning at 5 rad/s about
    its major axis, from the same orientation: ``(model, q0, v0)``."""
    R0 = axis_angle_rotation(np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0), 0.8)
    omega = np.array([0.0, 0.0, 5.0])
    free, _ = _free_flyers()["box"]
    builder = mb.ModelBuilder("top")
    builder.add_body("box", mb.joints.Spherical(), inertia=mb.inertia.box(2.0, [0.4, 0.3, 0.1]))
    return {"free-flyer": (free, np.concatenate([[0.1, -0.2, 3.0], rotation_to_quat(R0)]),
                           np.concatenate([R0.T @ np.array([1.0, 0.5, 2.0]), omega])),
            "spherical": (builder.build(), rotation_to_quat(R0), omega)}


@pytest.mark.parametrize("joint", ["free-flyer", "spherical"])
def test_adaptive_steps_turn_a_rotation_vector_by_at_most_half_a_revolution(joint, monkeypatch):
    """A rotation vector's chart is singular at 2π. In its charts the spinning box moves along polynomials, so
    DOP853 at rtol 1e-10 would lengthen its steps tenfold each time, past a revolution (a step of 1.26 s turning
    6.3 rad, whose dense output was off by 1e-7 in orientation). Each step turns the chart by at most
    ``CHART_TURN`` (π) at the angular speed of its start, and the steps reach that length."""
    ends = []
    settle = mb.simulation._ChartStages.settle

    def recorded(self, t, state):
        ends.append(t)
        return settle(self, t, state)

    # (a Python controller runs the steps as Python, whose maps see every step's end)
    monkeypatch.setattr(mb.simulation._ChartStages, "settle", recorded)
    model, q0, v0 = _spinning_bodies()[joint]
    mb.simulate(model, q0, v0, 4.0, dt=0.1, tau=lambda t, q, v: None, **TIGHT)
    turn = np.max(np.diff([0.0] + ends)) * 5.0
    assert 0.9 * mb.simulation.CHART_TURN <= turn <= mb.simulation.CHART_TURN * (1.0 + 1e-12), turn


def test_fast_spin_far_from_the_origin_keeps_long_steps_and_digits():
    """Lie-group integration with parent-aligned velocities: the box spins at 60 rad/s about its major
    axis (95 revolutions) while falling 490 m in 10 s. In each step's chart the rotation vector grows
    with the spin and the aligned velocity only with gravity, so DOP853 steps half a revolution at a time,
    the longest its charts allow (``CHART_TURN``): 2364 evaluations of the joint forces (one per evaluation
    of the motion) measured; the bound of 8000 is seven steps per revolution, where quaternion coordinates
    with body-frame velocities take many times more; and the dynamics, taken at the base rather than the
    world origin, keeps its digits 490 m away. The closed form holds to 1e-9 at the end."""
    builder = mb.ModelBuilder("box")
    builder.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.4, 0.3, 0.1]))
    model = builder.build()
    system = mb.ConstrainedSystem(model)
    evaluations = [0]

    def counted(t, q, v):
        """No joint forces, counting the evaluations of the motion (each calls it once)."""
        evaluations[0] += 1
        return np.zeros(model.nv)

    omega = np.array([0.0, 0.0, 60.0])
    R0 = axis_angle_rotation(np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0), 0.8)
    p0, velocity0 = np.array([0.1, -0.2, 3.0]), np.array([1.0, 0.5, 2.0])
    q0, v0 = np.concatenate([p0, rotation_to_quat(R0)]), np.concatenate([R0.T @ velocity0, omega])
    trajectory = mb.simulate(system, q0, v0, 10.0, dt=0.5, tau=counted, **TIGHT)
    t = trajectory.t[-1]
    pose = mb.forward_kinematics(model, trajectory.q[-1])[0]
    assert_close(pose[:3, 3], p0 + velocity0 * t + 0.5 * GRAVITY * t**2, 1e-9, scale=500.0, what="position")
    assert_close(pose[:3, :3], R0 @ axis_angle_rotation(omega / 60.0, 60.0 * t), 1e-9, scale=1.0, what="orientation")
    assert_close(np.linalg.norm(trajectory.q[:, 3:], axis=1), np.ones(len(trajectory)), 1e-14, scale=1.0,
                 what="|quaternion|")
    assert evaluations[0] < 8000


def test_every_joint_type_integrates_in_charts():
    """A random tree with every joint type (free flyer, spherical, planar, revolute, prismatic, ...):
    DOP853 with a new chart per step conserves energy to 1e-11 relative, keeps every quaternion and
    planar (cos θ, sin θ) pair unit (the returned states are not normalised afterwards), and agrees
    with RK4 (one chart per 1 ms step) to 1e-9 (measured: 2e-11 in q, 5e-11 relative in v). The free
    motion leaves the prismatic joint's limits, which are reported, not enforced: not this test's matter."""
    model = random_tree_model(0)
    rng = np.random.default_rng(0)
    q0, v0 = model.random_configuration(rng), rng.standard_normal(model.nv)
    adaptive = mb.simulate(model, q0, v0, 0.5, dt=0.05, limits="ignore", **TIGHT)
    assert relative_energy_drift(adaptive) <= 1e-11
    assert_close(model.normalize(adaptive.q), adaptive.q, 1e-14, scale=1.0, what="unit blocks")
    fixed = mb.simulate(model, q0, v0, 0.5, dt=1e-3, method="RK4", limits="ignore")
    assert_close(model.difference(fixed.q[-1], adaptive.q[-1]), np.zeros(model.nv), 1e-9, scale=1.0,
                 what="configuration, DOP853 vs RK4")
    assert_close(adaptive.v[-1], fixed.v[-1], 1e-9, scale=max(1.0, np.abs(fixed.v[-1]).max()), what="velocity")


def test_inconsistent_initial_state_is_projected_with_a_warning():
    """A pendulum started 1 % too long with a radial velocity: projected with a UserWarning that gives
    the distance moved (max over q and v of the change, 3 significant digits)."""
    cs = pendulum_system()
    q_ok, v_ok = pendulum_state(L_PEND, 0.6, 0.4)
    q0, v0 = 1.01 * q_ok, v_ok + 0.05 * q_ok / L_PEND
    with pytest.warns(UserWarning, match="projected onto them") as record:
        trajectory = mb.simulate(cs, q0, v0, 0.2, dt=0.1)
    message = str(record[0].message)
    moved = float(re.search(r"moved by ([0-9.eE+-]+)", message).group(1))
    actual = max(np.abs(trajectory.q[0] - q0).max(), np.abs(trajectory.v[0] - v0).max())
    assert actual > 1e-3 and moved == pytest.approx(actual, rel=6e-3)
    assert trajectory.residual[0] <= 1e-12
    # a consistent start is not warned about
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        mb.simulate(cs, q_ok, v_ok, 0.2, dt=0.1)


#: Every integration method of ``mb.simulate``.
ALL_METHODS = mb.simulation.ADAPTIVE_METHODS + mb.simulation.FIXED_STEP_METHODS + ("variational",)


@pytest.mark.parametrize("method", ["RK4", "RK45", "variational"])
def test_blow_up_raises_simulation_error_with_partial_trajectory(method):
    """A torque that turns NaN after t = 0.5 s: SimulationError naming the time it was evaluated at and the
    joint, whose ``.trajectory`` holds the (finite) states computed before the failure, all at times before
    it."""
    cs = pendulum_system()
    q0, v0 = pendulum_state(L_PEND, 0.6, 0.4)

    def tau(t, q, v):
        return np.full(3, np.nan) if t > 0.5 else np.zeros(3)

    with pytest.raises(mb.SimulationError) as info:
        mb.simulate(cs, q0, v0, 1.0, dt=0.05, method=method, tau=tau)
    message = str(info.value)
    found = re.search(r"the joint forces tau\(t, q, v\) are not finite at t = (\S+) s: tau\[0\] \(joint 'p_joint', N\) "
                      r"= nan, tau\[1\] .* = nan, tau\[2\] .* = nan$", message)
    assert found, message
    partial = info.value.trajectory
    assert isinstance(partial, mb.Trajectory)
    assert len(partial) > 0 and partial.t[-1] <= 0.5 + 1e-12 and float(found.group(1)) > 0.5
    assert message.startswith(f"simulation stopped at t = {partial.t[-1]:.6g} s: ")
    assert_close(partial.t, np.linspace(0.0, partial.t[-1], len(partial)), 1e-12, scale=1.0, what="times")
    assert np.all(np.isfinite(partial.q)) and np.all(np.isfinite(partial.v)) and np.all(np.isfinite(partial.lam))
    assert partial.status == message
    # the states before the failure are the undisturbed motion (the same run to the same t_final, so
    # the same steps: the outputs agree to rounding, not just to the integration tolerance)
    reference = mb.simulate(cs, q0, v0, 1.0, dt=0.05, method=method)
    assert_close(partial.q, reference.q[: len(partial)], 1e-12, scale=1.0, what="states before the failure")


@pytest.mark.parametrize("method", ALL_METHODS)
def test_joint_forces_that_turn_non_finite_stop_every_method_naming_time_and_joint(method):
    """The double pendulum with an elbow torque that turns NaN after t = 0.5 s, by every method: SimulationError
    naming the time the torque was evaluated at and the joint, with the finite states before it, which are
    those of the run without the torque (the same steps, so to rounding)."""
    model = mb.robots.load("double_pendulum")
    q0, v0 = np.array([0.3, 0.2]), np.zeros(2)

    def tau(t, q, v):
        return np.array([0.0, np.nan if t > 0.5 else 0.0])

    with pytest.raises(mb.SimulationError) as info:
        mb.simulate(model, q0, v0, 1.0, dt=0.05, method=method, tau=tau)
    message = str(info.value)
    found = re.search(r"the joint forces tau\(t, q, v\) are not finite at t = (\S+) s: tau\[1\] \(joint 'elbow', "
                      r"N·m\) = nan$", message)
    assert found and float(found.group(1)) > 0.5, message
    partial = info.value.trajectory
    # the last output is the start of the step that failed (an explicit Euler step evaluates the torque there)
    assert 0 < len(partial) and partial.t[-1] <= float(found.group(1)) and partial.status == message
    assert np.isfinite(partial.q).all() and np.isfinite(partial.v).all()
    reference = mb.simulate(model, q0, v0, 1.0, dt=0.05, method=method)
    assert_close(partial.q, reference.q[: len(partial)], 1e-12, scale=1.0, what="states before the failure")


def test_non_finite_initial_state_or_constant_joint_forces_are_refused_rather_than_hanging():
    """Non-finite q0, v0 or constant tau: ValueError at once by every method, naming the argument and its
    entries by joint (from a NaN state SciPy's RK45 and DOP853 would shrink their steps for ever). The
    simulations run in a child process with a timeout, so that a regression fails instead of hanging the
    suite: the child takes about 3 s, most of it importing, and the timeout of 120 s leaves a wide margin for
    a slow machine."""
    code = textwrap.dedent("""
        import numpy as np
        import multibody as mb
        from multibody.simulation import ADAPTIVE_METHODS, FIXED_STEP_METHODS
        model = mb.robots.load("double_pendulum")
        q0, v0 = np.array([0.3, 0.2]), np.zeros(2)
        cases = {"q0": dict(q0=np.array([np.nan, 0.2]), v0=v0), "v0": dict(q0=q0, v0=np.array([-np.inf, np.nan])),
                 "tau": dict(q0=q0, v0=v0, tau=np.array([0.0, np.nan])),
                 # (joint damping wraps the joint forces in a callable: the array is checked first)
                 "damped tau": dict(q0=q0, v0=v0, tau=np.array([0.0, np.nan]), joint_damping=True)}
        for method in ADAPTIVE_METHODS + FIXED_STEP_METHODS + ("variational",):
            for case, arguments in cases.items():
                try:
                    mb.simulate(model, t_final=1.0, method=method, **arguments)
                except ValueError as error:
                    print(f"{method}, {case}: {error}")
        """)
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert child.returncode == 0, child.stderr
    messages = {"q0": "q0 must be finite: q[0] (joint 'shoulder', rad) = nan",
                "v0": "v0 must be finite: v[0] (joint 'shoulder', rad/s) = -inf, v[1] (joint 'elbow', rad/s) = nan",
                "tau": "tau must be finite: tau[1] (joint 'elbow', N·m) = nan",
                "damped tau": "tau must be finite: tau[1] (joint 'elbow', N·m) = nan"}
    assert child.stdout.splitlines() == [f"{method}, {case}: {message}" for method in ALL_METHODS
                                         for case, message in messages.items()]


def _free_particle_system():
    """A free particle of 1 g on a line, written as a symbolic Lagrangian system (no Model: no joint names)."""
    import sympy as sp
    from sympy.physics.mechanics import dynamicsymbols

    x, y = dynamicsymbols("x y")
    mass = sp.Symbol("m")
    return mb.LagrangianSystem([x, y], mass / 2 * (x.diff() ** 2 + y.diff() ** 2)).numeric(m=1e-3)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_non_finite_joint_forces_of_a_system_without_a_model_name_the_coordinate(method):
    system = _free_particle_system()

    def tau(t, q, v):
        return np.array([0.0, np.nan if t > 0.5 else 0.0])

    with pytest.raises(mb.SimulationError, match=r"the joint forces tau\(t, q, v\) are not finite at t = \S+ s: "
                                                 r"tau\[1\] = nan$") as info:
        mb.simulate(system, np.zeros(2), np.ones(2), 1.0, dt=0.01, method=method, tau=tau)
    failed_at = float(re.search(r"are not finite at t = (\S+) s", str(info.value)).group(1))
    assert failed_at > 0.5 and info.value.trajectory.t[-1] <= failed_at and np.isfinite(info.value.trajectory.q).all()


def test_a_non_finite_initial_state_of_a_system_without_a_model_is_named_by_index():
    with pytest.raises(ValueError, match=re.escape("q0 must be finite: q[1] = inf")):
        mb.simulate(_free_particle_system(), np.array([0.0, np.inf]), np.ones(2), 1.0, method="RK4")


@pytest.mark.parametrize("method", ALL_METHODS)
def test_dynamics_that_overflow_stop_with_the_time(method):
    """Finite joint forces of 1e307 N on a particle of 1 g from t = 0.5 s: the accelerations overflow. Every
    method stops with SimulationError naming a time after 0.5 s; the adaptive ones, which would shrink their
    steps until SciPy gives up, say that the equations of motion are not finite and where."""
    system = _free_particle_system()

    def tau(t, q, v):
        return np.array([1e307 if t > 0.5 else 0.0, 0.0])

    with pytest.raises(mb.SimulationError) as info:
        mb.simulate(system, np.zeros(2), np.ones(2), 1.0, dt=0.01, method=method, tau=tau)
    message = str(info.value)
    times = [float(t) for t in re.findall(r"at t = (\S+) s", message)]
    assert len(times) == 2 and times[1] > 0.5, message
    if method in mb.simulation.ADAPTIVE_METHODS:
        assert re.search(r"the equations of motion are not finite at t = \S+ s, at a finite state \(the dynamics "
                         r"overflowed\): the acceleration of v\[0\] is (inf|nan)$", message), message
    partial = info.value.trajectory
    assert partial.t[-1] == pytest.approx(times[0], abs=1e-6) and np.isfinite(partial.q).all()
    assert np.isfinite(partial.v).all()


def test_massless_model_raises_simulation_error():
    """A massless particle: M = 0, no KKT solution at all; the error names the joint that moves nothing."""
    builder = mb.ModelBuilder("ghost")
    builder.add_body("p", mb.joints.Translation())
    model = builder.build(check_inertia=False)
    with pytest.raises(mb.SimulationError, match="mass matrix is singular: joint 'p_joint' moves no inertia") as info:
        mb.simulate(model, np.zeros(3), np.zeros(3), 1.0)
    assert len(info.value.trajectory) == 0


# ============================================================================= 11. JointCoupling in motion

def test_joint_coupling_holds_along_a_simulation():
    """The double pendulum with its elbow geared to the shoulder, ``q_e = −0.6 q_s + 0.4``: the
    relation holds along a 3 s DOP853 run to 1e-10 and the (workless) coupling conserves energy."""
    model = mb.robots.load("double_pendulum")
    ratio, offset = -0.6, 0.4
    cs = mb.ConstrainedSystem(model, [mb.JointCoupling("shoulder", "elbow", ratio, offset)])
    trajectory = mb.simulate(cs, np.array([1.0, ratio + offset]), np.array([0.5, ratio * 0.5]), 3.0, dt=0.1, **TIGHT)
    q = trajectory.q
    assert_close(q[:, 1], ratio * q[:, 0] + offset, 1e-10, scale=1.0, what="q_b = r q_a + c")
    assert_close(trajectory.v[:, 1], ratio * trajectory.v[:, 0], 1e-10, scale=1.0, what="v_b = r v_a")
    assert np.ptp(q[:, 0]) > 1.0
    assert relative_energy_drift(trajectory) <= 1e-8


# ============================================================================= 12. bad input

def test_simulate_rejects_bad_arguments():
    cs = pendulum_system()
    q0, v0 = pendulum_state(L_PEND, 0.3, 0.0)
    with pytest.raises(ValueError, match="method must be one of"):
        mb.simulate(cs, q0, v0, 1.0, method="Verlet")
    with pytest.raises(ValueError, match="must be after t0"):
        mb.simulate(cs, q0, v0, 0.0)
    with pytest.raises(ValueError, match="must be after t0"):
        mb.simulate(cs, q0, v0, 1.0, t0=2.0)
    with pytest.raises(ValueError, match="dt must be positive"):
        mb.simulate(cs, q0, v0, 1.0, dt=0.0)
    with pytest.raises(ValueError, match="shapes"):
        mb.simulate(cs, q0[:2], v0, 1.0)
    with pytest.raises(ValueError, match="tau must be None, an array"):
        mb.simulate(cs, q0, v0, 1.0, tau=np.zeros(2))
    with pytest.raises(TypeError, match="not a mechanical system"):
        mb.simulate("pendulum", q0, v0, 1.0)


class _CircleWithoutCharts:
    """A rotor whose angle is stored as (cos θ, sin θ) (nq = 2, nv = 1), with no chart maps."""

    nq, nv = 2, 1

    def mass_matrix(self, q):
        return np.ones(np.shape(q)[:-1] + (1, 1))

    def bias_forces(self, q, v):
        return np.zeros(np.shape(v))

    def integrate(self, q, v, dt=1.0):
        c, s = np.cos(v[..., 0] * dt), np.sin(v[..., 0] * dt)
        return np.stack([c * q[..., 0] - s * q[..., 1], s * q[..., 0] + c * q[..., 1]], axis=-1)


def test_simulate_refuses_a_curved_system_without_chart_maps():
    with pytest.raises(ValueError, match="nq = 2 != nv = 1 but no chart maps"):
        mb.simulate(_CircleWithoutCharts(), np.array([1.0, 0.0]), np.array([1.0]), 1.0)


def test_a_diverging_integration_says_so():
    """A stiff PD gain with a long RK4 step diverges: the error says the state grew beyond bounds,
    names the coordinate and its size, and suggests a smaller step, rather than blaming the mass
    matrix."""
    model = mb.robots.load("double_pendulum")
    gains = 1e6

    def stiff(t, q, v):
        return -gains * (q - 0.3) - 10.0 * v

    with pytest.raises(mb.SimulationError) as info:
        mb.simulate(model, np.zeros(2), np.zeros(2), 5.0, dt=0.05, method="RK4", tau=stiff)
    message = str(info.value)
    assert "grew beyond bounds" in message and "smaller step" in message
    assert re.search(r"v\[\d\] \(joint '\w+', rad/s\)", message), message


def test_an_adaptive_method_that_stalls_says_so():
    """Joint forces with a random part at every call (no smooth right-hand side) drive RK45 at rtol 1e-10
    to ever smaller steps: once its last ``STALLED_STEPS`` steps advance less than ``STALLED_SPAN`` of the
    run, the error names the method, the time and how far those steps went, with the trajectory so far,
    rather than running on; away from constraints it says nothing of singular configurations."""
    model = mb.robots.load("pendulum")
    rng = np.random.default_rng(0)

    def noisy(t, q, v):
        return 10.0 * rng.standard_normal(model.nv)

    with pytest.raises(mb.SimulationError) as info:
        mb.simulate(model, np.zeros(1), np.zeros(1), 10.0, method="RK45", rtol=1e-10, atol=1e-12, tau=noisy)
    message = str(info.value)
    assert re.search(r"RK45 stalled at t = \S+ s: its last 1000 steps advanced \S+ s in all", message), message
    assert "singular" not in message
    partial = info.value.trajectory
    assert partial.t[-1] < 10.0 and np.isfinite(partial.q).all()
    stalled_at = float(re.search(r"stalled at t = (\S+) s", message).group(1))
    assert partial.t[-1] <= stalled_at


def test_the_projection_warning_names_the_coordinates_and_units():
    cs = pendulum_system()
    q_ok, v_ok = pendulum_state(L_PEND, 0.6, 0.4)
    with pytest.warns(UserWarning, match=r"moved by [0-9.e+-]+: q\[\d\] .* by [0-9.e+-]+ and v\[\d\] .*m/s.* by"):
        mb.simulate(cs, 1.01 * q_ok, v_ok + 0.05 * q_ok / L_PEND, 0.2, dt=0.1)
