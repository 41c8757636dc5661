"""Articulated Body Algorithm: forward dynamics.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, Table 7.1, in joint
coordinates: each body's velocity, articulated inertia ``I^A`` and bias force ``p^A`` are expressed
in its own joint frame and moved to the parent's with the joint's pose, as Pinocchio's ``aba`` does. The
joints' armature enters each joint's ``D = Sᵀ I^A S + diag(armature)`` (Pinocchio's ``aba``, which adds it
to ``StU``), so that ABA solves ``(M_bodies + diag(armature)) q̈ = τ − h``, the ``M`` of
:func:`multibody.kernels.crba.mass_matrix`.

Articulated inertias are symmetric 6×6 matrices acting on motions to give forces (linear rows and
columns first), kept row-major with both triangles equal: each update computes the upper triangle and
mirrors it. A joint's ``U = I^A S`` and ``U D⁻¹`` are kept by columns (column ``k`` at ``6 k``), ``D = Sᵀ U``
and ``D⁻¹`` as the leading ``nv_i × nv_i`` block of a row-major 6×6. Each joint's data is a block of
:data:`BLOCK` floats of the flat workspace, addressed by offsets (a reshaped view would cost a call into
Numba's runtime per view and call). A joint of one coordinate (revolute, prismatic) takes a path of its
own whose ``D`` is a scalar, with the same arithmetic as the general one. The per-joint helpers of that
path are inlined at Numba's IR level (``inline="always"``): LLVM leaves them as calls, which pass their
tuples through memory.
"""

from __future__ import annotations

import math

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .spatial import (add6, compose_rotations, cross, dot6, force_cross, force_to_parent, inertia_times, load3,
                      load6, load9, motion_cross, motion_to_child, nan_unless_finite, row10, row3, scale6, store, sub6)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

#: Offsets in a joint's block of the workspace (joint i's starts at ``BLOCK i``): its pose in its parent
#: (``R`` row-major, then ``p``), articulated inertia (6×6), ``U D⁻¹`` (by columns), velocity, bias
#: acceleration ``c``, bias force ``p^A``, acceleration and ``D⁻¹ u``; the scratch blocks ``U``, ``D``,
#: ``D⁻¹`` (6×6 each) follow the last joint's block.
POSE, ARTICULATED, U_D_INV, VELOCITY, BIAS, BIAS_FORCE, ACCELERATION, W, BLOCK = 0, 12, 48, 84, 90, 96, 102, 108, 114


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its pose in its parent (12), articulated inertia
    (36), ``U D⁻¹`` (36) and five 6-vectors (velocity, bias acceleration, bias force, acceleration,
    ``D⁻¹ u``); three 6×6 scratch blocks (``U``, ``D`` and its factor, ``D⁻¹``)."""
    return BLOCK * nj + 108


# ----------------------------------------------------------------------------- 6×6 helpers
# ``Y`` is the flat workspace and ``at`` the offset of a row-major 6×6 in it.

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
def rotate_symmetric(R, A):
    """``R A Rᵀ`` of a symmetric 3×3 ``A``: its upper triangle ``(R A) Rᵀ``, mirrored."""
    RA = compose_rotations(R, A)
    xx = RA[0] * R[0] + RA[1] * R[1] + RA[2] * R[2]
    xy = RA[0] * R[3] + RA[1] * R[4] + RA[2] * R[5]
    xz = RA[0] * R[6] + RA[1] * R[7] + RA[2] * R[8]
    yy = RA[3] * R[3] + RA[4] * R[4] + RA[5] * R[5]
    yz = RA[3] * R[6] + RA[4] * R[7] + RA[5] * R[8]
    zz = RA[6] * R[6] + RA[7] * R[7] + RA[8] * R[8]
    return (xx, xy, xz, xy, yy, yz, xz, yz, zz)


@njit(cache=True, error_model="numpy")
def load_block(Y, at, r0, c0):
    """The 3×3 block at rows ``r0 : r0 + 3``, columns ``c0 : c0 + 3`` as a row-major 9-tuple."""
    k = at + 6 * r0 + c0
    return (Y[k], Y[k + 1], Y[k + 2], Y[k + 6], Y[k + 7], Y[k + 8], Y[k + 12], Y[k + 13], Y[k + 14])


@njit(cache=True, error_model="numpy")
def load_symmetric_block(Y, at, r0):
    """The diagonal 3×3 block at rows and columns ``r0 : r0 + 3`` from its upper triangle."""
    k = at + 7 * r0
    xx, xy, xz, yy, yz, zz = Y[k], Y[k + 1], Y[k + 2], Y[k + 7], Y[k + 8], Y[k + 14]
    return (xx, xy, xz, xy, yy, yz, xz, yz, zz)


@njit(cache=True, error_model="numpy")
def add_block(Y, at, r0, c0, A):
    """``Y[r0 : r0 + 3, c0 : c0 + 3] += A``."""
    for r in range(3):
        for c in range(3):
            Y[at + 6 * (r0 + r) + c0 + c] += A[3 * r + c]


@njit(cache=True, error_model="numpy")
def add_block_transposed(Y, at, r0, c0, A):
    """``Y[r0 : r0 + 3, c0 : c0 + 3] += Aᵀ``."""
    for r in range(3):
        for c in range(3):
            Y[at + 6 * (r0 + r) + c0 + c] += A[3 * c + r]


@njit(cache=True, error_model="numpy")
def add_symmetric_block(Y, at, r0, A):
    """``Y[r0 : r0 + 3, r0 : r0 + 3] += A`` for a symmetric ``A``: its upper triangle, into both triangles."""
    for r in range(3):
        for c in range(r, 3):
            x = Y[at + 6 * (r0 + r) + r0 + c] + A[3 * r + c]
            Y[at + 6 * (r0 + r) + r0 + c] = x
            Y[at + 6 * (r0 + c) + r0 + r] = x


@njit(cache=True, error_model="numpy", inline="always")
def rigid_to_matrix(I, Y, at):
    """``Y = [[m 1, −[h]×], [[h]×, Ī]]``: the 6×6 matrix of the inertia 10-tuple ``I`` (RBDA eq. 2.63)."""
    m, hx, hy, hz = I[0], I[1], I[2], I[3]
    rows = ((m, 0.0, 0.0, 0.0, hz, -hy),
            (0.0, m, 0.0, -hz, 0.0, hx),
            (0.0, 0.0, m, hy, -hx, 0.0),
            (0.0, -hz, hy, I[4], I[5], I[6]),
            (hz, 0.0, -hx, I[5], I[7], I[8]),
            (-hy, hx, 0.0, I[6], I[8], I[9]))
    for r in range(6):
        for c in range(6):
            Y[at + 6 * r + c] = rows[r][c]


@njit(cache=True, error_model="numpy", inline="always")
def matrix_times(Y, at, m):
    """``Y m`` for a 6×6 ``Y`` and a 6-tuple ``m``."""
    return (dot6(load6(Y, at), m), dot6(load6(Y, at + 6), m), dot6(load6(Y, at + 12), m),
            dot6(load6(Y, at + 18), m), dot6(load6(Y, at + 24), m), dot6(load6(Y, at + 30), m))


@njit(cache=True, error_model="numpy")
def block_times(Y, at, c0, x):
    """``Y[:, c0 : c0 + 3] x`` for a 6×6 ``Y`` and a 3-vector ``x``: ``Y S`` for a subspace column ``S`` that is
    zero outside those three entries (a revolute or a prismatic joint)."""
    k = at + c0
    return (Y[k] * x[0] + Y[k + 1] * x[1] + Y[k + 2] * x[2],
            Y[k + 6] * x[0] + Y[k + 7] * x[1] + Y[k + 8] * x[2],
            Y[k + 12] * x[0] + Y[k + 13] * x[1] + Y[k + 14] * x[2],
            Y[k + 18] * x[0] + Y[k + 19] * x[1] + Y[k + 20] * x[2],
            Y[k + 24] * x[0] + Y[k + 25] * x[1] + Y[k + 26] * x[2],
            Y[k + 30] * x[0] + Y[k + 31] * x[1] + Y[k + 32] * x[2])


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


@njit(cache=True, error_model="numpy", inline="always")
def articulated_to_parent(R, p, Y, at, parent_at):
    """``Y_P += ᴾX_C* Y_C ᶜX_P`` for the articulated inertia ``Y_C`` (at ``at``) about the child frame C, into
    the parent's ``Y_P`` (at ``parent_at``), with ``X_PC = (R, p)`` (RBDA eq. 2.66, which holds for any
    symmetric 6×6 inertia).

    With ``ᶜX_P = diag(Rᵀ, Rᵀ) [[1, −[p]×], [0, 1]]`` and ``Y_C = [[A, B], [Bᵀ, C]]``, after the
    rotation ``A' = R A Rᵀ``, ``B' = R B Rᵀ``, ``C' = R C Rᵀ`` the shift to P gives
    ``[[A', B' − A'[p]×], [·ᵀ, C' + [p]× (B' − A'[p]×) − B'ᵀ [p]×]]``; the diagonal blocks are symmetric,
    so only their upper triangles are computed.
    """
    Rt = transpose3(R)
    A = rotate_symmetric(R, load_symmetric_block(Y, at, 0))
    B = compose_rotations(compose_rotations(R, load_block(Y, at, 0, 3)), Rt)
    C = rotate_symmetric(R, load_symmetric_block(Y, at, 3))
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
    add_symmetric_block(Y, parent_at, 0, A)
    add_block(Y, parent_at, 0, 3, B_P)
    add_block_transposed(Y, parent_at, 3, 0, B_P)
    add_symmetric_block(Y, parent_at, 3, C_P)


@njit(cache=True, error_model="numpy")
def invert_symmetric(n, X, d, d_inv):
    """``D⁻¹`` into the row-major 6×6 at ``X[d_inv:]`` for a symmetric positive definite ``D``, the leading
    ``n × n`` block of the row-major 6×6 at ``X[d:]`` (its lower triangle is read), by ``D = L diag(d) Lᵀ`` with
    ``L`` unit lower triangular, which overwrites the lower triangle of ``D`` (pivots on its diagonal). A pivot
    that is not positive (a joint that moves no inertia) makes every entry NaN, without raising."""
    singular = False
    for j in range(n):
        # d_j = D_jj − Σ_k L_jk² d_k
        pivot = X[d + 7 * j]
        for k in range(j):
            pivot -= X[d + 6 * j + k] * X[d + 6 * j + k] * X[d + 7 * k]
        X[d + 7 * j] = pivot
        if not pivot > 0.0:
            singular = True
            pivot = 1.0
        for r in range(j + 1, n):
            # L_rj = (D_rj − Σ_k L_rk L_jk d_k) / d_j
            s = X[d + 6 * r + j]
            for k in range(j):
                s -= X[d + 6 * r + k] * X[d + 6 * j + k] * X[d + 7 * k]
            X[d + 6 * r + j] = s / pivot
    for c in range(n):
        # column c of D⁻¹: L y = e_c, then Lᵀ x = diag(d)⁻¹ y (each in place in the column)
        for r in range(n):
            y = 1.0 if r == c else 0.0
            for k in range(r):
                y -= X[d + 6 * r + k] * X[d_inv + 6 * k + c]
            X[d_inv + 6 * r + c] = y
        for r in range(n - 1, -1, -1):
            x = X[d_inv + 6 * r + c] / X[d + 7 * r] if not singular else math.nan
            for k in range(r + 1, n):
                x -= X[d + 6 * k + r] * X[d_inv + 6 * k + c]
            X[d_inv + 6 * r + c] = x


@njit(cache=True, error_model="numpy", inline="always")
def factor_single(Y, at, s, rows, axis, armature_0):
    """:func:`factor_joint` of a joint of one coordinate with subspace column ``s`` (the unit ``axis`` in
    ``rows : rows + 3``) and armature ``armature_0``: returns ``(U, U D⁻¹, D⁻¹)`` (two 6-tuples and a scalar,
    NaN where ``D`` is not positive) and leaves ``I^a = I^A − U D⁻¹ Uᵀ`` in place of ``I^A`` at ``Y[at:]``."""
    # U = I^A S, which reads three columns
    U = block_times(Y, at, rows, axis)
    # D = Sᵀ U + armature
    D = dot6(s, U) + armature_0
    d_inv = 1.0 / D if D > 0.0 else math.nan
    UD = scale6(d_inv, U)
    for r in range(6):
        for c in range(r, 6):
            # I^a = I^A − U D⁻¹ Uᵀ (symmetric: the upper triangle, mirrored)
            x = Y[at + 6 * r + c] - UD[r] * U[c]
            Y[at + 6 * r + c] = x
            Y[at + 6 * c + r] = x
    return U, UD, d_inv


@njit(cache=True, error_model="numpy")
def factor_joint(kind, axis, nv, reals, i, Y, at, scratch, u_d_inv):
    """For joint i of articulated inertia ``I^A`` (at ``Y[at:]``) (RBDA Table 7.1): ``U = I^A S`` (by columns,
    at ``Y[scratch:]``), ``D = Sᵀ U + diag(armature)`` (the armature of joint i's coordinates in ``reals``; at
    ``Y[scratch + 36:]``, overwritten by its factor), ``D⁻¹`` (at ``Y[scratch + 72:]``), ``U D⁻¹`` (by columns,
    at ``Y[u_d_inv:]``), and ``I^a = I^A − U D⁻¹ Uᵀ`` in place of ``I^A``."""
    U, D, D_inv = scratch, scratch + 36, scratch + 72
    for k in range(nv):
        # U = I^A S
        store(Y, U + 6 * k, matrix_times(Y, at, kinds.subspace_column(kind, axis, k)))
    for m in range(nv):
        s = kinds.subspace_column(kind, axis, m)
        for k in range(m + 1):
            # D = Sᵀ U
            Y[D + 6 * m + k] = dot6(s, load6(Y, U + 6 * k))
        # D_mm += armature_m
        Y[D + 7 * m] += armature(reals, i, m)
    invert_symmetric(nv, Y, D, D_inv)
    for k in range(nv):
        for r in range(6):
            # (U D⁻¹)_k = Σ_m U_m (D⁻¹)_mk
            x = 0.0
            for m in range(nv):
                x += Y[U + 6 * m + r] * Y[D_inv + 6 * m + k]
            Y[u_d_inv + 6 * k + r] = x
    for r in range(6):
        for c in range(r, 6):
            # I^a = I^A − U D⁻¹ Uᵀ (symmetric: the upper triangle, mirrored)
            x = Y[at + 6 * r + c]
            for k in range(nv):
                x -= Y[u_d_inv + 6 * k + r] * Y[U + 6 * k + c]
            Y[at + 6 * r + c] = x
            Y[at + 6 * c + r] = x


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy")
def forward_dynamics(joints, reals, frames, q, v, tau, f_ext, out, ws):
    """Accelerations ``q̈`` (RBDA Table 7.1) into ``out[0] (nv,)``: m/s² or rad/s² per coordinate.

    ``q (nq,)``, ``v, tau (nv,)`` (length 0: zero), ``f_ext (6 nj,)`` (one force per joint on the
    body it moves, in its frame, ``[f; n]``) or empty. Gravity enters as the world's acceleration
    ``a₀ = [−g; 0]``. A joint that moves no inertia (``D`` not positive definite) leaves NaN in
    ``out``. ``frames`` is unused; ``ws`` as :func:`workspace_size` (layout :data:`BLOCK`).
    """
    nj = joints.shape[0]
    scratch = BLOCK * nj
    g = row3(reals, nj, GRAVITY)
    moving, torqued, loaded = v.shape[0] > 0, tau.shape[0] > 0, f_ext.shape[0] > 0
    for i in range(nj):
        b = BLOCK * i
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        R, p = joint_pose(joints, reals, q, i)
        store(ws, b + POSE, R)
        store(ws, b + POSE + 9, p)
        I = row10(reals, i, INERTIA)
        # I^A_i = I_i
        rigid_to_matrix(I, ws, b + ARTICULATED)
        if moving:
            # v_J = S q̇_i ;  v_i = ⁱX_λ v_λ + v_J
            v_J = scale6(v[iv], kinds.subspace_column(kind, axis, 0)) if nv == 1 else kinds.motion(kind, axis, nv, v,
                                                                                                        iv)
            v_i = add6(motion_to_child(R, p, load6(ws, BLOCK * parent + VELOCITY)), v_J) if parent >= 0 else v_J
            # c_i = c_J + v_i × v_J   (c_J = 0: S is constant in the joint frame)
            c_i = motion_cross(v_i, v_J)
            # p^A_i = v_i ×* I_i v_i − f_ext,i
            p_i = force_cross(v_i, inertia_times(I, v_i))
        else:
            v_i, c_i, p_i = ZERO6, ZERO6, ZERO6
        if loaded:
            p_i = sub6(p_i, load6(f_ext, 6 * i))
        store(ws, b + VELOCITY, v_i)
        store(ws, b + BIAS, c_i)
        store(ws, b + BIAS_FORCE, p_i)
    for i in range(nj - 1, -1, -1):
        b = BLOCK * i
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        p_i = load6(ws, b + BIAS_FORCE)
        p_a = ZERO6
        if nv == 1:
            s = kinds.subspace_column(kind, axis, 0)
            # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i + armature_i ;  I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ (in place)
            U_0, U_D_0, d_inv = factor_single(ws, b + ARTICULATED, s, kinds.axis_rows(kind), axis,
                                              armature(reals, i, 0))
            store(ws, b + U_D_INV, U_D_0)
            # w_i = D_i⁻¹ u_i = D_i⁻¹ (τ_i − S_iᵀ p^A_i)
            w_0 = d_inv * ((tau[iv] if torqued else 0.0) - dot6(s, p_i))
            ws[b + W] = w_0
            if parent >= 0:
                # p^a_i = p^A_i + I^a_i c_i + U_i w_i
                p_a = add6(add6(p_i, matrix_times(ws, b + ARTICULATED, load6(ws, b + BIAS))), scale6(w_0, U_0))
        else:
            # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i + diag(armature_i) ;  I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ (in place)
            factor_joint(kind, axis, nv, reals, i, ws, b + ARTICULATED, scratch, b + U_D_INV)
            # u_i = τ_i − S_iᵀ p^A_i
            u = subspace_transpose_times(kind, axis, nv, p_i)
            for k in range(nv):
                # w_i = D_i⁻¹ u_i
                w_k = 0.0
                for m in range(nv):
                    w_k += ws[scratch + 72 + 6 * k + m] * ((tau[iv + m] if torqued else 0.0) - u[m])
                ws[b + W + k] = w_k
            if parent >= 0:
                # p^a_i = p^A_i + I^a_i c_i + U_i D_i⁻¹ u_i = p^A_i + I^a_i c_i + U_i w_i
                p_a = add6(p_i, matrix_times(ws, b + ARTICULATED, load6(ws, b + BIAS)))
                for k in range(nv):
                    p_a = add6(p_a, scale6(ws[b + W + k], load6(ws, scratch + 6 * k)))
        if parent >= 0:
            R, p = load9(ws, b + POSE), load3(ws, b + POSE + 9)
            # I^A_λ(i) += λ(i)X*_i I^a_i ⁱX_λ(i) ;  p^A_λ(i) += λ(i)X*_i p^a_i
            articulated_to_parent(R, p, ws, b + ARTICULATED, BLOCK * parent + ARTICULATED)
            store(ws, BLOCK * parent + BIAS_FORCE, add6(load6(ws, BLOCK * parent + BIAS_FORCE),
                                                        force_to_parent(R, p, p_a)))
    a_0 = (-g[0], -g[1], -g[2], 0.0, 0.0, 0.0)
    qdd = out[0]
    for i in range(nj):
        b = BLOCK * i
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        axis = row3(reals, i, AXIS)
        a_parent = load6(ws, BLOCK * parent + ACCELERATION) if parent >= 0 else a_0
        # a'_i = ⁱX_λ a_λ + c_i
        a_i = add6(motion_to_child(load9(ws, b + POSE), load3(ws, b + POSE + 9), a_parent), load6(ws, b + BIAS))
        for k in range(nv):
            # q̈_i = D_i⁻¹ (u_i − U_iᵀ a'_i) = w_i − (U_i D_i⁻¹)ᵀ a'_i
            qdd[iv + k] = ws[b + W + k] - dot6(load6(ws, b + U_D_INV + 6 * k), a_i)
        if nv == 1:
            # a_i = a'_i + S_i q̈_i
            a_i = add6(a_i, scale6(qdd[iv], kinds.subspace_column(kind, axis, 0)))
        else:
            for k in range(nv):
                # a_i = a'_i + S_i q̈_i
                a_i = add6(a_i, scale6(qdd[iv + k], kinds.subspace_column(kind, axis, k)))
        store(ws, b + ACCELERATION, a_i)
    nan_unless_finite(q, v, tau, f_ext, out)
