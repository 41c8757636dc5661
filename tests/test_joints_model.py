"""Joint types, configuration-space maps, the immutable Model, the builder and the shipped robots."""

import dataclasses
import os

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody import joints as jt
from multibody import spatial as sp
from multibody.inertia import Inertia

from conftest import (
    ALL_MOVING_KINDS,
    erd_urdf,
    import_pinocchio,
    pinocchio_nq,
    pinocchio_twin,
    q_from_pinocchio,
    q_to_pinocchio,
    random_axis,
    random_inertia,
    random_tree_model,
)

TOL = 1e-12


def joint_instances():
    rng = np.random.default_rng(7)
    return [
        jt.Revolute(random_axis(rng)),
        jt.Continuous(random_axis(rng)),
        jt.Prismatic(random_axis(rng)),
        jt.Planar(),
        jt.Spherical(),
        jt.FreeFlyer(),
        jt.Translation(),
    ]


JOINTS = joint_instances()
JOINT_IDS = [j.kind for j in JOINTS]


def quaternion_slices(joint):
    """Slices of ``q`` holding a quaternion (compared up to sign: q and −q are one rotation)."""
    return {"spherical": [slice(0, 4)], "free-flyer": [slice(3, 7)]}.get(joint.kind, [])


def assert_same_joint_configuration(joint, qa, qb, atol=TOL):
    qa, qb = np.array(qa, dtype=float), np.array(qb, dtype=float)
    for s in quaternion_slices(joint):
        if qa[..., s] @ qb[..., s] < 0:
            qb[..., s] = -qb[..., s]
    assert_allclose(qa, qb, atol=atol)


def moderate_velocity(rng, joint, scale=1.0):
    """A velocity whose rotation part stays below π (where exp is one-to-one)."""
    v = rng.uniform(-1.0, 1.0, joint.nv) * scale
    if joint.kind in ("spherical", "free-flyer"):
        w = v[-3:]
        if np.linalg.norm(w) > 2.5:
            v[-3:] = w / np.linalg.norm(w) * 2.5
    return v


def random_joint_q(rng, joint, shape=()):
    return joint.random(rng, *joint.default_limits, shape=shape)


# ----------------------------------------------------------------------------- joint maps

@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_integrate_difference_inverse(joint):
    rng = np.random.default_rng(1)
    for _ in range(50):
        q0 = random_joint_q(rng, joint)
        v = moderate_velocity(rng, joint, scale=2.0)
        q1 = joint.integrate(q0, v)
        # difference(q, integrate(q, v)) = v
        assert_allclose(joint.difference(q0, q1), v, atol=1e-12)
        # integrate(q0, difference(q0, q1)) = q1 for an arbitrary q1
        q2 = random_joint_q(rng, joint)
        assert_same_joint_configuration(joint, joint.integrate(q0, joint.difference(q0, q2)), q2, atol=1e-12)


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_integrate_zero_and_difference_self(joint):
    rng = np.random.default_rng(2)
    q = random_joint_q(rng, joint)
    assert_same_joint_configuration(joint, joint.integrate(q, np.zeros(joint.nv)), q)
    assert_allclose(joint.difference(q, q), np.zeros(joint.nv), atol=TOL)


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_unit_norm_preserved(joint):
    rng = np.random.default_rng(3)
    q = random_joint_q(rng, joint)
    for _ in range(200):
        q = joint.integrate(q, rng.standard_normal(joint.nv))
    if joint.kind == "planar":
        assert abs(np.hypot(q[2], q[3]) - 1.0) < 1e-14
    for s in quaternion_slices(joint):
        assert abs(np.linalg.norm(q[s]) - 1.0) < 1e-14


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_neutral_is_identity_transform(joint):
    q = joint.neutral()
    assert q.shape == (joint.nq,)
    R, p = joint.transform(q)
    assert_allclose(R, np.eye(3), atol=TOL)
    assert_allclose(p, np.zeros(3), atol=TOL)


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_integrate_matches_motion_subspace(joint):
    """For small steps, exp(S v dt) from neutral moves the joint frame with velocity S v (in J)."""
    rng = np.random.default_rng(4)
    v = rng.standard_normal(joint.nv)
    q0 = random_joint_q(rng, joint)
    R0, p0 = joint.transform(q0)
    eps = 1e-6
    Rp, pp = joint.transform(joint.integrate(q0, eps * v))
    Rm, pm = joint.transform(joint.integrate(q0, -eps * v))
    # body velocity of J in P, expressed in J: v_lin = R0ᵀ ṗ, [ω]× = R0ᵀ Ṙ
    p_dot = (pp - pm) / (2 * eps)
    W = R0.T @ (Rp - Rm) / (2 * eps)
    twist = np.concatenate([R0.T @ p_dot, [W[2, 1], W[0, 2], W[1, 0]]])
    if joint.kind == "translation":
        # Translation's velocity is [vx, vy, vz] in P (= J axes, no rotation)
        expected = np.concatenate([v, np.zeros(3)])
    else:
        expected = joint.motion_subspace @ v
    assert_allclose(twist, expected, atol=1e-8)


def test_revolute_and_prismatic_transforms():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    R, p = jt.Revolute(axis * 3).transform(np.array([0.4]))
    assert_allclose(R, sp.axis_angle_rotation(axis, 0.4), atol=TOL)
    assert_allclose(p, np.zeros(3))
    R, p = jt.Prismatic(axis).transform(np.array([0.4]))
    assert_allclose(R, np.eye(3))
    assert_allclose(p, 0.4 * axis, atol=TOL)
    # the axis is normalised and read-only
    joint = jt.Revolute([0, 0, 5])
    assert_allclose(joint.axis, [0, 0, 1])
    with pytest.raises(ValueError):
        joint.axis[0] = 1.0


@pytest.mark.parametrize("make", [lambda: jt.Revolute([0, 0, 0]), lambda: jt.Prismatic([0, 0, 0]),
                                  lambda: jt.Revolute([1, 0]), lambda: jt.Continuous([np.nan, 0, 1])])
def test_bad_axes(make):
    with pytest.raises(ValueError, match="axis"):
        make()


def test_joint_sizes():
    sizes = {j.kind: (j.nq, j.nv) for j in JOINTS + [jt.Fixed()]}
    assert sizes == {"revolute": (1, 1), "continuous": (1, 1), "prismatic": (1, 1), "planar": (4, 3),
                     "spherical": (4, 3), "free-flyer": (7, 6), "translation": (3, 3), "fixed": (0, 0)}
    for j in JOINTS:
        assert j.motion_subspace.shape == (6, j.nv)
        assert np.linalg.matrix_rank(j.motion_subspace) == j.nv


# ----------------------------------------------------------------------------- model-level maps

@pytest.fixture(scope="module")
def tree():
    return random_tree_model(0)


def test_random_tree_uses_every_joint_type(tree):
    kinds = {j.kind for j in tree.joints}
    assert set(ALL_MOVING_KINDS) <= kinds
    # branches: some joint has more than one child
    assert np.max(np.bincount(tree.parents + 1)) > 1
    # bodies fixed to moving bodies and to the world
    assert tree.nbodies > tree.njoints
    assert -1 in tree.body_joints


def test_model_sizes_and_indices(tree):
    assert tree.nq == sum(j.nq for j in tree.joints)
    assert tree.nv == sum(j.nv for j in tree.joints)
    assert_allclose(tree.idx_q, np.cumsum([0] + [j.nq for j in tree.joints])[:-1])
    assert_allclose(tree.idx_v, np.cumsum([0] + [j.nv for j in tree.joints])[:-1])
    assert tree.dof_joint.shape == (tree.nv,)
    for i, s in enumerate(tree.idx_v):
        assert np.all(tree.dof_joint[s : s + tree.joints[i].nv] == i)


def test_model_neutral(tree):
    q = tree.neutral()
    assert q.shape == (tree.nq,)
    for joint, s in zip(tree.joints, tree.idx_q):
        assert_allclose(q[s : s + joint.nq], joint.neutral())
    # at the neutral configuration every joint frame sits at its placement
    R_WJ, p_WJ = mb.kinematics.joint_world_poses(tree, q)
    for i, parent in enumerate(tree.parents):
        X_parent = np.eye(4) if parent < 0 else sp.pose_matrix(R_WJ[parent], p_WJ[parent])
        assert_allclose(sp.pose_matrix(R_WJ[i], p_WJ[i]), X_parent @ tree.joint_placements[i], atol=1e-12)


def test_model_integrate_difference_inverse(tree):
    rng = np.random.default_rng(5)
    for _ in range(10):
        q0 = tree.random_configuration(rng)
        v = np.concatenate([moderate_velocity(rng, j) for j in tree.joints])
        q1 = tree.integrate(q0, v)
        assert_allclose(tree.difference(q0, q1), v, atol=1e-12)
        assert_allclose(tree.integrate(q0, v, dt=0.5), tree.integrate(q0, 0.5 * v), atol=TOL)
        q2 = tree.random_configuration(rng)
        back = tree.integrate(q0, tree.difference(q0, q2))
        for joint, s in zip(tree.joints, tree.idx_q):
            assert_same_joint_configuration(joint, back[s : s + joint.nq], q2[s : s + joint.nq])


def test_model_maps_batched(tree):
    rng = np.random.default_rng(6)
    q0 = tree.random_configuration(rng, shape=(2, 3))
    q1 = tree.random_configuration(rng, shape=(2, 3))
    v = rng.standard_normal((2, 3, tree.nv))
    assert q0.shape == (2, 3, tree.nq)
    integ, diff = tree.integrate(q0, v), tree.difference(q0, q1)
    assert integ.shape == (2, 3, tree.nq) and diff.shape == (2, 3, tree.nv)
    for i in range(2):
        for k in range(3):
            assert_allclose(integ[i, k], tree.integrate(q0[i, k], v[i, k]), atol=1e-15)
            assert_allclose(diff[i, k], tree.difference(q0[i, k], q1[i, k]), atol=1e-15)
    # broadcasting one configuration against a batch of velocities
    assert tree.integrate(q0[0, 0], v).shape == (2, 3, tree.nq)


# ----------------------------------------------------------------------------- charts (Lie-group integration)

@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_chart_is_centred_and_stays_on_the_manifold(joint):
    rng = np.random.default_rng(21)
    q0 = random_joint_q(rng, joint, (5,))
    centred, q = joint.chart(q0, np.zeros((5, joint.nv))), joint.chart(q0, rng.uniform(-2.0, 2.0, (5, joint.nv)))
    for k in range(5):
        assert_same_joint_configuration(joint, centred[k], q0[k])
        assert_same_joint_configuration(joint, joint.normalize(q[k]), q[k])


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_chart_coordinates_invert_the_chart(joint):
    """``chart(q₀, chart_coordinates(q₀, q)) = q`` and ``chart_coordinates(q₀, chart(q₀, δ)) = δ`` for
    rotation angles below π, on batches."""
    rng = np.random.default_rng(23)
    q0 = random_joint_q(rng, joint, (5,))
    delta = rng.uniform(-1.0, 1.0, (5, joint.nv))
    q = joint.chart(q0, delta)
    np.testing.assert_allclose(joint.chart_coordinates(q0, q), delta, rtol=0.0, atol=1e-14)
    back = joint.chart(q0, joint.chart_coordinates(q0, q))
    for k in range(5):
        assert_same_joint_configuration(joint, back[k], q[k])


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_chart_rate_moves_the_configuration_with_the_aligned_velocity(joint):
    """Along δ(t) with δ̇ = chart_rate(δ, w), the configuration chart(q₀, δ) moves with body velocity
    v = Tᵀ w: its q̇ is configuration_rate(q, v) (central differences)."""
    rng = np.random.default_rng(22)
    q0, delta = random_joint_q(rng, joint), moderate_velocity(rng, joint)
    q = joint.chart(q0, delta)
    w = rng.standard_normal(joint.nv)
    T = joint.velocity_alignment(q)
    v = w if T is None else T.T @ w
    rate, h = joint.chart_rate(delta, w), 1e-6
    numeric = (joint.chart(q0, delta + h * rate) - joint.chart(q0, delta - h * rate)) / (2 * h)
    assert_allclose(numeric, joint.configuration_rate(q, v), atol=1e-9)  # central differences: ~1e-10


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_aligned_velocity_rate_is_alignment_times_acceleration_plus_coupling(joint):
    """``d/dt (T(q) v) = T (a + κ(v))`` along ``q(t) = integrate(q, v t)``, ``v(t) = v + a t``; T orthogonal."""
    rng = np.random.default_rng(23)
    q, v, a = random_joint_q(rng, joint), rng.standard_normal(joint.nv), rng.standard_normal(joint.nv)
    T = joint.velocity_alignment(q)
    if T is None:
        assert joint.velocity_coupling(v) is None and type(joint).chart is jt.Joint.chart
        return
    assert_allclose(T @ T.T, np.eye(joint.nv), atol=1e-14)
    aligned = lambda t: joint.velocity_alignment(joint.integrate(q, v * t)) @ (v + a * t)  # noqa: E731
    kappa = joint.velocity_coupling(v)
    h = 1e-6
    assert_allclose((aligned(h) - aligned(-h)) / (2 * h), T @ (a + (0.0 if kappa is None else kappa)), atol=5e-9)


def test_model_charts_assemble_the_joint_charts(tree):
    rng = np.random.default_rng(24)
    q0, delta = tree.random_configuration(rng, (3,)), 0.5 * rng.standard_normal((3, tree.nv))
    q, w = tree.chart(q0, delta), rng.standard_normal((3, tree.nv))
    T, rate, kappa = tree.velocity_alignment(q), tree.chart_rate(delta, w), tree.velocity_coupling(w)
    assert q.shape == (3, tree.nq) and T.shape == (3, tree.nv, tree.nv) and rate.shape == kappa.shape == (3, tree.nv)
    assert_allclose(T @ np.swapaxes(T, -1, -2), np.broadcast_to(np.eye(tree.nv), T.shape), atol=1e-14)
    for joint, iq, iv in zip(tree.joints, tree.idx_q, tree.idx_v):
        sq, sv = slice(iq, iq + joint.nq), slice(iv, iv + joint.nv)
        assert_allclose(q[:, sq], joint.chart(q0[:, sq], delta[:, sv]), atol=1e-15)
        assert_allclose(rate[:, sv], joint.chart_rate(delta[:, sv], w[:, sv]), atol=1e-15)
        block = joint.velocity_alignment(q[:, sq])
        assert_allclose(T[:, sv, sv], np.broadcast_to(np.eye(joint.nv), (3, joint.nv, joint.nv)) if block is None else block)
        coupling = joint.velocity_coupling(w[:, sv])
        assert_allclose(kappa[:, sv], 0.0 if coupling is None else coupling)
    assert not tree.is_vector_space
    assert mb.robots.load("double_pendulum").is_vector_space


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_chart_magnitude_is_the_size_of_q_in_each_chart_direction(joint):
    """|q| for angles and displacements (what an integrator of q itself would use), 1 rad for rotations."""
    q = random_joint_q(np.random.default_rng(25), joint, (4,))
    expected = {"free-flyer": np.concatenate([np.abs(q[:, :3]), np.ones((4, 3))], -1),
                "spherical": np.ones((4, 3)),
                "planar": np.concatenate([np.abs(q[:, :2]), np.ones((4, 1))], -1)}.get(joint.kind, np.abs(q))
    assert_allclose(joint.chart_magnitude(q), expected)


def test_model_chart_magnitude_assembles_the_joints(tree):
    q = tree.random_configuration(np.random.default_rng(26), (2,))
    magnitude = tree.chart_magnitude(q)
    assert magnitude.shape == (2, tree.nv)
    for joint, iq, iv in zip(tree.joints, tree.idx_q, tree.idx_v):
        assert_allclose(magnitude[:, iv : iv + joint.nv], joint.chart_magnitude(q[:, iq : iq + joint.nq]))


def test_random_configuration_within_limits_and_shapes():
    rng = np.random.default_rng(8)
    model = random_tree_model(1)
    for shape in [(), (5,), (2, 3)]:
        q = model.random_configuration(rng, shape=shape)
        assert q.shape == shape + (model.nq,)
        assert np.all(q >= model.lower) and np.all(q <= model.upper)
        # unbounded angles are drawn in [−π, π]
        for joint, s in zip(model.joints, model.idx_q):
            if joint.kind in ("revolute", "continuous") and not np.isfinite(model.lower[s]):
                assert np.all(np.abs(q[..., s]) <= np.pi)
        for joint, s in zip(model.joints, model.idx_q):
            block = q[..., s : s + joint.nq]
            if joint.kind == "planar":
                assert_allclose(np.hypot(block[..., 2], block[..., 3]), 1.0, atol=1e-15)
            for qs in quaternion_slices(joint):
                assert_allclose(np.linalg.norm(block[..., qs], axis=-1), 1.0, atol=1e-15)
    # bounded joints are sampled inside their finite limits, and seeding reproduces the draw
    assert np.any(np.isfinite(model.lower))
    assert_allclose(model.random_configuration(42), model.random_configuration(42))
    # draws of the bounded revolute/prismatic joints are spread over their range, not stuck at a value
    qs = model.random_configuration(rng, shape=(200,))
    scalar = np.zeros(model.nq, dtype=bool)
    scalar[[s for j, s in zip(model.joints, model.idx_q) if j.kind in ("revolute", "prismatic")]] = True
    bounded = scalar & np.isfinite(model.lower) & np.isfinite(model.upper)
    assert bounded.sum() >= 2
    spread = qs[:, bounded].max(axis=0) - qs[:, bounded].min(axis=0)
    assert np.all(spread > 0.5 * (model.upper - model.lower)[bounded])


def test_normalize(tree):
    rng = np.random.default_rng(9)
    q = tree.random_configuration(rng)
    scaled = q.copy()
    for joint, s in zip(tree.joints, tree.idx_q):
        for qs in quaternion_slices(joint):
            scaled[s + qs.start : s + qs.stop] *= 1.3
        if joint.kind == "planar":
            scaled[s + 2 : s + 4] *= 0.7
    with pytest.raises(ValueError, match="unit norm"):
        tree.integrate(scaled, np.zeros(tree.nv))
    assert_allclose(tree.normalize(scaled), q, atol=1e-15)


# ----------------------------------------------------------------------------- against Pinocchio

def both_models(pin, specs):
    """Our model and Pinocchio's for a chain given as ``(our joint, Pinocchio joint model)`` pairs."""
    rng = np.random.default_rng(10)
    b = mb.ModelBuilder("chain")
    pmodel = pin.Model()
    parent_id = 0
    for k, (ours, theirs) in enumerate(specs):
        X = sp.pose_from_xyz_rpy(rng.uniform(-1, 1, 3), rng.uniform(-np.pi, np.pi, 3))
        inertia = random_inertia(rng)
        b.add_body(f"b{k}", ours, parent=f"b{k - 1}" if k else None, placement=X, inertia=inertia)
        parent_id = pmodel.addJoint(parent_id, theirs, pin.SE3(X[:3, :3], X[:3, 3]), f"j{k}")
        pmodel.appendBodyToJoint(parent_id, pin.Inertia(inertia.mass, inertia.com, inertia.rotational), pin.SE3.Identity())
    return b.build(), pmodel


def assert_same_config(model, q, q_pin, atol=TOL):
    """Our ``q`` against a Pinocchio configuration, quaternions up to sign."""
    mapped = q_to_pinocchio(model, q)
    s_pin = 0
    for joint in model.joints:
        n = 2 if isinstance(joint, jt.Continuous) else joint.nq
        assert_same_joint_configuration(joint if not isinstance(joint, jt.Continuous) else jt.Revolute(),
                                        mapped[s_pin : s_pin + n], q_pin[s_pin : s_pin + n], atol=atol)
        s_pin += n


def assert_same_velocity(model, v, v_pin, atol=TOL):
    """Velocities are equal, except continuous angles: ours are plain angle differences (q is an
    angle in R), Pinocchio's are wrapped to (−π, π] (q is a point on the circle): equal modulo 2π."""
    diff = np.asarray(v) - np.asarray(v_pin)
    for joint, s in zip(model.joints, model.idx_v):
        if isinstance(joint, jt.Continuous):
            diff[s] = (diff[s] + np.pi) % (2 * np.pi) - np.pi
    assert_allclose(diff, np.zeros_like(diff), atol=atol)


def test_integrate_difference_match_pinocchio_solo12_free_flyer():
    pin = import_pinocchio()
    path = erd_urdf("solo_description/robots/solo12.urdf")
    model = mb.load_urdf(path, floating_base=True)
    pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
    assert model.joints[0].kind == "free-flyer"
    rng = np.random.default_rng(11)
    for _ in range(10):
        q0, q1 = model.random_configuration(rng), model.random_configuration(rng)
        v = rng.standard_normal(model.nv) * 2.0
        assert_same_config(model, model.integrate(q0, v), pin.integrate(pmodel, q0, v))
        assert_allclose(model.difference(q0, q1), pin.difference(pmodel, q0, q1), atol=1e-12)


def test_integrate_difference_match_pinocchio_every_joint_type():
    pin = import_pinocchio()
    model, pmodel = both_models(pin, [
        (jt.FreeFlyer(), pin.JointModelFreeFlyer()),
        (jt.Spherical(), pin.JointModelSpherical()),
        (jt.Planar(), pin.JointModelPlanar()),
        (jt.Revolute([0, 0, 1]), pin.JointModelRZ()),
        (jt.Prismatic([1, 0, 0]), pin.JointModelPX()),
        (jt.Translation(), pin.JointModelTranslation()),
        (jt.Continuous([0, 1, 0]), pin.JointModelRUBY()),
        (jt.Revolute([0.6, 0.8, 0]), pin.JointModelRevoluteUnaligned(np.array([0.6, 0.8, 0.0]))),
    ])
    assert model.nv == pmodel.nv
    assert pinocchio_nq(model) == pmodel.nq
    rng = np.random.default_rng(12)
    for _ in range(20):
        q0, q1 = model.random_configuration(rng), model.random_configuration(rng)
        v = rng.standard_normal(model.nv) * 2.0
        assert_same_config(model, model.integrate(q0, v), pin.integrate(pmodel, q_to_pinocchio(model, q0), v))
        assert_same_velocity(model, model.difference(q0, q1),
                             pin.difference(pmodel, q_to_pinocchio(model, q0), q_to_pinocchio(model, q1)), atol=1e-12)
    assert_same_config(model, model.neutral(), pin.neutral(pmodel))
    # the configuration maps round trip
    q = model.random_configuration(rng)
    assert_allclose(q_from_pinocchio(model, q_to_pinocchio(model, q)), q, atol=1e-15)


def test_integrate_difference_match_pinocchio_random_trees():
    pin = import_pinocchio()
    rng = np.random.default_rng(15)
    for seed in range(3):
        model = random_tree_model(seed)
        pmodel, _ = pinocchio_twin(pin, model)
        for _ in range(5):
            q0, q1 = model.random_configuration(rng), model.random_configuration(rng)
            v = rng.standard_normal(model.nv)
            q0_pin, q1_pin = q_to_pinocchio(model, q0), q_to_pinocchio(model, q1)
            assert_same_config(model, model.integrate(q0, v), pin.integrate(pmodel, q0_pin, v))
            assert_same_velocity(model, model.difference(q0, q1), pin.difference(pmodel, q0_pin, q1_pin), atol=1e-12)


def test_free_flyer_difference_small_steps_match_pinocchio():
    pin = import_pinocchio()
    model, pmodel = both_models(pin, [(jt.FreeFlyer(), pin.JointModelFreeFlyer())])
    rng = np.random.default_rng(13)
    worst = 0.0
    for _ in range(50):
        q0 = model.random_configuration(rng)
        v = 1.5e-4 * rng.standard_normal(model.nv)
        q1 = pin.integrate(pmodel, q0, v)
        worst = max(worst, np.abs(model.difference(q0, q1) - pin.difference(pmodel, q0, q1)).max() / 1.5e-4)
    # rounding of q (~1e-16) limits the relative accuracy to ~1e-12 here
    assert worst < 1e-10


# ----------------------------------------------------------------------------- input checks

@pytest.fixture(scope="module")
def solo():
    """A free-flyer base with revolute legs (Solo-like layout, built here so that no file is needed)."""
    rng = np.random.default_rng(16)
    b = mb.ModelBuilder("legged")
    b.add_body("base", jt.FreeFlyer(), inertia=random_inertia(rng))
    for leg in range(4):
        parent = "base"
        for k in range(3):
            name = f"leg{leg}_{k}"
            b.add_body(name, jt.Revolute(random_axis(rng)), parent=parent, inertia=random_inertia(rng),
                       placement=sp.pose_from_xyz_rpy(rng.uniform(-0.2, 0.2, 3)))
            parent = name
    return b.build()


def test_non_unit_quaternion_raises(tree):
    q = tree.neutral()
    s = tree.idx_q[0]
    bad = q.copy()
    bad[s + 3 : s + 7] = [0.0, 0.0, 0.0, 1.01]
    for call in (lambda: tree.integrate(bad, np.zeros(tree.nv)), lambda: tree.difference(bad, q),
                 lambda: tree.difference(q, bad), lambda: mb.forward_kinematics(tree, bad)):
        with pytest.raises(ValueError, match="unit norm"):
            call()
    # inside the tolerance the quaternion is accepted and treated as normalised
    ok = q.copy()
    ok[s + 3 : s + 7] = [0.0, 0.0, 0.0, 1.0 + 1e-8]
    assert_allclose(mb.forward_kinematics(tree, ok), mb.forward_kinematics(tree, q), atol=1e-15)
    # a planar (cos θ, sin θ) pair is checked too
    p = [j.kind for j in tree.joints].index("planar")
    bad = q.copy()
    bad[tree.idx_q[p] + 2] = 2.0
    with pytest.raises(ValueError, match="unit norm"):
        tree.integrate(bad, np.zeros(tree.nv))


def test_wrong_shapes_raise_naming_expected_shape(solo):
    q, v = solo.neutral(), np.zeros(solo.nv)
    with pytest.raises(ValueError, match=rf"\(\.\.\., {solo.nq}\)"):
        solo.integrate(q[:-1], v)
    with pytest.raises(ValueError, match=rf"\(\.\.\., {solo.nv}\)"):
        solo.integrate(q, np.zeros(solo.nv + 1))
    with pytest.raises(ValueError, match=rf"\(\.\.\., {solo.nq}\)"):
        solo.difference(q, np.zeros((2, solo.nq + 2)))
    with pytest.raises(ValueError, match=rf"\(\.\.\., {solo.nq}\)"):
        solo.integrate(1.0, v)
    with pytest.raises(ValueError, match=rf"\(\.\.\., {solo.nq}\)"):
        mb.forward_kinematics(solo, q[None, :-1])


@pytest.mark.parametrize("bad", [
    lambda n: np.array(["0"] * n),
    lambda n: np.zeros(n, dtype=complex),
    lambda n: np.array([object()] * n, dtype=object),
])
def test_wrong_dtype_raises(solo, bad):
    q, v = solo.neutral(), np.zeros(solo.nv)
    with pytest.raises(ValueError, match="dtype"):
        solo.integrate(bad(solo.nq), v)
    with pytest.raises(ValueError, match="dtype"):
        solo.integrate(q, bad(solo.nv))
    with pytest.raises(ValueError, match="dtype"):
        mb.forward_kinematics(solo, bad(solo.nq))


def test_integer_and_list_inputs_are_accepted(tree):
    v = [0] * tree.nv
    assert_allclose(tree.integrate(list(tree.neutral()), v), tree.neutral())


def test_nan_warns_and_propagates(solo):
    q, v = solo.neutral(), np.zeros(solo.nv)
    bad_q = q.copy()
    bad_q[4] = np.nan  # inside the base quaternion
    with pytest.warns(RuntimeWarning, match="NaN"):
        out = solo.integrate(bad_q, v)
    assert np.all(np.isnan(out[3:7]))
    bad_v = v.copy()
    bad_v[8] = np.nan
    with pytest.warns(RuntimeWarning, match="NaN"):
        out = solo.integrate(q, bad_v)
    assert np.isnan(out[9])
    with pytest.warns(RuntimeWarning, match="NaN"):
        out = solo.difference(bad_q, q)
    assert np.any(np.isnan(out))
    with pytest.warns(RuntimeWarning, match="NaN"):
        X = mb.forward_kinematics(solo, bad_q)
    assert np.all(np.isnan(X[..., :3, :]))


def test_nan_in_one_batch_row_leaves_other_rows_finite(solo):
    q = np.stack([solo.neutral(), solo.neutral()])
    q[1, 10] = np.nan
    with pytest.warns(RuntimeWarning):
        out = solo.integrate(q, np.zeros((2, solo.nv)))
    assert np.all(np.isfinite(out[0])) and np.isnan(out[1, 10])


# ----------------------------------------------------------------------------- immutability

def test_model_is_immutable(tree):
    for name in ("parents", "joint_placements", "body_joints", "body_placements", "lower", "upper", "gravity",
                 "idx_q", "idx_v", "spatial_inertias", "motion_subspaces", "ancestors"):
        array = getattr(tree, name)
        assert isinstance(array, np.ndarray) and not array.flags.writeable, name
        with pytest.raises(ValueError):
            array.flat[0] = 1
    for name in ("nq", "joints", "parents", "name", "gravity", "idx_q"):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(tree, name, 0)
    assert isinstance(tree.joints, tuple) and isinstance(tree.joint_names, tuple)
    assert isinstance(tree.body_names, tuple) and isinstance(tree.body_inertias, tuple)
    with pytest.raises(ValueError):
        tree.body_inertias[0].rotational[0, 0] = 1.0


def test_model_does_not_alias_builder_inputs():
    placement = np.eye(4)
    b = mb.ModelBuilder()
    b.add_body("a", jt.Revolute(), placement=placement)
    model = b.build()
    placement[0, 3] = 5.0
    assert model.joint_placements[0, 0, 3] == 0.0


# ----------------------------------------------------------------------------- builder

def test_builder_errors():
    b = mb.ModelBuilder()
    b.add_body("a", jt.Revolute())
    with pytest.raises(ValueError, match="duplicate body name 'a'"):
        b.add_body("a", jt.Revolute(), joint_name="other")
    with pytest.raises(ValueError, match="duplicate joint name 'a_joint'"):
        b.add_body("b", jt.Revolute(), joint_name="a_joint")
    with pytest.raises(ValueError, match="parent body 'nope'"):
        b.add_body("c", jt.Revolute(), parent="nope")
    with pytest.raises(ValueError, match=r"placement must have shape \(4, 4\)"):
        b.add_body("d", jt.Revolute(), parent="a", placement=np.eye(3))
    with pytest.raises(ValueError, match=r"limits .* shape \(1,\)"):
        b.add_body("e", jt.Revolute(), parent="a", lower=[0.0, 1.0], upper=[1.0, 2.0])
    with pytest.raises(TypeError, match="Joint"):
        b.add_body("f", "revolute", parent="a")
    # the failed calls added nothing
    model = b.build()
    assert model.body_names == ("a",) and model.joint_names == ("a_joint",)


def test_default_limits_bound_only_the_unit_norm_parts_and_are_shared_read_only():
    inf = np.inf
    expected = {jt.Revolute(): ([-inf], [inf]), jt.Prismatic(): ([-inf], [inf]), jt.Fixed(): ([], []),
                jt.Translation(): ([-inf] * 3, [inf] * 3), jt.Planar(): ([-inf, -inf, -1, -1], [inf, inf, 1, 1]),
                jt.Spherical(): ([-1] * 4, [1] * 4), jt.FreeFlyer(): ([-inf] * 3 + [-1] * 4, [inf] * 3 + [1] * 4)}
    for joint, (lower, upper) in expected.items():
        got = joint.default_limits
        assert got[0].tolist() == lower and got[1].tolist() == upper, joint.kind
        # made once per kind of joint, so no caller may change them
        assert got[0] is type(joint)().default_limits[0] and not got[0].flags.writeable and not got[1].flags.writeable


def test_builder_per_coordinate_numbers_and_lists_agree_and_errors_name_every_coordinate():
    def build(**dynamics):
        b = mb.ModelBuilder()
        b.add_body("a", jt.Spherical(), **dynamics)
        return b.build(check_inertia=False)

    numbers, lists = build(damping=0.5, armature=2), build(damping=[0.5] * 3, armature=np.full(3, 2.0))
    for name in ("damping", "friction", "effort_limit", "velocity_limit", "armature", "lower", "upper"):
        assert getattr(numbers, name).tobytes() == getattr(lists, name).tobytes(), name
    assert numbers.effort_limit.tolist() == [np.inf] * 3 and numbers.lower.tolist() == [-1.0] * 4
    # finite entries whose sum overflows are accepted
    assert build(damping=[1e308] * 3).damping.tolist() == [1e308] * 3
    for dynamics, message in ((dict(damping=-1.0), r"damping of joint 'a_joint' must not be negative, got \[-1.0, -1.0, -1.0\]"),
                              (dict(friction=np.nan), r"friction .* must be finite, got \[nan, nan, nan\]"),
                              (dict(armature=[0.0, np.inf, 1.0]), r"armature .* must be finite, got \[0.0, inf, 1.0\]"),
                              (dict(effort_limit=-np.inf), r"effort_limit .* must not be negative, got \[-inf, -inf, -inf\]"),
                              (dict(velocity_limit=[1.0, np.nan, 2.0]), r"velocity_limit .* numbers \(inf for none\)"),
                              (dict(damping=[1.0, 2.0]), r"damping .* must have shape \(3,\), got \(2,\)"),
                              (dict(damping="x"), r"damping .* must be numbers, got 'x'")):
        with pytest.raises(ValueError, match=message):
            build(**dynamics)


def test_builder_refuses_impossible_inertia():
    b = mb.ModelBuilder()
    b.add_body("a", jt.Revolute(), inertia=Inertia(1.0, np.zeros(3), np.diag([1.0, 1.0, 5.0])))
    with pytest.raises(ValueError, match="triangle"):
        b.build()
    assert b.build(check_inertia=False).njoints == 1


def test_builder_lumps_fixed_bodies():
    """joint_inertias[i] is the sum, in joint frame i, of the links fixed to body i (hand computation
    through 6×6 spatial inertias, independent of Inertia.__add__)."""
    rng = np.random.default_rng(14)
    I_a, I_b, I_c, I_w = (random_inertia(rng) for _ in range(4))
    X_wa = sp.pose_from_xyz_rpy([0.0, 0.0, 1.0], [0.1, 0.2, 0.3])
    X_ab = sp.pose_from_xyz_rpy([0.5, -0.2, 0.1], [0.5, -0.3, 1.2])
    X_bc = sp.pose_from_xyz_rpy([0.0, 0.4, -0.3], [-1.0, 0.2, 0.0])
    b = mb.ModelBuilder()
    b.add_body("w", inertia=I_w)  # fixed to the world
    b.add_body("a", jt.Revolute([0, 0, 1]), parent="w", placement=X_wa, inertia=I_a)
    b.add_body("b", parent="a", placement=X_ab, inertia=I_b)  # Fixed by default
    b.add_body("c", parent="b", placement=X_bc, inertia=I_c)
    b.add_body("d", jt.Prismatic([1, 0, 0]), parent="c", placement=np.eye(4))
    model = b.build()
    assert model.joint_names == ("a_joint", "d_joint")
    assert list(model.body_joints) == [-1, 0, 0, 0, 1]
    assert_allclose(model.body_placements[2], X_ab, atol=TOL)
    assert_allclose(model.body_placements[3], X_ab @ X_bc, atol=TOL)
    # the joint behind fixed bodies is placed relative to the moving body's joint frame
    assert_allclose(model.joint_placements[1], X_ab @ X_bc, atol=TOL)
    assert model.parents.tolist() == [-1, 0]

    def spatial_in(X, inertia):
        return sp.transform_inertia(X[:3, :3], X[:3, 3], inertia.spatial)

    expected = I_a.spatial + spatial_in(X_ab, I_b) + spatial_in(X_ab @ X_bc, I_c)
    lumped = model.joint_inertias[0]
    mass = expected[0, 0]
    com = np.array([expected[5, 1], expected[3, 2], expected[4, 0]]) / mass  # m [c]× block
    C = sp.skew(com)
    I_com = expected[3:, 3:] + mass * C @ C
    assert lumped.mass == pytest.approx(I_a.mass + I_b.mass + I_c.mass, rel=1e-15)
    assert_allclose(lumped.com, com, atol=1e-13)
    assert_allclose(lumped.rotational, I_com, atol=1e-13)
    assert_allclose(model.spatial_inertias[0], expected, atol=1e-13)
    # the massless prismatic body, and the world-fixed mass counted only in total_mass
    assert model.joint_inertias[1].mass == 0.0
    assert model.total_mass == pytest.approx(I_w.mass + I_a.mass + I_b.mass + I_c.mass, rel=1e-15)


def test_builder_hides_joint_carriers_and_keeps_the_equality_constraints():
    """A body added only to carry a joint (``hidden``) is left out of the model's bodies, its joint kept; the
    builder's equality constraints are the model's. A hidden name that is no body, a body with mass or one with
    geometries (which would name a body the model does not have) is refused, naming it and why."""
    b = mb.ModelBuilder("slider")
    b.add_body("carrier", jt.Prismatic([1, 0, 0]))
    b.add_body("arm", jt.Revolute([0, 0, 1]), parent="carrier", inertia=Inertia(1.0, [0.1, 0, 0], np.eye(3)))
    b.equality_constraints.append(mb.JointCoupling(None, "carrier_joint", offset=0.2))
    model = b.build(hidden={"carrier"})
    assert model.body_names == ("arm",) and model.joint_names == ("carrier_joint", "arm_joint")
    assert model.body_joints.tolist() == [1] and model.parents.tolist() == [-1, 0]
    assert model.equality_constraints == tuple(b.equality_constraints)
    # any collection of names, an iterator read once included
    assert b.build(hidden=iter(["carrier"])).body_names == b.build(hidden=["carrier"]).body_names == ("arm",)
    for wrong, why in (({"arm"}, r"'arm' \(mass 1\.0 kg\)"), ({"carrier", "nope"}, r"'nope' \(not a body\)")):
        with pytest.raises(ValueError, match=rf"^hidden must name massless bodies of the builder without geometries, "
                                             rf"got {why}$"):
            b.build(hidden=wrong)
    with pytest.raises(TypeError, match="hidden must be a collection of body names, got the string 'carrier'"):
        b.build(hidden="carrier")
    b.add_geometry(mb.Geometry("carrier", "visual", "sphere", np.eye(4), size=(0.1,)))
    with pytest.raises(ValueError, match=r"got 'carrier' \(has geometries\)$"):
        b.build(hidden={"carrier"})


def test_builder_default_joint_names_and_limits():
    b = mb.ModelBuilder("m")
    b.add_body("a", jt.Revolute(), lower=[-1.0], upper=[2.0])
    b.add_body("s", jt.Spherical(), parent="a", joint_name="ball")
    model = b.build()
    assert model.joint_names == ("a_joint", "ball")
    assert_allclose(model.lower, [-1.0, -1, -1, -1, -1])
    assert_allclose(model.upper, [2.0, 1, 1, 1, 1])
    assert model.name == "m"
    assert_allclose(model.gravity, [0, 0, -9.81])


def test_model_index_lookups(tree):
    assert tree.body_index(tree.body_names[3]) == 3
    assert tree.body_index(-1) == tree.nbodies - 1
    with pytest.raises(ValueError, match="unknown body 'nope'"):
        tree.body_index("nope")
    with pytest.raises(ValueError, match="out of range"):
        tree.body_index(tree.nbodies)
    assert tree.joint_index(tree.joint_names[2]) == 2
    with pytest.raises(ValueError, match="unknown joint"):
        tree.joint_index("nope")


def test_model_members_the_algorithms_read(tree):
    """One state's quick check, the unit-norm blocks of ``q``, a body's frame row by name or index and the
    check of external forces: the members the dynamics, kinematics and constrained modules ask the model for."""
    q, v = tree.neutral(), np.zeros(tree.nv)
    nan = np.full(tree.nv, np.nan)
    assert tree.is_one_state(q, v) and tree.is_one_state(q, nan, finite=False)
    assert not (tree.is_one_state(q[None], v) or tree.is_one_state(q, v[:-1]) or tree.is_one_state(q, nan))
    slices = tree.unit_norm_slices
    assert len(slices) == sum(joint.unit_norm is not None for joint in tree.joints) > 0
    assert all(stop - start in (2, 4) and np.linalg.norm(q[start:stop]) == 1.0 for start, stop in slices)
    np.testing.assert_array_equal(tree.body_frame_row(tree.body_names[3]), tree.body_frame_row(3))
    np.testing.assert_array_equal(tree.body_frame_row(np.int64(3)), tree.tree.bodies[3:4])
    with pytest.raises(ValueError, match="unknown body 'nope'"):
        tree.body_frame_row("nope")
    f_ext = tree.check_external_forces(np.zeros((2, tree.njoints, 6), dtype=int))
    assert f_ext.dtype == np.float64 and f_ext.shape == (2, tree.njoints, 6)
    with pytest.raises(ValueError, match=rf"^f_ext must have shape \(\.\.\., {tree.njoints}, 6\)"):
        tree.check_external_forces(np.zeros((tree.njoints, 3)))


def test_misspelled_names_suggest_the_close_ones():
    model = mb.robots.load("four_bar")
    with pytest.raises(ValueError, match=r"unknown body 'coupler_tp'; did you mean 'coupler_tip'") as info:
        model.body_index("coupler_tp")
    assert all(repr(name) in str(info.value) for name in model.body_names)
    with pytest.raises(ValueError, match=r"unknown joint 'crank'; did you mean 'crank_joint'\? moving joints are"):
        model.joint_index("crank")
    with pytest.raises(ValueError, match=r"unknown body 'zzz'; bodies are \['ground'"):
        model.body_index("zzz")


def test_with_gravity_returns_a_new_model_and_leaves_the_original():
    model = mb.robots.load("double_pendulum")
    q = np.array([0.3, -0.2])
    moon = model.with_gravity((0.0, 0.0, -1.62))
    assert isinstance(moon, mb.Model) and moon is not model
    np.testing.assert_array_equal(model.gravity, [0.0, 0.0, -9.81])
    np.testing.assert_array_equal(moon.gravity, [0.0, 0.0, -1.62])
    assert not moon.gravity.flags.writeable
    # g(q) is linear in the gravity vector; the mass matrix does not depend on it
    assert_allclose(mb.generalized_gravity(moon, q), 1.62 / 9.81 * mb.generalized_gravity(model, q), rtol=1e-14)
    assert_allclose(mb.mass_matrix(moon, q), mb.mass_matrix(model, q), rtol=0, atol=0)
    assert_allclose(mb.generalized_gravity(model.with_gravity(np.zeros(3)), q), 0.0, atol=0)


@pytest.mark.parametrize("bad", [(0.0, -9.81), (0.0, 0.0, np.inf), (0.0, np.nan, 0.0), "down", [[0, 0, -9.81]], None])
def test_with_gravity_refuses_bad_vectors(bad):
    model = mb.robots.load("double_pendulum")
    with pytest.raises(ValueError, match=r"gravity must be 3 finite numbers \(m/s², world frame\), got"):
        model.with_gravity(bad)


def test_empty_model():
    b = mb.ModelBuilder()
    b.add_body("only", inertia=mb.inertia.box(1.0, (1, 1, 1)))
    model = b.build()
    assert model.nq == 0 and model.nv == 0
    assert model.neutral().shape == (0,)
    assert model.random_configuration(0).shape == (0,)
    X = mb.forward_kinematics(model, np.zeros(0))
    assert X.shape == (1, 4, 4)
    assert_allclose(X[0], np.eye(4))


# ----------------------------------------------------------------------------- shipped robots

def test_robots_path():
    path = mb.robots.path("double_pendulum")
    assert os.path.isfile(path) and path.endswith("double_pendulum.urdf")
    assert mb.robots.path("double_pendulum.urdf") == path
    assert {"ball", "double_pendulum", "pendulum"} <= set(mb.robots.names())


def test_robots_load_ball_floating():
    model = mb.robots.load("ball", floating_base=True)
    assert model.nq == 7 and model.nv == 6
    assert model.joint_names == ("root_joint",)
    assert model.total_mass == pytest.approx(1.0)
    assert_allclose(model.joint_inertias[0].rotational, 0.004 * np.eye(3))


def test_robots_load_double_pendulum():
    model = mb.robots.load("double_pendulum")
    assert model.joint_names == ("shoulder", "elbow")
    assert all(isinstance(j, jt.Continuous) for j in model.joints)
    # hanging straight down the tip is 2 m below the base
    X = mb.forward_kinematics(model, model.neutral())
    assert_allclose(X[model.body_index("tip"), :3, 3], [0, 0, -2.0], atol=TOL)


def test_robots_unknown_name():
    with pytest.raises(ValueError, match="no shipped robot named 'nope'.*double_pendulum"):
        mb.robots.path("nope")
    with pytest.raises(ValueError):
        mb.robots.load("nope")


@pytest.mark.parametrize("joint", JOINTS, ids=JOINT_IDS)
def test_lone_joint_model_maps_are_the_joints_own(joint):
    """A model of one joint (a free body, a ball joint, ...) returns its joint's maps whole: the same
    values and shapes as the joint's, batches broadcast, and arrays that are not its arguments."""
    builder = mb.ModelBuilder("lone")
    builder.add_body("body", joint, inertia=mb.inertia.box(1.0, [0.1, 0.2, 0.3]))
    model = builder.build()
    rng = np.random.default_rng(31)
    q0, delta = model.random_configuration(rng, (4,)), 0.3 * rng.standard_normal((4, model.nv))
    w = rng.standard_normal(model.nv)  # one velocity for the whole batch
    q = model.chart(q0, delta)
    maps = {"integrate": (model.integrate(q0, w), joint.integrate(q0, np.broadcast_to(w, (4, model.nv)))),
            "difference": (model.difference(q0, q), joint.difference(q0, q)),
            "configuration_rate": (model.configuration_rate(q, w), joint.configuration_rate(q, np.broadcast_to(w, (4, model.nv)))),
            "chart": (q, joint.chart(q0, delta)),
            "chart_rate": (model.chart_rate(delta, np.broadcast_to(w, (4, model.nv))),
                           joint.chart_rate(delta, np.broadcast_to(w, (4, model.nv))))}
    for name, (got, want) in maps.items():
        assert got.shape == want.shape, name
        assert_allclose(got, want, atol=1e-15, err_msg=name)
    rate = model.chart_rate(delta[0], w)
    assert not np.shares_memory(rate, w) and not np.shares_memory(model.configuration_rate(q[0], w), w)
    T, kappa = model.velocity_alignment(q), model.velocity_coupling(np.broadcast_to(w, (4, model.nv)))
    block, coupling = joint.velocity_alignment(q), joint.velocity_coupling(np.broadcast_to(w, (4, model.nv)))
    assert T.shape == (4, model.nv, model.nv) and kappa.shape == (4, model.nv)
    assert_allclose(T, np.broadcast_to(np.eye(model.nv), T.shape) if block is None else block, atol=0)
    assert_allclose(kappa, 0.0 if coupling is None else coupling, atol=0)
