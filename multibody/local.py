"""Recursive dynamics in joint coordinates, for many states at once.

The algorithms of :mod:`multibody.dynamics` work in world Plücker coordinates, where sums over
subtrees and supports replace the recursions and every joint is processed in a handful of NumPy
calls: the fewest calls for one state, but each state pays for world poses and world inertias
(a 6×6 congruence per body). With many states on the lanes, arithmetic outweighs calls, and the
classical recursions in each joint's own coordinates (RBDA Tables 5.1, 6.2 and 7.1, as Pinocchio
runs them) do far less of it: the inertias and tree transforms are constants, applied as matrix products
over all lanes at once, and all that varies from state to state is each joint's own motion.

Inside, each revolute or prismatic joint frame is turned (by a constant rotation ``P`` with
``P e_z = axis``) so that the joint moves about or along its ``z`` axis: its transform is then a
rotation of two components of each 3-vector by ``(cos q, sin q)``, or a shift by ``q``, instead of
a 3×3 product. Other joints use their type's transform. Results (joint forces, accelerations) do
not depend on these frames; forces given or returned in joint frames are turned on the way.

Lane layout as :mod:`multibody.lanes`: per-joint vectors ``(nj, 6, N)``, the state axis last.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import joints as jt
from . import lanes, spatial
from .model import _add_to_parents, _index, _parent_rounds


#: Fewest states for which the recursions here beat the world-coordinate algorithms: below it,
#: the per-joint NumPy calls cost more than the arithmetic they save (Panda and Talos: 64–128).
MIN_STATES = 128


def suits(batch):
    """Whether a batch of shape ``batch`` is large enough for the joint-coordinate recursions."""
    return math.prod(batch) >= MIN_STATES


def lane_block(model):
    """States per block for the recursions here: their per-joint vectors, ``12 nj`` numbers per state
    (velocities and accelerations, or forces), near 4 MB, within [128, 4096]. They stream through
    these arrays a level at a time, so blocks larger than a core's cache still pay: per state, Panda
    (9 joints) ran fastest with 2048–4096 states, Talos (33) with 512–1024."""
    return int(np.clip(2 ** np.round(np.log2(2**22 / (8 * 12 * max(model.njoints, 1)))), 128, 4096))


class LocalGroup(NamedTuple):
    """Joints of one tree depth that move the same way (see :func:`local_tree`).

    ``motion`` is ``"revolute"`` (about ``z``), ``"prismatic"`` (along ``z``) or a joint type;
    ``joints``, ``parents`` (``None`` at the root), ``configuration`` and ``dofs`` index joints,
    ``q`` and ``v`` (``(k,)`` for one coordinate per joint, else ``(k, nq)``, ``(k, nv)``);
    ``Y (k, 6, 6)`` is each joint's constant motion transform from its parent's (turned) frame to its
    pre-joint frame and ``Y_T`` its transpose; ``subspace (k, 6, n, 1)`` and ``constants`` (of the
    type's ``group_transform`` with identity placements) serve the general joint types.
    """

    motion: object
    joints: object
    parents: object
    configuration: object
    dofs: object
    Y: np.ndarray
    Y_T: np.ndarray
    subspace: object
    constants: object
    parent_rounds: tuple
    rigid_to_parent: np.ndarray  # (k, 10, 10) the tree transform on rigid-body parameters (rigid_parameters)
    # CRBA's force columns, in an order where every subtree's are contiguous (_subtree_columns):
    composite_columns: np.ndarray  # (k, n, 6, 10) I S of each joint's n subspace columns, linear in I's parameters
    composite_gather: object  # the same as (index, weight) when each entry is one signed parameter (_as_gather), else None
    own_columns: object  # the joints' own columns
    subtree_columns: object  # (m,) the columns of the joints' subtrees, joint after joint
    column_joint: object  # (m,) the group position of each of those columns' joint (None for one joint)
    mass_rows: np.ndarray  # (m, n) for each of those columns, the coordinates of its joint ...
    mass_columns: np.ndarray  # (m, 1) ... and its own coordinate: where S_iᵀ F_j goes in M
    articulated_to_parent: object  # (k, 36, 21 or 36) ABA's Yᵀ (·) Y (_articulated_to_parent)


class LocalTree(NamedTuple):
    """Constants of the joint-coordinate recursions of a model (:func:`local_tree`)."""

    groups: tuple  # LocalGroup per level and motion, root level first
    angles: np.ndarray  # (n,) indices into q of the revolute joints' angles, in group order
    unrelated: tuple  # (rows, columns) of M where neither coordinate's joint supports the other's: zero
    inertia: np.ndarray  # (nj, 6, 6) spatial inertias in the turned joint frames
    turn: np.ndarray  # (nj, 3, 3) P: the turned frame's axes in the joint frame
    rigid: np.ndarray  # (nj, 10) the inertias as rigid-body parameters (see rigid_parameters)


def _turn_to_z(axis):
    """Rotation ``P`` with ``P e_z = axis`` (unit), so that ``Pᵀ axis = e_z``: the columns ``[x, y, axis]``
    of a right-handed orthonormal frame, ``x`` from the coordinate axis least aligned with ``axis``."""
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    x = helper - (helper @ axis) * axis
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(axis, x), axis], axis=1)


#: Motion subspace ``(6, 1)`` of a turned revolute or prismatic joint: about or along ``z``
_TURNED_SUBSPACE = {"revolute": np.eye(6)[:, 5:], "prismatic": np.eye(6)[:, 2:3]}


def _motion_kind(joint):
    if isinstance(joint, jt.Revolute):
        return "revolute"
    if isinstance(joint, jt.Prismatic):
        return "prismatic"
    return type(joint)


def _block_diagonal(R):
    """``diag(R, R) (6, 6)``: a rotation of both halves of a spatial vector."""
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = R
    return out


def local_tree(model):
    """The constants of :class:`LocalTree` for ``model`` (cached as ``Model.local_tree``)."""
    turns = np.array([_turn_to_z(joint.axis) if isinstance(_motion_kind(joint), str) else np.eye(3)
                      for joint in model.joints]).reshape(-1, 3, 3)
    inertia = np.array([_block_diagonal(P).T @ I @ _block_diagonal(P)
                        for P, I in zip(turns, model.spatial_inertias)]).reshape(-1, 6, 6)
    # Pose of turned frame i in its parent's turned frame: X = P_λᵀ X_T P_i ;  Y = X⁻¹ for motions
    Y = np.empty((model.njoints, 6, 6))
    rigid_to_parent = np.empty((model.njoints, 10, 10))
    for i, (placement, parent) in enumerate(zip(model.joint_placements, model.parents)):
        P_parent = np.eye(3) if parent < 0 else turns[parent]
        R, p = P_parent.T @ placement[:3, :3] @ turns[i], P_parent.T @ placement[:3, 3]
        Y[i] = spatial.motion_transform(*spatial.inverse_pose(R, p))
        # ᴾX_i* I ⁱX_P is linear in I: its matrix on the parameters, column by column
        rigid_to_parent[i] = np.stack([rigid_parameters(spatial.transform_inertia(R, p, rigid_inertia(e)))
                                       for e in np.eye(10)], axis=1)
    column_dofs, first_column, subtree_size = _subtree_columns(model)
    groups = []
    for index, _ in model.levels:
        members = np.arange(model.njoints)[index]
        kinds = [_motion_kind(model.joints[i]) for i in members]
        for kind in dict.fromkeys(kinds):
            joints = members[[k == kind for k in kinds]]
            parents = model.parents[joints]
            first = model.joints[joints[0]]
            configuration = model.idx_q[joints][:, None] + np.arange(first.nq)
            dofs = model.idx_v[joints][:, None] + np.arange(first.nv)
            subspace = constants = None
            if not isinstance(kind, str):
                subspace = np.stack([model.joints[i].motion_subspace for i in joints])[..., None]
                constants = kind.group_constants([model.joints[i] for i in joints], np.broadcast_to(np.eye(4), (len(joints), 4, 4)))
            else:
                configuration, dofs = _index(configuration[:, 0]), _index(dofs[:, 0])
            # CRBA: the columns of each joint's subtree, its own first
            columns = [np.arange(first_column[i], first_column[i] + subtree_size[i]) for i in joints]
            column_joint = np.repeat(np.arange(len(joints)), [len(c) for c in columns])
            columns = np.concatenate(columns)
            own_dofs = model.idx_v[joints][:, None] + np.arange(first.nv)
            S = subspace[..., 0] if subspace is not None else np.broadcast_to(_TURNED_SUBSPACE[kind], (len(joints), 6, 1))
            composite_columns = np.einsum("pcd,kdn->kncp", rigid_inertia(np.eye(10)), S)
            groups.append(LocalGroup(kind, _index(joints), None if parents[0] < 0 else _index(parents), configuration,
                                     dofs, Y[joints], np.ascontiguousarray(Y[joints].transpose(0, 2, 1)), subspace,
                                     constants, () if parents[0] < 0 else _parent_rounds(parents), rigid_to_parent[joints],
                                     composite_columns, _as_gather(composite_columns),
                                     _index((first_column[joints][:, None] + np.arange(first.nv)).ravel()),
                                     _index(columns), None if len(joints) == 1 else column_joint,
                                     own_dofs[column_joint], column_dofs[columns][:, None],
                                     _articulated_to_parent(kind, Y[joints])))
    angles = [model.idx_q[np.arange(model.njoints)[g.joints]] for g in groups if g.motion == "revolute"]
    unrelated = np.nonzero(~(model.dof_ancestor | model.dof_ancestor.T))
    return LocalTree(tuple(groups), np.concatenate(angles) if angles else np.zeros(0, dtype=int), unrelated, inertia,
                     turns, rigid_parameters(inertia).reshape(-1, 10))


def _as_gather(C):
    """A constant linear map of rigid-body parameters ``C (k, n, 6, 10)`` as a signed gather, when each of
    its rows picks at most one parameter: ``(index (k n 6,), weight (k n 6, 1))`` with ``C x`` equal to
    ``x.reshape(k 10, N)[index] * weight`` for ``x (k, 10, N)``; else ``None``. A revolute or prismatic
    joint's column ``I S`` is such a map (``[−h_y, h_x, 0, Ī_xz, Ī_yz, Ī_zz]`` about ``z``): a gather reads
    six numbers per state where the product multiplies sixty."""
    rows = C.reshape(C.shape[0], -1, C.shape[-1])
    if np.any(np.count_nonzero(rows, axis=-1) > 1):
        return None
    parameter = np.abs(rows).argmax(axis=-1)
    weight = np.take_along_axis(rows, parameter[..., None], axis=-1)
    return (np.arange(C.shape[0])[:, None] * C.shape[-1] + parameter).ravel(), weight.reshape(-1, 1)


#: Positions of the ten rigid-body parameters (:func:`rigid_parameters`): each pair a turn about ``z``
#: moves is contiguous, so that the turn reads and writes views.
_TURNED_BY_ANGLE = slice(0, 2), slice(2, 4)  # (h_x, Ī_xz) and (h_y, Ī_yz): x and y parts of the turn by q
_TURNED_BY_DOUBLE_ANGLE = 4, 5  # (b, d): turned by 2q
_UNMOVED = slice(6, 10)  # m, h_z, a, Ī_zz
_H_X, _XZ, _H_Y, _YZ, _B, _D, _MASS, _H_Z, _A, _ZZ = range(10)


def _subtree_columns(model):
    """An order of the velocity coordinates in which each joint's own come first and its whole subtree's
    are contiguous (the joints depth first): the coordinate at each position ``(nv,)``, and each joint's
    first position and number of subtree coordinates ``(nj,)``."""
    children = [[] for _ in range(model.njoints)]
    for joint, parent in enumerate(model.parents):
        if parent >= 0:
            children[parent].append(joint)
    order, pending = [], [j for j in reversed(range(model.njoints)) if model.parents[j] < 0]
    while pending:
        joint = pending.pop()
        order.append(joint)
        pending.extend(reversed(children[joint]))
    nv = np.array([joint.nv for joint in model.joints], dtype=int)
    column_dofs = np.concatenate([model.idx_v[j] + np.arange(nv[j]) for j in order] + [np.zeros(0, dtype=int)])
    first_column = np.empty(model.njoints, dtype=int)
    first_column[order] = np.cumsum(nv[order]) - nv[order]
    subtree_size = model.tree_sum_weights[1] @ nv if model.njoints else nv
    return column_dofs, first_column, np.round(subtree_size).astype(int)


def rigid_parameters(I):
    """The ten parameters ``[h_x, Ī_xz, h_y, Ī_yz, b, d, m, h_z, a, Ī_zz]`` of rigid-body inertias
    ``I = [[m 1, −[h]×], [[h]×, Ī]] (..., 6, 6)`` (``h = m c``, ``Ī`` about the frame origin), with
    ``a = (Ī_xx + Ī_yy)/2``, ``b = (Ī_xx − Ī_yy)/2``, ``d = Ī_xy``: under a turn by ``q`` about ``z``,
    ``(h_x, h_y)`` and ``(Ī_xz, Ī_yz)`` turn by ``q``, ``(b, d)`` by ``2q``, and the rest stays. ``-> (..., 10)``."""
    rotational = I[..., 3:, 3:]
    xx, yy = rotational[..., 0, 0], rotational[..., 1, 1]
    return np.stack([I[..., 5, 1], rotational[..., 0, 2], I[..., 3, 2], rotational[..., 1, 2], 0.5 * (xx - yy),
                     rotational[..., 0, 1], I[..., 0, 0], I[..., 4, 0], 0.5 * (xx + yy), rotational[..., 2, 2]], axis=-1)


def rigid_inertia(x):
    """The spatial inertia ``(..., 6, 6)`` of parameters ``x (..., 10)`` (:func:`rigid_parameters`)."""
    hx, xz, hy, yz, b, d, m, hz, a, zz = np.moveaxis(x, -1, 0)
    I = np.zeros(x.shape[:-1] + (6, 6))
    I[..., [0, 1, 2], [0, 1, 2]] = m[..., None]
    H = spatial.skew(np.stack([hx, hy, hz], axis=-1))
    I[..., :3, 3:], I[..., 3:, :3] = -H, H
    I[..., 3:, 3:] = np.stack([np.stack([a + b, d, xz], -1), np.stack([d, a - b, yz], -1), np.stack([xz, yz, zz], -1)], -2)
    return I


# ----------------------------------------------------------------------------- joint motions
#
# The recursions carry spatial vectors as (..., k, 6, N): k joints of a group, 6 components, N lanes,
# and leading axes for several vectors per joint and state (velocity and acceleration, or the six
# columns of an articulated inertia).

class JointMotion(NamedTuple):
    """A group's joint transforms ``X_J`` at the current states: ``(cos q, sin q) (k, 1, N)`` about
    ``z``, a shift ``q (k, N)`` along it, or a general pose ``R (k, 3, 3, N)``, ``p (k, 3, N)``."""

    cos: object = None
    sin: object = None
    shift: object = None
    R: object = None
    p: object = None


def joint_motions(tree, q):
    """:class:`JointMotion` of every group of ``tree`` at ``q (nq, N)``."""
    # the cosines and sines of all revolute joints at once
    angles = q[tree.angles][:, None, :]
    (cosines, sines), first = lanes.cos_sin(angles), 0
    motions = []
    for group in tree.groups:
        if group.motion == "revolute":
            last = first + len(group.Y)
            motions.append(JointMotion(cos=cosines[first:last], sin=sines[first:last]))
            first = last
        elif group.motion == "prismatic":
            motions.append(JointMotion(shift=q[group.configuration]))
        else:
            X = group.motion.group_transform(group.constants, q[group.configuration])
            motions.append(JointMotion(R=X[:, :, :3], p=X[:, :, 3]))
    return motions


def _lanes_shape(x, *others):
    return x.shape[:-1] + (max(y.shape[-1] for y in (x,) + others),)


def _turn_pair(c, s, x, y, out_x, out_y):
    """``(x, y) -> (c x − s y, s x + c y)`` into ``out_x, out_y`` (which must not overlap ``x, y``):
    a turn about ``z`` of the pair of components."""
    np.multiply(c, x, out=out_x)
    out_x -= s * y
    np.multiply(s, x, out=out_y)
    out_y += c * y


def _turn_pair_in_place(c, s, x, y):
    """``(x, y) <- (c x − s y, s x + c y)``: :func:`_turn_pair` in place."""
    s_x = s * x
    x *= c
    x -= s * y
    y *= c
    y += s_x


def _double_angle(c, s):
    """``(cos 2q, sin 2q) = (c² − s², 2 c s)`` from ``(c, s) = (cos q, sin q)``."""
    return c * c - s * s, 2.0 * c * s


def _turned(x, c, s, out=None):
    """Both 3-vectors of ``x (..., k, 6, N)`` turned about ``z`` by the angle of ``(c, s) (k, 1, N)``,
    into ``out`` (which must not overlap ``x``) when given."""
    shape = _lanes_shape(x, c)
    out = np.empty(shape) if out is None else out
    halves = x.reshape(x.shape[:-2] + (2, 3, x.shape[-1]))
    turned = out.reshape(shape[:-2] + (2, 3, shape[-1]))
    _turn_pair(c, s, halves[..., 0, :], halves[..., 1, :], turned[..., 0, :], turned[..., 1, :])
    turned[..., 2, :] = halves[..., 2, :]
    return out


def _copy_into(x, out, *others):
    """``x`` broadcast to the lanes of ``others`` and copied (into ``out`` when given)."""
    if out is None:
        return np.array(np.broadcast_to(x, _lanes_shape(x, *others)))
    out[...] = x
    return out


def to_child(group, motion, x, out=None):
    """Motion vectors ``x (..., k, 6, N)`` from the pre-joint frames to the joint frames, ``X_J⁻¹ x``
    (into ``out`` when given, which must not overlap ``x``)."""
    if group.motion == "revolute":
        return _turned(x, motion.cos, -motion.sin, out)
    if group.motion == "prismatic":
        # [v − (q e_z) × ω; ω],  e_z × ω = (−ω_y, ω_x, 0)
        out = _copy_into(x, out, motion.shift)
        out[..., 0, :] += motion.shift * x[..., 4, :]
        out[..., 1, :] -= motion.shift * x[..., 3, :]
        return out
    R_T, angular = lanes.transpose(motion.R), x[..., 3:, :]
    # [Rᵀ (v − p × ω); Rᵀ ω]
    linear = lanes.matvec(R_T, x[..., :3, :] - lanes.cross(motion.p, angular))
    return _copy_into(np.concatenate([linear, lanes.matvec(R_T, angular)], axis=-2), out)


def to_parent(group, motion, f, out=None):
    """Force vectors ``f (..., k, 6, N)`` from the joint frames to the pre-joint frames, ``X_J* f``."""
    if group.motion == "revolute":
        return _turned(f, motion.cos, motion.sin, out)
    if group.motion == "prismatic":
        # [f; n + (q e_z) × f]
        out = _copy_into(f, out, motion.shift)
        out[..., 3, :] -= motion.shift * f[..., 1, :]
        out[..., 4, :] += motion.shift * f[..., 0, :]
        return out
    return _copy_into(lanes.transform_force(motion.R, motion.p, f), out)


def add_joint_rates(group, x, rates):
    """``x += S q̇`` in place, ``x (..., k, 6, N)`` in the joint frames, for rates ``(..., k, N)`` (one
    coordinate per joint) or ``(..., k, n, N)``."""
    if group.motion == "revolute":
        x[..., 5, :] += rates
    elif group.motion == "prismatic":
        x[..., 2, :] += rates
    else:
        x += np.einsum("kcm,...kmn->...kcn", group.subspace[..., 0], rates)


def joint_rate_product(group, v, rate):
    """``c = v × S q̇`` of joint velocities ``v (k, 6, N)`` and rates ``rate (k, N)`` or ``(k, n, N)``:
    the acceleration a joint's own motion adds as its frame moves (RBDA Table 5.1)."""
    if group.motion == "revolute":
        # [v; ω] × [0; e_z q̇] = q̇ (v_y, −v_x, 0, ω_y, −ω_x, 0)
        out = np.empty(v.shape)
        halves, product = v.reshape(-1, 2, 3, v.shape[-1]), out.reshape(-1, 2, 3, v.shape[-1])
        np.multiply(rate[:, None], halves[:, :, 1], out=product[:, :, 0])
        np.multiply(rate[:, None], halves[:, :, 0], out=product[:, :, 1])
        product[:, :, 1] *= -1.0
        product[:, :, 2] = 0.0
        return out
    if group.motion == "prismatic":
        # [v; ω] × [e_z q̇; 0] = q̇ (ω_y, −ω_x, 0, 0, 0, 0)
        out = np.zeros(v.shape)
        np.multiply(rate, v[:, 4], out=out[:, 0])
        np.multiply(rate, v[:, 3], out=out[:, 1])
        out[:, 1] *= -1.0
        return out
    return lanes.motion_cross(v, lanes.matvec(group.subspace, rate))


def joint_share(group, f):
    """``Sᵀ f``: each coordinate's component of ``f (..., k, 6, N)`` -> ``(..., k, N)`` or ``(..., k, n, N)``."""
    if group.motion == "revolute":
        return f[..., 5, :]
    if group.motion == "prismatic":
        return f[..., 2, :]
    return np.einsum("kcm,...kcn->...kmn", group.subspace[..., 0], f)


def _into(x, index, compute):
    """``compute(out)``, which fills ``out`` of the shape of ``x[..., index, :, :]``, written there: in
    place when ``index`` selects a view."""
    if isinstance(index, (slice, int)):
        return compute(x[..., index, :, :])
    result = compute(np.empty(x.shape[:-3] + (len(index),) + x.shape[-2:]))
    x[..., index, :, :] = result
    return result


def to_turned_frames(tree, f):
    """Per-joint spatial vectors ``(nj, 6, N)`` from the joint frames to the turned frames."""
    return np.matmul(tree.turn.transpose(0, 2, 1)[:, None], f.reshape(f.shape[0], 2, 3, -1)).reshape(f.shape[0], 6, -1)


def from_turned_frames(tree, f):
    """The inverse of :func:`to_turned_frames`."""
    return np.matmul(tree.turn[:, None], f.reshape(f.shape[0], 2, 3, -1)).reshape(f.shape[0], 6, -1)


# ----------------------------------------------------------------------------- RNEA

def rnea(model, q, v, a, f_ext):
    """Recursive Newton–Euler in joint coordinates on lanes (RBDA Table 5.1): the joint forces
    ``τ (nv, N)`` and the force ``f_i (nj, 6, N)`` each joint transmits to its body, in the turned joint
    frames. ``v``, ``a`` or ``f_ext`` ``None`` stand for zero; gravity enters as the world's
    acceleration ``a₀ = [−g; 0]`` (RBDA §5.3)."""
    tree = model.local_tree
    n = max(x.shape[-1] for x in (q, v, a, f_ext) if x is not None)
    motions = joint_motions(tree, q)
    # [v_i; a_i] (2, nj, 6, N), or a_i alone (1, nj, 6, N) when v = 0
    slots = 1 if v is None else 2
    VA = np.empty((slots, model.njoints, 6, n))
    rates = None if v is None else np.stack(np.broadcast_arrays(v, np.zeros((model.nv, 1)) if a is None else a))
    world = np.zeros((slots, 1, 6, 1))
    world[-1, 0] = model.gravity_acceleration
    for group, motion in zip(tree.groups, motions):
        # v_i = ⁱX_λ v_λ + S_i q̇_i ;  a_i = ⁱX_λ a_λ + S_i q̈_i + v_i × S_i q̇_i
        pre = group.Y @ (world if group.parents is None else VA[:, group.parents])

        def step(out):
            x = to_child(group, motion, pre, out)
            if rates is not None:
                rate = rates[:, group.dofs]
                add_joint_rates(group, x, rate)
                x[1] += joint_rate_product(group, x[0], rate[0])
            elif a is not None:
                add_joint_rates(group, x[0], a[group.dofs])
            return x

        _into(VA, group.joints, step)
    # f_i = I_i a_i + v_i ×* I_i v_i − f_ext,i
    IVA = tree.inertia @ VA
    F = IVA[-1]
    if v is not None:
        F += lanes.force_cross(VA[0], IVA[0])
    if f_ext is not None:
        F -= to_turned_frames(tree, f_ext)
    tau = np.empty((model.nv, n))
    for group, motion in zip(reversed(tree.groups), reversed(motions)):
        # τ_i = S_iᵀ f_i ;  f_λ += λX_i* f_i
        f = F[group.joints]
        tau[group.dofs] = joint_share(group, f)
        if group.parents is not None:
            _add_to_parents(F, group, group.Y_T @ to_parent(group, motion, f))
    return tau, F


# ----------------------------------------------------------------------------- turn coordinates

def _turn_coordinates(M):
    """Coordinates of a symmetric ``M = [[A, B], [Bᵀ, C]] (6, 6)`` in which ``X_J* M X_J*ᵀ`` for a turn by ``q``
    about ``z`` is four pairs turned by ``q``, three by ``2q``, and seven invariants ``(21,)``.

    Rows ``(x, y)`` of ``[[R, 0], [0, R]] M [[R, 0], [0, R]]ᵀ`` turn as vectors, columns likewise: column z of
    each block and row z of ``B`` turn by ``q``; a 2×2 block ``α 1 + β J + γ K + δ L`` (``J`` the quarter turn,
    ``K = diag(1, −1)``, ``L`` the swap) keeps ``α, β`` and turns ``(γ, δ)`` by ``2q``.
    """
    A, B, C = M[:3, :3], M[:3, 3:], M[3:, 3:]
    return np.array([A[0, 2], C[0, 2], B[0, 2], B[2, 0],  # x parts of the pairs turned by q
                     A[1, 2], C[1, 2], B[1, 2], B[2, 1],  # y parts
                     (A[0, 0] - A[1, 1]) / 2, (C[0, 0] - C[1, 1]) / 2, (B[0, 0] - B[1, 1]) / 2,  # γ: x parts for 2q
                     A[0, 1], C[0, 1], (B[0, 1] + B[1, 0]) / 2,  # δ: y parts
                     (A[0, 0] + A[1, 1]) / 2, A[2, 2], (C[0, 0] + C[1, 1]) / 2, C[2, 2],
                     (B[0, 0] + B[1, 1]) / 2, (B[1, 0] - B[0, 1]) / 2, B[2, 2]])


#: ``(21, 36)``: the entries of a symmetric 6×6 matrix, row by row -> its turn coordinates
_TO_TURN_COORDINATES = np.stack([_turn_coordinates(E.reshape(6, 6)) for E in np.eye(36)], axis=1)


def _articulated_to_parent(kind, Y):
    """``Yᵀ M Y`` for joints with transforms ``Y (k, 6, 6)``, as a matrix from the coordinates of a symmetric
    ``M`` to the entries of ``Yᵀ M Y``, row by row: ``(k, 36, 21)`` from turn coordinates for a revolute joint,
    ``(k, 36, 36)`` from the entries for a prismatic one (``None`` for other joints)."""
    if kind == "revolute":
        symmetric = np.array([E + E.T - np.diag(np.diag(E)) for E in np.eye(36).reshape(36, 6, 6)])
        rows, columns = np.triu_indices(6)
        symmetric = symmetric[rows * 6 + columns]  # (21, 6, 6): one per entry of the upper triangle
        unit = np.einsum("pb,prc->brc", np.linalg.inv(_TO_TURN_COORDINATES @ symmetric.reshape(21, 36).T), symmetric)
    elif kind == "prismatic":
        unit = np.eye(36).reshape(36, 6, 6)
    else:
        return None
    return np.stack([(y.T @ unit @ y).reshape(len(unit), 36).T for y in Y]).reshape(-1, 36, len(unit))


# ----------------------------------------------------------------------------- ABA

def aba(model, q, v, tau, f_ext):
    """Articulated Body Algorithm in joint coordinates on lanes (RBDA Table 7.1): ``q̈ (nv, N)`` from
    ``q (nq, N)``, ``v, tau (nv, N)`` and ``f_ext (nj, 6, N)`` (joint frames; ``None``: zero).

    Articulated inertias are held as ``(nj, 6, 6, N)``; as they are symmetric, their transpose
    ``(6, nj, 6, N)`` holds them column by column, so that transforming their rows is transforming six
    force vectors. They move to the parent by :func:`_moved_to_parents`. A singular ``D_i`` leaves
    non-finite accelerations (the caller names the joint).
    """
    tree = model.local_tree
    n = max(x.shape[-1] for x in (q, v, tau, f_ext) if x is not None)
    motions = joint_motions(tree, q)
    # First pass: v_i = ⁱX_λ v_λ + S_i q̇_i ;  c_i = v_i × S_i q̇_i
    V, C = np.empty((model.njoints, 6, n)), np.empty((model.njoints, 6, n))
    for group, motion in zip(tree.groups, motions):
        rate = v[group.dofs]

        def step(out):
            if group.parents is None:
                out[...] = 0.0
            else:
                to_child(group, motion, group.Y @ V[group.parents], out)
            add_joint_rates(group, out, rate)
            return out

        C[group.joints] = joint_rate_product(group, _into(V, group.joints, step), rate)
    # I^A_i = I_i ;  p^A_i = v_i ×* I_i v_i − f_ext,i
    articulated = np.array(np.broadcast_to(tree.inertia[..., None], (model.njoints, 6, 6, n)))
    bias = lanes.force_cross(V, tree.inertia @ V)
    if f_ext is not None:
        bias -= to_turned_frames(tree, f_ext)
    # Second pass, leaves first: U_i = I^A_i S_i ;  D_i = S_iᵀ U_i ;  u_i = τ_i − S_iᵀ p^A_i
    factors = [None] * len(tree.groups)
    with np.errstate(divide="ignore", invalid="ignore"):
        for g, group, motion in zip(reversed(range(len(tree.groups))), reversed(tree.groups), reversed(motions)):
            I_A = articulated[group.joints].transpose(1, 0, 2, 3)  # by columns
            U = _columns(group, I_A).copy()  # (k, 6, N), or (n, k, 6, N) by columns; I_A becomes I_a below
            D_inv = _inverse(group, joint_share(group, U))
            u = tau[group.dofs] - joint_share(group, bias[group.joints])
            U_D_inv = _times_inverse(group, U, D_inv)
            factors[g] = U, D_inv, u
            if group.parents is None:
                continue
            # I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ ;  p^a_i = p^A_i + I^a_i c_i + U_i D_i⁻¹ u_i
            I_a = _subtract_outer(group, I_A, U_D_inv, U)
            p_a = bias[group.joints] + np.einsum("ckrn,kcn->krn", I_a, C[group.joints]) + _apply(group, U_D_inv, u)
            # I^A_λ += λX_i* I^a_i ⁱX_λ ;  p^A_λ += λX_i* p^a_i, with λX_i* = Yᵀ X_J*
            _add_to_parents(articulated, group, _moved_to_parents(group, motion, I_a))
            _add_to_parents(bias, group, group.Y_T @ to_parent(group, motion, p_a))
        # Third pass: a'_i = ⁱX_λ a_λ + c_i ;  q̈_i = D_i⁻¹ (u_i − U_iᵀ a'_i) ;  a_i = a'_i + S_i q̈_i
        A = np.empty((model.njoints, 6, n))
        qdd = np.empty((model.nv, n))
        gravity = model.gravity_acceleration[None]
        for group, motion, (U, D_inv, u) in zip(tree.groups, motions, factors):

            def step(out):
                to_child(group, motion, group.Y @ (gravity if group.parents is None else A[group.parents]), out)
                out += C[group.joints]
                acceleration = _apply(group, D_inv, u - _transpose_times(group, U, out))
                qdd[group.dofs] = acceleration
                add_joint_rates(group, out, acceleration)
                return out

            _into(A, group.joints, step)
    return qdd


def _moved_to_parents(group, motion, M):
    """``λX_i* M ⁱX_λ = Yᵀ X_J* M X_J*ᵀ Y`` for symmetric ``M`` held by columns ``(6, k, 6, N)``: ``(k, 6, 6, N)``.

    About a revolute joint, ``X_J*`` on both sides turns four pairs of turn coordinates
    (:func:`_turn_coordinates`) by ``q`` and three by ``2q``; along a prismatic one it acts on the rows
    and then on the columns as on force vectors. Either way ``Yᵀ (·) Y`` is then one constant product.
    Other joints take :func:`_congruence`.
    """
    k, n = M.shape[1], M.shape[-1]
    if group.motion == "revolute":
        moved = _TO_TURN_COORDINATES @ M.transpose(1, 0, 2, 3).reshape(k, 36, n)
        c, s = motion.cos, motion.sin  # (k, 1, N)
        _turn_pair_in_place(c, s, moved[:, 0:4], moved[:, 4:8])
        _turn_pair_in_place(*_double_angle(c, s), moved[:, 8:11], moved[:, 11:14])
    elif group.motion == "prismatic":
        # X_J* = 1 but for n += (q e_z) × f: rows 3 and 4 of X_J* M, then columns 3 and 4 of (X_J* M) X_J*ᵀ
        moved = M.transpose(1, 0, 2, 3).copy()  # (k, 6, 6, N); symmetric, so by columns is by rows
        shift = motion.shift[:, None]  # (k, 1, N)
        moved[:, 3] -= shift * moved[:, 1]
        moved[:, 4] += shift * moved[:, 0]
        moved[:, :, 3] -= shift * moved[:, :, 1]
        moved[:, :, 4] += shift * moved[:, :, 0]
        moved = moved.reshape(k, 36, n)
    else:
        return _congruence(group, motion, M).transpose(1, 0, 2, 3)  # symmetric: by columns is by rows
    return (group.articulated_to_parent @ moved).reshape(k, 6, 6, n)


def _congruence(group, motion, M):
    """``λX_i* M ⁱX_λ = B M Bᵀ`` with ``B = Yᵀ X_J*`` for symmetric ``M`` held by columns ``(6, k, 6, N)``:
    ``B`` on the rows is ``B`` on six force vectors, and ``(B M)ᵀ = M Bᵀ`` by columns is ``B M`` by rows,
    so ``B`` on its rows once more gives ``B M Bᵀ``, by columns."""
    rows = group.Y_T @ to_parent(group, motion, M)  # [c, i, r] = (B M)[r, c]
    return group.Y_T @ to_parent(group, motion, np.ascontiguousarray(rows.transpose(2, 1, 0, 3)))


def _columns(group, M):
    """``M S`` for ``M`` held by columns ``(6, k, 6, N)``: ``(k, 6, N)``, or ``(n, k, 6, N)`` by columns."""
    if group.motion == "revolute":
        return M[5]
    if group.motion == "prismatic":
        return M[2]
    return np.einsum("ckrn,kcm->mkrn", M, group.subspace[..., 0])


def _inverse(group, D):
    """``D⁻¹`` of the joint-space articulated inertias: ``(k, N)``, or ``(n, k, n, N)`` held by columns."""
    if isinstance(group.motion, str):
        return 1.0 / D
    # (c, k, r, N) -> (k, r, c, N) for the stacked inverse, and back (D and D⁻¹ are symmetric)
    return lanes.inverse(D.transpose(1, 2, 0, 3)).transpose(2, 0, 1, 3)


def _times_inverse(group, U, D_inv):
    """``U D⁻¹``, both held by columns."""
    if isinstance(group.motion, str):
        return U * D_inv[:, None]
    return np.einsum("mkrn,lkmn->lkrn", U, D_inv)


def _subtract_outer(group, M, U_D_inv, U):
    """``M − (U D⁻¹) Uᵀ``, in place on ``M`` held by columns ``(6, k, 6, N)``: column by column for one
    coordinate per joint, whose temporaries then stay small."""
    if not isinstance(group.motion, str):
        M -= np.einsum("mkrn,mkcn->ckrn", U_D_inv, U)
        return M
    for column, u in zip(M, U.transpose(1, 0, 2)):
        column -= u[:, None] * U_D_inv
    return M


def _apply(group, M, x):
    """``M x`` for ``M`` held by columns (``(k, 6, N)`` or ``(k, N)`` for one coordinate per joint,
    else ``(n, k, r, N)``) and joint coordinates ``x`` (``(k, N)`` or ``(k, n, N)``)."""
    if isinstance(group.motion, str):
        return M * (x[:, None] if M.ndim == 3 else x)
    return np.einsum("mkrn,kmn->krn", M, x)


def _transpose_times(group, U, a):
    """``Uᵀ a`` for ``U`` held by columns and vectors ``a (k, 6, N)``."""
    if isinstance(group.motion, str):
        return np.einsum("krn,krn->kn", U, a)
    return np.einsum("mkrn,krn->kmn", U, a)


# ----------------------------------------------------------------------------- CRBA

def crba(model, q):
    """Composite Rigid Body Algorithm in joint coordinates on lanes (RBDA Table 6.2): ``M (nv, nv, N)``.

    A composite inertia is a rigid-body inertia, so it travels up the tree as its ten parameters
    (:func:`rigid_parameters`): the joint's turn moves five of them, and the tree transform is one
    constant 10×10 product. The force columns ``F = I^c_i S_i`` travel up as force vectors, all those
    of a subtree in one contiguous block, and meet each ancestor's ``S_jᵀ``.
    """
    tree = model.local_tree
    n = q.shape[-1]
    motions = joint_motions(tree, q)
    composite = np.array(np.broadcast_to(tree.rigid[..., None], (model.njoints, 10, n)))
    M = np.empty((model.nv, model.nv, n))
    M[tree.unrelated] = 0.0  # where neither joint supports the other; the levels fill the rest
    F = np.empty((model.nv, 6, n))  # force columns, in the order of LocalGroup.subtree_columns
    for group, motion in zip(reversed(tree.groups), reversed(motions)):
        x = composite[group.joints]  # complete: every deeper level has been added
        column_group, column_motion = _per_column(group, motion)

        def own_columns(out):
            # F_i = I^c_i S_i, beside the columns of i's subtree (already in frame i)
            if group.composite_gather is None:
                np.matmul(group.composite_columns, x[:, None], out=out.reshape(group.composite_columns.shape[:3] + (n,)))
            else:
                index, weight = group.composite_gather
                np.multiply(x.reshape(-1, n)[index], weight, out=out.reshape(-1, n))
            return out

        def to_parents(out):
            # F_j <- λX_i* F_j = Yᵀ X_J* F_j
            return np.matmul(column_group.Y_T, to_parent(column_group, column_motion, block), out=out)

        _into(F, group.own_columns, own_columns)
        block = F[group.subtree_columns]
        # M_ij = S_iᵀ F_j for the coordinates j of i's subtree (RBDA eq. 6.14), and its mirror
        shares = joint_share(column_group, block)  # (m, N) or (m, n, N)
        shares = shares[:, None] if shares.ndim == 2 else shares
        M[group.mass_rows, group.mass_columns] = shares
        M[group.mass_columns, group.mass_rows] = shares
        if group.parents is not None:
            _into(F, group.subtree_columns, to_parents)
            # I^c_λ += λX_i* I^c_i ⁱX_λ
            _add_to_parents(composite, group, group.rigid_to_parent @ _turned_composite(group, motion, x))
    return M


def _per_column(group, motion):
    """The group and its joint motions for the block of its subtrees' force columns ``(m, 6, N)``:
    a single joint broadcasts over them, several are repeated column by column."""
    index = group.column_joint
    if index is None:
        return group, motion
    take = lambda x: None if x is None else x[index]  # noqa: E731
    return (group._replace(Y_T=group.Y_T[index], subspace=take(group.subspace)),
            JointMotion(*(take(x) for x in motion)))


def _turned_composite(group, motion, x):
    """Rigid-body parameters ``x (k, 10, N)`` moved by the joint: ``X_J* I X_J⁻¹`` in parameters."""
    if group.motion == "revolute":
        out = np.empty(_lanes_shape(x, motion.cos))
        c, s = motion.cos, motion.sin  # (k, 1, N)
        (x_parts, y_parts), (b, d) = _TURNED_BY_ANGLE, _TURNED_BY_DOUBLE_ANGLE
        _turn_pair(c, s, x[:, x_parts], x[:, y_parts], out[:, x_parts], out[:, y_parts])
        c2, s2 = _double_angle(c[:, 0], s[:, 0])
        _turn_pair(c2, s2, x[:, b], x[:, d], out[:, b], out[:, d])
        out[:, _UNMOVED] = x[:, _UNMOVED]
        return out
    if group.motion == "prismatic":
        # shifted by q e_z: h_z += m q ;  a += q (2 h_z + m q) ;  Ī_xz −= q h_x ;  Ī_yz −= q h_y
        out = x.copy()
        shift, m = motion.shift, x[:, _MASS]
        out[:, _A] += shift * (2.0 * x[:, _H_Z] + m * shift)
        out[:, _XZ] -= shift * x[:, _H_X]
        out[:, _YZ] -= shift * x[:, _H_Y]
        out[:, _H_Z] += m * shift
        return out
    # a general pose: g = R h ;  h' = g + m p ;  Ī' = R Ī Rᵀ − h' pᵀ − p gᵀ + pᵀ(h' + g) 1
    I = rigid_inertia(x.transpose(0, 2, 1)).transpose(0, 2, 3, 1)  # (k, 6, 6, N)
    moved = lanes.world_inertias(x[:, _MASS, 0], x[:, [_H_X, _H_Y, _H_Z]], I[:, 3:, 3:], motion.R, motion.p)
    return rigid_parameters(moved.transpose(0, 3, 1, 2)).transpose(0, 2, 1)
