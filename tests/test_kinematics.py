"""Forward kinematics, Jacobians and their time variation: Pinocchio, finite differences, batching."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody import spatial as sp

from conftest import erd_urdf, import_pinocchio, pinocchio_twin, q_to_pinocchio, random_tree_model

PIN_ROBOTS = [
    ("ur_description/urdf/ur5_robot.urdf", False),
    ("panda_description/urdf/panda.urdf", False),
    ("solo_description/robots/solo12.urdf", True),
    ("talos_data/robots/talos_reduced.urdf", True),
]
PIN_IDS = ["ur5", "panda", "solo12-floating", "talos-floating"]

_CACHE = {}


def load_both(relative, floating_base):
    pin = import_pinocchio()
    key = (relative, floating_base)
    if key not in _CACHE:
        path = erd_urdf(relative)
        model = mb.load_urdf(path, floating_base=floating_base)
        pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating_base \
            else pin.buildModelFromUrdf(path)
        _CACHE[key] = (model, pmodel)
    return _CACHE[key]


def load_ours(relative, floating_base):
    return mb.load_urdf(erd_urdf(relative), floating_base=floating_base)


@pytest.fixture(scope="module", params=[0, 1, 2], ids=["tree0", "tree1", "tree2"])
def tree(request):
    return random_tree_model(request.param)


# ----------------------------------------------------------------------------- against Pinocchio

@pytest.mark.parametrize("relative,floating_base", PIN_ROBOTS, ids=PIN_IDS)
def test_forward_kinematics_and_jacobians_match_pinocchio(relative, floating_base):
    pin = import_pinocchio()
    model, pmodel = load_both(relative, floating_base)
    data = pmodel.createData()
    frame_ids = [pmodel.getFrameId(name, pin.BODY) for name in model.body_names]
    assert all(fid < pmodel.nframes for fid in frame_ids)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = model.random_configuration(rng)
        q_pin = q_to_pinocchio(model, q)
        pin.forwardKinematics(pmodel, data, q_pin)
        pin.updateFramePlacements(pmodel, data)
        pin.computeJointJacobians(pmodel, data, q_pin)
        X = mb.forward_kinematics(model, q)
        assert X.shape == (model.nbodies, 4, 4)
        worst_X = worst_J = 0.0
        for b, fid in enumerate(frame_ids):
            worst_X = max(worst_X, np.abs(X[b] - data.oMf[fid].homogeneous).max())
            J_pin = pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            worst_J = max(worst_J, np.abs(mb.jacobian(model, q, b) - J_pin).max())
        assert worst_X <= 1e-12
        assert worst_J <= 1e-12


def test_random_trees_match_pinocchio_twin(tree):
    """Every joint type (spherical, planar, translation, free-flyer, axes off the coordinate axes),
    branches and fixed attachments: placements, Jacobians and their time variation."""
    pin = import_pinocchio()
    pmodel, frame_ids = pinocchio_twin(pin, tree)
    assert pmodel.nv == tree.nv
    data = pmodel.createData()
    rng = np.random.default_rng(20)
    for _ in range(5):
        q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
        q_pin = q_to_pinocchio(tree, q)
        pin.computeJointJacobiansTimeVariation(pmodel, data, q_pin, v)  # also runs forward kinematics
        pin.updateFramePlacements(pmodel, data)
        X = mb.forward_kinematics(tree, q)
        for b, fid in enumerate(frame_ids):
            name = tree.body_names[b]
            assert_allclose(X[b], data.oMf[fid].homogeneous, atol=1e-12, err_msg=name)
            assert_allclose(mb.jacobian(tree, q, b), pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED),
                            atol=1e-12, err_msg=name)
            assert_allclose(mb.jacobian_time_variation(tree, q, v, b),
                            pin.getFrameJacobianTimeVariation(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED),
                            atol=1e-11, err_msg=name)


@pytest.mark.parametrize("relative,floating_base", PIN_ROBOTS[1:3], ids=PIN_IDS[1:3])
def test_point_jacobian_matches_pinocchio_offset_frame(relative, floating_base):
    pin = import_pinocchio()
    model, pmodel = load_both(relative, floating_base)
    pmodel = pin.Model(pmodel)  # a copy: the frames added here stay out of the cache
    rng = np.random.default_rng(1)
    bodies = [model.body_names[k] for k in rng.choice(model.nbodies, size=4, replace=False)]
    points = rng.uniform(-0.3, 0.3, size=(len(bodies), 3))
    point_frames = []
    for name, point in zip(bodies, points):
        fid = pmodel.getFrameId(name, pin.BODY)
        frame = pmodel.frames[fid]
        placement = frame.placement * pin.SE3(np.eye(3), point)
        point_frames.append(pmodel.addFrame(pin.Frame(f"{name}_point", frame.parentJoint, fid, placement, pin.OP_FRAME)))
    data = pmodel.createData()
    for _ in range(3):
        q = model.random_configuration(rng)
        q_pin = q_to_pinocchio(model, q)
        pin.computeJointJacobians(pmodel, data, q_pin)
        pin.updateFramePlacements(pmodel, data)
        X = mb.forward_kinematics(model, q)
        for name, point, fid in zip(bodies, points, point_frames):
            b = model.body_index(name)
            assert_allclose(X[b, :3, :3] @ point + X[b, :3, 3], data.oMf[fid].translation, atol=1e-12)
            J_pin = pin.getFrameJacobian(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            assert_allclose(mb.jacobian(model, q, name, point=point), J_pin, atol=1e-12)


def test_jacobian_time_variation_matches_pinocchio_panda():
    """Pinocchio 3+'s ``getFrameJacobianTimeVariation(..., LOCAL_WORLD_ALIGNED)`` is the plain time
    derivative of the world-aligned frame Jacobian, so that ``J a + J̇ v`` is the classical
    acceleration of the frame origin: it agrees with ours with no correction term. (Pinocchio 2
    returned a derivative whose linear rows lacked ``ω × (J_lin)``-type terms; the finite-difference
    tests below are the ground truth either way.)"""
    pin = import_pinocchio()
    model, pmodel = load_both("panda_description/urdf/panda.urdf", False)
    data = pmodel.createData()
    rng = np.random.default_rng(2)
    for _ in range(5):
        q, v, a = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        pin.computeJointJacobiansTimeVariation(pmodel, data, q, v)
        pin.updateFramePlacements(pmodel, data)
        for b, name in enumerate(model.body_names):
            fid = pmodel.getFrameId(name, pin.BODY)
            dJ = pin.getFrameJacobianTimeVariation(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED)
            assert_allclose(mb.jacobian_time_variation(model, q, v, name), dJ, atol=1e-12, err_msg=name)
        # the classical acceleration of a frame origin, from Pinocchio's second-order kinematics
        pin.forwardKinematics(pmodel, data, q, v, a)
        pin.updateFramePlacements(pmodel, data)
        fid = pmodel.getFrameId("panda_hand", pin.BODY)
        acc = pin.getFrameClassicalAcceleration(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
        assert_allclose(mb.point_acceleration(model, q, v, a, "panda_hand"), acc, atol=1e-12)
        vel = pin.getFrameVelocity(pmodel, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
        assert_allclose(mb.point_velocity(model, q, v, "panda_hand"), vel, atol=1e-12)


# ----------------------------------------------------------------------------- finite differences

def rotation_rate(R_plus, R_minus, eps):
    """World angular velocity from a central difference: R₊ R₋ᵀ = exp(2ε [ω]×) + O(ε³)."""
    return sp.so3_log(R_plus @ R_minus.T) / (2 * eps)


def check_jacobian_by_finite_differences(model, q, rng, eps=1e-6):
    direction = rng.standard_normal(model.nv)
    X_plus = mb.forward_kinematics(model, model.integrate(q, eps * direction))
    X_minus = mb.forward_kinematics(model, model.integrate(q, -eps * direction))
    for b in range(model.nbodies):
        point = rng.uniform(-0.5, 0.5, 3)
        J = mb.jacobian(model, q, b, point=point)
        x_plus = X_plus[b, :3, :3] @ point + X_plus[b, :3, 3]
        x_minus = X_minus[b, :3, :3] @ point + X_minus[b, :3, 3]
        Jv = J @ direction
        scale = max(1.0, np.abs(Jv).max())
        assert_allclose((x_plus - x_minus) / (2 * eps), Jv[:3], atol=1e-7 * scale, err_msg=model.body_names[b])
        assert_allclose(rotation_rate(X_plus[b, :3, :3], X_minus[b, :3, :3], eps), Jv[3:], atol=1e-7 * scale,
                        err_msg=model.body_names[b])


def test_point_jacobian_finite_differences_random_trees(tree):
    rng = np.random.default_rng(3)
    for _ in range(3):
        check_jacobian_by_finite_differences(tree, tree.random_configuration(rng), rng)


@pytest.mark.parametrize("relative,floating_base", [PIN_ROBOTS[2]], ids=[PIN_IDS[2]])
def test_point_jacobian_finite_differences_solo(relative, floating_base):
    model = load_ours(relative, floating_base)
    rng = np.random.default_rng(4)
    for _ in range(2):
        check_jacobian_by_finite_differences(model, model.random_configuration(rng), rng)


def test_point_jacobian_is_origin_jacobian_plus_lever(tree):
    # v_x = v_O + ω × (x − O) with x − O = R_WB point
    rng = np.random.default_rng(5)
    q = tree.random_configuration(rng)
    X = mb.forward_kinematics(tree, q)
    for b in range(tree.nbodies):
        point = rng.standard_normal(3)
        J_origin, J_point = mb.jacobian(tree, q, b), mb.jacobian(tree, q, b, point=point)
        r = X[b, :3, :3] @ point
        assert_allclose(J_point[:3], J_origin[:3] - sp.skew(r) @ J_origin[3:], atol=1e-12)
        assert_allclose(J_point[3:], J_origin[3:], atol=0)


def check_time_variation_by_finite_differences(model, q, v, rng, h=1e-5):
    """J̇(q, v) = d/dt J(q(t)) along q(t) = q ⊕ v t (the exponential keeps the velocity equal to v)."""
    q_plus, q_minus = model.integrate(q, h * v), model.integrate(q, -h * v)
    for b in range(model.nbodies):
        point = rng.uniform(-0.5, 0.5, 3)
        J_dot = mb.jacobian_time_variation(model, q, v, b, point=point)
        fd = (mb.jacobian(model, q_plus, b, point=point) - mb.jacobian(model, q_minus, b, point=point)) / (2 * h)
        scale = max(1.0, np.abs(fd).max())
        assert_allclose(J_dot, fd, atol=1e-6 * scale, err_msg=model.body_names[b])


def test_jacobian_time_variation_finite_differences_random_trees(tree):
    rng = np.random.default_rng(6)
    for _ in range(3):
        q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
        check_time_variation_by_finite_differences(tree, q, v, rng)


def test_jacobian_time_variation_finite_differences_solo_floating():
    model = load_ours("solo_description/robots/solo12.urdf", True)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
        check_time_variation_by_finite_differences(model, q, v, rng)


def test_point_acceleration_is_J_a_plus_Jdot_v(tree):
    rng = np.random.default_rng(8)
    q, v, a = tree.random_configuration(rng), rng.standard_normal(tree.nv), rng.standard_normal(tree.nv)
    for b in range(tree.nbodies):
        point = rng.standard_normal(3)
        expected = (mb.jacobian(tree, q, b, point) @ a + mb.jacobian_time_variation(tree, q, v, b, point) @ v)
        assert_allclose(mb.point_acceleration(tree, q, v, a, b, point), expected, atol=1e-12)
        assert_allclose(mb.point_velocity(tree, q, v, b, point), mb.jacobian(tree, q, b, point) @ v, atol=1e-12)


def test_point_acceleration_finite_differences(tree):
    """The classical acceleration d/dt (J(q(t)) v(t)) along q(t) = q ⊕ (v t + a t²/2), whose velocity
    is v + a t + O(t²) (the O(t) Lie bracket term [v, v] vanishes)."""
    rng = np.random.default_rng(9)
    h = 1e-5
    q, v, a = tree.random_configuration(rng), rng.standard_normal(tree.nv), rng.standard_normal(tree.nv)
    q_plus = tree.integrate(q, h * v + 0.5 * h**2 * a)
    q_minus = tree.integrate(q, -h * v + 0.5 * h**2 * a)
    for b in range(tree.nbodies):
        point = rng.uniform(-0.5, 0.5, 3)
        fd = (mb.point_velocity(tree, q_plus, v + h * a, b, point)
              - mb.point_velocity(tree, q_minus, v - h * a, b, point)) / (2 * h)
        acc = mb.point_acceleration(tree, q, v, a, b, point)
        assert_allclose(acc, fd, atol=1e-6 * max(1.0, np.abs(fd).max()), err_msg=tree.body_names[b])


# ----------------------------------------------------------------------------- structure

def test_world_fixed_body_has_zero_jacobian(tree):
    rng = np.random.default_rng(10)
    q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
    b = tree.body_names.index("ground")
    assert tree.body_joints[b] == -1
    assert_allclose(mb.jacobian(tree, q, b, point=[0.1, 0.2, 0.3]), np.zeros((6, tree.nv)))
    assert_allclose(mb.jacobian_time_variation(tree, q, v, b), np.zeros((6, tree.nv)))
    # and its placement does not depend on q
    assert_allclose(mb.forward_kinematics(tree, q)[b], mb.forward_kinematics(tree, tree.neutral())[b], atol=0)


def test_jacobian_columns_vanish_outside_support(tree):
    rng = np.random.default_rng(11)
    q = tree.random_configuration(rng)
    for b in range(tree.nbodies):
        J = mb.jacobian(tree, q, b)
        assert np.all(J[:, ~tree.body_support[b]] == 0.0)


def test_body_by_name_or_index(tree):
    rng = np.random.default_rng(12)
    q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
    name = tree.body_names[5]
    assert_allclose(mb.jacobian(tree, q, name), mb.jacobian(tree, q, 5))
    assert_allclose(mb.jacobian(tree, q, np.int64(5)), mb.jacobian(tree, q, 5))
    assert_allclose(mb.jacobian_time_variation(tree, q, v, name), mb.jacobian_time_variation(tree, q, v, 5))


def test_bad_body_name_lists_names(tree):
    q = tree.neutral()
    with pytest.raises(ValueError, match="unknown body 'nope'") as info:
        mb.jacobian(tree, q, "nope")
    assert all(name in str(info.value) for name in tree.body_names)
    with pytest.raises(ValueError, match="unknown body"):
        mb.jacobian_time_variation(tree, q, np.zeros(tree.nv), "nope")
    with pytest.raises(ValueError, match="out of range"):
        mb.jacobian(tree, q, tree.nbodies)


@pytest.mark.parametrize("point", [[0.1, 0.2], [0.1, 0.2, 0.3, 0.4], 0.5])
def test_bad_point_shape(tree, point):
    q = tree.neutral()
    with pytest.raises(ValueError, match="point"):
        mb.jacobian(tree, q, 1, point=point)
    with pytest.raises(ValueError, match="point"):
        mb.jacobian_time_variation(tree, q, np.zeros(tree.nv), 1, point=point)


def test_bad_velocity_shape(tree):
    with pytest.raises(ValueError, match=rf"\(\.\.\., {tree.nv}\)"):
        mb.jacobian_time_variation(tree, tree.neutral(), np.zeros(tree.nv + 1), 1)


# ----------------------------------------------------------------------------- batching

@pytest.mark.parametrize("shape", [(4,), (2, 3)])
def test_batched_calls_equal_stacked_single_calls(tree, shape):
    rng = np.random.default_rng(13)
    q = tree.random_configuration(rng, shape=shape)
    v = rng.standard_normal(shape + (tree.nv,))
    a = rng.standard_normal(shape + (tree.nv,))
    point = np.array([0.1, -0.2, 0.3])
    body = tree.body_names[-1]
    X = mb.forward_kinematics(tree, q)
    J = mb.jacobian(tree, q, body, point=point)
    J_dot = mb.jacobian_time_variation(tree, q, v, body, point=point)
    acc = mb.point_acceleration(tree, q, v, a, body, point=point)
    assert X.shape == shape + (tree.nbodies, 4, 4)
    assert J.shape == J_dot.shape == shape + (6, tree.nv)
    assert acc.shape == shape + (6,)
    for index in np.ndindex(*shape):
        assert_allclose(X[index], mb.forward_kinematics(tree, q[index]), atol=1e-15)
        assert_allclose(J[index], mb.jacobian(tree, q[index], body, point=point), atol=1e-15)
        assert_allclose(J_dot[index], mb.jacobian_time_variation(tree, q[index], v[index], body, point=point),
                        atol=1e-14)
        assert_allclose(acc[index], mb.point_acceleration(tree, q[index], v[index], a[index], body, point=point),
                        atol=1e-14)


def test_batched_points_with_matching_configurations(tree):
    rng = np.random.default_rng(14)
    q = tree.random_configuration(rng, shape=(5,))
    v = rng.standard_normal((5, tree.nv))
    points = rng.standard_normal((5, 3))
    J = mb.jacobian(tree, q, 3, point=points)
    J_dot = mb.jacobian_time_variation(tree, q, v, 3, point=points)
    assert J.shape == J_dot.shape == (5, 6, tree.nv)
    for k in range(5):
        assert_allclose(J[k], mb.jacobian(tree, q[k], 3, point=points[k]), atol=1e-15)
        assert_allclose(J_dot[k], mb.jacobian_time_variation(tree, q[k], v[k], 3, point=points[k]), atol=1e-14)


@pytest.mark.parametrize("q_shape,point_shape", [((), (5,)), ((2, 1), (3,))], ids=["single-q", "broadcast"])
def test_batched_points_broadcast_against_configurations(tree, q_shape, point_shape):
    rng = np.random.default_rng(15)
    q = tree.random_configuration(rng, shape=q_shape)
    points = rng.standard_normal(point_shape + (3,))
    batch = np.broadcast_shapes(q_shape, point_shape)
    J = mb.jacobian(tree, q, 3, point=points)
    assert J.shape == batch + (6, tree.nv)
    q_b = np.broadcast_to(q, batch + (tree.nq,))
    p_b = np.broadcast_to(points, batch + (3,))
    for index in np.ndindex(*batch):
        assert_allclose(J[index], mb.jacobian(tree, q_b[index], 3, point=p_b[index]), atol=1e-15)


def test_configuration_and_velocity_batches_broadcast(tree):
    rng = np.random.default_rng(16)
    q = tree.random_configuration(rng, shape=(2, 1))
    v, a = rng.standard_normal((3, tree.nv)), rng.standard_normal((3, tree.nv))
    J_dot = mb.jacobian_time_variation(tree, q, v, 3)
    acc = mb.point_acceleration(tree, q, v, a, 3)
    assert J_dot.shape == (2, 3, 6, tree.nv) and acc.shape == (2, 3, 6)
    for i in range(2):
        for k in range(3):
            assert_allclose(J_dot[i, k], mb.jacobian_time_variation(tree, q[i, 0], v[k], 3), atol=1e-14)
            assert_allclose(acc[i, k], mb.point_acceleration(tree, q[i, 0], v[k], a[k], 3), atol=1e-14)
