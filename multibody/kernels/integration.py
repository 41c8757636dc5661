"""The right-hand side of the equations of motion in the integrator's chart, for :func:`multibody.simulate`.

The integrator's state is ``y = [δ, w]`` around a configuration ``q_c`` (``docs/conventions.md``,
charts; E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical Integration*, §IV.8.2):

    q = chart(q_c, δ),   v = T(q)ᵀ w
    a from ABA (chart_derivative: no constraints) or the constrained step (constrained_chart_derivative,
      :mod:`multibody.kernels.kkt`), both with the joints' armature in ``M``
    ẇ = T(q) (a + κ(v)),   δ̇ = chart_rate(δ, w)

One kernel call per evaluation, with the maps of :mod:`multibody.kernels.configuration`.
"""

from __future__ import annotations

from . import aba, configuration, kkt
from .jit import njit
from .spatial import nan_unless_finite


def output_columns(nv, m=0):
    """Columns of :func:`chart_derivative`'s output row: ``ẏ = [δ̇ (nv), ẇ (nv)]`` and a status; with ``m``
    constraint rows (:func:`constrained_chart_derivative`), the step's :data:`multibody.kernels.kkt.TAIL` after
    them."""
    return 2 * nv + 1 + (kkt.TAIL if m else 0)


def workspace_size(nq, nv, step_workspace, step_columns):
    """Floats of workspace: ``q``, ``v``, ``T``, ``κ``, the step's output row and its workspace."""
    return nq + 2 * nv + nv * nv + step_columns + step_workspace


@njit(cache=True, error_model="numpy")
def unchart(joints, reals, frames, q_chart, y, ws):
    """The state of the chart state ``y = [δ; w] (2 nv,)`` around ``q_chart (nq,)``, in the workspace
    (layout :func:`workspace_size`): ``q = chart(q_c, δ)`` and ``v = Tᵀ w``. Returns the views
    ``(q (1, nq), v (nv,), κ (1, nv), T (nv, nv))``, ``κ`` for :func:`chart_rates` to fill."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    delta, w = y[:nv], y[nv:]
    none = y[:0]
    q = ws[:nq].reshape((1, nq))
    v = ws[nq : nq + nv]
    kappa = ws[nq + nv : nq + 2 * nv].reshape((1, nv))
    T = ws[nq + 2 * nv : nq + 2 * nv + nv * nv].reshape((nv, nv))
    configuration.chart(joints, reals, frames, q_chart, delta, none, none, q, none)
    configuration.velocity_alignment(joints, reals, frames, q[0], none, none, none, T, none)
    for c in range(nv):
        s = 0.0
        for r in range(nv):
            s += T[r, c] * w[r]
        v[c] = s
    return q, v, kappa, T


@njit(cache=True, error_model="numpy")
def chart_rates(joints, reals, frames, y, v, kappa, T, a, status, out):
    """``ẏ = [δ̇; ẇ]`` and ``status`` into ``out[0]`` (layout :func:`output_columns`) from the accelerations
    ``a (nv,)`` at the state :func:`unchart` gave: ``ẇ = T (a + κ(v))``, ``δ̇ = chart_rate(δ, w)``."""
    nv = v.shape[0]
    none = y[:0]
    row = out[0]
    configuration.velocity_coupling(joints, reals, frames, v, none, none, none, kappa, none)
    for r in range(nv):
        s = 0.0
        for c in range(nv):
            s += T[r, c] * (a[c] + kappa[0, c])
        row[nv + r] = s
    configuration.chart_rate(joints, reals, frames, y[:nv], y[nv:], none, none, out, none)
    row[2 * nv] = status


@njit(cache=True, error_model="numpy")
def chart_derivative(joints, reals, frames, q_chart, y, tau, x3, out, ws):
    """``ẏ = [δ̇; ẇ]`` of the chart state ``y = [δ; w] (2 nv,)`` around ``q_chart (nq,)`` into ``out[0]``
    (layout :func:`output_columns`), with joint forces ``tau (nv,)`` or length 0 (zero), for a system
    without constraints: ``a`` by ABA (status 0, or NaN where ``M`` is singular). ``x3`` is unused."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    q, v, kappa, T = unchart(joints, reals, frames, q_chart, y, ws)
    start = nq + 2 * nv + nv * nv
    step = ws[start : start + nv].reshape((1, nv))
    aba.forward_dynamics(joints, reals, frames, q[0], v, tau, y[:0], step, ws[start + nv :])
    chart_rates(joints, reals, frames, y, v, kappa, T, step[0, :nv], 0.0, out)
    nan_unless_finite(q_chart, y, tau, x3, out)


@njit(cache=True, error_model="numpy")
def constrained_chart_derivative(joints, reals, frames, q_chart, y, tau, program, out, ws):
    """:func:`chart_derivative` with the constraints of ``program`` (:mod:`multibody.kernels.constraints`):
    ``a`` by the constrained step, whose status is passed on (0: solved), and its status outputs (the
    :data:`multibody.kernels.kkt.TAIL`) in the last columns (layout :func:`output_columns` with ``m``; the last
    ``NON_FINITE`` where an input is not finite). A kernel of its own, so that neither kind of system compiles
    the other's step."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    q, v, kappa, T = unchart(joints, reals, frames, q_chart, y, ws)
    start = nq + 2 * nv + nv * nv
    m = int(program[1])
    columns = kkt.output_columns(nv, m)
    step = ws[start : start + columns].reshape((1, columns))
    kkt.constrained_accelerations(joints, reals, frames, q[0], v, tau, program, step, ws[start + columns :])
    chart_rates(joints, reals, frames, y, v, kappa, T, step[0, :nv], step[0, columns - 1], out)
    for c in range(kkt.TAIL):
        out[0, 2 * nv + 1 + c] = step[0, columns - kkt.TAIL + c]
    kkt.status_unless_finite(q_chart, y, tau, program, out)
