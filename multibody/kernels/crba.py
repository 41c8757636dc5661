"""Composite Rigid Body Algorithm: the joint-space inertia matrix ``M(q)``.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, Table 6.2, in joint
coordinates: each composite inertia and force column is expressed in its own joint frame and moved
to the parent's with the joint's pose, as Pinocchio's ``crba`` does, which then adds the joints' armature
to the diagonal, ``M += diag(armature)`` (as MuJoCo's ``mj_crb`` adds ``dof_armature`` to ``qM``).
"""

from __future__ import annotations

import numpy as np

from .layout import AXIS, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .spatial import (add10, dot6, force_to_parent, inertia_times, inertia_to_parent, nan_unless_finite, row10, row3,
                      row9, store_row)


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its pose in its parent (12) and its composite
    inertia (10); for :func:`inverse_mass_matrix` the factor of ``M`` and the coordinates' parents too."""
    return 22 * nj + nv * nv + nv


@njit(cache=True, error_model="numpy")
def mass_matrix(joints, reals, frames, q, x1, x2, x3, out, ws):
    """``M(q)`` (RBDA Table 6.2) plus ``diag(armature)`` into ``out (nv, nv)``: full and symmetric (kg, kg m,
    kg m²).

    ``q (nq,)``; ``frames``, ``x1``, ``x2``, ``x3`` are unused. Every entry of ``out`` is written:
    ``M_ij = 0`` where neither joint supports the other.
    """
    nj = joints.shape[0]
    pose = ws[: 12 * nj].reshape((nj, 12))
    for i in range(nj):
        # X_λ(i),i = X_T X_J(q_i)
        R, p = joint_pose(joints, reals, q, i)
        store_row(pose, i, 0, R)
        store_row(pose, i, 9, p)
    placed_mass_matrix(joints, reals, out, ws)
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def placed_mass_matrix(joints, reals, out, ws):
    """:func:`mass_matrix` (the composite-inertia passes of RBDA Table 6.2, plus ``diag(armature)``; kg, kg m, kg m²)
    into ``out (nv, nv)`` from the joints' poses in their parents already in ``ws[: 12 nj]`` (rows
    ``[R (9, row-major), p (3)]``, as :func:`mass_matrix` and :func:`multibody.kernels.rnea.forces` leave them), so
    that a step that has run one of those passes computes no joint transform again; ``ws[12 nj : 22 nj]`` takes the
    composite inertias."""
    nj = joints.shape[0]
    pose = ws[: 12 * nj].reshape((nj, 12))
    composite = ws[12 * nj : 22 * nj].reshape((nj, 10))
    for i in range(nj):
        # I^c_i = I_i
        store_row(composite, i, 0, row10(reals, i, INERTIA))
    n = out.shape[0]
    # coordinates on different branches do not couple: M_ij = 0 unless one joint supports the other
    for r in range(n):
        for c in range(n):
            out[r, c] = 0.0
    for i in range(nj - 1, -1, -1):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        I_c = row10(composite, i, 0)
        if parent >= 0:
            # I^c_λ(i) = I^c_λ(i) + λ(i)X*_i I^c_i ⁱX_λ(i)
            moved = inertia_to_parent(row9(pose, i, 0), row3(pose, i, 9), I_c)
            store_row(composite, parent, 0, add10(row10(composite, parent, 0), moved))
        for k in range(nv):
            col = iv + k
            # F = I^c_i S_i,k
            F = inertia_times(I_c, kinds.subspace_column(kind, axis, k))
            # H_ii = S_iᵀ F, computed once per pair so that the block is exactly symmetric
            for m in range(k + 1):
                h = dot6(kinds.subspace_column(kind, axis, m), F)
                out[iv + m, col] = h
                out[col, iv + m] = h
            # M_kk += armature_k
            out[col, col] += armature(reals, i, k)
            j = i
            while joints[j, PARENT] >= 0:
                # F = λ(j)X*_j F
                F = force_to_parent(row9(pose, j, 0), row3(pose, j, 9), F)
                j = joints[j, PARENT]
                kind_j, iv_j = joints[j, KIND], joints[j, IV]
                axis_j = row3(reals, j, AXIS)
                for m in range(joints[j, NV]):
                    # H_ji = S_jᵀ F ;  H_ij = H_jiᵀ
                    h = dot6(kinds.subspace_column(kind_j, axis_j, m), F)
                    out[iv_j + m, col] = h
                    out[col, iv_j + m] = h


# ----------------------------------------------------------------------------- sparse factorization

@njit(cache=True, error_model="numpy")
def coordinate_parents(joints, parent):
    """``λ(k)`` of each velocity coordinate into ``parent (nv,)`` (RBDA §6.5): the coordinate before k in
    its joint, else the last coordinate of the parent joint, ``-1`` at a root. ``M_ij`` can be non-zero
    only where one of i and j is an ancestor (by ``λ``) of the other."""
    for i in range(joints.shape[0]):
        iv, p = joints[i, IV], joints[i, PARENT]
        parent[iv] = joints[p, IV] + joints[p, NV] - 1 if p >= 0 else -1
        for k in range(1, joints[i, NV]):
            parent[iv + k] = iv + k - 1


@njit(cache=True, error_model="numpy")
def factor_ltl(H, parent):
    """``H = Lᵀ L`` in place (RBDA Table 6.3, the LTL factorization): ``L`` lower triangular with the
    sparsity of ``λ`` (``parent`` of :func:`coordinate_parents`), so that the tree's branches cause no
    fill-in. ``L`` overwrites the lower triangle where ``λ`` allows; other entries are left as they were.
    Returns False, leaving ``H`` partly factored, when ``H`` is not positive definite."""
    for k in range(H.shape[0] - 1, -1, -1):
        if not H[k, k] > 0.0:
            return False
        # L_kk = √H_kk ;  L_ki = H_ki / L_kk for the ancestors i of k
        H[k, k] = H[k, k] ** 0.5
        i = parent[k]
        while i >= 0:
            H[k, i] /= H[k, k]
            i = parent[i]
        # H_ij −= L_ki L_kj for the ancestors j ⪯ i of k
        i = parent[k]
        while i >= 0:
            j = i
            while j >= 0:
                H[i, j] -= H[k, i] * H[k, j]
                j = parent[j]
            i = parent[i]
    return True


@njit(cache=True, error_model="numpy")
def solve_lt(L, parent, X):
    """``X ← L⁻ᵀ X`` for ``X (nv, k)`` from the factor of :func:`factor_ltl` (RBDA §6.5, the first half of
    :func:`solve_ltl`): ``Lᵀ Y = X`` from the leaves to the root, one row operation per non-zero of ``L``. A
    column that is zero outside the support of a body (a contact's Jacobian row) stays zero outside it."""
    n, columns = X.shape[0], X.shape[1]
    for k in range(n - 1, -1, -1):
        # y_k = x_k / L_kk ;  x_i −= L_ki y_k for the ancestors i of k
        pivot = L[k, k]
        for c in range(columns):
            X[k, c] /= pivot
        i = parent[k]
        while i >= 0:
            factor = L[k, i]
            for c in range(columns):
                X[i, c] -= factor * X[k, c]
            i = parent[i]


@njit(cache=True, error_model="numpy")
def solve_l(L, parent, X):
    """``X ← L⁻¹ X`` for ``X (nv, k)`` from the factor of :func:`factor_ltl` (RBDA §6.5, the second half of
    :func:`solve_ltl`): ``L X = Y`` from the root to the leaves, one row operation per non-zero of ``L``."""
    n, columns = X.shape[0], X.shape[1]
    for k in range(n):
        # x_k = (y_k − Σ_{j ancestor of k} L_kj x_j) / L_kk
        j = parent[k]
        while j >= 0:
            factor = L[k, j]
            for c in range(columns):
                X[k, c] -= factor * X[j, c]
            j = parent[j]
        pivot = L[k, k]
        for c in range(columns):
            X[k, c] /= pivot


@njit(cache=True, error_model="numpy")
def solve_ltl(L, parent, X):
    """``X ← H⁻¹ X`` for ``X (nv, k)`` from the factor of :func:`factor_ltl` (RBDA §6.5): ``H⁻¹ = L⁻¹ L⁻ᵀ``,
    :func:`solve_lt` then :func:`solve_l`."""
    solve_lt(L, parent, X)
    solve_l(L, parent, X)


@njit(cache=True, error_model="numpy")
def inverse_mass_matrix(joints, reals, frames, q, x1, x2, x3, out, ws):
    """``M(q)⁻¹`` into ``out (nv, nv)``: full and symmetric (1/kg, 1/(kg m²), ...).

    CRBA's ``M`` (RBDA Table 6.2), factored as ``M = Lᵀ L`` with the tree's sparsity
    (:func:`factor_ltl`, RBDA Table 6.3), then ``M⁻¹ = L⁻¹ L⁻ᵀ`` by :func:`solve_ltl` on the identity,
    mirrored so that it is exactly symmetric. ``M`` not positive definite (a joint that moves no
    inertia) leaves NaN. ``q (nq,)``; ``frames``, ``x1``, ``x2``, ``x3`` are unused. Pinocchio:
    ``computeMinverse``.
    """
    n, nj = out.shape[0], joints.shape[0]
    M = ws[22 * nj : 22 * nj + n * n].reshape((n, n))
    parent = ws[22 * nj + n * n : 22 * nj + n * n + n].view(np.int64)
    coordinate_parents(joints, parent)
    mass_matrix(joints, reals, frames, q, x1, x2, x3, M, ws)
    factored = factor_ltl(M, parent)
    for r in range(n):
        for c in range(n):
            out[r, c] = 1.0 if r == c else 0.0
    if not factored:
        for r in range(n):
            for c in range(n):
                out[r, c] = np.nan
        return
    solve_ltl(M, parent, out)
    for r in range(n):
        for c in range(r):
            # the two triangles agree to rounding; their mean is exactly symmetric
            mean = 0.5 * (out[r, c] + out[c, r])
            out[r, c] = mean
            out[c, r] = mean
    nan_unless_finite(q, x1, x2, x3, out)
