"""Inverse kinematics (``mb.inverse_kinematics``): the error Jacobian against finite differences, quadratic
convergence, convergence from 100 random starts on Panda and UR5, unreachable targets, joint limits,
position targets, several frames, batches against single calls, free-flyer models, the null-space
posture and the input errors."""

import dataclasses
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody.kernels import ik as kernels

from conftest import erd_urdf, random_tree_model

TOL = 1e-10

ROBOTS = {
    # name: (path below example-robot-data/robots, free-flyer base, end-effector frame)
    "panda": ("panda_description/urdf/panda.urdf", False, "panda_hand_tcp"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False, "tool0"),
    "solo12": ("solo_description/robots/solo12.urdf", True, "FL_FOOT"),
}
_MODELS = {}


def robot(name):
    """An example-robot-data model (meshes are irrelevant here: their warning is silenced)."""
    if name not in _MODELS:
        relative, floating_base, _ = ROBOTS[name]
        path = erd_urdf(relative)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            _MODELS[name] = mb.load_urdf(path, floating_base=floating_base)
    return _MODELS[name]


def pose_errors(model, q, frame, X_target):
    """``(position error (m), rotation angle (rad))`` of ``frame`` at ``q`` against the pose ``X_target``."""
    X = mb.frame_placement(model, q, frame)
    position = np.linalg.norm(X[..., :3, 3] - X_target[..., :3, 3], axis=-1)
    R = np.swapaxes(X_target[..., :3, :3], -1, -2) @ X[..., :3, :3]
    angle = np.linalg.norm(mb.spatial.so3_log(R), axis=-1)
    return position, angle


def within_limits(model, q):
    """Whether every angle and displacement of ``q (..., nq)`` lies within ``model.lower``, ``model.upper``."""
    index = [s + k for joint, s in zip(model.joints, model.idx_q) if joint.vector_space for k in range(joint.nq)]
    x = q[..., index]
    return bool(np.all((x >= model.lower[index]) & (x <= model.upper[index])))


# ----------------------------------------------------------------------------- the error and its Jacobian

def kernel_errors(model, names, kinds, targets, q):
    """``e (m,)`` and ``A = ∂e/∂δ (m, nv)`` of the compiled kernel at ``q``."""
    tree = model.tree
    rows = np.ascontiguousarray(tree.bodies[[model.body_names.index(n) for n in names]])
    options = np.zeros(kernels.KINDS + len(names))
    options[kernels.KINDS:] = kinds
    m = sum(6 if k == kernels.POSE else 3 for k in kinds)
    nj = model.njoints
    ws, e = np.zeros(13 * nj + 12), np.zeros(m)
    kernels.mark_supports(tree.joints, rows, ws[12 * (nj + 1) :])
    J, A = np.zeros((6, model.nv)), np.zeros((m, model.nv))
    kernels.errors(tree.joints, tree.reals, rows, targets, options, q, ws, e)
    kernels.error_jacobian(tree.joints, tree.reals, rows, options, ws, e, J, A)
    return e, A


@pytest.mark.parametrize("which", ["solo12", "tree"])
def test_error_jacobian_matches_finite_differences(which):
    """``A = J_r(e)⁻¹ J_local`` (pose) and the world-aligned linear rows (position) are the derivatives of
    the errors along tangent steps ``q ⊕ δ``, free-flyer and spherical joints included."""
    model = robot("solo12") if which == "solo12" else random_tree_model(1)
    rng = np.random.default_rng(3)
    names = [model.body_names[-1], model.body_names[1], model.body_names[len(model.body_names) // 2]]
    kinds = [kernels.POSITION, kernels.POSE, kernels.POSE]
    targets = np.concatenate([np.concatenate([X[:3, :3].reshape(9), X[:3, 3]]) for X in
                              (mb.frame_placement(model, model.random_configuration(rng), n) for n in names)])
    for _ in range(3):
        q = model.random_configuration(rng)
        e, A = kernel_errors(model, names, kinds, targets, q)
        h, numeric = 1e-6, np.zeros_like(A)
        for c in range(model.nv):
            step = np.zeros(model.nv)
            step[c] = h
            e_plus, _ = kernel_errors(model, names, kinds, targets, model.integrate(q, step))
            e_minus, _ = kernel_errors(model, names, kinds, targets, model.integrate(q, -step))
            numeric[:, c] = (e_plus - e_minus) / (2 * h)
        assert np.abs(A - numeric).max() < 1e-7 * max(1.0, np.abs(A).max())


@pytest.mark.parametrize("angle", [0.0, 1e-6, 0.05, 0.0999, 0.1001, 0.3, 0.4999, 0.5001, 1.5, 3.0, 3.14])
def test_right_jacobian_inverse_of_se3(angle):
    """``log(exp(ξ) exp(τ)) = ξ + J_r(ξ)⁻¹ τ + O(τ²)``: the blocks of ``J_r⁻¹`` on both sides of the series
    thresholds, against central differences of ``mb.spatial.se3_log``."""
    rng = np.random.default_rng(int(angle * 1e4))
    axis = rng.standard_normal(3)
    xi = np.concatenate([rng.standard_normal(3), angle * axis / np.linalg.norm(axis)])
    B, C = kernels.right_jacobian_inverse_blocks(tuple(xi[:3]), tuple(xi[3:]))
    B, C = np.reshape(B, (3, 3)), np.reshape(C, (3, 3))
    expected = np.block([[B, C], [np.zeros((3, 3)), B]])
    R, p = mb.spatial.se3_exp(xi)
    h, numeric = 1e-6, np.zeros((6, 6))
    for c in range(6):
        logs = []
        for sign in (1.0, -1.0):
            dR, dp = mb.spatial.se3_exp(sign * h * np.eye(6)[c])
            logs.append(mb.spatial.se3_log(R @ dR, R @ dp + p))
        numeric[:, c] = (logs[0] - logs[1]) / (2 * h)
    np.testing.assert_allclose(expected, numeric, atol=1e-8)


def test_pose_error_is_the_se3_log():
    """The error of a pose target is ``log(X_WT⁻¹ X_WF)``, ``[ρ; θ]`` in the target's axes."""
    model = robot("panda")
    rng = np.random.default_rng(0)
    frame = ROBOTS["panda"][2]
    X_target = mb.frame_placement(model, model.random_configuration(rng), frame)
    q = model.random_configuration(rng)
    result = mb.inverse_kinematics(model, {frame: X_target}, q0=q, max_iterations=0)
    X = mb.frame_placement(model, q, frame)
    R_TW, p_TW = X_target[:3, :3].T, -X_target[:3, :3].T @ X_target[:3, 3]
    expected = mb.spatial.se3_log(R_TW @ X[:3, :3], R_TW @ X[:3, 3] + p_TW)
    np.testing.assert_allclose(result.frame_errors[frame], expected, atol=1e-14)
    assert result.error == pytest.approx(np.linalg.norm(expected), rel=1e-14)
    assert result.iterations == 0 and not result.converged
    np.testing.assert_array_equal(result.q, q)


def test_newton_steps_converge_quadratically():
    """Near a solution the steps are Gauss–Newton steps with the exact Jacobian: ‖e_{k+1}‖ ≤ C ‖e_k‖²."""
    model = robot("ur5")
    rng = np.random.default_rng(1)
    frame = ROBOTS["ur5"][2]
    q_star = model.random_configuration(rng)
    X_target = mb.frame_placement(model, q_star, frame)
    q0 = q_star + 0.05 * rng.standard_normal(model.nv)
    errors = [mb.inverse_kinematics(model, {frame: X_target}, q0=q0, tol=0.0, max_iterations=k, restarts=0).error
              for k in range(8)]
    pairs = [(a, b) for a, b in zip(errors, errors[1:]) if 1e-12 < b and a < 1e-2]
    assert len(pairs) >= 2, errors
    assert all(b <= 100.0 * a * a for a, b in pairs), errors
    assert errors[-1] < 1e-14


# ----------------------------------------------------------------------------- convergence, limits

@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_converges_from_100_random_starts(name):
    """Reachable targets (forward kinematics of configurations within the limits) are met to 1e-10 in
    position (m) and orientation (rad) from each of 100 random starts, within the joint limits."""
    model = robot(name)
    frame = ROBOTS[name][2]
    rng = np.random.default_rng(7)
    X_targets = mb.frame_placement(model, model.random_configuration(rng, (4,)), frame)
    starts = model.random_configuration(rng, (100,))
    result = mb.inverse_kinematics(model, {frame: X_targets[:, None]}, q0=starts)  # batch (4, 100)
    assert result.q.shape == (4, 100, model.nq) and result.converged.shape == (4, 100)
    assert result.converged.all(), result.error[~result.converged]
    assert result.error.max() <= TOL
    position, angle = pose_errors(model, result.q, frame, X_targets[:, None])
    assert position.max() <= TOL and angle.max() <= TOL
    assert within_limits(model, result.q)


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_unreachable_target_is_refused_with_its_error(name):
    """A target out of reach ends with ``converged`` false, the best configuration within the limits and
    its error, which is at least the distance beyond the reach."""
    model = robot(name)
    frame = ROBOTS[name][2]
    far = np.eye(4)
    far[:3, 3] = (3.0, 0.0, 0.5)
    result = mb.inverse_kinematics(model, {frame: far}, max_iterations=200)
    assert not result.converged and result.error > 1.0
    assert result.iterations == 200
    assert within_limits(model, result.q)
    position, _ = pose_errors(model, result.q, frame, far)
    assert 1.0 < position < 3.0
    assert np.isfinite(result.frame_errors[frame]).all()
    assert np.linalg.norm(result.frame_errors[frame]) == pytest.approx(result.error)


def test_keeps_joint_limits_where_the_unlimited_solution_leaves_them():
    """A Panda target met by a configuration on a limit: the start is projected into the limits, and the
    result stays within them (the fourth joint's range is [−3.07, −0.07] rad)."""
    model = robot("panda")
    frame = ROBOTS["panda"][2]
    q_star = (model.lower + model.upper) / 2
    q_star[3] = model.upper[3]  # elbow on its limit
    X_target = mb.frame_placement(model, q_star, frame)
    q0 = model.neutral()  # outside the fourth joint's range: projected
    result = mb.inverse_kinematics(model, {frame: X_target}, q0=q0)
    assert result.converged
    assert within_limits(model, result.q)


def test_position_target():
    """A ``(3,)`` target constrains the frame's origin only: its error is ``p_WF − p_WT`` (world axes)."""
    model = robot("panda")
    frame = ROBOTS["panda"][2]
    rng = np.random.default_rng(2)
    p_targets = mb.frame_placement(model, model.random_configuration(rng, (20,)), frame)[:, :3, 3]
    result = mb.inverse_kinematics(model, {frame: p_targets})
    assert result.converged.all() and result.frame_errors[frame].shape == (20, 3)
    X = mb.frame_placement(model, result.q, frame)
    assert np.abs(X[:, :3, 3] - p_targets).max() <= TOL
    np.testing.assert_allclose(result.frame_errors[frame], X[:, :3, 3] - p_targets, atol=1e-15)
    assert within_limits(model, result.q)


@pytest.mark.parametrize("name, frames", [
    ("panda", ("panda_hand_tcp", "panda_link4")),  # pose and elbow position: 9 rows, 9 coordinates
    ("ur5", ("tool0", "forearm_link")),            # 9 rows, 6 coordinates: the primal system
])
def test_two_frames_at_once(name, frames):
    """A pose target and a position target on two frames, from a configuration that meets both."""
    model = robot(name)
    rng = np.random.default_rng(4)
    q_star = model.random_configuration(rng, (10,))
    X_tool, X_elbow = (mb.frame_placement(model, q_star, f) for f in frames)
    result = mb.inverse_kinematics(model, {frames[0]: X_tool, frames[1]: X_elbow[:, :3, 3]})
    assert result.converged.all(), result.error
    assert set(result.frame_errors) == set(frames)
    position, angle = pose_errors(model, result.q, frames[0], X_tool)
    assert position.max() <= TOL and angle.max() <= TOL
    assert np.abs(mb.frame_placement(model, result.q, frames[1])[:, :3, 3] - X_elbow[:, :3, 3]).max() <= TOL


def test_batched_equals_single():
    """A batch of targets (and of starts, broadcast) gives the single calls' results exactly."""
    model = robot("panda")
    frame = ROBOTS["panda"][2]
    rng = np.random.default_rng(5)
    X_targets = mb.frame_placement(model, model.random_configuration(rng, (6,)), frame)
    starts = model.random_configuration(rng, (6,))
    batch = mb.inverse_kinematics(model, {frame: X_targets}, q0=starts)
    for k in range(6):
        single = mb.inverse_kinematics(model, {frame: X_targets[k]}, q0=starts[k])
        np.testing.assert_array_equal(batch.q[k], single.q)
        assert batch.error[k] == single.error and batch.iterations[k] == single.iterations
        np.testing.assert_array_equal(batch.frame_errors[frame][k], single.frame_errors[frame])
    # one target for many starts, and one start for many targets
    many_starts = mb.inverse_kinematics(model, {frame: X_targets[0]}, q0=starts)
    np.testing.assert_array_equal(many_starts.q[2], mb.inverse_kinematics(model, {frame: X_targets[0]}, q0=starts[2]).q)
    many_targets = mb.inverse_kinematics(model, {frame: X_targets}, q0=starts[0])
    single = mb.inverse_kinematics(model, {frame: X_targets[3]}, q0=starts[0])
    np.testing.assert_array_equal(many_targets.q[3], single.q)
    # the number of threads does not change a result
    threads = mb.get_num_threads()
    try:
        mb.set_num_threads(1)
        np.testing.assert_array_equal(mb.inverse_kinematics(model, {frame: X_targets}, q0=starts).q, batch.q)
    finally:
        mb.set_num_threads(threads)


def test_empty_batch():
    model = robot("ur5")
    result = mb.inverse_kinematics(model, {"tool0": np.zeros((0, 3))})
    assert result.q.shape == (0, model.nq) and result.error.shape == (0,) and result.converged.shape == (0,)
    assert result.frame_errors["tool0"].shape == (0, 3)


# ----------------------------------------------------------------------------- free flyers

def test_free_flyer_base_through_foot_targets():
    """Solo12 on its free-flyer base: the base (position and quaternion) and the legs found together from
    the four feet's positions and the base's pose."""
    model = robot("solo12")
    rng = np.random.default_rng(6)
    q_star = model.random_configuration(rng, (5,))
    feet = ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT")
    targets = {foot: mb.frame_placement(model, q_star, foot)[:, :3, 3] for foot in feet}
    targets["base_link"] = mb.frame_placement(model, q_star, "base_link")
    result = mb.inverse_kinematics(model, targets)
    assert result.converged.all(), result.error
    for foot in feet:
        assert np.abs(mb.frame_placement(model, result.q, foot)[:, :3, 3] - targets[foot]).max() <= TOL
    position, angle = pose_errors(model, result.q, "base_link", targets["base_link"])
    assert position.max() <= TOL and angle.max() <= TOL
    quaternions = result.q[:, 3:7]
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=-1), 1.0, atol=1e-14)
    # feet only: the base is free to move, the problem is redundant
    feet_only = mb.inverse_kinematics(model, {foot: targets[foot] for foot in feet})
    assert feet_only.converged.all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_tree_with_every_joint_kind(seed):
    """A random tree (free flyer, spherical, planar, translation, continuous, revolute and prismatic joints,
    fixed attachments): poses of two bodies met together, limits kept."""
    model = random_tree_model(seed)
    rng = np.random.default_rng(seed)
    q_star = model.random_configuration(rng, (8,))
    leaf_a, leaf_b = model.body_names[-1], model.body_names[-3]
    targets = {leaf_a: mb.frame_placement(model, q_star, leaf_a), leaf_b: mb.frame_placement(model, q_star, leaf_b)}
    result = mb.inverse_kinematics(model, targets)
    assert result.converged.all(), result.error
    for frame, X in targets.items():
        position, angle = pose_errors(model, result.q, frame, X)
        assert position.max() <= TOL and angle.max() <= TOL
    assert within_limits(model, result.q)
    model.check_configuration(result.q)  # unit quaternions and planar pairs


# ----------------------------------------------------------------------------- posture

def test_null_space_posture_selects_the_solution_nearest_the_posture():
    """On the redundant Panda the posture picks, among the configurations that meet the target, one nearer
    to ``q_ref`` than the plain solve's (never farther), without costing accuracy; with the target at
    ``q_ref``'s own hand pose, the nearest solution is ``q_ref`` itself."""
    model = robot("panda")
    frame = ROBOTS["panda"][2]
    rng = np.random.default_rng(8)
    q_ref = model.random_configuration(rng, (20,))
    X_targets = mb.frame_placement(model, q_ref, frame)
    q0 = np.clip(q_ref + 0.3 * rng.standard_normal(q_ref.shape), model.lower, model.upper)
    plain = mb.inverse_kinematics(model, {frame: X_targets}, q0=q0)
    posture = mb.inverse_kinematics(model, {frame: X_targets}, q0=q0, posture=q_ref)
    assert plain.converged.all() and posture.converged.all()
    position, angle = pose_errors(model, posture.q, frame, X_targets)
    assert position.max() <= TOL and angle.max() <= TOL
    distance_plain = np.linalg.norm(model.difference(plain.q, q_ref), axis=-1)
    distance_posture = np.linalg.norm(model.difference(posture.q, q_ref), axis=-1)
    assert np.all(distance_posture <= distance_plain + 1e-12)
    assert distance_posture.max() < 1e-6 and distance_plain.min() > 0.05
    assert within_limits(model, posture.q)
    # a smaller weight reaches the same configurations, in more steps
    gentle = mb.inverse_kinematics(model, {frame: X_targets}, q0=q0, posture=q_ref, posture_weight=0.3)
    assert gentle.converged.all() and np.median(gentle.iterations) > np.median(posture.iterations)


def test_posture_with_a_target_that_fixes_every_coordinate():
    """UR5 has no redundancy for a pose: the posture leaves the solution as it is."""
    model = robot("ur5")
    rng = np.random.default_rng(10)
    q_star = model.random_configuration(rng, (5,))
    X_targets = mb.frame_placement(model, q_star, "tool0")
    plain = mb.inverse_kinematics(model, {"tool0": X_targets})
    posture = mb.inverse_kinematics(model, {"tool0": X_targets}, posture=model.neutral())
    assert posture.converged.all()
    np.testing.assert_allclose(posture.q, plain.q, atol=1e-8)


# ----------------------------------------------------------------------------- the result and errors

def test_target_met_at_the_start_takes_no_step():
    model = robot("ur5")
    q = model.random_configuration(np.random.default_rng(9))
    result = mb.inverse_kinematics(model, {"tool0": mb.frame_placement(model, q, "tool0")}, q0=q)
    assert result.converged and result.iterations == 0 and result.error <= TOL
    np.testing.assert_array_equal(result.q, q)
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.q = None
    with pytest.raises(TypeError):
        result.frame_errors["tool0"] = None


def test_default_start_is_the_middle_of_the_limits():
    model = robot("panda")
    start = mb.ik.default_start(model)
    np.testing.assert_allclose(start[:7], (model.lower[:7] + model.upper[:7]) / 2)
    result = mb.inverse_kinematics(model, {"panda_hand_tcp": np.eye(4)}, max_iterations=0)
    np.testing.assert_array_equal(result.q, start)


def test_clear_errors():
    model = robot("ur5")
    X = np.eye(4)
    with pytest.raises(ValueError, match=r"unknown frame 'hand'.*'base_link'"):
        mb.inverse_kinematics(model, {"hand": X})
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\).*\(\.\.\., 3\).*got \(4, 2\)"):
        mb.inverse_kinematics(model, {"tool0": np.zeros((4, 2))})
    with pytest.raises(ValueError, match="rotation"):
        mb.inverse_kinematics(model, {"tool0": np.diag([1.0, 1.0, 2.0, 1.0])})
    with pytest.raises(ValueError, match="last row"):
        mb.inverse_kinematics(model, {"tool0": np.ones((4, 4))})
    with pytest.raises(ValueError, match="NaN"):
        mb.inverse_kinematics(model, {"tool0": [np.nan, 0.0, 0.0]})
    with pytest.raises(ValueError, match=r"q0 must have shape \(\.\.\., 6\)"):
        mb.inverse_kinematics(model, {"tool0": X}, q0=np.zeros(7))
    with pytest.raises(ValueError, match=r"posture must have shape"):
        mb.inverse_kinematics(model, {"tool0": X}, posture=np.zeros(5))
    with pytest.raises(ValueError, match="do not broadcast"):
        mb.inverse_kinematics(model, {"tool0": np.zeros((3, 3))}, q0=np.zeros((2, 6)))
    with pytest.raises(ValueError, match="non-empty mapping"):
        mb.inverse_kinematics(model, {})
    with pytest.raises(ValueError, match="non-empty mapping"):
        mb.inverse_kinematics(model, X)
    for option, value in (("tol", -1.0), ("max_iterations", 2.5), ("damping", 0.0), ("posture_weight", 2.0),
                          ("restarts", -1)):
        with pytest.raises(ValueError, match=option):
            mb.inverse_kinematics(model, {"tool0": X}, **{option: value})
