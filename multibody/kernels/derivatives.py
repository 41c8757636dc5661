"""Analytical derivatives of inverse and forward dynamics with respect to ``q`` and ``v``.

J. Carpentier and N. Mansard, *Analytical Derivatives of Rigid Body Dynamics Algorithms*, Robotics:
Science and Systems 2018 (Pinocchio's ``computeRNEADerivatives`` and ``computeABADerivatives``).
Derivatives with respect to ``q`` are taken in the tangent space: ``∂τ(q ⊕ δq)/∂δq`` at ``δq = 0``.

Every quantity is expressed in one frame fixed in the world, with world axes and its origin at the
reference point O of :func:`~multibody.kernels.kinematics.joint_placements`: the Jacobian columns
``s = ᴼX_i S_i e_k``, the body twists ``V_i``, the accelerations ``A_i`` (gravity folded in as
``A₀ = [−g; 0]``), the inertias ``Y_i`` and the forces ``F_i`` each joint transmits to its subtree, so
that ``τ_i = J_iᵀ F_i``.

Moving coordinate k of joint j by ``δq`` carries the whole subtree of j by the twist ``s δq``; a
quantity fixed in a moving body changes as ``s ×`` (motions), ``s ×*`` (forces) and
``s ×* Y − Y s×`` (inertias). ``τ_i`` is invariant under such a rigid motion, so only the parts that do
not ride along count: the twist and acceleration of joint j's parent λ do not move, which gives, with
``u = s × V_λ`` and ``P = s × A_λ + V_λ × u``, the change of each body force in the subtree of j

    δf_k = −Y_k P − Ẏ_k u − u ×* h_k                  (h_k = Y_k V_k,  Ẏ_k = V_k ×* Y_k − Y_k V_k×)

and, for a unit change of the velocity coordinate, with ``w = (V_λ + V_j) × s``,

    δf_k = Y_k w + Ẏ_k s + s ×* h_k.

Summed over a subtree these need only the composite ``Y_i``, ``Ẏ_i`` and momentum ``H_i`` of each
joint, so every entry costs O(1) after one forward and one backward pass:

* rows of the joints ``i`` in the subtree of j (j included): ``∂τ_i/∂q = J_iᵀ (−Y_i P − Ẏ_i u − u ×* H_i)``
  and ``∂τ_i/∂v = J_iᵀ (Y_i w + Ẏ_i s + s ×* H_i)``;
* rows of j's ancestors, whose own columns do not move but see the subtree force of j turn with it:
  ``∂τ_i/∂q = J_iᵀ (s ×* F_j − Y_j P − Ẏ_j u − u ×* H_j)`` and ``∂τ_i/∂v`` as for ``i = j``;
* every other entry is zero.
"""

from __future__ import annotations

import numpy as np

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import aba, crba, rnea
from . import joints as kinds
from .jit import njit
from .kinematics import joint_placements
from .spatial import (add6, add10, dot6, force_cross, force_to_parent, inertia_rate, inertia_times, inertia_to_parent,
                      motion_cross, motion_to_parent, nan_unless_finite, row3, row6, row9, row10, store_row, sub6)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs for either kernel: RNEA's passes (30 per joint), the world
    poses (12 per joint and the reference point), per joint its twist, acceleration and force (6 each),
    composite inertia and its rate (10 each), composite momentum (6) and a subtree mark (1); per
    coordinate its Jacobian column and two 6-vectors of its row; for the forward-dynamics derivatives ABA's and CRBA's
    workspaces, the accelerations, the factor of ``M`` and the coordinates' parents."""
    return max(87 * nj + 12 + 18 * nv, aba.workspace_size(nj, nv), crba.workspace_size(nj, nv)) + 2 * nv + nv * nv


@njit(cache=True, error_model="numpy")
def project_rows(joints, i, J, c, f, out, row_offset):
    """``out[row_offset + r, c] = J_r · f`` for each coordinate r of joint i (``J (nv, 6)``: one column of
    the Jacobian per row)."""
    iv = joints[i, IV]
    for r in range(iv, iv + joints[i, NV]):
        out[row_offset + r, c] = (J[r, 0] * f[0] + J[r, 1] * f[1] + J[r, 2] * f[2] + J[r, 3] * f[3] + J[r, 4] * f[4]
                                  + J[r, 5] * f[5])


@njit(cache=True, error_model="numpy")
def torque_derivatives(joints, reals, q, v, a, f_ext, out, ws):
    """``∂τ/∂q`` into ``out[:nv]`` and, when ``out`` has ``2 nv`` rows, ``∂τ/∂v`` into ``out[nv:]``, at the
    RNEA torque ``τ(q, v, a, f_ext)`` (module docstring). Arguments as :func:`rnea.inverse_dynamics`.

    For the rows of a joint i below the column's joint, ``J_rᵀ (−Y_i P − Ẏ_i u − u ×* H_i)`` is
    ``−(Y_i J_r)·P − (Ẏ_i J_r − J_r ×* H_i)·u`` (``Y_i`` and ``Ẏ_i`` are symmetric, and
    ``f·(u ×* H) = −(f ×* H)·u`` for a motion ``f``), so the two 6-vectors of each row are formed once and
    each entry costs two dot products.
    """
    nj, nv = joints.shape[0], out.shape[1]
    with_velocity = out.shape[0] == 2 * nv
    force_local = rnea.forces(joints, reals, q, v, a, f_ext, ws)
    vel_local, acc_local, transmitted = force_local[1], force_local[2], force_local[3]
    start = 30 * nj
    pose, _ = joint_placements(joints, reals, q, ws[start:], None)
    start += 12 * (nj + 1)
    twist = ws[start : start + 6 * nj].reshape((nj, 6))
    accel = ws[start + 6 * nj : start + 12 * nj].reshape((nj, 6))
    force = ws[start + 12 * nj : start + 18 * nj].reshape((nj, 6))
    inertia = ws[start + 18 * nj : start + 28 * nj].reshape((nj, 10))
    inertia_dot = ws[start + 28 * nj : start + 38 * nj].reshape((nj, 10))
    momentum = ws[start + 38 * nj : start + 44 * nj].reshape((nj, 6))
    in_subtree = ws[start + 44 * nj : start + 45 * nj]
    start += 45 * nj
    J = ws[start : start + 6 * nv].reshape((nv, 6))
    YJ = ws[start + 6 * nv : start + 12 * nv].reshape((nv, 6))
    BJ = ws[start + 12 * nv : start + 18 * nv].reshape((nv, 6))
    g = row3(reals, nj, GRAVITY)
    for i in range(nj):
        kind, iv = joints[i, KIND], joints[i, IV]
        axis = row3(reals, i, AXIS)
        R, p = row9(pose, i, 0), row3(pose, i, 9)
        # V_i = ᴼX_i v_i ;  A_i = ᴼX_i a_i ;  F_i = ᴼX_i* f_i
        V_i = motion_to_parent(R, p, row6(vel_local, i, 0))
        store_row(twist, i, 0, V_i)
        store_row(accel, i, 0, motion_to_parent(R, p, row6(acc_local, i, 0)))
        store_row(force, i, 0, force_to_parent(R, p, row6(transmitted, i, 0)))
        # Y_i = ᴼX_i* I_i ⁱX_O ;  Ẏ_i = V_i ×* Y_i − Y_i V_i× ;  h_i = Y_i V_i
        Y_i = inertia_to_parent(R, p, row10(reals, i, INERTIA))
        store_row(inertia, i, 0, Y_i)
        store_row(inertia_dot, i, 0, inertia_rate(Y_i, V_i))
        store_row(momentum, i, 0, inertia_times(Y_i, V_i))
        for k in range(joints[i, NV]):
            # J_r = ᴼX_i S_i e_k
            store_row(J, iv + k, 0, motion_to_parent(R, p, kinds.subspace_column(kind, axis, k)))
    for i in range(nj - 1, -1, -1):
        parent = joints[i, PARENT]
        if parent >= 0:
            # composites: Y_λ += Y_i ;  Ẏ_λ += Ẏ_i ;  H_λ += H_i
            store_row(inertia, parent, 0, add10(row10(inertia, parent, 0), row10(inertia, i, 0)))
            store_row(inertia_dot, parent, 0, add10(row10(inertia_dot, parent, 0), row10(inertia_dot, i, 0)))
            store_row(momentum, parent, 0, add6(row6(momentum, parent, 0), row6(momentum, i, 0)))
    for i in range(nj):
        Y_i, Y_dot_i, H_i = row10(inertia, i, 0), row10(inertia_dot, i, 0), row6(momentum, i, 0)
        for r in range(joints[i, IV], joints[i, IV] + joints[i, NV]):
            J_r = row6(J, r, 0)
            # Y_i J_r ;  Ẏ_i J_r − J_r ×* H_i
            store_row(YJ, r, 0, inertia_times(Y_i, J_r))
            store_row(BJ, r, 0, sub6(inertia_times(Y_dot_i, J_r), force_cross(J_r, H_i)))
    for r in range(out.shape[0]):
        for c in range(nv):
            out[r, c] = 0.0
    for j in range(nj):
        parent, iv_j = joints[j, PARENT], joints[j, IV]
        V_parent = row6(twist, parent, 0) if parent >= 0 else ZERO6
        A_parent = row6(accel, parent, 0) if parent >= 0 else (-g[0], -g[1], -g[2], 0.0, 0.0, 0.0)
        V_sum = add6(V_parent, row6(twist, j, 0))
        Y_j, Y_dot_j, H_j, F_j = row10(inertia, j, 0), row10(inertia_dot, j, 0), row6(momentum, j, 0), row6(force, j, 0)
        # the subtree of j: joints come after their parents
        in_subtree[j] = 1.0
        for i in range(j + 1, nj):
            in_subtree[i] = 1.0 if joints[i, PARENT] >= j and in_subtree[joints[i, PARENT]] == 1.0 else 0.0
        for c in range(iv_j, iv_j + joints[j, NV]):
            s = row6(J, c, 0)
            # u = s × V_λ ;  P = s × A_λ + V_λ × u ;  w = (V_λ + V_j) × s
            u = motion_cross(s, V_parent)
            P = add6(motion_cross(s, A_parent), motion_cross(V_parent, u))
            w = motion_cross(V_sum, s)
            for i in range(j, nj):
                if in_subtree[i] == 0.0:
                    continue
                for r in range(joints[i, IV], joints[i, IV] + joints[i, NV]):
                    a_r, b_r = row6(YJ, r, 0), row6(BJ, r, 0)
                    # ∂τ_r/∂q_c = −(Y_i J_r)·P − (Ẏ_i J_r − J_r ×* H_i)·u
                    out[r, c] = -dot6(a_r, P) - dot6(b_r, u)
                    if with_velocity:
                        # ∂τ_r/∂v_c = J_rᵀ (Y_i w + Ẏ_i s + s ×* H_i) = (Y_i J_r)·w + (Ẏ_i J_r − J_r ×* H_i)·s
                        out[nv + r, c] = dot6(a_r, w) + dot6(b_r, s)
            if parent < 0:
                continue
            # ancestors: ∂τ_i/∂q_c = J_iᵀ (s ×* F_j − Y_j P − Ẏ_j u − u ×* H_j) ;  ∂τ_i/∂v_c = J_iᵀ (Y_j w + Ẏ_j s + s ×* H_j)
            f_q = sub6(force_cross(s, F_j),
                       add6(add6(inertia_times(Y_j, P), inertia_times(Y_dot_j, u)), force_cross(u, H_j)))
            f_v = add6(add6(inertia_times(Y_j, w), inertia_times(Y_dot_j, s)), force_cross(s, H_j))
            ancestor = parent
            while ancestor >= 0:
                project_rows(joints, ancestor, J, c, f_q, out, 0)
                if with_velocity:
                    project_rows(joints, ancestor, J, c, f_v, out, nv)
                ancestor = joints[ancestor, PARENT]


@njit(cache=True, error_model="numpy")
def inverse_dynamics_derivatives(joints, reals, frames, q, v, a, f_ext, out, ws):
    """``∂τ/∂q`` into ``out[:nv]`` and ``∂τ/∂v`` into ``out[nv:]`` (``out (2 nv, nv)``), or ``∂τ/∂q``
    alone for ``out (nv, nv)``, where ``τ = RNEA(q, v, a, f_ext)`` (Carpentier & Mansard 2018; module
    docstring). Units: N/m, N, N·m/rad, … per pair of coordinates. ``∂τ/∂a = M(q)``, the armature on its
    diagonal; the armature's term ``armature ⊙ a`` of ``τ`` depends on neither ``q`` nor ``v``.

    ``q (nq,)``, ``v, a (nv,)`` (length 0: zero), ``f_ext (6 nj,)`` (one force per joint in its frame)
    or empty; with ``v`` and ``a`` empty, ``∂τ/∂q`` is ``∂g/∂q``. ``frames`` is unused. Pinocchio:
    ``computeRNEADerivatives``, ``computeGeneralizedGravityDerivatives``.
    """
    torque_derivatives(joints, reals, q, v, a, f_ext, out, ws)
    nan_unless_finite(q, v, a, f_ext, out)


@njit(cache=True, error_model="numpy")
def forward_dynamics_derivatives(joints, reals, frames, q, v, tau, f_ext, out, ws):
    """``∂a/∂q``, ``∂a/∂v`` and ``∂a/∂τ`` into the three ``(nv, nv)`` blocks of ``out (3 nv, nv)``, where
    ``a = ABA(q, v, τ, f_ext)``.

    Differentiating ``M(q) a + h(q, v) − Σ Jᵀ f_ext = τ`` at the ABA acceleration gives
    ``∂a/∂(q, v) = −M⁻¹ ∂τ/∂(q, v)|_a`` and ``∂a/∂τ = M⁻¹`` (Carpentier & Mansard 2018, §IV), with
    ``∂τ/∂(q, v)`` from :func:`torque_derivatives` at ``(q, v, a)`` and ``M⁻¹`` applied through the
    sparse ``M = Lᵀ L`` of :func:`crba.factor_ltl` on CRBA's ``M`` (RBDA §6.5), which the branches of a
    tree leave sparse; ``M`` holds the armature, as the ABA acceleration does (Pinocchio alike). ``M`` not positive definite leaves NaN in ``out``. Arguments as
    :func:`aba.forward_dynamics`. Pinocchio: ``computeABADerivatives``.
    """
    nv = out.shape[1]
    tail = ws.shape[0] - 2 * nv - nv * nv
    acc = ws[tail : tail + nv].reshape((1, nv))
    M = ws[tail + nv : tail + nv + nv * nv].reshape((nv, nv))
    parent = ws[tail + nv + nv * nv :].view(np.int64)
    crba.coordinate_parents(joints, parent)
    crba.mass_matrix(joints, reals, frames, q, v, tau, f_ext, M, ws)
    if not crba.factor_ltl(M, parent):
        for r in range(out.shape[0]):
            for c in range(nv):
                out[r, c] = np.nan
        return
    aba.forward_dynamics(joints, reals, frames, q, v, tau, f_ext, acc, ws)
    torque_derivatives(joints, reals, q, v, acc[0], f_ext, out[: 2 * nv], ws)
    for r in range(nv):
        for c in range(nv):
            # −∂τ/∂(q, v), and the identity for ∂a/∂τ
            out[r, c] = -out[r, c]
            out[nv + r, c] = -out[nv + r, c]
            out[2 * nv + r, c] = 1.0 if r == c else 0.0
    # ∂a/∂q = −M⁻¹ ∂τ/∂q ;  ∂a/∂v = −M⁻¹ ∂τ/∂v ;  ∂a/∂τ = M⁻¹
    crba.solve_ltl(M, parent, out[:nv])
    crba.solve_ltl(M, parent, out[nv : 2 * nv])
    crba.solve_ltl(M, parent, out[2 * nv :])
    nan_unless_finite(q, v, tau, f_ext, out)
