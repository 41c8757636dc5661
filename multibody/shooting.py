"""One fixed integration step and its derivatives, for shooting methods (iLQR, DDP, multiple shooting).

The step is exactly the classical Runge–Kutta step that :func:`multibody.simulate` takes with
``method="RK4"`` (Hairer, Nørsett & Wanner, *Solving Ordinary Differential Equations I*, §II.1,
Table 1.2), with the joint forces ``τ`` held constant over the step. It runs in the chart around the
step's first configuration (:meth:`multibody.Model.chart`): the state is ``y = [δ, w]``, with
``q = chart(q₀, δ)`` and ``w = T(q) v`` the aligned velocity, and

    K_i = [chart_rate(δ_i, w_i); T(q_i) (a_i + κ(v_i))],      y_{i+1} = y₀ + c_{i+1} h K_i,
    y⁺ = y₀ + h/6 (K₁ + 2 K₂ + 2 K₃ + K₄),                    q⁺ = chart(q₀, δ⁺),  v⁺ = T(q⁺)ᵀ w⁺,

where ``a_i = a(q_i, v_i, τ)`` is the forward dynamics at stage i. For angles and displacements the chart
is ``q₀ + δ`` and ``T = 1``: plain RK4 on ``[q, v]``.

The derivatives with respect to ``q`` (tangent space: ``q ⊕ δq``), ``v`` and ``τ`` follow the stages
(forward sensitivity). Each stage state, and the step's end, is a function ``g_i`` of ``(δq, v)`` and of
the accelerations of the earlier stages alone: the *glue* of chart maps above. So

    ∂(q_i, v_i) = ∂g_i/∂(δq, v) + Σ_{j<i} ∂g_i/∂a_j ∂a_j,     ∂a_j = ∂a/∂q ∂q_j + ∂a/∂v ∂v_j + ∂a/∂τ ∂τ,

with ``∂a`` analytical (:func:`multibody.forward_dynamics_derivatives`, or
:meth:`ConstrainedSystem.forward_dynamics_derivatives` with constraints) and ``∂g_i``, cheap closed-form
chart maps, by five-point central differences (:mod:`multibody.differences`; exact up to rounding for
angles and displacements, where the glue is linear). Positions of the stages are compared in the tangent
space at each stage (``model.difference``). A constrained step is the step before ``simulate``'s
projection onto the constraints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import derivatives, differences, dynamics
from .mechanical import Charts, system_parts
from .spatial import matvec


@dataclass(frozen=True)
class StepDerivatives:
    """Derivatives of one step ``(q⁺, v⁺)`` with respect to ``(q, v, τ)``, each ``(..., nv, nv)``: row i of
    ``dq_dv`` is ``∂q⁺_i/∂v`` (``q⁺`` in the tangent space at ``q⁺``, ``q`` at ``q``), and so on."""

    dq_dq: np.ndarray
    dq_dv: np.ndarray
    dq_dtau: np.ndarray
    dv_dq: np.ndarray
    dv_dv: np.ndarray
    dv_dtau: np.ndarray


#: Stage times (fractions of the step) and weights of the classical Runge–Kutta method.
_NODES, _WEIGHTS = (0.0, 0.5, 0.5, 1.0), (1.0, 2.0, 2.0, 1.0)


class _Step:
    """The pieces of one step of ``system`` (a :class:`Model` or a :class:`ConstrainedSystem`)."""

    def __init__(self, system):
        self.constrained, mechanical, self.model = system_parts(system)
        self.charts = Charts(mechanical)
        self.mechanical = mechanical
        self.nq, self.nv = mechanical.nq, mechanical.nv

    def acceleration(self, q, v, tau, t):
        if self.constrained is not None:
            return self.constrained.forward_dynamics(q, v, tau, t)[0]
        return dynamics.forward_dynamics(self.model, q, v, tau)

    def acceleration_derivatives(self, q, v, tau, t):
        """``(∂a/∂q, ∂a/∂v, ∂a/∂τ)`` at one stage."""
        if self.constrained is not None:
            d = self.constrained.forward_dynamics_derivatives(q, v, tau, t)
            return d.da_dq, d.da_dv, d.da_dtau
        return derivatives.forward_dynamics_derivatives(self.model, q, v, tau)

    def difference(self, q0, q1):
        """Tangent ``δ`` with ``q1 = q0 ⊕ δ``."""
        return self.mechanical.model.difference(q0, q1) if self.charts.curved else q1 - q0

    def glue(self, q, v, accelerations, dt):
        """Stage states ``[(q_i, v_i)]`` for ``i = 1..4`` and the end ``(q⁺, v⁺)`` (module docstring), with
        ``accelerations(i, q_i, v_i)`` the acceleration of stage i; arrays carry leading axes."""
        charts = self.charts

        def aligned(q_, x):  # T(q) x, or x without alignment
            T = charts.velocity_alignment(q_)
            return x if T is None else matvec(T, x)

        def unaligned(q_, w):  # Tᵀ w
            T = charts.velocity_alignment(q_)
            return w if T is None else matvec(np.swapaxes(T, -1, -2), w)

        w0 = aligned(q, v)
        delta, w = np.zeros_like(w0), w0
        q_i, v_i = q, v
        stages, sum_delta, sum_w = [], 0.0, 0.0
        for k, (node, weight) in enumerate(zip(_NODES, _WEIGHTS)):
            stages.append((q_i, v_i))
            a_i = accelerations(k, q_i, v_i)
            # K = [chart_rate(δ, w); T (a + κ(v))]
            coupling = 0.0 if not charts.curved else self.mechanical.velocity_coupling(v_i)
            K_delta, K_w = charts.chart_rate(delta, w), aligned(q_i, a_i + coupling)
            sum_delta, sum_w = sum_delta + weight * K_delta, sum_w + weight * K_w
            if k + 1 < len(_NODES):
                # y_{k+1} = y₀ + c_{k+1} h K_k
                delta, w = _NODES[k + 1] * dt * K_delta, w0 + _NODES[k + 1] * dt * K_w
                q_i = charts.chart(q, delta)
                v_i = unaligned(q_i, w)
        # y⁺ = y₀ + h/6 Σ b_i K_i
        q_next = charts.chart(q, dt / 6.0 * sum_delta)
        return stages, (q_next, unaligned(q_next, w0 + dt / 6.0 * sum_w))


def rk4_step(system, q, v, tau, dt, t=0.0):
    """One RK4 step of ``dt`` seconds from ``(q, v)`` at time ``t`` with constant joint forces ``tau``:
    ``(q⁺ (..., nq), v⁺ (..., nv))``, the step :func:`multibody.simulate` takes (module docstring).
    ``system``: a :class:`Model` or a :class:`ConstrainedSystem`. ``q (..., nq)``, ``v, tau (..., nv)``."""
    step, q, v, tau = _inputs(system, q, v, tau, dt)
    _, end = step.glue(q, v, lambda k, q_k, v_k: step.acceleration(q_k, v_k, tau, t + _NODES[k] * dt), dt)
    return end


def rk4_step_derivatives(system, q, v, tau, dt, t=0.0):
    """``((q⁺, v⁺), StepDerivatives)``: :func:`rk4_step` and its derivatives with respect to ``q`` (tangent
    space), ``v`` and ``τ`` (module docstring). Shapes as :func:`rk4_step`."""
    step, q, v, tau = _inputs(system, q, v, tau, dt)
    nv = step.nv
    accelerations = []

    def dynamics_at(k, q_k, v_k):
        accelerations.append(step.acceleration(q_k, v_k, tau, t + _NODES[k] * dt))
        return accelerations[-1]

    stages, end = step.glue(q, v, dynamics_at, dt)
    glue = _glue_jacobian(step, q, v, np.stack(accelerations), dt, [s[0] for s in stages[1:]] + [end[0]])
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], tau.shape[:-1])
    # ∂(q_i, v_i)/∂(δq, v, τ), (..., 2 nv, 3 nv): stage 1 is the state itself
    inputs = np.broadcast_to(np.eye(2 * nv, 3 * nv), batch + (2 * nv, 3 * nv))
    d_accelerations = []
    for k in range(len(_NODES) + 1):
        # ∂g_k/∂(δq, v) and ∂g_k/∂a_j for the earlier stages j
        d_stage = inputs if k == 0 else glue[k - 1][0] @ inputs[..., : 2 * nv, :] + sum(
            glue[k - 1][1 + j] @ d_accelerations[j] for j in range(k))
        if k == len(_NODES):
            break
        q_k, v_k = stages[k]
        da_dq, da_dv, da_dtau = step.acceleration_derivatives(q_k, v_k, tau, t + _NODES[k] * dt)
        # ∂a_k = ∂a/∂q ∂q_k + ∂a/∂v ∂v_k + ∂a/∂τ ∂τ
        d_a = da_dq @ d_stage[..., :nv, :] + da_dv @ d_stage[..., nv:, :]
        d_a[..., 2 * nv :] += da_dtau
        d_accelerations.append(d_a)
    dq, dv = d_stage[..., :nv, :], d_stage[..., nv:, :]
    return end, StepDerivatives(dq[..., :nv], dq[..., nv : 2 * nv], dq[..., 2 * nv :],
                                dv[..., :nv], dv[..., nv : 2 * nv], dv[..., 2 * nv :])


def _inputs(system, q, v, tau, dt):
    step = _Step(system)
    q, v, tau = (np.asarray(x, dtype=float) for x in (q, v, tau))
    if q.shape[-1:] != (step.nq,) or v.shape[-1:] != (step.nv,) or tau.shape[-1:] != (step.nv,):
        raise ValueError(f"q, v and tau must have shapes (..., {step.nq}), (..., {step.nv}) and (..., {step.nv}), "
                         f"got {q.shape}, {v.shape} and {tau.shape}")
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    return step, q, v, tau


def _glue_jacobian(step, q, v, accelerations, dt, positions):
    """For stages 2, 3, 4 and the end: ``[∂g/∂(δq, v) (..., 2 nv, 2 nv), ∂g/∂a_1, ∂g/∂a_2, ...]`` (the
    accelerations of the earlier stages only, each ``(..., 2 nv, nv)``), by five-point differences of
    the glue with the stage accelerations held as inputs. ``positions``: the stages' unperturbed
    configurations, at which position changes are measured in the tangent space."""
    nv, stages = step.nv, len(_NODES)
    n = (2 + stages) * nv  # inputs: δq, v, a_1 .. a_4
    # each state's own scales (so that a state's derivatives do not depend on the rest of its batch):
    # rad or m for δq, max(1, |v|) and max(1, |a|) for the velocities and accelerations, shaped (..., 1)
    scale_v = np.maximum(1.0, np.abs(v).max(axis=-1, keepdims=True))
    scale_a = np.maximum(1.0, np.abs(accelerations).max(axis=(0, -1))[..., None])

    def evaluate(steps):
        # steps (4 n, n) in units of each block's own scale
        steps = steps.reshape((4 * n,) + (1,) * (q.ndim - 1) + (n,))
        q_displaced = step.mechanical.integrate(q, steps[..., :nv], 1.0)
        v_displaced = v + steps[..., nv : 2 * nv] * scale_v
        a_steps = steps[..., 2 * nv :] * scale_a
        a_steps = a_steps.reshape(a_steps.shape[:-1] + (stages, nv))
        a_displaced = accelerations[:, None] + np.moveaxis(a_steps, -2, 0)
        stage_states, end = step.glue(q_displaced, v_displaced, lambda k, q_k, v_k: a_displaced[k], dt)
        outputs = [state for state in stage_states[1:]] + [end]
        return np.stack([np.concatenate([step.difference(reference, q_out), v_out], axis=-1)
                         for reference, (q_out, v_out) in zip(positions, outputs)], axis=-2)

    jacobian = differences.five_point_jacobian(evaluate, lambda steps: steps, n, differences.STEP)
    # back to the inputs' units: the columns of v and a divided by their scales
    jacobian = np.concatenate([jacobian[..., :nv], jacobian[..., nv : 2 * nv] / scale_v[..., None, None, :],
                               jacobian[..., 2 * nv :] / scale_a[..., None, None, :]], axis=-1)
    return [[jacobian[..., k, :, : 2 * nv]] + [jacobian[..., k, :, (2 + j) * nv : (3 + j) * nv] for j in range(k + 1)]
            for k in range(stages)]
