"""Equations of motion ``M(q) a + C(q, v) v + g(q) = τ`` of a kinematic tree.

Each function validates its inputs, hands them to one compiled kernel through the batch driver
(:mod:`multibody.driver`) and shapes the result; the algorithms themselves are in
:mod:`multibody.kernels` (R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008):
Recursive Newton–Euler (:mod:`~multibody.kernels.rnea`), Composite Rigid Body
(:mod:`~multibody.kernels.crba`), Articulated Body (:mod:`~multibody.kernels.aba`), the Coriolis
matrix (:mod:`~multibody.kernels.coriolis`) and the energies (:mod:`~multibody.kernels.energy`).

The ``method="lagrangian"`` forms check them the textbook way, in NumPy: ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ +
diag(armature)`` from world body Jacobians and inertias, ``C`` from the Christoffel symbols of ``M``.

Every algorithm adds the joints' armature (``model.armature``, rotor inertia) to the diagonal of ``M``,
as Pinocchio and MuJoCo do: ``τ`` gets ``armature ⊙ a``, the accelerations, ``M⁻¹``, the derivatives and
the kinetic energy ``½ vᵀ M v`` see it; ``C`` and ``g`` do not depend on it.

Conventions (``docs/conventions.md``): spatial vectors are ``[linear; angular]``; gravity enters as
a fictitious acceleration ``a₀ = [−g; 0]`` of the world (RBDA §5.3); external forces ``f_ext`` have
shape ``(..., njoints, 6)``: the spatial force on the rigid body of each joint, expressed in that
joint's frame at its origin (Pinocchio's ``fext``). Every function accepts leading batch axes on
its array arguments and broadcasts them, and takes ``out=``: a C-contiguous float64 array of the
result's shape that receives the result and is returned (:func:`multibody.driver.output`).

Finite inputs whose result is not finite raise: ``FloatingPointError`` when float64 overflowed,
naming the input whose size did it and the state of a batch; ``numpy.linalg.LinAlgError`` for a
singular mass matrix (:func:`_require_finite`).
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from . import driver, gpu, spatial
from .driver import NO_INPUT
from .kernels import aba, coriolis, crba, energy, rnea
from .kernels import derivatives as derivative_kernels
from .kinematics import frame_arguments, frame_motions, joint_world_poses
from .model import NOT_GIVEN, all_finite


# ============================================================================= shared pieces

def checked_arguments(model, q, v=NOT_GIVEN, a=NOT_GIVEN, tau=NOT_GIVEN, f_ext=None):
    """Validated float arrays and their common batch shape (``f_ext`` flattened to ``(..., 6 nj)``);
    the arguments a function does not take come back as ``None``."""
    if f_ext is None and model.is_one_state(q, v, tau if a is NOT_GIVEN else a):
        given = [None if x is NOT_GIVEN else x for x in (v, a, tau)]
        return q, *given, None, ()
    q = model.check_configuration(q)
    v = None if v is NOT_GIVEN else model.check_velocity(v, "v")
    a = None if a is NOT_GIVEN else model.check_velocity(a, "a")
    tau = None if tau is NOT_GIVEN else model.check_velocity(tau, "tau")
    shapes = {name: x.shape[:-1] for name, x in (("q", q), ("v", v), ("a", a), ("tau", tau)) if x is not None}
    if f_ext is not None:
        f_ext = model.check_external_forces(f_ext)
        shapes["f_ext"] = f_ext.shape[:-2]
        f_ext = f_ext.reshape(f_ext.shape[:-2] + (6 * model.njoints,))
    try:
        batch = spatial.batch_shape(*shapes.values())
    except ValueError:
        raise ValueError("the leading (batch) axes of " + ", ".join(f"{name} {shape}" for name, shape in shapes.items())
                         + " do not broadcast") from None
    return q, v, a, tau, f_ext, batch


def _single(model, kernel, out_shape, q, v=NOT_GIVEN, w=NOT_GIVEN):
    """``kernel``'s output ``out_shape`` for one state when ``q`` and the velocities ``v``, ``w`` given are
    exactly that, C-contiguous float64 vectors of sizes ``nq`` and ``nv`` (:meth:`multibody.Model.is_one_state`), and
    its output is finite; ``None`` otherwise, for the general path (conversion, broadcasting, the full
    checks and their warnings).

    The single call's path, which leaves the entries to :func:`multibody.driver.vouches`."""
    if not model.is_one_state(q, v, w, finite=False):
        return None
    out = driver.evaluate_one(kernel, model.tree, out_shape, q, NO_INPUT if v is NOT_GIVEN else v,
                              NO_INPUT if w is NOT_GIVEN else w)
    return out if driver.vouches(out) else None


def _on_device(q):
    """Whether ``q`` is a CUDA array, which sends the call to :mod:`multibody.gpu`."""
    return type(q) is not np.ndarray and gpu.is_device_array(q)


def _on_gpu(model, kernel, inputs, out_shape, template, out=None):
    """``kernel`` on the GPU: ``inputs`` ``(name, array or None, trailing size)`` -> a device array
    ``batch + out_shape`` (of ``template``'s library)."""
    if out is not None:
        raise ValueError("out must be None for CUDA arrays: the result is a new device array")
    arrays, batch = gpu.check(inputs)
    out = gpu.evaluate_device(kernel, gpu.device_tree(model), arrays, out_shape if len(out_shape) == 2
                              else (1,) + out_shape, batch)
    return gpu.like(out.reshape(batch + out_shape), template)


def _vector(model, kernel, inputs, batch, out=None):
    """A kernel whose per-state output is one vector ``(nv,)``: ``-> batch + (nv,)`` (:func:`evaluate_checked`)."""
    return evaluate_checked(model, kernel, inputs, (1, model.nv), batch, out, (model.nv,))


def evaluate_checked(model, kernel, inputs, out_shape, batch, out=None, shape=None):
    """``kernel`` on ``inputs`` through the batch driver (:func:`multibody.driver.evaluate`, whose
    arguments these are), its result checked by :func:`_require_finite`: every dynamics kernel's result
    passes here."""
    result = driver.evaluate(kernel, model.tree, inputs, out_shape, batch, out=out, shape=shape)
    return _require_finite(model, kernel, inputs, out_shape, result, batch)


def _written(out, result):
    """``result`` (NumPy's, of a ``method="lagrangian"`` form), or ``out`` holding it when given."""
    if out is None:
        return result
    driver.output(out, result.shape)[...] = result
    return out


#: Kernels that divide by the joints' articulated inertias ``Sᵀ I^A S``: a result that is not finite at
#: finite inputs of ordinary size comes from a singular mass matrix.
_INVERTING = frozenset((aba.forward_dynamics, crba.inverse_mass_matrix, derivative_kernels.forward_dynamics_derivatives))

#: Entries beyond this size make an input a suspect when a result overflows (no quantity of a mechanism in
#: SI units comes near it); the state evaluated again without the suspect confirms it.
_HUGE = 1e30

#: What an input too large overflows, for the message.
_TERMS = {"q": "the terms of the bodies' positions (moments, inertias about the joints)", "v": "the velocity-product terms",
          "a": "the inertial terms M a", "tau": "the terms M⁻¹ τ", "f_ext": "the external-force terms"}


def _require_finite(model, kernel, inputs, out_shape, result, batch):
    """``result`` (``batch + ...``) of ``kernel`` on ``inputs`` (leading axes broadcasting to ``batch``,
    kernel output ``out_shape`` per state), or an error when it is not finite at a state whose inputs
    are (a state with a NaN or infinite input, already warned about, just propagates). The error names
    that state of a batch (the first, and how many there are):

    * ``FloatingPointError`` when an input's size overflowed float64: it names the input and its
      largest entry. Suspects are the inputs with entries beyond :data:`_HUGE`; one is to blame when the
      state's result is finite without it (zero, or the neutral configuration for ``q``), and so are
      all of them together when only that makes it finite.
    * ``numpy.linalg.LinAlgError`` from a kernel of :data:`_INVERTING` otherwise, when the state's mass
      matrix is finite: it is singular (:func:`_singular`).
    * ``FloatingPointError`` otherwise: the model's own masses, inertias or lengths overflowed.

    A finite result costs one sum (:func:`~multibody.model.all_finite`); the rest runs only on a result
    that is not."""
    if all_finite(result):
        return result
    n = math.prod(batch)
    failed = ~np.isfinite(result.reshape(n, -1)).all(axis=1)
    for x in inputs:
        if x is not None:
            failed &= np.broadcast_to(np.isfinite(x).all(axis=-1), batch).reshape(n)
    states = np.flatnonzero(failed)
    if not states.size:
        return result
    index = tuple(int(i) for i in np.unravel_index(states[0], batch))
    state = {name: np.broadcast_to(x, batch + x.shape[-1:])[index]
             for name, x in zip(list(inspect.signature(getattr(kernel, "py_func", kernel)).parameters)[3:], inputs)
             if x is not None}
    where = "" if not batch else (f" at state {index} of the batch" if states.size == 1 else
                                  f" at state {index} of the batch (the first of {states.size} states)")
    largest = {name: float(np.max(np.abs(x), initial=0.0)) for name, x in state.items()}

    def finite_without(names):
        xs = [(model.neutral() if name == "q" else np.zeros_like(x)) if name in names else x for name, x in state.items()]
        return np.isfinite(driver.evaluate(kernel, model.tree, tuple(xs), out_shape)).all()

    suspects = [name for name, size in largest.items() if size > _HUGE]
    blamed = [name for name in suspects if finite_without((name,))]
    if not blamed and len(suspects) > 1 and finite_without(suspects):
        blamed = suspects
    if blamed:
        sizes = " and ".join(f"{name} has entries up to {largest[name]:.3g}" for name in blamed)
        terms = _TERMS[blamed[0]] if len(blamed) == 1 else "together their terms"
        raise FloatingPointError(f"the computation overflowed float64{where}: {sizes}; {terms} overflow float64")
    if kernel in _INVERTING and np.isfinite(driver.evaluate(crba.mass_matrix, model.tree, (state["q"],),
                                                            (model.nv, model.nv))).all():
        _singular(model, where)
    sizes = ", ".join(f"{name} {size:.3g}" for name, size in largest.items())
    raise FloatingPointError(f"the computation overflowed float64{where}, and no input's size explains it (largest "
                             f"entries: {sizes}): the model's masses, inertias or lengths are too large for float64")


# ============================================================================= RNEA

def inverse_dynamics(model, q, v, a, f_ext=None, *, out=None):
    """Joint forces ``τ = M(q) a + C(q, v) v + g(q) − Σ Jᵢᵀ f_ext,i`` by Recursive Newton–Euler.

    RBDA Table 5.1 (:func:`multibody.kernels.rnea.inverse_dynamics`). Shapes: ``q (..., nq)``,
    ``v, a (..., nv)``, ``f_ext (..., njoints, 6)`` (see module docstring) -> ``τ (..., nv)`` (N or N m
    per coordinate), written into ``out`` when given (C-contiguous float64 of that shape). Inputs so large
    that float64 overflows raise ``FloatingPointError`` naming the input. Pinocchio counterpart: ``rnea``.
    CUDA arrays in, CUDA arrays out (:mod:`multibody.gpu`).
    """
    if f_ext is None and out is None and (tau := _single(model, rnea.inverse_dynamics, (1, model.nv), q, v, a)) is not None:
        return tau[0]
    if _on_device(q):
        return _on_gpu(model, rnea.inverse_dynamics, (("q", q, model.nq), ("v", v, model.nv), ("a", a, model.nv),
                                                      ("f_ext", f_ext, (model.njoints, 6))), (model.nv,), q, out)
    q, v, a, _, f_ext, batch = checked_arguments(model, q, v, a, f_ext=f_ext)
    return _vector(model, rnea.inverse_dynamics, (q, v, a, f_ext), batch, out)


def joint_reaction_forces(model, q, v, a, f_ext=None, *, out=None):
    """Spatial force each joint transmits from its parent to its child body: ``(..., njoints, 6)``.

    The force ``[f; n]`` (N, N m) the parent exerts on the subtree of joint i through the joint,
    expressed in joint frame i at its origin: the RNEA backward-pass force ``f_i`` (RBDA Table 5.1).
    Its projection on the motion subspace, ``S_iᵀ f_i``, is the joint force ``τ_i`` less the armature's
    share ``armature_i ⊙ a_i`` (the rotor is no body); the rest is what the joint's bearings carry.
    Constraint forces enter through ``f_ext`` (see ``ConstrainedSystem.body_forces``). Shapes, ``out`` and
    errors as :func:`inverse_dynamics`.
    """
    q, v, a, _, f_ext, batch = checked_arguments(model, q, v, a, f_ext=f_ext)
    return evaluate_checked(model, rnea.joint_reaction_forces, (q, v, a, f_ext), (model.njoints, 6), batch, out)


def generalized_gravity(model, q, *, out=None):
    """Gravity term ``g(q) = ∂U/∂q`` (N, N m), i.e. RNEA with ``v = a = 0``. ``(..., nq) -> (..., nv)``;
    ``out`` and errors as :func:`inverse_dynamics`.

    Pinocchio counterpart: ``computeGeneralizedGravity``.
    """
    if out is None and (g := _single(model, rnea.inverse_dynamics, (1, model.nv), q)) is not None:
        return g[0]
    if _on_device(q):
        return _on_gpu(model, rnea.inverse_dynamics, (("q", q, model.nq),), (model.nv,), q, out)
    q = model.check_configuration(q)
    return _vector(model, rnea.inverse_dynamics, (q,), q.shape[:-1], out)


def bias_forces(model, q, v, *, out=None):
    """``h(q, v) = C(q, v) v + g(q)``, i.e. RNEA with ``a = 0``. ``-> (..., nv)``; ``out`` and errors as
    :func:`inverse_dynamics`.

    Pinocchio counterpart: ``nonLinearEffects``.
    """
    if out is None and (h := _single(model, rnea.inverse_dynamics, (1, model.nv), q, v)) is not None:
        return h[0]
    if _on_device(q):
        return _on_gpu(model, rnea.inverse_dynamics, (("q", q, model.nq), ("v", v, model.nv)), (model.nv,), q, out)
    q, v, *_, batch = checked_arguments(model, q, v)
    return _vector(model, rnea.inverse_dynamics, (q, v), batch, out)


# ============================================================================= mass matrix

def mass_matrix(model, q, method="crba", *, out=None):
    """Joint-space inertia matrix ``M(q)``, full and symmetric: ``(..., nq) -> (..., nv, nv)``; ``out`` and
    errors as :func:`inverse_dynamics`.

    ``method="crba"``: Composite Rigid Body Algorithm (RBDA Table 6.2,
    :func:`multibody.kernels.crba.mass_matrix`).
    ``method="lagrangian"``: ``M = Σᵢ Jᵢᵀ Iᵢ Jᵢ + diag(armature)`` from the world-frame Jacobian ``Jᵢ`` and
    inertia ``Iᵢ`` of each body, the kinetic energy ``T = ½ vᵀ M v`` made explicit.
    Both hold ``model.armature`` on the diagonal. Pinocchio counterpart: ``crba`` (upper triangle,
    symmetrised).
    """
    if method not in ("crba", "lagrangian"):
        raise ValueError(f"method must be 'crba' or 'lagrangian', got {method!r}")
    if method == "crba" and out is None and (M := _single(model, crba.mass_matrix, (model.nv, model.nv), q)) is not None:
        return M
    if method == "crba" and _on_device(q):
        return _on_gpu(model, crba.mass_matrix, (("q", q, model.nq),), (model.nv, model.nv), q, out)
    q = model.check_configuration(q)
    if method == "crba":
        return evaluate_checked(model, crba.mass_matrix, (q,), (model.nv, model.nv), q.shape[:-1], out)
    _, jacobians, inertias = _world_tree(model, q)
    # M = Σ_i J_iᵀ I_i J_i + diag(armature)
    M = np.einsum("...ick,...icd,...idl->...kl", jacobians, inertias, jacobians, optimize=True)
    M = 0.5 * (M + spatial.transpose(M))  # exactly symmetric
    M[..., np.arange(model.nv), np.arange(model.nv)] += model.armature
    return _written(out, M)


def mass_matrix_and_bias(model, q, v):
    """``(M(q) (..., nv, nv), h(q, v) (..., nv))``: what a constrained or implicit step needs together."""
    M, h, _ = mass_matrix_bias_and_frames(model, q, v)
    return M, h


def mass_matrix_bias_and_frames(model, q, v, frames=()):
    """:func:`mass_matrix_and_bias` and the :func:`~multibody.kinematics.frame_kinematics` of each
    ``(body, placement)`` in ``frames``. Returns ``(M, h, [(R_WF, p_WF, J, J̇v), ...])``."""
    q, v, *_, batch = checked_arguments(model, q, v)
    M = evaluate_checked(model, crba.mass_matrix, (q,), (model.nv, model.nv), batch)
    h = _vector(model, rnea.inverse_dynamics, (q, v), batch)
    if not frames:
        return M, h, []
    return M, h, frame_motions(model, q, v, [frame_arguments(model, body, placement) for body, placement in frames],
                               batch)


def _world_tree(model, q):
    """Each velocity coordinate's unit motion ``ξ (..., nv, 6)``, each moving body's Jacobian ``(..., nj, 6, nv)``
    (the columns ``ξ`` of the coordinates that move it) and inertia ``(..., nj, 6, 6)``, world axes at the first
    joint's origin O (a point near the bodies keeps the moments ``p × f`` small), for the Lagrangian assemblies."""
    R_WJ, p_WJ = joint_world_poses(model, q)
    p_OJ = p_WJ - p_WJ[..., :1, :]
    R, p = R_WJ[..., model.dof_joint, :, :], p_OJ[..., model.dof_joint, :]
    # ξ_k = ᴼX_j S_k: ω = R s_ω, v = R s_v + p × ω
    S = model.motion_subspaces
    angular = spatial.matvec(R, S[:, 3:])
    xi = np.concatenate([spatial.matvec(R, S[:, :3]) + spatial.cross(p, angular), angular], axis=-1)
    inertias = spatial.transform_inertia(R_WJ, p_OJ, model.spatial_inertias)
    jacobians = spatial.transpose(xi)[..., None, :, :] * model.joint_support[:, None, :]
    return xi, jacobians, inertias


# ============================================================================= Coriolis matrix

def coriolis_matrix(model, q, v, method="recursive", *, out=None):
    """Christoffel-consistent Coriolis matrix ``C(q, v)``: ``Ṁ = C + Cᵀ``, ``C v + g = h``.

    ``method="recursive"``: :func:`multibody.kernels.coriolis.coriolis_matrix`, Pinocchio's
    ``computeCoriolisMatrix``.
    ``method="lagrangian"`` forms the Christoffel symbols of the first kind,
    ``Γᵢⱼₖ = ½ (∂Mᵢⱼ/∂qₖ + ∂Mᵢₖ/∂qⱼ − ∂Mⱼₖ/∂qᵢ)``, ``Cᵢⱼ = Σₖ Γᵢⱼₖ q̇ₖ``, from an analytic ``∂M/∂q``;
    it needs ``v = q̇`` (revolute, continuous, prismatic and translation joints only).

    Shapes: ``q (..., nq)``, ``v (..., nv)`` -> ``(..., nv, nv)``; ``out`` and errors as :func:`inverse_dynamics`.
    """
    if method not in ("recursive", "lagrangian"):
        raise ValueError(f"method must be 'recursive' or 'lagrangian', got {method!r}")
    if (method == "recursive" and out is None
            and (C := _single(model, coriolis.coriolis_matrix, (model.nv, model.nv), q, v)) is not None):
        return C
    q, v, *_, batch = checked_arguments(model, q, v)
    if method == "recursive":
        return evaluate_checked(model, coriolis.coriolis_matrix, (q, v), (model.nv, model.nv), batch, out)
    if any(joint.nq != joint.nv for joint in model.joints):
        raise ValueError("method='lagrangian' needs v = q̇ (revolute, continuous, prismatic and translation "
                         "joints only); use method='recursive'")
    dM = mass_matrix_derivative(model, q)  # (..., k, i, j) = ∂M_ij/∂q_k
    # Γ_ijk = ½ (∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i)
    christoffel = 0.5 * (np.einsum("...kij->...ijk", dM) + np.einsum("...jik->...ijk", dM)
                         - np.einsum("...ijk->...ijk", dM))
    # C_ij = Σ_k Γ_ijk q̇_k
    return _written(out, np.einsum("...ijk,...k->...ij", christoffel, v))


def mass_matrix_derivative(model, q):
    """Analytic ``∂M/∂qₖ`` for models with ``v = q̇``: ``(..., nv, nv, nv)``, index order ``[k, i, j]``.

    From ``M = Σ_b J_bᵀ I_b J_b`` in world coordinates (b over bodies): a column ξ_l of J moves with
    every coordinate k of an ancestor joint, ``∂ξ_l/∂q_k = ξ_k × ξ_l``, and so does the world inertia
    of a body that k supports, ``∂I_b/∂q_k = (ξ_k×*) I_b − I_b (ξ_k×)``.
    """
    q = model.check_configuration(q)
    xi, jacobians, inertias = _world_tree(model, q)  # jacobians (..., b, 6, l)
    support = model.joint_support  # (nj, nv)
    # ∂ξ_l/∂q_k is non-zero when k's joint is a strict ancestor of l's joint.
    strict = model.ancestors[model.dof_joint][:, model.dof_joint].T & (model.dof_joint[:, None] != model.dof_joint[None, :])
    d_xi = spatial.motion_cross(xi[..., :, None, :], xi[..., None, :, :]) * strict[:, :, None]  # [k, l, 6]
    # ∂J_b/∂q_k: columns l of body b, (..., k, b, 6, l)
    d_jacobians = np.einsum("...klc,bl->...kbcl", d_xi, support)
    d_inertias = (spatial.force_cross_matrix(xi)[..., :, None, :, :] @ inertias[..., None, :, :, :]
                  - inertias[..., None, :, :, :] @ spatial.motion_cross_matrix(xi)[..., :, None, :, :])
    d_inertias = d_inertias * support.T[:, :, None, None]  # (..., k, b, 6, 6)
    half = np.einsum("...kbci,...bcd,...bdj->...kij", d_jacobians, inertias, jacobians, optimize=True)
    return half + np.swapaxes(half, -1, -2) + np.einsum("...bci,...kbcd,...bdj->...kij", jacobians, d_inertias,
                                                        jacobians, optimize=True)


# ============================================================================= ABA

def _singular(model, where=""):
    """``LinAlgError``: the mass matrix is singular (``where``: at which state of a batch, or ""). The error
    names the first joint whose subtree carries no inertia at all and whose coordinates do not all have
    armature (which alone keeps ``Sᵀ I^A S + diag(armature)`` regular), the usual cause (at every state)."""
    for i in range(model.njoints):
        subtree = [model.joint_inertias[j] for j in range(i, model.njoints) if model.ancestors[j, i]]
        own = model.armature[model.idx_v[i] : model.idx_v[i] + model.joints[i].nv]
        if not any(inertia.mass or np.any(inertia.rotational) for inertia in subtree) and not np.all(own > 0.0):
            raise np.linalg.LinAlgError(
                f"the mass matrix is singular: joint {model.joint_names[i]!r} moves no inertia "
                "(its articulated inertia Sᵀ I^A S is singular); give the bodies it carries mass and inertia")
    raise np.linalg.LinAlgError(f"the mass matrix is singular {where.strip() or 'at this configuration'} (the "
                                "articulated inertia Sᵀ I^A S of some joint is singular)")


def forward_dynamics(model, q, v, tau, f_ext=None, *, out=None):
    """Accelerations ``a = M⁻¹ (τ + Σ Jᵀ f_ext − C v − g)`` by the Articulated Body Algorithm.

    RBDA Table 7.1 (:func:`multibody.kernels.aba.forward_dynamics`). Shapes: ``q (..., nq)``,
    ``v, tau (..., nv)``, ``f_ext (..., njoints, 6)`` -> ``a (..., nv)``; ``out`` as
    :func:`inverse_dynamics`. A joint that moves no inertia makes ``M`` singular and raises
    ``numpy.linalg.LinAlgError`` naming it; inputs so large that float64 overflows raise
    ``FloatingPointError`` naming the input. Pinocchio counterpart: ``aba``. On CUDA arrays
    (:mod:`multibody.gpu`) a singular ``M`` gives NaN rather than the error.
    """
    # (a result that is not finite throughout takes the general path, whose check says why)
    if (f_ext is None and out is None and (a := _single(model, aba.forward_dynamics, (1, model.nv), q, v, tau)) is not None
            and all_finite(a)):
        return a[0]
    if _on_device(q):
        return _on_gpu(model, aba.forward_dynamics, (("q", q, model.nq), ("v", v, model.nv), ("tau", tau, model.nv),
                                                     ("f_ext", f_ext, (model.njoints, 6))), (model.nv,), q, out)
    q, v, _, tau, f_ext, batch = checked_arguments(model, q, v, tau=tau, f_ext=f_ext)
    return articulated_body_accelerations(model, q, v, tau, f_ext, batch, out)


def articulated_body_accelerations(model, q, v, tau, f_ext, batch, out=None):
    """:func:`forward_dynamics` of inputs already checked: float64 arrays of the right sizes, whose
    leading axes broadcast to ``batch`` (``f_ext (..., 6 nj)`` or ``None``). For callers that produce
    their own states, such as the integrators."""
    return _vector(model, aba.forward_dynamics, (q, v, tau, f_ext), batch, out)


def inverse_mass_matrix(model, q, *, out=None):
    """``M(q)⁻¹`` from CRBA's ``M`` and its sparse ``Lᵀ L`` factorization
    (:func:`multibody.kernels.crba.inverse_mass_matrix`): ``(..., nq) -> (..., nv, nv)``; ``out`` as
    :func:`inverse_dynamics`. A joint that moves no inertia makes ``M`` singular and raises
    ``numpy.linalg.LinAlgError`` naming it. Pinocchio counterpart: ``computeMinverse``.
    """
    q = model.check_configuration(q)
    return evaluate_checked(model, crba.inverse_mass_matrix, (q,), (model.nv, model.nv), q.shape[:-1], out)


# ============================================================================= energies

def kinetic_energy(model, q, v, *, out=None):
    """``T = ½ vᵀ M(q) v = Σᵢ ½ Vᵢᵀ Iᵢ Vᵢ + ½ Σₖ armatureₖ vₖ²`` (J), with ``Vᵢ`` each body's spatial velocity
    and the joints' rotor inertia ``model.armature``. ``-> (...)``
    (a float64 scalar for one state); ``out`` (of shape ``(...)``) and errors as :func:`inverse_dynamics`.

    Pinocchio counterpart: ``computeKineticEnergy``.
    """
    if out is None and (T := _single(model, energy.kinetic_energy, (1, 1), q, v)) is not None:
        return T[0, 0]
    q, v, *_, batch = checked_arguments(model, q, v)
    T = evaluate_checked(model, energy.kinetic_energy, (q, v), (1, 1), batch, out, ())
    return T[()] if out is None else T


def potential_energy(model, q, *, out=None):
    """Gravitational potential ``U = −Σᵢ mᵢ gᵀ cᵢ`` (J) of the moving bodies, ``cᵢ`` their world centres of mass.

    Bodies fixed to the world are not counted (their energy is constant), as in Pinocchio's
    ``computePotentialEnergy``. ``(..., nq) -> (...)`` (a float64 scalar for one state); ``out`` and errors
    as :func:`kinetic_energy`.
    """
    if out is None and (U := _single(model, energy.potential_energy, (1, 1), q)) is not None:
        return U[0, 0]
    q = model.check_configuration(q)
    U = evaluate_checked(model, energy.potential_energy, (q,), (1, 1), q.shape[:-1], out, ())
    return U[()] if out is None else U


def mechanical_energy(model, q, v):
    """``E = T + U`` (J): :func:`kinetic_energy` plus :func:`potential_energy` from one pass down the tree
    (:func:`multibody.kernels.energy.mechanical_energy`). ``-> (...)`` (a float64 scalar for one state); errors as
    :func:`kinetic_energy`."""
    if (E := _single(model, energy.mechanical_energy, (1, 1), q, v)) is not None:
        return E[0, 0]
    q, v, *_, batch = checked_arguments(model, q, v)
    E = evaluate_checked(model, energy.mechanical_energy, (q, v), (1, 1), batch, None, ())
    return E[()]
