"""Articulated Body Algorithm: forward dynamics.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, Table 7.1, with every spatial
quantity in world axes, as Pinocchio's ``aba`` computes it (J. Carpentier and N. Mansard, "Analytical
derivatives of rigid body dynamics algorithms", RSS 2018, §III), about the first joint's origin ``o`` rather than the
world's, so that a robot far from the world origin keeps its digits (as the kinematics do): each joint's motion
subspace ``S`` and its body's inertia are moved to that frame once, in the pass down the tree, and then the velocities,
accelerations, articulated inertias ``I^A`` and bias forces ``p^A`` of a child add to its parent's without a
change of coordinates (RBDA's ``λ(i)X*_i I^a_i ⁱX_λ(i)`` becomes ``I^a_i``). The joints' armature enters each
joint's ``D = Sᵀ I^A S + diag(armature)`` (Pinocchio's ``aba``, which adds it to ``StU``), so that ABA solves
``(M_bodies + diag(armature)) q̈ = τ − h``, the ``M`` of :func:`multibody.kernels.crba.mass_matrix`.

Articulated inertias are symmetric 6×6 matrices acting on motions to give forces (linear rows and columns first),
kept packed as their upper triangle, row by row (21 floats, :func:`packed_index`): each update computes and stores
only those entries, and a product reads each once. A joint's ``S`` and ``U D⁻¹`` are kept by columns (column ``k`` at
``6 k``), ``U = I^A S`` too, ``D = Sᵀ U`` and ``D⁻¹`` as the leading ``nv_i × nv_i`` block of a row-major 6×6. Each
joint's data is a block of :data:`BLOCK` floats of the flat workspace, addressed by offsets (a reshaped view would
cost a call into Numba's runtime per view and call). A joint of one coordinate (revolute, prismatic) takes a path of
its own whose ``D`` is a scalar, the general factorisation's equations in scalars; it leaves ``I^A`` as it is and
adds ``I^a = I^A − U D⁻¹ Uᵀ`` to the parent's in the same pass, with ``I^a c = I^A c − U D⁻¹ (Uᵀ c)``, so that the
joint's articulated inertia is read twice and written never (the numbers equal the general path's to rounding). The
per-joint helpers of that path are inlined at Numba's IR level (``inline="always"``): LLVM leaves them as calls,
which pass their tuples through memory.

The pass down the tree has every body's velocity and world inertia at hand, so :func:`articulated_body` also
gives the mechanical energy of the state on request (:mod:`multibody.kernels.energy` defines it): a
simulation records the energy of each step's start from its first stage.
"""

from __future__ import annotations

import math

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .spatial import (add6, compose, dot3, dot6, force_cross, force_to_parent, inertia_times, inertia_to_parent,
                      load3, load6, load9, motion_cross, nan_unless_finite, row10, row3, scale6,
                      store, sub6)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

#: Offsets in a joint's block of the workspace (joint i's starts at ``BLOCK i``): its pose in the world
#: (``R`` row-major, then ``p``), articulated inertia (packed, 21), ``U D⁻¹`` (by columns), ``S`` (by columns),
#: velocity, bias acceleration ``c``, bias force ``p^A``, acceleration and ``D⁻¹ u``, all in world axes about ``o``;
#: the scratch blocks ``U``, ``D``, ``D⁻¹`` (6×6 each) follow the last joint's block, then the kinetic and the
#: potential energy (:func:`energy_offset`).
POSE, ARTICULATED, U_D_INV, SUBSPACE, VELOCITY, BIAS, BIAS_FORCE, ACCELERATION, W, BLOCK = (0, 12, 33, 69, 105, 111,
                                                                                         117, 123, 129, 135)
#: Floats of a packed symmetric 6×6 (its upper triangle).
PACKED = 21


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its pose in the world (12), articulated inertia (21),
    ``U D⁻¹`` and ``S`` (36 each) and five 6-vectors (velocity, bias acceleration, bias force, acceleration,
    ``D⁻¹ u``); three 6×6 scratch blocks (``U``, ``D`` and its factor, ``D⁻¹``); the two energies."""
    return BLOCK * nj + 110


@njit(cache=True, error_model="numpy")
def energy_offset(nj):
    """Where :func:`articulated_body` leaves the kinetic and the potential energy (J) in the workspace of a
    tree of ``nj`` joints: ``ws[at]`` and ``ws[at + 1]``."""
    return BLOCK * nj + 108


@njit(cache=True, error_model="numpy", inline="always")
def recorded_energy(ws, nj):
    """The mechanical energy ``E = T + U`` (J) that :func:`articulated_body` called with ``energy`` left in ``ws``
    (a tree of ``nj`` joints)."""
    at = energy_offset(nj)
    return ws[at] + ws[at + 1]


# ----------------------------------------------------------------------------- 6×6 helpers
# ``Y`` is the flat workspace and ``at`` the offset of a packed symmetric 6×6 in it.

@njit(cache=True, error_model="numpy", inline="always")
def packed_index(r, c):
    """Where entry ``(r, c)``, ``r ≤ c``, of a symmetric 6×6 sits in its packed upper triangle: row ``r`` starts
    after the ``6 + 5 + … + (7 − r)`` entries of the rows above it."""
    return 6 * r - (r * (r - 1)) // 2 + c - r


@njit(cache=True, error_model="numpy", inline="always")
def rigid_to_matrix(I, Y, at):
    """``Y = [[m 1, −[h]×], [[h]×, Ī]]``: the 6×6 matrix of the inertia 10-tuple ``I`` (RBDA eq. 2.63), packed."""
    m, hx, hy, hz = I[0], I[1], I[2], I[3]
    upper = (m, 0.0, 0.0, 0.0, hz, -hy,
             m, 0.0, -hz, 0.0, hx,
             m, hy, -hx, 0.0,
             I[4], I[5], I[6],
             I[7], I[8],
             I[9])
    for k in range(PACKED):
        Y[at + k] = upper[k]


@njit(cache=True, error_model="numpy", inline="always")
def matrix_times(Y, at, m):
    """``Y m`` for a packed symmetric 6×6 ``Y`` and a 6-tuple ``m``, each row summed from its first column."""
    y0, y1, y2, y3, y4, y5, y6 = Y[at], Y[at + 1], Y[at + 2], Y[at + 3], Y[at + 4], Y[at + 5], Y[at + 6]
    y7, y8, y9, y10, y11, y12, y13 = Y[at + 7], Y[at + 8], Y[at + 9], Y[at + 10], Y[at + 11], Y[at + 12], Y[at + 13]
    y14, y15, y16, y17, y18, y19, y20 = (Y[at + 14], Y[at + 15], Y[at + 16], Y[at + 17], Y[at + 18], Y[at + 19],
                                         Y[at + 20])
    return (dot6((y0, y1, y2, y3, y4, y5), m), dot6((y1, y6, y7, y8, y9, y10), m),
            dot6((y2, y7, y11, y12, y13, y14), m), dot6((y3, y8, y12, y15, y16, y17), m),
            dot6((y4, y9, y13, y16, y18, y19), m), dot6((y5, y10, y14, y17, y19, y20), m))


@njit(cache=True, error_model="numpy", inline="always")
def add_reduced(Y, at, UD, U, P, to):
    """``P += Y − (U D⁻¹) Uᵀ`` for packed symmetric 6×6 ``Y`` (at ``Y[at:]``) and ``P`` (at ``P[to:]``) and the
    6-tuples ``U D⁻¹`` and ``U`` of a joint of one coordinate: its ``I^a`` added to its parent's ``I^A`` (RBDA
    Table 7.1, ``I^A_λ(i) += I^a_i``), in the same axes."""
    k = 0
    for r in range(6):
        for c in range(r, 6):
            # I^a_rc = I^A_rc − (U D⁻¹)_r U_c
            P[to + k] += Y[at + k] - UD[r] * U[c]
            k += 1


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
def factor_single(Y, at, s, armature_0):
    """:func:`factor_joint` of a joint of one coordinate with subspace column ``s`` (a 6-tuple), armature
    ``armature_0`` and articulated inertia ``I^A`` packed at ``Y[at:]``, which it leaves as it is: returns ``(U,
    U D⁻¹, D⁻¹)`` (two 6-tuples and a scalar, NaN where ``D`` is not positive); ``I^a = I^A − U D⁻¹ Uᵀ`` is
    :func:`add_reduced`'s."""
    # U = I^A S
    U = matrix_times(Y, at, s)
    # D = Sᵀ U + armature
    D = dot6(s, U) + armature_0
    d_inv = 1.0 / D if D > 0.0 else math.nan
    return U, scale6(d_inv, U), d_inv


@njit(cache=True, error_model="numpy")
def factor_joint(nv, reals, i, J, X):
    """For joint i of ``nv`` coordinates, its block ``J`` of the workspace (:data:`BLOCK`) with its articulated
    inertia ``I^A`` and motion subspace ``S`` (RBDA Table 7.1): ``U = I^A S`` (by columns, at ``X[0:]``),
    ``D = Sᵀ U + diag(armature)`` (the armature of joint i's coordinates in ``reals``; at ``X[36:]``, overwritten by
    its factor), ``D⁻¹`` (at ``X[72:]``), ``U D⁻¹`` into ``J``, and ``I^a = I^A − U D⁻¹ Uᵀ`` in place of ``I^A``
    (packed)."""
    U, D, D_inv = 0, 36, 72
    for k in range(nv):
        # U = I^A S
        store(X, U + 6 * k, matrix_times(J, ARTICULATED, load6(J, SUBSPACE + 6 * k)))
    for m in range(nv):
        s = load6(J, SUBSPACE + 6 * m)
        for k in range(m + 1):
            # D = Sᵀ U
            X[D + 6 * m + k] = dot6(s, load6(X, U + 6 * k))
        # D_mm += armature_m
        X[D + 7 * m] += armature(reals, i, m)
    invert_symmetric(nv, X, D, D_inv)
    for k in range(nv):
        for r in range(6):
            # (U D⁻¹)_k = Σ_m U_m (D⁻¹)_mk
            x = 0.0
            for m in range(nv):
                x += X[U + 6 * m + r] * X[D_inv + 6 * m + k]
            J[U_D_INV + 6 * k + r] = x
    for r in range(6):
        for c in range(r, 6):
            # I^a = I^A − U D⁻¹ Uᵀ (symmetric: the upper triangle)
            at = ARTICULATED + packed_index(r, c)
            x = J[at]
            for k in range(nv):
                x -= J[U_D_INV + 6 * k + r] * X[U + 6 * k + c]
            J[at] = x


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy")
def articulated_body(joints, reals, q, v, tau, f_ext, qdd, ws, energy):
    """Accelerations ``q̈ (nv,)`` (RBDA Table 7.1, in world axes about the first joint's origin as the module docstring says) into ``qdd``:
    m/s² or rad/s² per coordinate, and with ``energy`` the kinetic and the potential energy (J) of the state into
    ``ws`` at :func:`energy_offset` (:mod:`multibody.kernels.energy`'s ``T`` and ``U``, the same sums).

    ``q (nq,)``, ``v, tau (nv,)`` (length 0: zero), ``f_ext (6 nj,)`` (one force per joint on the body it moves,
    in its frame, ``[f; n]``) or empty. Gravity enters as the world's acceleration ``a₀ = [−g; 0]``. A joint that
    moves no inertia (``D`` not positive definite) leaves NaN in ``qdd``. ``ws`` as :func:`workspace_size`
    (layout :data:`BLOCK`).
    """
    nj = joints.shape[0]
    scratch = BLOCK * nj
    # each joint's block as a view of its own, so that its offsets are constants
    X = ws[scratch : scratch + 108]
    g = row3(reals, nj, GRAVITY)
    moving, torqued, loaded = v.shape[0] > 0, tau.shape[0] > 0, f_ext.shape[0] > 0
    kinetic, potential = 0.0, 0.0
    o = (0.0, 0.0, 0.0)
    for i in range(nj):
        J = ws[BLOCK * i : BLOCK * (i + 1)]
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        P = ws[BLOCK * parent : BLOCK * (parent + 1)] if parent >= 0 else J
        axis = row3(reals, i, AXIS)
        # ⁰X_i = ⁰X_λ(i) X_λ(i),i, about the first joint's origin o
        R, p = joint_pose(joints, reals, q, i)
        if i == 0:
            o = p
        if parent >= 0:
            R, p = compose(load9(P, POSE), load3(P, POSE + 9), R, p)
        else:
            p = (p[0] - o[0], p[1] - o[1], p[2] - o[2])
        store(J, POSE, R)
        store(J, POSE + 9, p)
        # S_i in world axes about o: ⁰X_i S_i, column by column
        for k in range(nv):
            store(J, SUBSPACE + 6 * k, kinds.subspace_column_to_parent(kind, axis, k, R, p))
        # I_i in world axes about o: ⁰X_i* I_i ⁱX_0 ;  I^A_i = I_i
        I = inertia_to_parent(R, p, row10(reals, i, INERTIA))
        rigid_to_matrix(I, J, ARTICULATED)
        if moving:
            # v_J = S_i q̇_i ;  v_i = v_λ + v_J
            v_J = scale6(v[iv], load6(J, SUBSPACE))
            for k in range(1, nv):
                v_J = add6(v_J, scale6(v[iv + k], load6(J, SUBSPACE + 6 * k)))
            v_i = add6(load6(P, VELOCITY), v_J) if parent >= 0 else v_J
            # c_i = v_i × v_J   (Ṡ_i = v_i × S_i: S is constant in the joint frame)
            c_i = motion_cross(v_i, v_J)
            # p^A_i = v_i ×* I_i v_i − ⁰X_i* f_ext,i
            h_i = inertia_times(I, v_i)
            p_i = force_cross(v_i, h_i)
            if energy:
                # T += ½ v_iᵀ I_i v_i + ½ Σ_k armature_k q̇_k²
                kinetic += 0.5 * dot6(v_i, h_i)
                for k in range(nv):
                    kinetic += 0.5 * armature(reals, i, k) * v[iv + k] * v[iv + k]
        else:
            v_i, c_i, p_i = ZERO6, ZERO6, ZERO6
        if energy:
            # U −= gᵀ m_i c_i, with m_i c_i = m_i o + h_i the first moment about the world origin
            potential -= dot3(g, (I[1] + I[0] * o[0], I[2] + I[0] * o[1], I[3] + I[0] * o[2]))
        if loaded:
            p_i = sub6(p_i, force_to_parent(R, p, load6(f_ext, 6 * i)))
        store(J, VELOCITY, v_i)
        store(J, BIAS, c_i)
        store(J, BIAS_FORCE, p_i)
    for i in range(nj - 1, -1, -1):
        J = ws[BLOCK * i : BLOCK * (i + 1)]
        parent, iv, nv = joints[i, PARENT], joints[i, IV], joints[i, NV]
        p_i = load6(J, BIAS_FORCE)
        if nv == 1:
            s = load6(J, SUBSPACE)
            # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i + armature_i
            U_0, U_D_0, d_inv = factor_single(J, ARTICULATED, s, armature(reals, i, 0))
            store(J, U_D_INV, U_D_0)
            # w_i = D_i⁻¹ u_i = D_i⁻¹ (τ_i − S_iᵀ p^A_i)
            w_0 = d_inv * ((tau[iv] if torqued else 0.0) - dot6(s, p_i))
            J[W] = w_0
            if parent >= 0:
                c_i = load6(J, BIAS)
                # I^a_i c_i = I^A_i c_i − U_i D_i⁻¹ (U_iᵀ c_i)
                I_c = sub6(matrix_times(J, ARTICULATED, c_i), scale6(dot6(U_0, c_i), U_D_0))
                # p^a_i = p^A_i + I^a_i c_i + U_i w_i
                p_a = add6(add6(p_i, I_c), scale6(w_0, U_0))
                P = ws[BLOCK * parent : BLOCK * (parent + 1)]
                # I^A_λ(i) += I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ ;  p^A_λ(i) += p^a_i   (both in the same axes about o)
                add_reduced(J, ARTICULATED, U_D_0, U_0, P, ARTICULATED)
                store(P, BIAS_FORCE, add6(load6(P, BIAS_FORCE), p_a))
        else:
            # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i + diag(armature_i) ;  I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ (in place)
            factor_joint(nv, reals, i, J, X)
            for k in range(nv):
                # w_i = D_i⁻¹ u_i = D_i⁻¹ (τ_i − S_iᵀ p^A_i)
                w_k = 0.0
                for m in range(nv):
                    u_m = (tau[iv + m] if torqued else 0.0) - dot6(load6(J, SUBSPACE + 6 * m), p_i)
                    w_k += X[72 + 6 * k + m] * u_m
                J[W + k] = w_k
            if parent >= 0:
                # p^a_i = p^A_i + I^a_i c_i + U_i D_i⁻¹ u_i = p^A_i + I^a_i c_i + U_i w_i
                p_a = add6(p_i, matrix_times(J, ARTICULATED, load6(J, BIAS)))
                for k in range(nv):
                    p_a = add6(p_a, scale6(J[W + k], load6(X, 6 * k)))
                P = ws[BLOCK * parent : BLOCK * (parent + 1)]
                # I^A_λ(i) += I^a_i ;  p^A_λ(i) += p^a_i   (both in the same axes about o)
                for k in range(PACKED):
                    P[ARTICULATED + k] += J[ARTICULATED + k]
                store(P, BIAS_FORCE, add6(load6(P, BIAS_FORCE), p_a))
    a_0 = (-g[0], -g[1], -g[2], 0.0, 0.0, 0.0)
    for i in range(nj):
        J = ws[BLOCK * i : BLOCK * (i + 1)]
        parent, iv, nv = joints[i, PARENT], joints[i, IV], joints[i, NV]
        # a'_i = a_λ + c_i
        a_λ = load6(ws[BLOCK * parent : BLOCK * (parent + 1)], ACCELERATION) if parent >= 0 else a_0
        a_i = add6(a_λ, load6(J, BIAS))
        for k in range(nv):
            # q̈_i = D_i⁻¹ (u_i − U_iᵀ a'_i) = w_i − (U_i D_i⁻¹)ᵀ a'_i
            qdd[iv + k] = J[W + k] - dot6(load6(J, U_D_INV + 6 * k), a_i)
        for k in range(nv):
            # a_i = a'_i + S_i q̈_i
            a_i = add6(a_i, scale6(qdd[iv + k], load6(J, SUBSPACE + 6 * k)))
        store(J, ACCELERATION, a_i)
    if energy:
        at = energy_offset(nj)
        ws[at] = kinetic
        ws[at + 1] = potential


@njit(cache=True, error_model="numpy")
def forward_dynamics(joints, reals, frames, q, v, tau, f_ext, out, ws):
    """Accelerations ``q̈`` (RBDA Table 7.1) into ``out[0] (nv,)``: m/s² or rad/s² per coordinate, by
    :func:`articulated_body` (arguments as it takes them). ``frames`` is unused; ``ws`` as :func:`workspace_size`.
    """
    articulated_body(joints, reals, q, v, tau, f_ext, out[0], ws, False)
    nan_unless_finite(q, v, tau, f_ext, out)
