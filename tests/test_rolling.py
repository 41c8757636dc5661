"""Rolling and knife-edge constraints at single states: ``RollingSphere``, ``RollingDisc``, ``KnifeEdge``.

Checked against closed forms (a uniform ball on an incline, a differential-drive robot driven
straight), against the definition of the rows (slip velocity of the contact material point from
``mb.point_velocity``), against central finite differences (γ), and against Pinocchio's KKT solve.

Sign convention (docs/conventions.md): ``M a + h = τ + Aᵀ λ``, ``A v + b = 0``, ``A a = γ``.
Pinocchio's ``pin.forwardDynamics(model, data, q, v, τ, J, drift)`` solves ``M a + h = τ + Jᵀ λ``
with ``J a = −drift``; fed ``J = A`` and ``drift = −γ`` its ``data.lambda_c`` is our ``λ``.

Tolerances: closed forms and Pinocchio at 1e-9 relative (a KKT solve of ≤ 6 unknowns loses a few
hundred ulps at most; observed ~1e-13); finite differences at 1e-7 relative (see ``fd_gamma``).
"""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import quat_to_rotation

from conftest import q_to_pinocchio
from rolling_helpers import (
    BALL_MASS,
    BALL_RADIUS,
    G,
    chaplygin_ball,
    coin,
    diff_drive_numbers,
    downhill,
    fd_gamma,
    free_ball,
    quat,
    relative_error,
    rotation,
    sleigh,
    tilted_normal,
    turntable,
)

# ============================================================================= 1. ball on an incline, at rest

INCLINES = [(0.3, 0.0), (0.15, 1.1), (0.6, -2.4)]  # (tilt α, azimuth of the downhill direction)


@pytest.mark.parametrize("alpha, azimuth", INCLINES)
def test_ball_on_incline_at_rest_closed_form(alpha, azimuth):
    """Uniform ball released on an incline: ẍ = 5/7 g sin α downhill, friction 2/7 m g sin α uphill,
    normal force m g cos α (Newton: m ẍ = m g + F + N n, I ω̇ = (−r n) × F, rolling ẍ = r ω̇ × n)."""
    ball = free_ball()
    n = tilted_normal(alpha, azimuth)
    contact = mb.RollingSphere("ball", BALL_RADIUS, plane_normal=n)
    cs = mb.ConstrainedSystem(ball, [contact])
    d = downhill(n)
    for rpy in ([0.0, 0.0, 0.0], [0.4, -1.2, 2.0]):  # the ball's orientation must not matter
        R = rotation(rpy)
        q = np.concatenate([BALL_RADIUS * n, quat(R)])
        assert cs.residual(q, np.zeros(6)) <= 1e-15
        a, lam = cs.forward_dynamics(q, np.zeros(6))
        # v = 0: the body-frame accelerations are R_WBᵀ ẍ and R_WBᵀ ω̇.
        x_ddot, omega_dot = R @ a[:3], R @ a[3:]
        assert relative_error(x_ddot, 5.0 / 7.0 * G * np.sin(alpha) * d, scale=G) <= 1e-9
        assert relative_error(omega_dot, np.cross(n, x_ddot) / BALL_RADIUS, scale=G / BALL_RADIUS) <= 1e-9
        friction = -2.0 / 7.0 * BALL_MASS * G * np.sin(alpha) * d
        expected = np.concatenate([contact.frame[:, :2].T @ friction, [BALL_MASS * G * np.cos(alpha)]])
        assert relative_error(lam, expected, scale=BALL_MASS * G) <= 1e-9
        # The multipliers are the contact force in the plane frame [t₁ t₂ n].
        assert relative_error(contact.frame @ lam, friction + BALL_MASS * G * np.cos(alpha) * n,
                              scale=BALL_MASS * G) <= 1e-9


# ============================================================================= 2. the rows are the slip velocity

def _body_point(model, q, body, world_point):
    """Body coordinates of a world point, for ``mb.point_velocity``."""
    X = mb.forward_kinematics(model, q)[model.body_index(body)]
    return X[:3, :3].T @ (world_point - X[:3, 3])


def _slip_rows(model, contact, q, v, t):
    """``Eᵀ (v_material(c) − v_surface(c, t))`` from ``mb.point_velocity`` at the contact point ``c``."""
    c = contact.contact_point(model, q)
    material = mb.point_velocity(model, q, v, contact.body, _body_point(model, q, contact.body, c))[:3]
    surface = np.zeros(3) if contact.surface_velocity is None else contact.surface_velocity(c, t)
    rows = contact.frame.T @ (material - surface)
    return rows if contact.include_normal else rows[:2]


def _onto_plane(cs, q):
    """Translate a free-flyer body along the plane normal so that its contact point lies on the plane.

    ``project``'s Gauss–Newton steps are the smallest moves in the kinetic-energy metric; from a
    random configuration far (~1 m) from the plane, with a sphere centre offset from the centre of
    mass, most of that move is a large rotation, the linearisation fails and the projection does not
    converge (observed). Starting on the plane leaves ``project`` only the velocities to fix.
    """
    contact = cs.constraints[0]
    if not isinstance(contact, (mb.RollingSphere, mb.RollingDisc)) or not contact.include_normal:
        return q
    q = np.array(q, dtype=float)
    q[:3] -= cs.position_error(q)[2] * contact.normal
    return q


def _random_disc_state(model, rng, normal, axis_body=(0.0, 0.0, 1.0), max_tilt=0.95):
    """A random free-flyer state whose disc axis is not (nearly) along the plane normal."""
    while True:
        q = model.random_configuration(rng)
        if abs(normal @ quat_to_rotation(q[3:]) @ np.asarray(axis_body)) < max_tilt:
            return q, rng.standard_normal(model.nv)


def test_rolling_sphere_rows_are_slip_velocity():
    """Sphere with its centre offset from the body origin, tilted turning plane: A v + b is the
    velocity of the body's material point at c = centre − r n relative to the surface there."""
    rng = np.random.default_rng(1)
    model = chaplygin_ball()
    n = tilted_normal(0.4, 0.7)
    centre = np.array([0.03, -0.02, 0.05])
    table = turntable(2.5, centre=[0.3, -0.1, 0.0], axis=n)
    contact = mb.RollingSphere("ball", 0.2, center=centre, plane_normal=n, plane_point=[0.3, -0.1, 0.0],
                               surface_velocity=table)
    cs = mb.ConstrainedSystem(model, [contact])
    E = contact.frame  # the plane frame [t₁ t₂ n]: orthonormal, right-handed, third axis n
    assert np.allclose(E.T @ E, np.eye(3), atol=1e-15) and np.linalg.det(E) == pytest.approx(1.0)
    assert np.allclose(E[:, 2], n, atol=1e-15)
    for _ in range(3):
        q, v, t = model.random_configuration(rng), rng.standard_normal(6), rng.uniform(0, 2)
        R, p = quat_to_rotation(q[3:]), q[:3]
        c = contact.contact_point(model, q)
        assert relative_error(c, p + R @ centre - 0.2 * n, scale=1.0) <= 1e-14
        A, b = cs.jacobian(q, t), cs.velocity_bias(q, t)
        assert relative_error(A @ v + b, _slip_rows(model, contact, q, v, t), scale=1.0 + np.abs(v).max()) <= 1e-13
        # The normal row's position level: height of the contact point above the plane.
        assert cs.position_error(q, t)[2] == pytest.approx(n @ (c - [0.3, -0.1, 0.0]), abs=1e-14)


@pytest.mark.parametrize("axis, centre", [((0.0, 0.0, 1.0), None), ((0.0, 1.0, 0.0), (0.01, 0.02, -0.03))])
def test_rolling_disc_contact_point_and_rows(axis, centre):
    """Disc on a tilted plane at random leans: the contact point is the rim point lowest along n
    (|c − x_O| = r, (c − x_O) ⟂ axis, n·(c − x_O) = −r √(1 − (n·a)²)), and A v + b is its slip velocity."""
    rng = np.random.default_rng(2)
    model = coin(radius=0.3)
    n = tilted_normal(0.35, -0.8)
    contact = mb.RollingDisc("coin", 0.3, axis=axis, center=centre, plane_normal=n,
                             surface_velocity=turntable(-1.5, axis=n))
    cs = mb.ConstrainedSystem(model, [contact])
    for _ in range(3):
        q, v = _random_disc_state(model, rng, n, axis)
        t = rng.uniform(0, 2)
        R = quat_to_rotation(q[3:])
        x_O = q[:3] + R @ (np.zeros(3) if centre is None else np.asarray(centre))
        a = R @ np.asarray(axis)
        c = contact.contact_point(model, q)
        d = c - x_O
        assert np.linalg.norm(d) == pytest.approx(0.3, rel=1e-14)
        # rounding: d = c − x_O carries ε (|c| + |x_O|) in each entry, c ε r more, and the dot product sums three
        # of them (measured up to 0.6 of this); margin 10
        rounding = 3.0 * np.finfo(float).eps * (np.abs(c).max() + np.abs(x_O).max() + 0.3)
        assert abs(d @ a) <= 10.0 * rounding
        assert n @ d == pytest.approx(-0.3 * np.sqrt(1.0 - (n @ a) ** 2), rel=1e-13)
        A, b = cs.jacobian(q, t), cs.velocity_bias(q, t)
        assert relative_error(A @ v + b, _slip_rows(model, contact, q, v, t), scale=1.0 + np.abs(v).max()) <= 1e-13


def test_knife_edge_row_is_sideways_velocity():
    """One row: the blade point's velocity along w = n × e / |n × e| (e the blade in world axes)."""
    rng = np.random.default_rng(3)
    model = chaplygin_ball()
    n = tilted_normal(0.3, 2.0)
    point, direction = np.array([0.1, 0.2, -0.05]), np.array([0.6, -0.8, 0.3])
    blade = mb.KnifeEdge("ball", point=point, direction=direction, plane_normal=n)
    cs = mb.ConstrainedSystem(model, [blade])
    for _ in range(3):
        q, v = model.random_configuration(rng), rng.standard_normal(6)
        e = quat_to_rotation(q[3:]) @ direction / np.linalg.norm(direction)
        w = np.cross(n, e) / np.linalg.norm(np.cross(n, e))
        x_dot = mb.point_velocity(model, q, v, "ball", point)[:3]
        assert cs.jacobian(q) @ v == pytest.approx([w @ x_dot], abs=1e-14 * (1 + np.abs(v).max()))
        assert np.all(cs.velocity_bias(q) == 0.0)


# ============================================================================= 3. γ by finite differences

def _sphere_tilted():
    model = free_ball()
    return model, [mb.RollingSphere("ball", BALL_RADIUS, plane_normal=tilted_normal(0.5, 0.3),
                                    plane_point=[0.1, 0.2, -0.3])]


def _sphere_turntable_offset():
    # A turntable (v = Ω e_z × p) under an eccentric sphere: b ≠ 0 and depends on q.
    model = chaplygin_ball()
    return model, [mb.RollingSphere("ball", 0.15, center=[0.04, -0.03, 0.02], surface_velocity=turntable(3.0))]


def _sphere_accelerating_table_tilted():
    # Explicitly time-dependent surface: Ω(t) = 2 (1 + 0.5 sin 3t) about the tilted normal.
    n = tilted_normal(0.25, -1.0)
    model = chaplygin_ball()

    def table(p, t):
        return 2.0 * (1.0 + 0.5 * np.sin(3.0 * t)) * np.cross(n, np.asarray(p) - [0.2, 0.0, 0.0])

    return model, [mb.RollingSphere("ball", 0.12, center=[-0.02, 0.05, 0.01], plane_normal=n, surface_velocity=table)]


def _disc_tilted():
    model = coin(radius=0.3)
    return model, [mb.RollingDisc("coin", 0.3, axis=(0.0, 0.0, 1.0), plane_normal=tilted_normal(0.4, 2.2))]


def _disc_offset_turntable():
    n = tilted_normal(0.2, 0.5)
    model = coin(radius=0.3)
    return model, [mb.RollingDisc("coin", 0.25, axis=(0.3, 1.0, -0.2), center=(0.02, -0.01, 0.03), plane_normal=n,
                                  surface_velocity=turntable(1.7, centre=[0.5, 0.1, 0.0], axis=n))]


def _disc_diff_drive():
    model = mb.robots.load("diff_drive")
    return model, [mb.RollingDisc(w, 0.08, axis=(0.0, 1.0, 0.0), normal=False) for w in ("left_wheel", "right_wheel")]


def _knife_free_flyer():
    model = chaplygin_ball()
    return model, [mb.KnifeEdge("ball", point=[0.1, -0.2, 0.05], direction=[1.0, 0.5, -0.2],
                                plane_normal=tilted_normal(0.3, 1.0))]


def _knife_sleigh():
    model, blade = sleigh()
    return model, [blade]


GAMMA_CASES = {
    "sphere-tilted": _sphere_tilted,
    "sphere-turntable-centre-offset": _sphere_turntable_offset,
    "sphere-time-varying-table-tilted": _sphere_accelerating_table_tilted,
    "disc-tilted-random-lean": _disc_tilted,
    "disc-axis-centre-offset-turntable": _disc_offset_turntable,
    "disc-diff-drive-wheels": _disc_diff_drive,
    "knife-edge-free-flyer-tilted": _knife_free_flyer,
    "knife-edge-sleigh": _knife_sleigh,
}


@pytest.mark.parametrize("case", sorted(GAMMA_CASES))
def test_gamma_matches_finite_differences(case):
    """γ = −d/ds [A(q ⊕ v s, t + s) v + b(q ⊕ v s, t + s)] at s = 0 (any state, not only consistent ones)."""
    model, constraints = GAMMA_CASES[case]()
    cs = mb.ConstrainedSystem(model, constraints)
    rng = np.random.default_rng(sorted(GAMMA_CASES).index(case))
    discs = [c for c in constraints if isinstance(c, mb.RollingDisc) and model.joints[0].kind == "free-flyer"]
    for _ in range(4):
        if discs:
            q, v = _random_disc_state(model, rng, discs[0].normal, discs[0].axis)
        else:
            q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
        t = rng.uniform(0.0, 2.0)
        gamma = cs.acceleration_rhs(q, v, t)
        expected = fd_gamma(cs, q, v, t)
        assert relative_error(gamma, expected, scale=max(np.abs(expected).max(), 1e-3)) <= 1e-7, case
        # The shared evaluate() pass gives the same three levels as the separate calls.
        A, b, gamma_eval = constraints[0].evaluate(cs.system, q, v, t)
        assert np.allclose(A, constraints[0].jacobian(cs.system, q, t), rtol=0, atol=1e-14)
        assert np.allclose(gamma_eval, gamma[: len(gamma_eval)], rtol=0, atol=1e-12 * (1 + np.abs(gamma).max()))


def test_gamma_is_quadratic_in_v_for_fixed_surfaces():
    """Scleronomic rows: γ(q, s v) = s² γ(q, v) (no explicit time, b = 0)."""
    rng = np.random.default_rng(5)
    for make in (_sphere_tilted, _disc_tilted, _knife_free_flyer):
        model, constraints = make()
        cs = mb.ConstrainedSystem(model, constraints)
        q, v = _random_disc_state(model, rng, constraints[0].normal) if make is _disc_tilted else (
            model.random_configuration(rng), rng.standard_normal(model.nv))
        gamma = cs.acceleration_rhs(q, v)
        assert relative_error(cs.acceleration_rhs(q, 3.0 * v), 9.0 * gamma) <= 1e-12
        assert np.all(cs.velocity_bias(q) == 0.0)


# ============================================================================= 4. Pinocchio's KKT

def test_ball_rolling_matches_pinocchio_kkt(pin):
    """Free-flyer ball on a tilted plane, random consistent states and torques: (a, λ) equal
    Pinocchio's forwardDynamics fed J = A and drift = −γ."""
    ball = free_ball()
    cs = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", BALL_RADIUS, plane_normal=tilted_normal(0.3, 0.4))])
    pmodel = pin.buildModelFromUrdf(mb.robots.path("ball"), pin.JointModelFreeFlyer())
    pdata = pmodel.createData()
    assert np.allclose(pmodel.gravity.linear, ball.gravity)
    rng = np.random.default_rng(7)
    for _ in range(4):
        q, v = cs.project(ball.random_configuration(rng), rng.standard_normal(6))
        tau = rng.standard_normal(6)
        solution = cs.solve(q, v, tau)
        A, gamma = cs.jacobian(q), cs.acceleration_rhs(q, v)
        assert np.array_equal(A, solution.A) and np.allclose(gamma, solution.gamma, rtol=0, atol=1e-14)
        a_pin = pin.forwardDynamics(pmodel, pdata, q, v, tau, A, -gamma).copy()
        assert relative_error(solution.a, a_pin) <= 1e-9
        assert relative_error(solution.lam, pdata.lambda_c) <= 1e-9
        assert solution.rank == 3


def _diff_drive_system():
    robot = mb.robots.load("diff_drive")
    wheels = [mb.RollingDisc(w, 0.08, axis=(0.0, 1.0, 0.0), normal=False) for w in ("left_wheel", "right_wheel")]
    return robot, mb.ConstrainedSystem(robot, wheels)


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the redundancy, below)
def test_diff_drive_matches_pinocchio_kkt(pin):
    """Differential drive (URDF planar + continuous joints), random consistent states and torques.

    The four rows have rank 3: the wheels' contact points both lie on the axle line (body y), and
    two points of one rigid body have the same velocity component along the line joining them, so
    the chassis' sideways velocity is constrained twice. Pinocchio's (undamped) Cholesky of the
    singular Delassus matrix ``J M⁻¹ Jᵀ`` cannot take the redundant row, so it gets three
    independent combinations ``J₃ = Uᵀ A``, ``drift = −Uᵀ γ`` (``U``: left singular vectors of A for
    its non-zero singular values). Then ``a`` is unique and equal, the constraint force
    ``Aᵀ λ = J₃ᵀ λ₃`` is unique and equal, and since our λ is the minimum-norm one (it lies in the
    range of A, spanned by U), ``λ = U λ₃``, i.e. ``λ₃ = Uᵀ λ``.
    """
    robot, cs = _diff_drive_system()
    pmodel = pin.buildModelFromUrdf(mb.robots.path("diff_drive"))
    pdata = pmodel.createData()
    assert (pmodel.nq, pmodel.nv) == (robot.nq + 2, robot.nv)  # two continuous joints as (cos, sin)
    rng = np.random.default_rng(8)
    states = [(robot.neutral(), np.zeros(robot.nv))] + [
        (robot.random_configuration(rng), rng.standard_normal(robot.nv)) for _ in range(3)]
    for q, v in states:
        q, v = cs.project(q, v)
        tau = rng.standard_normal(robot.nv)
        solution = cs.solve(q, v, tau)
        assert solution.rank == 3 and cs.num_rows == 4
        U, sigma, _ = np.linalg.svd(solution.A)
        assert sigma[3] <= 1e-12 * sigma[0]
        U3 = U[:, :3]
        J3, drift3 = U3.T @ solution.A, -U3.T @ solution.gamma
        a_pin = pin.forwardDynamics(pmodel, pdata, q_to_pinocchio(robot, q), v, tau, J3, drift3).copy()
        lam3 = pdata.lambda_c.copy()
        assert relative_error(solution.a, a_pin) <= 1e-9
        force = solution.A.T @ solution.lam
        assert relative_error(force, J3.T @ lam3) <= 1e-9
        assert relative_error(U3.T @ solution.lam, lam3) <= 1e-9
        assert relative_error(solution.lam, U3 @ lam3) <= 1e-9  # minimum norm: no part outside range(A)


# ============================================================================= 5. differential drive

def test_diff_drive_straight_acceleration_closed_form():
    """Equal wheel torques τ: the robot accelerates straight ahead at

        u̇ = 2τ / (r (m_total + 2 I_w / r²))

    (power 2τ φ̇ = 2τ u/r into T = ½ m_total u² + 2 · ½ I_w (u/r)², the rolling constraint
    φ̇ = u / r for a wheel spinning about +y). From the URDF: m_total = 5 + 2·0.4 + 0.1 (the caster is
    fixed to the chassis) = 5.9 kg, I_w = 0.00128 kg m², r = 0.08 m: effective mass 6.3 kg."""
    robot, cs = _diff_drive_system()
    total_mass, wheel_inertia, r = diff_drive_numbers()
    assert total_mass == pytest.approx(robot.total_mass, rel=1e-12)
    assert total_mass + 2 * wheel_inertia / r**2 == pytest.approx(6.3, rel=1e-12)
    left = robot.idx_v[robot.joint_index("left_wheel_joint")]
    right = robot.idx_v[robot.joint_index("right_wheel_joint")]
    torque = 0.35
    tau = np.zeros(robot.nv)
    tau[[left, right]] = torque
    expected = 2 * torque / (r * (total_mass + 2 * wheel_inertia / r**2))
    for heading, u in [(0.0, 0.0), (0.7, 0.0), (-2.1, 1.3)]:
        q = robot.neutral()
        q[[0, 1]] = [0.4, -0.2]
        q[[2, 3]] = [np.cos(heading), np.sin(heading)]
        v = np.zeros(robot.nv)
        v[0], v[left], v[right] = u, u / r, u / r
        assert cs.residual(q, v) <= 1e-15
        solution = cs.solve(q, v, tau)
        assert solution.rank == 3 and len(solution.lam) == 4
        a = solution.a
        assert a[0] == pytest.approx(expected, rel=1e-12)      # forward (body x)
        assert abs(a[1]) <= 1e-12 and abs(a[2]) <= 1e-12        # no sideways motion, no turning
        assert a[left] == pytest.approx(expected / r, rel=1e-12) and a[right] == pytest.approx(expected / r, rel=1e-12)


# ============================================================================= 6. body forces

def _ball_on_incline():
    ball = free_ball()
    return ball, [mb.RollingSphere("ball", BALL_RADIUS, plane_normal=tilted_normal(0.3, 0.9))]


def _coin_tilted():
    model = coin()
    return model, [mb.RollingDisc("coin", 0.5, axis=(0.0, 0.0, 1.0), plane_normal=tilted_normal(0.1, 0.3))]


BODY_FORCE_CASES = {
    "ball-incline": _ball_on_incline,
    "sphere-turntable-centre-offset": _sphere_turntable_offset,
    "coin": _coin_tilted,
    "diff-drive": _disc_diff_drive,
    "sleigh": _knife_sleigh,
    "knife-edge-free-flyer": _knife_free_flyer,
}


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the differential drive's axle)
@pytest.mark.parametrize("case", sorted(BODY_FORCE_CASES))
def test_body_forces_reproduce_constraint_force(case):
    """Σ Jᵀ f of ``body_forces(q, λ)`` (through RNEA with and without f_ext) is Aᵀ λ, and RNEA with
    these forces returns the applied τ at the constrained accelerations."""
    model, constraints = BODY_FORCE_CASES[case]()
    cs = mb.ConstrainedSystem(model, constraints)
    rng = np.random.default_rng(sorted(BODY_FORCE_CASES).index(case) + 20)
    for _ in range(3):
        if isinstance(constraints[0], mb.RollingDisc) and model.joints[0].kind == "free-flyer":
            q, v = _random_disc_state(model, rng, constraints[0].normal)
        else:
            q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
        q, v = cs.project(_onto_plane(cs, q), v, 0.3)
        tau = rng.standard_normal(model.nv)
        a, lam = cs.forward_dynamics(q, v, tau, 0.3)
        f_ext = cs.body_forces(q, lam, 0.3)
        assert f_ext.shape == (model.njoints, 6)
        generalized = mb.inverse_dynamics(model, q, v, a) - mb.inverse_dynamics(model, q, v, a, f_ext=f_ext)
        force = cs.jacobian(q, 0.3).T @ lam
        scale = max(np.abs(force).max(), 1.0)
        assert relative_error(generalized, force, scale=scale) <= 1e-9
        assert relative_error(mb.inverse_dynamics(model, q, v, a, f_ext=f_ext), tau, scale=scale) <= 1e-9


# ============================================================================= 7. bad input

class _NotAModel:
    """A minimal mechanical system that is not a multibody Model (one particle on a line)."""

    nq = nv = 1

    def mass_matrix(self, q):
        return np.eye(1)

    def bias_forces(self, q, v):
        return np.zeros(1)

    def integrate(self, q, v, dt=1.0):
        return q + v * dt

    def neutral(self):
        return np.zeros(1)


@pytest.mark.parametrize("radius", [0.0, -0.1, float("nan")])
def test_rolling_radius_must_be_positive(radius):
    with pytest.raises(ValueError, match="radius must be positive"):
        mb.RollingSphere("ball", radius)
    with pytest.raises(ValueError, match="radius must be positive"):
        mb.RollingDisc("coin", radius)


@pytest.mark.parametrize("normal", [(0.0, 0.0, 0.0), (0.0, 0.0), (np.nan, 0.0, 1.0)])
def test_plane_normal_must_be_nonzero_vector(normal):
    with pytest.raises(ValueError, match="plane normal"):
        mb.RollingSphere("ball", 0.1, plane_normal=normal)
    with pytest.raises(ValueError, match="plane normal"):
        mb.RollingDisc("coin", 0.1, plane_normal=normal)
    with pytest.raises(ValueError, match="plane normal"):
        mb.KnifeEdge("sleigh", plane_normal=normal)


def test_disc_axis_must_be_nonzero():
    with pytest.raises(ValueError, match="axis"):
        mb.RollingDisc("coin", 0.1, axis=(0.0, 0.0, 0.0))


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), tuple(tilted_normal(0.4, 1.0))])
def test_disc_lying_flat_raises_clear_error(normal):
    """Axis along the plane normal: every rim point touches, the contact point is undefined."""
    model = coin(radius=0.3)
    n = np.asarray(normal) / np.linalg.norm(normal)
    contact = mb.RollingDisc("coin", 0.3, axis=(0.0, 0.0, 1.0), plane_normal=n, name="coin on table")
    cs = mb.ConstrainedSystem(model, [contact])
    # Orientation taking body z onto n.
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    R = np.eye(3) if np.linalg.norm(axis) < 1e-12 else mb.spatial.axis_angle_rotation(
        axis / np.linalg.norm(axis), np.arccos(n @ z))
    q = np.concatenate([[0.0, 0.0, 0.0], quat(R)])
    for call in (lambda: cs.forward_dynamics(q, np.zeros(6)), lambda: cs.jacobian(q),
                 lambda: contact.contact_point(model, q)):
        with pytest.raises(ValueError, match="coin on table.*lies flat.*contact point is undefined"):
            call()
    # Upside down is flat too.
    q_down = np.concatenate([[0.0, 0.0, 0.0], quat(R @ mb.spatial.axis_angle_rotation([1.0, 0.0, 0.0], np.pi))])
    with pytest.raises(ValueError, match="lies flat"):
        cs.residual(q_down, np.zeros(6))


def test_knife_edge_needs_a_model():
    system = _NotAModel()
    blade = mb.KnifeEdge("sleigh")
    with pytest.raises(TypeError, match="needs a multibody Model.*_NotAModel"):
        mb.ConstrainedSystem(system, [blade])
    with pytest.raises(TypeError, match="needs a multibody Model"):
        blade.jacobian(system, np.zeros(1))
    with pytest.raises(TypeError, match="needs a multibody Model"):
        blade.body_forces(system, np.zeros(1), np.zeros(1))
    with pytest.raises(TypeError, match="needs a multibody Model"):
        mb.ConstrainedSystem(system, [mb.RollingSphere("ball", 0.1)])


def test_knife_edge_refuses_a_zero_blade_direction():
    with pytest.raises(ValueError, match="blade direction"):
        mb.KnifeEdge("sleigh", direction=(0.0, 0.0, 0.0))


def test_readme_rolling_ball_says_what_the_projection_does_to_its_speed():
    """The README's rolling ball runs as written, and its comment's numbers are the projection's: a solid
    ball (I = 2/5 m r²) sliding at 1 m/s keeps its momentum about the contact point, ``m v = (m + I / r²) v'``,
    so it rolls at 5/7 m/s with the spin ``v' / r`` about y."""
    readme = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")
    with open(readme, encoding="utf-8") as f:
        block = next(b for b in re.findall(r"```python\n(.*?)```", f.read(), re.S) if "RollingSphere" in b)
    namespace = {"mb": mb, "np": np}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(compile(block, "README.md", "exec"), namespace)
    v0, trajectory = namespace["v0"], namespace["trajectory"]
    assert np.allclose(v0, [5 / 7, 0.0, 0.0, 0.0, 50 / 7, 0.0], rtol=0, atol=1e-12)
    # the comment's numbers are the projected state's, as printed
    assert f"{v0[0]:.3f} m/s" in block and f"{v0[4]:.2f} rad/s about y" in block
    assert trajectory.residual.max() <= 1e-9
