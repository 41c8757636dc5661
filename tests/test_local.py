"""The joint-coordinate recursions (``multibody.local``) that serve batches of many states.

They must equal the world-coordinate algorithms of ``multibody.dynamics`` state for state: on trees
of every joint type (turned revolute and prismatic frames, general joints in the middle of a tree,
levels whose joints share parents), with external forces, with one configuration shared by many
velocities, and across lane blocks. A singular articulated inertia must still be named.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody import dynamics, lanes, local
from conftest import random_tree_model
from dyn_helpers import erd_urdf


def local_test_model(name):
    if name.startswith("random_tree"):
        return random_tree_model(int(name[-1]))
    return mb.load_urdf(erd_urdf("talos_data/robots/talos_reduced.urdf"), floating_base=True)


MODELS = ["random_tree_0", "random_tree_1", "random_tree_2", "talos_floating"]


def random_lanes(model, rng, n):
    """``q, v, a (…, n)`` and ``f_ext (nj, 6, n)`` on lanes."""
    q = model.random_configuration(rng, (n,)).T.copy()
    v, a = rng.standard_normal((2, model.nv, n))
    f_ext = rng.standard_normal((model.njoints, 6, n))
    return q, v, a, f_ext


@pytest.mark.parametrize("model_name", MODELS)
def test_turned_frames_move_each_axis_onto_z(model_name):
    model = local_test_model(model_name)
    tree = model.local_tree
    for joint, P in zip(model.joints, tree.turn):
        assert_allclose(P.T @ P, np.eye(3), atol=1e-15)
        assert np.linalg.det(P) == pytest.approx(1.0)
        if isinstance(joint, (mb.joints.Revolute, mb.joints.Prismatic)):
            assert_allclose(P @ [0.0, 0.0, 1.0], joint.axis, atol=1e-15)
        else:
            assert_allclose(P, np.eye(3))


@pytest.mark.parametrize("axis", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0), (0.6, 0.0, -0.8), (1e-13, 0, -1)])
def test_turn_to_z_of_axes_along_and_against_z(axis):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    P = local._turn_to_z(axis)
    assert_allclose(P @ [0.0, 0.0, 1.0], axis, atol=1e-12)
    assert_allclose(P.T @ P, np.eye(3), atol=1e-15)
    assert np.linalg.det(P) == pytest.approx(1.0)


@pytest.mark.parametrize("model_name", MODELS)
def test_rnea_equals_the_world_coordinate_recursion(model_name):
    model = local_test_model(model_name)
    rng = np.random.default_rng(11)
    q, v, a, f_ext = random_lanes(model, rng, 9)
    for args in [(v, a, f_ext), (v, a, None), (v, None, None), (None, a, None), (None, None, None), (None, None, f_ext)]:
        tau, F = local.rnea(model, q, *args)
        R_WJ, p_OJ, xi, F_subtree = dynamics._rnea_forces(model, q, *args)
        scale = max(1.0, np.abs(tau).max())
        assert_allclose(tau, dynamics._joint_forces(model, xi, F_subtree), rtol=1e-12, atol=1e-12 * scale)
        # the force each joint transmits, in its joint frame
        assert_allclose(local.from_turned_frames(model.local_tree, F), lanes.inverse_transform_force(R_WJ, p_OJ, F_subtree),
                        rtol=1e-12, atol=1e-12 * max(1.0, np.abs(F).max()))


@pytest.mark.parametrize("model_name", MODELS)
def test_crba_equals_the_world_coordinate_crba(model_name):
    model = local_test_model(model_name)
    q = random_lanes(model, np.random.default_rng(16), 9)[0]
    M = local.crba(model, q)
    expected = dynamics._mass_matrix_crba(model, q)
    assert_allclose(M, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    assert_allclose(M, M.transpose(1, 0, 2), rtol=0, atol=0)


@pytest.mark.parametrize("model_name", MODELS)
def test_own_force_columns_by_gather_equal_the_product_and_unrelated_entries_are_zero(model_name):
    model = local_test_model(model_name)
    tree = model.local_tree
    rng = np.random.default_rng(18)
    kinds = set()
    for group in tree.groups:
        k = group.composite_columns.shape[0]
        x = rng.standard_normal((k, 10, 5))
        expected = np.matmul(group.composite_columns, x[:, None])
        # revolute and prismatic joints: six signed parameters
        assert group.composite_gather is not None or not isinstance(group.motion, str)
        if group.composite_gather is None:
            kinds.add("product")
            # a general joint: some entry of I S combines parameters (Ī_xx = a + b)
            assert np.any(np.count_nonzero(group.composite_columns.reshape(k, -1, 10), axis=-1) > 1)
            continue
        kinds.add("gather")
        index, weight = group.composite_gather
        assert_allclose((x.reshape(-1, 5)[index] * weight).reshape(expected.shape), expected, rtol=0, atol=0)
    assert "gather" in kinds
    # M entries that no level writes
    rows, columns = tree.unrelated
    related = model.dof_ancestor | model.dof_ancestor.T
    assert not related[rows, columns].any() and len(rows) == np.count_nonzero(~related)
    if len(rows):
        M = local.crba(model, random_lanes(model, rng, 3)[0])
        assert np.all(M[rows, columns] == 0.0)


def test_rigid_parameters_round_trip_and_turn_as_the_inertia_does():
    rng = np.random.default_rng(17)
    inertia = mb.inertia.box(2.0, (0.3, 0.2, 0.1)).transformed(mb.spatial.pose_from_xyz_rpy(rng.uniform(-1, 1, 3),
                                                                                             rng.uniform(-3, 3, 3)))
    I = inertia.spatial
    x = local.rigid_parameters(I)
    assert_allclose(local.rigid_inertia(x), I, atol=1e-15)
    # a turn about z and a shift along it, against the 6×6 congruence
    q = 0.7
    group = local.LocalGroup("revolute", *([None] * (len(local.LocalGroup._fields) - 1)))
    turned = local._turned_composite(group, local.JointMotion(cos=np.cos([[[q]]]), sin=np.sin([[[q]]])), x[None, :, None])
    R = mb.spatial.pose_from_xyz_rpy((0, 0, 0), (0, 0, q))[:3, :3]
    assert_allclose(local.rigid_inertia(turned[0, :, 0]), mb.spatial.transform_inertia(R, np.zeros(3), I), atol=1e-14)
    group = group._replace(motion="prismatic")
    shifted = local._turned_composite(group, local.JointMotion(shift=np.array([[q]])), x[None, :, None])
    assert_allclose(local.rigid_inertia(shifted[0, :, 0]), mb.spatial.transform_inertia(np.eye(3), [0, 0, q], I), atol=1e-14)


@pytest.mark.parametrize("model_name", MODELS)
def test_aba_equals_the_world_coordinate_sweeps(model_name):
    model = local_test_model(model_name)
    rng = np.random.default_rng(12)
    q, v, tau, f_ext = random_lanes(model, rng, 9)
    for forces in (f_ext, None):
        qdd = local.aba(model, q, v, tau, forces)
        expected = dynamics._aba(model, q, v, tau, forces)
        assert_allclose(qdd, expected, rtol=1e-11, atol=1e-11 * max(1.0, np.abs(expected).max()))
        # and it inverts RNEA
        back, _ = local.rnea(model, q, v, qdd, forces)
        assert_allclose(back, tau, rtol=1e-12, atol=1e-12)  # |τ| ~ 1: worst seen 1.7e-13 (Talos)


@pytest.mark.parametrize("model_name", MODELS[:3])
def test_articulated_inertias_move_to_the_parent_as_the_6x6_congruence_does(model_name):
    model = local_test_model(model_name)
    rng = np.random.default_rng(14)
    q = model.random_configuration(rng, (5,)).T.copy()
    for group, motion in zip(model.local_tree.groups, local.joint_motions(model.local_tree, q)):
        k = len(group.Y)
        G = rng.standard_normal((k, 5, 6, 6))
        M = G @ np.swapaxes(G, -1, -2)  # symmetric, (k, 5, 6, 6)
        by_columns = np.ascontiguousarray(np.moveaxis(M, 1, -1).transpose(2, 0, 1, 3))
        # the joint transforms X_J of each joint and state as poses (R, p): (k, 5, 3, 3), (k, 5, 3)
        if group.motion == "revolute":
            c, s = motion.cos[:, 0], motion.sin[:, 0]
            R = np.zeros((k, 5, 3, 3))
            R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
            p = np.zeros((k, 5, 3))
        elif group.motion == "prismatic":
            R, p = np.broadcast_to(np.eye(3), (k, 5, 3, 3)), np.zeros((k, 5, 3))
            p[..., 2] = motion.shift
        else:
            R, p = np.moveaxis(motion.R, -1, 1), np.moveaxis(motion.p, -1, 1)
        B = group.Y_T[:, None] @ mb.spatial.force_transform(R, p)  # λX_i* (k, 5, 6, 6)
        expected = B @ M @ np.swapaxes(B, -1, -2)
        moved = np.moveaxis(local._moved_to_parents(group, motion, by_columns), -1, 1)
        assert_allclose(moved, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max(), err_msg=str(group.motion))


@pytest.mark.parametrize("model_name", ["random_tree_1", "talos_floating"])
def test_public_functions_switch_to_joint_coordinates_for_many_states_and_agree_across_blocks(model_name):
    model = local_test_model(model_name)
    block = local.lane_block(model)
    n = block + 5  # a full block of the joint-coordinate recursions and a partial one
    assert local.suits((n,)) and not local.suits((local.MIN_STATES - 1,))
    rng = np.random.default_rng(13)
    q = model.random_configuration(rng, (n,))
    v, a = rng.standard_normal((2, n, model.nv))
    f = rng.standard_normal((n, model.njoints, 6))
    calls = {
        "inverse_dynamics": lambda q, v, a, f: mb.inverse_dynamics(model, q, v, a, f_ext=f),
        "bias_forces": lambda q, v, a, f: mb.bias_forces(model, q, v),
        "generalized_gravity": lambda q, v, a, f: mb.generalized_gravity(model, q),
        "joint_reaction_forces": lambda q, v, a, f: mb.joint_reaction_forces(model, q, v, a, f_ext=f),
        "forward_dynamics": lambda q, v, a, f: mb.forward_dynamics(model, q, v, a, f_ext=f),
        "mass_matrix": lambda q, v, a, f: mb.mass_matrix(model, q),
    }
    for what, call in calls.items():
        batched = call(q, v, a, f)
        for k in (0, block - 1, block, n - 1):
            single = call(q[k], v[k], a[k], f[k])  # one state: the world-coordinate algorithms
            assert_allclose(batched[k], single, rtol=1e-11, atol=1e-11 * max(1.0, np.abs(single).max()), err_msg=what)


def test_many_states_with_a_massless_joint_name_it():
    builder = mb.ModelBuilder("massless_leaf")
    builder.add_body("arm", joint=mb.joints.Revolute([0, 0, 1]), inertia=mb.inertia.box(1.0, (1, 0.1, 0.1)))
    builder.add_body("ghost", parent="arm", joint=mb.joints.Revolute([1, 0, 0]), joint_name="ghost_joint")
    model = builder.build()
    n = local.MIN_STATES
    q = model.random_configuration(np.random.default_rng(15), (n,))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(np.linalg.LinAlgError, match="ghost_joint"):
            mb.forward_dynamics(model, q, np.zeros((n, 2)), np.zeros((n, 2)))
