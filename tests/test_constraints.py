"""Holonomic constraints at one state: ``ConstrainedSystem.solve`` / ``forward_dynamics`` and the
built-in constraints, against closed forms, finite differences and Pinocchio.

Sign convention (docs/conventions.md): ``M a + h = τ + Aᵀ λ`` and ``A a = γ``.
Pinocchio's KKT (``pin.forwardDynamics(model, data, q, v, tau, J, drift)``) solves
``M a + h = τ + Jᵀ λ_pin`` with ``J a = −drift`` (``drift = J̇ v``), so where our rows equal ``J``:
``γ = −drift`` and ``λ = λ_pin`` (``data.lambda_c``). Both signs are asserted below, not assumed.

Tolerances: results that involve only closed forms and exact (analytic) derivatives are compared at
1e-9–1e-10 relative (a few hundred rounding errors of a 3–9 dof KKT solve); the ones that go through
numerical derivatives carry the stencil errors estimated next to each test.
"""

from __future__ import annotations

import os
import warnings
import zlib

import numpy as np
import pytest

import multibody as mb
from multibody.constrained import ModelSystem
from multibody.spatial import axis_angle_rotation, pose_from_xyz_rpy, pose_matrix

from conftest import erd_urdf, pinocchio_twin, q_to_pinocchio, random_placement, random_tree_model
from constraint_helpers import (
    GRAVITY,
    CurveCoordinateSystem,
    Helix,
    Parabola,
    assert_close,
    crank_state,
    fd_constraint_jacobian,
    fd_gamma,
    four_bar,
    null_space,
    parallelogram_chain,
    particle_model,
    pendulum_state,
    pendulum_tension,
    planar_closures,
)

PANDA = "panda_description/urdf/panda.urdf"


def kkt_residuals(cs, q, v, tau, a, lam, t=0.0):
    """``(M a + h − τ − Aᵀλ, A a − γ)`` of a solution."""
    system = cs.system
    A, gamma = cs.acceleration_level(q, v, t)
    tau = np.zeros(cs.nv) if tau is None else tau
    return system.mass_matrix(q) @ a + system.bias_forces(q, v) - tau - A.T @ lam, A @ a - gamma


# ============================================================================= 1. particle pendulum

M_PEND, L_PEND = 2.0, 1.5


@pytest.fixture(scope="module")
def pendulum():
    model = particle_model(M_PEND, names=["p"])
    return model, mb.ConstrainedSystem(model, [mb.Distance("p", None, L_PEND)])


def test_pendulum_tension_in_the_plane(pendulum):
    """λ = m g cos θ + m l θ̇² at random (θ, θ̇) in the x–z plane, θ over the whole circle."""
    _, cs = pendulum
    rng = np.random.default_rng(1)
    for theta, theta_dot in zip(rng.uniform(-np.pi, np.pi, 15), rng.uniform(-4.0, 4.0, 15)):
        q, v = pendulum_state(L_PEND, theta, theta_dot)
        a, lam = cs.forward_dynamics(q, v)
        expected = M_PEND * 9.81 * np.cos(theta) + M_PEND * L_PEND * theta_dot**2
        assert lam.shape == (1,)
        assert_close(lam[0], expected, 1e-8, scale=max(abs(expected), M_PEND * 9.81), what="tension")
        # Newton: m a = m g_vec − λ u (u = q / l points away from the pivot), so the tangential
        # acceleration is l θ̈ = −g sin θ and the radial one −l θ̇².
        u = q / L_PEND
        assert_close(a, GRAVITY - lam[0] * u / M_PEND, 1e-10, scale=9.81, what="acceleration")
        assert_close(a @ u, -L_PEND * theta_dot**2, 1e-10, scale=9.81, what="centripetal acceleration")


def test_pendulum_tension_spherical_states(pendulum):
    """Out of the plane too (spherical pendulum): λ = m g cos θ + m |v|²/l, and the KKT equations hold."""
    _, cs = pendulum
    rng = np.random.default_rng(2)
    for _ in range(10):
        theta, azimuth = rng.uniform(0.0, np.pi), rng.uniform(-np.pi, np.pi)
        q, _ = pendulum_state(L_PEND, theta, 0.0, azimuth)
        u = q / L_PEND
        v = rng.standard_normal(3) * 2.0
        v -= (v @ u) * u  # tangent to the sphere
        a, lam = cs.forward_dynamics(q, v)
        expected = pendulum_tension(M_PEND, L_PEND, q, v)
        assert_close(lam[0], expected, 1e-8, scale=max(abs(expected), M_PEND * 9.81), what="tension")
        dyn, acc = kkt_residuals(cs, q, v, None, a, lam)
        assert_close(dyn, np.zeros(3), 1e-12, scale=M_PEND * 9.81, what="M a + h − Aᵀλ")
        assert_close(acc, np.zeros(1), 1e-12, scale=9.81, what="A a − γ")


# ============================================================================= 2. bead on a wire (single states)

BEAD_MASS = 0.7


def bead_cases():
    helix, parabola = Helix(1.0, 0.3), Parabola(0.6, 0.4)
    return {
        # analytic r', r'' given to the constraint
        "helix-analytic": (helix, dict(derivative=helix.d1, second_derivative=helix.d2), (-12.0, 8.0), (-6.0, 3.0)),
        # r', r'' by the constraint's own five-point stencils
        "helix-numeric": (helix, {}, (-12.0, 8.0), (-6.0, 3.0)),
        "parabola-analytic": (parabola, dict(derivative=parabola.d1, second_derivative=parabola.d2), (-3.0, 3.0), (-1.5, 1.5)),
        "parabola-numeric": (parabola, {}, (-3.0, 3.0), (-1.5, 1.5)),
    }


@pytest.mark.parametrize("case", list(bead_cases()))
def test_bead_on_wire_cartesian_vs_minimal_states(case):
    """Cartesian bead (Translation particle + PointOnCurve) vs the seed's minimal coordinate s.

    At random (s, ṡ): the Cartesian accelerations equal ``r' s̈ + r'' ṡ²`` from the minimal
    equation, the 3 rows have rank 2, and the minimum-norm multipliers are the normal force
    ``N = m r̈ − m g_vec`` (world axes), orthogonal to the tangent.

    Tolerance 1e-9 relative to the force scale with analytic r', r''. With the numerical ones the
    constraint's second-derivative stencil (h = 2e-3) carries a rounding error near
    ``(64/12) ε |r| / h² ≈ 3e-10 |r|`` (|r| ≤ 7 here), hence 2e-8.
    """
    curve, kwargs, s_range, s_sample = bead_cases()[case]
    tol = 1e-9 if kwargs else 2e-8
    model = particle_model(BEAD_MASS, names=["bead"])
    cs = mb.ConstrainedSystem(model, [mb.PointOnCurve("bead", curve.r, s_range=s_range, samples=4001, **kwargs)])
    minimal = CurveCoordinateSystem(curve, BEAD_MASS)
    rng = np.random.default_rng(3)
    force_scale = BEAD_MASS * 9.81
    for s, s_dot in zip(rng.uniform(*s_sample, 8), rng.uniform(-3.0, 3.0, 8)):
        q, v = curve.r(s), curve.d1(s) * s_dot
        solution = cs.solve(q, v)
        assert solution.lam.shape == (3,) and solution.rank == 2
        assert cs.rank(q) == 2
        accel = minimal.cartesian_acceleration(s, s_dot)
        normal = minimal.normal_force(s, s_dot)
        scale = max(np.abs(normal).max(), force_scale)
        assert_close(solution.a, accel, tol, scale=scale / BEAD_MASS, what=f"{case}: acceleration")
        assert_close(solution.lam, normal, tol, scale=scale, what=f"{case}: normal force")
        tangent = curve.d1(s) / np.linalg.norm(curve.d1(s))
        assert abs(solution.lam @ tangent) <= tol * scale, "the wire exerts no tangential force"
        assert abs(normal @ tangent) <= 1e-12 * scale  # the reference is normal too


# ============================================================================= 5. Panda vs pin.forwardDynamics

@pytest.fixture(scope="module")
def panda(pin):
    path = erd_urdf(PANDA)
    model = mb.load_urdf(path)
    pmodel = pin.buildModelFromUrdf(path)
    fid = pmodel.getFrameId("panda_hand")
    return model, pmodel, pmodel.createData(), fid


def hand_pose(model, q):
    return mb.forward_kinematics(model, q)[model.body_index("panda_hand")]


def pin_point_kkt(pin, pmodel, pdata, fid, q_pin, v, tau):
    """Pinocchio's KKT with the hand origin held: ``J`` = its world-aligned linear Jacobian, drift = ``J̇v``."""
    zero = np.zeros(pmodel.nv)
    pin.forwardKinematics(pmodel, pdata, q_pin, v, zero)
    pin.computeJointJacobians(pmodel, pdata, q_pin)
    pin.updateFramePlacements(pmodel, pdata)
    J = pin.getFrameJacobian(pmodel, pdata, fid, pin.LOCAL_WORLD_ALIGNED)[:3].copy()
    drift = pin.getFrameClassicalAcceleration(pmodel, pdata, fid, pin.LOCAL_WORLD_ALIGNED).linear.copy()
    a = pin.forwardDynamics(pmodel, pdata, q_pin, v, tau, J, drift).copy()
    return a, pdata.lambda_c.copy(), J, drift


def panda_states(model, n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield model.random_configuration(rng), rng.standard_normal(model.nv), 5.0 * rng.standard_normal(model.nv)


def test_pinocchio_kkt_sign_convention(pin, panda):
    """What we rely on about pin.forwardDynamics: M a + h = τ + Jᵀ λ_pin and J a = −drift."""
    model, pmodel, pdata, fid = panda
    for q, v, tau in panda_states(model, 3, 10):
        q_pin = q_to_pinocchio(model, q)
        a, lam, J, drift = pin_point_kkt(pin, pmodel, pdata, fid, q_pin, v, tau)
        M = pin.crba(pmodel, pdata, q_pin)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(pmodel, pdata, q_pin, v)
        assert_close(M @ a + h, tau + J.T @ lam, 1e-10, what="Pinocchio dynamics with +Jᵀλ")
        assert_close(J @ a, -drift, 1e-10, scale=max(1.0, np.abs(drift).max()), what="J a = −drift")
        # and the drift is our J̇v (a = 0 classical acceleration of the hand origin)
        ours = mb.point_acceleration(model, q, v, np.zeros(model.nv), "panda_hand")[:3]
        assert_close(ours, drift, 1e-10, scale=max(1.0, np.abs(drift).max()), what="J̇v")


@pytest.mark.parametrize("formulation", ["holonomic-analytic", "loop-world-to-hand"])
def test_panda_point_constraint_matches_pinocchio_kkt(pin, panda, formulation):
    """Rows identical to Pinocchio's J (world-aligned linear Jacobian of the hand origin), so ``a`` and
    ``λ`` compare directly, at arbitrary (inconsistent) velocities, to 1e-9 relative.

    * ``Holonomic(φ = p_hand(q) − p0)`` with ``jacobian = mb.jacobian[:3]`` and
      ``γ = −(J̇v)`` from ``mb.point_acceleration(..., a=0)``;
    * ``LoopClosure(None, "panda_hand", frame_a=<world-axes frame at p0>)``: frame A is fixed in the
      world with world axes, so its rows ``R_Aᵀ (J_B − 0) = J`` and ``γ = −J̇v``.
    """
    model, pmodel, pdata, fid = panda
    nv = model.nv
    for q, v, tau in panda_states(model, 4, 11):
        p0 = hand_pose(model, q)[:3, 3]
        if formulation == "holonomic-analytic":
            constraint = mb.Holonomic(
                lambda qq, t: hand_pose(model, qq)[:3, 3] - p0,
                jacobian=lambda qq, t: mb.jacobian(model, qq, "panda_hand")[:3],
                gamma=lambda qq, vv, t: -mb.point_acceleration(model, qq, vv, np.zeros(nv), "panda_hand")[:3])
        else:
            constraint = mb.LoopClosure(None, "panda_hand", frame_a=pose_from_xyz_rpy(p0), kind="point")
        cs = mb.ConstrainedSystem(model, [constraint])
        a, lam = cs.forward_dynamics(q, v, tau)
        a_pin, lam_pin, J, drift = pin_point_kkt(pin, pmodel, pdata, fid, q_to_pinocchio(model, q), v, tau)
        assert_close(cs.jacobian(q), J, 1e-12, scale=1.0, what="rows = Pinocchio's J")
        assert_close(cs.acceleration_rhs(q, v), -drift, 1e-10, scale=max(1.0, np.abs(drift).max()), what="γ = −drift")
        assert_close(a, a_pin, 1e-9, scale=max(1.0, np.abs(a_pin).max()), what=f"{formulation}: a")
        assert_close(lam, lam_pin, 1e-9, scale=max(1.0, np.abs(lam_pin).max()), what=f"{formulation}: λ")


def test_panda_loop_closure_in_hand_frame_matches_pinocchio(pin, panda):
    """``LoopClosure("panda_hand", None, frame_b=<hand pose at q>)``: frame A is the hand, B the world.

    Rows: ``r = R_Aᵀ (p_B − p_A)``, so at the closed configuration ``A = R_handᵀ (0 − J) = −R_handᵀ J``.
    Then ``Aᵀ λ = −Jᵀ R_hand λ``: with J of full row rank, ``λ_pin = −R_hand λ`` and the generalized
    constraint forces ``Aᵀ λ = Jᵀ λ_pin`` agree (and are frame-independent).

    The acceleration levels agree only on the velocity manifold: ``r`` is measured in the rotating
    hand frame, so ``r̈`` carries a Coriolis term ``2 ω × ṗ`` that vanishes when ``J v = 0``.
    Consistent velocities: compare ``a``, ``Aᵀλ`` and ``λ`` (1e-9). Inconsistent ones: our
    accelerations must satisfy exactly ``J a = −J̇v + 2 ω × ṗ_hand`` instead of Pinocchio's ``J a = −J̇v``.
    """
    model, pmodel, pdata, fid = panda
    rng = np.random.default_rng(12)
    for q, v_random, tau in panda_states(model, 4, 13):
        T = hand_pose(model, q)
        R = T[:3, :3]
        cs = mb.ConstrainedSystem(model, [mb.LoopClosure("panda_hand", None, frame_b=T, kind="point")])
        q_pin = q_to_pinocchio(model, q)
        J = mb.jacobian(model, q, "panda_hand")
        assert_close(cs.jacobian(q), -R.T @ J[:3], 1e-12, scale=1.0, what="A = −R_handᵀ J")
        assert_close(cs.position_error(q), np.zeros(3), 1e-14, scale=1.0, what="closed at q")
        # consistent velocity: J v = 0
        v = null_space(J[:3]) @ rng.standard_normal(model.nv - 3)
        a, lam = cs.forward_dynamics(q, v, tau)
        a_pin, lam_pin, J_pin, _ = pin_point_kkt(pin, pmodel, pdata, fid, q_pin, v, tau)
        scale_a, scale_f = max(1.0, np.abs(a_pin).max()), max(1.0, np.abs(lam_pin).max())
        assert_close(a, a_pin, 1e-9, scale=scale_a, what="a (consistent v)")
        assert_close(cs.jacobian(q).T @ lam, J_pin.T @ lam_pin, 1e-9, scale=scale_f, what="Aᵀλ")
        assert_close(-R @ lam, lam_pin, 1e-9, scale=scale_f, what="λ_pin = −R_hand λ")
        # inconsistent velocity: the documented rotating-frame acceleration level
        a, _ = cs.forward_dynamics(q, v_random, tau)
        twist = J @ v_random
        drift = mb.point_acceleration(model, q, v_random, np.zeros(model.nv), "panda_hand")[:3]
        expected = -drift + 2.0 * np.cross(twist[3:], twist[:3])
        assert_close(J[:3] @ a, expected, 1e-9, scale=max(1.0, np.abs(expected).max()), what="J a (inconsistent v)")


def test_panda_holonomic_numerical_derivatives_match_pinocchio(pin, panda):
    """``Holonomic(φ)`` alone: A by five-point differences (h = 1e-3) of φ along ``q ⊕ ε e_k`` and γ as
    minus the five-point second derivative (h = 2e-3) of φ along ``q ⊕ v s``.

    Error budget: the Jacobian's truncation ``h⁴ |φ⁽⁵⁾| / 30 ≈ 3e-14 · O(1)`` and rounding
    ``1.5 ε |φ| / h ≈ 3e-13``; γ's rounding ``(64/12) ε |φ| / h² ≈ 3e-10 |φ|`` (|φ| ≲ 1 m) and
    truncation ``h⁴ |φ⁽⁶⁾| / 90 ≈ 2e-13 |v|⁶`` (|v| ≈ 3 here: ≈ 1e-10). The Delassus solve amplifies
    these by at most ~100 for these arm configurations, so ~1e-8 relative is expected: 1e-7 is asserted.
    """
    model, pmodel, pdata, fid = panda
    for q, v, tau in panda_states(model, 3, 14):
        p0 = hand_pose(model, q)[:3, 3]
        cs = mb.ConstrainedSystem(model, [mb.Holonomic(lambda qq, t: hand_pose(model, qq)[:3, 3] - p0)])
        a, lam = cs.forward_dynamics(q, v, tau)
        a_pin, lam_pin, J, _ = pin_point_kkt(pin, pmodel, pdata, fid, q_to_pinocchio(model, q), v, tau)
        assert_close(cs.jacobian(q), J, 1e-9, scale=1.0, what="numerical A")
        assert_close(a, a_pin, 1e-7, scale=max(1.0, np.abs(a_pin).max()), what="a (numerical derivatives)")
        assert_close(lam, lam_pin, 1e-7, scale=max(1.0, np.abs(lam_pin).max()), what="λ (numerical derivatives)")


# ============================================================================= 6. pin.constraintDynamics

def pin_constraint_dynamics(pin, pmodel, constraint_model, q, v, tau, mu=1e-8):
    """``pin.constraintDynamics`` with one ``RigidConstraintModel``: ``(a, λ = data.lambda_c, J)``.

    A proximal parameter ``mu > 0`` is needed with redundant rows (mu = 0 factorizes the singular
    Delassus matrix and returns NaN); the proximal iterations started at λ = 0 converge to the
    minimum-norm multipliers.
    """
    pdata = pmodel.createData()
    cdata = constraint_model.createData()
    pin.initConstraintDynamics(pmodel, pdata, [constraint_model], [cdata])
    settings = pin.ProximalSettings(1e-14, mu, 100)
    a = pin.constraintDynamics(pmodel, pdata, q, v, tau, [constraint_model], [cdata], settings).copy()
    assert settings.iter < 100, "Pinocchio's proximal solver did not converge"
    J = pin.getConstraintJacobian(pmodel, pdata, constraint_model, cdata).copy()
    return a, pdata.lambda_c.copy(), J


def four_bar_states(cs, n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        guess = np.array([-1.2, 1.0, 1.5]) + 0.2 * rng.standard_normal(3)
        q, v = cs.project(guess, 2.0 * rng.standard_normal(3))
        yield q, v, rng.standard_normal(3)


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the redundant y row, below)
def test_four_bar_matches_pinocchio_constraint_dynamics(pin):
    """Closed four-bar: Pinocchio's CONTACT_3D between the tip of link3 (joint 3, placement ``tip``)
    and the world point (joint 0, placement ``pivot``), LOCAL_WORLD_ALIGNED.

    Pinocchio's rows are ``J_1 − J_2`` (world axes) of the two anchor points, with
    ``M a + h = τ + Jᵀ λ``; ours, ``LoopClosure(None, "link3", frame_a=<pivot, world axes>,
    frame_b=tip)``, are ``R_Aᵀ (J_B − J_A) = J_tip`` with ``R_A = I``: the same rows, so ``a`` and ``λ``
    (the force on link3's tip, world axes) compare directly. The y row is redundant for this planar
    mechanism: both give it a zero multiplier (minimum norm).
    """
    model, tip, pivot = four_bar()
    pmodel, _ = pinocchio_twin(pin, model)
    cs = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=pose_from_xyz_rpy(pivot), frame_b=tip)])
    cm = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, pmodel, 3, pin.SE3(tip[:3, :3], tip[:3, 3]),
                                  0, pin.SE3(np.eye(3), pivot), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    for q, v, tau in four_bar_states(cs, 4, 20):
        assert cs.residual(q, v) < 1e-12
        solution = cs.solve(q, v, tau)
        a_pin, lam_pin, J_pin = pin_constraint_dynamics(pin, pmodel, cm, q, v, tau)
        assert_close(cs.jacobian(q), J_pin, 1e-12, scale=1.0, what="rows")
        assert_close(solution.a, a_pin, 1e-9, scale=max(1.0, np.abs(a_pin).max()), what="four-bar a")
        assert_close(solution.lam, lam_pin, 1e-9, scale=max(1.0, np.abs(lam_pin).max()), what="four-bar λ")
        assert solution.rank == 2 and abs(solution.lam[1]) <= 1e-12 * np.abs(solution.lam).max()


@pytest.mark.parametrize("case", ["point-local", "point-world-aligned", "weld-local"])
def test_panda_hand_anchored_matches_pinocchio_constraint_dynamics(pin, panda, case):
    """Panda hand anchored to its current world pose ``T``: our ``LoopClosure(None, "panda_hand",
    frame_a=T, kind=...)`` (frame A fixed in the world, with the hand's axes at q) vs Pinocchio's
    ``RigidConstraintModel`` between the hand frame (joint 7, placement of the ``panda_hand`` frame)
    and the world (joint 0, placement ``T``).

    Row maps (our rows ``A``, Pinocchio's ``J_pin`` from ``getConstraintJacobian``):

    * CONTACT_3D, LOCAL: rows in the hand (= frame A) axes: ``J_pin = A``, ``λ_pin = λ``;
    * CONTACT_3D, LOCAL_WORLD_ALIGNED: world axes: ``J_pin = R_T A``, ``λ_pin = R_T λ``;
    * CONTACT_6D, LOCAL vs kind="weld": the position rows coincide; our orientation rows are
      ``(e_i^A × f_j^B)·(ω_A − ω_B)`` for (i, j) = (y, z), (z, x), (x, y) — at aligned frames
      ``e_k^A · (0 − ω_B) = −ω_local,k`` — while Pinocchio's are ``+ω_local``: ``J_pin = D A`` and
      ``λ_pin = D λ`` with ``D = diag(1, 1, 1, −1, −1, −1)``.

    Velocities on the constraint manifold (the hand at rest), where classical and spatial
    accelerations, and fixed and moving frames, give the same acceleration level.
    """
    model, pmodel, _, fid = panda
    frame = pmodel.frames[fid]
    rng = np.random.default_rng(21)
    kind = "weld" if case.startswith("weld") else "point"
    for q, _, tau in panda_states(model, 3, 22):
        T = hand_pose(model, q)
        J6 = mb.jacobian(model, q, "panda_hand")
        rows = 6 if kind == "weld" else 3
        v = null_space(J6[:rows]) @ rng.standard_normal(model.nv - rows)
        cs = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "panda_hand", frame_a=T, kind=kind)])
        if case == "point-local":
            contact, reference, D = pin.ContactType.CONTACT_3D, pin.ReferenceFrame.LOCAL, np.eye(3)
        elif case == "point-world-aligned":
            contact, reference, D = pin.ContactType.CONTACT_3D, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED, T[:3, :3]
        else:
            contact, reference, D = pin.ContactType.CONTACT_6D, pin.ReferenceFrame.LOCAL, np.diag([1, 1, 1, -1, -1, -1.0])
        cm = pin.RigidConstraintModel(contact, pmodel, frame.parentJoint, frame.placement, 0,
                                      pin.SE3(T[:3, :3], T[:3, 3]), reference)
        solution = cs.solve(q, v, tau)
        a_pin, lam_pin, J_pin = pin_constraint_dynamics(pin, pmodel, cm, q_to_pinocchio(model, q), v, tau, mu=0.0)
        assert_close(D @ solution.A, J_pin, 1e-12, scale=1.0, what=f"{case}: rows")
        assert_close(solution.a, a_pin, 1e-9, scale=max(1.0, np.abs(a_pin).max()), what=f"{case}: a")
        assert_close(D @ solution.lam, lam_pin, 1e-9, scale=max(1.0, np.abs(lam_pin).max()), what=f"{case}: λ")
        assert_close(solution.A.T @ solution.lam, J_pin.T @ lam_pin, 1e-9,
                     scale=max(1.0, np.abs(lam_pin).max()), what=f"{case}: Aᵀλ")


# ============================================================================= 7. redundant rows

def test_four_bar_redundant_point_closure_is_minimum_norm():
    """3-D point closure of a planar four-bar: 3 rows, rank 2. The minimum-norm multipliers are the
    unique λ with ``M a + h = τ + Aᵀλ``, ``A a = γ`` and ``λ ⟂ null(Aᵀ)``; with frame A rotated by a
    random angle the redundant direction is not a single row, which the orthogonality check covers."""
    model, tip, pivot = four_bar()
    rng = np.random.default_rng(30)
    axis = rng.standard_normal(3)
    frames = {"world axes": pose_from_xyz_rpy(pivot),
              "rotated": pose_matrix(axis_angle_rotation(axis / np.linalg.norm(axis), 1.1), pivot)}
    for label, frame_a in frames.items():
        cs = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=frame_a, frame_b=tip, kind="point")])
        assert cs.num_rows == 3
        with pytest.warns(mb.RankDeficientWarning, match="rank 2 of 3 rows: 'point loop closure None-link3' has rank 2 "
                                                         "of its 3 rows"):
            states = list(four_bar_states(cs, 3, 31))
        for q, v, tau in states:
            solution = cs.solve(q, v, tau)
            assert solution.rank == 2 and cs.rank(q) == 2, label
            dyn, acc = kkt_residuals(cs, q, v, tau, solution.a, solution.lam)
            scale = max(1.0, np.abs(solution.lam).max())
            assert_close(dyn, np.zeros(3), 1e-10, scale=scale, what=f"{label}: dynamics")
            assert_close(acc, np.zeros(3), 1e-10, scale=max(1.0, np.abs(solution.gamma).max()), what=f"{label}: A a = γ")
            n = null_space(solution.A.T, rtol=1e-8)
            assert n.shape == (3, 1)
            assert abs(n[:, 0] @ solution.lam) <= 1e-10 * scale, f"{label}: λ has a component in null(Aᵀ)"
            if label == "world axes":
                # the redundant row is the world-y one, and its multiplier is 0
                assert np.abs(solution.A[1]).max() <= 1e-14
                assert abs(solution.lam[1]) <= 1e-12 * scale


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the point closure's redundant row)
def test_four_bar_point_and_planar_closures_agree():
    """kind="planar" keeps the x and y axes of frame A: with frame A rotated by +90° about x its
    x–y plane is the mechanism plane x–z (A's y axis is the world z). Same accelerations; its two
    multipliers are the x and z components of the point closure's (world axes) force."""
    model, tip, pivot = four_bar()
    point = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=pose_from_xyz_rpy(pivot), frame_b=tip)])
    frame_planar = pose_from_xyz_rpy(pivot, [np.pi / 2, 0.0, 0.0])
    assert_close(frame_planar[:3, 1], [0.0, 0.0, 1.0], 1e-15, scale=1.0, what="A's y axis is world z")
    planar = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=frame_planar, frame_b=tip, kind="planar")])
    assert planar.num_rows == 2
    for q, v, tau in four_bar_states(point, 4, 32):
        s_point, s_planar = point.solve(q, v, tau), planar.solve(q, v, tau)
        assert s_planar.rank == 2
        assert_close(s_point.a, s_planar.a, 1e-10, scale=max(1.0, np.abs(s_planar.a).max()), what="a")
        scale = max(1.0, np.abs(s_planar.lam).max())
        assert_close(s_point.lam[[0, 2]], s_planar.lam, 1e-10, scale=scale, what="λ")
        assert_close(s_point.A.T @ s_point.lam, s_planar.A.T @ s_planar.lam, 1e-10, scale=scale, what="Aᵀλ")


# ============================================================================= 8. inconsistent constraints

def test_inconsistent_distances_raise_constraint_error():
    """A particle between two world points 10 m apart, tied to both by 1 m rods.

    On the line between the points the two rows are parallel (rank 1) and, with a velocity across the
    line, their γ's contradict: the KKT solve raises. Off the line the rows are independent but the
    positions cannot be met: projecting (as simulate does first) raises.
    """
    model = particle_model(1.0, names=["p"])
    cs = mb.ConstrainedSystem(model, [mb.Distance("p", None, 1.0, point_b=[-5.0, 0, 0], name="left rod"),
                                      mb.Distance("p", None, 1.0, point_b=[5.0, 0, 0], name="right rod")])
    with pytest.raises(mb.ConstraintError, match=r"inconsistent constraints.*rank 1.*rod\[0\]' is off by"):
        cs.forward_dynamics(np.zeros(3), np.array([0.0, 1.0, 0.5]))
    with pytest.raises(mb.ConstraintError, match="did not converge"):
        cs.project(np.array([0.0, 0.3, -0.2]), np.zeros(3))
    with pytest.raises(mb.ConstraintError, match="did not converge"):
        mb.simulate(cs, np.array([0.0, 0.3, -0.2]), np.zeros(3), 0.1)


def test_contradictory_couplings_raise_constraint_error():
    """The elbow geared to the shoulder twice: ``q_e = q_s`` (JointCoupling) and ``q_e = q_s + t²``
    (a rheonomic Holonomic): identical rows, ``γ = 0`` vs ``γ = 2``: no acceleration satisfies both."""
    model = mb.robots.load("double_pendulum")
    coupling = mb.JointCoupling("shoulder", "elbow", 1.0, 0.0)
    moving = mb.Holonomic(lambda q, t: np.array([q[1] - q[0] - t**2]),
                          jacobian=lambda q, t: np.array([[-1.0, 1.0]]), name="moving gear")
    cs = mb.ConstrainedSystem(model, [coupling, moving])
    with pytest.raises(mb.ConstraintError, match="inconsistent constraints"):
        cs.forward_dynamics(np.array([0.3, 0.3]), np.array([0.1, 0.1]))
    # Two equal couplings are merely redundant: rank 1, the multiplier shared equally (minimum norm).
    twice = mb.ConstrainedSystem(model, [coupling, mb.JointCoupling("shoulder", "elbow", 1.0, 0.0, name="again")])
    solution = twice.solve(np.array([0.3, 0.3]), np.array([0.1, 0.1]))
    assert solution.rank == 1
    assert_close(solution.lam[0], solution.lam[1], 1e-12, scale=np.abs(solution.lam).max(), what="shared λ")
    assert_close(solution.a[0], solution.a[1], 1e-12, scale=1.0, what="coupled a")
    # Same ratio, different offsets: consistent at acceleration level, impossible in position.
    offset = mb.ConstrainedSystem(model, [coupling, mb.JointCoupling("shoulder", "elbow", 1.0, 0.5, name="offset")])
    with pytest.raises(mb.ConstraintError, match="did not converge"):
        offset.project(np.array([0.3, 0.3]), np.zeros(2))


# ============================================================================= 9. rheonomic constraint

OMEGA, M_BEAD_ROT = 1.3, 0.5


def rotating_wire_constraints():
    """A horizontal wire through the origin rotating about z at ω: ``φ = [x sin ωt − y cos ωt, z]``."""
    w = OMEGA

    def phi(q, t):
        return np.array([q[0] * np.sin(w * t) - q[1] * np.cos(w * t), q[2]])

    def jacobian(q, t):
        return np.array([[np.sin(w * t), -np.cos(w * t), 0.0], [0.0, 0.0, 1.0]])

    def dphi_dt(q, t):
        return np.array([w * (q[0] * np.cos(w * t) + q[1] * np.sin(w * t)), 0.0])

    def gamma(q, v, t):
        # γ = −(J̇v + 2 ∂J/∂t v + ∂²φ/∂t²) with J̇ = 0 (J does not depend on q)
        c, s = np.cos(w * t), np.sin(w * t)
        return -np.array([2.0 * w * (v[0] * c + v[1] * s) + w * w * (q[1] * c - q[0] * s), 0.0])

    numeric = mb.Holonomic(phi, name="rotating wire (numeric)")
    analytic = mb.Holonomic(phi, jacobian=jacobian, dphi_dt=dphi_dt, gamma=gamma, name="rotating wire")
    return numeric, analytic


def test_rotating_wire_numeric_vs_analytic_derivatives():
    """Numerical (five-point stencils) vs analytic derivatives at random states and times.

    Stencil errors: A and b ≈ ε|φ|/h ≈ 1e-12; γ (second difference, h = 2e-3) ≈ 5 ε |φ| / h² ≈ 3e-10
    for |φ| ≈ 1, hence 1e-8 relative for γ, a and λ.
    """
    model = particle_model(M_BEAD_ROT, names=["bead"])
    numeric, analytic = rotating_wire_constraints()
    cs_num, cs_ana = mb.ConstrainedSystem(model, [numeric]), mb.ConstrainedSystem(model, [analytic])
    rng = np.random.default_rng(40)
    for _ in range(6):
        q, v, t = rng.standard_normal(3), rng.standard_normal(3), rng.uniform(0.0, 5.0)
        assert_close(cs_num.jacobian(q, t), cs_ana.jacobian(q, t), 1e-10, scale=1.0, what="A")
        assert_close(cs_num.velocity_bias(q, t), cs_ana.velocity_bias(q, t), 1e-10, scale=1.0, what="b = ∂φ/∂t")
        assert_close(cs_num.acceleration_rhs(q, v, t), cs_ana.acceleration_rhs(q, v, t), 1e-8, scale=1.0, what="γ")
        # The analytic γ itself is −d/ds [A v + b] along (q + v s, t + s): checks the callback.
        assert_close(fd_gamma(analytic, cs_ana.system, model, q, v, t), cs_ana.acceleration_rhs(q, v, t), 1e-9,
                     scale=1.0, what="analytic γ by finite differences")
        (a_n, l_n), (a_a, l_a) = cs_num.forward_dynamics(q, v, t=t), cs_ana.forward_dynamics(q, v, t=t)
        assert_close(a_n, a_a, 1e-8, scale=max(1.0, np.abs(a_a).max()), what="a")
        assert_close(l_n, l_a, 1e-8, scale=max(1.0, np.abs(l_a).max()), what="λ")


def test_rotating_wire_closed_form_forces():
    """On the wire, at ``x = r u(t)``, ``ẋ = ṙ u + r ω u⊥``: no force along the wire, so ``r̈ = ω² r`` and
    the Cartesian acceleration is ``2 ṙ ω u⊥`` (Coriolis). Row 1 is ``n = (sin ωt, −cos ωt, 0) = −u⊥``:
    ``λ₁ = −2 m ω ṙ``; row 2 (z) carries the weight, ``λ₂ = m g``."""
    model = particle_model(M_BEAD_ROT, names=["bead"])
    numeric, analytic = rotating_wire_constraints()
    # numerical γ: stencil error ≈ 3e-10 (see the test above), hence 1e-8
    for constraint, tol in ((analytic, 1e-10), (numeric, 1e-8)):
        cs = mb.ConstrainedSystem(model, [constraint])
        rng = np.random.default_rng(41)
        for r, r_dot, t in zip(rng.uniform(-2, 2, 5), rng.uniform(-2, 2, 5), rng.uniform(0, 4, 5)):
            u = np.array([np.cos(OMEGA * t), np.sin(OMEGA * t), 0.0])
            u_perp = np.array([-np.sin(OMEGA * t), np.cos(OMEGA * t), 0.0])
            q, v = r * u, r_dot * u + r * OMEGA * u_perp
            assert cs.residual(q, v, t) < 1e-9
            a, lam = cs.forward_dynamics(q, v, t=t)
            assert_close(a, 2.0 * r_dot * OMEGA * u_perp, tol, scale=max(1.0, abs(2 * r_dot * OMEGA)), what="a")
            assert_close(lam, [-2.0 * M_BEAD_ROT * OMEGA * r_dot, M_BEAD_ROT * 9.81], tol, scale=M_BEAD_ROT * 9.81, what="λ")


# ============================================================================= 11. built-ins: generic derivative checks

@pytest.fixture(scope="module")
def tree():
    return random_tree_model(0)


def _curve_through(x, rng):
    """A circle of radius 0.7 through ``x`` (at s = 0), in a random plane."""
    n1 = rng.standard_normal(3)
    n1 /= np.linalg.norm(n1)
    n2 = np.cross(n1, rng.standard_normal(3))
    n2 /= np.linalg.norm(n2)
    center = x - 0.7 * n1
    return lambda s: center + 0.7 * (np.cos(np.asarray(s, float)[..., None]) * n1 + np.sin(np.asarray(s, float)[..., None]) * n2)


def _normal(kind):
    """The plane of a planar closure on the random tree, whose loops are not planar: frame A's x–y plane."""
    return (0.0, 0.0, 1.0) if kind == "planar" else None


def builtin_cases():
    """name -> f(model, q, rng) -> constraint; every built-in class, every LoopClosure kind, bodies and
    the world on either side, points off the body origins."""
    cases = {}
    for kind in mb.LoopClosure.KINDS:
        cases[f"loop-{kind}-bodies"] = lambda m, q, rng, k=kind: mb.LoopClosure(
            "spherical_4", "extra_2", frame_a=random_placement(rng), frame_b=random_placement(rng), kind=k,
            normal=_normal(k))
        cases[f"loop-{kind}-world-a"] = lambda m, q, rng, k=kind: mb.LoopClosure(
            None, "extra_3", frame_a=random_placement(rng), frame_b=random_placement(rng), kind=k, normal=_normal(k))
        cases[f"loop-{kind}-world-b"] = lambda m, q, rng, k=kind: mb.LoopClosure(
            "planar_3", None, frame_a=random_placement(rng), frame_b=random_placement(rng), kind=k, normal=_normal(k))
    cases["distance-bodies"] = lambda m, q, rng: mb.Distance(
        "extra_1", "translation_5", 0.7, point_a=0.3 * rng.standard_normal(3), point_b=0.3 * rng.standard_normal(3))
    cases["distance-world"] = lambda m, q, rng: mb.Distance("fixed_tip", None, 0.7, point_a=0.3 * rng.standard_normal(3),
                                                            point_b=rng.standard_normal(3))
    cases["joint-coupling"] = lambda m, q, rng: mb.JointCoupling("revolute_0_joint", "prismatic_2_joint", -1.7, 0.3)

    def surface(m, q, rng):
        center = rng.standard_normal(3)
        return mb.PointOnSurface("extra_4", lambda x: np.sum((x - center) ** 2, axis=-1) - 0.5, point=[0.1, 0.2, 0.3])
    cases["point-on-surface"] = surface

    def curve(m, q, rng):
        x = mb.forward_kinematics(m, q)[m.body_index("extra_4")] @ np.array([0.1, 0.2, 0.3, 1.0])
        return mb.PointOnCurve("extra_4", _curve_through(x[:3], rng), point=[0.1, 0.2, 0.3], s_range=(-2, 2), samples=401)
    cases["point-on-curve"] = curve
    return cases


@pytest.mark.parametrize("case", list(builtin_cases()))
def test_builtin_constraint_derivatives_by_finite_differences(tree, case):
    """For a random state of the random tree (free-flyer, spherical, planar, translation, revolute,
    prismatic joints): ``A == d/dε φ(q ⊕ ε e_k)`` and ``γ == −d/ds [A(q ⊕ v s) v + b]`` at s = 0.

    Fourth-order central differences with h = 1e-3: truncation ``h⁴ |f⁽⁵⁾| / 30`` (≈ 1e-11 for these
    O(1) lever arms and |v| ≈ 2.5) plus rounding ``1.5 ε |f| / h`` (≈ 1e-12), so 1e-6 relative (to
    max(1, |reference|)) has a wide margin; the observed errors are ~1e-12.

    The PointOnCurve rows ``P(s*) J`` are the derivative of ``φ = P(s*)(x − r(s*))`` only on the curve,
    and its γ keeps only the normal part of ``−d/dt (A v)`` (the tangential part vanishes on the
    velocity manifold), so for it q lies on the curve and v on the velocity manifold; every other
    constraint is checked at a state that satisfies nothing.
    """
    model = tree
    system = ModelSystem(model)
    rng = np.random.default_rng(zlib.crc32(case.encode()))
    q = model.random_configuration(rng)
    v = 0.5 * rng.standard_normal(model.nv)
    constraint = builtin_cases()[case](model, q, rng)
    m = constraint.rows(system)
    A, b, gamma = constraint.evaluate(system, q, v)
    if case == "point-on-curve":
        assert_close(constraint.position(system, q), np.zeros(3), 1e-12, scale=1.0, what="on the curve")
        v = v - np.linalg.pinv(A) @ (A @ v)
        A, b, gamma = constraint.evaluate(system, q, v)
    assert A.shape == (m, model.nv) and b.shape == (m,) and gamma.shape == (m,)
    # evaluate() shares one kinematics pass; it must equal the separate methods
    assert_close(constraint.jacobian(system, q), A, 1e-13, scale=1.0, what=f"{case}: jacobian vs evaluate")
    assert_close(constraint.acceleration_rhs(system, q, v), gamma, 1e-13, scale=1.0, what=f"{case}: γ vs evaluate")
    assert_close(b, np.zeros(m), 0.0, scale=1.0, what=f"{case}: scleronomic b")
    A_fd = fd_constraint_jacobian(constraint, system, model, q)
    assert_close(A, A_fd, 1e-6, scale=max(1.0, np.abs(A_fd).max()), what=f"{case}: A vs dφ/dε")
    gamma_fd = fd_gamma(constraint, system, model, q, v)
    assert_close(gamma, gamma_fd, 1e-6, scale=max(1.0, np.abs(gamma_fd).max()), what=f"{case}: γ vs −d(Av)/ds")


def test_rheonomic_holonomic_derivatives_by_finite_differences(tree):
    """The user class with numerical derivatives on the random tree, time-dependent:
    ``φ = p_body(q) − c(t)``. Checks A, ``b = ∂φ/∂t`` and γ = −d/ds[A v + b] along (q ⊕ v s, t + s).
    The constraint's own stencils (γ: second difference with h = 2e-3, rounding ≈ 5 ε|φ|/h² ≈ 3e-10|φ|)
    bound the agreement: 1e-7."""
    model = tree
    system = ModelSystem(model)
    body = model.body_index("extra_5")

    def phi(q, t):
        target = np.array([np.cos(2.0 * t), np.sin(3.0 * t), 0.5 * t**2])
        return mb.forward_kinematics(model, q)[body][:3, 3] - target

    constraint = mb.Holonomic(phi)
    rng = np.random.default_rng(42)
    q, v, t = model.random_configuration(rng), 0.5 * rng.standard_normal(model.nv), 0.7
    A = constraint.jacobian(system, q, t)
    assert_close(A, mb.jacobian(model, q, body)[:3], 1e-9, scale=1.0, what="A = J")
    assert_close(constraint.velocity_bias(system, q, t), -np.array([-2 * np.sin(1.4), 3 * np.cos(2.1), 0.7]),
                 1e-9, scale=1.0, what="b = ∂φ/∂t")
    gamma = constraint.acceleration_rhs(system, q, v, t)
    expected = -(mb.point_acceleration(model, q, v, np.zeros(model.nv), body)[:3]
                 - np.array([-4 * np.cos(1.4), -9 * np.sin(2.1), 1.0]))
    assert_close(gamma, expected, 1e-7, scale=max(1.0, np.abs(expected).max()), what="γ closed form")
    assert_close(gamma, fd_gamma(constraint, system, model, q, v, t), 1e-7, scale=max(1.0, np.abs(expected).max()),
                 what="γ by finite differences")


# ============================================================================= 11. built-ins: semantics

R_SPHERE = 1.3


def sphere_surface_constraints():
    numeric = mb.PointOnSurface("p", lambda x: np.sum(x * x, axis=-1) - R_SPHERE**2)
    analytic = mb.PointOnSurface("p", lambda x: np.sum(x * x, axis=-1) - R_SPHERE**2,
                                 gradient=lambda x: 2.0 * np.asarray(x),
                                 hessian=lambda x: 2.0 * np.broadcast_to(np.eye(3), np.shape(x) + (3,)))
    return numeric, analytic


def test_point_on_sphere_surface_closed_form():
    """Particle on ``f(x) = |x|² − R² = 0``: ``A = 2xᵀ``, ``γ = −2|v|²`` and, from ``m a = m g + 2x λ``,
    ``λ = −m (|v|² + x·g) / (2R²)``. Numerical and analytic gradient/Hessian agree: the gradient stencil
    is exact for a quadratic up to rounding (≈ ε|f|/h ≈ 1e-12), the Hessian (a stencil of the
    gradient stencil) carries ≈ ε|f|/h² ≈ 1e-9, so 1e-8 for A, γ and the dynamics."""
    m = 0.9
    model = particle_model(m, names=["p"])
    system = ModelSystem(model)
    numeric, analytic = sphere_surface_constraints()
    rng = np.random.default_rng(50)
    for _ in range(8):
        x = rng.standard_normal(3)
        x *= R_SPHERE / np.linalg.norm(x)
        v = rng.standard_normal(3) * 2.0
        v -= (v @ x) / (x @ x) * x
        expected_lam = -m * (v @ v + x @ GRAVITY) / (2 * R_SPHERE**2)
        for constraint, tol in ((analytic, 1e-12), (numeric, 1e-8)):
            A, _, gamma = constraint.evaluate(system, x, v)
            assert_close(A, 2.0 * x[None, :], tol, scale=2 * R_SPHERE, what="A = 2xᵀ")
            assert_close(gamma, [-2.0 * v @ v], tol, scale=max(1.0, 2 * v @ v), what="γ = −2|v|²")
            a, lam = mb.ConstrainedSystem(model, [constraint]).forward_dynamics(x, v)
            assert_close(lam, [expected_lam], max(tol, 1e-10), scale=max(1.0, abs(expected_lam)), what="λ")
            assert_close(a, GRAVITY + 2.0 * x * lam[0] / m, max(tol, 1e-10), scale=9.81, what="a")


def test_distance_between_bodies_tension_sign():
    """Two particles hanging in a chain, at rest: rod 1 (p1 to the pivot) carries ``(m1 + m2) g``, rod 2
    (p1 to p2) ``m2 g``; positive multipliers are tensions (they pull the points together)."""
    m1, m2 = 1.0, 0.5
    model = particle_model(m1, m2)
    cs = mb.ConstrainedSystem(model, [mb.Distance("p1", None, 1.0), mb.Distance("p1", "p2", 0.8)])
    q = np.array([0.0, 0.0, -1.0, 0.0, 0.0, -1.8])
    a, lam = cs.forward_dynamics(q, np.zeros(6))
    assert_close(a, np.zeros(6), 1e-12, scale=9.81, what="at rest")
    assert_close(lam, [(m1 + m2) * 9.81, m2 * 9.81], 1e-12, what="tensions")
    # A compressed rod pushes: a particle standing on a rod above the pivot
    a, lam = cs.forward_dynamics(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 1.8]), np.zeros(6))
    assert_close(lam, [-(m1 + m2) * 9.81, -m2 * 9.81], 1e-12, what="compressions")


@pytest.mark.parametrize("kind, free_motions", [("point", 3), ("planar", 4), ("revolute", 1), ("weld", 0)])
def test_loop_closure_kinds_leave_the_right_motions_free(kind, free_motions):
    """A free-flying box anchored by ``LoopClosure(None, "box", frame_a=<world pose of B>, frame_b=B)``
    (closed at q). With body velocity ``v = [v_O; ω]`` (local axes), the allowed motions are:
    point: any ω with B's origin still, ``v_O = −ω × p_B``; planar: those plus a translation along A's
    z; revolute: ω along A's z only (a hinge); weld: none. The rows have full rank and annihilate
    exactly these motions."""
    b = mb.ModelBuilder("box")
    b.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1]))
    model = b.build()
    rng = np.random.default_rng(60)
    q = model.random_configuration(rng)
    frame_b = random_placement(rng)
    T_body = mb.forward_kinematics(model, q)[0]
    frame_a = T_body @ frame_b
    cs = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "box", frame_a=frame_a, frame_b=frame_b, kind=kind,
                                                     normal=(0.0, 0.0, 1.0) if kind == "planar" else None)])
    A = cs.jacobian(q)
    assert A.shape == (6 - free_motions, 6) and cs.rank(q) == 6 - free_motions
    assert_close(cs.position_error(q), np.zeros(6 - free_motions), 1e-12, scale=1.0, what="closed")
    p_b, R_WB = frame_b[:3, 3], T_body[:3, :3]
    z_a = R_WB.T @ frame_a[:3, 2]  # A's z axis in body coordinates

    def pivot(omega):
        return np.concatenate([-np.cross(omega, p_b), omega])

    generators = {
        "point": [pivot(e) for e in np.eye(3)],
        "planar": [pivot(e) for e in np.eye(3)] + [np.concatenate([z_a, np.zeros(3)])],
        "revolute": [pivot(z_a)],
        "weld": [],
    }[kind]
    for motion in generators:
        assert_close(A @ motion, np.zeros(len(A)), 1e-12, scale=1.0, what=f"{kind}: allowed motion is blocked")


def test_joint_coupling_reduces_to_the_geared_system():
    """``JointCoupling("shoulder", "elbow", r, c)`` on the double pendulum: with ``q_e = r q_s + c``,
    ``v = S θ̇``, ``S = [1, r]ᵀ``, the accelerations are ``S θ̈`` with ``(SᵀMS) θ̈ = Sᵀ(τ − h)``; the
    multiplier is the torque on the elbow, ``−r λ`` the one on the shoulder."""
    model = mb.robots.load("double_pendulum")
    ratio, offset = -0.6, 0.4
    cs = mb.ConstrainedSystem(model, [mb.JointCoupling("shoulder", "elbow", ratio, offset)])
    S = np.array([1.0, ratio])
    rng = np.random.default_rng(70)
    for _ in range(5):
        theta, theta_dot = rng.uniform(-2, 2), rng.uniform(-2, 2)
        q, v, tau = np.array([theta, ratio * theta + offset]), S * theta_dot, rng.standard_normal(2)
        assert cs.residual(q, v) <= 1e-15
        a, lam = cs.forward_dynamics(q, v, tau)
        M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
        theta_ddot = S @ (tau - h) / (S @ M @ S)
        assert_close(a, S * theta_ddot, 1e-10, scale=max(1.0, abs(theta_ddot)), what="geared accelerations")
        generalized = M @ a + h - tau
        assert_close(generalized, np.array([-ratio, 1.0]) * lam[0], 1e-10, scale=max(1.0, abs(lam[0])), what="λ")


def test_mimic_constraints_on_panda(panda):
    """The Panda's URDF mimic (finger 2 follows finger 1): one JointCoupling; the constrained fingers
    accelerate together, and the dynamics equal the reduced (fingers geared) system."""
    model = panda[0]
    constraints = mb.mimic_constraints(model)
    assert len(constraints) == 1
    (c,) = constraints
    assert isinstance(c, mb.JointCoupling)
    assert (c.joint_a, c.joint_b, c.ratio, c.offset) == ("panda_finger_joint1", "panda_finger_joint2", 1.0, 0.0)
    assert mb.mimic_constraints(mb.robots.load("double_pendulum")) == []
    cs = mb.ConstrainedSystem(model, constraints)
    i1, i2 = model.joint_index("panda_finger_joint1"), model.joint_index("panda_finger_joint2")
    S = np.eye(model.nv)[:, :8]
    S[i2, i1] = 1.0  # v = S u with u the first 8 velocities (finger 2 follows finger 1)
    rng = np.random.default_rng(71)
    for _ in range(3):
        q = model.random_configuration(rng)
        q[i2] = q[i1]
        v, tau = S @ rng.standard_normal(8), rng.standard_normal(model.nv)
        a, lam = cs.forward_dynamics(q, v, tau)
        M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
        u_dot = np.linalg.solve(S.T @ M @ S, S.T @ (tau - h))
        assert_close(a, S @ u_dot, 1e-9, scale=max(1.0, np.abs(a).max()), what="mimic accelerations")
        assert_close(M @ a + h - tau, cs.jacobian(q).T @ lam, 1e-9, scale=max(1.0, np.abs(lam).max()), what="dynamics")


# ============================================================================= 12. bad input

def test_forward_dynamics_rejects_wrong_shapes(pendulum):
    _, cs = pendulum
    q, v = pendulum_state(L_PEND, 0.3, 0.1)
    with pytest.raises(ValueError, match="shapes"):
        cs.forward_dynamics(q[:2], v)
    with pytest.raises(ValueError, match="shapes"):
        cs.forward_dynamics(q, np.zeros(4))
    # the distance's rows take batches: a batch of two equal states gives the state's answer twice
    a, lam = cs.forward_dynamics(q, v)
    a2, lam2 = cs.forward_dynamics(np.stack([q, q]), np.stack([v, v]))
    assert np.array_equal(a2, [a, a]) and np.array_equal(lam2, [lam, lam])
    # a user constraint takes one state at a time
    user = mb.ConstrainedSystem(cs.model, [mb.Pfaffian(lambda q, t: np.array([[0.0, 0.0, 1.0]]))])
    with pytest.raises(ValueError, match="shapes"):
        user.forward_dynamics(np.stack([q, q]), np.stack([v, v]))
    with pytest.raises(ValueError, match="tau"):
        cs.forward_dynamics(q, v, tau=np.zeros(2))


def test_constraint_constructors_reject_bad_arguments():
    with pytest.raises(ValueError, match="kind must be one of"):
        mb.LoopClosure("a", "b", kind="hinge")
    with pytest.raises(ValueError, match="4x4"):
        mb.LoopClosure("a", None, frame_a=np.eye(3))
    with pytest.raises(ValueError, match="positive"):
        mb.Distance("a", None, 0.0)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        mb.Distance("a", None, 1.0, point_a=[1.0, 2.0])
    with pytest.raises(ValueError, match="non-negative"):
        mb.ConstrainedSystem(particle_model(1.0), [], baumgarte=-1.0)


def test_builtin_constraint_needs_a_model():
    """Built-in constraints refer to bodies: with a user-defined system they raise TypeError where they meet it,
    at the ConstrainedSystem's construction, and when their methods are called with it."""
    minimal = CurveCoordinateSystem(Helix(), 1.0)
    q = np.array([0.1])
    for constraint in (mb.Distance("p", None, 1.0), mb.LoopClosure("p", None), mb.JointCoupling("a", "b"),
                       mb.PointOnSurface("p", lambda x: x[..., 0]), mb.PointOnCurve("p", Helix().r),
                       mb.RollingSphere("p", 0.1), mb.RollingDisc("p", 0.1), mb.KnifeEdge("p")):
        with pytest.raises(TypeError, match=f"{constraint.name} refers to bodies, so it needs a multibody Model"):
            mb.ConstrainedSystem(minimal, [constraint])
        with pytest.raises(TypeError, match="needs a multibody Model"):
            constraint.jacobian(minimal, q)
    with pytest.raises(TypeError, match="not a mechanical system"):
        mb.ConstrainedSystem(object(), [])


def test_joint_coupling_rejects_multi_coordinate_joints():
    model = particle_model(1.0, 1.0)
    with pytest.raises(ValueError, match="coupling p1_joint-p2_joint: joint 'p1_joint' must have one coordinate"):
        mb.ConstrainedSystem(model, [mb.JointCoupling("p1_joint", "p2_joint")])


def test_point_on_curve_outside_parameter_range():
    model = particle_model(1.0, names=["bead"])
    helix = Helix()
    cs = mb.ConstrainedSystem(model, [mb.PointOnCurve("bead", helix.r, s_range=(0.0, 2.0), samples=201)])
    with pytest.raises(ValueError, match="outside s_range"):
        cs.forward_dynamics(helix.r(3.0), np.zeros(3))


def test_compiled_rows_of_one_state_equal_those_of_a_batch():
    """The built-in rows of one state (the driver's single-state path) equal those of the same state in a batch,
    with and without a velocity; a non-finite configuration warns, as the full checks do."""
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    rolling = mb.RollingSphere("ball", 0.1, plane_normal=(np.sin(0.1), 0.0, np.cos(0.1)))
    system = ModelSystem(ball)
    rng = np.random.default_rng(4)
    q = ball.random_configuration(rng, (3,))
    v = rng.standard_normal((3, ball.nv))
    batch = rolling._levels(system, q, v, 0.0)
    for k in range(3):
        one = rolling._levels(system, q[k], v[k], 0.0)
        for single, batched in zip(one, batch):
            assert single.shape == batched[k].shape
            np.testing.assert_array_equal(single, batched[k])
        without_velocity = rolling._levels(system, q[k], None, 0.0)
        np.testing.assert_array_equal(without_velocity[0], batch[0][k])
        np.testing.assert_array_equal(without_velocity[3], batch[3][k])
    q_bad = q[0].copy()
    q_bad[0] = np.nan
    with pytest.warns(RuntimeWarning, match="NaN"):
        A, _, _, _ = rolling._levels(system, q_bad, None, 0.0)
    assert np.isnan(A).all()


def test_a_systems_compiled_rows_and_rank_equal_its_constraints_own():
    """A system of compiled rows evaluates them at one state in one kernel call of its program, and makes its
    rank decision in the compiled step: the same rows as each constraint's own, stacked, and the same rank
    as the singular values of ``A`` in the metric of ``M``, also near a singular configuration (two
    parallelograms with redundant closures, 1e-9 rad from flat)."""
    model = parallelogram_chain(2)
    system = mb.ConstrainedSystem(model, planar_closures(2))
    assert system._compiled_step is not None
    for phi in (0.3, 1e-9):
        q, _ = crank_state(2, phi)
        phi_rows, A, b = system.position_and_velocity_levels(q, 0.0)
        own = [c.position_and_velocity_level(system.system, q, 0.0) for c in system.constraints]
        np.testing.assert_array_equal(phi_rows, np.concatenate([level[0] for level in own]))
        np.testing.assert_array_equal(A, np.concatenate([level[1] for level in own]))
        np.testing.assert_array_equal(b, np.zeros(system.num_rows))
        # the rank rule on the singular values of B = A L⁻ᵀ (M = L Lᵀ), by LAPACK: the compiled step's rank on the
        # program's rows, and the compiled solve's on the same rows passed as arrays
        sigma = np.linalg.svd(np.linalg.solve(np.linalg.cholesky(mb.mass_matrix(model, q)), A.T), compute_uv=False)
        expected = int((sigma > system.rank_tolerance * sigma[0]).sum())
        assert system.rank(q) == system._row_rank(q, A) == expected
    # an undefined or non-finite state leaves the answer (and its error or warning) to the constraints' own path
    q_bad = crank_state(2, 0.3)[0]
    q_bad[0] = np.nan
    assert system._compiled_levels(q_bad) is None
    assert system._compiled_rank(q[None]) is None


def test_projection_takes_projects_options_by_keyword_and_gives_the_conditioning():
    """``projection`` is :meth:`project` with the rows' conditioning at the projected state (1 for one row), its
    tolerance, iterations and warning's stack level given by keyword, as ``project``'s."""
    system = mb.ConstrainedSystem(particle_model(1.0), [mb.Holonomic(lambda q, t: np.array([q @ q - 1.0]))])
    q, v = np.array([0.0, 0.0, 1.1]), np.array([1.0, 0.0, 1.0])
    q_p, v_p, conditioning = system.projection(q, v, tolerance=1e-10, max_iterations=20)
    expected = system.project(q, v, tolerance=1e-10, max_iterations=20)
    np.testing.assert_array_equal(q_p, expected[0])
    np.testing.assert_array_equal(v_p, expected[1])
    assert conditioning == 1.0
    with pytest.raises(TypeError):
        system.projection(q, v, 0.0, 1e-10)


def test_rank_decides_on_the_rows_the_caller_has():
    """``rank(q, A=A)``: the rank of the rows ``A`` given (those of another time, as the variational step has them),
    by the rule of the rows the system evaluates. A particle's two rows that coincide at t = 1 s only."""
    system = mb.ConstrainedSystem(particle_model(1.0), [mb.Holonomic(
        lambda q, t: np.array([q[0], (1.0 - t) * q[1] + t * q[0]]),
        lambda q, t: np.array([[1.0, 0.0, 0.0], [t, 1.0 - t, 0.0]]))])
    q = np.array([0.0, 0.0, 1.0])
    assert (system.rank(q), system.rank(q, 1.0)) == (2, 1)
    assert system.rank(q, A=system.jacobian(q, 1.0)) == 1
    assert system.rank(q, 1.0, A=system.jacobian(q, 0.0)) == 2
    with pytest.raises(ValueError, match=r"A must have shape \(\.\.\., 2, 3\), got \(1, 3\)"):
        system.rank(q, A=np.ones((1, 3)))


# ============================================================================= the plane of a planar closure, names, rank

FOUR_BAR_GUESS = np.array([-np.pi / 3, 0.9, -1.4])  # robots/four_bar.urdf: crank, coupler, rocker angles (rad)


def four_bar_urdf(rocker_axis="0 1 0"):
    """robots/four_bar.urdf (the mechanism in the x–z plane, every axis along y), the rocker's axis replaced."""
    with open(mb.robots.path("four_bar")) as file:
        xml = file.read()
    rocker = '<joint name="rocker_joint" type="continuous">'
    head, tail = xml.split(rocker)
    return mb.load_urdf(head + rocker + tail.replace('<axis xyz="0 1 0"/>', f'<axis xyz="{rocker_axis}"/>', 1))


def tip_gap(model, q):
    """``(n,)`` distance between the coupler's and the rocker's tips (m) at configurations ``q (n, nq)``."""
    X = mb.forward_kinematics(model, q)
    return np.linalg.norm(X[:, model.body_index("coupler_tip"), :3, 3] - X[:, model.body_index("rocker_tip"), :3, 3],
                          axis=-1)


def test_planar_closure_of_the_four_bar_urdf_infers_its_plane_and_keeps_the_tips_together():
    """The four-bar URDF lies in the x–z plane. ``kind="planar"`` without a plane takes the plane normal to the
    joints' common axis (y): two independent rows, and the tips stay together through a simulation (with the
    x–y plane they would have one row's rank and drift apart by metres)."""
    model = four_bar_urdf()
    closure = mb.LoopClosure("coupler_tip", "rocker_tip", kind="planar")
    with warnings.catch_warnings():
        warnings.simplefilter("error", mb.RankDeficientWarning)
        system = mb.ConstrainedSystem(model, [closure])
        q0, v0 = system.project(FOUR_BAR_GUESS, np.zeros(model.nv))
        trajectory = mb.simulate(system, q0, v0, 2.0, dt=0.01, method="DOP853", rtol=1e-10, atol=1e-12)
    bound = system.constraints[0]
    assert bound.name == closure.name and closure.normal is None
    assert_close(bound.normal, [0.0, 1.0, 0.0], 1e-15, scale=1.0, what="the plane's normal (frame A = coupler_tip's axes)")
    # the rows are along A's x and A's z turned onto the plane: x and −z
    assert_close(bound.position_directions(), [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], 1e-15, scale=1.0, what="rows")
    assert_close(closure.position_directions(model), bound.position_directions(), 0.0, scale=1.0, what="same plane")
    assert system.num_rows == 2 and system.rank(q0) == 2
    assert np.ptp(trajectory.q[:, 0]) > 0.5  # the linkage moves
    assert tip_gap(model, trajectory.q).max() <= 1e-9
    # the same rows when the plane is given, and when the constraint is evaluated on its own
    explicit = mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", kind="planar", normal=(0, -2, 0))])
    q, v = trajectory.q[50], trajectory.v[50]
    assert_close(explicit.jacobian(q), system.jacobian(q), 1e-15, scale=1.0, what="A")
    assert_close(closure.jacobian(model, q), system.jacobian(q), 0.0, scale=1.0, what="A of the constraint alone")
    assert_close(explicit.solve(q, v).lam, system.solve(q, v).lam, 1e-12, scale=10.0, what="λ")


def test_planar_closure_in_a_plane_that_is_not_the_loops_warns_of_its_rank():
    """The x–y plane given explicitly for the x–z four-bar: its y row is zero, rank 1 of 2."""
    model = four_bar_urdf()
    system = mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", kind="planar", normal=(0, 0, 1))])
    with pytest.warns(mb.RankDeficientWarning, match=r"not independent at the initial state: rank 1 of 2 rows: "
                                                     r"'planar loop closure coupler_tip-rocker_tip' has rank 1 of its 2 rows"):
        q0, v0 = system.project(FOUR_BAR_GUESS, np.zeros(model.nv))
    with warnings.catch_warnings():  # once per system: later projections are silent
        warnings.simplefilter("error", mb.RankDeficientWarning)
        system.project(q0, v0)
    for method in ("RK45", "RK4", "variational"):  # simulate's initial state too, whichever run takes it
        with pytest.warns(mb.RankDeficientWarning, match="rank 1 of 2 rows") as caught:
            mb.simulate(mb.ConstrainedSystem(model, system.constraints), q0, v0, 0.05, method=method)
        assert os.path.basename(caught[0].filename) == os.path.basename(__file__), method  # points at the caller


def test_planar_closure_infers_the_plane_across_a_slider():
    """The slider–crank (revolute joints about y, a prismatic joint along x): the plane x–z."""
    model = mb.robots.load("slider_crank")
    system = mb.ConstrainedSystem(model, [mb.LoopClosure("rod_tip", "slider", kind="planar")])
    assert_close(system.constraints[0].normal, [0.0, 1.0, 0.0], 1e-15, scale=1.0, what="normal")
    q0, _ = system.project(np.array([0.3, -0.2, 0.45]), np.zeros(model.nv))
    assert system.rank(q0) == 2


def test_planar_closure_refuses_a_loop_that_is_not_planar():
    """Axes that are not parallel, a loop that only slides, and no loop at all: ``ValueError`` naming the
    joints (or the lack of them) and asking for the plane."""
    model = four_bar_urdf(rocker_axis="0 0 1")
    with pytest.raises(ValueError, match="planar loop closure coupler_tip-rocker_tip: cannot infer the plane") as info:
        mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", kind="planar")])
    message = str(info.value)
    for joint in ("'crank_joint' (continuous about [0.0, 1.0, 0.0])", "'coupler_joint' (continuous about [0.0, 1.0, 0.0])",
                  "'rocker_joint' (continuous about [0.0, 0.0, 1.0])", "normal=(nx, ny, nz)"):
        assert joint in message
    # the plane given: accepted (the constraint says which plane; the mechanism decides what moves)
    mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", kind="planar", normal=(0, 1, 0))])
    with pytest.raises(ValueError, match="no joint moves frame B relative to frame A; give the plane's normal"):
        mb.ConstrainedSystem(model, [mb.LoopClosure("coupler", "coupler_tip", kind="planar")])
    b = mb.ModelBuilder("slides")
    b.add_body("x", mb.joints.Prismatic([1, 0, 0]), inertia=mb.inertia.point_mass(1.0, [0, 0, 0]))
    b.add_body("z", mb.joints.Prismatic([0, 0, 1]), parent="x", inertia=mb.inertia.point_mass(1.0, [0, 0, 0]))
    with pytest.raises(ValueError, match=r"\('x_joint' \(prismatic along \[1.0, 0.0, 0.0\]\), 'z_joint' \(prismatic "
                                         r"along \[0.0, 0.0, 1.0\]\); .*only slide"):
        mb.ConstrainedSystem(b.build(), [mb.LoopClosure(None, "z", kind="planar")])


@pytest.mark.parametrize("kwargs, message", [
    (dict(kind="point", normal=(0, 0, 1)), "normal gives the plane of kind='planar'; it does not apply to kind='point'"),
    (dict(kind="planar", normal=(0, 0, 0)), "normal must be a non-zero, finite 3-vector"),
    (dict(kind="planar", normal=(0, np.nan, 1)), "normal must be a non-zero, finite 3-vector"),
    (dict(kind="planar", normal=(0, 1)), "normal must be a non-zero, finite 3-vector"),
])
def test_loop_closure_refuses_a_bad_normal(kwargs, message):
    with pytest.raises(ValueError, match=message):
        mb.LoopClosure("coupler_tip", "rocker_tip", **kwargs)


def test_rank_warning_names_rows_that_repeat_other_constraints():
    """Two equal couplings: each has full rank alone, together one row repeats the other."""
    model = mb.robots.load("double_pendulum")
    coupling = [mb.JointCoupling("shoulder", "elbow", 0.5, name=f"gear {k}") for k in (1, 2)]
    system = mb.ConstrainedSystem(model, coupling)
    with pytest.warns(mb.RankDeficientWarning, match=r"rank 1 of 2 rows: 1 row\(s\) repeat rows of other constraints"):
        system.project(np.array([0.2, 0.1]), np.zeros(2))


def test_intended_redundancy_can_be_filtered():
    model = mb.robots.load("double_pendulum")
    system = mb.ConstrainedSystem(model, [mb.JointCoupling("shoulder", "elbow", 0.5, name=f"gear {k}") for k in (1, 2)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", category=mb.RankDeficientWarning)
        q, v = system.project(np.array([0.2, 0.1]), np.zeros(2))
    assert system.residual(q, v) <= 1e-15


@pytest.mark.parametrize("make", [
    lambda: mb.RollingSphere("bal", radius=0.1),
    lambda: mb.RollingDisc("bal", 0.1),
    lambda: mb.KnifeEdge("bal"),
    lambda: mb.LoopClosure(None, "bal", kind="planar"),
    lambda: mb.Distance("bal", None, 1.0),
    lambda: mb.PointOnSurface("bal", lambda x: x[..., 2]),
    lambda: mb.PointOnCurve("bal", Helix().r),
])
def test_misspelled_body_is_refused_at_the_systems_construction(make):
    """Every built-in constraint's bodies are checked where it meets the model, with the close matches."""
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    constraint = make()
    with pytest.raises(ValueError, match=rf"^{constraint.name}: unknown body 'bal'; did you mean 'ball'\? bodies are"):
        mb.ConstrainedSystem(ball, [constraint])


def test_misspelled_joint_of_a_coupling_is_refused_at_the_systems_construction():
    model = mb.robots.load("double_pendulum")
    with pytest.raises(ValueError, match=r"coupling shoulder-elbw: unknown joint 'elbw'; did you mean 'elbow'\?"):
        mb.ConstrainedSystem(model, [mb.JointCoupling("shoulder", "elbw")])


# ============================================================================= the branch of a weld or revolute closure

def anchored_box(kind, seed=80):
    """A free box held to the world by ``LoopClosure(None, "box", kind=kind)`` with random frames A (world) and
    B (in the box), and ``pose(R_AB)``: the configuration where frame B is turned by ``R_AB`` from frame A
    (their origins together)."""
    b = mb.ModelBuilder("box")
    b.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1]))
    model = b.build()
    rng = np.random.default_rng(seed)
    frame_a, frame_b = random_placement(rng), random_placement(rng)
    closure = mb.LoopClosure(None, "box", frame_a=frame_a, frame_b=frame_b, kind=kind)

    def pose(R_AB):
        X = frame_a @ pose_matrix(R_AB, np.zeros(3)) @ np.linalg.inv(frame_b)
        q = model.neutral()
        q[:3], q[3:7] = X[:3, 3], mb.spatial.rotation_to_quat(X[:3, :3])
        return q

    return model, closure, mb.ConstrainedSystem(model, [closure]), pose


DIAGONAL = np.ones(3) / np.sqrt(3.0)

#: Relative rotations other than I where the closure's rows vanish, and what the refusal says of them.
WRONG_BRANCHES = {
    "weld, half turn about x": (
        "weld", np.diag([1.0, -1.0, -1.0]),
        (r"frame B is turned 180\.0° from frame A about \[-?1\.0, 0\.0, 0\.0\] \(frame A's axes\), its [yz] axis at "
         r"e_[yz]\^A · e_[yz]\^B = -1;")),
    "weld, 120° about (1, 1, 1)": (
        "weld", axis_angle_rotation(DIAGONAL, 2.0 * np.pi / 3.0),
        (r"frame B is turned 120\.0° from frame A about \[0\.577, 0\.577, 0\.577\] \(frame A's axes\), its [xyz] "
         r"axis at e_[xyz]\^A · e_[xyz]\^B = ")),
    "revolute, z antiparallel": (
        "revolute", axis_angle_rotation([1.0, 0.0, 0.0], np.pi) @ axis_angle_rotation([0.0, 0.0, 1.0], 0.7),
        (r"frame B's z axis is 180\.0° from frame A's \(e_z\^A · e_z\^B = -1\); the orientation rows also vanish "
         r"with the z axes antiparallel")),
}


@pytest.mark.parametrize("case", list(WRONG_BRANCHES))
def test_closure_on_another_zero_of_its_rows_is_refused(case):
    """A weld's rows ``e_i^A · e_j^B`` for (y, z), (z, x), (x, y) vanish with frame B a half turn about an axis
    of A or 120° about (1, 1, 1) from it, a revolute's (x, z), (y, z) with the z axes antiparallel: ``φ = 0``
    there, and a projection started near such a pose stays on it. The projection, ``residual`` and
    ``position_error`` refuse the state, naming the constraint, the axis and the angle, and ``simulate``
    refuses to start from it."""
    kind, R_AB, found = WRONG_BRANCHES[case]
    model, closure, system, pose = anchored_box(kind)
    q = pose(R_AB)
    assert np.abs(closure.position(model, q)).max() < 1e-15  # every row vanishes, orientation rows included
    message = rf"^{closure.name}: {found}.*away from the closed pose; start the projection nearer the closed pose"
    with pytest.raises(mb.ConstraintError, match=message):
        system.project(q, np.zeros(6))
    with pytest.raises(mb.ConstraintError, match=message):
        system.residual(q, np.zeros(6))
    with pytest.raises(mb.ConstraintError, match=message):
        system.position_error(q)
    with pytest.raises(mb.ConstraintError, match=message):
        mb.simulate(system, q, np.zeros(6), 0.1, dt=0.01, method="RK4")
    # from a start near the wrong pose, Gauss–Newton converges to it: the rows alone do not tell
    rng = np.random.default_rng(81)
    start = model.integrate(q, 0.1 * rng.standard_normal(6))
    settled = system._projected(start, np.zeros(6), 0.0, 1e-12, 50)[0]
    assert np.abs(closure.position(model, settled)).max() < 1e-12
    with pytest.raises(mb.ConstraintError, match=message):
        system.project(start, np.zeros(6))


def test_every_projection_onto_the_120_degree_zero_is_refused():
    """At the 120° zero the cosines ``e_k^A · e_k^B`` are zero, known only to the rows' tolerance and of either
    sign; the check asks more than a positive cosine of each axis, so that none of these states passes."""
    model, _, system, pose = anchored_box("weld")
    q = pose(axis_angle_rotation(DIAGONAL, 2.0 * np.pi / 3.0))
    rng = np.random.default_rng(82)
    for _ in range(100):
        with pytest.raises(mb.ConstraintError, match="120.0° from frame A"):
            system.project(model.integrate(q, 0.1 * rng.standard_normal(6)), np.zeros(6))


@pytest.mark.parametrize("kind", ["weld", "revolute"])
def test_closure_started_near_its_pose_projects_and_passes_the_check(kind):
    """From starts a few tenths of a radian off the closed pose, the projection closes the loop on the pose's
    branch, one state and a batch alike, and ``residual`` and ``position_error`` report it; a batch with one
    state on a wrong zero is refused, naming that state."""
    model, closure, system, pose = anchored_box(kind)
    rng = np.random.default_rng(83)
    q = np.stack([model.integrate(pose(np.eye(3)), 0.3 * rng.standard_normal(6)) for _ in range(3)])
    v = rng.standard_normal((3, 6))
    q_batch, v_batch = system.project(q, v)
    for k in range(3):
        q_k, v_k = system.project(q[k], v[k])
        assert np.abs(q_k - q[k]).max() > 1e-2  # the positions moved
        assert system.residual(q_k, v_k) <= 1e-12
        assert np.abs(system.position_error(q_k)).max() <= 1e-12
        R_A, R_B = closure.frame_a[:3, :3], mb.frame_placement(model, q_k, "box")[:3, :3] @ closure.frame_b[:3, :3]
        axes = [2] if kind == "revolute" else [0, 1, 2]
        assert_close(np.diag(R_A.T @ R_B)[axes], np.ones(len(axes)), 1e-12, scale=1.0, what="cosines on the branch")
    assert (system.residual(q_batch, v_batch) <= 1e-12).all()
    flipped = q_batch.copy()
    flipped[1] = pose(np.diag([1.0, -1.0, -1.0]))
    with pytest.raises(mb.ConstraintError, match=rf"^{closure.name}: at state 1: frame B"):
        system.residual(flipped, v_batch)
