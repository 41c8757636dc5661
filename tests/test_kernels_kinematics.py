"""The kinematics and energy kernels (``multibody.kernels.kinematics``, ``multibody.kernels.energy``)
called directly on one state, against Pinocchio and the NumPy implementation.

Robots: Panda and UR5 (fixed base), Solo12 and Talos reduced (free flyer), and random trees with every
joint kind (through conftest's Pinocchio twin). Error measure: ``max|ours − ref| / max(1, max|ref|)``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import multibody as mb
from multibody.kernels import energy, kinematics as kin
from multibody.kinematics import frame_kinematics
from multibody.tree import compile_tree, frame_rows

from conftest import erd_urdf, pinocchio_twin, q_to_pinocchio, random_tree_model

pin = pytest.importorskip("pinocchio")

TOL = 1e-12
N_STATES = 4
EMPTY = np.zeros(0)

ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", False),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos": ("talos_data/robots/talos_reduced.urdf", True),
}
CASES = list(ROBOTS) + ["tree0", "tree1", "tree2"]


class Case:
    """A model, its compiled tree, its Pinocchio counterpart with the frame id of each body, and
    random states."""

    def __init__(self, name):
        if name in ROBOTS:
            relative, floating = ROBOTS[name]
            path = erd_urdf(relative)
            self.model = mb.load_urdf(path, floating_base=floating)
            self.pmodel = (pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating
                           else pin.buildModelFromUrdf(path))
            self.frame_ids = [self.pmodel.getFrameId(body, pin.BODY) for body in self.model.body_names]
        else:
            self.model = random_tree_model(int(name[-1]))
            self.pmodel, self.frame_ids = pinocchio_twin(pin, self.model)
        model = self.model
        assert self.pmodel.nv == model.nv and all(f < self.pmodel.nframes for f in self.frame_ids)
        self.tree = compile_tree(model)
        rng = np.random.default_rng(sum(map(ord, name)))
        self.q = model.random_configuration(rng, shape=(N_STATES,))
        self.v = rng.standard_normal((N_STATES, model.nv))
        self.points = rng.uniform(-0.4, 0.4, size=(N_STATES, model.nbodies, 3))
        self.q_pin = q_to_pinocchio(model, self.q)

    def run(self, kernel, frames, x0, x1, x2, shape, size=None):
        """``kernel`` on one state, ``out`` prefilled with NaN so that every entry must be written."""
        tree = self.tree
        out = np.full(shape, np.nan)
        ws = np.full(size if size is not None else kin.workspace_size(tree.njoints, tree.nv), np.nan)
        kernel(tree.joints, tree.reals, frames, x0, x1, x2, EMPTY, out, ws)
        return out


@functools.lru_cache(maxsize=None)
def get_case(name):
    return Case(name)


def rel_error(ours, ref):
    ref = np.asarray(ref, dtype=float)
    return np.abs(ours - ref).max() / max(1.0, np.abs(ref).max())


def offset_frames(pmodel, fids, X_BFs):
    """A copy of ``pmodel`` with an operational frame at ``X_BF`` in each body frame ``fid``, and their ids."""
    pmodel = pin.Model(pmodel)
    ids = []
    for k, (fid, X_BF) in enumerate(zip(fids, X_BFs)):
        frame = pmodel.frames[fid]
        placement = frame.placement * pin.SE3(X_BF[:3, :3], X_BF[:3, 3])
        ids.append(pmodel.addFrame(pin.Frame(f"offset_{k}", frame.parentJoint, fid, placement, pin.OP_FRAME)))
    return pmodel, ids


# ----------------------------------------------------------------------------- against Pinocchio

@pytest.mark.parametrize("name", CASES)
def test_frame_placements_match_pinocchio(name):
    """With ``frames = tree.bodies`` the kernel is the forward kinematics of every body."""
    case = get_case(name)
    model, pmodel, data = case.model, case.pmodel, case.pmodel.createData()
    for k in range(N_STATES):
        out = case.run(kin.frame_placements, case.tree.bodies, case.q[k], EMPTY, EMPTY, (model.nbodies, 16))
        X = out.reshape(model.nbodies, 4, 4)
        pin.forwardKinematics(pmodel, data, case.q_pin[k])
        pin.updateFramePlacements(pmodel, data)
        for b, fid in enumerate(case.frame_ids):
            assert rel_error(X[b], data.oMf[fid].homogeneous) <= TOL, model.body_names[b]
        assert rel_error(X, mb.forward_kinematics(model, case.q[k])) <= TOL


@pytest.mark.parametrize("name", CASES)
def test_frame_jacobians_match_pinocchio(name):
    """Jacobian and its time variation of every body's origin, world-aligned."""
    case = get_case(name)
    model, pmodel, data = case.model, case.pmodel, case.pmodel.createData()
    for k in range(N_STATES):
        pin.computeJointJacobiansTimeVariation(pmodel, data, case.q_pin[k], case.v[k])
        pin.updateFramePlacements(pmodel, data)
        for b, fid in enumerate(case.frame_ids):
            frames = case.tree.bodies[b : b + 1]
            J = case.run(kin.frame_jacobian, frames, case.q[k], EMPTY, EMPTY, (6, model.nv))
            J_dot = case.run(kin.frame_jacobian_time_variation, frames, case.q[k], case.v[k], EMPTY, (6, model.nv))
            name_b = model.body_names[b]
            assert rel_error(J, pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)) <= TOL, name_b
            ref = pin.getFrameJacobianTimeVariation(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            assert rel_error(J_dot, ref) <= TOL, name_b


@pytest.mark.parametrize("name", ["panda", "solo12", "tree0", "tree1"])
def test_point_jacobians_match_pinocchio_offset_frames(name):
    """A point offset from the body origin, in the body's axes, is an operational frame in Pinocchio."""
    case = get_case(name)
    model = case.model
    moving = [b for b in range(model.nbodies) if model.body_joints[b] >= 0]
    for k in range(N_STATES):
        X_BFs = [mb.spatial.pose_matrix(np.eye(3), case.points[k, b]) for b in moving]
        pmodel, ids = offset_frames(case.pmodel, [case.frame_ids[b] for b in moving], X_BFs)
        data = pmodel.createData()
        pin.computeJointJacobiansTimeVariation(pmodel, data, case.q_pin[k], case.v[k])
        pin.updateFramePlacements(pmodel, data)
        for b, fid in zip(moving, ids):
            frames, point = case.tree.bodies[b : b + 1], case.points[k, b]
            J = case.run(kin.frame_jacobian, frames, case.q[k], point, EMPTY, (6, model.nv))
            J_dot = case.run(kin.frame_jacobian_time_variation, frames, case.q[k], case.v[k], point, (6, model.nv))
            assert rel_error(J, pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)) <= TOL
            ref = pin.getFrameJacobianTimeVariation(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            assert rel_error(J_dot, ref) <= TOL


@pytest.mark.parametrize("name", CASES)
def test_frame_motions_match_pinocchio(name):
    """Pose, Jacobian and ``J̇ v`` (the classical acceleration at ``q̈ = 0``) of frames at random
    placements in every body, all rows from one call."""
    case = get_case(name)
    model, tree = case.model, case.tree
    rng = np.random.default_rng(7)
    moving = [b for b in range(model.nbodies) if model.body_joints[b] >= 0]
    X_BFs = [mb.spatial.pose_from_xyz_rpy(rng.uniform(-0.3, 0.3, 3), rng.uniform(-np.pi, np.pi, 3)) for _ in moving]
    frames = frame_rows(model, list(zip(moving, X_BFs)))
    pmodel, ids = offset_frames(case.pmodel, [case.frame_ids[b] for b in moving], X_BFs)
    data = pmodel.createData()
    nv = model.nv
    for k in range(N_STATES):
        out = case.run(kin.frame_motions, frames, case.q[k], case.v[k], EMPTY, (len(moving), kin.motion_columns(nv)))
        pin.computeJointJacobians(pmodel, data, case.q_pin[k])
        pin.forwardKinematics(pmodel, data, case.q_pin[k], case.v[k], np.zeros(nv))
        pin.updateFramePlacements(pmodel, data)
        for row, fid in zip(out, ids):
            oMf = data.oMf[fid]
            assert rel_error(row[:9], oMf.rotation.reshape(9)) <= TOL
            assert rel_error(row[9:12], oMf.translation) <= TOL
            J = pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            assert rel_error(row[12 : 12 + 6 * nv].reshape(6, nv), J) <= TOL
            acc = pin.getFrameClassicalAcceleration(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
            assert rel_error(row[12 + 6 * nv :], acc) <= TOL


@pytest.mark.parametrize("name", CASES)
def test_energies_match_pinocchio(name):
    case = get_case(name)
    model, pmodel, data = case.model, case.pmodel, case.pmodel.createData()
    size = energy.workspace_size(model.njoints, model.nv)
    for k in range(N_STATES):
        T = case.run(energy.kinetic_energy, case.tree.bodies, case.q[k], case.v[k], EMPTY, (1, 1), size)[0, 0]
        U = case.run(energy.potential_energy, case.tree.bodies, case.q[k], EMPTY, EMPTY, (1, 1), size)[0, 0]
        assert rel_error(T, pin.computeKineticEnergy(pmodel, data, case.q_pin[k], case.v[k])) <= TOL
        assert rel_error(U, pin.computePotentialEnergy(pmodel, data, case.q_pin[k])) <= TOL
        assert rel_error(T, mb.kinetic_energy(model, case.q[k], case.v[k])) <= TOL
        assert rel_error(U, mb.potential_energy(model, case.q[k])) <= TOL


# ----------------------------------------------------------------------------- against the NumPy implementation

@pytest.mark.parametrize("name", CASES)
def test_kernels_match_numpy(name):
    """Every body, with a point offset, against ``mb.jacobian``, ``mb.jacobian_time_variation`` and
    ``frame_kinematics``; ``J̇ v`` of :func:`frame_motions` equals the time-variation kernel times ``v``."""
    case = get_case(name)
    model, tree, nv = case.model, case.tree, case.model.nv
    for k in range(N_STATES):
        q, v = case.q[k], case.v[k]
        motions = case.run(kin.frame_motions, tree.bodies, q, v, EMPTY, (model.nbodies, kin.motion_columns(nv)))
        for b in range(model.nbodies):
            frames, point = tree.bodies[b : b + 1], case.points[k, b]
            J = case.run(kin.frame_jacobian, frames, q, point, EMPTY, (6, nv))
            J_dot = case.run(kin.frame_jacobian_time_variation, frames, q, v, point, (6, nv))
            assert rel_error(J, mb.jacobian(model, q, b, point)) <= TOL
            assert rel_error(J_dot, mb.jacobian_time_variation(model, q, v, b, point)) <= TOL
            R, p, J0, bias = frame_kinematics(model, q, v, b)
            row = motions[b]
            assert rel_error(row[:9], R.reshape(9)) <= TOL
            assert rel_error(row[9:12], p) <= TOL
            assert rel_error(row[12 : 12 + 6 * nv].reshape(6, nv), J0) <= TOL
            assert rel_error(row[12 + 6 * nv :], bias) <= TOL
            J_dot0 = case.run(kin.frame_jacobian_time_variation, frames, q, v, EMPTY, (6, nv))
            assert rel_error(row[12 + 6 * nv :], J_dot0 @ v) <= TOL


# ----------------------------------------------------------------------------- special frames

@pytest.mark.parametrize("name", ["panda", "tree0"])
def test_world_fixed_frames(name):
    """A body fixed to the world (Panda's ``panda_link0``, the tree's ``ground``) and a frame row with
    joint −1 at an arbitrary pose: the pose is the row's own, Jacobian, ``J̇`` and ``J̇ v`` are zero."""
    case = get_case(name)
    model, tree, nv = case.model, case.tree, case.model.nv
    b = model.body_index("panda_link0" if name == "panda" else "ground")
    assert model.body_joints[b] < 0
    X = mb.spatial.pose_from_xyz_rpy(np.array([0.3, -0.2, 0.5]), np.array([0.4, -1.0, 2.0]))
    frames = np.concatenate([tree.bodies[b : b + 1], frame_rows(model, [(None, X)])])
    q, v = case.q[0], case.v[0]
    poses = case.run(kin.frame_placements, frames, q, EMPTY, EMPTY, (2, 16)).reshape(2, 4, 4)
    np.testing.assert_array_equal(poses[0], model.body_placements[b])
    np.testing.assert_array_equal(poses[1], X)
    for row in range(2):
        one = frames[row : row + 1]
        np.testing.assert_array_equal(case.run(kin.frame_jacobian, one, q, np.ones(3), EMPTY, (6, nv)), 0.0)
        np.testing.assert_array_equal(case.run(kin.frame_jacobian_time_variation, one, q, v, np.ones(3), (6, nv)), 0.0)
    motions = case.run(kin.frame_motions, frames, q, v, EMPTY, (2, kin.motion_columns(nv)))
    np.testing.assert_array_equal(motions[:, 12:], 0.0)
    np.testing.assert_array_equal(motions[1, :9], X[:3, :3].reshape(9))
    np.testing.assert_array_equal(motions[1, 9:12], X[:3, 3])


@pytest.mark.parametrize("name", ["panda", "talos", "tree1"])
def test_columns_outside_support_are_zero(name):
    case = get_case(name)
    model, tree, nv = case.model, case.tree, case.model.nv
    for b in range(model.nbodies):
        j = model.body_joints[b]
        supported = np.zeros(nv, dtype=bool)
        while j >= 0:
            supported[model.idx_v[j] : model.idx_v[j] + model.joints[j].nv] = True
            j = model.parents[j]
        frames = tree.bodies[b : b + 1]
        J = case.run(kin.frame_jacobian, frames, case.q[0], EMPTY, EMPTY, (6, nv))
        J_dot = case.run(kin.frame_jacobian_time_variation, frames, case.q[0], case.v[0], EMPTY, (6, nv))
        np.testing.assert_array_equal(J[:, ~supported], 0.0)
        np.testing.assert_array_equal(J_dot[:, ~supported], 0.0)


def test_joint_placements_match_numpy():
    """The shared forward pass, and the poses :func:`joint_motions` leaves in the workspace."""
    case = get_case("tree2")
    tree, q = case.tree, case.q[0]
    ws = np.full(kin.workspace_size(tree.njoints, tree.nv), np.nan)
    # (read from the workspace: compiled code hands a view back to Python as the array it views)
    p_WO = np.array(kin.joint_placements(tree.joints, tree.reals, q, ws, None)[1])
    pose = ws[: 12 * (tree.njoints + 1)].reshape(-1, 12).copy()
    R_WJ, p_WJ = mb.kinematics.joint_world_poses(case.model, q)
    # positions from the reference point O, the first joint's origin, whose world position is the last row's
    np.testing.assert_array_equal(pose[-1, 9:], p_WO)
    np.testing.assert_array_equal(pose[0, 9:], 0.0)
    assert rel_error(pose[:-1, :9].reshape(-1, 3, 3), R_WJ) <= TOL
    assert rel_error(pose[:-1, 9:] + p_WO, p_WJ) <= TOL
    assert rel_error(p_WO, p_WJ[0]) <= TOL
    ws[:] = np.nan
    kin.joint_motions(tree.joints, tree.reals, q, case.v[0], ws, None)
    np.testing.assert_array_equal(ws[: 12 * (tree.njoints + 1)].reshape(-1, 12), pose)
