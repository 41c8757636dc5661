"""Equations of motion ``M(q) a + C(q, v) v + g(q) = τ`` of a kinematic tree.

Two families of algorithms, which check each other:

* recursive (Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008): Recursive
  Newton–Euler (§5.3), Composite Rigid Body (§6.2), Articulated Body (§7.3), in world Plücker
  coordinates, where sums over subtrees and supports replace most of the recursions;
* Lagrangian assembly from body Jacobians in world Plücker coordinates: ``T = ½ vᵀ M v`` with
  ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ``, and Christoffel symbols of ``M`` for ``C``.

Conventions (``docs/conventions.md``): spatial vectors are ``[linear; angular]``; gravity enters as
a fictitious acceleration ``a₀ = [−g; 0]`` of the world (RBDA §5.3); external forces ``f_ext`` have
shape ``(..., njoints, 6)``: the spatial force on the rigid body of each joint, expressed in that
joint's frame at its origin (Pinocchio's ``fext``).
Every function accepts leading batch axes on its array arguments and broadcasts them; inside, the
recursive algorithms compute on lanes (:mod:`multibody.lanes`), every state a column. From
:data:`multibody.local.MIN_STATES` states on, RNEA (with bias forces, gravity and joint reaction
forces), CRBA and ABA run as the classical recursions in joint coordinates instead
(:mod:`multibody.local`): more NumPy calls, far less arithmetic per state. Each pair is tested
against the other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import lanes, linalg, local, spatial
from .kinematics import (_at_dofs, _fixed_frame, _frame_arguments, _frame_motion, _in_blocks, _joint_frames,
                         _single_joint_frames, _spatial_velocities, _support_sums, _velocities, world_poses)
from .spatial import motion_cross, transpose
from .model import _add_to_parents


# ============================================================================= shared pieces

def _check(model, q, v=None, a=None, tau=None, f_ext=None):
    """Validated float arrays and their common batch shape."""
    q = model.check_configuration(q)
    arrays = [model.check_velocity(x, name) if x is not None else None
              for x, name in ((v, "v"), (a, "a"), (tau, "tau"))]
    shapes = [q.shape[:-1]] + [x.shape[:-1] for x in arrays if x is not None]
    if f_ext is not None:
        f_ext = model._as_float_array(f_ext, "f_ext")
        if f_ext.shape[-2:] != (model.njoints, 6):
            raise ValueError(f"f_ext must have shape (..., {model.njoints}, 6) (one spatial force per moving "
                             f"joint, in its frame), got {f_ext.shape}")
        shapes.append(f_ext.shape[:-2])
    return q, *arrays, f_ext, spatial.batch_shape(*shapes)


class Tree(NamedTuple):
    """One pass down the tree on lanes (:func:`_tree`): the joint frames of
    :class:`~multibody.kinematics.JointFrames` and the world inertias."""

    R_WJ: np.ndarray  # (nj, 3, 3, N)
    p_WO: np.ndarray  # (3, N) the reference point O, the first joint's origin
    p_OJ: np.ndarray  # (nj, 3, N)
    xi: np.ndarray  # (nv, 6, N) at O
    inertia: np.ndarray  # (nj, 6, 6, N) at O


def _tree(model, q):
    """One pass down the tree on lanes (``q (nq, N)``): world orientations of the joint frames
    ``R_WJ (nj, 3, 3, N)``, their positions ``p_OJ (nj, 3, N)`` relative to the reference point ``O``
    (the first joint's origin, at ``p_WO``), Plücker motion subspaces ``ξ (nv, 6, N)`` and inertias
    ``ᴼI_i = ᴼX_i* I_i ⁱX_O`` ``(nj, 6, 6, N)`` (RBDA eq. 2.66), in world axes at ``O``.

    ``O`` is not the world origin, whose coordinates cost digits far from it (see
    :func:`~multibody.kinematics._joint_frames`): joint forces, ``M``, ``C`` and energies do not
    depend on the point; only translations between frames do, and they all use ``p_OJ``.
    """
    if q.shape[-1] > 1:
        frames = _joint_frames(model, q)
        return Tree(*frames, lanes.world_inertias(*model.inertia_parameters, frames.R_WJ, frames.p_OJ))
    # A single lane: the inertias by the force transforms ᴼX_J* that give ξ (fewer NumPy calls than their
    # own formula), ᴼI = ᴼX_J* I_J ᴼX_J*ᵀ
    frames, X_star = _single_joint_frames(model, q)
    return Tree(*frames, (X_star @ model.spatial_inertias @ transpose(X_star))[..., None])


def _subtree_sums(model, x):
    """``y_i = Σ_{j in subtree(i)} x_j``: ``x (nj, ...) -> (nj, ...)``.

    The backward pass of a recursion such as ``f_λ(i) += f_i``: one matrix product for small
    arrays, else level by level from the leaves.
    """
    _, subtree, _ = model.tree_sum_weights
    if lanes.small_tree_sum(subtree, x):
        return lanes.tree_sum(subtree, x)
    y = x.copy()
    for index, parents in model.upward_levels:
        y[parents] += y[index]
    return y


def _world_tree(model, q):
    """``ξ (..., nv, 6)`` and inertias ``(..., nj, 6, 6)`` of :func:`_tree` with leading batch axes, for the
    Lagrangian assemblies."""
    def kernel(q):
        tree = _tree(model, q)
        return tree.xi, tree.inertia

    return _in_blocks(model, kernel, q.shape[:-1], (q, 1))


def _in_blocks_by_size(model, kernel, joint_coordinates, batch, *arrays):
    """:func:`~multibody.kinematics._in_blocks` with ``kernel`` (world coordinates), or for a batch
    large enough (:func:`multibody.local.suits`) with ``joint_coordinates`` in its own blocks."""
    if local.suits(batch):
        return _in_blocks(model, joint_coordinates, batch, *arrays, block=local.lane_block(model))
    return _in_blocks(model, kernel, batch, *arrays)


# ============================================================================= RNEA

def inverse_dynamics(model, q, v, a, f_ext=None):
    """Joint forces ``τ = M(q) a + C(q, v) v + g(q) − Σ Jᵢᵀ f_ext,i`` by Recursive Newton–Euler.

    RBDA Table 5.1, written in world Plücker coordinates (RBDA §5.3, "RNEA in base coordinates"),
    where every recursion but the poses' becomes a sum over the subtree or the support of a joint,
    so all joints are processed at once. Shapes: ``q (..., nq)``, ``v, a (..., nv)``,
    ``f_ext (..., njoints, 6)`` (see module docstring) -> ``τ (..., nv)`` (N or N m per coordinate).
    Batches of many states: RBDA Table 5.1 in joint coordinates (:func:`multibody.local.rnea`).
    Pinocchio counterpart: ``rnea``.
    """
    q, v, a, _, f_ext, batch = _check(model, q, v, a, f_ext=f_ext)
    return _rnea(model, q, v, a, f_ext, batch)


def _rnea(model, q, v, a, f_ext, batch):
    """:func:`inverse_dynamics` on validated arrays with common batch shape ``batch`` (``v`` or ``a``
    ``None``: zero)."""
    def kernel(q, v, a, f_ext):
        _, _, xi, F_subtree = _rnea_forces(model, q, v, a, f_ext)
        return _joint_forces(model, xi, F_subtree)

    def joint_coordinates(q, v, a, f_ext):
        return local.rnea(model, q, v, a, f_ext)[0]

    return _in_blocks_by_size(model, kernel, joint_coordinates, batch, (q, 1), None if v is None else (v, 1),
                              None if a is None else (a, 1), None if f_ext is None else (f_ext, 2))


def _rnea_forces(model, q, v, a, f_ext, tree=None, motion=None):
    """RNEA up to the joint forces on lanes: the joint poses ``R_WJ``, ``p_OJ`` and ``ξ`` of :func:`_tree`,
    and the force each joint transmits (at the reference point ``O``). ``v`` or ``a`` ``None`` stands for
    zero (their terms are skipped); ``tree`` is :func:`_tree` of ``q`` and ``motion`` the velocities
    :func:`~multibody.kinematics._velocities` of ``v``, when already computed."""
    R_WJ, _, p_OJ, xi, inertia = _tree(model, q) if tree is None else tree
    # Forward: v_i = v_λ + ξ_i q̇_i ;  a_i = a_λ + ξ_i q̈_i + ξ̇_i q̇_i  (summed over each support)
    V, xi_dot_v = (None, None) if v is None else _velocities(model, xi, v) if motion is None else motion
    # Each coordinate's share ξ_k q̈_k + ξ̇_k q̇_k of the acceleration (None: zero)
    shares = xi_dot_v if a is None else xi * a[:, None, :] if v is None else xi * a[:, None, :] + xi_dot_v
    A = model.gravity_acceleration  # a₀ = [−g; 0]: gravity as an acceleration of the world (RBDA §5.3)
    if shares is not None:
        A = A + _support_sums(model, shares)
    # (with v = a = 0 every body accelerates as the world does: a₀, which lanes.matvec broadcasts)
    # f_i = I_i a_i + v_i ×* I_i v_i − f_ext_i
    F = lanes.matvec(inertia, A)
    if V is not None:
        F = F + lanes.force_cross(V, lanes.matvec(inertia, V))
    if f_ext is not None:
        F = F - lanes.transform_force(R_WJ, p_OJ, f_ext)
    # Backward: the force a joint transmits is the sum over its subtree;  τ_k = ξ_kᵀ f_subtree(j(k))
    return R_WJ, p_OJ, xi, _subtree_sums(model, F)


def _joint_forces(model, xi, F_subtree):
    """``τ_k = ξ_kᵀ f_j(k)``: each coordinate's share of the force its joint transmits ``(nj, 6, N) -> (nv, N)``."""
    return lanes.dot(xi, _at_dofs(model, F_subtree))


def joint_reaction_forces(model, q, v, a, f_ext=None):
    """Spatial force each joint transmits from its parent to its child body: ``(..., njoints, 6)``.

    The force ``[f; n]`` (N, N m) the parent exerts on the subtree of joint i through the joint,
    expressed in joint frame i at its origin: the RNEA backward-pass force ``f_i`` (RBDA Table 5.1).
    Its projection on the motion subspace is the joint force ``τ_i = S_iᵀ f_i``; the rest is what
    the joint's bearings carry. Constraint forces enter through ``f_ext`` (see
    ``ConstrainedSystem.body_forces``). Shapes as :func:`inverse_dynamics`.
    """
    q, v, a, _, f_ext, batch = _check(model, q, v, a, f_ext=f_ext)
    def kernel(q, v, a, f_ext):
        R_WJ, p_OJ, _, F_subtree = _rnea_forces(model, q, v, a, f_ext)
        return lanes.inverse_transform_force(R_WJ, p_OJ, F_subtree)

    def joint_coordinates(q, v, a, f_ext):
        return local.from_turned_frames(model.local_tree, local.rnea(model, q, v, a, f_ext)[1])

    return _in_blocks_by_size(model, kernel, joint_coordinates, batch, (q, 1), (v, 1), (a, 1),
                              None if f_ext is None else (f_ext, 2))


def generalized_gravity(model, q):
    """Gravity term ``g(q) = ∂U/∂q`` (N, N m), i.e. RNEA with ``v = a = 0``. ``(..., nq) -> (..., nv)``.

    Pinocchio counterpart: ``computeGeneralizedGravity``.
    """
    q = model.check_configuration(q)
    return _rnea(model, q, None, None, None, q.shape[:-1])


def bias_forces(model, q, v):
    """``h(q, v) = C(q, v) v + g(q)``, i.e. RNEA with ``a = 0``. ``-> (..., nv)``.

    Pinocchio counterpart: ``nonLinearEffects``.
    """
    q, v, *_, batch = _check(model, q, v)
    return _rnea(model, q, v, None, None, batch)


# ============================================================================= mass matrix

def mass_matrix(model, q, method="crba"):
    """Joint-space inertia matrix ``M(q)``, full and symmetric: ``(..., nq) -> (..., nv, nv)``.

    ``method="crba"``: Composite Rigid Body Algorithm (RBDA Table 6.2) in world coordinates; for
    batches of many states in joint coordinates (:func:`multibody.local.crba`).
    ``method="lagrangian"``: ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ`` from the world-frame Jacobian ``Jᵢ`` and inertia
    ``Iᵢ`` of each body, the kinetic energy ``T = ½ vᵀ M v`` made explicit.
    Pinocchio counterpart: ``crba`` (upper triangle, symmetrised).
    """
    if method == "crba":
        q = model.check_configuration(q)
        return _in_blocks_by_size(model, lambda q: _mass_matrix_crba(model, q), lambda q: local.crba(model, q),
                                  q.shape[:-1], (q, 1))
    if method == "lagrangian":
        q = model.check_configuration(q)
        jacobians, inertias = _world_body_jacobians_and_inertias(model, q)
        # M = Σ_i J_iᵀ I_i J_i
        M = np.einsum("...ick,...icd,...idl->...kl", jacobians, inertias, jacobians, optimize=True)
        return 0.5 * (M + transpose(M))  # exactly symmetric
    raise ValueError(f"method must be 'crba' or 'lagrangian', got {method!r}")


def _mass_matrix_crba(model, q, tree=None):
    """CRBA on lanes: ``q (nq, N) -> M (nv, nv, N)`` (``tree``: :func:`_tree` of ``q``, when at hand)."""
    # (only ξ and the inertias are held: the poses' memory is free for the temporaries below, which
    # costs Talos 10 % at 4096 states when it is not)
    _, _, _, xi, inertia = _tree(model, q) if tree is None else tree
    # Composite inertias: in world coordinates, I^c_i is the plain sum of the subtree's inertias.
    composite = _subtree_sums(model, inertia)
    # F_l = I^c_j(l) ξ_l ;  M_kl = ξ_kᵀ F_l when k's joint supports l's (RBDA eq. 6.14)
    F = lanes.matvec(_at_dofs(model, composite), xi)
    products = np.einsum("kcn,lcn->kln", xi, F)
    # M_kl is products[k, l] for k's joint supporting l's, mirrored below, zero off the branches: one
    # gather (model.mass_matrix_entries) from the products and a row of zeros.
    nv, n = products.shape[1:]
    with_zero = np.concatenate([products.reshape(nv * nv, n), np.zeros((1, n))])
    return with_zero[model.mass_matrix_entries]


def mass_matrix_and_bias(model, q, v):
    """``(M(q) (..., nv, nv), h(q, v) (..., nv))`` from one pass down the tree: CRBA and RNEA at ``a = 0``
    share the poses, ``ξ`` and world inertias (what a constrained or implicit step needs together)."""
    M, h, _ = mass_matrix_bias_and_frames(model, q, v)
    return M, h


def mass_matrix_bias_and_frames(model, q, v, frames=()):
    """:func:`mass_matrix_and_bias` and the :func:`~multibody.kinematics.frame_kinematics` of each
    ``(body, placement)`` in ``frames``, all from one pass down the tree (what a constrained step
    needs: its constraints read the frames). Returns ``(M, h, [(R_WF, p_WF, J, J̇v), ...])``."""
    q, v, *_, batch = _check(model, q, v)
    frames = [_frame_arguments(model, body, placement) for body, placement in frames]
    fixed = [_fixed_frame(model, b, X_BF, batch) for b, X_BF in frames]
    moving = [frame for frame, known in zip(frames, fixed) if known is None]

    def kernel(q, v):
        tree = _tree(model, q)
        motion = _velocities(model, tree.xi, v)
        F_subtree = _rnea_forces(model, q, v, None, None, tree, motion)[-1]
        return (_mass_matrix_crba(model, q, tree), _joint_forces(model, tree.xi, F_subtree),
                *(x for b, X_BF in moving for x in _frame_motion(model, b, X_BF, tree, *motion)))

    M, h, *values = _in_blocks(model, kernel, batch, (q, 1), (v, 1))
    computed = iter([tuple(values[k : k + 4]) for k in range(0, len(values), 4)])
    return M, h, [next(computed) if known is None else known for known in fixed]


def _world_body_jacobians_and_inertias(model, q):
    """World Plücker Jacobian ``(..., nj, 6, nv)`` and world inertia ``(..., nj, 6, 6)`` of each body."""
    xi, inertias = _world_tree(model, q)
    jacobians = transpose(xi)[..., None, :, :] * model.joint_support[:, None, :]
    return jacobians, inertias


# ============================================================================= Coriolis matrix

def coriolis_matrix(model, q, v, method="recursive"):
    """Christoffel-consistent Coriolis matrix ``C(q, v)``: ``Ṁ = C + Cᵀ``, ``C v + g = h``.

    ``method="recursive"`` (any joint type; equals Pinocchio's ``computeCoriolisMatrix``) sums,
    over bodies, ``C = Σᵢ Jᵢᵀ (Iᵢ J̇ᵢ + Bᵢ Jᵢ)`` in world Plücker coordinates with the body-level
    factorisation ``Bᵢ = ½ [(Vᵢ×*) Iᵢ + (Iᵢ Vᵢ)×̄* − Iᵢ (Vᵢ×)]`` (S. Echeandia and P. M. Wensing,
    *Numerical methods to compute the Coriolis matrix and Christoffel symbols for rigid-body
    systems*, J. Comput. Nonlinear Dyn. 16(9), 2021, eq. 20), where ``(f×̄*) m = m ×* f``.

    ``method="lagrangian"`` forms the Christoffel symbols of the first kind,
    ``Γᵢⱼₖ = ½ (∂Mᵢⱼ/∂qₖ + ∂Mᵢₖ/∂qⱼ − ∂Mⱼₖ/∂qᵢ)``, ``Cᵢⱼ = Σₖ Γᵢⱼₖ q̇ₖ``, from an analytic ``∂M/∂q``;
    it needs ``v = q̇`` (revolute, continuous, prismatic and translation joints only).

    Shapes: ``q (..., nq)``, ``v (..., nv)`` -> ``(..., nv, nv)``.
    """
    q, v, *_, batch = _check(model, q, v)
    if method == "recursive":
        return _in_blocks(model, lambda q, v: _coriolis_on_lanes(model, q, v), batch, (q, 1), (v, 1))
    if method == "lagrangian":
        return _coriolis_christoffel(model, q, v)
    raise ValueError(f"method must be 'recursive' or 'lagrangian', got {method!r}")


def _coriolis_on_lanes(model, q, v):
    """``C = Σᵢ Jᵢᵀ (Iᵢ J̇ᵢ + Bᵢ Jᵢ)`` on lanes, summed over bodies by composites: ``-> (nv, nv, N)``.

    Column l of ``Jᵢ`` is ``ξ_l`` when l's joint supports body i, so the bodies that both k and l
    move are the subtree of the deeper of their joints, and (as in Pinocchio's
    ``computeCoriolisMatrix``) ``C_kl = ξ_kᵀ (I^c_j ξ̇_l + B^c_j ξ_l)`` with ``j`` that joint and
    ``I^c``, ``B^c`` subtree sums of ``Iᵢ`` and ``Bᵢ``; zero when neither joint supports the other.
    """
    _, _, _, xi, inertia = _tree(model, q)
    V = _spatial_velocities(model, xi, v)
    # B_i = ½ [(V×*) I − I (V×) + (I V)×̄*] = ½ [(I V)×̄* − K − Kᵀ] with K = I (V×), as (V×*) = −(V×)ᵀ
    K = lanes.matmul(inertia, lanes.motion_cross_matrix(V))
    B = 0.5 * (lanes.bar_force_cross_matrix(lanes.matvec(inertia, V)) - K - lanes.transpose(K))
    composite = _subtree_sums(model, lanes.concatenate([inertia, B], axis=1))  # [I^c; B^c] (nj, 12, 6, N)
    composite = _at_dofs(model, composite)
    I_c, B_c = composite[:, :6], composite[:, 6:]
    # ξ̇_l = V_j(l) × ξ_l (the column moves with its own joint)
    xi_dot = lanes.motion_cross(_at_dofs(model, V), xi)
    # l's joint supports k's: C_kl = (I^c_j(k) ξ_k)ᵀ ξ̇_l + (B^c_j(k)ᵀ ξ_k)ᵀ ξ_l
    rows = lanes.concatenate([lanes.matvec(I_c, xi), lanes.matvec(lanes.transpose(B_c), xi)], axis=-2)
    below = np.einsum("kcn,lcn->kln", rows, lanes.concatenate([xi_dot, xi], axis=-2))
    # k's joint strictly supports l's: C_kl = ξ_kᵀ (I^c_j(l) ξ̇_l + B^c_j(l) ξ_l)
    columns = lanes.matvec(I_c, xi_dot) + lanes.matvec(B_c, xi)
    above = np.einsum("kcn,lcn->kln", xi, columns)
    return np.where(model.dof_ancestor.T[:, :, None], below,
                    np.where((model.dof_ancestor & ~model.dof_same_joint)[:, :, None], above, 0.0))


def _coriolis_christoffel(model, q, v):
    if any(joint.nq != joint.nv for joint in model.joints):
        raise ValueError("method='lagrangian' needs v = q̇ (revolute, continuous, prismatic and translation "
                         "joints only); use method='recursive'")
    dM = mass_matrix_derivative(model, q)  # (..., k, i, j) = ∂M_ij/∂q_k
    # Γ_ijk = ½ (∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i)
    christoffel = 0.5 * (np.einsum("...kij->...ijk", dM) + np.einsum("...jik->...ijk", dM)
                         - np.einsum("...ijk->...ijk", dM))
    # C_ij = Σ_k Γ_ijk q̇_k
    return np.einsum("...ijk,...k->...ij", christoffel, v)


def mass_matrix_derivative(model, q):
    """Analytic ``∂M/∂qₖ`` for models with ``v = q̇``: ``(..., nv, nv, nv)``, index order ``[k, i, j]``.

    From ``M = Σ_b J_bᵀ I_b J_b`` in world coordinates (b over bodies): a column ξ_l of J moves with
    every coordinate k of an ancestor joint, ``∂ξ_l/∂q_k = ξ_k × ξ_l``, and so does the world inertia
    of a body that k supports, ``∂I_b/∂q_k = (ξ_k×*) I_b − I_b (ξ_k×)``.
    """
    q = model.check_configuration(q)
    xi, inertias = _world_tree(model, q)
    support = model.joint_support  # (nj, nv)
    # ∂ξ_l/∂q_k is non-zero when k's joint is a strict ancestor of l's joint.
    strict = model.ancestors[model.dof_joint][:, model.dof_joint].T & (model.dof_joint[:, None] != model.dof_joint[None, :])
    d_xi = motion_cross(xi[..., :, None, :], xi[..., None, :, :]) * strict[:, :, None]  # [k, l, 6]
    # ∂J_b/∂q_k: columns l of body b, (..., k, b, 6, l)
    d_jacobians = np.einsum("...klc,bl->...kbcl", d_xi, support)
    jacobians = transpose(xi)[..., None, :, :] * support[:, None, :]  # (..., b, 6, l)
    d_inertias = (spatial.force_cross_matrix(xi)[..., :, None, :, :] @ inertias[..., None, :, :, :]
                  - inertias[..., None, :, :, :] @ spatial.motion_cross_matrix(xi)[..., :, None, :, :])
    d_inertias = d_inertias * support.T[:, :, None, None]  # (..., k, b, 6, 6)
    half = np.einsum("...kbci,...bcd,...bdj->...kij", d_jacobians, inertias, jacobians, optimize=True)
    return half + np.swapaxes(half, -1, -2) + np.einsum("...bci,...kbcd,...bdj->...kij", jacobians, d_inertias,
                                                        jacobians, optimize=True)


# ============================================================================= ABA

def _articulated_inertias(model, xi, inertia):
    """Backward pass of ABA for the q-dependent part (RBDA Table 7.1, second loop), in world coordinates.

    On lanes, level by level from the leaves, all joints of one depth and size at once. Returns per
    level group ``U_i = I^A_i S_i (k, 6, n, N)``, ``U_i D_i⁻¹`` and ``D_i⁻¹ = (S_iᵀ U_i)⁻¹ (k, n, n, N)``.
    In world coordinates a child's articulated inertia ``I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ`` adds to its
    parent's without transformation. A singular ``D_i`` leaves infinities (and NaN downstream), which
    :func:`_require_nonsingular` reports: one check per call instead of one per level.
    """
    articulated = inertia.copy()
    factors = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        for group in reversed(model.level_groups):
            S = xi[group.dofs]  # (k, n, 6, N)
            I_A = articulated[group.joints]
            # U_i = I^A_i S_i ;  D_i = S_iᵀ U_i
            U = lanes.matmul(I_A, lanes.transpose(S))
            D = lanes.matmul(S, U)
            D_inv = lanes.inverse(D)
            U_D_inv = lanes.matmul(U, D_inv)
            if group.parents is not None:
                # I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ ;  I^A_λ += I^a_i
                _add_to_parents(articulated, group, I_A - lanes.matmul(U_D_inv, lanes.transpose(U)))
            factors[group] = U, U_D_inv, D_inv
    return factors


def _require_nonsingular(model, factors, result):
    """``result``, or an error naming the first joint whose articulated inertia ``D_i`` is singular when
    ``result`` is not finite (a NaN input, already warned about, just propagates)."""
    if np.isfinite(result).all():
        return result
    for group, (_, _, D_inv) in factors.items():
        singular = ~np.isfinite(D_inv).all(axis=(1, 2)) & ~np.isnan(D_inv).any(axis=(1, 2))
        if singular.any():
            i = np.arange(model.njoints)[group.joints][np.flatnonzero(singular.any(axis=-1))[0]]
            raise np.linalg.LinAlgError(
                f"the mass matrix is singular: joint {model.joint_names[i]!r} moves no inertia "
                "(its articulated inertia Sᵀ I^A S is singular); give the bodies it carries mass and inertia")
    return result


def _articulated_solve(model, xi, factors, tau):
    """``q̈ = M⁻¹ τ`` from the articulated inertias: the last two sweeps of RBDA Table 7.1 with no velocity
    and no gravity (``c_i = 0``, ``p^A_i = 0``, ``a_0 = 0``), in world coordinates, on lanes.

    ``tau (nv, N)``; the lanes of ``xi`` and ``factors`` broadcast against it. Returns ``q̈ (nv, N)``.
    """
    n = max(xi.shape[-1], tau.shape[-1])
    p_art = np.zeros((model.njoints, 6, n))
    u = {}
    qdd = np.empty((model.nv, n))
    accelerations = np.empty(p_art.shape)
    with np.errstate(invalid="ignore"):  # a singular D_i (see _articulated_inertias)
        for group in reversed(model.level_groups):
            _, U_D_inv, _ = factors[group]
            p_i = p_art[group.joints]
            # u_i = τ_i − S_iᵀ p^A_i ;  p^a_i = p^A_i + U_i D_i⁻¹ u_i ;  p^A_λ += p^a_i
            u[group] = tau[group.dofs] - lanes.matvec(xi[group.dofs], p_i)
            if group.parents is not None:
                _add_to_parents(p_art, group, p_i + lanes.matvec(U_D_inv, u[group]))
        for group in model.level_groups:
            U, _, D_inv = factors[group]
            # q̈_i = D_i⁻¹ (u_i − U_iᵀ a_λ) ;  a_i = a_λ + S_i q̈_i   (a_λ = 0 at the root)
            if group.parents is None:
                qdd_i = lanes.matvec(D_inv, u[group])
                accelerations[group.joints] = lanes.matvec(lanes.transpose(xi[group.dofs]), qdd_i)
            else:
                a_parent = accelerations[group.parents]
                qdd_i = lanes.matvec(D_inv, u[group] - lanes.matvec(lanes.transpose(U), a_parent))
                accelerations[group.joints] = a_parent + lanes.matvec(lanes.transpose(xi[group.dofs]), qdd_i)
            qdd[group.dofs] = qdd_i
    return qdd


def forward_dynamics(model, q, v, tau, f_ext=None):
    """Accelerations ``a = M⁻¹ (τ + Σ Jᵀ f_ext − C v − g)`` by the Articulated Body Algorithm.

    RBDA Table 7.1 (§7.3), in world coordinates, with the velocity-product and gravity terms of the
    bias force taken from RNEA instead of the sweeps: ``h = C v + g − Σ Jᵀ f_ext`` is RNEA at
    ``a = 0`` (all joints at once, no level loop), and the articulated inertias with the two
    remaining sweeps solve ``M a = τ − h`` (for a single configuration, CRBA's ``M`` and LU instead:
    fewer NumPy calls, equal within rounding). Shapes: ``q (..., nq)``, ``v, tau (..., nv)``,
    ``f_ext (..., njoints, 6)`` -> ``a (..., nv)``. Batches of many states: RBDA Table 7.1 in joint
    coordinates (:func:`multibody.local.aba`). A joint that moves no inertia makes ``M``
    singular and raises ``numpy.linalg.LinAlgError`` naming it. Pinocchio counterpart: ``aba``.
    """
    q, v, _, tau, f_ext, batch = _check(model, q, v, tau=tau, f_ext=f_ext)
    if model.nv == 0:
        return np.zeros(batch + (0,))

    def joint_coordinates(*arrays):
        a = local.aba(model, *arrays)
        # a singular articulated inertia: the world-coordinate sweeps name the joint (or pass on the NaN)
        return a if np.isfinite(a).all() else _aba(model, *arrays)

    return _in_blocks_by_size(model, lambda *arrays: _aba(model, *arrays), joint_coordinates, batch,
                              (q, 1), (v, 1), (tau, 1), None if f_ext is None else (f_ext, 2))


def _aba(model, q, v, tau, f_ext):
    """ABA on lanes: ``q (nq, N)``, ``v, tau (nv, N)``, ``f_ext (nj, 6, N)`` or ``None`` -> ``a (nv, N)``."""
    tree = _tree(model, q)
    xi, inertia = tree.xi, tree.inertia
    # h = C v + g − Σ Jᵀ f_ext: RNEA at a = 0 ;  M a = τ − h
    _, _, _, F_subtree = _rnea_forces(model, q, v, None, f_ext, tree)
    rhs = tau - _joint_forces(model, xi, F_subtree)
    a = _single_configuration_solve(model, q, tree, rhs)
    if a is not None:
        return a
    factors = _articulated_inertias(model, xi, inertia)
    return _require_nonsingular(model, factors, _articulated_solve(model, xi, factors, rhs))


def _single_configuration_solve(model, q, tree, rhs):
    """``M⁻¹ rhs`` by CRBA and LU when ``q (nq, 1)`` is one configuration (``rhs (nv, k)``, any ``k``
    lanes sharing it), else ``None``; ``None`` too when ``M`` is singular or the result not finite,
    for the articulated sweeps to name the joint or propagate the NaN.

    For one configuration the sweeps' level loops cost more NumPy calls than forming ``M`` from the
    tree pass at hand and factoring it (``nv³/3`` flops are nothing at robot sizes): 2–3× faster.
    """
    if q.shape[-1] != 1:
        return None
    M = _mass_matrix_crba(model, q, tree)[..., 0]
    try:
        x = linalg.solve(M, rhs)
    except np.linalg.LinAlgError:
        return None
    return x if np.isfinite(x).all() else None


def inverse_mass_matrix(model, q):
    """``M(q)⁻¹`` by the Articulated Body Algorithm: ``(..., nq) -> (..., nv, nv)``.

    Column k is ABA's acceleration for a unit force on coordinate k with ``v = 0`` and no gravity;
    the articulated inertias are computed once and shared by all columns (each column a lane).
    For a single configuration, the inverse of CRBA's ``M`` by LU instead (fewer NumPy calls).
    Pinocchio counterpart: ``computeMinverse``.
    """
    q = model.check_configuration(q)
    batch, nv = q.shape[:-1], model.nv
    if nv == 0:
        return np.zeros(batch + (0, 0))

    def kernel(q):
        tree = _tree(model, q)
        xi, inertia = tree.xi, tree.inertia
        M_inv = _single_configuration_solve(model, q, tree, np.eye(nv))
        if M_inv is not None:
            return (0.5 * (M_inv + M_inv.T))[..., None]  # exactly symmetric, as the sweeps' result
        factors = _articulated_inertias(model, xi, inertia)
        n = xi.shape[-1]
        # Lane s nv + k: state s, unit force on coordinate k.
        repeat = lambda x: np.repeat(x, nv, axis=-1)  # noqa: E731
        factors = {group: tuple(repeat(x) for x in values) for group, values in factors.items()}
        columns = _require_nonsingular(model, factors, _articulated_solve(model, repeat(xi), factors, np.tile(np.eye(nv), n)))
        # columns[:, s nv + k] is (M⁻¹ e_k) of state s; M⁻¹ is symmetric.
        return columns.reshape(nv, n, nv).transpose(0, 2, 1)

    return _in_blocks(model, kernel, batch, (q, 1), block=max(1, model.lane_block // nv))


# ============================================================================= energies

def kinetic_energy(model, q, v):
    """``T = ½ vᵀ M(q) v = Σᵢ ½ Vᵢᵀ Iᵢ Vᵢ`` (J), with ``Vᵢ`` each body's spatial velocity. ``-> (...)``.

    Pinocchio counterpart: ``computeKineticEnergy``.
    """
    q, v, *_, batch = _check(model, q, v)

    def kernel(q, v):
        _, _, _, xi, inertia = _tree(model, q)
        V = _spatial_velocities(model, xi, v)
        return 0.5 * np.sum(V * lanes.matvec(inertia, V), axis=(0, 1))

    return _in_blocks(model, kernel, batch, (q, 1), (v, 1))


def potential_energy(model, q):
    """Gravitational potential ``U = −Σᵢ mᵢ gᵀ cᵢ`` (J) of the moving bodies, ``cᵢ`` their world centres of mass.

    Bodies fixed to the world are not counted (their energy is constant), as in Pinocchio's
    ``computePotentialEnergy``. ``(..., nq) -> (...)``.
    """
    q = model.check_configuration(q)

    def kernel(q):
        R_WJ, p_WJ = world_poses(model, q)
        mass, first_moment, _ = model.inertia_parameters
        # m c_W = R m c_J + m p
        moments = lanes.matvec(R_WJ, first_moment) + mass[:, None, None] * p_WJ
        return -np.einsum("c,jcn->n", model.gravity, moments)

    return _in_blocks(model, kernel, q.shape[:-1], (q, 1))
