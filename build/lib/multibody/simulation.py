"""Time integration of (constrained) equations of motion: ``mb.simulate``.

The state is ``(q, v)`` with ``q̇ = G(q) v`` (``model.configuration_rate``) and ``v̇ = a`` from the
KKT solve of :class:`~multibody.constrained.ConstrainedSystem`. Adaptive methods run through
``scipy.integrate.solve_ivp`` (RK45, DOP853, Radau, ...) from one output time to the next;
``"RK4"`` is the classical fixed-step method with step ``dt``. At every output time (every step
for RK4) the state is put back on the configuration manifold (unit quaternions) and, with
``project=True``, onto the constraints ``φ = 0`` and ``A v + b = 0``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from .constrained import ConstrainedSystem, ConstraintError

ADAPTIVE_METHODS = ("RK45", "DOP853", "Radau", "RK23", "BDF", "LSODA")
FIXED_STEP_METHODS = ("RK4",)


@dataclass
class Trajectory:
    """A simulated motion, one row per output time.

    Attributes:
        t: ``(n,)`` times (s).
        q: ``(n, nq)`` configurations; v: ``(n, nv)`` velocities.
        lam: ``(n, m)`` constraint multipliers (sign convention ``M a + h = τ + Aᵀ λ``).
        energy: ``(n,)`` mechanical energy (J; NaN when the system defines none).
        residual: ``(n,)`` largest constraint violation ``max(|φ|, |A v + b|)``.
        row_names: names of the ``m`` constraint rows.
        status: ``"completed"``, or the reason the simulation stopped early.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    energy: np.ndarray
    residual: np.ndarray
    row_names: list = field(default_factory=list)
    status: str = "completed"

    def __len__(self):
        return len(self.t)


class SimulationError(RuntimeError):
    """A simulation that could not go on (NaN, a singular KKT system, a failed step).

    ``error.trajectory`` holds everything computed up to the failure.
    """

    def __init__(self, message, trajectory):
        super().__init__(message)
        self.trajectory = trajectory


def _torque_function(tau, nv):
    if tau is None:
        return lambda t, q, v: None
    if callable(tau):
        return tau
    tau = np.asarray(tau, dtype=float)
    if tau.shape != (nv,):
        raise ValueError(f"tau must be None, an array of shape ({nv},) or a callable tau(t, q, v), got shape {tau.shape}")
    return lambda t, q, v: tau


def simulate(system, q0, v0, t_final, *, dt=None, method="RK45", tau=None, rtol=1e-8, atol=1e-10,
             project=True, t0=0.0, max_step=np.inf):
    """Integrate the motion of a ``Model`` or ``ConstrainedSystem`` from ``(q0, v0)`` at ``t0`` to ``t_final``.

    Args:
        system: a :class:`~multibody.model.Model`, a :class:`ConstrainedSystem`, or any mechanical system.
        q0, v0: initial state ``(nq,)``, ``(nv,)``. An inconsistent state is projected onto the
            constraints with a warning giving the distance moved; if that fails, ``ConstraintError``.
        t_final: end time (s).
        dt: output interval (s), which is also the projection interval, and the step of ``"RK4"``;
            default ``(t_final − t0) / 500``.
        method: ``"RK45"``, ``"DOP853"``, ``"Radau"`` (or ``"RK23"``, ``"BDF"``, ``"LSODA"``), or ``"RK4"``.
        tau: joint forces: ``None``, an array ``(nv,)``, or a callable ``tau(t, q, v) -> (nv,)``.
        rtol, atol: tolerances of the adaptive methods.
        project: project onto the constraints at every output time (default ``True``).
        max_step: largest internal step of the adaptive methods (s).
    Returns:
        :class:`Trajectory`.
    Raises:
        SimulationError: the integration failed; ``.trajectory`` holds the part computed so far.
    """
    constrained = system if isinstance(system, ConstrainedSystem) else ConstrainedSystem(system)
    mechanical = constrained.system
    nq, nv = constrained.nq, constrained.nv
    if method not in ADAPTIVE_METHODS + FIXED_STEP_METHODS:
        raise ValueError(f"method must be one of {ADAPTIVE_METHODS + FIXED_STEP_METHODS}, got {method!r}")
    if not t_final > t0:
        raise ValueError(f"t_final ({t_final}) must be after t0 ({t0})")
    dt = (t_final - t0) / 500.0 if dt is None else float(dt)
    if not dt > 0.0:
        raise ValueError(f"dt must be positive, got {dt}")
    torque = _torque_function(tau, nv)
    normalize = getattr(mechanical, "normalize", lambda q: q)
    rate = getattr(mechanical, "configuration_rate", lambda q, v: v)

    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    if q.shape != (nq,) or v.shape != (nv,):
        raise ValueError(f"q0 and v0 must have shapes ({nq},) and ({nv},), got {q.shape} and {v.shape}")
    q_projected, v_projected = constrained.project(q, v, t0)
    moved = max(np.abs(q_projected - q).max(initial=0.0), np.abs(v_projected - v).max(initial=0.0))
    if moved > 1e-10 and constrained.num_rows:
        warnings.warn(f"initial state violated the constraints; projected onto them (moved by {moved:.3g})",
                      UserWarning, stacklevel=2)
    q, v = q_projected, v_projected

    def derivative(t, y):
        q_t = normalize(y[:nq])
        v_t = y[nq:]
        a, _ = constrained.forward_dynamics(q_t, v_t, torque(t, q_t, v_t), t)
        return np.concatenate([rate(q_t, v_t), a])

    def rk4_step(t, y, h):
        k1 = derivative(t, y)
        k2 = derivative(t + h / 2, y + h / 2 * k1)
        k3 = derivative(t + h / 2, y + h / 2 * k2)
        k4 = derivative(t + h, y + h * k3)
        return y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def settle(t, y):
        """Back onto the configuration manifold and, with ``project``, onto the constraints."""
        if not np.all(np.isfinite(y)):
            raise SimulationError(f"the state became non-finite at t = {t:.6g} s", None)
        q_t, v_t = normalize(y[:nq]), y[nq:]
        return constrained.project(q_t, v_t, t) if project else (q_t, v_t)

    step_size = None
    n_intervals = int(np.ceil((t_final - t0) / dt - 1e-9))
    times = np.minimum(t0 + dt * np.arange(n_intervals + 1), t_final)
    record = {"t": [], "q": [], "v": [], "lam": [], "energy": [], "residual": []}

    def append(t, q, v):
        solution = constrained.solve(q, v, torque(t, q, v), t)
        record["t"].append(t)
        record["q"].append(q)
        record["v"].append(v)
        record["lam"].append(solution.lam)
        record["energy"].append(constrained.energy(q, v))
        record["residual"].append(constrained.residual(q, v, t))

    def trajectory(status):
        n, m = len(record["t"]), constrained.num_rows
        return Trajectory(
            t=np.array(record["t"], dtype=float),
            q=np.array(record["q"], dtype=float).reshape(n, nq),
            v=np.array(record["v"], dtype=float).reshape(n, nv),
            lam=np.array(record["lam"], dtype=float).reshape(n, m),
            energy=np.array(record["energy"], dtype=float),
            residual=np.array(record["residual"], dtype=float),
            row_names=list(constrained.row_names),
            status=status,
        )

    try:
        append(times[0], q, v)
        for t_start, t_end in zip(times[:-1], times[1:]):
            y = np.concatenate([q, v])
            if method == "RK4":
                q, v = settle(t_end, rk4_step(t_start, y, t_end - t_start))
            else:
                # Adaptive steps up to the next output time, then the projection; the next interval
                # starts with the step size this one ended with, so no step-size search is repeated.
                options = {"first_step": min(step_size, t_end - t_start)} if step_size else {}
                result = solve_ivp(derivative, (t_start, t_end), y, method=method, rtol=rtol, atol=atol,
                                   max_step=max_step, **options)
                if not result.success:
                    raise SimulationError(f"{method} failed at t = {t_start:.6g} s: {result.message}", None)
                # The last step may have been shortened to land on t_end: take the longer of the last two.
                step_size = np.diff(result.t)[-2:].max()
                q, v = settle(t_end, result.y[:, -1])
            append(t_end, q, v)
    except (SimulationError, ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        t_fail = record["t"][-1] if record["t"] else t0
        message = f"simulation stopped at t = {t_fail:.6g} s: {exc}"
        raise SimulationError(message, trajectory(message)) from exc
    return trajectory("completed")
