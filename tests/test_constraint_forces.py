"""Constraint forces on bodies and joint reaction forces."""

import numpy as np
import pytest

import multibody as mb


def _generalized(model, q, f_ext):
    """Σ Jᵢᵀ f_ext,i, read off RNEA: τ(f = 0) − τ(f)."""
    zero = np.zeros(model.nv)
    return mb.inverse_dynamics(model, q, zero, zero) - mb.inverse_dynamics(model, q, zero, zero, f_ext)


def _constraints():
    line = lambda s: np.stack([s, 0.2 * s, -1.0 + 0.0 * s], axis=-1)  # noqa: E731
    return [
        mb.LoopClosure("tip", None, frame_b=mb.spatial.pose_from_xyz_rpy([0.5, 0.1, -1.5], [0.1, 0.2, 0.3]), kind="weld"),
        mb.LoopClosure("link1", "tip", frame_a=mb.spatial.pose_from_xyz_rpy([0.1, 0, 0], [0.3, 0, 0]), kind="revolute"),
        mb.Distance("link2", "link1", 1.0, point_a=[0.0, 0.0, -1.0], point_b=[0.1, 0.0, 0.0]),
        mb.PointOnSurface("tip", lambda x: x @ x - 4.0),
        mb.PointOnCurve("tip", line, s_range=(-3.0, 3.0)),
    ]


@pytest.mark.parametrize("constraint", _constraints(), ids=lambda c: type(c).__name__)
def test_body_forces_reproduce_the_generalized_constraint_force(constraint):
    """Σ Jᵀ f (from the body forces) equals Aᵀ λ for any multipliers."""
    model = mb.robots.load("double_pendulum")
    system = mb.ConstrainedSystem(model, [constraint])
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = rng.uniform(-1.0, 1.0, model.nq)
        lam = rng.standard_normal(system.num_rows)
        np.testing.assert_allclose(_generalized(model, q, system.body_forces(q, lam)), system.jacobian(q).T @ lam,
                                   rtol=1e-12, atol=1e-12)


def test_user_constraints_have_no_body_forces():
    model = mb.robots.load("double_pendulum")
    system = mb.ConstrainedSystem(model, [mb.Holonomic(lambda q, t: q[:1] - 0.1)])
    with pytest.raises(TypeError, match="generalized coordinates"):
        system.body_forces(np.zeros(2), np.ones(1))


def test_joint_reaction_forces_project_onto_joint_torques():
    """S_iᵀ f_i = τ_i, and a hanging pendulum's pivot carries its weight."""
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(0)
    q, v, a = rng.standard_normal((3, 4, model.nv))
    forces = mb.joint_reaction_forces(model, q, v, a)
    tau = mb.inverse_dynamics(model, q, v, a)
    for i, joint in enumerate(model.joints):
        np.testing.assert_allclose(forces[:, i] @ joint.motion_subspace[:, 0], tau[:, i], rtol=1e-12, atol=1e-12)
    # At rest, straight down: the shoulder holds both rods' weight (2 kg), the elbow one rod's.
    at_rest = mb.joint_reaction_forces(model, np.zeros(2), np.zeros(2), np.zeros(2))
    np.testing.assert_allclose(at_rest[:, :3], [[0, 0, 2 * 9.81], [0, 0, 9.81]], atol=1e-12)
    np.testing.assert_allclose(at_rest[:, 3:], 0.0, atol=1e-12)


def test_closed_loop_bearing_loads_balance_statically():
    """A four-bar held still by the constraint: the ground joints carry the whole weight."""
    model = mb.robots.load("four_bar")
    in_plane = mb.spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))
    system = mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", frame_a=in_plane, kind="planar")])
    q, _ = system.project(np.array([-np.pi / 3, 0.9, -1.4]), np.zeros(3))
    # Hold it with the joint torques that make a = 0: τ = g − Aᵀ λ for λ from the solve with those torques.
    tau = mb.generalized_gravity(model, q)
    a, lam = system.forward_dynamics(q, np.zeros(3), tau)
    np.testing.assert_allclose(a, 0.0, atol=1e-10)
    loads = mb.joint_reaction_forces(model, q, np.zeros(3), a, system.body_forces(q, lam))
    # Vertical forces through the two ground joints (crank, rocker), in world axes, sum to the weight.
    R_WJ, _ = mb.kinematics.joint_world_poses(model, q)
    crank, rocker = model.joint_index("crank_joint"), model.joint_index("rocker_joint")
    vertical = sum((R_WJ[j] @ loads[j, :3])[2] for j in (crank, rocker))
    np.testing.assert_allclose(vertical, model.total_mass * 9.81, rtol=1e-10)
