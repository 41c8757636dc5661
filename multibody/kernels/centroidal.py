"""Centre of mass and centroidal momentum of the moving bodies.

D. E. Orin, A. Goswami and S.-H. Lee, "Centroidal dynamics of a humanoid robot", *Autonomous Robots*
35 (2013) 161–176: the centroidal momentum ``h_G = A_G q̇`` is the sum of the bodies' momenta moved to
the centre of mass G, and the columns of the centroidal momentum matrix ``A_G`` are the momenta about
G of the composite rigid bodies (each joint's subtree) moving with one coordinate. Spatial algebra from
R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008; forward passes from
:mod:`multibody.kernels.kinematics`.

What is counted, as in Pinocchio (``centerOfMass``, ``computeCentroidalMap``): the bodies of the moving
joints, each the lump of its links; links fixed to the world are left out (their mass never moves).
The total mass ``M`` is theirs: with none, the centre of mass is ``0 / 0``, NaN. The joints' armature
(rotor inertia on the diagonal of the mass matrix) is no body's momentum and is left out, as Pinocchio
leaves it out of ``ccrba``.

Momenta have rows ``[linear; angular]``, world axes, the angular momentum about G. The sums over bodies
need them in one set of coordinates: world axes, with Plücker coordinates at the reference point O, the
first joint's origin (``docs/conventions.md``), moved to G at the end.
"""

from __future__ import annotations

import math

from .layout import AXIS, INERTIA, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .kinematics import joint_motions, joint_placements, world_position
from .spatial import (IDENTITY, add3, add6, cross, force_to_child, force_to_parent, inertia_rate, inertia_times,
                      inertia_to_parent, load3, load6, load9, load10, motion_cross, motion_to_parent, nan_unless_finite,
                      rotate, scale3, store, sub3)

ZERO3 = (0.0, 0.0, 0.0)


def workspace_size(nj, nv):
    """Floats of workspace one state needs for any kernel of this module: the forward pass of
    :func:`~multibody.kernels.kinematics.joint_motions` (``24 nj + 12``), then per joint a composite
    inertia and its rate (10 each)."""
    return 44 * nj + 12


@njit(cache=True, error_model="numpy")
def inverse_mass(M):
    """``1 / M``, NaN without moving mass (there is no centre of mass), also in plain Python
    (``NUMBA_DISABLE_JIT``), where a division by zero raises."""
    return 1.0 / M if M > 0.0 else math.nan


@njit(cache=True, error_model="numpy")
def store_column(out, c, values):
    """``out[:len(values), c] = values``."""
    for r in range(len(values)):
        out[r, c] = values[r]


@njit(cache=True, error_model="numpy")
def center_of_mass(joints, reals, frames, q, v, a, x3, out, ws):
    """The centre of mass ``c`` of the moving bodies and its time derivatives into ``out (k, 3)``, one per
    row: ``c`` (m), then for ``k ≥ 2`` its velocity ``ċ`` (m/s), for ``k = 3`` its acceleration ``c̈`` (m/s²);
    world frame.

    ``M c = Σᵢ mᵢ cᵢ`` over the moving bodies, from each body's first moment ``hᵢ = mᵢ c`` in its joint
    frame and the body's motion there (RBDA §2.11; ``vᵢ, ωᵢ, aᵢ, αᵢ`` from Table 5.1's forward pass):

        mᵢ cᵢ = mᵢ p_Wi + R_Wi hᵢ
        mᵢ ċᵢ = R_Wi (mᵢ vᵢ + ωᵢ × hᵢ)
        mᵢ c̈ᵢ = R_Wi (mᵢ aᵢ + αᵢ × hᵢ + ωᵢ × (mᵢ vᵢ + ωᵢ × hᵢ))

    ``q (nq,)``; ``v (nv,)`` for ``k ≥ 2``, ``a (nv,)`` (joint accelerations) for ``k = 3``, else length 0;
    ``frames``, ``x3`` unused. Pinocchio: ``centerOfMass(model, data, q[, v[, a]])``, ``data.com[0]``,
    ``data.vcom[0]``, ``data.acom[0]``.
    """
    nj = joints.shape[0]
    order = out.shape[0]
    if order == 1:
        pose, _ = joint_placements(joints, reals, q, ws, None)
        vel, acc = pose, pose  # unused
    elif order == 2:
        pose, vel, acc = joint_motions(joints, reals, q, v, ws, None)
    else:
        pose, vel, acc = joint_motions(joints, reals, q, v, ws, a)
    M = 0.0
    moment, momentum, rate = ZERO3, ZERO3, ZERO3
    for i in range(nj):
        I = load10(reals[i], INERTIA)
        m, h = I[0], (I[1], I[2], I[3])
        R_Wi = load9(pose[i], 0)
        M += m
        # m_i c_i = m_i p_Wi + R_Wi h_i   (positions from O)
        moment = add3(moment, add3(scale3(m, load3(pose[i], 9)), rotate(R_Wi, h)))
        if order >= 2:
            v_i, w_i = load3(vel[i], 0), load3(vel[i], 3)
            # m_i ċ_i = R_Wi (m_i v_i + ω_i × h_i)
            linear = add3(scale3(m, v_i), cross(w_i, h))
            momentum = add3(momentum, rotate(R_Wi, linear))
            if order == 3:
                # m_i c̈_i = R_Wi (m_i a_i + α_i × h_i + ω_i × (m_i v_i + ω_i × h_i))
                a_i, alpha_i = load3(acc[i], 0), load3(acc[i], 3)
                force = add3(add3(scale3(m, a_i), cross(alpha_i, h)), cross(w_i, linear))
                rate = add3(rate, rotate(R_Wi, force))
    per_mass = inverse_mass(M)
    store(out[0], 0, world_position(pose, scale3(per_mass, moment)))
    if order >= 2:
        store(out[1], 0, scale3(per_mass, momentum))
    if order == 3:
        store(out[2], 0, scale3(per_mass, rate))
    nan_unless_finite(q, v, a, x3, out)


@njit(cache=True, error_model="numpy")
def centroidal_momentum(joints, reals, frames, q, v, x2, x3, out, ws):
    """The centroidal momentum ``h_G = [M ċ; k_G]`` into ``out (1, 6)``: the moving bodies' linear momentum
    (kg m/s) and their angular momentum about the centre of mass G (kg m²/s), world axes.

    ``h_G = ᴳX*_O Σᵢ ᴼX*_i Iᵢ vᵢ`` (Orin, Goswami and Lee: the bodies' momenta moved to G), with the body
    velocities ``vᵢ`` of RBDA Table 5.1's forward pass and ``ᴳX*_O [f; n] = [f; n − (c − O) × f]``.

    ``q (nq,)``, ``v (nv,)``; ``frames``, ``x2``, ``x3`` unused. Pinocchio: ``computeCentroidalMomentum``
    (``data.hg``, linear first).
    """
    nj = joints.shape[0]
    pose, vel, _ = joint_motions(joints, reals, q, v, ws, None)
    M = 0.0
    moment = ZERO3
    F = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for i in range(nj):
        I = load10(reals[i], INERTIA)
        R_Wi, p_Oi = load9(pose[i], 0), load3(pose[i], 9)
        M += I[0]
        moment = add3(moment, add3(scale3(I[0], p_Oi), rotate(R_Wi, (I[1], I[2], I[3]))))
        # F += ᴼX*_i I_i v_i
        F = add6(F, force_to_parent(R_Wi, p_Oi, inertia_times(I, load6(vel[i], 0))))
    # h_G = ᴳX*_O F   (G's axes are the world's)
    store(out[0], 0, force_to_child(IDENTITY, scale3(inverse_mass(M), moment), F))
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def composite_inertias(joints, reals, pose, vel, Y, Y_dot):
    """Composite inertias of every joint's subtree in world axes about O into ``Y (nj, 10)``, and, when
    ``vel`` (the body velocities, joint coordinates) has rows, their rates into ``Y_dot (nj, 10)``.
    Returns ``(M, g, ġ)``: the moving mass and the centre of mass from O, ``g = c − O``, with its rate.

    Each body's ``Yᵢ = ᴼX*_i Iᵢ ⁱX_O`` (RBDA eq. 2.66) and its rate ``Ẏᵢ = Vᵢ ×* Yᵢ − Yᵢ Vᵢ×``
    (:func:`~multibody.kernels.spatial.inertia_rate`, ``Vᵢ = ᴼX_i vᵢ``), summed over the subtree from the
    leaves (children come after their parents). ``M g = Σ hᵢ``, the first moments about O, and
    ``M ġ = Σ ḣᵢ``.
    """
    nj = joints.shape[0]
    moving = vel.shape[0] > 0
    M = 0.0
    moment, moment_rate = ZERO3, ZERO3
    for i in range(nj):
        R_Wi, p_Oi = load9(pose[i], 0), load3(pose[i], 9)
        # Y_i = ᴼX*_i I_i ⁱX_O
        I = inertia_to_parent(R_Wi, p_Oi, load10(reals[i], INERTIA))
        store(Y[i], 0, I)
        M += I[0]
        moment = add3(moment, (I[1], I[2], I[3]))
        if moving:
            # Ẏ_i = V_i ×* Y_i − Y_i V_i× ,  V_i = ᴼX_i v_i
            I_dot = inertia_rate(I, motion_to_parent(R_Wi, p_Oi, load6(vel[i], 0)))
            store(Y_dot[i], 0, I_dot)
            moment_rate = add3(moment_rate, (I_dot[1], I_dot[2], I_dot[3]))
    for i in range(nj - 1, -1, -1):
        parent = joints[i, PARENT]
        if parent >= 0:
            # Y^c_λ += Y^c_i ;  Ẏ^c_λ += Ẏ^c_i
            for c in range(10):
                Y[parent, c] += Y[i, c]
                if moving:
                    Y_dot[parent, c] += Y_dot[i, c]
    per_mass = inverse_mass(M)
    return M, scale3(per_mass, moment), scale3(per_mass, moment_rate)


@njit(cache=True, error_model="numpy")
def centroidal_map(joints, reals, frames, q, x1, x2, x3, out, ws):
    """The centroidal momentum matrix ``A_G (6, nv)`` into ``out``: ``h_G = A_G v`` (rows ``[linear;
    angular]``, world axes, angular momentum about the centre of mass G). With ``out (3, nv)``, the
    centre-of-mass Jacobian ``J_c = A_G,linear / M`` instead: ``ċ = J_c v`` (m/s per unit of ``v``).

    Column k, a coordinate of joint i, is the momentum about G of joint i's subtree, a composite rigid
    body ``Y^c_i``, moving with the coordinate's subspace column ``ξ_k = ᴼX_i s_k`` (Orin, Goswami and
    Lee; RBDA Table 6.2's composites): ``A_G,k = ᴳX*_O Y^c_i ξ_k``.

    ``q (nq,)``; ``frames``, ``x1..x3`` unused. Pinocchio: ``computeCentroidalMap`` (``data.Ag``) and
    ``jacobianCenterOfMass``.
    """
    nj = joints.shape[0]
    pose, _ = joint_placements(joints, reals, q, ws, None)
    start = 24 * nj + 12
    Y = ws[start : start + 10 * nj].reshape((nj, 10))
    # no velocities (zero rows): no rates
    M, g, _ = composite_inertias(joints, reals, pose, Y[:0], Y, Y[:0])
    per_mass = inverse_mass(M)
    for i in range(nj):
        kind, iv = joints[i, KIND], joints[i, IV]
        axis = load3(reals[i], AXIS)
        R_Wi, p_Oi = load9(pose[i], 0), load3(pose[i], 9)
        Y_c = load10(Y[i], 0)
        for k in range(joints[i, NV]):
            # F = Y^c_i ξ_k ,  ξ_k = ᴼX_i s_k
            F = inertia_times(Y_c, motion_to_parent(R_Wi, p_Oi, kinds.subspace_column(kind, axis, k)))
            if out.shape[0] == 3:
                # J_c,k = f / M
                store_column(out, iv + k, scale3(per_mass, (F[0], F[1], F[2])))
            else:
                # A_G,k = ᴳX*_O F = [f; n − g × f]
                store_column(out, iv + k, force_to_child(IDENTITY, g, F))
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def centroidal_map_time_variation(joints, reals, frames, q, v, x2, x3, out, ws):
    """The time derivative ``Ȧ_G (6, nv)`` of :func:`centroidal_map` along the motion ``v`` into ``out``:
    ``ḣ_G = A_G q̈ + Ȧ_G q̇`` (world axes, angular rows about the moving centre of mass).

    With ``F = Y^c_i ξ_k`` the column at O: ``Ḟ = Ẏ^c_i ξ_k + Y^c_i ξ̇_k``, where ``Ẏ^c_i`` sums the
    subtree's inertia rates (:func:`composite_inertias`) and ``ξ̇_k = V_i × ξ_k`` (RBDA eq. 2.37, computed
    as ``ᴼX_i (v_i × s_k)``). Moving it to G, ``g = c − O``, whose rate is ``ċ``:
    ``Ȧ_G,k = [ḟ; ṅ − g × ḟ − ċ × f]``.

    ``q (nq,)``, ``v (nv,)``; ``frames``, ``x2``, ``x3`` unused. Pinocchio:
    ``computeCentroidalMapTimeVariation`` (``data.dAg``).
    """
    nj = joints.shape[0]
    pose, vel, _ = joint_motions(joints, reals, q, v, ws, None)
    start = 24 * nj + 12
    Y = ws[start : start + 10 * nj].reshape((nj, 10))
    Y_dot = ws[start + 10 * nj : start + 20 * nj].reshape((nj, 10))
    _, g, g_dot = composite_inertias(joints, reals, pose, vel, Y, Y_dot)
    for i in range(nj):
        kind, iv = joints[i, KIND], joints[i, IV]
        axis = load3(reals[i], AXIS)
        R_Wi, p_Oi = load9(pose[i], 0), load3(pose[i], 9)
        Y_c, Y_c_dot = load10(Y[i], 0), load10(Y_dot[i], 0)
        v_i = load6(vel[i], 0)
        for k in range(joints[i, NV]):
            s = kinds.subspace_column(kind, axis, k)
            xi = motion_to_parent(R_Wi, p_Oi, s)
            # ξ̇_k = ᴼX_i (v_i × s_k)
            xi_dot = motion_to_parent(R_Wi, p_Oi, motion_cross(v_i, s))
            # F = Y^c ξ ;  Ḟ = Ẏ^c ξ + Y^c ξ̇
            f = inertia_times(Y_c, xi)
            F_dot = add6(inertia_times(Y_c_dot, xi), inertia_times(Y_c, xi_dot))
            # Ȧ_G,k = [ḟ; ṅ − g × ḟ − ċ × f]
            column = force_to_child(IDENTITY, g, F_dot)
            store_column(out, iv + k, (column[0], column[1], column[2]) +
                         sub3((column[3], column[4], column[5]), cross(g_dot, (f[0], f[1], f[2]))))
    nan_unless_finite(q, v, x2, x3, out)
