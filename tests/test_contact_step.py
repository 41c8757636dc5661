"""The contact step's linear algebra on the tree's sparse factor (multibody.kernels.timestepping): ``M = Lᵀ L`` with the
branches' sparsity (RBDA §6.5), the rows ``W = L⁻ᵀ Jᵀ``, the Delassus matrix ``G = Wᵀ W = J M⁻¹ Jᵀ`` and the velocity
change ``M⁻¹ Jᵀ x = L⁻¹ W x``, each equal to the dense computation with NumPy's solve to 1e-13 on random states."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.joints import FreeFlyer, Revolute
from multibody.kernels import crba, kinematics
from multibody.kernels import timestepping as ts

from conftest import random_inertia, random_placement, random_tree_model


def quadruped():
    """A free-flyer trunk with four legs of three revolute joints (Go1's tree)."""
    rng = np.random.default_rng(5)
    b = mb.ModelBuilder("quadruped")
    b.add_body("trunk", FreeFlyer(), inertia=random_inertia(rng))
    for leg in range(4):
        parent = "trunk"
        for k, axis in enumerate(((1, 0, 0), (0, 1, 0), (0, 1, 0))):
            name = f"leg{leg}_{k}"
            b.add_body(name, Revolute(axis), parent=parent, placement=random_placement(rng), inertia=random_inertia(rng))
            parent = name
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
