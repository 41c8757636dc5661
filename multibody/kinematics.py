"""Forward kinematics, Jacobians and their time variation, batched over leading axes.

Naming: ``R_WJ, p_WJ`` is the pose of joint frame J in the world W; a *world Plücker* motion
vector is expressed in world axes and taken at the world origin (its linear part is the velocity
of the body point that currently coincides with the world origin). Inside, the algorithms take
their Plücker coordinates at the first joint's origin ``O`` instead (``p_OJ``; see
:func:`_joint_frames`). Velocities of a point are *world-aligned*: world axes, taken at the point
(Pinocchio's ``LOCAL_WORLD_ALIGNED``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import lanes, spatial
from .spatial import matvec


def local_poses(model, q):
    """Pose ``X_λ(i),i(q) = X_T,i X_J,i(q_i)`` of every joint frame in its parent joint frame, on lanes.

    ``q (nq, N)`` -> homogeneous ``X = [[R, p], [0, 1]] (nj, 4, 4, N)`` (RBDA §4.1: the tree transform
    ``X_T`` is the joint's placement, followed by the joint transform ``X_J``); one call per joint type.
    """
    X = np.empty((model.njoints, 4, 4, q.shape[-1]))
    X[:, 3] = _HOMOGENEOUS_ROW
    for kind, index, q_index, constants in model.joint_groups:
        X[index, :3] = kind.group_transform(constants, q[q_index])
    return X


_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])[:, None]


def world_poses(model, q):
    """World pose of every joint frame on lanes: ``q (nq, N)`` -> ``R_WJ (nj, 3, 3, N)``, ``p_WJ (nj, 3, N)``.

    ``X_W,i = X_W,λ(i) X_λ(i),i`` level by level down the tree: all joints of one depth at once (one lane:
    by the Plücker poses of :func:`_plucker_poses`).
    """
    if q.shape[-1] == 1:
        R_WJ, p_WO, p_OJ = _joint_poses(model, q)
        return R_WJ, p_WO + p_OJ
    X_local = local_poses(model, q)
    X_world = np.empty((model.njoints, 3, 4, q.shape[-1]))
    for level, (index, parents) in enumerate(model.levels):
        X_world[index] = X_local[index, :3] if level == 0 else lanes.matmul(X_world[parents], X_local[index])
    return X_world[:, :, :3], X_world[:, :, 3]


def _plucker_poses(model, q):
    """Plücker poses ``ᴼP_J = [[R, 0, p], [[p]× R, R, 0], [0, 0, 1]]`` (:func:`~multibody.spatial.plucker_pose`)
    of the joint frames at one configuration ``q (nq,)``: ``(nj, 7, 7)``, relative to the reference point
    ``O`` of :func:`_joint_frames`, and its world position ``p_WO (3,)``.

    ``ᴼP_i = ᴼP_λ(i) P_λ(i),i`` level by level down the tree, written in place where the level's joints are a
    view: one NumPy call per level of a chain. The products give the force transforms ``ᴼX_J*`` and the
    positions ``p_OJ`` at once, far fewer NumPy calls than forming the transforms from the poses (the
    single configuration's cost is all in the calls).
    """
    P_local = np.empty((model.njoints, 7, 7))
    for kind, index, q_index, constants in model.plucker_pose_groups:
        P_local[index] = kind.group_plucker_poses(constants, q[q_index])
    P = np.empty_like(P_local)
    levels = model.pose_levels
    if not levels:
        return P, np.zeros(3)
    # The roots relative to O, the first joint's origin
    roots = levels[0][0]
    p_WO = P_local[0, :3, 6]
    if isinstance(roots, int):
        # Joint 0 alone, at O: its translation zeroed (by a product, so that a non-finite pose still shows)
        np.multiply(P_local[0], _AT_ORIGIN, out=P[0])
    else:
        P[roots] = spatial.plucker_pose(P_local[roots, :3, :3], P_local[roots, :3, 6] - p_WO)
    for index, parents, view in levels[1:]:
        if view:
            np.matmul(P[parents], P_local[index], out=P[index])
        else:
            P[index] = P[parents] @ P_local[index]
    return P, p_WO


#: A Plücker pose times this (entry by entry) has no translation: p and [p]× R zero, the rest as it was
_AT_ORIGIN = np.ones((7, 7))
_AT_ORIGIN[:3, 6] = _AT_ORIGIN[3:6, :3] = 0.0


class JointFrames(NamedTuple):
    """The joint frames of one pass down the tree, on lanes (see :func:`_joint_frames`)."""

    R_WJ: np.ndarray  # (nj, 3, 3, N) world orientations
    p_WO: np.ndarray  # (3, N) world position of the reference point O, the first joint's origin
    p_OJ: np.ndarray  # (nj, 3, N) joint origins relative to O
    xi: np.ndarray  # (nv, 6, N) motion subspaces, world axes at O


def _joint_frames(model, q):
    """World poses of the joint frames and the motion subspaces, on lanes (``q (nq, N)``).

    Positions and Plücker coordinates are taken at ``O``, the origin of the first joint, not of the
    world: at a point far from the bodies, coordinates carry moments (``p × f``, ``m |p|²``) that
    swamp the local ones and cost digits (a 2 kg body 170 m from the world origin lost 6 of them).
    Velocities, accelerations of points, joint forces and energies do not depend on the point.
    """
    if q.shape[-1] == 1:
        return _single_joint_frames(model, q)[0]
    R_WJ, p_WO, p_OJ = _joint_poses(model, q)
    return JointFrames(R_WJ, p_WO, p_OJ, motion_subspaces(model, R_WJ, p_OJ))


def _single_joint_frames(model, q):
    """:func:`_joint_frames` of one lane (``q (nq, 1)``), and the force transforms ``ᴼX_J* (nj, 6, 6)`` they
    come from (:func:`_plucker_poses`): ``ξ = ᴼX_J S = Π ᴼX_J* Π S``, Π swapping the linear and angular halves
    of a spatial vector."""
    P, p_WO = _plucker_poses(model, q[:, 0])
    X_star = P[:, :6, :6]
    xi = (_at_dofs(model, X_star) @ model.angular_first_subspaces).take(_SWAP_HALVES, axis=-2)
    return JointFrames(*_lane_poses(P, p_WO), xi), X_star


_SWAP_HALVES = np.array([3, 4, 5, 0, 1, 2])  # Π: [v; ω] <-> [ω; v]


def _lane_poses(P, p_WO):
    """``R_WJ (nj, 3, 3, 1)``, ``p_WO (3, 1)``, ``p_OJ (nj, 3, 1)`` from :func:`_plucker_poses`: views."""
    return P[:, :3, :3, None], p_WO[:, None], P[:, :3, 6, None]


def _joint_poses(model, q):
    """The poses of :func:`_joint_frames` without the motion subspaces: ``R_WJ``, ``p_WO``, ``p_OJ``."""
    if q.shape[-1] == 1:
        return _lane_poses(*_plucker_poses(model, q[:, 0]))
    R_WJ, p_WJ = world_poses(model, q)
    p_WO = p_WJ[0] if model.njoints else np.zeros(p_WJ.shape[1:])
    return R_WJ, p_WO, p_WJ - p_WO


def motion_subspaces(model, R_WJ, p_WJ):
    """Each velocity coordinate's unit motion as a world Plücker vector, on lanes: ``ξ (nv, 6, N)``.

    For coordinate k of joint j with subspace column ``s = [s_v; s_ω]`` (joint frame):
    ``ω_k = R_Wj s_ω``, ``v_k = R_Wj s_v + p_Wj × ω_k``.
    """
    # [R s_v, R s_ω] in one product
    columns = lanes.matmul(_at_dofs(model, R_WJ), model.subspace_columns)
    angular = columns[:, :, 1]
    return np.concatenate([columns[:, :, 0] + lanes.cross(_at_dofs(model, p_WJ), angular), angular], axis=-2)


def _at_dofs(model, x):
    """A per-joint lane array ``(nj, ...)`` taken at each velocity coordinate's joint: ``(nv, ...)``."""
    return x if model.one_dof_per_joint else x[model.dof_joint]


def _spatial_velocities(model, xi, v):
    """World velocity of every joint frame, ``V_j = Σ_{k ⪯ j} ξ_k v_k``, on lanes: ``(nj, 6, N)``."""
    return _support_sums(model, xi * v[:, None, :])


def _velocities(model, xi, v):
    """World velocities ``V_j`` ``(nj, 6, N)`` (:func:`_spatial_velocities`) and the column rates times
    speeds, ``ξ̇_k v_k = V_j(k) × ξ_k v_k`` ``(nv, 6, N)`` (RBDA eq. 2.37; a column moves with its own joint)."""
    xi_v = xi * v[:, None, :]
    V = _support_sums(model, xi_v)
    return V, lanes.motion_cross(_at_dofs(model, V), xi_v)


def _support_sums(model, x):
    """``y_j = Σ_{k ⪯ j} x_k``, the sum over the coordinates that move joint j: ``x (nv, ...) -> (nj, ...)``.

    The forward pass of a recursion such as ``v_i = v_λ(i) + ξ_i q̇_i``: one matrix product for small
    arrays, else level by level.
    """
    support, _, own = model.tree_sum_weights
    if lanes.small_tree_sum(support, x):
        return lanes.tree_sum(support, x)
    y = x.copy() if model.one_dof_per_joint else lanes.tree_sum(own, x)
    for index, parents in model.levels[1:]:
        y[index] += y[parents]
    return y


def _in_blocks(model, kernel, batch, *arrays, block=None):
    """Run a lane algorithm on arrays with leading batch axes, a block of states at a time.

    ``arrays`` are ``(x, k)`` pairs (``x (..., *c)`` with ``k`` component axes) or ``None``; each is
    put on lanes and ``kernel(*lane arrays)`` returns a lane array ``(*c, n)`` or a tuple of them,
    given back as ``batch + c``. Blocks of ``model.lane_block`` states (or ``block``) keep the
    temporaries small enough to stay in cache, and :func:`_raise_allocator_thresholds` keeps them
    out of the operating system's page allocator, which costs more than the arithmetic for large
    batches. Each block runs on :func:`_padded_lanes`.
    """
    # (one state: each array is a single lane as it is)
    lane_arrays = [None if x is None else lanes.to_lanes(x[0], x[1], batch) if batch else x[0][..., None]
                   for x in arrays]
    n, size = math.prod(batch), block or model.lane_block
    if 8 * 6 * max(model.njoints, 1) * n >= _DEFAULT_MMAP_THRESHOLD:  # per-joint spatial vectors, 8-byte floats
        _raise_allocator_thresholds()
    if n <= size:
        result = kernel(*_padded_lanes(lane_arrays, n))
        if isinstance(result, tuple):
            return tuple(_from_lanes(x[..., :n], batch) for x in result)
        return _from_lanes(result[..., :n], batch)
    out = None
    for start in range(0, n, size):
        count = min(size, n - start)
        part = kernel(*_padded_lanes([x if x is None or x.shape[-1] == 1 else x[..., start : start + count]
                                      for x in lane_arrays], count))
        parts = part if isinstance(part, tuple) else (part,)
        if out is None:
            out = [np.empty((n,) + x.shape[:-1]) for x in parts]
        for target, x in zip(out, parts):
            target[start : start + count] = np.moveaxis(x[..., :count], -1, 0)
    out = [x.reshape(batch + x.shape[1:]) for x in out]
    return tuple(out) if isinstance(part, tuple) else out[0]


#: From this many lanes on, lane arrays are padded (:func:`_padded_lanes`)
_PADDED_FROM = 512


def _padded_lanes(lane_arrays, n):
    """The lane arrays of ``n`` states, those of ``n`` lanes padded to an odd number of 64-byte cache lines
    (``n' ≡ 8 (mod 16)`` lanes) by repeating the last state, for ``n ≥ _PADDED_FROM``.

    Consecutive rows of a lane array lie ``8 n`` bytes apart. With ``n`` a multiple of 512 (a batch of
    4096, say) that is a multiple of 4 KiB, so that the rows of an operand all fall into the same few
    sets of the processor's caches and evict each other; the transposition of a result to the
    caller's ``(n, ...)`` layout suffered most (Panda's mass matrices at 4096 states: 0.3–2.1 µs per
    state, against 0.04 padded). An odd number of cache lines per row spreads the rows over all sets.
    The kernels see ``n'`` lanes, whose last ``n' − n`` results the caller drops.
    """
    if n < _PADDED_FROM or n % 16 == 8:
        return lane_arrays
    padded_count = n + (8 - n % 16) % 16
    padded = []
    for x in lane_arrays:
        if x is not None and x.shape[-1] == n:
            y = np.empty(x.shape[:-1] + (padded_count,), dtype=x.dtype)
            y[..., :n] = x
            y[..., n:] = x[..., -1:]
            x = y
        padded.append(x)
    return padded


#: glibc's initial ``M_MMAP_THRESHOLD`` (bytes): larger blocks are served by ``mmap`` until it rises
_DEFAULT_MMAP_THRESHOLD = 128 * 1024


def _raise_allocator_thresholds():
    """Let the temporaries of large lane arrays reuse memory instead of page-faulting anew.

    glibc's malloc serves blocks above its mmap threshold by ``mmap`` and returns heap memory above
    its trim threshold to the operating system on every ``free``; both thresholds rise when a block
    served by ``mmap`` is freed, to its size and twice that (mallopt(3), ``M_MMAP_THRESHOLD``).
    Until something in the process has freed a large array, every temporary above 128 KiB is thus
    mapped, faulted in and given back, within a block and from block to block, which costs more
    than its arithmetic (Panda at 4096 states in a fresh process: RNEA 2.3 µs per state instead
    of 1.3, ABA 6.8 instead of 4.9).
    Allocating and freeing one untouched 16 MB array (below glibc's 32 MB ceiling for the
    adjustment) puts the thresholds where it would settle anyway; elsewhere it costs nothing.
    """
    np.empty(2**21)


def _from_lanes(x, batch):
    """A lane result ``(*c, N)`` with the common batch shape (one lane broadcasts to all states)."""
    if x.shape[-1] == 1 and batch != ():
        x = np.broadcast_to(x, x.shape[:-1] + (int(np.prod(batch)),))
    return lanes.from_lanes(x, batch)


def joint_world_poses(model, q):
    """World pose of every joint frame: ``R_WJ (..., nj, 3, 3)``, ``p_WJ (..., nj, 3)``."""
    q = np.asarray(q, dtype=float)
    R, p = world_poses(model, lanes.to_lanes(q))
    return lanes.from_lanes(R, q.shape[:-1]), lanes.from_lanes(p, q.shape[:-1])


def _body_world_poses(model, R_WJ, p_WJ):
    """World poses of all bodies from the joint poses: ``X_WB = X_WJ(b) X_J(b),B``."""
    batch = R_WJ.shape[:-3]
    # A body fixed to the world uses the identity as its "joint" pose; index -1 picks that slot.
    R_ext = np.concatenate([R_WJ, np.broadcast_to(np.eye(3), batch + (1, 3, 3))], axis=-3)
    p_ext = np.concatenate([p_WJ, np.zeros(batch + (1, 3))], axis=-2)
    R_JB, p_JB = model.body_placements[:, :3, :3], model.body_placements[:, :3, 3]
    return spatial.compose(R_ext[..., model.body_joints, :, :], p_ext[..., model.body_joints, :], R_JB, p_JB)


def forward_kinematics(model, q):
    """World placements of every body: ``(..., nbodies, 4, 4)``, in ``model.body_names`` order.

    ``q (..., nq)``. Pinocchio counterpart: ``forwardKinematics`` + ``updateFramePlacements``.
    """
    q = model.check_configuration(q)
    R_WB, p_WB = _body_world_poses(model, *joint_world_poses(model, q))
    return spatial.pose_matrix(R_WB, p_WB)


def _point(point):
    """A body-frame point ``(..., 3)`` (m) as a float array, the body origin for ``None``."""
    point = np.zeros(3) if point is None else np.asarray(point, dtype=float)
    if point.shape[-1:] != (3,):
        raise ValueError(f"point must have shape (..., 3), got {point.shape}")
    return point


def jacobian(model, q, body, point=None):
    """World-aligned Jacobian of a body point: ``(..., 6, nv)``, rows ``[linear; angular]``.

    ``[ẋ; ω] = J(q) v`` where ``x`` is ``point`` (body-frame coordinates, m; default the body
    origin) and both rows are in world axes. ``body`` is a name from ``model.body_names`` or an index.
    Pinocchio counterpart: ``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)``.
    """
    q, b, point = model.check_configuration(q), model.body_index(body), _point(point)
    batch = spatial.batch_shape(q.shape[:-1], point.shape[:-1])
    j = model.body_joints[b]
    if j < 0:
        return np.zeros(batch + (6, model.nv))

    def kernel(q, p_BF):
        return lanes.transpose(_frame_on_lanes(model, j, _EYE, _point_in_joint_frame(model, b, p_BF), _joint_frames(model, q))[2])

    return _in_blocks(model, kernel, batch, (q, 1), (point, 1))


def jacobian_time_variation(model, q, v, body, point=None):
    """Time derivative ``J̇(q, v)`` of :func:`jacobian` along the motion: ``(..., 6, nv)``.

    A column ξ_k fixed in its joint's frame moves with that joint: ``ξ̇_k = V_j(k) × ξ_k`` (RBDA
    eq. 2.37). Then, for the point ``x`` moving with velocity ``ẋ = v_O,b + ω_b × x``:
    ``d/dt (v_k + ω_k × x) = v̇_k + ω̇_k × x + ω_k × ẋ``.
    Together with the Jacobian, ``J a + J̇ v`` is the point's classical acceleration.
    Pinocchio counterpart: ``getFrameJacobianTimeVariation(..., LOCAL_WORLD_ALIGNED)``.
    """
    q, v, b, point = model.check_configuration(q), model.check_velocity(v), model.body_index(body), _point(point)
    batch = spatial.batch_shape(q.shape[:-1], v.shape[:-1], point.shape[:-1])
    j = model.body_joints[b]
    if j < 0:
        return np.zeros(batch + (6, model.nv))

    def kernel(q, v, p_BF):
        frames = _joint_frames(model, q)
        xi, x = frames.xi, _frame_on_lanes(model, j, _EYE, _point_in_joint_frame(model, b, p_BF), frames)[1]
        V = _spatial_velocities(model, xi, v)
        xi_dot = lanes.motion_cross(_at_dofs(model, V), xi)
        x_dot = V[j, :3] + lanes.cross(V[j, 3:], x)
        linear = xi_dot[:, :3] + lanes.cross(xi_dot[:, 3:], x) + lanes.cross(xi[:, 3:], x_dot)
        J_dot = lanes.concatenate([linear, xi_dot[:, 3:]], axis=-2) * model.tree_sum_weights[0][j][:, None, None]
        return lanes.transpose(J_dot)

    return _in_blocks(model, kernel, batch, (q, 1), (v, 1), (point, 1))


_EYE = np.eye(3)


def _frame_on_lanes(model, j, R_JF, p_JF, frames):
    """Pose and Jacobian of a frame F fixed in the body of the moving joint ``j``, on lanes, from the
    joint frames ``frames`` (:class:`JointFrames`, or anything with their ``R_WJ``, ``p_OJ`` and ``xi``).

    F has orientation ``R_JF (3, 3)`` and origin ``p_JF (3, N)`` (which may vary per state) in the
    joint frame. Returns ``R_WF (3, 3, N)``, ``p_OF (3, N)`` relative to the reference point ``O`` and
    the world-aligned Jacobian of F's origin by columns ``(nv, 6, N)`` (zero for coordinates that do
    not move the body).
    """
    R_WJ, xi = frames.R_WJ[j], frames.xi
    R_WF = lanes.matmul(R_WJ, R_JF[:, :, None])
    p_OF = lanes.matvec(R_WJ, p_JF) + frames.p_OJ[j]
    # Column k at the point x: [v_k + ω_k × x; ω_k]
    linear = xi[:, :3] + lanes.cross(xi[:, 3:], p_OF)  # (points may vary per state where q does not)
    J = lanes.concatenate([linear, xi[:, 3:]], axis=-2) * model.tree_sum_weights[0][j][:, None, None]
    return R_WF, p_OF, J


def _point_in_joint_frame(model, b, p_BF):
    """A point ``p_BF (3, N)`` of body ``b`` in the frame of its joint: ``X_JB p_BF``."""
    X_JB = model.body_placements[b]
    return X_JB[:3, 3, None] + lanes.matvec(X_JB[:3, :3, None], p_BF)


def _frame_motion(model, b, X_BF, frames, V, xi_dot_v):
    """:func:`frame_kinematics` of the frame ``X_BF (4, 4)`` fixed in the moving body ``b``, on lanes, from
    the joint frames ``frames`` (see :func:`_frame_on_lanes`) and the velocities ``V``, ``ξ̇_k v_k`` of
    :func:`_velocities`: ``R_WF (3, 3, N)``, ``p_WF (3, N)``, ``J (6, nv, N)``, ``J̇v (6, N)``."""
    j, X_JF = model.body_joints[b], model.body_placements[b] @ X_BF
    R_WF, x, J = _frame_on_lanes(model, j, X_JF[:3, :3], X_JF[:3, 3, None], frames)
    # J̇ v (jacobian_time_variation) summed over the columns first: with the body's velocity V_b and
    # velocity-product acceleration A_b = Σ_k ξ̇_k v_k (world Plücker), the classical acceleration
    # of x at a = 0 is a_O + α × x + ω × ẋ, ẋ = v_O + ω × x.
    A_b = lanes.tree_sum(model.tree_sum_weights[0][j][None], xi_dot_v)[0]
    x_dot = V[j, :3] + lanes.cross(V[j, 3:], x)
    linear = A_b[:3] + lanes.cross(A_b[3:], x) + lanes.cross(V[j, 3:], x_dot)
    return R_WF, x + frames.p_WO, lanes.transpose(J), np.concatenate([linear, A_b[3:]], axis=-2)


def _frame_arguments(model, body, placement):
    """``(b, X_BF)``: the index of ``body`` (``None`` for the world) and the frame's 4×4 pose in it,
    validated (identity for ``None``)."""
    X_BF = np.eye(4) if placement is None else np.asarray(placement, dtype=float)
    if X_BF.shape != (4, 4):
        raise ValueError(f"placement must have shape (4, 4), got {X_BF.shape}")
    return (None if body is None else model.body_index(body)), X_BF


def _fixed_frame(model, b, X_BF, batch):
    """:func:`frame_kinematics` of a frame that does not move (``b`` ``None`` for the world, or a body
    fixed to it), or ``None`` when body ``b`` moves."""
    if b is not None and model.body_joints[b] >= 0:
        return None
    # A body fixed to the world: its placement is its world pose.
    X_WF = X_BF if b is None else model.body_placements[b] @ X_BF
    return (np.broadcast_to(X_WF[:3, :3], batch + (3, 3)), np.broadcast_to(X_WF[:3, 3], batch + (3,)),
            np.zeros(batch + (6, model.nv)), np.zeros(batch + (6,)))


def frame_kinematics(model, q, v, body, placement=None):
    """Everything a constraint needs about one frame F fixed in a body, from a single tree pass.

    ``placement`` is the 4×4 pose of F in the body frame (default identity); ``body`` a name or
    index, or ``None`` for a frame fixed in the world (then ``placement`` is its world pose).
    Returns ``(R_WF (..., 3, 3), p_WF (..., 3), J (..., 6, nv), J̇v (..., 6))``: the world pose,
    the world-aligned Jacobian of F's origin, and the velocity-product acceleration ``J̇ v``
    (classical linear acceleration of the origin and angular acceleration when ``a = 0``).
    """
    q = model.check_configuration(q)
    v = model.check_velocity(v)
    batch = spatial.batch_shape(q.shape[:-1], v.shape[:-1])
    b, X_BF = _frame_arguments(model, body, placement)
    fixed = _fixed_frame(model, b, X_BF, batch)
    if fixed is not None:
        return fixed

    def kernel(q, v):
        frames = _joint_frames(model, q)
        return _frame_motion(model, b, X_BF, frames, *_velocities(model, frames.xi, v))

    return _in_blocks(model, kernel, batch, (q, 1), (v, 1))


def point_velocity(model, q, v, body, point=None):
    """``[ẋ; ω]`` of a body point in world axes (m/s, rad/s): ``J v``. ``-> (..., 6)``."""
    return matvec(jacobian(model, q, body, point), model.check_velocity(v))


def point_acceleration(model, q, v, a, body, point=None):
    """``[ẍ; ω̇]`` of a body point in world axes (m/s², rad/s²): ``J a + J̇ v``. ``-> (..., 6)``.

    ``ẍ`` is the classical (not spatial) acceleration. With ``a = 0`` this is the velocity-product
    term ``J̇ v`` that acceleration-level constraints need.
    """
    a = model.check_velocity(a, "a")
    return matvec(jacobian(model, q, body, point), a) + matvec(jacobian_time_variation(model, q, v, body, point), v)
