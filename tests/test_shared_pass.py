"""A constrained step evaluates its constraints' body frames in the pass down the tree that gives
``M`` and ``h`` (``dynamics.mass_matrix_bias_and_frames``, ``Constraint.body_frames``), and small dense
linear algebra goes to LAPACK directly for one matrix (``multibody.linalg``).

Everything here is compared with the separate, long-standing computations: they do the same
arithmetic in another grouping, so the tolerances are a few hundred rounding errors.
"""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.constraints import CompiledRows
from multibody import dynamics, kinematics, linalg
from multibody.constrained import _ModelAtState
from multibody.spatial import pose_from_xyz_rpy

from conftest import random_placement, random_tree_model


@pytest.fixture(scope="module")
def tree():
    return random_tree_model(3)


def _frames(model, rng):
    """A frame on every fourth body (with an offset placement or none), the world, and a body fixed to it."""
    frames = [(name, random_placement(rng) if k % 2 else None) for k, name in enumerate(model.body_names[1::4])]
    return frames + [(None, random_placement(rng)), (model.body_names[0], None)]


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["single", "batch5", "batch2x3"])
def test_mass_matrix_bias_and_frames_equal_separate_calls(tree, batch):
    rng = np.random.default_rng(1)
    q, v = tree.random_configuration(rng, batch), rng.standard_normal(batch + (tree.nv,))
    frames = _frames(tree, rng)
    M, h, values = dynamics.mass_matrix_bias_and_frames(tree, q, v, frames)
    assert M.shape == batch + (tree.nv, tree.nv) and h.shape == batch + (tree.nv,)
    np.testing.assert_allclose(M, mb.mass_matrix(tree, q), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(h, mb.bias_forces(tree, q, v), rtol=1e-11, atol=1e-11)
    assert len(values) == len(frames)
    for (body, placement), value in zip(frames, values):
        expected = kinematics.frame_kinematics(tree, q, v, body, placement)
        for got, want in zip(value, expected):
            assert got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-11)


def test_mass_matrix_bias_and_frames_in_thread_shares(tree):
    """A batch is split into one share of states per thread; frames come back in state order."""
    rng = np.random.default_rng(2)
    n = 517
    q, v = tree.random_configuration(rng, (n,)), rng.standard_normal((n, tree.nv))
    frames = [(tree.body_names[-1], random_placement(rng))]
    _, _, [(R, p, J, J_dot_v)] = dynamics.mass_matrix_bias_and_frames(tree, q, v, frames)
    for k in (0, n // 2 - 1, n // 2, n // 2 + 1, n - 1):
        for got, want in zip((R[k], p[k], J[k], J_dot_v[k]), kinematics.frame_kinematics(tree, q[k], v[k], *frames[0])):
            np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-11)


def test_mass_matrix_bias_and_frames_checks_its_frames(tree):
    q, v = tree.neutral(), np.zeros(tree.nv)
    with pytest.raises(ValueError, match="placement must have shape"):
        dynamics.mass_matrix_bias_and_frames(tree, q, v, [(tree.body_names[1], np.eye(3))])
    with pytest.raises(ValueError, match="unknown body"):
        dynamics.mass_matrix_bias_and_frames(tree, q, v, [("no such body", None)])


def test_frame_kinematics_far_from_the_world_origin():
    """Jacobians and ``J̇v`` do not depend on where the body is: the pass works relative to the first
    joint's origin. (In world-origin Plücker coordinates, 20 km away, they were off by 2e-12 and
    4e-13; now they agree exactly, and positions to their own rounding, 4e-12 at 2e4 m.)"""
    model = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    rng = np.random.default_rng(3)
    q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
    placement = pose_from_xyz_rpy([0.05, -0.02, 0.1], [0.3, -0.2, 1.0])
    near = kinematics.frame_kinematics(model, q, v, "ball", placement)
    far_q = q.copy()
    far_q[:3] += [1e4, -2e4, 5e3]
    far = kinematics.frame_kinematics(model, far_q, v, "ball", placement)
    np.testing.assert_allclose(far[1] - far_q[:3], near[1] - q[:3], rtol=0, atol=1e-11)
    for got, want in ((far[0], near[0]), (far[2], near[2]), (far[3], near[3])):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)


def test_model_at_state_answers_only_for_its_state(tree):
    rng = np.random.default_rng(4)
    q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
    frames = [(tree.body_names[-1], random_placement(rng))]
    _, _, values = dynamics.mass_matrix_bias_and_frames(tree, q, v, frames)
    system = _ModelAtState(tree, q, v, frames, values)
    body, placement = frames[0]
    assert system.known_frame(q, v, body, placement) is values[0]
    assert system.known_frame(q, v, tree.body_index(body), placement.copy()) is values[0]  # same frame, named otherwise
    assert system.known_frame(q.copy(), v, body, placement) is None  # another array: maybe another state
    assert system.known_frame(q, None, body, placement) is None
    assert system.known_frame(q, v, body, None) is None  # another frame


def _every_body_constraint(model):
    """One of each built-in constraint that reads body frames, on a random tree (not all consistent)."""
    a, b = model.body_names[2], model.body_names[-1]
    return [mb.Distance(a, b, 0.7, point_a=[0.1, 0.0, 0.0]),
            mb.LoopClosure(b, None, kind="revolute", frame_a=pose_from_xyz_rpy([0, 0, 0.1], [0.2, 0, 0])),
            mb.PointOnSurface(a, lambda x: x[..., 2] - 0.3, point=[0.0, 0.1, 0.0]),
            mb.RollingSphere(model.body_names[1], 0.1, plane_normal=(0.1, 0.0, 1.0)),
            mb.KnifeEdge(b, point=[0.0, 0.0, 0.05]),
            mb.RollingSphere(model.body_names[1], 0.1, surface_velocity=lambda x, t: np.array([0.1, 0.0, 0.0]))]


@pytest.mark.parametrize("index", range(6), ids=["distance", "loop", "surface", "sphere", "knife", "moving sphere"])
def test_constrained_step_with_shared_frames_equals_separate_passes(tree, index):
    """The KKT step gives the same a, λ and rows as the constraints evaluated on their own: a compiled
    step for constraints with compiled rows (which compute their frames themselves), the NumPy step
    reading frames from the shared pass for those evaluated in Python, where every frame a constraint
    reads is one it declares."""
    constraint = _every_body_constraint(tree)[index]
    system = mb.ConstrainedSystem(tree, [constraint])
    if isinstance(constraint, CompiledRows) and not constraint.moving:
        assert system._compiled_step is not None and not system._body_frames
    else:
        assert system._compiled_step is None and system._body_frames  # the shared path is taken
    rng = np.random.default_rng(5 + index)
    q, v = tree.random_configuration(rng), rng.standard_normal(tree.nv)
    solution = system.solve(q, v)
    A, gamma = system.acceleration_level(q, v)  # each constraint on its own pass
    np.testing.assert_allclose(solution.A, A, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(solution.gamma, gamma, rtol=1e-10, atol=1e-10)
    M, h = mb.mass_matrix(tree, q), mb.bias_forces(tree, q, v)
    np.testing.assert_allclose(M @ solution.a + h, A.T @ solution.lam, rtol=1e-9, atol=1e-9)

    # Every frame evaluate reads is found among the shared ones.
    misses = []
    original = _ModelAtState.known_frame

    def spy(self, q_, v_, body, placement):
        found = original(self, q_, v_, body, placement)
        if found is None and q_ is self._q and v_ is self._v:
            misses.append((body, placement))
        return found

    _ModelAtState.known_frame = spy
    try:
        system.solve(q, v)
    finally:
        _ModelAtState.known_frame = original
    assert misses == []


def test_compiled_tree_holds_gravity_in_its_world_row_and_is_read_only():
    from multibody.tree import GRAVITY

    model = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    tree = model.tree
    np.testing.assert_array_equal(tree.reals[model.njoints, GRAVITY : GRAVITY + 3], model.gravity)
    assert not any(array.flags.writeable for array in (tree.joints, tree.reals, tree.bodies, tree.joint_frames))


# ----------------------------------------------------------------------------- multibody.linalg

@pytest.mark.parametrize("batch", [(), (4,), (2, 3)], ids=["one", "stack4", "stack2x3"])
def test_linalg_matches_numpy(batch):
    rng = np.random.default_rng(6)
    X = rng.standard_normal(batch + (5, 5))
    M = X @ np.swapaxes(X, -1, -2) + 0.5 * np.eye(5)
    rhs = rng.standard_normal(batch + (5, 3))
    np.testing.assert_allclose(linalg.solve(M, rhs), np.linalg.solve(M, rhs), rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("batch", [(), (3,)], ids=["one", "stack"])
def test_linalg_errors(batch):
    singular = np.broadcast_to(np.diag([1.0, 0.0, 2.0]), batch + (3, 3))
    with pytest.raises(np.linalg.LinAlgError):
        linalg.solve(singular, np.ones(batch + (3, 1)))
