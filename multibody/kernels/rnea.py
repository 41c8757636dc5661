"""Recursive Newton–Euler: inverse dynamics, bias forces, gravity and joint reaction forces.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, Table 5.1, in joint
coordinates: each body's velocity, acceleration and force are expressed in its own joint frame.
Gravity is a fictitious acceleration of the world, ``a₀ = [−g; 0]`` (RBDA §5.3). The joints' armature
adds ``armature ⊙ a`` to ``τ``, the term ``diag(armature) a`` of ``M a`` (Pinocchio's ``rnea``; MuJoCo's
``qM``, whose diagonal holds ``dof_armature``); it moves no body, so the body forces leave it out.
"""

from __future__ import annotations

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .spatial import (add6, force_cross, force_to_parent, inertia_times, load10, load3, load6, load9, motion_cross,
                      motion_to_child, nan_unless_finite, store, sub6)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs: per joint its pose in its parent (12), velocity,
    acceleration and force (6 each)."""
    return 30 * nj


@njit(cache=True, error_model="numpy")
def forces(joints, reals, q, v, a, f_ext, ws):
    """The two passes of RBDA Table 5.1; returns the per-joint arrays of ``ws`` they fill:
    ``pose (nj, 12)`` the pose ``(R, p)`` of each joint frame in its parent's (``R`` row-major, then
    ``p``), ``vel``, ``acc (nj, 6)`` the body velocities and accelerations, and ``force (nj, 6)`` the force
    each joint transmits from its parent to its subtree, all in joint coordinates.

    ``v`` or ``a`` of length 0 stands for zero, ``f_ext`` of length 0 for no external force (else
    ``(6 nj,)``: one force per joint in its frame).
    """
    nj = joints.shape[0]
    pose = ws[: 12 * nj].reshape((nj, 12))
    vel = ws[12 * nj : 18 * nj].reshape((nj, 6))
    acc = ws[18 * nj : 24 * nj].reshape((nj, 6))
    force = ws[24 * nj : 30 * nj].reshape((nj, 6))
    g = load3(reals[nj], GRAVITY)
    moving, accelerated, loaded = v.shape[0] > 0, a.shape[0] > 0, f_ext.shape[0] > 0
    for i in range(nj):
        parent, kind, iv, nv = joints[i, PARENT], joints[i, KIND], joints[i, IV], joints[i, NV]
        row = reals[i]
        axis = load3(row, AXIS)
        R, p = joint_pose(joints, reals, q, i)
        store(pose[i], 0, R)
        store(pose[i], 9, p)
        # v_J = S q̇_i ;  a_J = S q̈_i   (S constant in the joint frame: c_J = 0)
        v_J = kinds.motion(kind, axis, nv, v, iv) if moving else ZERO6
        a_J = kinds.motion(kind, axis, nv, a, iv) if accelerated else ZERO6
        if parent < 0:
            v_parent, a_parent = ZERO6, (-g[0], -g[1], -g[2], 0.0, 0.0, 0.0)
        else:
            v_parent, a_parent = load6(vel[parent], 0), load6(acc[parent], 0)
        # v_i = ⁱX_λ v_λ + v_J
        v_i = add6(motion_to_child(R, p, v_parent), v_J)
        # a_i = ⁱX_λ a_λ + a_J + v_i × v_J
        a_i = add6(add6(motion_to_child(R, p, a_parent), a_J), motion_cross(v_i, v_J))
        # f_i = I_i a_i + v_i ×* I_i v_i − f_ext,i
        I = load10(row, INERTIA)
        f_i = add6(inertia_times(I, a_i), force_cross(v_i, inertia_times(I, v_i)))
        if loaded:
            f_i = sub6(f_i, load6(f_ext, 6 * i))
        store(vel[i], 0, v_i)
        store(acc[i], 0, a_i)
        store(force[i], 0, f_i)
    for i in range(nj - 1, -1, -1):
        parent = joints[i, PARENT]
        if parent >= 0:
            # f_λ(i) += λX_i* f_i
            f_up = force_to_parent(load9(pose[i], 0), load3(pose[i], 9), load6(force[i], 0))
            store(force[parent], 0, add6(load6(force[parent], 0), f_up))
    return pose, vel, acc, force


@njit(cache=True, error_model="numpy")
def inverse_dynamics(joints, reals, frames, q, v, a, f_ext, out, ws):
    """``τ = Sᵢᵀ fᵢ + armature ⊙ a`` for every joint (RBDA Table 5.1; module docstring) into ``out[0] (nv,)``:
    N or N m per coordinate.

    ``q (nq,)``, ``v, a (nv,)`` (length 0: zero, which gives ``g`` or ``h``), ``f_ext (6 nj,)`` or
    empty. ``frames`` is unused.
    """
    joint_torques(joints, reals, a, forces(joints, reals, q, v, a, f_ext, ws)[3], out[0])
    nan_unless_finite(q, v, a, f_ext, out)


@njit(cache=True, error_model="numpy")
def joint_torques(joints, reals, a, force, tau):
    """``τ = Sᵢᵀ fᵢ + armature ⊙ a`` into ``tau (nv,)`` (N or N m) from the forces ``force (nj, 6)`` (each in its
    joint's frame) that :func:`forces` returns for the accelerations ``a (nv,)`` (length 0: zero): the projection
    that ends RBDA Table 5.1, the last step of :func:`inverse_dynamics`."""
    accelerated = a.shape[0] > 0
    for i in range(joints.shape[0]):
        kind, iv, nv = joints[i, KIND], joints[i, IV], joints[i, NV]
        # τ_i = S_iᵀ f_i
        kinds.project_force(kind, load3(reals[i], AXIS), nv, load6(force[i], 0), tau, iv)
        if accelerated:
            for k in range(nv):
                # τ_i,k += armature_i,k q̈_i,k
                tau[iv + k] += armature(reals, i, k) * a[iv + k]


@njit(cache=True, error_model="numpy")
def joint_reaction_forces(joints, reals, frames, q, v, a, f_ext, out, ws):
    """The force ``f_i`` each joint transmits to its subtree, in its frame, into ``out (nj, 6)``
    (RBDA Table 5.1, backward pass): the bodies' share of ``τ``, without the armature's. Arguments as
    :func:`inverse_dynamics`."""
    force = forces(joints, reals, q, v, a, f_ext, ws)[3]
    for i in range(joints.shape[0]):
        for k in range(6):
            out[i, k] = force[i, k]
    nan_unless_finite(q, v, a, f_ext, out)
