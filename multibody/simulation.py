"""Time integration of (constrained) equations of motion: ``mb.simulate``.

The motion is ``q̇ ↔ v`` (``model.configuration_rate``) with ``v̇ = a`` from the KKT solve of
:class:`~multibody.constrained.ConstrainedSystem`. It is integrated as a Lie-group method of the
Munthe-Kaas type (E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical Integration*, 2nd ed.,
Springer 2006, §IV.8.2): in the chart ``q = chart(q_c, δ)`` around the configuration ``q_c`` at the
start of a step, the integrator's state is ``y = [δ, w]`` with ``δ̇ = J_l(δ)⁻¹ w`` for rotation
vectors and ``w`` the velocity with free-flyer, spherical and planar coordinates rotated into the
parent frame (:meth:`multibody.model.Model.chart`). Quaternions stay exactly on the unit sphere,
and since aligned velocities do not turn with a spinning body, a step may span most of a
revolution. Adaptive methods run through a ``scipy.integrate`` solver (RK45, DOP853, Radau, ...)
to ``t_final``, the output states at the requested times coming from its dense output
(continuous extension) inside each step, so a high output rate does not restrict the step size;
on a curved configuration space it restarts in a new chart at the end of every step, with the
step size it proposed next, measuring the error of ``δ`` against the configuration's size
(:meth:`multibody.model.Model.chart_magnitude`), as for ``q`` itself. ``"RK4"`` is the classical fixed-step method with step ``dt``, one
chart per step. With ``project=True``, a step's end state whose constraint residual exceeds
``projection_tolerance`` is projected onto ``φ = 0`` and ``A v + b = 0`` and the integrator restarts
from it; output states from the dense output that violate the constraints by more are projected
too (the integration itself goes on from its own states). The multipliers, energies and residuals
of all output states are computed afterwards, in one batched call when the system allows it; the
residuals are those of the returned states.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from dataclasses import MISSING, dataclass, field, fields, replace

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, Radau

from .constrained import ConstrainedSystem, ConstraintError
from .spatial import matvec, transpose

METHODS = {"RK45": RK45, "DOP853": DOP853, "Radau": Radau, "RK23": RK23, "BDF": BDF, "LSODA": LSODA}
ADAPTIVE_METHODS = tuple(METHODS)
FIXED_STEP_METHODS = ("RK4",)
#: What ``simulate(..., limits=...)`` does with positions outside ``[model.lower, model.upper]``.
LIMIT_MODES = ("warn", "error", "ignore")


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
        projection_tolerance: the residual above which output states were projected back onto the
            constraints (``simulate``'s ``projection_tolerance``), ``None`` when they were not.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    energy: np.ndarray
    residual: np.ndarray
    row_names: list = field(default_factory=list)
    status: str = "completed"
    projection_tolerance: float | None = None

    def __len__(self):
        return len(self.t)

    def save(self, path):
        """Write the trajectory to a NumPy ``.npz`` archive at ``path`` (``.npz`` added when missing) and
        return the path written. Every array keeps its shape and dtype; names and the status are stored
        as arrays of ``str``, so :meth:`load` reads the file without pickle."""
        arrays = {_FILE_FORMAT_KEY: np.array(_FILE_FORMAT)}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:  # an absent entry loads as the field's default, None
                arrays[f.name] = _stored(f.name, value)
        path = os.fspath(path)
        path = path if path.endswith(".npz") else path + ".npz"
        np.savez(path, **arrays)
        return path

    @classmethod
    def load(cls, path):
        """The trajectory that :meth:`save` wrote to ``path``. Raises ``FileNotFoundError`` when there is
        no such file, ``ValueError`` when the file is not a saved trajectory."""
        path = os.fspath(path)
        not_ours = f"{path!r} is not a trajectory saved by Trajectory.save"
        try:
            archive = np.load(path, allow_pickle=False)
        except (ValueError, EOFError, OSError) as error:
            if isinstance(error, FileNotFoundError | IsADirectoryError):
                raise
            raise ValueError(f"{not_ours}: {error}") from None
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise ValueError(f"{not_ours}: it holds one array, not a .npz archive")
        with archive:
            if _FILE_FORMAT_KEY not in archive.files:
                raise ValueError(f"{not_ours}: a .npz archive without the entry {_FILE_FORMAT_KEY!r} "
                                 f"(it has {sorted(archive.files)})")
            name, version = archive[_FILE_FORMAT_KEY].tolist()
            if name != _FILE_FORMAT[0] or version != _FILE_FORMAT[1]:
                raise ValueError(f"{not_ours}: its format is {name!r} version {version!r}; this version of "
                                 f"multibody reads {_FILE_FORMAT[0]!r} version {_FILE_FORMAT[1]!r}")
            required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
            missing = [key for key in required if key not in archive.files]
            if missing:
                raise ValueError(f"{not_ours}: it lacks the arrays {missing}")
            try:
                values = {f.name: _restored(archive[f.name]) for f in fields(cls) if f.name in archive.files}
            except ValueError as error:  # an object array, which only pickle could read
                raise ValueError(f"{not_ours}: {error}") from None
        return cls(**values)


# The entry that marks a file written by Trajectory.save, holding (format name, version).
_FILE_FORMAT_KEY = "__multibody_format__"
_FILE_FORMAT = ("multibody.Trajectory", "1")


def _stored(name, value):
    """A :class:`Trajectory` field as an array that loads without pickle: arrays as they are, strings and
    lists of strings as arrays of ``str``, numbers as 0-d arrays."""
    if isinstance(value, np.ndarray) and value.dtype != object:
        return value
    if isinstance(value, str) or (isinstance(value, list | tuple) and all(isinstance(x, str) for x in value)):
        return np.array(value, dtype=str)
    if isinstance(value, bool | int | float | np.number):
        return np.array(value)
    raise TypeError(f"Trajectory.save: field {name!r} holds {type(value).__name__} {value!r}, which is not an "
                    "array, a string, a list of strings or a number")


def _restored(array):
    """The field value of a stored array (inverse of :func:`_stored`): ``str`` arrays become a string
    (0-d) or a list of strings, 0-d numbers Python numbers, other arrays stay arrays."""
    if array.dtype.kind == "U":
        return str(array[()]) if array.ndim == 0 else array.tolist()
    return array[()].item() if array.ndim == 0 else array


class JointLimitWarning(UserWarning):
    """A simulated joint left its position limits (``simulate(..., limits="warn")``)."""


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
             project=True, projection_tolerance=1e-12, t0=0.0, max_step=np.inf, joint_damping=False, limits="warn",
             progress=None):
    """Integrate the motion of a ``Model`` or ``ConstrainedSystem`` from ``(q0, v0)`` at ``t0`` to ``t_final``.

    Args:
        system: a :class:`~multibody.model.Model`, a :class:`ConstrainedSystem`, or any mechanical system
            (:class:`~multibody.constrained.ModelSystem` lists the members; one without the chart maps
            must have ``q̇ = v``).
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
        joint_damping: add viscous joint damping ``−D v`` (``D = diag(model.damping)``, from URDF
            ``<dynamics damping>``) to the joint forces; needs a system built on a ``Model``.
        limits: what to do, after the run, with output positions outside ``[model.lower, model.upper]``
            (URDF ``<limit lower upper>``; limits are reported, not enforced): ``"warn"`` (default) gives
            one :class:`JointLimitWarning` per joint, naming it with the first time and value outside;
            ``"error"`` raises :class:`SimulationError` at the first output time outside, naming the
            joint, time and value, with the trajectory up to that time; ``"ignore"`` does nothing.
            Systems without a ``Model`` (symbolic ones) have no limits.
        progress: a progress bar over simulated time (``tqdm``, on standard error): ``None`` (default) shows
            one when the run is expected to take more than :data:`PROGRESS_AFTER` seconds, judged from the
            wall time of its first steps, and the output is a terminal or a notebook; ``True`` always;
            ``False`` never.
    Returns:
        :class:`Trajectory`.
    Raises:
        SimulationError: the integration failed, or (``limits="error"``) a joint left its limits;
            ``.trajectory`` holds the part computed so far.
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
    if progress not in (None, True, False):
        raise ValueError(f"progress must be None (a bar for long runs), True or False, got {progress!r}")
    if limits not in LIMIT_MODES:
        raise ValueError(f"limits must be one of {LIMIT_MODES}, got {limits!r}")
    model = getattr(mechanical, "model", None)  # limits and damping belong to a Model
    if joint_damping:
        if model is None:
            raise ValueError(f"joint_damping=True needs a system built on a Model (model.damping); "
                             f"{type(mechanical).__name__} has none: give the damping as tau(t, q, v) instead")
        if np.any(model.damping):
            tau = _with_joint_damping(_torque_function(tau, nv), model.damping)
    torque = _torque_function(tau, nv)
    charts = _Charts(mechanical)

    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    if q.shape != (nq,) or v.shape != (nv,):
        raise ValueError(f"q0 and v0 must have shapes ({nq},) and ({nv},), got {q.shape} and {v.shape}")
    q_projected, v_projected = constrained.project(q, v, t0)
    dq, dv = np.abs(q_projected - q), np.abs(v_projected - v)
    moved = max(dq.max(initial=0.0), dv.max(initial=0.0))
    if moved > 1e-10 and constrained.num_rows:
        largest = [f"{_coordinate(mechanical, int(np.argmax(d)), rate)} by {d.max():.3g}"
                   for d, rate in ((dq, False), (dv, True)) if d.size and d.max() > 1e-10]
        warnings.warn(f"initial state violated the constraints; projected onto them (moved by {moved:.3g}: "
                      f"{' and '.join(largest)})", UserWarning, stacklevel=2)
    q, v = q_projected, v_projected

    # The integrator's state is y = [δ, w] in the chart around a configuration q_c: q = chart(q_c, δ),
    # w the aligned velocity (see Model.chart). A new chart starts from each step's end state.
    def unchart(q_chart, y):
        """``(q, T(q), v)`` of chart states ``y = [δ, w] (..., 2 nv)``: ``q = chart(q_c, δ)``, ``v = Tᵀ w``."""
        q_t = charts.chart(q_chart, y[..., :nv])
        T = charts.velocity_alignment(q_t)
        w = y[..., nv:]
        return q_t, T, (w if T is None else matvec(transpose(T), w))

    # With a compiled step, each evaluation is one compiled call (after the joint forces, when they
    # depend on the state); the NumPy composition below is the fallback that raises the right error.
    compiled = constrained._compiled_motion is not None
    constant_tau = None if tau is None or callable(tau) else torque(t0, None, None)

    def derivative(t, y, q_chart):
        if compiled:
            if callable(tau):
                q_t, _, v_t = unchart(q_chart, y)
                tau_t = torque(t, q_t, v_t)
                tau_t = None if tau_t is None else constrained._tau(tau_t)
            else:
                tau_t = constant_tau
            y_dot = constrained._chart_derivative(q_chart, y, tau_t)
            if y_dot is not None:
                return y_dot
        q_t, T, v_t = unchart(q_chart, y)
        a, _ = constrained.forward_dynamics(q_t, v_t, torque(t, q_t, v_t), t)
        # ẇ = T (a + κ(v))
        w_dot = a if T is None else T @ (a + charts.velocity_coupling(v_t))
        return np.concatenate([charts.chart_rate(y[:nv], y[nv:]), w_dot])

    def to_chart(state):
        """``y = [0, w]`` of a state ``[q, v]`` in the chart around its own ``q``."""
        T = charts.velocity_alignment(state[:nq])
        return np.concatenate([np.zeros(nv), state[nq:] if T is None else matvec(T, state[nq:])])

    def from_chart(q_chart, y):
        """States ``[q, v] (..., nq + nv)`` of chart states ``y (..., 2 nv)``."""
        q_t, _, v_t = unchart(q_chart, y)
        return np.concatenate([q_t, v_t], axis=-1)

    def settle(t, state):
        """``state`` projected onto the constraints when, with ``project``, its residual exceeds the
        tolerance. Returns the state and whether it was projected."""
        if not np.all(np.isfinite(state)):
            raise SimulationError(f"the state became non-finite at t = {t:.6g} s", None)
        q_t, v_t = state[:nq], state[nq:]
        if project and constrained.num_rows and constrained.residual(q_t, v_t, t) > projection_tolerance:
            return np.concatenate(constrained.project(q_t, v_t, t)), True
        return state, False

    tolerance = projection_tolerance if project else None
    n_intervals = int(np.ceil((t_final - t0) / dt - 1e-9))
    times = np.minimum(t0 + dt * np.arange(n_intervals + 1), t_final)
    states = np.empty((len(times), nq + nv))
    states[0] = np.concatenate([q, v])
    done = 0  # output states filled so far
    bar = _Progress(progress, t0, t_final)

    try:
        constrained.solve(q, v, torque(t0, q, v), t0)  # the initial state has a KKT solution
        done = 1
        if method == "RK4":
            for k in range(1, len(times)):
                q_chart = states[k - 1, :nq]
                y = _rk4_step(lambda t, y: derivative(t, y, q_chart), times[k - 1], to_chart(states[k - 1]),
                              times[k] - times[k - 1])
                states[k] = settle(times[k], from_chart(q_chart, y))[0]
                done = k + 1
                bar.update(times[k])
        else:
            solver_class = METHODS[method]

            def start(t, state, step_size, w_dot=None):
                """A solver from ``state`` at ``t`` in the chart around it. ``w_dot``: the aligned
                acceleration there when already known (the end of an unprojected step: the same state
                in another chart), which then stands in for the solver's first evaluation, as
                ``δ̇ = J_l(0)⁻¹ w = w`` at the chart's centre."""
                q_chart, y0 = state[:nq], to_chart(state)
                first = [None if w_dot is None else np.concatenate([y0[nv:], w_dot])]

                def fun(t_, y):
                    if first[0] is not None and t_ == t and np.array_equal(y, y0):
                        known, first[0] = first[0], None
                        return known
                    return derivative(t_, y, q_chart)

                first_step = None if step_size is None else min(step_size, t_final - t)
                # Errors of δ relative to the configuration's size, as when integrating q itself; the solver
                # would measure them against δ, which is zero at every step's start.
                atol_chart = np.concatenate([atol + rtol * charts.chart_magnitude(q_chart), np.full(nv, atol)])
                solver = solver_class(fun, t, y0, t_final, rtol=rtol, atol=atol_chart, max_step=max_step,
                                      first_step=first_step)
                return solver, q_chart

            # One solver runs on to t_final; the output states inside each of its steps come from its
            # dense output (continuous extension), so the output rate does not restrict the step size.
            # It restarts from the end of a step that was projected, and, on a curved configuration
            # space, from every step's end in a new chart (keeping the step size it proposes next).
            solver, q_chart = start(t0, states[0], None)
            while done < len(times):
                t_before = solver.t
                message = solver.step()
                if solver.status == "failed":
                    raise SimulationError(f"{method} failed at t = {t_before:.6g} s: {message}", None)
                bar.update(solver.t)
                inside = done + int(np.searchsorted(times[done:], solver.t, side="left"))
                if inside > done:
                    states[done:inside] = from_chart(q_chart, solver.dense_output()(times[done:inside]).T)
                    done = inside
                end, projected = settle(solver.t, from_chart(q_chart, solver.y))
                if done < len(times) and times[done] == solver.t:
                    states[done] = end
                    done += 1
                if done < len(times) and (projected or charts.curved):
                    # (explicit Runge–Kutta solvers keep the derivative at their end state in .f)
                    w_dot = None if projected or not hasattr(solver, "f") else solver.f[nv:]
                    solver, q_chart = start(solver.t, end, getattr(solver, "h_abs", solver.step_size), w_dot)
    except (SimulationError, ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        t_fail = times[max(done - 1, 0)]
        message = f"simulation stopped at t = {t_fail:.6g} s: {_grown(mechanical, states[:done], nq, v) or exc}"
        try:
            partial = _trajectory(constrained, times[:done], states[:done], torque, message, tolerance)
        except (ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError):
            # states so far out that their multipliers cannot be computed: the states alone
            m = constrained.num_rows
            partial = Trajectory(t=times[:done].copy(), q=states[:done, :nq].copy(), v=states[:done, nq:].copy(),
                                 lam=np.full((done, m), np.nan), energy=np.full(done, np.nan),
                                 residual=np.full(done, np.nan), row_names=list(constrained.row_names), status=message,
                                 projection_tolerance=tolerance)
        raise SimulationError(message, partial) from exc
    finally:
        bar.close()
    trajectory = _trajectory(constrained, times, states, torque, "completed", tolerance)
    if model is not None and limits != "ignore":
        _report_limits(mechanical, trajectory, limits)
    return trajectory


def _with_joint_damping(torque, damping):
    """The joint forces ``torque(t, q, v) − D v`` (``D = diag(damping)``, ``(nv,)``), as ``tau(t, q, v)``."""
    def damped(t, q, v):
        applied = torque(t, q, v)
        return -damping * v if applied is None else applied - damping * v
    return damped


def _report_limits(system, trajectory, mode):
    """Positions of ``trajectory`` outside ``[model.lower, model.upper]`` of ``system.model``: one
    :class:`JointLimitWarning` per joint at its first output time outside (``mode="warn"``), or a
    :class:`SimulationError` at the first output time any joint is outside, carrying the trajectory up to
    it (``mode="error"``). Unit-norm components (quaternions, planar ``(cos θ, sin θ)``) are bounded by ±1
    by construction and not checked: rounding may take them a few ulps past."""
    model = system.model
    q = trajectory.q
    outside = (q < model.lower) | (q > model.upper)
    for start, stop in model._unit_norm_slices:
        outside[:, start:stop] = False
    if not outside.any():
        return
    first = []  # (output index, coordinate) of each joint's first excursion
    for joint, start in zip(model.joints, model.idx_q):
        rows, cols = np.nonzero(outside[:, start:start + joint.nq])
        if rows.size:
            first.append((int(rows[0]), int(start + cols[0])))

    def describe(k, c):
        return (f"{_coordinate(system, c, False)} left its limits [{model.lower[c]:.6g}, {model.upper[c]:.6g}] "
                f"at t = {trajectory.t[k]:.6g} s: q = {q[k, c]:.6g}")

    if mode == "error":
        k, c = min(first)
        message = describe(k, c) + " (limits='error')"
        n = len(trajectory.t)
        partial = replace(trajectory, status=message, **{
            f.name: getattr(trajectory, f.name)[:k + 1] for f in fields(trajectory)
            if isinstance(getattr(trajectory, f.name), np.ndarray) and getattr(trajectory, f.name).shape[:1] == (n,)})
        raise SimulationError(message, partial)
    for k, c in first:
        warnings.warn(describe(k, c) + "; joint limits are reported, not enforced (limits='ignore' silences this)",
                      JointLimitWarning, stacklevel=3)


def _coordinate(system, k, rate):
    """``"q[k] (joint 'name', unit)"`` or ``"v[k] (...)"``: a coordinate of ``system`` named for messages."""
    symbol = f"{'v' if rate else 'q'}[{k}]"
    model = getattr(system, "model", None)
    if model is None:
        return symbol
    offsets = model.idx_v if rate else model.idx_q
    joint = max(j for j in range(model.njoints) if offsets[j] <= k)
    within = k - offsets[joint]
    kind = model.joints[joint].kind
    if kind in ("revolute", "continuous"):
        unit = "rad/s" if rate else "rad"
    elif kind in ("prismatic", "translation") or (kind in ("free-flyer", "planar") and within < (3 if kind == "free-flyer" else 2)):
        unit = "m/s" if rate else "m"
    else:  # quaternion or (cos θ, sin θ) entries, angular velocities
        unit = "rad/s" if rate else "unit-norm component"
    return f"{symbol} (joint {model.joint_names[joint]!r}, {unit})"


def _grown(system, states, nq, v0):
    """A message when the last computed state's velocities grew beyond a thousand times their start
    (and 1e3): the integration diverged, which is what a failure then means; ``None`` otherwise."""
    if not len(states):
        return None
    v = states[-1, nq:]
    bound = 1e3 * max(1.0, np.abs(v0).max(initial=0.0))
    finite = np.isfinite(v).all()
    if finite and np.abs(v).max(initial=0.0) <= bound:
        return None
    k = int(np.argmax(np.where(np.isfinite(v), np.abs(v), np.inf)))
    size = "is not finite" if not finite else f"reached {abs(v[k]):.3g}"
    return (f"the state grew beyond bounds: {_coordinate(system, k, True)} {size}, over {bound:.3g} (a thousand "
            "times the initial velocities); the integration diverged: take a smaller step (dt with RK4) or an "
            "adaptive method")


class _Charts:
    """The chart maps of a mechanical system (see :meth:`multibody.model.Model.chart`); a system without
    them is a vector space with ``q̇ = v``: ``q = q_c + δ``, ``w = v`` (``velocity_alignment`` ``None``),
    magnitudes ``|q|``."""

    def __init__(self, system):
        self.curved = hasattr(system, "chart") and not getattr(system, "vector_space", False)
        if not hasattr(system, "chart") and system.nq != system.nv:
            raise ValueError(f"{type(system).__name__} has nq = {system.nq} != nv = {system.nv} but no chart maps: "
                             "simulate integrates a curved configuration space through chart, chart_rate, "
                             "velocity_alignment, velocity_coupling and chart_magnitude (see multibody.model.Model.chart)")
        if self.curved:
            self.chart, self.chart_rate = system.chart, system.chart_rate
            self.velocity_alignment, self.velocity_coupling = system.velocity_alignment, system.velocity_coupling
            self.chart_magnitude = system.chart_magnitude
        else:
            self.chart, self.chart_rate = (lambda q0, delta: q0 + delta), (lambda delta, w: w)
            self.velocity_alignment, self.chart_magnitude = (lambda q: None), np.abs


#: Wall time (s) above which a run shows a progress bar with ``simulate(..., progress=None)``.
PROGRESS_AFTER = 2.0


class _Progress:
    """A ``tqdm`` bar over simulated time from ``t0`` to ``t_final`` (s), told each step's end time.

    ``mode`` ``True`` opens it at once, ``False`` never. ``None`` opens it only when the whole run is
    expected to take more than :data:`PROGRESS_AFTER` seconds of wall time, and only where someone can
    see it (a terminal or a notebook). The expected time is the wall time so far plus the simulated
    time left at the rate of the steps after the first, which is timed apart because it may include
    compiling the kernels.
    """

    def __init__(self, mode, t0, t_final):
        self.mode, self.t0, self.span = mode, t0, t_final - t0
        self.started = time.perf_counter()
        self.first = None  # (wall time, simulated time) at the end of the first step
        self.bar = self._open(t0) if mode is True else None

    def _open(self, t):
        if _in_notebook():  # a notebook widget where ipywidgets is installed, else text
            from tqdm.auto import tqdm
        else:
            from tqdm import tqdm
        return tqdm(total=self.span, initial=t - self.t0, unit="s", unit_scale=False, desc="simulate",
                    bar_format="{desc}: {percentage:3.0f}%|{bar}| t = {n:.4g}/{total:.4g} s [{elapsed}<{remaining}]")

    def update(self, t):
        if self.bar is not None:
            self.bar.update(t - self.t0 - self.bar.n)
        elif self.mode is None:
            self._decide(t)

    def _decide(self, t):
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, t)
            return
        wall, simulated = now - self.first[0], t - self.first[1]
        if wall < 0.1 or simulated <= 0.0:  # too little to judge the rate by yet
            return
        expected = now - self.started + (self.t0 + self.span - t) * wall / simulated
        self.mode = expected > PROGRESS_AFTER and _visible()
        if self.mode:
            self.bar = self._open(t)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _visible():
    """Whether a progress bar would be seen: standard error is a terminal, or this runs in a notebook."""
    stream = sys.stderr
    return bool(stream is not None and getattr(stream, "isatty", lambda: False)()) or _in_notebook()


def _in_notebook():
    """Whether this runs in a Jupyter kernel (whose standard error is a stream to the notebook)."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None and hasattr(ipython, "get_ipython") else None
    return shell is not None and hasattr(shell, "kernel")


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

    The states are on the configuration manifold already (charts keep them there); with a
    ``projection_tolerance``, states whose residual exceeds it (dense-output states between
    integrator steps) are projected onto the constraints. ``λ``, energy
    and residual are then evaluated at exactly the returned states, in one batched call each when the
    system takes batches (else one state at a time).
    """
    nq, nv, m = constrained.nq, constrained.nv, constrained.num_rows
    n = len(times)
    batched = constrained.batched and n > 0
    q, v = states[:, :nq].copy(), states[:, nq:].copy()

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
        tau = None if all(tau_k is None for tau_k in taus) else np.stack(
            [np.zeros(nv) if tau_k is None else np.asarray(tau_k, dtype=float) for tau_k in taus])
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
        projection_tolerance=projection_tolerance,
    )
