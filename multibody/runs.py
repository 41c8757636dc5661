"""What the runs of :func:`multibody.simulate` share, whichever method takes the steps: their errors, the failures
that stop one trajectory of a batch (:func:`by_state`), their warning, the checks of their options and inputs (named
by joint), the joint forces as a function, the report of joint limits, and the progress bar."""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import fields, replace

import numpy as np

from .model import all_finite

#: What ``simulate(..., limits=...)`` does with positions outside ``[model.lower, model.upper]``.
LIMIT_MODES = ("warn", "error", "ignore")


class JointLimitWarning(UserWarning):
    """A simulated joint left its position limits (``simulate(..., limits="warn")``)."""


class SimulationError(RuntimeError):
    """A simulation that could not go on (NaN, a singular KKT system, a failed step).

    ``error.trajectory`` holds everything computed up to the failure.
    """

    def __init__(self, message, trajectory):
        super().__init__(message)
        self.trajectory = trajectory


class ConstraintError(RuntimeError):
    """Constraints that cannot hold together (inconsistent), or a state that cannot be projected."""


#: The failures that stop one trajectory (the others of a batch go on).
FAILURES = (SimulationError, ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError)


def by_state(f, arrays, shape, batched=True):
    """``f(*arrays)`` on states ``arrays`` with a common leading axis of ``n``, ``(n,) + shape``, and ``{index:
    message}`` of the states it fails on: in one call where ``batched`` (the system takes batches), else, and where
    that call raises, on each state alone (``f`` of one state giving ``shape``), the states it fails on getting
    NaN."""
    if batched:
        try:
            return f(*arrays), {}
        except FAILURES:
            pass
    n = len(arrays[0])
    out, errors = np.full((n,) + shape, np.nan), {}
    for i in range(n):
        try:
            out[i] = f(*(x[i] for x in arrays))
        except FAILURES as error:
            errors[i] = str(error)
    return out, errors


def torque_function(tau, nv, batch=None, system=None):
    """``tau`` as a function ``(t, q, v) -> None or array``. For a batch of ``batch`` trajectories an array
    may also have the shape ``(batch, nv)``, and a callable's results are checked to have one of the two
    shapes. An array must be finite (``ValueError``); for one trajectory a callable's non-finite result raises
    :class:`SimulationError` naming the time and the joints (of ``system``, a mechanical system), a batch's
    stops only the trajectories whose rows are not finite (:func:`multibody.simulate`'s batch loop)."""
    shapes = ((nv,),) if batch is None else ((nv,), (batch, nv))
    if tau is None:
        return lambda t, q, v: None
    if callable(tau):
        if batch is None:
            def finite(t, q, v):
                value = tau(t, q, v)
                if value is not None:
                    values = np.asarray(value, dtype=float)
                    # (other shapes are refused, with their own message, where the forces are used)
                    if values.shape == (nv,) and not all_finite(values):
                        raise SimulationError(non_finite_torque(system, t, values), None)
                return value
            return finite

        def checked(t, q, v):
            value = tau(t, q, v)
            if value is None:
                return None
            value = np.asarray(value, dtype=float)
            if value.shape not in shapes:
                raise ValueError(f"tau(t, q, v) must return joint forces of shape ({batch}, {nv}) for a batch q "
                                 f"{q.shape}, v {v.shape} (or ({nv},), the same for every trajectory), got shape "
                                 f"{value.shape}")
            return value
        return checked
    tau = np.asarray(tau, dtype=float)
    if tau.shape not in shapes:
        raise ValueError(f"tau must be None, an array of shape {' or '.join(map(str, shapes))} or a callable "
                         f"tau(t, q, v), got shape {tau.shape}")
    require_finite(system, "tau", tau, force=True)
    return lambda t, q, v: tau


def output_times(t0, t_final, dt):
    """Output times ``t0, t0 + dt, ...`` up to and including ``t_final`` (s): the last interval may be shorter."""
    n_intervals = int(np.ceil((t_final - t0) / dt - 1e-9))
    return np.minimum(t0 + dt * np.arange(n_intervals + 1), t_final)


def joint_damping_of(mechanical, joint_damping):
    """The viscous damping ``D (nv,)`` (N·m·s/rad or N·s/m per coordinate) that ``simulate(...,
    joint_damping=True)`` subtracts from the joint forces, ``model.damping`` of the system's model; ``None`` with
    ``joint_damping=False`` or where every coefficient is zero. ``ValueError`` for a system without a model."""
    if not joint_damping:
        return None
    model = getattr(mechanical, "model", None)
    if model is None:
        raise ValueError(f"joint_damping=True needs a system built on a Model (model.damping); "
                         f"{type(mechanical).__name__} has none: give the damping as tau(t, q, v) instead")
    return np.array(model.damping, dtype=float) if np.any(model.damping) else None


def with_joint_damping(torque, damping):
    """The joint forces ``torque(t, q, v) − D v`` (``D = diag(damping)``, ``(nv,)``), as ``tau(t, q, v)``."""
    def damped(t, q, v):
        applied = torque(t, q, v)
        return -damping * v if applied is None else applied - damping * v
    return damped


def report_limits(system, trajectory, mode, enforced=(), stacklevel=3):
    """Positions of ``trajectory`` (one, ``q (n, nq)``, or a batch, ``q (N, n, nq)``) outside ``[model.lower,
    model.upper]`` of ``system.model``. ``mode="warn"``: one :class:`JointLimitWarning` per joint at its first output
    time outside (in a batch, with the trajectory that left first and how many did), warning at ``stacklevel``.
    ``mode="error"``: one trajectory raises a :class:`SimulationError` at the first output time any joint is outside,
    carrying the trajectory up to it (with contact, its contact entries up to it); in a batch each trajectory outside
    stops there, as a failed trajectory does (its status names joint, time and value; its outputs after it are NaN,
    its contact entries after it empty). Returns the trajectory (so marked).
    Unit-norm components (quaternions, planar ``(cos θ, sin θ)``) are bounded by ±1 by construction and not checked:
    rounding may take them a few ulps past; nor are the coordinates ``enforced`` (indices into ``q``), which
    :class:`multibody.JointLimits` holds to its solver's tolerance."""
    model = system.model
    one = trajectory.batch_size is None
    q = trajectory.q[None] if one else trajectory.q
    outside = (q < model.lower) | (q > model.upper)  # (NaN compares False: stopped trajectories stay inside)
    for start, stop in model.unit_norm_slices:
        outside[..., start:stop] = False
    outside[..., list(enforced)] = False
    if not outside.any():
        return trajectory
    count, n = q.shape[:2]

    def describe(j, k, c):
        return (f"{coordinate_name(system, c, False)} left its limits [{model.lower[c]:.6g}, {model.upper[c]:.6g}] "
                f"at t = {trajectory.t[k]:.6g} s: q = {q[j, k, c]:.6g}")

    def first(j):
        """The output index and coordinate at which trajectory ``j`` first left a limit."""
        k = int(np.argmax(outside[j].any(axis=1)))
        return k, int(np.argmax(outside[j, k]))

    if mode == "warn":
        for joint, start in zip(model.joints, model.idx_q):
            columns = outside[..., start : start + joint.nq]
            left = columns.any(axis=(1, 2))
            if not left.any():
                continue
            times = np.where(left, np.argmax(columns.any(axis=2), axis=1), n)
            j = int(np.argmin(times))
            k = int(times[j])
            c = start + int(np.argmax(columns[j, k]))
            where = "" if one else f" in trajectory {j} ({int(left.sum())} of {count} trajectories left them)"
            warnings.warn(f"{describe(j, k, c)}{where}; joint limits are reported, not enforced (limits='ignore' "
                          "silences this)", JointLimitWarning, stacklevel=stacklevel)
        return trajectory
    if one:
        k, c = first(0)
        message = describe(0, k, c) + " (limits='error')"
        kept = {f.name: value[:k + 1] for f in fields(trajectory)
                if isinstance(value := getattr(trajectory, f.name), np.ndarray) and value.shape[:1] == (n,)}
        if trajectory.contacts is not None:
            kept["contacts"] = list(trajectory.contacts[:k + 1])
        raise SimulationError(message, replace(trajectory, status=message, **kept))
    status = list(trajectory.status)
    names = ("q", "v", "lam", "energy", "residual")
    if trajectory.complementarity is not None:
        names += ("complementarity",)
    arrays = {name: getattr(trajectory, name).copy() for name in names}
    contacts = None if trajectory.contacts is None else list(trajectory.contacts)
    for j in np.flatnonzero(outside.any(axis=(1, 2))):
        k, c = first(j)
        status[j] = describe(j, k, c) + " (limits='error')"
        for value in arrays.values():
            value[j, k + 1 :] = np.nan
        if contacts is not None:
            # no contact rows after the stop, as for a trajectory whose step failed (entry 0 is the empty one)
            contacts[j] = list(contacts[j][: k + 1]) + [contacts[j][0]] * (n - k - 1)
    return replace(trajectory, status=status, contacts=contacts, **arrays)


def projected_start(constrained, q, v, t0, stacklevel):
    """The initial state ``q (nq,)``, ``v (nv,)`` of a run of ``constrained`` (a
    :class:`~multibody.constrained.ConstrainedSystem`) projected onto its constraints at ``t0`` (s): ``(q, v,
    conditioning)``, the projection of :meth:`~multibody.constrained.ConstrainedSystem.project` and the rows'
    conditioning there. Where it moved the state by more than ``1e-10``, a warning ``stacklevel`` calls up gives the
    distance and the coordinates that moved most; where the projection fails, its ``ConstraintError``."""
    # (the rows' rank warning, on the system's first projection, also points at the caller)
    q_projected, v_projected, conditioning = constrained.projection(q, v, t0, stacklevel=stacklevel + 1)
    if not constrained.num_rows:  # (without rows the projection normalises q only, which is not reported)
        return q_projected, v_projected, conditioning
    dq, dv = np.abs(q_projected - q), np.abs(v_projected - v)
    moved = max(dq.max(initial=0.0), dv.max(initial=0.0))
    if moved > 1e-10:
        largest = [f"{coordinate_name(constrained.system, int(np.argmax(d)), rate)} by {d.max():.3g}"
                   for d, rate in ((dq, False), (dv, True)) if d.size and d.max() > 1e-10]
        warnings.warn(f"initial state violated the constraints; projected onto them (moved by {moved:.3g}: "
                      f"{' and '.join(largest)})", UserWarning, stacklevel=stacklevel)
    return q_projected, v_projected, conditioning


def warn_projected_starts(moved, stacklevel):
    """One warning for a batch of initial states whose projection onto the constraints moved each by ``moved (N,)``
    (its largest change of a coordinate, m or rad, m/s or rad/s): how many moved by more than ``1e-10``, the largest
    move and its trajectory, ``stacklevel`` calls up; nothing where none moved that far."""
    if moved.max(initial=0.0) > 1e-10:
        j = int(np.argmax(moved))
        warnings.warn(f"the initial states of {int(np.sum(moved > 1e-10))} of {moved.size} trajectories violated the "
                      f"constraints; projected onto them (moved by up to {moved[j]:.3g}, in trajectory {j})",
                      UserWarning, stacklevel=stacklevel)


def coordinate_name(system, k, rate, force=False):
    """``"q[k] (joint 'name', unit)"``, ``"v[k] (...)"`` or, with ``force``, the joint force ``"tau[k] (..., N or
    N·m)"`` (indexed as ``v``): a coordinate of ``system`` named for messages (by its index alone without a
    ``Model``)."""
    rate = rate or force
    symbol = f"{'tau' if force else 'v' if rate else 'q'}[{k}]"
    model = getattr(system, "model", None)
    if model is None:
        return symbol
    offsets = model.idx_v if rate else model.idx_q
    joint = max(j for j in range(model.njoints) if offsets[j] <= k)
    within = k - offsets[joint]
    kind = model.joints[joint].kind
    linear = kind in ("prismatic", "translation") or (kind in ("free-flyer", "planar")
                                                      and within < (3 if kind == "free-flyer" else 2))
    if force:
        unit = "N" if linear else "N·m"
    elif kind in ("revolute", "continuous"):
        unit = "rad/s" if rate else "rad"
    elif linear:
        unit = "m/s" if rate else "m"
    else:  # quaternion or (cos θ, sin θ) entries, angular velocities
        unit = "rad/s" if rate else "unit-norm component"
    return f"{symbol} (joint {model.joint_names[joint]!r}, {unit})"


def non_finite(system, values, rate=False, force=False):
    """The non-finite entries of ``values (n,)`` (``q``, with ``rate`` ``v``, with ``force`` joint forces of
    ``system``), each named by :func:`coordinate_name` with its value, the first five listed."""
    bad = np.flatnonzero(~np.isfinite(values))
    named = ", ".join(f"{coordinate_name(system, int(k), rate, force)} = {values[k]}" for k in bad[:5])
    return named + (f" and {bad.size - 5} more" if bad.size > 5 else "")


def require_finite(system, name, values, rate=False, force=False):
    """``ValueError`` naming the argument ``name`` and its non-finite entries (see :func:`non_finite`) unless
    ``values`` ``(n,)``, or ``(N, n)`` for ``N`` trajectories (then also naming the trajectories), are finite:
    from a non-finite state an integrator cannot choose a step, and SciPy's adaptive ones try for ever."""
    values = np.asarray(values, dtype=float)
    finite = np.isfinite(values).all(axis=-1)
    if finite.all():
        return
    if values.ndim == 1:
        raise ValueError(f"{name} must be finite: {non_finite(system, values, rate, force)}")
    rows = np.flatnonzero(~finite)
    others = "" if rows.size == 1 else f" ({rows.size} trajectories have non-finite entries: {rows[:10].tolist()}" + (
        " ...)" if rows.size > 10 else ")")
    raise ValueError(f"{name} must be finite: in trajectory {rows[0]}, {name}[{rows[0]}] has "
                     f"{non_finite(system, values[rows[0]], rate, force)}{others}")


def non_finite_torque(system, t, values):
    """The message of joint forces ``values (nv,)`` from ``tau(t, q, v)`` at ``t`` (s) that are not finite."""
    return f"the joint forces tau(t, q, v) are not finite at t = {t:.6g} s: {non_finite(system, values, force=True)}"


#: A compiled run's first call takes :data:`FIRST_CHUNK` steps; the next ones about :data:`CHUNK_SECONDS` of wall
#: time each (:func:`next_chunk`), so that the progress bar moves and an interrupt (Ctrl-C, answered when a call
#: returns) stops the run between calls.
FIRST_CHUNK, CHUNK_SECONDS = 64, 0.2


def next_chunk(chunk, seconds):
    """The steps of a compiled run's next call, after its last call took ``chunk`` steps in ``seconds`` (wall time):
    as many as take about :data:`CHUNK_SECONDS` at that rate, at least :data:`FIRST_CHUNK` and at most 64 times
    ``chunk`` (a first call slowed by compiling does not make the next one short, a fast one not endless)."""
    return max(FIRST_CHUNK, min(int(chunk * CHUNK_SECONDS / max(seconds, 1e-9)), 64 * chunk, 1 << 30))


#: Wall time (s) above which a run shows a progress bar with ``simulate(..., progress=None)``.
PROGRESS_AFTER = 2.0


class Progress:
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
        """Tell the bar that the run has reached time ``t`` (s); with ``mode`` ``None``, decide whether to open
        it."""
        if self.bar is not None and t - self.t0 >= self.span:
            # tqdm draws on an update that comes over 0.1 s after its last drawing, and close draws again:
            # the end is drawn once, by close, however long the run's last call took
            self.bar.n = self.span
        elif self.bar is not None:
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
        """Draw the bar's end and close it (nothing where no bar was opened)."""
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


def checked_timing(t0, t_final, dt, progress, limits):
    """The output step ``dt`` (s; default a 500th of the run) after checking the options every method
    shares; ``ValueError`` names the bad one."""
    if not t_final > t0:
        raise ValueError(f"t_final ({t_final}) must be after t0 ({t0})")
    dt = (t_final - t0) / 500.0 if dt is None else float(dt)
    if not dt > 0.0:
        raise ValueError(f"dt must be positive, got {dt}")
    if progress not in (None, True, False):
        raise ValueError(f"progress must be None (a bar for long runs), True or False, got {progress!r}")
    if limits not in LIMIT_MODES:
        raise ValueError(f"limits must be one of {LIMIT_MODES}, got {limits!r}")
    return dt
