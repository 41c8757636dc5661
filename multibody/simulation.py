"""Time integration of (constrained) equations of motion: ``mb.simulate``.

The state is ``(q, v)`` with ``q̇ = G(q) v`` (``model.configuration_rate``) and ``v̇ = a`` from the
KKT solve of :class:`~multibody.constrained.ConstrainedSystem`. Adaptive methods run through a
``scipy.integrate`` solver (RK45, DOP853, Radau, ...). While the output interval ``dt`` spans several
of its steps, each interval is integrated on its own and landed on exactly; once a single step covers
an interval, one solver runs on to ``t_final`` and the output states at the requested times come from
its dense output (continuous extension) inside each step, so a high output rate does not restrict
the step size; with ``project=True`` those of them that violate
the constraints by more than ``projection_tolerance`` are projected onto them (the integration
itself goes on from its own states). ``"RK4"`` is the classical fixed-step method
with step ``dt``. After every integrator step the state is put back on the configuration manifold
(unit quaternions) and, with ``project=True``, when its constraint residual exceeds
``projection_tolerance`` it is projected onto ``φ = 0`` and ``A v + b = 0`` and the integrator restarts
from the projected state (with the step size it had reached). The multipliers, energies and residuals
of all output states are computed afterwards, in one batched call when the system allows it; the
residuals are those of the returned states.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, Radau

from .constrained import ConstrainedSystem, ConstraintError

METHODS = {"RK45": RK45, "DOP853": DOP853, "Radau": Radau, "RK23": RK23, "BDF": BDF, "LSODA": LSODA}
ADAPTIVE_METHODS = tuple(METHODS)
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
             project=True, projection_tolerance=1e-12, t0=0.0, max_step=np.inf):
    """Integrate the motion of a ``Model`` or ``ConstrainedSystem`` from ``(q0, v0)`` at ``t0`` to ``t_final``.

    Args:
        system: a :class:`~multibody.model.Model`, a :class:`ConstrainedSystem`, or any mechanical system.
        q0, v0: initial state ``(nq,)``, ``(nv,)``. An inconsistent state is projected onto the
            constraints with a warning giving the distance moved; if that fails, ``ConstraintError``.
        t_final: end time (s).
        dt: output interval (s), and the step of ``"RK4"``; default ``(t_final − t0) / 500``.
        method: ``"RK45"``, ``"DOP853"``, ``"Radau"`` (or ``"RK23"``, ``"BDF"``, ``"LSODA"``), or ``"RK4"``.
        tau: joint forces: ``None``, an array ``(nv,)``, or a callable ``tau(t, q, v) -> (nv,)``.
        rtol, atol: tolerances of the adaptive methods.
        project: keep the state on the constraints (default ``True``): after an integrator step whose
            end state violates them by more than ``projection_tolerance``, project it and restart there.
        projection_tolerance: largest residual ``max(|φ|, |A v + b|)`` left unprojected at a step end.
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

    def settle(t, y):
        """``y`` back onto the configuration manifold and, with ``project``, onto the constraints when
        its residual exceeds the tolerance. Returns the state and whether it was projected."""
        if not np.all(np.isfinite(y)):
            raise SimulationError(f"the state became non-finite at t = {t:.6g} s", None)
        q_t, v_t = normalize(y[:nq]), y[nq:]
        if project and constrained.num_rows and constrained.residual(q_t, v_t, t) > projection_tolerance:
            return np.concatenate(constrained.project(q_t, v_t, t)), True
        return np.concatenate([q_t, v_t]), False

    tolerance = projection_tolerance if project else None
    n_intervals = int(np.ceil((t_final - t0) / dt - 1e-9))
    times = np.minimum(t0 + dt * np.arange(n_intervals + 1), t_final)
    states = np.empty((len(times), nq + nv))
    states[0] = np.concatenate([q, v])
    done = 0  # output states filled so far

    try:
        constrained.solve(q, v, torque(t0, q, v), t0)  # the initial state has a KKT solution
        done = 1
        if method == "RK4":
            for k in range(1, len(times)):
                states[k] = settle(times[k], _rk4_step(derivative, times[k - 1], states[k - 1], times[k] - times[k - 1]))[0]
                done = k + 1
        else:
            solver_class = METHODS[method]

            def start(t, y, t_bound, step_size):
                first_step = None if step_size is None else min(step_size, t_bound - t)
                return solver_class(derivative, t, y, t_bound, rtol=rtol, atol=atol, max_step=max_step,
                                    first_step=first_step)

            def advance(solver):
                t_before = solver.t
                message = solver.step()
                if solver.status == "failed":
                    raise SimulationError(f"{method} failed at t = {t_before:.6g} s: {message}", None)

            # While the output intervals span several steps, each one is integrated on its own and landed
            # on exactly (the next starts with the step size this one reached, so no step-size search is
            # repeated). Once a single step covers an interval, one solver runs on to t_final and the
            # output states inside its steps come from its dense output.
            step_size = None
            while done < len(times):
                solver, steps = start(times[done - 1], states[done - 1], times[done], step_size), []
                while solver.status == "running":
                    advance(solver)
                    steps.append(solver.step_size)
                # The last step may have been shortened to land on the output time: take the longer of the last two.
                step_size = max(steps[-2:])
                states[done] = settle(times[done], solver.y)[0]
                done += 1
                if len(steps) == 1:
                    break
            solver = start(times[done - 1], states[done - 1], t_final, step_size) if done < len(times) else None
            while done < len(times):
                advance(solver)
                y_end, projected = settle(solver.t, solver.y)
                # Output times inside the step from the dense output; one landing on the step's end
                # takes the (projected) end state itself.
                inside = done + int(np.searchsorted(times[done:], solver.t, side="left"))
                if inside > done:
                    states[done:inside] = solver.dense_output()(times[done:inside]).T
                    done = inside
                if done < len(times) and times[done] == solver.t:
                    states[done] = y_end
                    done += 1
                if projected and done < len(times):
                    solver = start(solver.t, y_end, t_final, solver.step_size)
    except (SimulationError, ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        t_fail = times[max(done - 1, 0)]
        message = f"simulation stopped at t = {t_fail:.6g} s: {exc}"
        raise SimulationError(message, _trajectory(constrained, times[:done], states[:done], torque, message, tolerance)) from exc
    return _trajectory(constrained, times, states, torque, "completed", tolerance)


def _rk4_step(derivative, t, y, h):
    """One classical Runge–Kutta step of size ``h`` from ``(t, y)`` (Hairer, Nørsett & Wanner,
    *Solving Ordinary Differential Equations I*, §II.1, Table 1.2)."""
    k1 = derivative(t, y)
    k2 = derivative(t + h / 2, y + h / 2 * k1)
    k3 = derivative(t + h / 2, y + h / 2 * k2)
    k4 = derivative(t + h, y + h * k3)
    return y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def _trajectory(constrained, times, states, torque, status, projection_tolerance=None):
    """The :class:`Trajectory` of output ``states (n, nq + nv)`` at ``times (n,)``.

    Configurations are normalised; with a ``projection_tolerance``, states whose residual exceeds it
    (dense-output states between integrator steps) are projected onto the constraints. ``λ``, energy
    and residual are then evaluated at exactly the returned states, in one batched call each when the
    system takes batches (else one state at a time).
    """
    nq, nv, m = constrained.nq, constrained.nv, constrained.num_rows
    n = len(times)
    batched = constrained.batched and n > 0
    normalize = getattr(constrained.system, "normalize", lambda q: q)
    q = normalize(states[:, :nq]) if batched else np.array([normalize(row) for row in states[:, :nq]]).reshape(n, nq)
    v = states[:, nq:].copy()

    def residuals(index):
        if not m:
            return np.zeros(len(index))
        if batched:
            return constrained.residual(q[index], v[index], times[index])
        return np.array([constrained.residual(q[k], v[k], times[k]) for k in index])

    residual = residuals(np.arange(n))
    if projection_tolerance is not None and m:
        off = np.flatnonzero(residual > projection_tolerance)
        if off.size and batched:
            q[off], v[off] = constrained.project(q[off], v[off], times[off])
        for k in off if not batched else ():
            q[k], v[k] = constrained.project(q[k], v[k], times[k])
        if off.size:
            residual[off] = residuals(off)
    taus = [torque(t, q_k, v_k) for t, q_k, v_k in zip(times, q, v)]
    if batched:
        tau = np.stack([np.zeros(nv) if tau_k is None else np.asarray(tau_k, dtype=float) for tau_k in taus])
        lam = constrained.solve(q, v, tau, times).lam
        energy = np.broadcast_to(constrained.energy(q, v), (n,))
    else:
        lam = [constrained.solve(q_k, v_k, tau_k, t).lam for t, q_k, v_k, tau_k in zip(times, q, v, taus)]
        energy = [constrained.energy(q_k, v_k) for q_k, v_k in zip(q, v)]
    return Trajectory(
        t=np.array(times, dtype=float),
        q=q,
        v=v,
        lam=np.array(lam, dtype=float).reshape(n, m),
        energy=np.array(energy, dtype=float).reshape(n),
        residual=residual,
        row_names=list(constrained.row_names),
        status=status,
    )
