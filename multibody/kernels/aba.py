"""Articulated Body Algorithm: forward dynamics.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, Table 7.1, in joint
coordinates: each body's velocity, articulated inertia ``I^A`` and bias force ``p^A`` are expressed
in its own joint frame and moved to the parent's with the joint's pose, as Pinocchio's ``aba`` does. The
joints' armature enters each joint's ``D = Sᵀ I^A S + diag(armature)`` (Pinocchio's ``aba``, which adds it
to ``StU``), so that ABA solves ``(M_bodies + diag(armature)) q̈ = τ − h``, the ``M`` of
:func:`multibody.kernels.crba.mass_matrix`.

Articulated inertias are 6×6 matrices acting on motions to give forces (linear rows and columns
first), kept as ``(nj, 6, 6)``. A joint's ``U = I^A S`` and ``U D⁻¹`` are kept by columns
(``U[k]`` is column ``k``), ``D = Sᵀ U`` and ``D⁻¹`` as the leading ``nv_i × nv_i`` block of a 6×6.
Per-joint entries are read by index (``Y[i, r, c]``), not through row views ``Y[i]`` (see
:func:`multibody.kernels.spatial.row3`).
"""

from __future__ import annotations

import math

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .spatial import (add6, compose_rotations, cross, dot6, force_cross, force_to_parent, inertia_times,
                      motion_cross, motion_to_child, nan_unless_finite, row10, row3, row6, row9, scale6, store_row,
                      sub6)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its pose in its parent (12), articulated inertia
    (36), ``U D⁻¹`` (36) and five 6-vectors (velocity, bias acceleration, bias force, acceleration,
    ``D⁻¹ u``); three 6×6 scratch blocks (``U``, ``D`` and its factor, ``D⁻¹``)."""
    return 114 * nj + 108


# ----------------------------------------------------------------------------- 6×6 helpers

@njit(cache=True, error_model="numpy")
def transpose3(A):
    """``Aᵀ`` of a 3×3 row-major 9-tuple."""
    return (A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8])


@njit(cache=True, error_model="numpy")
def times_skew(A, p):
    """``A [p]×``: row ``r`` is ``a_r × p``."""
    return cross((A[0], A[1], A[2]), p) + cross((A[3], A[4], A[5]), p) + cross((A[6], A[7], A[8]), p)


@njit(cache=True, error_model="numpy")
def skew_times(p, A):
    """``[p]× A``: column ``c`` is ``p × a_c``."""
    c0 = cross(p, (A[0], A[3], A[6]))
    c1 = cross(p, (A[1], A[4], A[7]))
    c2 = cross(p, (A[2], A[5], A[8]))
    return (c0[0], c1[0], c2[0], c0[1], c1[1], c2[1], c0[2], c1[2], c2[2])


@njit(cache=True, error_model="numpy")
def load_block(Y, i, r0, c0):
    """The 3×3 block ``Y[i, r0 : r0 + 3, c0 : c0 + 3]`` as a row-major 9-tuple."""
    return (Y[i, r0, c0], Y[i, r0, c0 + 1], Y[i, r0, c0 + 2],
            Y[i, r0 + 1, c0], Y[i, r0 + 1, c0 + 1], Y[i, r0 + 1, c0 + 2],
            Y[i, r0 + 2, c0], Y[i, r0 + 2, c0 + 1], Y[i, r0 + 2, c0 + 2])


@njit(cache=True, error_model="numpy")
def add_block(Y, i, r0, c0, A):
    """``Y[i, r0 : r0 + 3, c0 : c0 + 3] += A``."""
    for r in range(3):
        for c in range(3):
            Y[i, r0 + r, c0 + c] += A[3 * r + c]


@njit(cache=True, error_model="numpy")
def add_block_transposed(Y, i, r0, c0, A):
    """``Y[i, r0 : r0 + 3, c0 : c0 + 3] += Aᵀ``."""
    for r in range(3):
        for c in range(3):
            Y[i, r0 + r, c0 + c] += A[3 * c + r]


@njit(cache=True, error_model="numpy")
def rigid_to_matrix(I, Y, i):
    """``Y[i] = [[m 1, −[h]×], [[h]×, Ī]]``: the 6×6 matrix of the inertia 10-tuple ``I`` (RBDA
    eq. 2.63)."""
    m, hx, hy, hz = I[0], I[1], I[2], I[3]
    rows = ((m, 0.0, 0.0, 0.0, hz, -hy),
            (0.0, m, 0.0, -hz, 0.0, hx),
            (0.0, 0.0, m, hy, -hx, 0.0),
            (0.0, -hz, hy, I[4], I[5], I[6]),
            (hz, 0.0, -hx, I[5], I[7], I[8]),
            (-hy, hx, 0.0, I[6], I[8], I[9]))
    for r in range(6):
        for c in range(6):
            Y[i, r, c] = rows[r][c]


@njit(cache=True, error_model="numpy")
def matrix_times(Y, i, m):
    """``Y[i] m`` for 6×6 matrices ``Y`` and a 6-tuple ``m``."""
    return (dot6((Y[i, 0, 0], Y[i, 0, 1], Y[i, 0, 2], Y[i, 0, 3], Y[i, 0, 4], Y[i, 0, 5]), m),
            dot6((Y[i, 1, 0], Y[i, 1, 1], Y[i, 1, 2], Y[i, 1, 3], Y[i, 1, 4], Y[i, 1, 5]), m),
            dot6((Y[i, 2, 0], Y[i, 2, 1], Y[i, 2, 2], Y[i, 2, 3], Y[i, 2, 4], Y[i, 2, 5]), m),
            dot6((Y[i, 3, 0], Y[i, 3, 1], Y[i, 3, 2], Y[i, 3, 3], Y[i, 3, 4], Y[i, 3, 5]), m),
            dot6((Y[i, 4, 0], Y[i, 4, 1], Y[i, 4, 2], Y[i, 4, 3], Y[i, 4, 4], Y[i, 4, 5]), m),
            dot6((Y[i, 5, 0], Y[i, 5, 1], Y[i, 5, 2], Y[i, 5, 3], Y[i, 5, 4], Y[i, 5, 5]), m))


@njit(cache=True, error_model="numpy")
def block_times(Y, i, c0, x):
    """``Y[i, :, c0 : c0 + 3] x`` for 6×6 matrices ``Y`` and a 3-vector ``x``: ``Y[i] S`` for a subspace
    column ``S`` that is zero outside those three entries (a revolute or a prismatic joint)."""
    return (Y[i, 0, c0] * x[0] + Y[i, 0, c0 + 1] * x[1] + Y[i, 0, c0 + 2] * x[2],
            Y[i, 1, c0] * x[0] + Y[i, 1, c0 + 1] * x[1] + Y[i, 1, c0 + 2] * x[2],
            Y[i, 2, c0] * x[0] + Y[i, 2, c0 + 1] * x[1] + Y[i, 2, c0 + 2] * x[2],
            Y[i, 3, c0] * x[0] + Y[i, 3, c0 + 1] * x[1] + Y[i, 3, c0 + 2] * x[2],
            Y[i, 4, c0] * x[0] + Y[i, 4, c0 + 1] * x[1] + Y[i, 4, c0 + 2] * x[2],
            Y[i, 5, c0] * x[0] + Y[i, 5, c0 + 1] * x[1] + Y[i, 5, c0 + 2] * x[2])


@njit(cache=True, error_model="numpy")
def column(X, i, k):
    """Column ``k`` of joint i's ``X`` kept by columns (``X[i, k]``), as a 6-tuple."""
    return (X[i, k, 0], X[i, k, 1], X[i, k, 2], X[i, k, 3], X[i, k, 4], X[i, k, 5])


@njit(cache=True, error_model="numpy")
def subspace_transpose_times(kind, axis, nv, f):
    """``Sᵀ f`` as a 6-tuple (zero past ``nv``): the joint's share of the force ``f`` (joint frame)."""
    y0 = dot6(kinds.subspace_column(kind, axis, 0), f) if nv > 0 else 0.0
    y1 = dot6(kinds.subspace_column(kind, axis, 1), f) if nv > 1 else 0.0
    y2 = dot6(kinds.subspace_column(kind, axis, 2), f) if nv > 2 else 0.0
    y3 = dot6(kinds.subspace_column(kind, axis, 3), f) if nv > 3 else 0.0
    y4 = dot6(kinds.subspace_column(kind, axis, 4), f) if nv > 4 else 0.0
    y5 = dot6(kinds.subspace_column(kind, axis, 5), f) if nv > 5 else 0.0
    return (y0, y1, y2, y3, y4, y5)


@njit(cache=True, error_model="numpy")
def articulated_to_parent(R, p, Y, i, parent):
    """``Y[parent] += ᴾX_C* Y[i] ᶜX_P`` for an articulated inertia ``Y[i]`` about the child frame C,
    with ``X_PC = (R, p)`` (RBDA eq. 2.66, which holds for any symmetric 6×6 inertia).

    With ``ᶜX_P = diag(Rᵀ, Rᵀ) [[1, −[p]×], [0, 1]]`` and ``Y[i] = [[A, B], [Bᵀ, C]]``, after the
    rotation ``A' = R A Rᵀ``, ``B' = R B Rᵀ``, ``C' = R C Rᵀ`` the shift to P gives
    ``[[A', B' − A'[p]×], [·ᵀ, C' + [p]× (B' − A'[p]×) − B'ᵀ [p]×]]``.
    """
    Rt = transpose3(R)
    A = compose_rotations(compose_rotations(R, load_block(Y, i, 0, 0)), Rt)
    B = compose_rotations(compose_rotations(R, load_block(Y, i, 0, 3)), Rt)
    C = compose_rotations(compose_rotations(R, load_block(Y, i, 3, 3)), Rt)
    # B_P = B' − A' [p]×
    A_p = times_skew(A, p)
    B_P = (B[0] - A_p[0], B[1] - A_p[1], B[2] - A_p[2], B[3] - A_p[3], B[4] - A_p[4], B[5] - A_p[5],
           B[6] - A_p[6], B[7] - A_p[7], B[8] - A_p[8])
    # C_P = C' + [p]× B_P − B'ᵀ [p]×
    pB = skew_times(p, B_P)
    Bp = times_skew(transpose3(B), p)
    C_P = (C[0] + pB[0] - Bp[0], C[1] + pB[1] - Bp[1], C[2] + pB[2] - Bp[2],
           C[3] + pB[3] - Bp[3], C[4] + pB[4] - Bp[4], C[5] + pB[5] - Bp[5],
           C[6] + pB[6] - Bp[6], C[7] + pB[7] - Bp[7], C[8] + pB[8] - Bp[8])
    add_block(Y, parent, 0, 0, A)
    add_block(Y, parent, 0, 3, B_P)
    add_block_transposed(Y, parent, 3, 0, B_P)
    add_block(Y, parent, 3, 3, C_P)


@njit(cache=True, error_model="numpy")
def invert_symmetric(n, D, D_inv):
    """``D_inv[:n, :n] = D⁻¹`` for a symmetric positive definite ``D[:n, :n]`` (its lower triangle is
    read), by ``D = L diag(d) Lᵀ`` with ``L`` unit lower triangular, which overwrites the lower triangle
    of ``D`` (pivots ``d`` on its diagonal). A pivot that is not positive (a joint that moves no
    inertia) makes every entry NaN, without raising."""
    singular = False
    for j in range(n):
        # d_j = D_jj − Σ_k L_jk² d_k
        d = D[j, j]
        for k in range(j):
            d -= D[j, k] * D[j, k] * D[k, k]
        D[j, j] = d
        if not d > 0.0:
            singular = True
            d = 1.0
        for r in range(j + 1, n):
            # L_rj = (D_rj − Σ_k L_rk L_jk d_k) / d_j
            s = D[r, j]
            for k in range(j):
                s -= D[r, k] * D[j, k] * D[k, k]
            D[r, j] = s / d
    for c in range(n):
        # column c of D⁻¹: L y = e_c, then Lᵀ x = diag(d)⁻¹ y (each in place in the column)
        for r in range(n):
            y = 1.0 if r == c else 0.0
            for k in range(r):
                y -= D[r, k] * D_inv[k, c]
            D_inv[r, c] = y
        for r in range(n - 1, -1, -1):
            x = D_inv[r, c] / D[r, r] if not singular else math.nan
            for k in range(r + 1, n):
                x -= D[k, r] * D_inv[k, c]
            D_inv[r, c] = x


@njit(cache=True, error_model="numpy")
def factor_joint(kind, axis, nv, reals, IA, i, U, D, D_inv, U_D_inv):
    """For joint i of articulated inertia ``IA[i]`` (RBDA Table 7.1): ``U = I^A S`` (into ``U``, by
    columns), ``D = Sᵀ U + diag(armature)`` (the armature of joint i's coordinates in ``reals``), ``D⁻¹`` (into ``D_inv``; ``D`` is overwritten), ``U D⁻¹`` (into
    ``U_D_inv[i]``, by columns), and ``I^a = I^A − U D⁻¹ Uᵀ`` in place of ``IA[i]``."""
    if nv == 1:
        # one coordinate (revolute, prismatic): D is a scalar
        s = kinds.subspace_column(kind, axis, 0)
        # S is the axis in three rows: U = I^A S reads three columns
        U_0 = block_times(IA, i, kinds.axis_rows(kind), axis)
        # D = Sᵀ U + armature
        D_0 = dot6(s, U_0) + armature(reals, i, 0)
        d_inv = 1.0 / D_0 if D_0 > 0.0 else math.nan
        UD_0 = scale6(d_inv, U_0)
        for r in range(6):
            U[0, r] = U_0[r]
            U_D_inv[i, 0, r] = UD_0[r]
            for c in range(6):
                IA[i, r, c] -= UD_0[r] * U_0[c]
        D_inv[0, 0] = d_inv
        return
    for k in range(nv):
        # U = I^A S
        U_k = matrix_times(IA, i, kinds.subspace_column(kind, axis, k))
        for r in range(6):
            U[k, r] = U_k[r]
    for m in range(nv):
        s = kinds.subspace_column(kind, axis, m)
        for k in range(m + 1):
            # D = Sᵀ U
            D[m, k] = dot6(s, (U[k, 0], U[k, 1], U[k, 2], U[k, 3], U[k, 4], U[k, 5]))
        # D_mm += armature_m
        D[m, m] += armature(reals, i, m)
    invert_symmetric(nv, D, D_inv)
    for k in range(nv):
        for r in range(6):
            # (U D⁻¹)_k = Σ_m U_m (D⁻¹)_mk
            x = 0.0
            for m in range(nv):
                x += U[m, r] * D_inv[m, k]
            U_D_inv[i, k, r] = x
    for r in range(6):
        for c in range(6):
            # I^a = I^A − U D⁻¹ Uᵀ
            x = IA[i, r, c]
            for k in range(nv):
                x -= U_D_inv[i, k, r] * U[k, c]
            IA[i, r, c] = x


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy")
def forward_dynamics(joints, reals, frames, q, v, tau, f_ext, out, ws):
    """Accelerations ``q̈`` (RBDA Table 7.1) into ``out[0] (nv,)``: m/s² or rad/s² per coordinate.

    ``q (nq,)``, ``v, tau (nv,)`` (length 0: zero), ``f_ext (6 nj,)`` (one force per joint on the
    body it moves, in its frame, ``[f; n]``) or empty. Gravity enters as the world's acceleration
    ``a₀ = [−g; 0]``. A joint that moves no inertia (``D`` not positive definite) leaves NaN in
    ``out``. ``frames`` is unused.
    """
    nj = joints.shape[0]
    pose = ws[: 12 * nj].reshape((nj, 12))
    articulated = ws[12 * nj : 48 * nj].reshape((nj, 6, 6))
    U_D_inv = ws[48 * nj : 84 * nj].reshape((nj, 6, 6))
    vel = ws[84 * nj : 90 * nj].reshape((nj, 6))
    bias = ws[90 * nj : 96 * nj].reshape((nj, 6))
    pA = ws[96 * nj : 102 * nj].reshape((nj, 6))
    acc = ws[102 * nj : 108 * nj].reshape((nj, 6))
    w = ws[108 * nj : 114 * nj].reshape((nj, 6))
    scratch = ws[114 * nj : 114 * nj + 108].reshape((3, 6, 6))
    U, D, D_inv = scratch[0], scratch[1], scratch[2]
    g = row3(reals, nj, GRAVITY)
    moving, torqued, loaded = v.shape[0] > 0, tau.shape[0] > 0, f_ext.shape[0] > 0
    for i in range(nj):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        R, p = joint_pose(joints, reals, q, i)
        store_row(pose, i, 0, R)
        store_row(pose, i, 9, p)
        I = row10(reals, i, INERTIA)
        # I^A_i = I_i
        rigid_to_matrix(I, articulated, i)
        if moving:
            # v_J = S q̇_i ;  v_i = ⁱX_λ v_λ + v_J
            v_J = kinds.motion(kind, axis, nv, v, iv)
            v_i = add6(motion_to_child(R, p, row6(vel, parent, 0)), v_J) if parent >= 0 else v_J
            # c_i = c_J + v_i × v_J   (c_J = 0: S is constant in the joint frame)
            c_i = motion_cross(v_i, v_J)
            # p^A_i = v_i ×* I_i v_i − f_ext,i
            p_i = force_cross(v_i, inertia_times(I, v_i))
        else:
            v_i, c_i, p_i = ZERO6, ZERO6, ZERO6
        if loaded:
            p_i = sub6(p_i, (f_ext[6 * i], f_ext[6 * i + 1], f_ext[6 * i + 2], f_ext[6 * i + 3], f_ext[6 * i + 4],
                             f_ext[6 * i + 5]))
        store_row(vel, i, 0, v_i)
        store_row(bias, i, 0, c_i)
        store_row(pA, i, 0, p_i)
    for i in range(nj - 1, -1, -1):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i + diag(armature_i) ;  I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ (in place)
        factor_joint(kind, axis, nv, reals, articulated, i, U, D, D_inv, U_D_inv)
        p_i = row6(pA, i, 0)
        # u_i = τ_i − S_iᵀ p^A_i
        u = subspace_transpose_times(kind, axis, nv, p_i)
        for k in range(nv):
            # w_i = D_i⁻¹ u_i
            w_k = 0.0
            for m in range(nv):
                w_k += D_inv[k, m] * ((tau[iv + m] if torqued else 0.0) - u[m])
            w[i, k] = w_k
        if parent >= 0:
            # p^a_i = p^A_i + I^a_i c_i + U_i D_i⁻¹ u_i = p^A_i + I^a_i c_i + U_i w_i
            p_a = add6(p_i, matrix_times(articulated, i, row6(bias, i, 0)))
            for k in range(nv):
                p_a = add6(p_a, scale6(w[i, k], (U[k, 0], U[k, 1], U[k, 2], U[k, 3], U[k, 4], U[k, 5])))
            R, p = row9(pose, i, 0), row3(pose, i, 9)
            # I^A_λ(i) += λ(i)X*_i I^a_i ⁱX_λ(i) ;  p^A_λ(i) += λ(i)X*_i p^a_i
            articulated_to_parent(R, p, articulated, i, parent)
            store_row(pA, parent, 0, add6(row6(pA, parent, 0), force_to_parent(R, p, p_a)))
    a_0 = (-g[0], -g[1], -g[2], 0.0, 0.0, 0.0)
    qdd = out[0]
    for i in range(nj):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        a_parent = row6(acc, parent, 0) if parent >= 0 else a_0
        # a'_i = ⁱX_λ a_λ + c_i
        a_i = add6(motion_to_child(row9(pose, i, 0), row3(pose, i, 9), a_parent), row6(bias, i, 0))
        for k in range(nv):
            # q̈_i = D_i⁻¹ (u_i − U_iᵀ a'_i) = w_i − (U_i D_i⁻¹)ᵀ a'_i
            qdd[iv + k] = w[i, k] - dot6(column(U_D_inv, i, k), a_i)
        for k in range(nv):
            # a_i = a'_i + S_i q̈_i
            a_i = add6(a_i, scale6(qdd[iv + k], kinds.subspace_column(kind, axis, k)))
        store_row(acc, i, 0, a_i)
    nan_unless_finite(q, v, tau, f_ext, out)
