"""Kinematics: world placements of joints and frames, frame Jacobians, their time variation and the
velocity-product acceleration of frames.

R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008: forward kinematics
(§4.1, Table 5.1's forward pass), the Jacobian of a body point (§8.4 and eq. 8.20) and its time
derivative from ``ξ̇ = V × ξ`` for a motion vector fixed in a moving body (eq. 2.37). The forward
passes run in joint coordinates as :mod:`multibody.kernels.rnea` does; the Jacobian columns are then
mapped to world axes at the frame's point, as Pinocchio's ``computeJointJacobians`` and
``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` do.

A frame row (:mod:`multibody.tree`) is ``[joint, R_JF (9), p_JF (3)]``: a frame F fixed in the body
moved by ``joint`` with its pose ``X_JF`` in that joint's frame, or, for ``joint = -1``, a frame fixed
in the world with its world pose. Its world pose is ``X_WF = X_WJ X_JF``.

Jacobians have rows ``[linear; angular]`` and one column per velocity coordinate (zero for coordinates
that do not move the frame), in one of Pinocchio's three references (``ReferenceFrame``), given to the
kernels as a vector of one code (length 0: the first):

=======================  ============================================================================
code                     rows of ``J v``
=======================  ============================================================================
``LOCAL_WORLD_ALIGNED``  ``[ẋ; ω]``: the velocity of the frame's point and the angular velocity, world
                         axes
``WORLD``                the body's spatial velocity in world Plücker coordinates: ``[ẋ − ω × x; ω]``,
                         the velocity of the body point at the world origin
``LOCAL``                ``[R_WFᵀ ẋ; R_WFᵀ ω]``: both in the frame's axes
=======================  ============================================================================

Each time variation is the time derivative of the Jacobian in the same reference, as in Pinocchio's
``getFrameJacobianTimeVariation``.
"""

from __future__ import annotations

from .layout import AXIS, FRAME_JOINT, FRAME_POSITION, FRAME_ROTATION, IV, KIND, NV, PARENT
from . import joints as kinds
from .jit import njit
from .placement import joint_pose
from .spatial import (add3, add6, compose, compose_rotations, cross, load3, load6, load9, motion_cross, motion_to_child,
                      nan_unless_finite, rotate, rotate_back, scale3, store, sub3)

ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

#: Codes of the references a frame Jacobian is expressed in (module docstring)
LOCAL_WORLD_ALIGNED, WORLD, LOCAL = 0, 1, 2

#: Columns of one row of :func:`frame_motions`: ``R_WF`` (9, row-major), ``p_WF`` (3), ``J`` (6 × nv,
#: row-major), then ``J̇ v`` (6) at ``MOTION_JACOBIAN + 6 nv``
MOTION_ROTATION, MOTION_POSITION, MOTION_JACOBIAN = 0, 9, 12


@njit(cache=True, error_model="numpy")
def motion_columns(nv):
    """Columns of one frame's row in :func:`frame_motions`: ``18 + 6 nv``."""
    return 18 + 6 * nv


def workspace_size(nj, nv):
    """Floats of workspace one state needs for any kernel of this module: per joint its world pose
    (12), its velocity and its velocity-product acceleration (6 each), and the reference point (12)."""
    return 24 * nj + 12


@njit(cache=True, error_model="numpy")
def joint_placements(joints, reals, q, ws, needed):
    """World pose ``X_Wi = (R_Wi, p_Oi)`` of every joint frame into ``ws[:12 (nj + 1)]``, returned as
    ``(pose (nj + 1, 12), p_WO)`` (``R_Wi`` row-major, then ``p_Oi`` in m): RBDA §4.1, ``X_Wi = X_Wλ(i) X_T X_J(q_i)``.

    Positions are taken from the reference point O, the first joint's origin, whose world position
    ``p_WO`` is row ``nj``'s (at column 9): coordinates far from the world origin would cost the lever
    arms ``x − p_i`` of the Jacobians their digits.

    ``needed (nj,)``: only the joints marked non-zero are placed (the support paths of the frames a caller
    reads; parents come before children, so a marked joint's parent is placed first); ``None``: every joint.
    (No default: Numba's own CUDA target compiles a device function only for the arguments a call gives.)
    """
    nj = joints.shape[0]
    pose = ws[: 12 * (nj + 1)].reshape((nj + 1, 12))
    origin = reference_point(joints, reals, q, pose)
    for i in range(nj):
        if needed is not None and needed[i] == 0.0:
            continue
        parent = joints[i, PARENT]
        R, p = joint_pose(joints, reals, q, i)
        if parent >= 0:
            # X_Wi = X_Wλ X_λ(i),i
            R, p = compose(load9(pose[parent], 0), load3(pose[parent], 9), R, p)
        else:
            p = sub3(p, origin)
        store(pose[i], 0, R)
        store(pose[i], 9, p)
    return pose, origin


@njit(cache=True, error_model="numpy")
def mark_supports(joints, frames, needed):
    """``needed[i] = 1`` for the joints that move a frame of ``frames`` (the frames' joints and their
    ancestors), ``0`` for the others, whose placements those frames do not need (:func:`joint_placements`)."""
    for i in range(needed.shape[0]):
        needed[i] = 0.0
    for k in range(frames.shape[0]):
        i = frame_joint(frames, k)
        while i >= 0 and needed[i] == 0.0:
            needed[i] = 1.0
            i = joints[i, PARENT]


@njit(cache=True, error_model="numpy")
def joint_motions(joints, reals, q, v, ws, qdd):
    """World poses, velocities and accelerations of every joint frame (RBDA Table 5.1, forward pass with
    no gravity), in ``ws[:24 nj + 12]``. Returns ``pose (nj + 1, 12)`` as :func:`joint_placements`,
    ``vel (nj, 6)`` the body velocities ``v_i`` and ``acc (nj, 6)`` the spatial accelerations ``a_i`` for the
    joint accelerations ``qdd (nv,)`` (``None``: zero, the velocity-product accelerations), both in joint
    coordinates at the joint origin (m/s, rad/s; m/s², rad/s²).
    """
    nj = joints.shape[0]
    pose = ws[: 12 * (nj + 1)].reshape((nj + 1, 12))
    vel = ws[12 * (nj + 1) : 12 * (nj + 1) + 6 * nj].reshape((nj, 6))
    acc = ws[12 * (nj + 1) + 6 * nj : 12 * (nj + 1) + 12 * nj].reshape((nj, 6))
    origin = reference_point(joints, reals, q, pose)
    for i in range(nj):
        parent, kind = joints[i, PARENT], joints[i, KIND]
        row = reals[i]
        axis = load3(row, AXIS)
        R, p = joint_pose(joints, reals, q, i)
        # v_J = S q̇_i   (S constant in the joint frame: c_J = 0)
        v_J = kinds.motion(kind, axis, joints[i, NV], v, joints[i, IV])
        if parent < 0:
            R_W, p_W, v_parent, a_parent = R, sub3(p, origin), ZERO6, ZERO6
        else:
            # X_Wi = X_Wλ X_λ(i),i
            R_W, p_W = compose(load9(pose[parent], 0), load3(pose[parent], 9), R, p)
            v_parent, a_parent = load6(vel[parent], 0), load6(acc[parent], 0)
        # v_i = ⁱX_λ v_λ + v_J
        v_i = add6(motion_to_child(R, p, v_parent), v_J)
        # a_i = ⁱX_λ a_λ + S q̈_i + v_i × v_J
        a_i = add6(motion_to_child(R, p, a_parent), motion_cross(v_i, v_J))
        if qdd is not None:
            a_i = add6(a_i, kinds.motion(kind, axis, joints[i, NV], qdd, joints[i, IV]))
        store(pose[i], 0, R_W)
        store(pose[i], 9, p_W)
        store(vel[i], 0, v_i)
        store(acc[i], 0, a_i)
    return pose, vel, acc


@njit(cache=True, error_model="numpy")
def placed_motions(joints, reals, q, local, velocities, ws):
    """The world poses and body velocities of :func:`joint_motions` (no accelerations) from the joints' poses in
    their parents ``local (nj, 12)`` and their body velocities ``velocities (nj, 6)``, as a pass of
    :func:`multibody.kernels.rnea.forces` at ``q``, ``v`` returns them: the same numbers, without the joints'
    transforms and velocities computed a second time. Returns ``pose (nj + 1, 12)`` and ``vel (nj, 6)`` in ``ws`` as
    :func:`joint_motions` does."""
    nj = joints.shape[0]
    pose = ws[: 12 * (nj + 1)].reshape((nj + 1, 12))
    vel = ws[12 * (nj + 1) : 12 * (nj + 1) + 6 * nj].reshape((nj, 6))
    origin = reference_point(joints, reals, q, pose)
    for i in range(nj):
        parent = joints[i, PARENT]
        R, p = load9(local[i], 0), load3(local[i], 9)
        if parent < 0:
            R_W, p_W = R, sub3(p, origin)
        else:
            # X_Wi = X_Wλ X_λ(i),i
            R_W, p_W = compose(load9(pose[parent], 0), load3(pose[parent], 9), R, p)
        store(pose[i], 0, R_W)
        store(pose[i], 9, p_W)
        store(vel[i], 0, load6(velocities[i], 0))
    return pose, vel


@njit(cache=True, error_model="numpy")
def frame_joint(frames, k):
    """The joint that moves frame row ``k`` (``-1``: fixed in the world)."""
    return int(frames[k, FRAME_JOINT])


@njit(cache=True, error_model="numpy")
def frame_pose(pose, frames, k):
    """Pose ``(R_WF, p_OF)`` of frame row ``k``, position from the reference point O, from the joint poses
    ``pose (nj + 1, 12)`` of :func:`joint_placements`: ``X_WF = X_WJ X_JF`` (``X_JF`` itself for a frame
    fixed in the world)."""
    j = frame_joint(frames, k)
    R_JF = load9(frames[k], FRAME_ROTATION)
    if j < 0:
        return R_JF, frame_position(pose, frames, k)
    return compose_rotations(load9(pose[j], 0), R_JF), frame_position(pose, frames, k)


@njit(cache=True, error_model="numpy")
def frame_position(pose, frames, k):
    """Position ``p_OF`` (m, from the reference point O) of frame row ``k``, the position of :func:`frame_pose`
    without its rotation: ``p_OF = p_OJ + R_WJ p_JF`` (``p_JF − p_WO`` for a frame fixed in the world)."""
    j = frame_joint(frames, k)
    p_JF = load3(frames[k], FRAME_POSITION)
    if j < 0:
        return sub3(p_JF, load3(pose[pose.shape[0] - 1], 9))
    return add3(load3(pose[j], 9), rotate(load9(pose[j], 0), p_JF))


@njit(cache=True, error_model="numpy")
def reference_point(joints, reals, q, pose):
    """World position ``p_WO`` of the reference point O, the first joint's origin (the world origin for a
    model without joints), stored in ``pose``'s last row at column 9 and returned."""
    origin = (0.0, 0.0, 0.0)
    if joints.shape[0] > 0:
        origin = joint_pose(joints, reals, q, 0)[1]
    last = pose[pose.shape[0] - 1]
    store(last, 0, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    store(last, 9, origin)
    return origin


@njit(cache=True, error_model="numpy")
def world_position(pose, p_O):
    """``p_W = p_WO + p_O``: a position from the reference point back in world coordinates."""
    return add3(load3(pose[pose.shape[0] - 1], 9), p_O)


@njit(cache=True, error_model="numpy")
def world_origin(pose):
    """The world origin's position from the reference point O: ``−p_WO``."""
    return scale3(-1.0, load3(pose[pose.shape[0] - 1], 9))


@njit(cache=True, error_model="numpy")
def reference_code(reference):
    """The reference code held by the vector ``reference`` (length 0: ``LOCAL_WORLD_ALIGNED``)."""
    return LOCAL_WORLD_ALIGNED if reference.shape[0] == 0 else int(reference[0])


@njit(cache=True, error_model="numpy")
def rotate_columns_back(R, J):
    """``J ← diag(Rᵀ, Rᵀ) J`` for ``J (6, n)``: both row blocks from world axes into those of a frame
    with world orientation ``R``."""
    for c in range(J.shape[1]):
        u = rotate_back(R, (J[0, c], J[1, c], J[2, c]))
        w = rotate_back(R, (J[3, c], J[4, c], J[5, c]))
        for r in range(3):
            J[r, c] = u[r]
            J[3 + r, c] = w[r]


@njit(cache=True, error_model="numpy")
def jacobian_columns(joints, reals, pose, j, x, J):
    """World-aligned Jacobian at the world point ``x`` of the body of joint ``j`` into ``J (6, nv)``
    (every entry written; ``j = -1`` gives zero).

    The column of coordinate k of a supporting joint i is its subspace column ``s = [s_v; s_ω]``
    (joint-i coordinates) seen in world axes at ``x``: ``ω_k = R_Wi s_ω``,
    ``v_k = R_Wi s_v + ω_k × (x − p_Wi)`` (RBDA eq. 8.20 with ``ⁱX_W``'s rotation and lever).
    """
    for r in range(6):
        for c in range(J.shape[1]):
            J[r, c] = 0.0
    i = j
    while i >= 0:
        kind, iv = joints[i, KIND], joints[i, IV]
        axis = load3(reals[i], AXIS)
        R_Wi = load9(pose[i], 0)
        lever = sub3(x, load3(pose[i], 9))
        for k in range(joints[i, NV]):
            s = kinds.subspace_column(kind, axis, k)
            # ω_k = R_Wi s_ω ;  v_k = R_Wi s_v + ω_k × (x − p_Wi)
            w = rotate(R_Wi, (s[3], s[4], s[5]))
            u = add3(rotate(R_Wi, (s[0], s[1], s[2])), cross(w, lever))
            for r in range(3):
                J[r, iv + k] = u[r]
                J[3 + r, iv + k] = w[r]
        i = joints[i, PARENT]


@njit(cache=True, error_model="numpy")
def frame_point(frames, pose, point):
    """World position ``x`` of frames[0]'s origin displaced by ``point (3,)`` (frame axes, m; length 0:
    the origin): ``x = p_WF + R_WF point``."""
    R_WF, p_WF = frame_pose(pose, frames, 0)
    if point.shape[0] == 0:
        return p_WF
    return add3(p_WF, rotate(R_WF, load3(point, 0)))


@njit(cache=True, error_model="numpy")
def frame_placements(joints, reals, frames, q, x1, x2, x3, out, ws):
    """World placements of every frame row into ``out (m, 16)``: row k the homogeneous ``X_WF`` of
    ``frames[k]``, row-major 4×4 (bottom row ``0 0 0 1``; rotation, then position in m). RBDA §4.1.

    ``q (nq,)``; ``frames (m, 13)``; ``x1..x3`` unused. With ``frames = tree.bodies`` this is the forward
    kinematics of every body (Pinocchio: ``forwardKinematics`` + ``updateFramePlacements``, ``data.oMf``).
    """
    pose, _ = joint_placements(joints, reals, q, ws, None)
    for k in range(frames.shape[0]):
        R, p_O = frame_pose(pose, frames, k)
        p = world_position(pose, p_O)
        X = out[k]
        # X_WF = [[R_WF, p_WF], [0, 1]]
        for r in range(3):
            X[4 * r] = R[3 * r]
            X[4 * r + 1] = R[3 * r + 1]
            X[4 * r + 2] = R[3 * r + 2]
            X[4 * r + 3] = p[r]
        X[12], X[13], X[14], X[15] = 0.0, 0.0, 0.0, 1.0
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def frame_jacobian(joints, reals, frames, q, point, reference, x3, out, ws):
    """Jacobian ``J (6, nv)`` of a point of frames[0] into ``out``: ``J q̇`` is the velocity of the frame F
    placed at that point with frames[0]'s axes, rows ``[linear; angular]`` in the reference coded by
    ``reference`` (module docstring; length 0: ``LOCAL_WORLD_ALIGNED``, ``[ẋ; ω]`` in world axes);
    RBDA §8.4, eq. 8.20.

    ``q (nq,)``; ``point (3,)`` the point in frames[0]'s axes relative to its origin (m), or length 0 for
    the origin; ``x3`` unused. Columns of coordinates that do not move the frame are zero, all of
    them for a frame fixed in the world. Pinocchio: ``computeJointJacobians`` + ``getFrameJacobian``.
    """
    # only the joints that move the frame: RBDA eq. 8.20 sums over its support
    nj = joints.shape[0]
    needed = ws[12 * (nj + 1) : 13 * nj + 12]
    mark_supports(joints, frames[:1], needed)
    pose, _ = joint_placements(joints, reals, q, ws, needed)
    code = reference_code(reference)
    # WORLD: the velocity of the body point at the world origin; otherwise at F's origin x
    x = world_origin(pose) if code == WORLD else frame_point(frames, pose, point)
    jacobian_columns(joints, reals, pose, frame_joint(frames, 0), x, out)
    if code == LOCAL:
        # J_local = diag(R_WFᵀ, R_WFᵀ) J_world-aligned
        rotate_columns_back(frame_pose(pose, frames, 0)[0], out)
    nan_unless_finite(q, point, reference, x3, out)


@njit(cache=True, error_model="numpy")
def frame_jacobian_time_variation(joints, reals, frames, q, v, point, reference, out, ws):
    """Time derivative ``J̇ (6, nv)`` of :func:`frame_jacobian`, in the same reference, along the motion
    ``v`` into ``out``: ``J q̈ + J̇ q̇`` is the time derivative of the velocity ``J q̇``, which is

    * ``LOCAL_WORLD_ALIGNED``: the point's classical acceleration ``[ẍ; ω̇]`` (world axes);
    * ``WORLD``: the body's spatial acceleration in world Plücker coordinates;
    * ``LOCAL``: the body's spatial acceleration in F's coordinates (the time derivative of F's
      velocity in its own axes equals the spatial one, since ``v_F × v_F = 0``).

    A subspace column ``ξ_k`` of joint i is fixed in body i, so ``ξ̇_k = V_i × ξ_k`` (RBDA eq. 2.37),
    computed in joint-i coordinates as ``v_i × s``, then taken at the world origin (``WORLD``) or at the
    point ``x``, which itself moves with ``ẋ``: ``J̇_k = [(V_i × ξ_k)_v + ω_k × ẋ; (V_i × ξ_k)_ω]``. The
    ``LOCAL`` Jacobian is ``Rᵀ J`` blockwise with ``Ṙ = [ω_F]× R``, so its rate is ``Rᵀ (J̇ − [ω_F]× J)``.

    ``q (nq,)``, ``v (nv,)``, ``point (3,)`` in frames[0]'s axes (m) or length 0, ``reference`` as in
    :func:`frame_jacobian`. Zero for a frame fixed in the world. Pinocchio:
    ``computeJointJacobiansTimeVariation`` + ``getFrameJacobianTimeVariation``.
    """
    pose, vel, _ = joint_motions(joints, reals, q, v, ws, None)
    for r in range(6):
        for c in range(out.shape[1]):
            out[r, c] = 0.0
    j = frame_joint(frames, 0)
    if j < 0:
        nan_unless_finite(q, v, point, reference, out)
        return
    code = reference_code(reference)
    x = frame_point(frames, pose, point)
    y = world_origin(pose) if code == WORLD else x
    R_WF = frame_pose(pose, frames, 0)[0]
    # ω_F = R_Wj ω_j ;  ẋ = R_Wj v_j + ω_F × (x − p_Wj)
    R_Wj = load9(pose[j], 0)
    w_F = rotate(R_Wj, load3(vel[j], 3))
    x_dot = add3(rotate(R_Wj, load3(vel[j], 0)), cross(w_F, sub3(x, load3(pose[j], 9))))
    i = j
    while i >= 0:
        kind, iv = joints[i, KIND], joints[i, IV]
        axis = load3(reals[i], AXIS)
        R_Wi = load9(pose[i], 0)
        p_Wi = load3(pose[i], 9)
        v_i = load6(vel[i], 0)
        for k in range(joints[i, NV]):
            s = kinds.subspace_column(kind, axis, k)
            # ξ̇_k = v_i × s   (joint-i coordinates)
            c = motion_cross(v_i, s)
            # at y, world axes: [R c_v + (R c_ω) × (y − p_Wi); R c_ω],  and ω_k = R s_ω
            c_w = rotate(R_Wi, (c[3], c[4], c[5]))
            w = rotate(R_Wi, (s[3], s[4], s[5]))
            u = add3(rotate(R_Wi, (c[0], c[1], c[2])), cross(c_w, sub3(y, p_Wi)))
            if code != WORLD:
                # the point x moves: + ω_k × ẋ
                u = add3(u, cross(w, x_dot))
            if code == LOCAL:
                # Rᵀ (J̇ − [ω_F]× J), J's column [R s_v + ω_k × (x − p_Wi); ω_k]
                J_v = add3(rotate(R_Wi, (s[0], s[1], s[2])), cross(w, sub3(x, p_Wi)))
                u = rotate_back(R_WF, sub3(u, cross(w_F, J_v)))
                c_w = rotate_back(R_WF, sub3(c_w, cross(w_F, w)))
            for r in range(3):
                out[r, iv + k] = u[r]
                out[3 + r, iv + k] = c_w[r]
        i = joints[i, PARENT]
    nan_unless_finite(q, v, point, reference, out)


@njit(cache=True, error_model="numpy")
def frame_motions(joints, reals, frames, q, v, x2, x3, out, ws):
    """What a constraint on a frame needs, for every frame row, from one forward pass: row k of
    ``out (m, 18 + 6 nv)`` holds for ``frames[k]``

    ==============================  ====================================================================
    columns                         content
    ==============================  ====================================================================
    ``0:9``                         ``R_WF`` row-major
    ``9:12``                        ``p_WF`` (m)
    ``12 : 12 + 6 nv``              ``J (6, nv)`` row-major: rows ``[linear; angular]``, world axes at F's
                                    origin (as :func:`frame_jacobian`)
    ``12 + 6 nv : 18 + 6 nv``       ``J̇ v``: the classical linear acceleration of F's origin and the
                                    angular acceleration when ``q̈ = 0`` (world axes; m/s², rad/s²)
    ==============================  ====================================================================

    ``J̇ v`` is the body's velocity-product acceleration ``a_j`` (RBDA Table 5.1 with ``q̈ = 0``, no
    gravity) taken at F's origin ``p`` (joint-j coordinates) and made classical:
    ``ẍ = a_v + α × p + ω × (v + ω × p)`` (RBDA §2.11), then turned to world axes. A frame fixed in
    the world has ``J = 0`` and ``J̇ v = 0``. ``q (nq,)``, ``v (nv,)``; ``x2, x3`` unused.
    NumPy counterpart: ``multibody.kinematics.frame_kinematics``.
    """
    pose, vel, acc = joint_motions(joints, reals, q, v, ws, None)
    nv = (out.shape[1] - 18) // 6
    for k in range(frames.shape[0]):
        row = out[k]
        R_WF, p_OF = frame_pose(pose, frames, k)
        store(row, MOTION_ROTATION, R_WF)
        store(row, MOTION_POSITION, world_position(pose, p_OF))
        j = frame_joint(frames, k)
        jacobian_columns(joints, reals, pose, j, p_OF, row[MOTION_JACOBIAN : MOTION_JACOBIAN + 6 * nv].reshape((6, nv)))
        bias = MOTION_JACOBIAN + 6 * nv
        if j < 0:
            store(row, bias, ZERO6)
            continue
        p = load3(frames[k], FRAME_POSITION)
        v_j, w_j = load3(vel[j], 0), load3(vel[j], 3)
        a_j, alpha_j = load3(acc[j], 0), load3(acc[j], 3)
        # ẍ = a_v + α × p + ω × (v + ω × p)   (joint-j coordinates)
        x_ddot = add3(add3(a_j, cross(alpha_j, p)), cross(w_j, add3(v_j, cross(w_j, p))))
        R_Wj = load9(pose[j], 0)
        store(row, bias, rotate(R_Wj, x_ddot))
        store(row, bias + 3, rotate(R_Wj, alpha_j))
    nan_unless_finite(q, v, x2, x3, out)
