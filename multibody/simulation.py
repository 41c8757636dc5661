"""Time integration of (constrained) equations of motion: ``mb.simulate``.

The motion is ``q̇ ↔ v`` (``model.configuration_rate``) with ``v̇ = a`` from the KKT solve of
:class:`~multibody.constrained.ConstrainedSystem`. It is integrated as a Lie-group method of the
Munthe-Kaas type (E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical Integration*, 2nd ed.,
Springer 2006, §IV.8.2): in the chart ``q = chart(q_c, δ)`` around the configuration ``q_c`` at the
start of a step, the integrator's state is ``y = [δ, w]`` with ``δ̇ = J_l(δ)⁻¹ w`` for rotation
vectors and ``w`` the velocity with free-flyer, spherical and planar coordinates rotated into the
parent frame (:meth:`multibody.model.Model.chart`). Quaternions stay exactly on the unit sphere,
and since aligned velocities do not turn with a spinning body, a step may span half a revolution
(:data:`CHART_TURN`: rotation vectors are singular at 2π). The adaptive explicit methods (RK23, RK45, DOP853) are
embedded Runge–Kutta pairs with step-size control (:data:`multibody.integrators.EMBEDDED`, run by
:func:`multibody.kernels.stepping.adaptive`), the implicit ones (Radau, BDF, LSODA) SciPy's solvers; each runs on to
``t_final``, the output states at the requested times coming from its dense output (continuous extension) inside
each step, so a high output rate does not restrict the step size; on a curved configuration space it restarts in a
new chart at the end of every step, with the step size it proposed next, measuring the error of ``δ`` against the
configuration's size (:meth:`multibody.model.Model.chart_magnitude`), as for ``q`` itself. The fixed-step methods (``"Euler"``,
``"semi-implicit Euler"``, ``"RK4"``: :data:`multibody.integrators.TABLEAUS`) take one step of ``dt`` per output
interval, one chart per step. Where the system's step is compiled (a ``Model``, or built-in constraints) and the
joint forces are ``None``, an array, :class:`multibody.PD` or a ``numba.njit`` function, every step runs in compiled
calls (:mod:`multibody.kernels.stepping`); a Python callable is called from there once per stage (fixed-step), or
the adaptive run's same loop runs as Python with a call per stage. A step that the compiled run leaves (one that
starts near a singular configuration, a stage or a projection its compiled step does not solve) is taken by the
Python loop, whose numbers it shares. They also integrate ``N`` trajectories from ``q0 (N, nq)``, ``v0 (N, nv)``:
each on its own in compiled calls on all cores, or, with a Python callable, in lockstep, each stage's derivatives of
all of them in one compiled call (:func:`multibody.driver.evaluate`); one trajectory is a batch of one, run by the
same loop. With ``project=True``, a step's end state, and an output state of the dense output, is projected onto
``φ = 0`` and ``A v + b = 0`` when that moves a coordinate by more than ``projection_tolerance`` (the move, not the
residual, decides: near a singular configuration of a closed chain, a row of size ``ε`` leaves a residual of ``ε``
times the velocity it fails to constrain), and the integrator restarts from a projected step end. The
multipliers, energies and residuals of all output states are computed afterwards, in one batched call when the
system allows it; the residuals are those of the returned states.
"""

from __future__ import annotations

import collections
import time
import warnings
from dataclasses import replace

import numpy as np
from scipy.integrate import BDF, LSODA, Radau

from . import contact, gpu
from .constrained import STATUS_ERRORS, ConstrainedSystem, ConstraintError, as_system
from .constraints import CompiledRows
from .integrators import (EMBEDDED, PD, TABLEAUS, AdaptiveRun, CompiledController, CompiledRun, PDController,
                          as_controller, is_compiled_controller, tableau_step)
from .kernels import kkt, stepping
from .mechanical import CHART_TURN, Charts, ModelSystem
from .model import all_finite
# JointLimitWarning is the warning simulate's docstring names, and scripts import it from here
from .runs import (FAILURES, FIRST_CHUNK, JointLimitWarning, Progress, SimulationError, by_state,  # noqa: F401
                   checked_timing, coordinate_name, joint_damping_of, next_chunk, non_finite_torque, output_times,
                   projected_start, report_limits, require_finite, torque_function, warn_projected_starts,
                   with_joint_damping)
from .trajectory import Trajectory, recorded_names

#: The implicit methods, SciPy's solvers through their public interface.
METHODS = {"Radau": Radau, "BDF": BDF, "LSODA": LSODA}
#: The adaptive methods: the embedded pairs of :data:`multibody.integrators.EMBEDDED` and SciPy's implicit ones.
ADAPTIVE_METHODS = ("RK45", "DOP853", "Radau", "RK23", "BDF", "LSODA")
#: The fixed-step methods (:data:`multibody.integrators.TABLEAUS`): one step of ``dt`` per output interval.
FIXED_STEP_METHODS = tuple(TABLEAUS)


def batch_size(q, v, nq, nv):
    """The number ``N`` of initial states in ``q (N, nq)``, ``v (N, nv)`` (one of them may be a single state,
    ``(nq,)`` or ``(nv,)``, shared by all), or ``None`` for one state; ``ValueError`` for other shapes."""
    if q.ndim == 1 and v.ndim == 1:
        return None
    sizes = {x.shape[0] for x in (q, v) if x.ndim == 2}
    if q.ndim > 2 or v.ndim > 2 or q.shape[-1:] != (nq,) or v.shape[-1:] != (nv,) or len(sizes) > 1:
        raise ValueError(f"q0 and v0 must have shapes ({nq},) and ({nv},) for one trajectory, or (N, {nq}) and "
                         f"(N, {nv}) with the same N for a batch (one of them may be a single state, shared by "
                         f"all), got {q.shape} and {v.shape}")
    return sizes.pop()


def simulate(system, q0, v0, t_final, *, dt=None, method=None, tau=None, rtol=1e-8, atol=1e-10,
             project=True, projection_tolerance=1e-12, t0=0.0, max_step=np.inf, joint_damping=False, limits="warn",
             progress=None, rule=None, order=None):
    """Integrate the motion of a ``Model`` or ``ConstrainedSystem`` from ``(q0, v0)`` at ``t0`` to ``t_final``.

    Args:
        system: a :class:`~multibody.model.Model`, a :class:`ConstrainedSystem`, or any mechanical system
            (:class:`~multibody.mechanical.ModelSystem` lists the members; one without the chart maps
            must have ``q̇ = v``).
        q0, v0: initial state ``(nq,)``, ``(nv,)``, finite (``ValueError`` names the non-finite entries by
            joint). An inconsistent state is projected onto the constraints with a warning giving the distance
            moved; if that fails, ``ConstraintError``.
            ``q0 (N, nq)``, ``v0 (N, nv)`` (or one of them a single state, shared) integrate ``N`` trajectories
            with a fixed-step method, in compiled calls on all cores: a
            ``Model``, or a ``ConstrainedSystem`` on one with built-in constraints (compiled rows); other
            systems, and the adaptive methods, raise ``ValueError``. The trajectories equal those simulated
            one at a time; one that fails (a non-finite state, a step without solution) stops and is marked
            in ``Trajectory.status``, and the others go on (one ``RuntimeWarning`` says how many stopped).
            CUDA arrays (CuPy, PyTorch or Numba device arrays) ``q0 (N, nq)``, ``v0 (N, nv)`` run the same
            compiled step on the GPU, one trajectory per thread (:func:`multibody.gpu.advance_batch`), and the
            result is the same ``Trajectory`` of host (NumPy) arrays: a fixed-step method, joint forces
            ``None``, an array (on the host or the device), :class:`multibody.PD` or a ``numba.njit`` function,
            and a ``Model`` or a ``ConstrainedSystem`` with built-in constraints; anything else (a Python callable,
            an adaptive or the variational method, user constraints, one initial state) raises ``ValueError``. The
            initial states' projection onto the constraints, a step that starts near a singular configuration of
            them and the steps after it, and the outputs' multipliers, energies and residuals are computed on the
            host.
        t_final: end time (s).
        dt: output interval (s), and the step of the fixed-step methods; default ``(t_final − t0) / 500``.
        method: ``"RK45"`` (the default), ``"DOP853"``, ``"Radau"`` (or ``"RK23"``, ``"BDF"``, ``"LSODA"``); the fixed-step
            ``"Euler"`` (explicit, order 1), ``"semi-implicit Euler"`` (velocities first, then positions with the new
            velocities: symplectic, order 1) or ``"RK4"`` (classical, order 4); or ``"variational"``: the discrete
            Hamilton's principle with step ``dt``, constraints by discrete multipliers
            (:func:`multibody.variational.simulate`, one state; Lie-group joints included). A system with contact
            or joint limits (:class:`multibody.Ground`, :class:`multibody.ContactPair`, :class:`multibody.JointLimits`)
            is simulated by velocity-level time stepping with step ``dt``, ``"Moreau-Jean"`` (its default and only
            method: :mod:`multibody.contact`); another method raises ``ValueError``.
        tau: joint forces (N·m or N per coordinate of ``v``): ``None``; an array ``(nv,)``; :class:`multibody.PD`, a
            joint-space PD law as data, run inside the compiled step; a ``numba.njit`` function ``f(t, q, v, out)``
            that writes them into ``out (nv,)`` (zeros on entry), also run inside it
            (:class:`multibody.integrators.CompiledController`); or a callable ``tau(t, q, v) -> (nv,)``, called once
            per stage. For ``N`` trajectories also an array ``(N, nv)``, a PD with ``(N, …)`` gains or references,
            and the callable takes the batch, ``q (N, nq)``, ``v (N, nv) -> (N, nv)`` (a stopped trajectory's row
            holds its last state). An array must be finite (``ValueError``); a controller's non-finite result stops
            the run (a batch: the trajectories of its non-finite rows) with :class:`SimulationError` naming the time
            it was called at and the joints.
        rtol, atol: tolerances of the adaptive methods.
        project: keep the state on the constraints (default ``True``): after an integrator step whose
            end state's projection onto them (:meth:`ConstrainedSystem.project`) moves it by more than
            ``projection_tolerance``, go on from the projected state (restarting an adaptive method there).
            Where the rows are close to singular there (the conditioning of ``A`` in the metric of ``M``,
            its smallest singular value above rounding over the largest, below :data:`NEAR_SINGULAR`: a
            closed chain near a flat configuration), the steps that start there evaluate every stage at its
            projection onto the constraints (each trajectory of a batch by its own conditioning; systems
            whose charts have ``chart_coordinates``, or with ``q̇ = v``), since off the constraints the
            accelerations' error grows as the conditioning falls; and RK23, RK45 and DOP853 measure their
            local error there without the parts along the rows, which the projection removes
            (``docs/theory.md`` §8).
        projection_tolerance: largest move of a coordinate (``q`` in m or rad, ``v`` in m/s or rad/s) left
            unprojected at a step end; output states of the dense output that their projection moves by
            more than it are projected too.
        max_step: largest internal step of the adaptive methods (s). Each step is also kept to turn the
            rotation vectors of its chart (free-flyer and spherical joints) by at most :data:`CHART_TURN` at the
            angular speeds of its start.
        joint_damping: add viscous joint damping ``−D v`` (``D = diag(model.damping)``, from URDF
            ``<dynamics damping>``) to the joint forces; needs a system built on a ``Model``.
        limits: what to do, after the run, with output positions outside ``[model.lower, model.upper]``
            (URDF ``<limit lower upper>``; limits are reported, not enforced, but for the joints of a
            :class:`multibody.JointLimits` in the system, which are held and not reported): ``"warn"`` (default) gives
            one :class:`JointLimitWarning` per joint, naming it with the first time and value outside;
            ``"error"`` raises :class:`SimulationError` at the first output time outside, naming the
            joint, time and value, with the trajectory up to that time; ``"ignore"`` does nothing.
            Systems without a ``Model`` (symbolic ones) have no limits. For ``N`` trajectories, ``"warn"``
            gives one warning per joint with the number of trajectories outside, and ``"error"`` stops each
            trajectory outside at its first output time outside, as a failure does.
        progress: a progress bar over simulated time (``tqdm``, on standard error), for every method, contact and
            joint limits included: ``None`` (default) shows one when the run is expected to take more than
            :data:`multibody.runs.PROGRESS_AFTER` seconds, judged from the wall time of its first steps, and the
            output is a terminal or a notebook; ``True`` always; ``False`` never. Compiled runs take their steps in
            calls of about :data:`multibody.runs.CHUNK_SECONDS`, between which the bar moves and an interrupt
            (Ctrl-C) stops the run (on the GPU, a batch's steps run in one launch).
        rule, order: ``method="variational"`` only: ``"midpoint"`` (default) or ``"trapezoidal"`` quadrature of the
            action, and order 2 (default) or 4 (Yoshida's composition, systems without constraints).
    Returns:
        :class:`Trajectory` (with a leading axis ``N`` for ``N`` trajectories).
    Raises:
        ValueError: invalid arguments, among them non-finite ``q0``, ``v0`` or an array ``tau``.
        SimulationError: the integration of one trajectory failed (a non-finite state, joint forces or
            derivative of the state, constraints without a solution, or an adaptive method that stalled: its
            last :data:`STALLED_STEPS` steps advanced less than :data:`STALLED_SPAN` of the run), or
            (``limits="error"``) a joint left its limits; ``.trajectory`` holds the part computed so far (up to
            the last output time before the failure).
    """
    device = gpu.is_device_array(q0) or gpu.is_device_array(v0)
    contact_system = isinstance(system, ConstrainedSystem) and bool(system.unilateral)
    if device:
        _check_device_run(contact.METHOD if contact_system and method is None else method, tau)
        q0, v0, tau = (gpu.to_host(x) if gpu.is_device_array(x) else x for x in (q0, v0, tau))
    if method == "variational":  # the discrete Hamilton's principle, in its own module
        from . import variational
        tau = as_controller(tau, system.system if isinstance(system, ConstrainedSystem) else as_system(system))
        options = {name: value for name, value in (("rule", rule), ("order", order)) if value is not None}
        return variational.simulate(system, q0, v0, t_final, dt=dt, tau=tau, t0=t0, joint_damping=joint_damping,
                                    limits=limits, progress=progress, **options)
    if rule is not None or order is not None:
        raise ValueError(f"rule and order are options of method='variational', not of method={method!r}")
    constrained = system if isinstance(system, ConstrainedSystem) else ConstrainedSystem(system)
    mechanical = constrained.system
    nq, nv = constrained.nq, constrained.nv
    if constrained.unilateral:
        _check_unilateral(constrained, method)
    else:
        method = "RK45" if method is None else method
        if method not in ADAPTIVE_METHODS + FIXED_STEP_METHODS:
            raise ValueError(f"method must be one of {ADAPTIVE_METHODS + FIXED_STEP_METHODS + ('variational',)}, "
                             f"got {method!r}")
    times = output_times(t0, t_final, checked_timing(t0, t_final, dt, progress, limits))
    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    batch = batch_size(q, v, nq, nv)
    if device and batch is None:
        raise ValueError(f"simulate on CUDA arrays integrates a batch, one trajectory per GPU thread: q0 (N, {nq}), "
                         f"v0 (N, {nv}); got one state, q0 {q.shape} and v0 {v.shape} (simulate one state from NumPy "
                         "arrays)")
    if batch is None:
        if q.shape != (nq,) or v.shape != (nv,):
            raise ValueError(f"q0 and v0 must have shapes ({nq},) and ({nv},), got {q.shape} and {v.shape}")
    elif not constrained.unilateral:
        try:
            check_batchable(constrained, method, q.shape, v.shape)
        except ValueError as error:
            if device:
                raise ValueError(f"simulate on CUDA arrays: {error}") from None
            raise
    require_finite(mechanical, "q0", q)
    require_finite(mechanical, "v0", v, rate=True)
    tau = as_controller(tau, mechanical, batch)
    torque = torque_function(tau, nv, batch, mechanical)
    # the joint forces as the compiled run takes them, before the damping joins them
    controller = tau if tau is None or callable(tau) else np.asarray(torque(t0, None, None))
    python = callable(controller) and not isinstance(controller, (PDController, CompiledController))
    damping = joint_damping_of(mechanical, joint_damping)
    # one trajectory is a batch of one: the same run, whose result loses the batch axis
    count = 1 if batch is None else batch
    if constrained.unilateral:
        # the compiled Moreau–Jean steps of multibody.contact.run, but for a Python controller's joint forces
        trajectory = contact.run(constrained, np.broadcast_to(q, (count, nq)), np.broadcast_to(v, (count, nv)), times,
                                 None if python else controller, torque if python else None, batch, damping,
                                 device=device, progress=progress)
        return _finish(mechanical, trajectory, limits, contact.enforced_coordinates(constrained),
                       f"simulate ({contact.METHOD}) stopped: ")
    if damping is not None:
        tau = with_joint_damping(torque, damping)
        torque = torque_function(tau, nv, batch, mechanical)
    charts = Charts(mechanical)
    if method in FIXED_STEP_METHODS:
        # a compiled run takes joint forces that are data or compiled, and one trajectory's Python callable too
        # (called from it once per stage); a batch's Python callable takes the batch at each stage, in lockstep
        compiled = constrained.compiled_step is not None and (not python or batch is None)
        run = _compiled_run(constrained, charts, TABLEAUS[method], controller, damping, project, projection_tolerance,
                            times) if compiled else None
        trajectory = _simulate_batch(constrained, charts, np.broadcast_to(q, (count, nq)),
                                     np.broadcast_to(v, (count, nv)), times, torque, callable(tau), TABLEAUS[method],
                                     run, project=project, projection_tolerance=projection_tolerance,
                                     progress=progress, device=device, single=batch is None, controller=controller)
        return _finish(mechanical, trajectory, limits)

    q, v, conditioning = projected_start(constrained, q, v, t0, stacklevel=3)

    # The integrator's state is y = [δ, w] in the chart around a configuration q_c: q = chart(q_c, δ),
    # w the aligned velocity (see Model.chart). A new chart starts from each step's end state.
    stages = _ChartStages(constrained, charts, torque, callable(tau), project, projection_tolerance, t0)
    tolerance = projection_tolerance if project else None
    states = np.empty((len(times), nq + nv))
    states[0] = np.concatenate([q, v])
    done = 0  # output states filled so far
    bar = Progress(progress, t0, t_final)

    try:
        constrained.solve(q, v, torque(t0, q, v), t0)  # the initial state has a KKT solution
        done = 1
        near = _near_singular(conditioning, project, constrained, charts)
        if method in EMBEDDED:
            # An embedded pair of our own (multibody.kernels.stepping.adaptive): compiled where the system's step
            # is and the joint forces are data or compiled, else the same run as Python with the maps of stages;
            # the steps that start near a singular configuration, or whose stage or projection the compiled step
            # did not solve, run as Python too, after which the compiled run goes on.
            run = _adaptive_run(constrained, charts, EMBEDDED[method], controller, damping, project,
                                projection_tolerance, times, rtol, atol, max_step)
            stages.hand_back = run.tree is not None
            run.start(states[0], near)
            chunk, handed = FIRST_CHUNK, False
            while done < len(times):
                python = stages if handed or run.near or not stages.hand_back else None
                started = time.perf_counter()
                try:
                    _, status = run.advance(states, min(len(times), done + chunk), python)
                finally:
                    done = run.done
                chunk = next_chunk(chunk, time.perf_counter() - started)
                bar.update(run.t)
                # (a stage or projection the compiled step did not solve: the next step runs as Python)
                handed = status in (stepping.STAGE_UNSOLVED, stepping.PROJECTION_UNSOLVED)
                if status in (stepping.COMPLETED, stepping.NEAR_SINGULAR, stepping.HANDED_BACK) or handed:
                    continue
                if status == stepping.STEP_TOO_SMALL:
                    raise SimulationError(f"{method} failed at t = {run.io[stepping.IO_TIME]:.6g} s: the step size "
                                          "fell below ten roundings of the time", None)
                if status == stepping.STALLED:
                    raise SimulationError(_stalled(method, run.io[stepping.IO_TIME], run.io[stepping.IO_VALUE],
                                                   run.near, t_final - t0), None)
                raise _RUN_FAILURES[status](mechanical, run.io, run.plan)
        else:
            solver_class = METHODS[method]

            def start(t, state, step_size):
                """An implicit SciPy solver from ``state`` at ``t`` in the chart around it, with the rates of
                ``stages`` (on the constraints when ``near``)."""
                q_chart, y0, magnitude = state[:nq], np.empty(2 * nv), np.empty(nv)
                stages.restart(t, state, near, y0, magnitude)

                def fun(t_, y):
                    y_dot = np.empty(2 * nv)
                    stages.rates(t_, q_chart, y, y_dot)
                    return y_dot

                longest = min(max_step, charts.step_limit(state))
                first_step = None if step_size is None else min(step_size, t_final - t, longest)
                # Errors of δ relative to the configuration's size, as when integrating q itself; the solver
                # would measure them against δ, which is zero at every step's start.
                atol_chart = np.concatenate([atol + rtol * magnitude, np.full(nv, atol)])
                solver = solver_class(fun, t, y0, t_final, rtol=rtol, atol=atol_chart, max_step=longest,
                                      first_step=first_step)
                return solver, q_chart

            # One solver runs on to t_final; the output states inside each of its steps come from its
            # dense output (continuous extension), so the output rate does not restrict the step size.
            # It restarts from the end of a step that was projected, and, on a curved configuration
            # space, from every step's end in a new chart (keeping the step size it proposes next).
            solver, q_chart = start(t0, states[0], None)
            recent = collections.deque(maxlen=STALLED_STEPS)  # the end times of the latest steps
            while done < len(times):
                t_before = solver.t
                message = solver.step()
                if solver.status == "failed":
                    raise SimulationError(f"{method} failed at t = {t_before:.6g} s: {message}", None)
                recent.append(solver.t)
                if len(recent) == STALLED_STEPS and recent[-1] - recent[0] < STALLED_SPAN * (t_final - t0):
                    raise SimulationError(_stalled(method, recent[-1], recent[-1] - recent[0], near, t_final - t0),
                                          None)
                bar.update(solver.t)
                inside = done + int(np.searchsorted(times[done:], solver.t, side="left"))
                if inside > done:
                    states[done:inside] = charts.from_chart(q_chart, solver.dense_output()(times[done:inside]).T)
                    done = inside
                was_near = near
                end = charts.from_chart(q_chart, solver.y)
                projected, near = stages.settle(solver.t, end)
                if done < len(times) and times[done] == solver.t:
                    states[done] = end
                    done += 1
                if done < len(times) and (projected or charts.curved or near != was_near):
                    solver, q_chart = start(solver.t, end, solver.step_size)
    except (SimulationError, ConstraintError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        t_fail = times[max(done - 1, 0)]
        message = f"simulation stopped at t = {t_fail:.6g} s: {_grown(mechanical, states[:done], nq, v) or exc}"
        try:
            partial = _trajectory(constrained, times[:done], states[:done], torque, message, tolerance)
        except FAILURES:
            # states so far out that their multipliers cannot be computed (or joint forces that are not finite
            # at them): the states alone, as a batch of one that stopped before them
            partial = _batch_trajectory(constrained, times[:done], states[None, :done, :nq], states[None, :done, nq:],
                                        np.zeros(1, dtype=int), None, None, False, [message], tolerance).select(0)
        raise SimulationError(message, partial) from exc
    finally:
        bar.close()
    return _finish(mechanical, _trajectory(constrained, times, states, torque, "completed", tolerance,
                                           state_dependent=callable(tau)), limits)


def _check_unilateral(constrained, method):
    """``ValueError`` unless the system with contact or joint limits ``constrained`` can be simulated by ``method``:
    ``None`` or :data:`multibody.contact.METHOD`, on a ``Model``."""
    if method not in (None, contact.METHOD):
        names = ", ".join(c.name for c in constrained.unilateral)
        raise ValueError(f"method={method!r} cannot simulate contact or joint limits ({names}): a system with unilateral "
                         f"constraints is simulated by velocity-level time stepping, method={contact.METHOD!r} (the "
                         "default), whose steps resolve each impact and the Coulomb cone; the smooth methods would "
                         "integrate through them")
    if not isinstance(constrained.system, ModelSystem):
        raise ValueError(f"contact and joint limits need a system built on a Model; {type(constrained.system).__name__} "
                         "is not")


def _finish(system, trajectory, limits, enforced=(), stopped=""):
    """The end of a fixed-step or contact run of ``system`` (the mechanical system), called by :func:`simulate`: one
    trajectory that stopped early raises :class:`SimulationError` (its status after ``stopped``) with the part so far;
    the joint limits are reported (:func:`multibody.runs.report_limits`, but for the coordinates ``enforced``); and a
    batch gives one warning of the trajectories that stopped early, each warning at the line that called
    :func:`simulate`. Returns the trajectory."""
    # (the warnings' frames: report_limits or warn_if_stopped, this function, simulate, its caller)
    stacklevel = 4
    one = trajectory.batch_size is None
    if one and trajectory.status != "completed":
        raise SimulationError(stopped + trajectory.status, trajectory)
    if getattr(system, "model", None) is not None and limits != "ignore":
        trajectory = report_limits(system, trajectory, limits, enforced, stacklevel=stacklevel)
    if not one:
        warn_if_stopped(trajectory, stacklevel)
    return trajectory


def _compiled_run(constrained, charts, tableau, controller, damping, project, projection_tolerance, times):
    """The :class:`~multibody.integrators.CompiledRun` of ``constrained`` (its step compiled) with ``tableau``, the
    ``controller`` (``None``, constant joint forces, a bound PD, a compiled or a Python controller) and ``damping``
    (``(nv,)`` or ``None``), at the output ``times``: the steps :func:`_simulate_batch`'s Python step would take,
    with the projection at each step's end as it makes it (:meth:`ConstrainedSystem.projection`'s tolerance and
    iterations) and the rule of :func:`_near_singular`."""
    return CompiledRun(constrained.compiled_step, tableau, controller, damping,
                       *_run_projection(constrained, charts, project, projection_tolerance), times, constrained.nq,
                       constrained.nv)


def _adaptive_run(constrained, charts, pair, controller, damping, project, projection_tolerance, times, rtol, atol,
                  max_step):
    """The :class:`~multibody.integrators.AdaptiveRun` of ``constrained`` with the embedded ``pair``: compiled where
    the system's step is and the ``controller`` is data or compiled (as :func:`_compiled_run` makes
    it), else one that runs as Python only. ``damping`` enters the compiled run's plan (its Python stages have it in
    their joint forces already)."""
    step = constrained.compiled_step
    if not (controller is None or isinstance(controller, (np.ndarray, PDController, CompiledController))):
        step = None
    if step is None:
        controller = damping = None
    return AdaptiveRun(step, charts.curved, pair, controller, damping,
                       *_run_projection(constrained, charts, project, projection_tolerance), times, constrained.nq,
                       constrained.nv, rtol, atol, max_step, CHART_TURN, charts.rotations[:, 0])


def _run_projection(constrained, charts, project, projection_tolerance):
    """``(projection tolerance, near singular)`` of a run's plan: the largest move left unprojected at a step's end
    (``None``: no projection), and the conditioning below which the next step leaves the run
    (:data:`NEAR_SINGULAR` where :func:`_near_singular` applies, else ``-inf``)."""
    return (projection_tolerance if project and constrained.num_rows else None,
            NEAR_SINGULAR if bool(_near_singular(0.0, project, constrained, charts)) else -np.inf)


class _ChartStages:
    """The stages of :func:`simulate`'s adaptive methods in the chart maps of ``charts``, with the joint forces
    ``torque(t, q, v)`` (of the state where ``state_dependent``, else constant from ``t0`` on) and the projection at
    a step's end (``project``, ``projection_tolerance``): the maps by which :func:`multibody.kernels.stepping.adaptive`
    runs as Python (a system without a compiled step, a Python controller, the steps near a singular configuration),
    whose restarts, rates and step ends SciPy's implicit solvers take too."""

    def __init__(self, constrained, charts, torque, state_dependent, project, projection_tolerance, t0):
        self.constrained, self.charts, self.torque = constrained, charts, torque
        self.state_dependent, self.project, self.projection_tolerance = state_dependent, project, projection_tolerance
        self.constant = None if state_dependent else torque(t0, None, None)
        #: whether the step's stages are evaluated at their projection onto the constraints (near a singular
        #: configuration)
        self.near = False
        #: whether the run returns after a step that ends away from a singular configuration, to go on compiled
        self.hand_back = False

    def derivative(self, t, y, q_chart):
        """``ẏ (2 nv,)`` of the chart state ``y (2 nv,)`` around ``q_chart`` at ``t`` (s), at its projection onto the
        constraints (in the same chart) where :attr:`near`. With a compiled step, one compiled call (after the
        joint forces, when they depend on the state), which raises the error of a failed solve itself."""
        constrained, charts = self.constrained, self.charts
        if self.near:
            q_t, v_t = constrained.project(*charts.state(q_chart, y), t)
            y = charts.coordinates(q_chart, q_t, v_t)
        if constrained.compiled_step is not None:
            q_t, tau_t = None, self.constant
            if self.state_dependent:
                q_t, v_t = charts.state(q_chart, y)
                tau_t = self.torque(t, q_t, v_t)
                tau_t = None if tau_t is None else constrained.checked_tau(tau_t)
            y_dot = constrained.chart_derivative(q_chart, y, tau_t, q_t)
            if y_dot is not None:
                return y_dot
        return _solved_chart_derivative(constrained, charts, t, q_chart, y, self.torque)

    def restart(self, t, state, near, y0, magnitude):
        self.near = bool(near)
        y0[:] = self.charts.to_chart(state)
        magnitude[:] = self.charts.chart_magnitude(state[: self.charts.nq])

    def rates(self, t, q_chart, y, out):
        y_dot = self.derivative(t, y, q_chart)
        # (SciPy's solvers would answer a non-finite derivative by shrinking the step, to no end)
        if not all_finite(y_dot):
            raise SimulationError(_non_finite_rates(self.constrained.system, t, y, y_dot), None)
        out[:] = y_dot

    def tangent(self, t, q_chart, y, out):
        out[:] = _tangent_map(self.constrained, self.charts, q_chart, t, y)

    def unchart(self, q_chart, y, out):
        out[:] = self.charts.from_chart(q_chart, y)

    def settle(self, t, state):
        """The end ``state = [q, v] (nq + nv,)`` of a step at ``t`` (s) projected in place onto the constraints
        when, with ``project``, the projection moves a coordinate by more than the tolerance: ``(whether it was
        projected, whether the next step evaluates its stages on the constraints)`` (the rows there are near
        singular)."""
        if not np.isfinite(state).all():
            raise SimulationError(f"the state became non-finite at t = {t:.6g} s", None)
        constrained, nq = self.constrained, self.charts.nq
        if not (self.project and constrained.num_rows):
            return False, False
        # Judged by the move, not the residual: near a singular configuration a residual of 1e-13 can hide a
        # velocity off the constraints by 1e-3 (a row of size ε moves v by residual/ε).
        q, v, conditioning = constrained.projection(state[:nq], state[nq:], t)
        near = bool(_near_singular(conditioning, self.project, constrained, self.charts))
        projected = np.abs(np.concatenate([q, v]) - state).max() > self.projection_tolerance
        if projected:
            state[:nq], state[nq:] = q, v
        return projected, near


#: The failures a compiled run reports (:mod:`multibody.kernels.stepping`), each as the error the Python loop raises
#: for it, from the system, the run's ``io`` and its plan; the statuses not listed (a stage or a projection the
#: compiled step did not solve) hand the step to the Python loop.
_RUN_FAILURES = {
    stepping.NON_FINITE_STATE: lambda system, io, plan: SimulationError(
        f"the state became non-finite at t = {io[stepping.IO_TIME]:.6g} s", None),
    stepping.NON_FINITE_TORQUE: lambda system, io, plan: SimulationError(non_finite_torque(
        system, io[stepping.IO_TIME],
        io[stepping.IO_HEADER + system.nq + system.nv : stepping.io_size(system.nq, system.nv)].copy()), None),
    stepping.NOT_CONVERGED: lambda system, io, plan: STATUS_ERRORS[kkt.NOT_CONVERGED](
        system, 0, -1, io[stepping.IO_VALUE], plan[int(plan[stepping.PLAN_SETTINGS]) + 1]),
}


def _non_finite_rates(system, t, y, y_dot):
    """The message of chart rates ``y_dot = [δ̇, ẇ] (2 nv,)`` at the chart state ``y (2 nv,)`` and ``t`` (s) that
    are not finite."""
    if not np.isfinite(y).all():
        return f"the state became non-finite at t = {t:.6g} s"
    nv = len(y) // 2
    k = int(np.flatnonzero(~np.isfinite(y_dot))[0])
    rate = "acceleration" if k >= nv else "velocity"
    return (f"the equations of motion are not finite at t = {t:.6g} s, at a finite state (the dynamics overflowed): "
            f"the {rate} of {coordinate_name(system, k % nv, True)} is {y_dot[k]}")


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
    return (f"the state grew beyond bounds: {coordinate_name(system, k, True)} {size}, over {bound:.3g} (a thousand "
            "times the initial velocities); the integration diverged: take a smaller step (dt with RK4) or an "
            "adaptive method")


def _solved_chart_derivative(constrained, charts, t, q_chart, y, torque):
    """``ẏ (2 nv,)`` of one chart state ``y`` around ``q_chart`` at ``t`` (s) from
    :meth:`ConstrainedSystem.forward_dynamics` and the chart maps, with joint forces ``torque(t, q, v)``: where
    the compiled chart derivative does not apply (rows evaluated in Python, a system that is not a Model), or
    where ABA alone gave non-finite rates (``forward_dynamics`` then raises the error that names the joint)."""
    nv = charts.nv
    q_t, T, v_t = charts.unchart(q_chart, y)
    a, _ = constrained.forward_dynamics(q_t, v_t, torque(t, q_t, v_t), t)
    # ẇ = T (a + κ(v))
    w_dot = a if T is None else T @ (a + charts.velocity_coupling(v_t))
    return np.concatenate([charts.chart_rate(y[:nv], y[nv:]), w_dot])


def _tangent_map(constrained, charts, q_chart, t, y):
    """The map ``Π (2 nv, 2 nv)`` that takes an error estimate ``[δ, w]`` of a step in the chart around ``q_chart`` to
    its tangent part at the chart state ``y`` (the step's start) and time ``t``: ``δ`` less its part along the rows
    with a position level, ``w`` less its part along all rows, each ``M``-orthogonal, as the projection removes them
    (``δ`` and ``v = T⁻¹ w`` are velocity-space vectors): ``Π = diag(1 − P_position, T (1 − P_velocity) T⁻¹)``."""
    nv = charts.nv
    q_t, T, _ = charts.unchart(q_chart, y)
    position, velocity = constrained.row_space_projectors(q_t, t)
    if T is not None:
        # on w = T v: T P T⁻¹
        velocity = T @ np.linalg.solve(T.T, velocity.T).T
    tangent = np.zeros((2 * nv, 2 * nv))
    tangent[:nv, :nv] = np.eye(nv) - position
    tangent[nv:, nv:] = np.eye(nv) - velocity
    return tangent


#: Conditioning of the constraint rows at a step's start (the smallest singular value of ``A L⁻ᵀ`` above
#: rounding over the largest, ``M = L Lᵀ``) below which :func:`simulate` evaluates that step's stages on the
#: constraints. A ten-cell parallelogram chain passing its flat configurations with DOP853 at rtol 1e-9 and
#: 1e-10 needs it from 1e-2, not from 1e-3; the demos' rows stay above 0.2.
NEAR_SINGULAR = 1e-2

#: An adaptive method has stalled when its last ``STALLED_STEPS`` steps together advance the time by less
#: than ``STALLED_SPAN`` of the whole run: at that pace the run would take a billion steps.
STALLED_STEPS, STALLED_SPAN = stepping.STALLED_STEPS, stepping.STALLED_SPAN


def _near_singular(conditioning, project, constrained, charts):
    """Whether a step that starts where the rows' conditioning is ``conditioning`` (``(...)``; NaN: a state
    that could not be projected) evaluates its stages on the constraints: with ``project``, rows, charts
    that can express a projected stage, and the conditioning below :data:`NEAR_SINGULAR`."""
    return bool(project and constrained.num_rows and charts.invertible) & (np.asarray(conditioning) < NEAR_SINGULAR)


def _stalled(method, last, advanced, near, span):
    """The message of an adaptive method that has stalled (see :data:`STALLED_STEPS`): its latest steps ended at
    ``last`` (s) and advanced ``advanced`` (s) in all, of a run of ``span`` (s); ``near``: whether the rows are near
    singular there."""
    message = (f"{method} stalled at t = {last:.6g} s: its last {STALLED_STEPS} steps advanced {advanced:.3g} s "
               f"in all ({advanced / span:.2g} of the run)")
    if near:
        message += (". The constraints are near a singular configuration there, where they fix the motion only to "
                    "rounding divided by the distance to it, and the accelerations change from one stage to the "
                    "next by more than the tolerances allow; a looser rtol, method='DOP853' or 'RK45' (which "
                    "measure their error there without the part the projection removes), or method='RK4' with a "
                    "fixed dt may pass it")
    return message


def _trajectory(constrained, times, states, torque, status, projection_tolerance=None, state_dependent=True):
    """The :class:`Trajectory` of one run's output ``states (n, nq + nv)`` at ``times (n,)``, with the joint forces
    ``torque(t, q (nq,), v (nv,))`` (called once, at the first time, where not ``state_dependent``).

    The states are on the configuration manifold already (charts keep them there); with a
    ``projection_tolerance``, states that their projection onto the constraints moves by more than it
    (dense-output states between integrator steps) are projected. ``λ``, energy and residual are then evaluated at
    exactly the returned states, as for a batch of one (:func:`_batch_trajectory`).
    """
    nq, n = constrained.nq, len(times)
    q, v = states[:, :nq].copy(), states[:, nq:].copy()
    if projection_tolerance is not None and constrained.num_rows and n:
        # judged by the move, as a step's end is (settle in simulate): near a singular configuration a
        # residual far below the tolerance can hide a velocity off the constraints
        if constrained.batched:
            q_p, v_p = constrained.project(q, v, times)
        else:
            q_p, v_p = (np.array(x) for x in zip(*(constrained.project(q[k], v[k], times[k]) for k in range(n))))
        off = np.flatnonzero(np.maximum(np.abs(q_p - q).max(axis=-1), np.abs(v_p - v).max(axis=-1))
                             > projection_tolerance)
        q[off], v[off] = q_p[off], v_p[off]

    def one(t, q_, v_):
        """The joint forces of the batch of one."""
        return torque(t, q_, v_) if q_ is None else torque(t, q_[0], v_[0])

    last = np.concatenate([q[-1:], v[-1:]], axis=-1) if n else np.zeros((1, nq + constrained.nv))
    return _batch_trajectory(constrained, times, q[None], v[None], np.array([n]), last, one, state_dependent,
                             [status], projection_tolerance).select(0)


# ============================================================================= many trajectories in lockstep

#: Output states whose multipliers, energies and residuals are computed in one call (bounds the memory of
#: the constrained step's outputs, a few dozen floats per state).
_OUTPUT_BLOCK = 1 << 16


def _check_device_run(method, tau):
    """``ValueError`` unless :func:`simulate` can run ``method`` and the joint forces ``tau`` on the GPU: a fixed-step
    method or the contact steps, and joint forces that are data or compiled (the GPU does not call Python)."""
    if method not in FIXED_STEP_METHODS + (contact.METHOD,):
        raise ValueError(f"simulate on CUDA arrays runs the fixed-step methods {FIXED_STEP_METHODS}, one trajectory "
                         f"per GPU thread; method={method!r} is not one (it runs on the host: pass NumPy arrays)")
    if callable(tau) and not isinstance(tau, PD) and not is_compiled_controller(tau):
        raise ValueError("simulate on CUDA arrays takes joint forces tau that the GPU computes: None, an array, mb.PD "
                         "or a numba.njit function f(t, q, v, out); a Python callable runs on the host (pass NumPy "
                         "arrays, or write it as a numba.njit function)")


def check_batchable(constrained, method, q_shape, v_shape):
    """``ValueError`` unless ``constrained`` can integrate a batch of initial states in lockstep with ``method``."""
    if method not in FIXED_STEP_METHODS:
        raise ValueError(f"a batch of initial states (q0 {q_shape}, v0 {v_shape}) is integrated in lockstep, which "
                         f"needs a fixed-step method {FIXED_STEP_METHODS}; {method!r} chooses its own steps for each "
                         "trajectory: pass method='RK4' with a step dt, or simulate the states one at a time")
    if constrained.batched and constrained.compiled_step is not None:
        return
    mechanical = constrained.system
    if not isinstance(mechanical, ModelSystem):
        why = (f"its mechanical system, a {type(mechanical).__name__}, is evaluated in Python one state at a time "
               "(batches run the compiled kernels of a Model)")
    else:
        python = [c.name for c in constrained.constraints
                  if not isinstance(c, CompiledRows) or c.moving or not getattr(c, "batched", False)]
        why = (f"its constraints {python} are evaluated in Python one state at a time (user constraints, moving "
               "surfaces); batches need built-in constraints with compiled rows") if python else \
            "its constrained step is not compiled"
    raise ValueError(f"simulate cannot integrate a batch of initial states (q0 {q_shape}) for this system: {why}; "
                     "simulate the states one at a time")


def _simulate_batch(constrained, charts, q0, v0, times, torque, state_dependent, tableau, run, *, project,
                    projection_tolerance, progress, device=False, single=False, controller=None):
    """:func:`simulate` from ``N`` initial states ``q0 (N, nq)``, ``v0 (N, nv)`` at the output ``times (n,)`` (s),
    one step of ``tableau`` per output interval. With a compiled ``run`` (:class:`~multibody.integrators.CompiledRun`:
    joint forces that are data or compiled), each trajectory runs on its own in compiled calls on all cores, and a
    step that the run leaves to Python (rows near a singular configuration, a stage the compiled step did not
    solve) is taken by the lockstep step below, for the trajectories at that step. Without one, the trajectories
    run in lockstep, each stage's chart derivatives of all of them in one compiled call on all cores
    (:meth:`ConstrainedSystem.chart_derivatives`).

    A trajectory that fails (a non-finite state or joint forces, a constrained step without solution, a projection
    that does not converge) stops: its status says when and why, its outputs from the next output time on are NaN,
    and the others go on. ``torque(t, q (N, nq), v (N, nv))`` sees every trajectory, a stopped one at its last
    state (one that never started, whose initial state cannot be projected, at rest in the neutral
    configuration). The initial states are finite (:func:`simulate` checks them). ``device``: the compiled run's
    first pass over every trajectory runs on the GPU (:func:`_run_batch`).

    ``single``: one trajectory, ``q0 (1, nq)``, ``v0 (1, nv)``, run as a batch of one: its joint forces
    ``torque(t, q (nq,), v (nv,))`` take one state, as a Python ``controller`` does, which the compiled ``run`` calls
    once per stage; its initial state's projection raises where it fails and is reported by coordinate; its initial
    state must have a solution of the constrained step; an error of its joint forces stops it; and it is returned
    without the batch axis, up to its last good output (:func:`simulate` raises where it stopped early). A system
    that takes one state at a time (not :attr:`ConstrainedSystem.batched`) runs as one trajectory only, its states
    evaluated one at a time.
    """
    mechanical = constrained.system
    nq, nv, m = constrained.nq, constrained.nv, constrained.num_rows
    count, n, t0 = len(q0), len(times), times[0]
    batched = constrained.batched
    if single:
        one_state = torque

        def torque(t, q, v):
            value = one_state(t, q, v) if q is None else one_state(t, q[0], v[0])
            return None if value is None else constrained.checked_tau(value)
    status = ["completed"] * count
    stop = np.full(count, n)  # each trajectory's outputs [stop:] are NaN

    def fail(r, k, reason):
        """Trajectory ``r`` stops at output index ``k`` (its last good state ``last[r]``, at ``times[k − 1]``)."""
        stop[r] = k
        grown = _grown(mechanical, last[r : r + 1], nq, v_start[r]) if k else None
        status[r] = f"simulation stopped at t = {times[max(k - 1, 0)]:.6g} s: {grown or reason}"

    last = np.concatenate([q0, v0], axis=-1)  # each trajectory's latest good state (finite: simulate checks)

    def projection(t):
        """The projection of a batch of states ``(q, v)`` at ``t`` onto the constraints, ``(n, nq + nv + 1)``:
        the states, and the conditioning of the rows there last."""
        def projected(q, v):
            q, v, conditioning = constrained.projection(q, v, t)
            return np.concatenate([q, v, conditioning[..., None]], axis=-1)
        return projected

    # whether each trajectory's next step evaluates its stages on the constraints, as settle decides for one
    if single:
        q_one, v_one, conditioning = projected_start(constrained, q0[0], v0[0], t0, stacklevel=4)
        projected, errors = np.concatenate([q_one, v_one, [conditioning]])[None], {}
    else:
        projected, errors = by_state(projection(t0), (q0, v0), (nq + nv + 1,), batched)
    near = np.zeros(count, dtype=bool) | _near_singular(projected[:, -1], project, constrained, charts)
    projected = projected[:, :-1]
    moved = np.abs(projected - last).max(axis=-1, initial=0.0)
    moved[list(errors)] = 0.0
    if not single and m:
        warn_projected_starts(moved, stacklevel=4)
    last[:] = projected
    if single:
        try:
            # the initial state has a solution of the constrained step
            constrained.solve(last[0, :nq], last[0, nq:], torque(t0, last[:, :nq], last[:, nq:]), t0)
        except FAILURES as error:
            errors[0] = str(error)
    good = np.ones(count, dtype=bool)
    good[list(errors)] = False
    if not single:
        # A trajectory that never started stands at rest in the neutral configuration, for the joint forces only
        # (a batch's, which take every trajectory; a batch is of a Model).
        last[~good] = np.concatenate([mechanical.model.neutral(), np.zeros(nv)])
    v_start = last[:, nq:].copy()
    for r, message in errors.items():
        fail(r, 0, message)
    states = np.full((count, n, nq + nv), np.nan)
    q_out, v_out = states[..., :nq], states[..., nq:]
    states[good, 0] = last[good]

    constant = None if state_dependent else torque(t0, None, None)

    def derivative(t, y, q_chart, rows, failed):
        """``ẏ (N, 2 nv)`` of the chart states ``y (N, 2 nv)`` around ``q_chart (N, nq)``: of the trajectories
        ``rows`` (indices) by one compiled call, zero for the others. A state the compiled step did not solve
        gets the message of its status in ``failed[row]`` (where ABA alone gave non-finite rates, or the step is not
        compiled, that of :meth:`ConstrainedSystem.forward_dynamics`). The trajectories ``near`` have their stage
        states projected onto the constraints first."""
        close = rows[near[rows]]
        if close.size:
            q_t, v_t = charts.state(q_chart[close], y[close])
            on, errors = by_state(projection(t), (q_t, v_t), (nq + nv + 1,), batched)
            y = y.copy()
            y[close] = charts.coordinates(q_chart[close], on[:, :nq], on[:, nq : nq + nv])
            failed.update({int(close[i]): message for i, message in errors.items()})
        tau = constant
        if state_dependent:
            q_t, v_t = charts.state(q_chart, y)
            tau = torque(t, q_t, v_t)
            if tau is not None:
                # a trajectory whose joint forces are not finite stops at the first stage that meets them
                bad = np.broadcast_to(~np.isfinite(tau).all(axis=-1), (count,))
                for r in rows[bad[rows]]:
                    failed.setdefault(int(r), non_finite_torque(mechanical, t, tau if tau.ndim == 1 else tau[r]))
        whole = rows.size == count
        q_rows, y_rows = (q_chart, y) if whole else (q_chart[rows], y[rows])
        tau_rows = tau if tau is None or tau.ndim == 1 or whole else tau[rows]
        if constrained.compiled_step is None:
            # (a step evaluated in Python: each state by the constrained step below)
            y_dot, failures = np.full_like(y_rows, np.nan), dict.fromkeys(range(len(y_rows)))
        else:
            y_dot, failures = constrained.chart_derivatives(q_rows, y_rows, tau_rows)
        for j, error in failures.items():
            r = rows[j]
            tau_r = tau if tau is None or tau.ndim == 1 else tau[r]
            if r in failed or not (np.isfinite(y_rows[j]).all() and (tau_r is None or np.isfinite(tau_r).all())):
                continue  # its rates stay NaN, and the end of the step stops it
            try:
                if error is not None:
                    raise error
                y_dot[j] = _solved_chart_derivative(constrained, charts, t, q_rows[j], y_rows[j], lambda *_: tau_r)
            except FAILURES as error:
                failed[r] = str(error)
        if whole:
            return y_dot
        full = np.zeros_like(y)
        full[rows] = y_dot
        return full

    def python_step(k, rows):
        """Step ``k`` (from ``times[k − 1]`` to ``times[k]``) of the trajectories ``rows`` from their last states, in
        lockstep; those that fail stop."""
        q_chart = np.ascontiguousarray(last[:, :nq])
        failed = {}
        try:
            y = tableau_step(lambda t, y: derivative(t, y, q_chart, rows, failed),
                             lambda y: charts.chart_rate(y[..., :nv], y[..., nv:]), times[k - 1],
                             charts.to_chart(last), times[k] - times[k - 1], tableau)
        except FAILURES as error:
            if not single:
                raise
            # (one trajectory's joint forces, which raised)
            fail(0, k, str(error))
            return
        end = charts.from_chart(q_chart[rows], y[rows])
        reasons = {rows[j]: f"the state became non-finite at t = {times[k]:.6g} s"
                   for j in np.flatnonzero(~np.isfinite(end).all(axis=-1))}
        reasons.update(failed)
        if project and m:
            # the states that their projection onto the constraints moves by more than the tolerance,
            # projected (as settle does for a step of the adaptive methods)
            at = np.flatnonzero(~np.isin(rows, list(reasons)))
            settled, errors = by_state(projection(times[k]), (end[at, :nq], end[at, nq:]), (nq + nv + 1,), batched)
            near[rows[at]] = _near_singular(settled[:, -1], project, constrained, charts)
            settled = settled[:, :-1]
            off = np.abs(settled - end[at]).max(axis=-1, initial=0.0) > projection_tolerance
            end[at[off]] = settled[off]
            reasons.update({rows[at[i]]: message for i, message in errors.items()})
        ok = ~np.isin(rows, list(reasons))
        last[rows[ok]] = end[ok]
        states[rows[ok], k] = end[ok]
        for r, reason in reasons.items():
            fail(r, k, reason)

    bar = Progress(progress, t0, times[-1])
    recorded = np.full((count, n), np.nan)  # the energies the compiled run records on the way
    try:
        if run is None:
            for k in range(1, n):
                rows = np.flatnonzero(stop == n)
                if not rows.size:
                    break
                python_step(k, rows)
                bar.update(times[k])
        else:
            _run_batch(run, constrained, states, last, stop, near, fail, python_step, times, bar, device,
                       controller, recorded)
    finally:
        bar.close()
    trajectory = _batch_trajectory(constrained, times, q_out, v_out, stop, last, torque, state_dependent, status,
                                   projection_tolerance if project else None, recorded)
    if not single:
        return trajectory
    k, one = int(stop[0]), trajectory.select(0)
    return replace(one, t=one.t[:k].copy(), **{name: getattr(one, name)[:k]
                                               for name in ("q", "v", "lam", "energy", "residual")})


def _run_batch(run, constrained, states, last, stop, near, fail, python_step, times, bar, device=False,
               controller=None, energies=None):
    """The steps of a batch by its compiled ``run`` (:meth:`~multibody.integrators.CompiledRun.advance_batch`), each
    trajectory on its own from its next step, in calls of about :data:`multibody.runs.CHUNK_SECONDS`
    (:func:`multibody.runs.next_chunk`). A step that a trajectory's run leaves to Python (it starts near a singular
    configuration, or a stage or a projection the compiled step did not solve) is taken by ``python_step(k, rows)``
    for the trajectories at that step, which then go on compiled. ``states (N, n, nq + nv)``, ``last (N, nq +
    nv)``, ``stop (N,)``, ``near (N,)`` and the failures (``fail(r, k, reason)``) as :func:`_simulate_batch` keeps
    them; ``constrained``: the system.

    A batch of one runs on this thread (:meth:`~multibody.integrators.CompiledRun.advance`), with its Python
    ``controller`` called once per stage; an error the controller raises stops it at that step.

    ``device``: every trajectory's steps up to the first it leaves to Python run first, in one launch on the GPU
    (:func:`multibody.gpu.advance_batch`, one trajectory per thread); the steps left after that run here.
    ``energies (N, n)``, where given, receives the energies the run recorded on the way
    (:attr:`~multibody.integrators.CompiledRun.energies`), NaN where it did not."""
    count, n = states.shape[:2]
    system = constrained.system
    io = np.zeros((count, run.io.size))
    tail = stepping.io_size(system.nq, system.nv)
    io[:, tail:] = np.nan
    following = np.ones(count, dtype=np.int64)  # each trajectory's next step
    handed = np.zeros(count, dtype=bool)  # whose next step the run left to Python

    def reports(rows):
        """Where the run of the trajectories ``rows`` stopped (their ``io`` rows), and why."""
        if energies is not None:
            energies[rows] = io[rows, tail:]
        following[rows] = io[rows, stepping.IO_STEP]
        last[rows] = states[rows, following[rows] - 1]
        for r in rows:
            status = int(io[r, stepping.IO_STATUS])
            if status == stepping.NEAR_SINGULAR:
                near[r] = True
            elif status in _RUN_FAILURES:
                states[r, following[r]] = np.nan
                fail(r, following[r], str(_RUN_FAILURES[status](system, io[r], run.plan)))
            elif status != stepping.COMPLETED:
                handed[r] = True

    if device:
        rows = np.flatnonzero((stop == n) & ~near)
        io[rows, stepping.IO_STEP], io[rows, stepping.IO_STOP] = 1, n
        gpu.advance_batch(run, states, io, rows)
        reports(rows)
    chunk = FIRST_CHUNK
    while True:
        going = (stop == n) & (following < n)
        rows = np.flatnonzero(going & ~near & ~handed)
        if rows.size:
            io[rows, stepping.IO_STEP] = following[rows]
            io[rows, stepping.IO_STOP] = np.minimum(n, following[rows] + chunk)
            started = time.perf_counter()
            if count == 1:
                try:
                    run.advance(states[0], int(io[0, stepping.IO_STEP]), int(io[0, stepping.IO_STOP]), controller,
                                constrained.checked_tau)
                except FAILURES as error:
                    # (the steps before the stage whose joint forces raised are done)
                    io[0] = run.io
                    if energies is not None:
                        energies[0] = io[0, tail:]
                    following[0] = io[0, stepping.IO_STEP]
                    last[0] = states[0, following[0] - 1]
                    fail(0, int(following[0]), str(error))
                    return
                io[0] = run.io
            else:
                run.advance_batch(states, io, rows)
            chunk = next_chunk(chunk, time.perf_counter() - started)
            reports(rows)
        going = (stop == n) & (following < n)
        bar.update(times[int(following[stop == n].min(initial=n)) - 1])
        waiting = np.flatnonzero(going & (near | handed))
        if not waiting.size:
            if not going.any():
                return
            continue
        # the earliest step left to Python, for all the trajectories at it
        k = int(following[waiting].min())
        at = waiting[following[waiting] == k]
        python_step(k, at)
        following[at] = k + 1
        handed[at] = False


def warn_if_stopped(trajectory, stacklevel):
    """One ``RuntimeWarning`` naming how many of a batch's trajectories stopped early, and why the first did."""
    stopped = np.flatnonzero(~trajectory.completed)
    if stopped.size:
        j = int(stopped[0])
        warnings.warn(f"{stopped.size} of {trajectory.batch_size} trajectories stopped early (trajectory.completed is "
                      f"False for them, trajectory.status says why; their outputs after it are NaN); trajectory {j}: "
                      f"{trajectory.status[j]}", RuntimeWarning, stacklevel=stacklevel)


def _batch_trajectory(constrained, times, q, v, stop, last, torque, state_dependent, status, projection_tolerance,
                      recorded=None):
    """The :class:`Trajectory` of ``N`` trajectories' output states ``q (N, n, nq)``, ``v (N, n, nv)`` at
    ``times (n,)``, each valid before its ``stop``: :func:`_trajectory` for each, the multipliers,
    energies and residuals of all valid states in a few batched calls (NaN elsewhere). ``last (N, nq + nv)``:
    each trajectory's last good state, which the joint forces ``torque`` see in place of a stopped one's NaN.
    ``recorded (N, n)``, where given: the energies a compiled run recorded at those states, NaN where it did not
    (only those are evaluated)."""
    nq, nv, m = constrained.nq, constrained.nv, constrained.num_rows
    count, n = q.shape[:2]
    batched = constrained.batched
    valid = np.arange(n) < stop[:, None]
    lam, energy, residual = np.full((count, n, m), np.nan), np.full((count, n), np.nan), np.full((count, n), np.nan)
    block = max(1, _OUTPUT_BLOCK // max(count, 1))
    for a in range(0, n, block):
        b = min(n, a + block)
        at = valid[:, a:b]
        if not at.any():
            continue
        # the energies the run recorded, and the others evaluated at their states alone
        e = energy[:, a:b]
        if recorded is not None:
            np.copyto(e, recorded[:, a:b], where=at)
        r_e, k_e = np.nonzero(at & np.isnan(e))
        if r_e.size:
            e[r_e, k_e] = by_state(constrained.energy, (q[r_e, a + k_e], v[r_e, a + k_e]), (), batched)[0]
        if not m:
            np.copyto(residual[:, a:b], 0.0, where=at)
            continue
        q_s, v_s = q[:, a:b][at], v[:, a:b][at]
        t_s = np.broadcast_to(times[a:b], at.shape)[at]
        # (every output state is a step's end, projected already where that moved it: RK4 steps once per
        # output interval)
        r_s, _ = by_state(constrained.residual, (q_s, v_s, t_s), (), batched)
        residual[:, a:b][at] = r_s
        if state_dependent:
            # (not called at the times after every trajectory stopped)
            tau = np.stack([_as_rows(torque(times[k], np.where(valid[:, k, None], q[:, k], last[:, :nq]),
                                            np.where(valid[:, k, None], v[:, k], last[:, nq:])), count, nv)
                            if valid[:, k].any() else np.zeros((count, nv)) for k in range(a, b)], axis=1)
        else:
            tau = torque(times[0], None, None)
            tau = tau if tau is None or tau.ndim == 1 else np.broadcast_to(tau[:, None], at.shape + (nv,))
        if tau is None or tau.ndim == 1:
            lam_s, _ = by_state(lambda q_, v_, t_: constrained.solve(q_, v_, tau, t_).lam, (q_s, v_s, t_s), (m,),
                                 batched)
        else:
            lam_s, _ = by_state(lambda q_, v_, t_, tau_: constrained.solve(q_, v_, tau_, t_).lam,
                                 (q_s, v_s, t_s, tau[at]), (m,), batched)
        lam[:, a:b][at] = lam_s
    return Trajectory(t=np.array(times, dtype=float), q=q, v=v, lam=lam, energy=energy, residual=residual,
                      row_names=list(constrained.row_names), status=list(status),
                      projection_tolerance=projection_tolerance, joint_names=recorded_names(constrained))


def _as_rows(tau, count, nv):
    """Joint forces ``None``, ``(nv,)`` or ``(count, nv)`` as ``(count, nv)``."""
    return np.zeros((count, nv)) if tau is None else np.broadcast_to(tau, (count, nv))
