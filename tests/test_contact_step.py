"""The contact step's linear algebra on the tree's sparse factor (multibody.kernels.timestepping): ``M = Lᵀ L`` with the
branches' sparsity (RBDA §6.5), the rows ``W = L⁻ᵀ Jᵀ``, the Delassus matrix ``G = Wᵀ W = J M⁻¹ Jᵀ`` and the velocity
change ``M⁻¹ Jᵀ x = L⁻¹ W x``, each equal to the dense computation with NumPy's solve to 1e-13 on random states; and
the warm start's modes (``held_modes``), which solve a resting problem at once and leave the others to the solver."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.joints import FreeFlyer, Revolute
from multibody.contact import geometry_rows
from multibody.kernels import complementarity, configuration, crba, kinematics, rnea
from multibody.kernels import timestepping as ts

from conftest import random_inertia, random_placement, random_tree_model


def quadruped(collisions=False):
    """A free-flyer trunk with four legs of three revolute joints (Go1's tree); with ``collisions``, a box on the
    trunk and a sphere at each leg's end, placed off their bodies' frames."""
    rng = np.random.default_rng(5)
    b = mb.ModelBuilder("quadruped")
    b.add_body("trunk", FreeFlyer(), inertia=random_inertia(rng))
    if collisions:
        b.add_collision("trunk", "box", (0.4, 0.2, 0.1), random_placement(rng))
    for leg in range(4):
        parent = "trunk"
        for k, axis in enumerate(((1, 0, 0), (0, 1, 0), (0, 1, 0))):
            name = f"leg{leg}_{k}"
            b.add_body(name, Revolute(axis), parent=parent, placement=random_placement(rng), inertia=random_inertia(rng))
            parent = name
        if collisions:
            b.add_collision(parent, "sphere", (0.02,), random_placement(rng))
    return b.build()


def contact_rows(model, q, rng, count):
    """``count`` rows ``(count, nv)`` of the kind a step has: the relative velocity along a random unit direction at a
    random point of a random body against the ground (zero outside that body's support) or against another body
    (the union of two supports), and a dense row (a bilateral constraint's)."""
    tree = model.tree
    nj, nv = tree.joints.shape[0], model.nv
    ws = np.zeros(kinematics.workspace_size(nj, nv))
    kinematics.joint_placements(tree.joints, tree.reals, q, ws, None)
    # (Python receives a kernel's returned view as its whole workspace: read the poses there)
    pose = ws[: 12 * (nj + 1)].reshape((nj + 1, 12))
    J6 = np.zeros((6, nv))
    rows = np.zeros((count, nv))
    for r in range(count):
        if r % 4 == 3:
            rows[r] = rng.standard_normal(nv)
            continue
        point, direction = rng.standard_normal(3), rng.standard_normal(3)
        for side, sign in enumerate((1.0, -1.0)):
            if side == 1 and r % 4 != 2:
                break
            kinematics.jacobian_columns(tree.joints, tree.reals, pose, int(rng.integers(nj)), point, J6)
            rows[r] += sign * direction @ J6[:3]
    return rows


@pytest.mark.parametrize("which", ["quadruped", "random tree"])
def test_sparse_factor_rows_equal_the_dense_delassus_matrix(which):
    """On five random states each: ``factor_ltl``'s ``Lᵀ L`` is ``M``; the step's ``G`` (:func:`~multibody.kernels.
    timestepping.delassus` of :func:`~multibody.kernels.timestepping.metric_rows`) equals ``J M⁻¹ Jᵀ`` and
    :func:`~multibody.kernels.timestepping.metric_motion` equals ``M⁻¹ Jᵀ x``, to 1e-13 of their size; ``G`` is
    exactly symmetric, and a column of ``W`` is zero outside the support of its row."""
    model = quadruped() if which == "quadruped" else random_tree_model(3)
    rng = np.random.default_rng(11)
    nv, m = model.nv, 9
    parent = np.zeros(nv, dtype=np.int64)
    crba.coordinate_parents(model.tree.joints, parent)
    for _ in range(5):
        q = model.random_configuration(rng)
        M = mb.mass_matrix(model, q)
        L = M.copy()
        assert crba.factor_ltl(L, parent)
        lower = np.tril(np.where(ancestors(parent), L, 0.0))
        np.testing.assert_allclose(lower.T @ lower, M, rtol=0, atol=1e-13 * np.abs(M).max())
        J = contact_rows(model, q, rng, m)
        W = np.zeros((nv, m))
        ts.metric_rows(L, parent, J, W)
        G = np.zeros((m, m))
        ts.delassus(W, G)
        dense = J @ np.linalg.solve(M, J.T)
        np.testing.assert_allclose(G, dense, rtol=0, atol=1e-13 * np.abs(dense).max())
        assert np.array_equal(G, G.T)
        x, out = rng.standard_normal(m), np.zeros(nv)
        ts.metric_motion(L, parent, W, x, out)
        expected = np.linalg.solve(M, J.T @ x)
        np.testing.assert_allclose(out, expected, rtol=0, atol=1e-13 * np.abs(expected).max())
        # a row zero on a coordinate that supports none of its entries keeps its column of W zero there
        support = ancestors(parent).T @ (J.T != 0)
        assert not np.any(W[~support])


def ancestors(parent):
    """``A (nv, nv)``: ``A[k, i]`` true where ``i`` is ``k`` or an ancestor of ``k`` by ``λ``."""
    nv = len(parent)
    A = np.eye(nv, dtype=bool)
    for k in range(nv):
        i = parent[k]
        while i >= 0:
            A[k, i] = True
            i = parent[i]
    return A


# ----------------------------------------------------------------------------- the step's geometry and chart


@pytest.mark.parametrize("which", ["quadruped", "random tree"])
def test_aligned_blocks_equal_the_dense_velocity_alignment(which):
    """:func:`~multibody.kernels.timestepping.aligned_blocks` gives ``T(q) x`` and ``T(q)ᵀ x`` of
    :func:`~multibody.kernels.configuration.velocity_alignment`'s dense ``T`` exactly (each joint's block alone: the
    dense sums less their zero terms), on five random states of every joint kind."""
    model = quadruped() if which == "quadruped" else random_tree_model(3)
    tree, nv = model.tree, model.nv
    rng = np.random.default_rng(4)
    none = np.zeros(0)
    for _ in range(5):
        q, x = model.random_configuration(rng), rng.standard_normal(nv)
        T = np.zeros((nv, nv))
        configuration.velocity_alignment(tree.joints, tree.reals, np.zeros((0, 13)), q, none, none, none, T, none)
        for transpose, dense in ((False, T), (True, T.T)):
            # the dense product summed in the order of the coordinates, as the step's loop did
            expected = [sum((float(a) * float(b) for a, b in zip(row, x)), 0.0) for row in dense]
            out = np.full(nv, np.nan)
            ts.aligned_blocks(tree.joints, q, x, np.full((nv, nv), np.nan), out, transpose)
            np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("which", ["quadruped", "random tree"])
def test_the_bias_pass_gives_joint_motions_and_the_mass_matrix(which):
    """The step's one pass down the tree: :func:`~multibody.kernels.kinematics.placed_motions` on the poses and
    velocities of :func:`~multibody.kernels.rnea.forces` gives :func:`~multibody.kernels.kinematics.joint_motions`'s
    world poses (the reference point's row too) and body velocities exactly,
    :func:`~multibody.kernels.rnea.joint_torques` on its forces the bias ``h`` of ``mb.inverse_dynamics``, and
    :func:`~multibody.kernels.crba.placed_mass_matrix` on its joint poses ``mb.mass_matrix``, on five random states of
    every joint kind far from the world origin."""
    model = quadruped() if which == "quadruped" else random_tree_model(3)
    tree, nj, nv = model.tree, model.tree.joints.shape[0], model.nv
    rng = np.random.default_rng(9)
    none = np.zeros(0)
    for _ in range(5):
        q, v = model.random_configuration(rng), rng.standard_normal(nv)
        q[:3] += rng.uniform(-100.0, 100.0, 3)
        expected = np.zeros(kinematics.workspace_size(nj, nv))
        kinematics.joint_motions(tree.joints, tree.reals, q, v, expected, None)
        passes = np.zeros(rnea.workspace_size(nj, nv))
        local, velocities, _, forces = rnea.forces(tree.joints, tree.reals, q, v, none, none, passes)
        # (Python receives a kernel's returned views as its whole workspace: read the pass's arrays there)
        local, velocities = passes[: 12 * nj].reshape((nj, 12)), passes[12 * nj : 18 * nj].reshape((nj, 6))
        forces = passes[24 * nj : 30 * nj].reshape((nj, 6))
        placed = np.full(kinematics.workspace_size(nj, nv), np.nan)
        kinematics.placed_motions(tree.joints, tree.reals, q, local, velocities, placed)
        size = 12 * (nj + 1) + 6 * nj
        np.testing.assert_array_equal(placed[:size], expected[:size])
        h = np.full(nv, np.nan)
        rnea.joint_torques(tree.joints, tree.reals, none, forces, h)
        np.testing.assert_array_equal(h, mb.inverse_dynamics(model, q, v, np.zeros(nv)))
        M = np.full((nv, nv), np.nan)
        crba.placed_mass_matrix(tree.joints, tree.reals, M, passes)
        np.testing.assert_array_equal(M, mb.mass_matrix(model, q))


def test_geometry_origin_is_the_position_of_world_pose():
    """The broad phase's :func:`~multibody.kernels.timestepping.geometry_origin` equals the position of
    :func:`~multibody.kernels.timestepping.world_pose` exactly for every geometry (on the trunk and at the legs' ends,
    placed off their frames) of random states, as :func:`~multibody.kernels.kinematics.frame_position` equals
    :func:`~multibody.kernels.kinematics.frame_pose`'s position."""
    rng = np.random.default_rng(6)
    model = quadruped(collisions=True)
    tree, geometry = model.tree, geometry_rows(model)
    ws = np.zeros(kinematics.workspace_size(tree.joints.shape[0], model.nv))
    R, p = np.zeros((3, 3)), np.zeros(3)
    for _ in range(5):
        q = model.random_configuration(rng)
        q[:3] += rng.uniform(-100.0, 100.0, 3)
        kinematics.joint_motions(tree.joints, tree.reals, q, rng.standard_normal(model.nv), ws, None)
        pose = ws[: 12 * (tree.joints.shape[0] + 1)].reshape((-1, 12))
        for g in range(len(geometry)):
            ts.world_pose(pose, geometry, g, R, p)
            np.testing.assert_array_equal(ts.geometry_origin(pose, geometry, g), p)


# ----------------------------------------------------------------------------- the warm start's modes

MU = 0.5


def spd(rng, n, condition=10.0):
    """A random symmetric positive definite matrix with eigenvalues in [1, condition]."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return Q @ np.diag(np.geomspace(1.0, condition, n)) @ Q.T


def resting_problem():
    """A problem whose solution ``x`` has a bilateral row, a limit pressing, two contacts sticking inside their cones
    and one separating (``u_N = 1`` m/s): ``(G, c, kinds, starts, mu, x)``."""
    rng = np.random.default_rng(2)
    kinds = np.array([complementarity.BILATERAL, complementarity.UNILATERAL] + [complementarity.CONTACT] * 3)
    starts = np.array([0, 1, 2, 5, 8])
    mu = np.array([0.0, 0.0, MU, MU, MU])
    G = spd(rng, 11)
    x = np.array([0.3, 0.2, 1.0, 0.2, -0.1, 2.0, -0.3, 0.5, 0.0, 0.0, 0.0])
    u = np.zeros(11)
    u[8:] = (1.0, 0.3, -0.2)
    return G, u - G @ x, kinds, starts, mu, x


def held(G, c, kinds, starts, mu, warm):
    x = warm.copy()
    residual = ts.held_modes(G, c, kinds, starts, mu, 1e-12, x, np.zeros(len(c) ** 2 + 5 * len(c)))
    return residual, x


def test_held_modes_solve_a_resting_problem_from_a_nearby_warm_start():
    """From the solution perturbed by 1e-3 (each block keeping its mode), :func:`~multibody.kernels.timestepping.
    held_modes` returns the solution to 1e-12 and its residual within the tolerance, as the solver's iterations
    find it."""
    G, c, kinds, starts, mu, x = resting_problem()
    warm = x * (1 + 1e-3 * np.random.default_rng(3).standard_normal(len(x)))
    residual, found = held(G, c, kinds, starts, mu, warm)
    assert residual <= 1e-12
    np.testing.assert_allclose(found, x, rtol=0, atol=1e-12)
    solved, u = warm.copy(), np.zeros(len(c))
    status, _, _ = complementarity.solve(G, c, kinds, starts, mu, 1e-12, 1000, solved, u,
                                         np.zeros(complementarity.workspace_size(len(c))))
    assert status == complementarity.CONVERGED
    np.testing.assert_allclose(found, solved, rtol=0, atol=1e-11)


@pytest.mark.parametrize("case", ["sliding", "modes changed", "dependent rows"])
def test_held_modes_leave_the_warm_start_to_the_solver(case):
    """``inf`` and the warm start unchanged: a warm contact on its cone's boundary (sliding); a warm start whose
    separating contact is pressed in the solution (its held rows' solve pulls); and a box flat on the ground, whose
    four corners' twelve rows have rank 6 (the solver's proximal rule chooses among the solutions)."""
    G, c, kinds, starts, mu, x = resting_problem()
    warm = x.copy()
    if case == "sliding":
        warm[3:5] = MU * warm[2] * np.array([0.6, 0.8])
    elif case == "modes changed":
        warm[8:] = (1.0, 0.0, 0.0)
    else:
        builder = mb.ModelBuilder("box")
        builder.add_body("box", joint=FreeFlyer(), inertia=random_inertia(np.random.default_rng(4)))
        model = builder.build()
        q = model.neutral()
        J = np.concatenate([mb.jacobian(model, q, "box", point=[sx * 0.2, sy * 0.1, -0.05])[[2, 0, 1]]
                            for sx in (-1, 1) for sy in (-1, 1)])
        G = J @ np.linalg.solve(mb.mass_matrix(model, q), J.T)
        c = J @ np.array([0, 0, -9.81e-3, 0, 0, 0])
        kinds, starts, mu = np.full(4, complementarity.CONTACT), np.arange(0, 12, 3), np.full(4, MU)
        warm = np.tile([1.0, 0.0, 0.0], 4)
    residual, found = held(G, c, kinds, starts, mu, warm)
    assert residual == np.inf
    assert np.array_equal(found, warm)
