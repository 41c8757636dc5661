"""The Coriolis matrix ``C(q, v)``, Christoffel-consistent: ``Ṁ = C + Cᵀ`` and ``C v + g = h``.

S. Echeandia and P. M. Wensing, "Numerical methods to compute the Coriolis matrix and Christoffel
symbols for rigid-body systems", *J. Comput. Nonlinear Dynam.* 16(9), 091004, 2021: each body's
``Bᵢ`` (eq. 20) gives ``C = Σᵢ Jᵢᵀ (Iᵢ J̇ᵢ + Bᵢ Jᵢ)``, summed over the bodies by the composites ``I^c``
and ``B^c`` of a backward pass (their recursive algorithm; Pinocchio's ``computeCoriolisMatrix``).

The sums over bodies need every body in one set of coordinates, so the algorithm works, as
Pinocchio's does, in world axes; its Plücker coordinates are taken at the first joint's origin
rather than the world's, which leaves ``C`` unchanged and keeps the moments ``m |p|²`` of distant
bodies from swamping their rotational inertias (``docs/conventions.md``).

The joints' armature, a constant on the diagonal of ``M``, changes neither ``Ṁ`` nor ``C`` (Pinocchio
alike): ``Ṁ = C + Cᵀ`` holds with it.
"""

from __future__ import annotations

from .layout import AXIS, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import joint_pose
from .spatial import (add6, compose, cross, dot6, inertia_rate, inertia_times, inertia_to_parent, load10, load3, load6,
                      load9, motion_cross, motion_to_parent, nan_unless_finite, store, sub3)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its world pose (12), velocity (6), composite
    inertia (10) and composite ``B`` (12: see :func:`body_factor`); per coordinate its motion
    subspace column ``ξ`` and that column's rate ``ξ̇`` (6 each)."""
    return 40 * nj + 12 * nv


@njit(cache=True, error_model="numpy")
def body_factor(I, V):
    """``Bᵢ = ½ [(V×*) I + (I V)×̄* − I (V×)]`` (Echeandia and Wensing, eq. 20) of a body of inertia
    ``I (m, h, Ī)`` moving at ``V = (v, ω)``, in the same coordinates, as ``(a, E)``: ``B = [[0, −[a]×],
    [0, E]]`` with ``a = m v + ω × h`` (3-tuple) and ``E`` (9-tuple, row-major).

    In 3×3 blocks, with ``f ×̄* m = m ×* f``: ``(V×*) I − I (V×) = [[0, −[a]×], [[a]×, D]]`` where
    ``D = −[v]×[h]× − [h]×[v]× + [ω]×Ī − Ī[ω]× = 2 (v·h) 1 − h vᵀ − v hᵀ + P + Pᵀ`` with ``P = [ω]× Ī``,
    and ``(I V)×̄* = [[0, −[a]×], [−[a]×, −[n]×]]`` with ``I V = (a, n)``, ``n = h × v + Ī ω``; so
    ``E = ½ (D − [n]×)``.
    """
    # a = m v + ω × h ;  n = h × v + Ī ω
    IV = inertia_times(I, V)
    a, n = (IV[0], IV[1], IV[2]), (IV[3], IV[4], IV[5])
    # D is the rotational block of the inertia's rate V ×* I − I V× (spatial.inertia_rate)
    rate = inertia_rate(I, V)
    d00, d01, d02, d11, d12, d22 = (0.5 * rate[4], 0.5 * rate[5], 0.5 * rate[6], 0.5 * rate[7], 0.5 * rate[8],
                                    0.5 * rate[9])
    # E = ½ D − ½ [n]×
    E = (d00, d01 + 0.5 * n[2], d02 - 0.5 * n[1],
         d01 - 0.5 * n[2], d11, d12 + 0.5 * n[0],
         d02 + 0.5 * n[1], d12 - 0.5 * n[0], d22)
    return a, E


@njit(cache=True, error_model="numpy")
def factor_times(B, m):
    """``B m = (−a × ω, E ω)`` for ``B = [[0, −[a]×], [0, E]]`` stored as ``(a, E)`` (12 floats) and
    ``m = (v, ω)``."""
    w = (m[3], m[4], m[5])
    lin = cross(w, (B[0], B[1], B[2]))
    return lin + (B[3] * w[0] + B[4] * w[1] + B[5] * w[2],
                  B[6] * w[0] + B[7] * w[1] + B[8] * w[2],
                  B[9] * w[0] + B[10] * w[1] + B[11] * w[2])


@njit(cache=True, error_model="numpy")
def factor_transpose_times(B, m):
    """``Bᵀ m = (0, a × v + Eᵀ ω)`` for ``B`` stored as ``(a, E)`` and ``m = (v, ω)``."""
    w = (m[3], m[4], m[5])
    ang = cross((B[0], B[1], B[2]), (m[0], m[1], m[2]))
    return (0.0, 0.0, 0.0, ang[0] + B[3] * w[0] + B[6] * w[1] + B[9] * w[2],
            ang[1] + B[4] * w[0] + B[7] * w[1] + B[10] * w[2],
            ang[2] + B[5] * w[0] + B[8] * w[1] + B[11] * w[2])


@njit(cache=True, error_model="numpy")
def coriolis_matrix(joints, reals, frames, q, v, x2, x3, out, ws):
    """``C(q, v)`` into ``out (nv, nv)`` (N m s per unit of velocity, Pinocchio's ``computeCoriolisMatrix``).

    ``q (nq,)``, ``v (nv,)`` (length 0: zero, which gives ``C = 0``); ``frames``, ``x2``, ``x3`` unused.

    Forward pass: each joint's world pose, relative to the first joint's origin, its subspace
    columns ``ξ_k`` in world axes, its body's velocity ``Vᵢ``, inertia ``Iᵢ`` and ``Bᵢ``. Backward pass:
    the composites ``I^c_j`` and ``B^c_j`` of the subtree of each joint ``j``, complete when ``j`` is
    reached, give the entries between ``j``'s coordinates ``k`` and those ``l`` of ``j``'s supporting joints
    (``j`` itself included): column ``l`` of the Jacobian of every body in the subtree is ``ξ_l`` and its
    rate ``ξ̇_l = V_λ(l) × ξ_l``, so ``C_kl = (I^c_j ξ_k)ᵀ ξ̇_l + (B^c_jᵀ ξ_k)ᵀ ξ_l`` and
    ``C_lk = ξ_lᵀ (I^c_j ξ̇_k + B^c_j ξ_k)``. The other entries, of coordinates whose joints do not
    support one another, vanish.
    """
    nj = joints.shape[0]
    n = out.shape[0]
    pose = ws[: 12 * nj].reshape((nj, 12))
    vel = ws[12 * nj : 18 * nj].reshape((nj, 6))
    inertia_c = ws[18 * nj : 28 * nj].reshape((nj, 10))
    factor_c = ws[28 * nj : 40 * nj].reshape((nj, 12))
    xi = ws[40 * nj : 40 * nj + 6 * n].reshape((n, 6))
    xi_dot = ws[40 * nj + 6 * n : 40 * nj + 12 * n].reshape((n, 6))
    moving = v.shape[0] > 0
    origin = (0.0, 0.0, 0.0)
    for i in range(nj):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        row = reals[i]
        axis = load3(row, AXIS)
        R_Pi, p_Pi = joint_pose(joints, reals, q, i)
        if parent < 0:
            # X_Wi, its position taken from the first joint's origin
            if i == 0:
                origin = p_Pi
            R, p = R_Pi, sub3(p_Pi, origin)
            V = ZERO6
        else:
            # X_Wi = X_Wλ X_λ,i
            R, p = compose(load9(pose[parent], 0), load3(pose[parent], 9), R_Pi, p_Pi)
            V = load6(vel[parent], 0)
        store(pose[i], 0, R)
        store(pose[i], 9, p)
        for k in range(nv):
            # ξ_k = ᵂX_i S_k ;  V_i = V_λ + Σ_k ξ_k v_k
            xi_k = motion_to_parent(R, p, kinds.subspace_column(kind, axis, k))
            store(xi[iv + k], 0, xi_k)
            if moving:
                vk = v[iv + k]
                V = (V[0] + xi_k[0] * vk, V[1] + xi_k[1] * vk, V[2] + xi_k[2] * vk,
                     V[3] + xi_k[3] * vk, V[4] + xi_k[4] * vk, V[5] + xi_k[5] * vk)
        store(vel[i], 0, V)
        for k in range(nv):
            # ξ̇_k = V_i × ξ_k   (S is constant in the joint frame)
            store(xi_dot[iv + k], 0, motion_cross(V, load6(xi[iv + k], 0)))
        # I_i = ᵂX_i* I ⁱX_W ;  B_i = ½ [(V_i×*) I_i + (I_i V_i)×̄* − I_i (V_i×)]
        I = inertia_to_parent(R, p, load10(row, INERTIA))
        a, E = body_factor(I, V)
        store(inertia_c[i], 0, I)
        store(factor_c[i], 0, a)
        store(factor_c[i], 3, E)
    for k in range(n):
        for l in range(n):
            out[k, l] = 0.0
    for j in range(nj - 1, -1, -1):
        # I^c_j and B^c_j hold the whole subtree of j: its children come after it and were added
        I_c, B_c = load10(inertia_c[j], 0), load6(factor_c[j], 0) + load6(factor_c[j], 6)
        for k in range(joints[j, IV], joints[j, IV] + joints[j, NV]):
            xi_k, xi_dot_k = load6(xi[k], 0), load6(xi_dot[k], 0)
            # rows: I^c_j ξ_k and B^c_jᵀ ξ_k ;  column: I^c_j ξ̇_k + B^c_j ξ_k
            I_xi = inertia_times(I_c, xi_k)
            Bt_xi = factor_transpose_times(B_c, xi_k)
            column = add6(inertia_times(I_c, xi_dot_k), factor_times(B_c, xi_k))
            a = j
            while a >= 0:
                for l in range(joints[a, IV], joints[a, IV] + joints[a, NV]):
                    xi_l = load6(xi[l], 0)
                    # C_kl = (I^c_j ξ_k)ᵀ ξ̇_l + (B^c_jᵀ ξ_k)ᵀ ξ_l
                    out[k, l] = dot6(I_xi, load6(xi_dot[l], 0)) + dot6(Bt_xi, xi_l)
                    if a != j:
                        # C_lk = ξ_lᵀ (I^c_j ξ̇_k + B^c_j ξ_k)
                        out[l, k] = dot6(xi_l, column)
                a = joints[a, PARENT]
        parent = joints[j, PARENT]
        if parent >= 0:
            # I^c_λ += I^c_j ;  B^c_λ += B^c_j   (all in the same coordinates)
            for c in range(10):
                inertia_c[parent, c] += inertia_c[j, c]
            for c in range(12):
                factor_c[parent, c] += factor_c[j, c]
    nan_unless_finite(q, v, x2, x3, out)
