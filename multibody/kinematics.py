"""Forward kinematics, Jacobians and their time variation, batched over leading axes.

Naming: ``R_WJ, p_WJ`` is the pose of joint frame J in the world W; a *world Plücker* motion
vector is expressed in world axes and taken at the world origin (its linear part is the velocity
of the body point that currently coincides with the world origin). Velocities of a point are
*world-aligned*: world axes, taken at the point (Pinocchio's ``LOCAL_WORLD_ALIGNED``).
"""

from __future__ import annotations

import math

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

    ``X_W,i = X_W,λ(i) X_λ(i),i`` level by level down the tree: all joints of one depth at once.
    """
    X_local = local_poses(model, q)
    X_world = np.empty((model.njoints, 3, 4, q.shape[-1]))
    for level, (index, parents) in enumerate(model.levels):
        # [R | p]_W,i = [R | p]_W,λ [[R, p], [0, 1]]_λ,i : one product of a 3×4 and a 4×4 matrix
        X_world[index] = X_local[index, :3] if level == 0 else lanes.matmul(X_world[parents], X_local[index])
    return X_world[:, :, :3], X_world[:, :, 3]


def motion_subspaces(model, R_WJ, p_WJ):
    """Each velocity coordinate's unit motion as a world Plücker vector, on lanes: ``ξ (nv, 6, N)``.

    For coordinate k of joint j with subspace column ``s = [s_v; s_ω]`` (joint frame):
    ``ω_k = R_Wj s_ω``, ``v_k = R_Wj s_v + p_Wj × ω_k``.
    """
    if not model.one_dof_per_joint:
        R_WJ, p_WJ = R_WJ[model.dof_joint], p_WJ[model.dof_joint]
    # [R s_v, R s_ω] in one product
    columns = lanes.matmul(R_WJ, model.subspace_columns)
    angular = columns[:, :, 1]
    return np.concatenate([columns[:, :, 0] + lanes.cross(p_WJ, angular), angular], axis=-2)


def _velocities(model, xi, v):
    """World velocities ``V_j = Σ_{k ⪯ j} ξ_k v_k`` ``(nj, 6, N)`` and the column rates times speeds,
    ``ξ̇_k v_k = V_j(k) × ξ_k v_k`` ``(nv, 6, N)`` (RBDA eq. 2.37; a column moves with its own joint)."""
    xi_v = xi * v[:, None, :]
    V = _support_sums(model, xi_v)
    return V, lanes.motion_cross(V if model.one_dof_per_joint else V[model.dof_joint], xi_v)


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
    temporaries small enough to stay in cache and out of the operating system's page allocator,
    which costs more than the arithmetic for large batches.
    """
    lane_arrays = [None if x is None else lanes.to_lanes(x[0], x[1], batch) for x in arrays]
    n, size = math.prod(batch), block or model.lane_block
    if n <= size:
        result = kernel(*lane_arrays)
        return tuple(_from_lanes(x, batch) for x in result) if isinstance(result, tuple) else _from_lanes(result, batch)
    _raise_allocator_thresholds()
    out = None
    for start in range(0, n, size):
        part = kernel(*(x if x is None or x.shape[-1] == 1 else x[..., start : start + size] for x in lane_arrays))
        parts = part if isinstance(part, tuple) else (part,)
        if out is None:
            out = [np.empty((n,) + x.shape[:-1]) for x in parts]
        for target, x in zip(out, parts):
            target[start : start + size] = np.moveaxis(x, -1, 0)
    out = [x.reshape(batch + x.shape[1:]) for x in out]
    return tuple(out) if isinstance(part, tuple) else out[0]


def _raise_allocator_thresholds():
    """Let the temporaries of consecutive lane blocks reuse memory instead of page-faulting anew.

    glibc's malloc serves blocks above its mmap threshold by ``mmap`` and returns heap memory above
    its trim threshold to the operating system on every ``free``; both thresholds rise when a block
    served by ``mmap`` is freed, to its size and twice that (mallopt(3), ``M_MMAP_THRESHOLD``).
    Until something in the process has freed a large array, a block's few MB of temporaries are
    thus given back and faulted in again for the next block, which costs more than their
    arithmetic (Panda RNEA at 4096 states: about 2 page faults and 2–3× the time per state).
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


def world_motion_subspaces(model, R_WJ, p_WJ):
    """:func:`motion_subspaces` for poses with leading batch axes: ``(..., nj, 3, 3), (..., nj, 3) -> (..., nv, 6)``."""
    batch = np.broadcast_shapes(R_WJ.shape[:-3], p_WJ.shape[:-2])
    xi = motion_subspaces(model, lanes.to_lanes(np.broadcast_to(R_WJ, batch + R_WJ.shape[-3:]), 3),
                          lanes.to_lanes(np.broadcast_to(p_WJ, batch + p_WJ.shape[-2:]), 2))
    return lanes.from_lanes(xi, batch)


def _point_in_world(model, R_WB, p_WB, point):
    """World position of a point given in body coordinates (default the body origin)."""
    if point is None:
        return p_WB
    point = np.asarray(point, dtype=float)
    if point.shape[-1:] != (3,):
        raise ValueError(f"point must have shape (..., 3), got {point.shape}")
    return matvec(R_WB, point) + p_WB


def _body_pose(model, q, body):
    b = model.body_index(body)
    R_WJ, p_WJ = joint_world_poses(model, q)
    R_WB, p_WB = _body_world_poses(model, R_WJ, p_WJ)
    return b, R_WJ, p_WJ, R_WB[..., b, :, :], p_WB[..., b, :]


def jacobian(model, q, body, point=None):
    """World-aligned Jacobian of a body point: ``(..., 6, nv)``, rows ``[linear; angular]``.

    ``[ẋ; ω] = J(q) v`` where ``x`` is ``point`` (body-frame coordinates, m; default the body
    origin) and both rows are in world axes. ``body`` is a name from ``model.body_names`` or an index.
    Pinocchio counterpart: ``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)``.
    """
    q = model.check_configuration(q)
    b = model.body_index(body)
    point = np.zeros(3) if point is None else np.asarray(point, dtype=float)
    if point.shape[-1:] != (3,):
        raise ValueError(f"point must have shape (..., 3), got {point.shape}")
    batch = np.broadcast_shapes(q.shape[:-1], point.shape[:-1])
    if model.body_joints[b] < 0:
        return np.zeros(batch + (6, model.nv))
    R_JB, p_JB = model.body_placements[b, :3, :3], model.body_placements[b, :3, 3]
    return _in_blocks(model, lambda q, p_BF: _frame_on_lanes(model, b, R_JB, p_JB, p_BF, q)[2], batch,
                      (q, 1), (point, 1))


def _frame_on_lanes(model, b, R_JF, p_JB, p_BF, q, v=None):
    """Pose, Jacobian and ``J̇ v`` of a frame F fixed in the moving body ``b``, on lanes.

    F sits at ``p_JF = p_JB + R_JB p_BF`` in the body's joint frame with orientation ``R_JF``;
    ``p_BF (3, N)`` may vary per state. Returns ``R_WF (3, 3, N)``, ``p_WF (3, N)``, the world-aligned
    Jacobian of F's origin ``(6, nv, N)`` and, given ``v (nv, N)``, ``J̇ v (6, N)``.
    """
    R_WJ, p_WJ = world_poses(model, q)
    xi = motion_subspaces(model, R_WJ, p_WJ)
    j = model.body_joints[b]
    R_WF = lanes.matmul(R_WJ[j], R_JF[:, :, None])
    R_JB = model.body_placements[b, :3, :3, None]
    p_WF = lanes.matvec(R_WJ[j], p_JB[:, None] + lanes.matvec(R_JB, p_BF)) + p_WJ[j]
    support = model.tree_sum_weights[0][j]  # (nv,) float: the coordinates that move the body
    # Column k at the point x: [v_k + ω_k × x; ω_k]
    angular = xi[:, 3:]
    linear = xi[:, :3] + lanes.cross(angular, p_WF)  # (points may vary per state where q does not)
    J = lanes.concatenate([linear, angular], axis=-2) * support[:, None, None]
    if v is None:
        return R_WF, p_WF, lanes.transpose(J)
    # The body's velocity V_b and velocity-product acceleration A_b = Σ_k ξ̇_k v_k (world Plücker), then
    # the classical acceleration of x at a = 0: a_O + α × x + ω × ẋ with ẋ = v_O + ω × x.
    V, xi_dot_v = _velocities(model, xi, v)
    A_b = lanes.tree_sum(support[None], xi_dot_v)[0]
    omega = V[j, 3:]
    x_dot = V[j, :3] + lanes.cross(omega, p_WF)
    linear = A_b[:3] + lanes.cross(A_b[3:], p_WF) + lanes.cross(omega, x_dot)
    return R_WF, p_WF, lanes.transpose(J), np.concatenate([linear, A_b[3:]], axis=-2)


def joint_velocities(model, xi, v):
    """World Plücker velocity of every joint frame, ``V_j = Σ_{k supports j} ξ_k v_k``: ``(..., nj, 6)``."""
    return model.joint_support @ (xi * v[..., :, None])  # boolean masks promote to float


def jacobian_time_variation(model, q, v, body, point=None):
    """Time derivative ``J̇(q, v)`` of :func:`jacobian` along the motion: ``(..., 6, nv)``.

    A column ξ_k fixed in its joint's frame moves with that joint: ``ξ̇_k = V_j(k) × ξ_k`` (RBDA
    eq. 2.37). Then, for the point ``x`` moving with velocity ``ẋ = v_O,b + ω_b × x``:
    ``d/dt (v_k + ω_k × x) = v̇_k + ω̇_k × x + ω_k × ẋ``.
    Together with the Jacobian, ``J a + J̇ v`` is the point's classical acceleration.
    Pinocchio counterpart: ``getFrameJacobianTimeVariation(..., LOCAL_WORLD_ALIGNED)``.
    """
    q = model.check_configuration(q)
    v = model.check_velocity(v)
    b, R_WJ, p_WJ, R_WB, p_WB = _body_pose(model, q, body)
    x = _point_in_world(model, R_WB, p_WB, point)
    return _point_jacobian_rate(model, world_motion_subspaces(model, R_WJ, p_WJ), v, b, x)


def _point_jacobian_rate(model, xi, v, b, x):
    """``J̇`` of the world point ``x`` of body ``b`` from the world Plücker columns ``xi``."""
    V = joint_velocities(model, xi, v)
    xi_dot = spatial.motion_cross(V[..., model.dof_joint, :], xi)
    j = model.body_joints[b]
    V_b = V[..., j, :] if j >= 0 else np.zeros(V.shape[:-2] + (6,))
    x_dot = V_b[..., :3] + spatial.cross(V_b[..., 3:], x)
    linear = xi_dot[..., :3] + spatial.cross(xi_dot[..., 3:], x[..., None, :]) + spatial.cross(xi[..., 3:], x_dot[..., None, :])
    angular = np.broadcast_to(xi_dot[..., 3:], linear.shape)
    J_dot = np.concatenate([linear, angular], axis=-1) * model.body_support[b][:, None]
    return spatial.transpose(J_dot)


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
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    X_BF = np.eye(4) if placement is None else np.asarray(placement, dtype=float)
    if X_BF.shape != (4, 4):
        raise ValueError(f"placement must have shape (4, 4), got {X_BF.shape}")
    if body is None:
        R = np.broadcast_to(X_BF[:3, :3], batch + (3, 3))
        p = np.broadcast_to(X_BF[:3, 3], batch + (3,))
        return R, p, np.zeros(batch + (6, model.nv)), np.zeros(batch + (6,))
    b = model.body_index(body)
    if model.body_joints[b] < 0:
        # A body fixed to the world: its placement is its world pose.
        X_WF = model.body_placements[b] @ X_BF
        return (np.broadcast_to(X_WF[:3, :3], batch + (3, 3)), np.broadcast_to(X_WF[:3, 3], batch + (3,)),
                np.zeros(batch + (6, model.nv)), np.zeros(batch + (6,)))
    R_JF = model.body_placements[b, :3, :3] @ X_BF[:3, :3]
    return _in_blocks(model, lambda q, v: _frame_on_lanes(model, b, R_JF, model.body_placements[b, :3, 3],
                                                          X_BF[:3, 3, None], q, v), batch, (q, 1), (v, 1))


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
