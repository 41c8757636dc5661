"""Kinetic and gravitational potential energy of the moving bodies.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008: the kinetic energy of a
rigid body ``½ vᵀ I v`` (eq. 2.67) summed over the bodies, with the body velocities of Table 5.1's
forward pass in joint coordinates, plus the joints' armature ``½ Σₖ armatureₖ vₖ²``, so that
``T = ½ vᵀ M v`` with the ``M`` of :func:`multibody.kernels.crba.mass_matrix` (Pinocchio's
``computeKineticEnergy`` adds the armature alike; MuJoCo's ``mj_energyVel`` forms ``½ vᵀ qM v``, whose
``qM`` holds it); the potential energy ``U = −Σ mᵢ gᵀ cᵢ`` from the world poses of
:func:`multibody.kernels.kinematics.joint_placements`. Bodies fixed to the world are not counted
(their energy is constant), as in Pinocchio's ``computePotentialEnergy``.
"""

from __future__ import annotations

from .layout import AXIS, GRAVITY, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import armature, joint_pose
from .kinematics import joint_motions, joint_placements, world_position
from .spatial import (add3, add6, dot3, dot6, inertia_times, load3, load6, load9, load10, motion_to_child,
                      nan_unless_finite, rotate, scale3, store)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs for any kernel of this module: :func:`mechanical_energy`'s pass of
    :func:`multibody.kernels.kinematics.joint_motions` (per joint its world pose, velocity and acceleration, 24, and
    the reference point, 12), which holds the kinetic energy's velocities (6 per joint) and the potential
    energy's poses (12 per joint and the reference point)."""
    return 24 * nj + 12


@njit(cache=True, error_model="numpy")
def body_kinetic_energy(joints, reals, i, v, v_i):
    """``½ v_iᵀ I_i v_i + ½ Σₖ armatureₖ vₖ²`` (J) of joint ``i``'s body, moving at ``v_i`` (6-tuple, its joint
    frame), and of its coordinates' armature at ``v (nv,)``: RBDA eq. 2.67."""
    # ½ v_iᵀ I_i v_i
    T = 0.5 * dot6(v_i, inertia_times(load10(reals[i], INERTIA), v_i))
    for k in range(joints[i, NV]):
        # + ½ armature_k v_k²
        v_k = v[joints[i, IV] + k]
        T += 0.5 * armature(reals, i, k) * v_k * v_k
    return T


@njit(cache=True, error_model="numpy")
def body_potential_energy(reals, pose, i, g):
    """``−gᵀ mᵢ cᵢ`` (J) of joint ``i``'s body, with its world pose in ``pose`` (rows of
    :func:`multibody.kernels.kinematics.joint_placements`) and the gravity ``g`` (m/s², world axes):
    ``mᵢ cᵢ = mᵢ p_Wi + R_Wi hᵢ``, ``hᵢ = mᵢ c`` the first moment in the joint frame."""
    row = reals[i]
    # m_i c_i = m_i p_Wi + R_Wi h_i
    moment = add3(scale3(row[INERTIA], world_position(pose, load3(pose[i], 9))),
                  rotate(load9(pose[i], 0), load3(row, INERTIA + 1)))
    return -dot3(g, moment)


@njit(cache=True, error_model="numpy")
def kinetic_energy(joints, reals, frames, q, v, x2, x3, out, ws):
    """``T = Σᵢ ½ vᵢᵀ Iᵢ vᵢ + ½ Σₖ armatureₖ vₖ² = ½ vᵀ M v`` (J) into ``out (1, 1)``, with ``vᵢ`` each body's
    velocity and ``Iᵢ`` its inertia, both in its joint frame (RBDA eq. 2.67, velocities by Table 5.1's
    forward pass; the armature as in the module docstring).

    ``q (nq,)``, ``v (nv,)``; ``frames``, ``x2``, ``x3`` unused. Pinocchio: ``computeKineticEnergy``.
    """
    nj = joints.shape[0]
    vel = ws[: 6 * nj].reshape((nj, 6))
    T = 0.0
    for i in range(nj):
        parent, kind = joints[i, PARENT], joints[i, KIND]
        row = reals[i]
        axis = load3(row, AXIS)
        R, p = joint_pose(joints, reals, q, i)
        v_parent = ZERO6 if parent < 0 else load6(vel[parent], 0)
        # v_i = ⁱX_λ v_λ + S q̇_i
        v_i = add6(motion_to_child(R, p, v_parent), kinds.motion(kind, axis, joints[i, NV], v, joints[i, IV]))
        store(vel[i], 0, v_i)
        T += body_kinetic_energy(joints, reals, i, v, v_i)
    out[0, 0] = T
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def potential_energy(joints, reals, frames, q, x1, x2, x3, out, ws):
    """``U = −Σᵢ mᵢ gᵀ cᵢ`` (J) into ``out (1, 1)`` over the moving bodies, ``cᵢ`` their world centres of
    mass and ``g`` the gravity (m/s², world axes).

    ``mᵢ cᵢ = mᵢ p_Wi + R_Wi hᵢ`` with ``hᵢ = mᵢ c`` the first moment in the joint frame.
    ``q (nq,)``; ``frames``, ``x1..x3`` unused. Pinocchio: ``computePotentialEnergy``.
    """
    nj = joints.shape[0]
    pose, _ = joint_placements(joints, reals, q, ws, None)
    g = load3(reals[nj], GRAVITY)
    U = 0.0
    for i in range(nj):
        U += body_potential_energy(reals, pose, i, g)
    out[0, 0] = U
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def mechanical_energy(joints, reals, frames, q, v, x2, x3, out, ws):
    """``E = T + U`` (J) into ``out (1, 1)``: :func:`kinetic_energy` plus :func:`potential_energy` from one pass
    down the tree (:func:`multibody.kernels.kinematics.joint_motions`: the world poses and the body velocities of
    RBDA Table 5.1's forward pass), the same sums as the two kernels', term for term.

    ``q (nq,)``, ``v (nv,)``; ``frames``, ``x2``, ``x3`` unused.
    """
    pose, vel, _ = joint_motions(joints, reals, q, v, ws, None)
    out[0, 0] = motion_energy(joints, reals, pose, vel, v)
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def motion_energy(joints, reals, pose, vel, v):
    """``E = T + U`` (J) of the state whose world poses ``pose (nj + 1, 12)`` and body velocities ``vel (nj, 6)``
    (joint coordinates, m/s and rad/s) a pass of :func:`multibody.kernels.kinematics.joint_motions` gave, ``v (nv,)``
    its velocity (the armature's terms)."""
    nj = joints.shape[0]
    g = load3(reals[nj], GRAVITY)
    T, U = 0.0, 0.0
    for i in range(nj):
        # T = Σᵢ ½ v_iᵀ I_i v_i + ½ Σₖ armature_k v_k² ;  U = −Σᵢ gᵀ m_i c_i
        T += body_kinetic_energy(joints, reals, i, v, load6(vel[i], 0))
        U += body_potential_energy(reals, pose, i, g)
    return T + U
