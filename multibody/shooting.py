"""One fixed integration step and its derivatives, for shooting methods (iLQR, DDP, multiple shooting).

The step is the classical Runge–Kutta step that :func:`multibody.simulate` takes with ``method="RK4"``
(Hairer, Nørsett & Wanner, *Solving Ordinary Differential Equations I*, §II.1, Table 1.2), on the state
``x = [q, v]`` with the joint forces ``τ`` held constant over the step:

    K₁ = f(x),  K₂ = f(x + h/2 K₁),  K₃ = f(x + h/2 K₂),  K₄ = f(x + h K₃),
    x⁺ = x + h/6 (K₁ + 2 K₂ + 2 K₃ + K₄),           f(q, v) = [v; a(q, v, τ)].

Its derivatives follow the stages (forward sensitivity): with ``X_i`` the stage states and
``∂f = [[0, 1], [∂a/∂q, ∂a/∂v]]``, ``∂X₁ = 1``, ``∂K_i = ∂f(X_i) ∂X_i + [0; ∂a/∂τ] ∂τ``,
``∂X_{i+1} = 1 + c_{i+1} h ∂K_i``, and ``∂x⁺ = 1 + h/6 (∂K₁ + 2 ∂K₂ + 2 ∂K₃ + ∂K₄)``, exact for the
discrete step. ``∂a`` comes from :func:`multibody.forward_dynamics_derivatives` for a :class:`Model`
and from :meth:`ConstrainedSystem.forward_dynamics_derivatives` with constraints.

The configurations must form a vector space with ``q̇ = v`` (revolute, continuous, prismatic and
translation joints, or a symbolic system): there the step is the one ``simulate`` takes, and derivatives
in ``q`` are ordinary ones. A constrained step is the step before ``simulate``'s projection onto the
constraints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import derivatives, dynamics
from .constrained import ConstrainedSystem
from .model import Model


@dataclass(frozen=True)
class StepDerivatives:
    """Derivatives of one step ``(q⁺, v⁺)`` with respect to ``(q, v, τ)``, each ``(..., nv, nv)``: row i of
    ``dq_dv`` is ``∂q⁺_i/∂v``, and so on."""

    dq_dq: np.ndarray
    dq_dv: np.ndarray
    dq_dtau: np.ndarray
    dv_dq: np.ndarray
    dv_dv: np.ndarray
    dv_dtau: np.ndarray


def _system(system):
    """``(model or None, constrained system or None, nv)``, refusing curved configuration spaces."""
    if isinstance(system, Model):
        model, constrained = system, None
    elif isinstance(system, ConstrainedSystem):
        model, constrained = system.model, system
    else:
        raise TypeError(f"system must be a Model or a ConstrainedSystem, got {type(system).__name__}")
    vector_space = model.is_vector_space if model is not None else getattr(constrained.system, "vector_space", True)
    if not vector_space or (model is None and constrained.nq != constrained.nv):
        raise ValueError("RK4 step derivatives need configurations that form a vector space with q̇ = v (revolute, "
                         "continuous, prismatic and translation joints); this system has free-flyer, spherical or "
                         "planar joints")
    return model, constrained, (model.nv if model is not None else constrained.nv)


def _acceleration(model, constrained, q, v, tau, t):
    if constrained is not None:
        return constrained.forward_dynamics(q, v, tau, t)[0]
    return dynamics.forward_dynamics(model, q, v, tau)


def _acceleration_derivatives(model, constrained, q, v, tau, t):
    """``(∂a/∂q, ∂a/∂v, ∂a/∂τ)`` at one stage."""
    if constrained is not None:
        d = constrained.forward_dynamics_derivatives(q, v, tau, t)
        return d.da_dq, d.da_dv, d.da_dtau
    return derivatives.forward_dynamics_derivatives(model, q, v, tau)


#: Stage times (fractions of the step) and weights of the classical Runge–Kutta method.
_NODES, _WEIGHTS = (0.0, 0.5, 0.5, 1.0), (1.0, 2.0, 2.0, 1.0)


def rk4_step(system, q, v, tau, dt, t=0.0):
    """One RK4 step of ``dt`` seconds from ``(q, v)`` at time ``t`` with constant joint forces ``tau``:
    ``(q⁺ (..., nq), v⁺ (..., nv))``. ``system``: a :class:`Model` or a :class:`ConstrainedSystem` (module
    docstring). ``q (..., nq)``, ``v, tau (..., nv)``."""
    return _step(system, q, v, tau, dt, t, with_derivatives=False)[:2]


def rk4_step_derivatives(system, q, v, tau, dt, t=0.0):
    """``((q⁺, v⁺), StepDerivatives)`` of :func:`rk4_step`: the step and its exact derivatives with respect
    to ``q``, ``v`` and ``τ`` (module docstring). Shapes as :func:`rk4_step`."""
    q_next, v_next, d = _step(system, q, v, tau, dt, t, with_derivatives=True)
    return (q_next, v_next), d


def _step(system, q, v, tau, dt, t, with_derivatives):
    model, constrained, nv = _system(system)
    q, v, tau = (np.asarray(x, dtype=float) for x in (q, v, tau))
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], tau.shape[:-1])
    identity = np.broadcast_to(np.eye(2 * nv, 3 * nv), batch + (2 * nv, 3 * nv))
    q_stage, v_stage = q, v
    q_next, v_next = q, v
    dX, dx_next = identity, identity
    for k, (node, weight) in enumerate(zip(_NODES, _WEIGHTS)):
        t_stage = t + node * dt
        # K_k = f(X_k) = [v_k; a(q_k, v_k, τ)]
        a_stage = _acceleration(model, constrained, q_stage, v_stage, tau, t_stage)
        q_next, v_next = q_next + dt / 6.0 * weight * v_stage, v_next + dt / 6.0 * weight * a_stage
        if with_derivatives:
            da_dq, da_dv, da_dtau = _acceleration_derivatives(model, constrained, q_stage, v_stage, tau, t_stage)
            # ∂K_k = [[0, 1], [∂a/∂q, ∂a/∂v]] ∂X_k + [0; ∂a/∂τ] ∂τ
            dK_q = dX[..., nv:, :]
            dK_v = da_dq @ dX[..., :nv, :] + da_dv @ dX[..., nv:, :]
            dK_v[..., 2 * nv :] += da_dtau
            dK = np.concatenate([dK_q, dK_v], axis=-2)
            dx_next = dx_next + dt / 6.0 * weight * dK
        if k + 1 < len(_NODES):
            # X_{k+1} = x + c_{k+1} h K_k
            step = _NODES[k + 1] * dt
            q_stage, v_stage = q + step * v_stage, v + step * a_stage
            if with_derivatives:
                dX = identity + step * dK
    if not with_derivatives:
        return q_next, v_next, None
    dq, dv = dx_next[..., :nv, :], dx_next[..., nv:, :]
    return q_next, v_next, StepDerivatives(dq[..., :nv], dq[..., nv : 2 * nv], dq[..., 2 * nv :],
                                           dv[..., :nv], dv[..., nv : 2 * nv], dv[..., 2 * nv :])
