"""Analytical derivatives of inverse and forward dynamics, batched over leading axes.

J. Carpentier and N. Mansard, *Analytical Derivatives of Rigid Body Dynamics Algorithms*, RSS 2018,
compiled in :mod:`multibody.kernels.derivatives`. Derivatives with respect to ``q`` are taken in the
tangent space, as Pinocchio's are: ``∂f/∂q`` is ``∂f(q ⊕ δq)/∂δq`` at ``δq = 0``, with ``δq`` of size
``nv`` and ``q ⊕ δq = model.integrate(q, δq)``, so that free-flyer, spherical and planar joints are
differentiated along their own velocity coordinates (the body-frame twist of the joint).

Matrices have one row per output coordinate and one column per coordinate differentiated:
``dtau_dq[..., i, k] = ∂τ_i/∂δq_k``. Shapes and the external forces ``f_ext (..., njoints, 6)`` are as
in :mod:`multibody.dynamics`.
"""

from __future__ import annotations

from .dynamics import checked_arguments, evaluate_checked
from .kernels import derivatives as kernels


def inverse_dynamics_derivatives(model, q, v, a, f_ext=None):
    """``(∂τ/∂q, ∂τ/∂v)`` of the inverse dynamics ``τ = RNEA(q, v, a, f_ext)``, each ``(..., nv, nv)``.

    ``∂τ/∂a`` is ``M(q)`` (:func:`multibody.mass_matrix`). Units are those of ``τ`` (N, N·m) per unit of
    the coordinate (m, rad; m/s, rad/s). ``q (..., nq)``, ``v, a (..., nv)``,
    ``f_ext (..., njoints, 6)`` (each joint's body, its frame). Pinocchio counterpart:
    ``computeRNEADerivatives`` (``dtau_dq``, ``dtau_dv``).
    """
    q, v, a, _, f_ext, batch = checked_arguments(model, q, v, a, f_ext=f_ext)
    nv = model.nv
    out = evaluate_checked(model, kernels.inverse_dynamics_derivatives, (q, v, a, f_ext), (2 * nv, nv), batch)
    return out[..., :nv, :], out[..., nv:, :]


def gravity_derivatives(model, q):
    """``∂g/∂q`` of the generalized gravity ``g(q)`` (:func:`multibody.generalized_gravity`): ``(..., nv, nv)``.

    ``q (..., nq)``. Pinocchio counterpart: ``computeGeneralizedGravityDerivatives``.
    """
    q = model.check_configuration(q)
    return evaluate_checked(model, kernels.inverse_dynamics_derivatives, (q,), (model.nv, model.nv), q.shape[:-1])


def forward_dynamics_derivatives(model, q, v, tau, f_ext=None):
    """``(∂a/∂q, ∂a/∂v, ∂a/∂τ)`` of the forward dynamics ``a = ABA(q, v, τ, f_ext)``, each ``(..., nv, nv)``.

    ``∂a/∂(q, v) = −M⁻¹ ∂τ/∂(q, v)`` at ``a``, ``∂a/∂τ = M⁻¹`` (Carpentier & Mansard 2018). Shapes as
    :func:`multibody.forward_dynamics`; a joint that moves no inertia makes ``M`` singular and raises
    ``numpy.linalg.LinAlgError`` naming it. Pinocchio counterpart: ``computeABADerivatives``
    (``ddq_dq``, ``ddq_dv``, ``Minv``).
    """
    q, v, _, tau, f_ext, batch = checked_arguments(model, q, v, tau=tau, f_ext=f_ext)
    nv = model.nv
    out = evaluate_checked(model, kernels.forward_dynamics_derivatives, (q, v, tau, f_ext), (3 * nv, nv), batch)
    return out[..., :nv, :], out[..., nv : 2 * nv, :], out[..., 2 * nv :, :]
