"""Equations of motion ``M(q) a + C(q, v) v + g(q) = τ`` of a kinematic tree.

Two families of algorithms, which check each other:

* recursive (Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008): Recursive
  Newton–Euler (§5.3), Composite Rigid Body (§6.2), Articulated Body (§7.3), in joint frames;
* Lagrangian assembly from body Jacobians in world Plücker coordinates: ``T = ½ vᵀ M v`` with
  ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ``, and Christoffel symbols of ``M`` for ``C``.

Conventions (``docs/conventions.md``): spatial vectors are ``[linear; angular]``; gravity enters as
a fictitious acceleration ``a₀ = [−g; 0]`` of the world (RBDA §5.3); external forces ``f_ext`` have
shape ``(..., njoints, 6)``: the spatial force on the rigid body of each joint, expressed in that
joint's frame at its origin (Pinocchio's ``fext``).
Every function accepts leading batch axes on its array arguments and broadcasts them.
"""

from __future__ import annotations

import numpy as np

from . import spatial
from .kinematics import joint_velocities, joint_world_poses, world_motion_subspaces
from .spatial import force_cross, matvec, motion_cross, transform_force, transpose


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
    return q, *arrays, f_ext, np.broadcast_shapes(*shapes)


def _gravity_acceleration(model):
    """Fictitious base acceleration ``a₀ = [−g; 0]`` that accounts for gravity (RBDA §5.3)."""
    return np.concatenate([-model.gravity, np.zeros(3)])


def _world_tree(model, q):
    """World poses of the joint frames, world Plücker motion subspaces ``ξ (..., nv, 6)`` and
    world inertias ``ᵂI_i = ᵂX_i* I_i ⁱX_W`` ``(..., nj, 6, 6)`` (RBDA eq. 2.66)."""
    R_WJ, p_WJ = joint_world_poses(model, q)
    xi = world_motion_subspaces(model, R_WJ, p_WJ)
    return R_WJ, p_WJ, xi, spatial.transform_inertia(R_WJ, p_WJ, model.spatial_inertias)


def _velocities(model, xi, v):
    """World velocities ``V_j = Σ_{k ⪯ j} ξ_k v_k`` ``(..., nj, 6)`` and column rates ``ξ̇_k = V_j(k) × ξ_k``."""
    V = joint_velocities(model, xi, v)
    return V, motion_cross(V[..., model.dof_joint, :], xi)


# ============================================================================= RNEA

def inverse_dynamics(model, q, v, a, f_ext=None):
    """Joint forces ``τ = M(q) a + C(q, v) v + g(q) − Σ Jᵢᵀ f_ext,i`` by Recursive Newton–Euler.

    RBDA Table 5.1, written in world Plücker coordinates (RBDA §5.3, "RNEA in base coordinates"),
    where every recursion becomes a sum over the subtree or the support of a joint, so all
    joints are processed at once. Shapes: ``q (..., nq)``, ``v, a (..., nv)``,
    ``f_ext (..., njoints, 6)`` (see module docstring) -> ``τ (..., nv)`` (N or N m per coordinate).
    Pinocchio counterpart: ``rnea``.
    """
    q, v, a, _, f_ext, batch = _check(model, q, v, a, f_ext=f_ext)
    return _rnea(model, q, v, a, f_ext, batch)


def _rnea(model, q, v, a, f_ext, batch):
    """:func:`inverse_dynamics` on validated arrays with common batch shape ``batch``."""
    _, _, xi, F_subtree = _rnea_forces(model, q, v, a, f_ext)
    tau = np.sum(xi * F_subtree[..., model.dof_joint, :], axis=-1)
    return np.broadcast_to(tau, batch + (model.nv,))


def _rnea_forces(model, q, v, a, f_ext):
    """RNEA up to the joint forces: world poses, ``ξ``, and the force each joint transmits (world Plücker)."""
    R_WJ, p_WJ, xi, inertia = _world_tree(model, q)
    # Forward: v_i = v_λ + ξ_i q̇_i ;  a_i = a_λ + ξ_i q̈_i + ξ̇_i q̇_i  (summed over each support)
    V, xi_dot = _velocities(model, xi, v)
    A = _gravity_acceleration(model) + model.joint_support @ (xi * a[..., :, None] + xi_dot * v[..., :, None])
    # f_i = I_i a_i + v_i ×* I_i v_i − f_ext_i
    F = matvec(inertia, A) + force_cross(V, matvec(inertia, V))
    if f_ext is not None:
        F = F - transform_force(R_WJ, p_WJ, f_ext)
    # Backward: the force a joint transmits is the sum over its subtree;  τ_k = ξ_kᵀ f_subtree(j(k))
    return R_WJ, p_WJ, xi, model.descendants @ F


def joint_reaction_forces(model, q, v, a, f_ext=None):
    """Spatial force each joint transmits from its parent to its child body: ``(..., njoints, 6)``.

    The force ``[f; n]`` (N, N m) the parent exerts on the subtree of joint i through the joint,
    expressed in joint frame i at its origin: the RNEA backward-pass force ``f_i`` (RBDA Table 5.1).
    Its projection on the motion subspace is the joint force ``τ_i = S_iᵀ f_i``; the rest is what
    the joint's bearings carry. Constraint forces enter through ``f_ext`` (see
    ``ConstrainedSystem.body_forces``). Shapes as :func:`inverse_dynamics`.
    """
    q, v, a, _, f_ext, batch = _check(model, q, v, a, f_ext=f_ext)
    R_WJ, p_WJ, _, F_subtree = _rnea_forces(model, q, v, a, f_ext)
    return np.broadcast_to(spatial.inverse_transform_force(R_WJ, p_WJ, F_subtree), batch + (model.njoints, 6))


def generalized_gravity(model, q):
    """Gravity term ``g(q) = ∂U/∂q`` (N, N m), i.e. RNEA with ``v = a = 0``. ``(..., nq) -> (..., nv)``.

    Pinocchio counterpart: ``computeGeneralizedGravity``.
    """
    q = model.check_configuration(q)
    zeros = np.zeros(q.shape[:-1] + (model.nv,))
    return _rnea(model, q, zeros, zeros, None, q.shape[:-1])


def bias_forces(model, q, v):
    """``h(q, v) = C(q, v) v + g(q)``, i.e. RNEA with ``a = 0``. ``-> (..., nv)``.

    Pinocchio counterpart: ``nonLinearEffects``.
    """
    q, v, *_, batch = _check(model, q, v)
    return _rnea(model, q, v, np.zeros(batch + (model.nv,)), None, batch)


# ============================================================================= mass matrix

def mass_matrix(model, q, method="crba"):
    """Joint-space inertia matrix ``M(q)``, full and symmetric: ``(..., nq) -> (..., nv, nv)``.

    ``method="crba"``: Composite Rigid Body Algorithm (RBDA Table 6.2) in world coordinates.
    ``method="lagrangian"``: ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ`` from the world-frame Jacobian ``Jᵢ`` and inertia
    ``Iᵢ`` of each body, the kinetic energy ``T = ½ vᵀ M v`` made explicit.
    Pinocchio counterpart: ``crba`` (upper triangle, symmetrised).
    """
    if method == "crba":
        return _mass_matrix_crba(model, model.check_configuration(q))
    if method == "lagrangian":
        q = model.check_configuration(q)
        jacobians, inertias = _world_body_jacobians_and_inertias(model, q)
        # M = Σ_i J_iᵀ I_i J_i
        M = np.einsum("...ick,...icd,...idl->...kl", jacobians, inertias, jacobians, optimize=True)
        return 0.5 * (M + transpose(M))  # exactly symmetric
    raise ValueError(f"method must be 'crba' or 'lagrangian', got {method!r}")


def _mass_matrix_crba(model, q):
    _, _, xi, inertia = _world_tree(model, q)
    batch = q.shape[:-1]
    # Composite inertias: in world coordinates, I^c_i is the plain sum of the subtree's inertias.
    composite = (model.descendants @ inertia.reshape(batch + (model.njoints, 36))).reshape(
        batch + (model.njoints, 6, 6))
    # F_l = I^c_j(l) ξ_l ;  M_kl = ξ_kᵀ F_l when k's joint supports l's (RBDA eq. 6.14)
    F = matvec(composite[..., model.dof_joint, :, :], xi)
    products = xi @ transpose(F)
    upper = np.where(model.dof_ancestor, products, 0.0)
    M = upper + transpose(np.where(model.dof_same_joint, 0.0, upper))
    return 0.5 * (M + transpose(M))  # exactly symmetric


def _world_body_jacobians_and_inertias(model, q):
    """World Plücker Jacobian ``(..., nj, 6, nv)`` and world inertia ``(..., nj, 6, 6)`` of each body."""
    _, _, xi, inertias = _world_tree(model, q)
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
    q, v, *_ = _check(model, q, v)
    if method == "recursive":
        return _coriolis_recursive(model, q, v)
    if method == "lagrangian":
        return _coriolis_christoffel(model, q, v)
    raise ValueError(f"method must be 'recursive' or 'lagrangian', got {method!r}")


def _bar_force_cross_matrix(f):
    """6×6 matrix of ``m ↦ m ×* f`` for a fixed force ``f = [f; n]``: ``[[0, −[f]×], [−[f]×, −[n]×]]``."""
    F, N = spatial.skew(f[..., :3]), spatial.skew(f[..., 3:])
    out = np.zeros(f.shape[:-1] + (6, 6))
    out[..., :3, 3:] = -F
    out[..., 3:, :3] = -F
    out[..., 3:, 3:] = -N
    return out


def _coriolis_recursive(model, q, v):
    _, _, xi, inertias = _world_tree(model, q)
    # J̇ column k: ξ̇_k = V_j(k) × ξ_k, the column moves with its own joint.
    V, xi_dot = _velocities(model, xi, v)
    support = model.joint_support[:, None, :]
    jacobians = transpose(xi)[..., None, :, :] * support
    jacobian_rates = transpose(xi_dot)[..., None, :, :] * support
    # B_i = ½ [(V_i×*) I_i + (I_i V_i)×̄* − I_i (V_i×)]
    momentum = matvec(inertias, V)
    B = 0.5 * (spatial.force_cross_matrix(V) @ inertias + _bar_force_cross_matrix(momentum)
               - inertias @ spatial.motion_cross_matrix(V))
    # C = Σ_i J_iᵀ (I_i J̇_i + B_i J_i)
    return np.einsum("...ick,...icl->...kl", jacobians, inertias @ jacobian_rates + B @ jacobians, optimize=True)


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
    _, _, xi, inertias = _world_tree(model, q)
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

def _joint_columns(model, xi, i):
    """World motion subspace of joint i as a ``(..., 6, nv_i)`` matrix."""
    start = model.idx_v[i]
    return transpose(xi[..., start : start + model.joints[i].nv, :])


def _inverse(D):
    """Inverse of the small SPD matrices ``D (..., n, n)``; a reciprocal when ``n = 1``."""
    return 1.0 / D if D.shape[-1] == 1 else np.linalg.inv(D)


def _articulated_inertias(model, xi, inertia):
    """Backward pass of ABA for the q-dependent part (RBDA Table 7.1, second loop), in world coordinates.

    Returns per joint ``U_i = I^A_i S_i``, ``D_i⁻¹ = (S_iᵀ U_i)⁻¹`` and ``I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ``.
    In world coordinates a child's articulated inertia adds to its parent's without transformation.
    """
    n = model.njoints
    articulated = [inertia[..., i, :, :] for i in range(n)]
    U, D_inv, projected = [None] * n, [None] * n, [None] * n
    for i in range(n - 1, -1, -1):
        S = _joint_columns(model, xi, i)
        U[i] = articulated[i] @ S
        D = transpose(S) @ U[i]
        # A zero pivot means the joint moves no inertia; NaN input (already warned about) just propagates.
        if np.any(np.linalg.det(D[np.isfinite(D).all(axis=(-1, -2))]) == 0.0):
            raise np.linalg.LinAlgError(
                f"the mass matrix is singular: joint {model.joint_names[i]!r} moves no inertia "
                "(its articulated inertia Sᵀ I^A S is singular); give the bodies it carries mass and inertia")
        D_inv[i] = _inverse(D)
        parent = model.parents[i]
        if parent >= 0:
            # I^a_i = I^A_i − U_i D_i⁻¹ U_iᵀ ;  I^A_λ += I^a_i
            projected[i] = articulated[i] - U[i] @ D_inv[i] @ transpose(U[i])
            articulated[parent] = articulated[parent] + projected[i]
    return U, D_inv, projected


def _aba_bias_and_accelerations(model, xi, U, D_inv, projected, bias, p_art, tau, a0):
    """Bias-force backward pass and acceleration forward pass of ABA (RBDA Table 7.1), world coordinates.

    ``bias[i] = c_i`` (velocity-product acceleration of joint i), ``p_art[i] = p^A_i`` (bias forces);
    all arguments broadcast against each other over their leading axes.
    """
    n = model.njoints
    p_art = list(p_art)
    u = [None] * n
    for i in range(n - 1, -1, -1):
        start, parent = model.idx_v[i], model.parents[i]
        S = _joint_columns(model, xi, i)
        # u_i = τ_i − S_iᵀ p^A_i
        u[i] = tau[..., start : start + model.joints[i].nv] - matvec(transpose(S), p_art[i])
        if parent >= 0:
            # p^a_i = p^A_i + I^a_i c_i + U_i D_i⁻¹ u_i ;  p^A_λ += p^a_i
            p_art[parent] = p_art[parent] + p_art[i] + matvec(projected[i], bias[i]) + matvec(U[i], matvec(D_inv[i], u[i]))

    qdd, accelerations = [None] * n, [None] * n
    for i, parent in enumerate(model.parents):
        # a'_i = a_λ + c_i ;  q̈_i = D_i⁻¹ (u_i − U_iᵀ a'_i) ;  a_i = a'_i + S_i q̈_i
        a_prime = (a0 if parent < 0 else accelerations[parent]) + bias[i]
        qdd[i] = matvec(D_inv[i], u[i] - matvec(transpose(U[i]), a_prime))
        accelerations[i] = a_prime + matvec(_joint_columns(model, xi, i), qdd[i])
    shape = np.broadcast_shapes(*(x.shape[:-1] for x in qdd))
    return np.concatenate([np.broadcast_to(x, shape + x.shape[-1:]) for x in qdd], axis=-1)


def forward_dynamics(model, q, v, tau, f_ext=None):
    """Accelerations ``a = M⁻¹ (τ + Σ Jᵀ f_ext − C v − g)`` by the Articulated Body Algorithm.

    RBDA Table 7.1 (§7.3), in world coordinates. Shapes: ``q (..., nq)``, ``v, tau (..., nv)``,
    ``f_ext (..., njoints, 6)`` -> ``a (..., nv)``. A joint that moves no inertia makes ``M``
    singular and raises ``numpy.linalg.LinAlgError`` naming it. Pinocchio counterpart: ``aba``.
    """
    q, v, _, tau, f_ext, batch = _check(model, q, v, tau=tau, f_ext=f_ext)
    if model.nv == 0:
        return np.zeros(batch + (0,))
    R_WJ, p_WJ, xi, inertia = _world_tree(model, q)
    U, D_inv, projected = _articulated_inertias(model, xi, inertia)
    V, xi_dot = _velocities(model, xi, v)
    # c_i = ξ̇_i q̇_i (the joint's own columns) ;  p^A_i = v_i ×* I_i v_i − f_ext_i
    bias = model.own_dofs @ (xi_dot * v[..., :, None])
    p_art = force_cross(V, matvec(inertia, V))
    if f_ext is not None:
        p_art = p_art - transform_force(R_WJ, p_WJ, f_ext)
    a = _aba_bias_and_accelerations(model, xi, U, D_inv, projected, [bias[..., i, :] for i in range(model.njoints)],
                                    [p_art[..., i, :] for i in range(model.njoints)], tau, _gravity_acceleration(model))
    return np.broadcast_to(a, batch + (model.nv,)).copy()


def inverse_mass_matrix(model, q):
    """``M(q)⁻¹`` by the Articulated Body Algorithm: ``(..., nq) -> (..., nv, nv)``.

    Column k is ABA's acceleration for a unit force on coordinate k with ``v = 0`` and no gravity;
    the articulated inertias are computed once and shared by all columns.
    Pinocchio counterpart: ``computeMinverse``.
    """
    q = model.check_configuration(q)
    batch = q.shape[:-1]
    if model.nv == 0:
        return np.zeros(batch + (0, 0))
    _, _, xi, inertia = _world_tree(model, q)
    U, D_inv, projected = _articulated_inertias(model, xi, inertia)
    # A new axis (of length nv, one per unit force) just before the vector/matrix axes.
    expand = lambda items: [None if x is None else x[..., None, :, :] for x in items]  # noqa: E731
    U, D_inv, projected = expand(U), expand(D_inv), expand(projected)
    zero = [np.zeros(6)] * model.njoints
    columns = _aba_bias_and_accelerations(model, xi[..., None, :, :], U, D_inv, projected, zero, zero,
                                          np.eye(model.nv), np.zeros(6))
    # columns[..., k, :] is M⁻¹ e_k; M⁻¹ is symmetric, so this is already M⁻¹ row by row.
    return np.broadcast_to(columns, batch + (model.nv, model.nv)).copy()


# ============================================================================= energies

def kinetic_energy(model, q, v):
    """``T = ½ vᵀ M(q) v = Σᵢ ½ Vᵢᵀ Iᵢ Vᵢ`` (J), with ``Vᵢ`` each body's spatial velocity. ``-> (...)``.

    Pinocchio counterpart: ``computeKineticEnergy``.
    """
    q, v, *_ = _check(model, q, v)
    _, _, xi, inertia = _world_tree(model, q)
    V, _ = _velocities(model, xi, v)
    return 0.5 * np.sum(V * matvec(inertia, V), axis=(-1, -2))


def potential_energy(model, q):
    """Gravitational potential ``U = −Σᵢ mᵢ gᵀ cᵢ`` (J) of the moving bodies, ``cᵢ`` their world centres of mass.

    Bodies fixed to the world are not counted (their energy is constant), as in Pinocchio's
    ``computePotentialEnergy``. ``(..., nq) -> (...)``.
    """
    q = model.check_configuration(q)
    R_WJ, p_WJ = joint_world_poses(model, q)
    masses = np.array([inertia.mass for inertia in model.joint_inertias])
    coms = np.array([inertia.com for inertia in model.joint_inertias]).reshape(-1, 3)
    world_coms = matvec(R_WJ, coms) + p_WJ
    return -np.einsum("j,...jc,c->...", masses, world_coms, model.gravity)
