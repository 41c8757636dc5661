"""The lane layout of the batched algorithms (``multibody.lanes``) and their processing in blocks.

Each lane primitive must equal its counterpart of ``multibody.spatial`` (components last) on the
same random data, after the layout change; the blocked evaluation of a batch larger than
``model.lane_block`` must equal the states evaluated one by one, including the last, partial block
and inputs that broadcast (one configuration for many velocities).
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody import lanes, local, spatial
from dyn_helpers import dynamics_calls, erd_urdf
from conftest import random_axis, random_inertia, random_placement, random_tree_model

RNG = np.random.default_rng(7)
N = 5  # states per lane array


def off_lanes(x):
    return lanes.from_lanes(x, (N,))


def lane_test_model(name, seed):
    """A random tree of all joint types, two trees side by side (several roots), or Talos on a free-flyer
    (deep, branched, several blocks)."""
    if name == "random_tree":
        return random_tree_model(seed)
    if name == "two_roots":
        return two_roots_model(seed)
    return mb.load_urdf(erd_urdf("talos_data/robots/talos_reduced.urdf"), floating_base=True)


def two_roots_model(seed):
    """An arm (revolute, then prismatic) and a floating ball with a spherical pendulum, both rooted in the
    world at random placements."""
    rng = np.random.default_rng(seed)
    b = mb.ModelBuilder(f"two_roots_{seed}")
    for name, joint, parent in [("arm", mb.joints.Revolute(random_axis(rng)), None),
                                ("ball", mb.joints.FreeFlyer(), None),
                                ("slider", mb.joints.Prismatic(random_axis(rng)), "arm"),
                                ("pendulum", mb.joints.Spherical(), "ball")]:
        b.add_body(name, joint, parent=parent, placement=random_placement(rng, reach=2.0), inertia=random_inertia(rng))
    return b.build()


def test_to_lanes_and_back_round_trip_with_batch_axes():
    x = RNG.standard_normal((2, 3, 4, 6))
    lane = lanes.to_lanes(x, 2)
    assert lane.shape == (4, 6, 6)
    assert_allclose(lane[:, :, 4], x[1, 1])
    assert_allclose(lanes.from_lanes(lane, (2, 3)), x)


@pytest.mark.parametrize("lane_shape, batch, expected", [((1,), (), ()), ((3, 1), (), (3,)), ((1,), (1,), (1,)),
                                                         ((2, 3, 1), (1, 1), (1, 1, 2, 3)), ((4,), (2, 2), (2, 2))])
def test_from_lanes_gives_contiguous_arrays_of_the_batch_shape_even_for_a_scalar_per_state(lane_shape, batch, expected):
    x = RNG.standard_normal(lane_shape[::-1]).T  # a transposed, strided view, as the lane algorithms return
    out = lanes.from_lanes(x, batch)
    assert out.shape == expected and out.flags.c_contiguous
    assert_allclose(out.reshape(-1), np.moveaxis(x, -1, 0).reshape(-1))


def test_to_lanes_keeps_one_lane_for_a_single_state_and_broadcasts_others():
    assert lanes.to_lanes(np.arange(3.0), 1, (5,)).shape == (3, 1)
    assert lanes.to_lanes(np.ones((1, 1, 3)), 1, (4, 2)).shape == (3, 1)
    x = np.arange(6.0).reshape(1, 2, 3)
    assert_allclose(lanes.to_lanes(x, 1, (4, 2)), np.tile(x[0].T, (1, 4)))


@pytest.mark.parametrize("name, ours, theirs, shapes", [
    ("matmul", lanes.matmul, lambda A, B: A @ B, [(3, 3), (3, 4)]),
    ("matvec", lanes.matvec, spatial.matvec, [(6, 6), (6,)]),
    ("cross", lanes.cross, spatial.cross, [(3,), (3,)]),
    ("motion_cross", lanes.motion_cross, spatial.motion_cross, [(6,), (6,)]),
    ("force_cross", lanes.force_cross, spatial.force_cross, [(6,), (6,)]),
    ("dot", lanes.dot, lambda a, b: np.sum(a * b, axis=-1), [(6,), (6,)]),
    ("motion_cross_matrix", lambda m, x: lanes.matvec(lanes.motion_cross_matrix(m), x), spatial.motion_cross,
     [(6,), (6,)]),
    ("bar_force_cross_matrix", lambda f, m: lanes.matvec(lanes.bar_force_cross_matrix(f), m),
     lambda f, m: spatial.force_cross(m, f), [(6,), (6,)]),
])
@pytest.mark.parametrize("lanes_per_array", [N, 1, lanes.ROW_BY_ROW])  # one lane: np.matmul; many: crosses by rows
def test_lane_primitive_equals_spatial(name, ours, theirs, shapes, lanes_per_array):
    args = [RNG.standard_normal((lanes_per_array, 2) + shape) for shape in shapes]
    lane_args = [np.moveaxis(x, 0, -1) for x in args]  # (2, *shape, N)
    assert_allclose(np.moveaxis(ours(*lane_args), -1, 0), theirs(*args), rtol=1e-14, atol=1e-14, err_msg=name)


@pytest.mark.parametrize("cross", ["motion_cross", "force_cross"])
def test_spatial_cross_products_by_rows_broadcast_a_single_lane(cross):
    one, many = RNG.standard_normal((3, 6, 1)), RNG.standard_normal((3, 6, lanes.ROW_BY_ROW))
    for a, b in ((one, many), (many, one)):
        expected = getattr(spatial, cross)(np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0))
        assert_allclose(np.moveaxis(getattr(lanes, cross)(a, b), -1, 0), expected, rtol=1e-14, atol=1e-14)


def test_cos_sin_equals_numpy_to_an_ulp_across_quadrants_and_magnitudes():
    quarter_turns = np.arange(-8, 9) * (np.pi / 2)
    x = np.concatenate([quarter_turns, np.nextafter(quarter_turns, np.inf), quarter_turns + np.pi / 4,
                        RNG.uniform(-4.0, 4.0, 4096), RNG.uniform(-1e5, 1e5, 65), [0.0, -0.0, 1e-300, 5e-324]])
    c, s = lanes.cos_sin(x.reshape(2, -1, 1))
    assert_allclose(c.ravel(), np.cos(x), rtol=0, atol=2.3e-16)
    assert_allclose(s.ravel(), np.sin(x), rtol=0, atol=2.3e-16)
    # beyond the reduction's range, and non-finite entries: NumPy's own
    for outside in ([1e7, 0.5], [np.nan, 0.5], [np.inf, 0.5]):
        with np.errstate(invalid="ignore"):
            assert_allclose(lanes.cos_sin(np.array(outside)), (np.cos(outside), np.sin(outside)))
    assert [y.shape for y in lanes.cos_sin(np.zeros((3, 0)))] == [(3, 0), (3, 0)]


def test_skew_and_quaternion_rotation_equal_spatial():
    w = RNG.standard_normal((N, 3))
    assert_allclose(off_lanes(lanes.skew(lanes.to_lanes(w, 1))), spatial.skew(w), atol=1e-15)
    quat = RNG.standard_normal((N, 4)) * 1.3  # not unit: both divide by |q|²
    assert_allclose(off_lanes(lanes.quat_to_rotation(lanes.to_lanes(quat, 1))), spatial.quat_to_rotation(quat), atol=1e-14)
    # a stack of joints on one lane (the single-configuration path, another formula) against the lanes'
    one = lanes.quat_to_rotation(quat[:3, :, None])
    assert one.shape == (3, 3, 3, 1)
    assert_allclose(one[..., 0], off_lanes(lanes.quat_to_rotation(lanes.to_lanes(quat, 1)))[:3], atol=1e-14)


def test_force_transforms_equal_spatial():
    R = spatial.quat_to_rotation(RNG.standard_normal((N, 4)))
    p, f = RNG.standard_normal((N, 3)), RNG.standard_normal((N, 6))
    R_l, p_l, f_l = lanes.to_lanes(R, 2), lanes.to_lanes(p, 1), lanes.to_lanes(f, 1)
    assert_allclose(off_lanes(lanes.transform_force(R_l, p_l, f_l)), spatial.transform_force(R, p, f), atol=1e-14)
    assert_allclose(off_lanes(lanes.inverse_transform_force(R_l, p_l, f_l)),
                    spatial.inverse_transform_force(R, p, f), atol=1e-14)


@pytest.mark.parametrize("batch", [(N,), ()], ids=["lanes", "one lane"])
def test_world_inertias_equal_the_spatial_transform_of_the_joint_frame_inertias(batch):
    model = random_tree_model(0)
    q = model.random_configuration(RNG, batch)
    R_WJ, p_WJ = mb.kinematics.joint_world_poses(model, q)
    expected = spatial.transform_inertia(R_WJ, p_WJ, model.spatial_inertias)
    world = lanes.world_inertias(*model.inertia_parameters, lanes.to_lanes(R_WJ, 3), lanes.to_lanes(p_WJ, 2))
    assert_allclose(lanes.from_lanes(world, batch), expected, rtol=1e-13, atol=1e-13)


def test_tree_sum_is_a_weighted_sum_over_the_leading_axis():
    weights = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    x = RNG.standard_normal((3, 2, 4))
    assert_allclose(lanes.tree_sum(weights, x), np.stack([x[0] + x[2], x[1] + x[2]]))


@pytest.mark.parametrize("lanes_per_array", [1, 4096])  # a matrix product, then level passes
def test_support_and_subtree_sums_equal_explicit_sums_on_both_paths(lanes_per_array):
    model = random_tree_model(4)
    x_joints = RNG.standard_normal((model.njoints, 6, lanes_per_array))
    x_dofs = RNG.standard_normal((model.nv, 6, lanes_per_array))
    support, subtree, _ = model.tree_sum_weights
    assert lanes.small_tree_sum(subtree, x_joints) == (lanes_per_array == 1)
    expected_support = np.stack([x_dofs[model.joint_support[j]].sum(axis=0) for j in range(model.njoints)])
    expected_subtree = np.stack([x_joints[model.descendants[j]].sum(axis=0) for j in range(model.njoints)])
    assert_allclose(mb.kinematics._support_sums(model, x_dofs), expected_support, rtol=1e-13, atol=1e-13)
    assert_allclose(mb.dynamics._subtree_sums(model, x_joints), expected_subtree, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("model_name", ["random_tree", "two_roots", "talos_floating"])
def test_the_tree_pass_of_one_lane_equals_that_of_many(model_name):
    """One lane takes the poses, ξ and the world inertias from one chain of Plücker poses; many lanes
    take homogeneous poses and the structured formulas."""
    model = lane_test_model(model_name, seed=2)
    q = model.random_configuration(np.random.default_rng(5), (N,))
    many = mb.dynamics._tree(model, lanes.to_lanes(q))
    many_world = mb.kinematics.world_poses(model, lanes.to_lanes(q))
    for k in range(N):
        one = mb.dynamics._tree(model, q[k][:, None])
        one_world = mb.kinematics.world_poses(model, q[k][:, None])
        for name, x, y in zip(one._fields + ("R_WJ", "p_WJ"), one + one_world, many + many_world):
            assert x.shape[-1] == 1, name
            assert_allclose(x[..., 0], y[..., k], rtol=1e-13, atol=1e-13, err_msg=name)


def test_concatenate_broadcasts_a_single_lane():
    one, many = RNG.standard_normal((2, 1)), RNG.standard_normal((3, 4))
    joined = lanes.concatenate([one, many], axis=0)
    assert_allclose(joined, np.concatenate([np.repeat(one, 4, axis=1), many]))


@pytest.mark.parametrize("model_name", ["random_tree", "talos_floating"])
def test_batches_larger_than_a_block_equal_single_calls(model_name):
    model = lane_test_model(model_name, seed=1)
    n = model.lane_block + 7  # one full block and a partial one
    rng = np.random.default_rng(3)
    q = model.random_configuration(rng, (n,))
    v, a = rng.standard_normal((2, n, model.nv))
    f = rng.standard_normal((n, model.njoints, 6))
    picks = [0, model.lane_block - 1, model.lane_block, n - 1]
    for what, fn in dynamics_calls(model).items():
        if what.startswith(("coriolis_matrix[lagrangian]", "mass_matrix[lagrangian]", "mass_matrix_derivative")):
            continue  # not computed on lanes
        batched = fn(q, v, a, f)
        assert batched.shape[0] == n, what
        for k in picks:
            single = fn(q[k], v[k], a[k], f[k])
            assert_allclose(batched[k], single, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(single).max()), err_msg=what)


def test_padded_lanes_repeat_the_last_state_to_an_odd_number_of_cache_lines():
    from multibody.kinematics import _PADDED_FROM, _padded_lanes
    n = 2 * _PADDED_FROM  # rows 8 KiB apart unpadded
    x, one = RNG.standard_normal((3, 4, n)), RNG.standard_normal((3, 1))
    padded, single, absent = _padded_lanes([x, one, None], n)
    assert padded.shape == (3, 4, n + 8) and (n + 8) % 16 == 8
    assert_allclose(padded[..., :n], x, rtol=0, atol=0)
    assert_allclose(padded[..., n:], np.repeat(x[..., -1:], 8, axis=-1), rtol=0, atol=0)
    assert single is one and absent is None  # a broadcast lane and a missing array stay as they are
    # already an odd number of cache lines, or too few lanes to matter: unchanged
    odd = RNG.standard_normal((2, n + 8))
    assert _padded_lanes([odd], n + 8)[0] is odd
    few = RNG.standard_normal((2, _PADDED_FROM - 16))
    assert _padded_lanes([few], _PADDED_FROM - 16)[0] is few


def test_a_padded_block_gives_back_only_the_callers_states():
    from multibody.kinematics import _in_blocks
    model = random_tree_model(2)
    n = 1024
    rng = np.random.default_rng(9)
    q = model.random_configuration(rng, (n,))
    seen = []

    def kernel(q_lanes):
        seen.append(q_lanes.shape[-1])
        return local.crba(model, q_lanes)

    M = _in_blocks(model, kernel, (n,), (q, 1), block=n)
    assert seen == [n + 8] and M.shape == (n, model.nv, model.nv)
    for k in (0, n - 1):
        assert_allclose(M[k], mb.mass_matrix(model, q[k]), rtol=1e-12, atol=1e-12)


def test_one_configuration_with_a_block_sized_batch_of_velocities():
    model = random_tree_model(2)
    n = model.lane_block + 3
    assert local.suits((n,))  # the joint-coordinate recursions, with one lane for q (multibody.local)
    rng = np.random.default_rng(4)
    q = model.random_configuration(rng)
    v, tau = rng.standard_normal((2, n, model.nv))
    a = mb.forward_dynamics(model, q, v, tau)
    assert a.shape == (n, model.nv)
    assert_allclose(a[-1], mb.forward_dynamics(model, q, v[-1], tau[-1]), rtol=1e-12, atol=1e-12)
    assert_allclose(mb.inverse_dynamics(model, q, v, a), tau, rtol=1e-9, atol=1e-9)
    assert_allclose(mb.bias_forces(model, q, v)[7], mb.bias_forces(model, q, v[7]), rtol=1e-12, atol=1e-12)
    C = mb.coriolis_matrix(model, q, v)
    assert C.shape == (n, model.nv, model.nv)
    assert_allclose(C[-1], mb.coriolis_matrix(model, q, v[-1]), rtol=1e-12, atol=1e-12)


def test_lane_block_shrinks_with_the_number_of_joints():
    small = mb.load_urdf(mb.robots.path("double_pendulum"))
    large = mb.load_urdf(erd_urdf("talos_data/robots/talos_reduced.urdf"), floating_base=True)
    assert small.lane_block > large.lane_block >= 128


@pytest.mark.parametrize("model_name", ["random_tree", "talos_floating"])
def test_mass_matrix_and_bias_from_one_tree_pass_equal_crba_and_rnea(model_name):
    model = lane_test_model(model_name, seed=5)
    rng = np.random.default_rng(6)
    n = model.lane_block + 5
    q = model.random_configuration(rng, (n,))
    v = rng.standard_normal((n, model.nv))
    M, h = mb.dynamics.mass_matrix_and_bias(model, q, v)
    assert_allclose(M, mb.mass_matrix(model, q), rtol=1e-13, atol=1e-12)
    assert_allclose(h, mb.bias_forces(model, q, v), rtol=1e-13, atol=1e-12)
    # one configuration, many velocities: M broadcast to every state
    M, h = mb.dynamics.mass_matrix_and_bias(model, q[0], v[:3])
    assert M.shape == (3, model.nv, model.nv)
    assert_allclose(M[2], mb.mass_matrix(model, q[0]), rtol=1e-13, atol=1e-12)
    assert_allclose(h[2], mb.bias_forces(model, q[0], v[2]), rtol=1e-13, atol=1e-12)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc behaviour")
def test_a_repeated_batched_call_does_not_page_fault_on_its_block_temporaries():
    # Without _raise_allocator_thresholds, glibc hands each block's temporaries back to the
    # operating system and this call faults about 5000 pages in again.
    resource = pytest.importorskip("resource")
    model = random_tree_model(0)
    rng = np.random.default_rng(8)
    n = 8 * model.lane_block
    q = model.random_configuration(rng, (n,))
    v, a = rng.standard_normal((2, n, model.nv))
    mb.inverse_dynamics(model, q, v, a)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    mb.inverse_dynamics(model, q, v, a)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before < 200


def test_one_large_block_in_a_fresh_process_does_not_page_fault_on_its_temporaries():
    # In a fresh process glibc still maps every temporary above 128 KiB anew (see
    # kinematics._raise_allocator_thresholds); a single block of the joint-coordinate RNEA then
    # faulted in about 4000 pages per call.
    pytest.importorskip("resource")
    script = """
import resource, numpy as np, multibody as mb
from conftest import random_axis, random_inertia, random_placement, random_tree_model
model = random_tree_model(0)
rng = np.random.default_rng(8)
n = mb.local.lane_block(model)
q = model.random_configuration(rng, (n,))
v, a = rng.standard_normal((2, n, model.nv))
mb.inverse_dynamics(model, q, v, a)
faults = []
for _ in range(3):  # the fewest of three calls: one may meet the interpreter's own allocations
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    mb.inverse_dynamics(model, q, v, a)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(min(faults))
"""
    tests = os.path.dirname(os.path.abspath(__file__))
    result = subprocess.run([sys.executable, "-c", script], cwd=tests, capture_output=True, text=True, check=True,
                            env={**os.environ, "PYTHONPATH": tests})
    assert int(result.stdout.split()[-1]) < 200
