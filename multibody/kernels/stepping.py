"""Fixed-step runs of the equations of motion: every step of a trajectory in one compiled call.

A run integrates ``y = [δ, w]`` in the chart around each step's first configuration (as
:func:`multibody.simulate` does, :mod:`multibody.kernels.integration`) with an explicit partitioned
Runge–Kutta method given by its coefficients (E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical
Integration*, 2nd ed., Springer 2006, §II.2.2): with ``K_j = [δ̇_j, ẇ_j]`` the rates of stage ``j``,

    δ_i = δ₀ + h Σ_j a^δ_ij δ̇_j,     w_i = w₀ + h Σ_j a^w_ij ẇ_j,     t_i = t₀ + c_i h
    δ⁺ = δ₀ + h Σ_i b^δ_i δ̇_i,        w⁺ = w₀ + h Σ_i b^w_i ẇ_i

(one table ``a`` for both halves: a Runge–Kutta method; explicit Euler, the classical RK4, and the
semi-implicit Euler method of two stages, ``w⁺ = w₀ + h ẇ(q₀, w₀)``, ``δ⁺ = h w⁺``). A stage whose ``ẇ``
no coefficient uses evaluates only ``δ̇``. At each step's end the state leaves the chart
(``q = chart(q₀, δ⁺)``, ``v = T(q)ᵀ w⁺``) and, with constraints, is projected onto them when that moves a
coordinate by more than the tolerance (:func:`multibody.kernels.kkt.project`).

The joint forces of a stage come from the controller of the plan: none, constant, the joint-space PD law
of :func:`pd_torque`, a compiled function ``f(t, q, v, out)``, or Python (the run returns with
:data:`NEED_TORQUE` and the stage's ``t, q, v``, and goes on from there when called again with ``τ``),
less viscous joint damping ``D v`` when the plan has it.

A run stops before a step it cannot take as :func:`multibody.simulate`'s Python loop would, with a status
(:data:`NEAR_SINGULAR`, :data:`STAGE_UNSOLVED`, ...): the loop then takes that step itself. :func:`run` is
the entry point of one trajectory whose controller is not a compiled function; :func:`advance` itself, as a
first-class function, serves :mod:`multibody.integrators`' loop over many trajectories on all cores (which
allocates their workspaces, and so lives outside the kernels). :func:`chart_state` and :func:`aligned_velocity`
are a run's chart maps as kernels, by which the Python loop takes its states.
"""

from __future__ import annotations

from .layout import IQ, IV, KIND, NV
from . import aba, configuration, integration, kkt
from . import joints as kinds
from .jit import njit
from .spatial import all_finite, nan_unless_finite

# ----------------------------------------------------------------------------- layouts

#: The plan's header (one float each): sizes, the kind of run, the controller, the projection rule and
#: the offsets of the blocks that follow.
(PLAN_NQ, PLAN_NV, PLAN_CHARTS, PLAN_STAGES, PLAN_CONTROL, PLAN_PROJECT, PLAN_PROJECTION_TOLERANCE, PLAN_NEAR_SINGULAR,
 PLAN_DAMPED, PLAN_TABLEAU, PLAN_DAMPING, PLAN_SETTINGS, PLAN_STEP_COLUMNS, PLAN_STEP_WORKSPACE,
 PLAN_PROJECTION_COLUMNS, PLAN_PROJECTION_WORKSPACE) = range(16)
PLAN_HEADER = 16

#: Controllers: no joint forces, constant ones (the control row's first ``nv``), the PD law of the control
#: row (:func:`pd_torque`), a compiled function, joint forces from Python.
NO_CONTROL, CONSTANT, PD, FUNCTION, PYTHON = range(5)

#: The entries of a run's ``io`` vector: the next step (in and out), the step to stop before, the status
#: (out), the stage that waits for joint forces and whether they are given (in and out), the time of what
#: the status reports (s), a value it reports, then ``q (nq)``, ``v (nv)`` and ``τ (nv)``.
IO_STEP, IO_STOP, IO_STATUS, IO_STAGE, IO_TORQUE_GIVEN, IO_TIME, IO_VALUE = range(7)
IO_HEADER = 7

#: Status of a run: it reached the step to stop before; it waits for the joint forces of a stage (``t``,
#: ``q``, ``v`` in ``io``); the state it stopped after has rows near a singular configuration, so the next
#: step evaluates its stages on the constraints; a stage the compiled step did not solve (a singular ``M``,
#: inconsistent rows, non-finite rates); a projection the compiled step did not solve; a non-finite state
#: at a step's end (``IO_TIME``); non-finite joint forces of the controller (``IO_TIME``, and ``τ`` in
#: ``io``); a projection whose positions did not converge (``|φ|`` in ``IO_VALUE``).
(COMPLETED, NEED_TORQUE, NEAR_SINGULAR, STAGE_UNSOLVED, PROJECTION_UNSOLVED, NON_FINITE_STATE, NON_FINITE_TORQUE,
 NOT_CONVERGED) = range(8)


def io_size(nq, nv):
    """Floats of a run's ``io`` vector."""
    return IO_HEADER + nq + 2 * nv


def workspace_size(nq, nv, stages, step_columns, step_workspace, projection_columns, projection_workspace):
    """Floats of a run's workspace: ``y₀``, the stages' rates, a stage state, the end state, the chart maps'
    ``q, v, κ, T``, a stage's rates, joint forces, the PD law's scratch, the step's and the projection's
    outputs and workspaces."""
    return (2 * nv * (stages + 3) + (nq + 2 * nv + nv * nv) + (2 * nv + 1) + nv + (nq + nv) + step_columns
            + step_workspace + projection_columns + projection_workspace)


# ----------------------------------------------------------------------------- the PD law

@njit(cache=True, error_model="numpy")
def interval(times, n, t):
    """``(i, s)``: the row ``i`` of a table sampled at ``times (n,)`` (strictly increasing) before ``t`` and the
    fraction ``s ∈ [0, 1)`` of the way to the next; the first row before the table, the last after it."""
    if n == 1 or t <= times[0]:
        return 0, 0.0
    if t >= times[n - 1]:
        return n - 1, 0.0
    low, high = 0, n - 1
    while high - low > 1:
        middle = (low + high) // 2
        if times[middle] <= t:
            low = middle
        else:
            high = middle
    return low, (t - times[low]) / (times[low + 1] - times[low])


@njit(cache=True, error_model="numpy")
def pd_torque(joints, t, q, v, pd, tau, scratch):
    """The joint-space PD law into ``tau (nv,)`` at time ``t`` (s) and state ``q (nq,)``, ``v (nv,)``:

        τ = k_p ⊙ (q_ref(t) ⊖ q) + k_d ⊙ (v_ref(t) − v) + τ_ff

    with ``q_ref ⊖ q`` the configuration logarithm (:func:`multibody.kernels.joints.difference`: the velocity
    that moves ``q`` to ``q_ref`` in unit time, tangent space). ``pd = [k_p (nv) | k_d (nv) | τ_ff (nv) | n |
    t_ref (n) | q_ref (n, nq) | v_ref (n, nv)]``: between the table's times ``q_ref`` moves along
    ``q_i ⊕ s (q_{i+1} ⊖ q_i)`` (linear for angles and displacements) and ``v_ref`` linearly; before the first
    time and after the last the end rows hold. ``scratch (nq + nv)``."""
    nq, nv = q.shape[0], v.shape[0]
    n = int(pd[3 * nv])
    start = 3 * nv + 1
    times = pd[start : start + n]
    Q = pd[start + n : start + n + n * nq]
    V = pd[start + n + n * nq : start + n + n * (nq + nv)]
    i, s = interval(times, n, t)
    reference, error = scratch[:nq], scratch[nq : nq + nv]
    row = Q[i * nq : (i + 1) * nq]
    if s == 0.0:
        for c in range(nq):
            reference[c] = row[c]
    else:
        # q_ref = q_i ⊕ s (q_{i+1} ⊖ q_i)
        following = Q[(i + 1) * nq : (i + 2) * nq]
        for j in range(joints.shape[0]):
            kinds.difference(joints[j, KIND], joints[j, NV], row, following, joints[j, IQ], joints[j, IV], error)
        for c in range(nv):
            error[c] *= s
        for j in range(joints.shape[0]):
            kinds.integrate(joints[j, KIND], joints[j, NV], row, error, joints[j, IQ], joints[j, IV], reference)
    # q_ref ⊖ q
    for j in range(joints.shape[0]):
        kinds.difference(joints[j, KIND], joints[j, NV], q, reference, joints[j, IQ], joints[j, IV], error)
    for c in range(nv):
        v_ref = V[i * nv + c]
        if s != 0.0:
            v_ref += s * (V[(i + 1) * nv + c] - V[i * nv + c])
        tau[c] = pd[c] * error[c] + pd[nv + c] * (v_ref - v[c]) + pd[2 * nv + c]


@njit(cache=True, error_model="numpy")
def pd_kernel(joints, reals, frames, q, v, pd, t, out, ws):
    """:func:`pd_torque` as a kernel of :mod:`multibody.driver`: ``τ`` into ``out[0] (nv,)`` at ``t = t[0]``
    (s); ``ws (nq + nv)``. ``reals`` and ``frames`` are unused."""
    pd_torque(joints, t[0], q, v, pd, out[0], ws)


@njit(cache=True, error_model="numpy")
def no_controller(t, q, v, out):
    """The compiled controller of a plan without one (never called)."""


# ----------------------------------------------------------------------------- one run

@njit(cache=True, error_model="numpy")
def weighted_sum(y0, h, weights, K, start, stop, out):
    """``out[c] = y₀[c] + h Σ_j weights_j K[j, c]`` for ``start ≤ c < stop`` (``out`` not ``y0``), the terms of
    non-zero weight summed in the order of the stages (as :func:`multibody.integrators.tableau_step` sums them);
    ``y₀[c]`` itself where every weight is zero."""
    first = True
    for j in range(weights.shape[0]):
        weight = weights[j]
        if weight == 0.0:
            continue
        if first:
            for c in range(start, stop):
                out[c] = weight * K[j, c]
            first = False
        else:
            for c in range(start, stop):
                out[c] += weight * K[j, c]
    if first:
        for c in range(start, stop):
            out[c] = y0[c]
    else:
        for c in range(start, stop):
            out[c] = y0[c] + h * out[c]


@njit(cache=True, error_model="numpy")
def aligned(joints, reals, frames, q, v, T, w):
    """``w = T(q) v (nv,)``: the velocity ``v (nv,)`` at ``q (nq,)`` in the chart's aligned axes
    (:func:`multibody.kernels.configuration.velocity_alignment`, into ``T (nv, nv)``)."""
    none = v[:0]
    configuration.velocity_alignment(joints, reals, frames, q, none, none, none, T, none)
    nv = v.shape[0]
    for r in range(nv):
        total = 0.0
        for c in range(nv):
            total += T[r, c] * v[c]
        w[r] = total


@njit(cache=True, error_model="numpy")
def aligned_velocity(joints, reals, frames, q, v, x2, x3, out, ws):
    """The kernel of :func:`aligned`: ``w = T(q) v`` into ``out[0] (nv,)``, ``ws (nv²)``; the map from a state to
    its chart state ``y = [0, w]`` that a run makes at each step's start."""
    nv = v.shape[0]
    aligned(joints, reals, frames, q, v, ws[: nv * nv].reshape((nv, nv)), out[0])
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def chart_state(joints, reals, frames, q_chart, y, x2, x3, out, ws):
    """The state ``[q, v]`` into ``out[0] (nq + nv,)`` of the chart state ``y = [δ, w] (2 nv,)`` around ``q_chart
    (nq,)``: ``q = chart(q_c, δ)``, ``v = T(q)ᵀ w`` (:func:`multibody.kernels.integration.unchart`, as a run
    leaves the chart at each step's end); ``ws`` as :func:`multibody.kernels.integration.workspace_size` holds
    before its step."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    integration.unchart(joints, reals, frames, q_chart, y, ws)
    row = out[0]
    for c in range(nq + nv):
        row[c] = ws[c]
    nan_unless_finite(q_chart, y, x2, x3, out)


@njit(cache=True, error_model="numpy")
def stage_state(joints, reals, frames, charts, q_chart, y, maps):
    """The state of a stage's chart state ``y = [δ, w] (2 nv,)`` around ``q_chart (nq,)`` into ``maps`` (``q``, ``v``,
    ``κ``, ``T``: :func:`multibody.kernels.integration.unchart`): ``q = chart(q₀, δ)``, ``v = Tᵀ w``, or without
    ``charts`` ``q = q₀ + δ``, ``v = w``."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    if charts:
        integration.unchart(joints, reals, frames, q_chart, y, maps)
    else:
        for c in range(nq):
            maps[c] = q_chart[c] + y[c]
        for c in range(nv):
            maps[nq + c] = y[nv + c]


@njit(cache=True, error_model="numpy")
def stage_torque(controller, joints, kind, control, t, q, v, tau, scratch):
    """The joint forces ``τ (nv,)`` of the controller ``kind`` (not :data:`PYTHON`) at ``t`` (s), ``q``, ``v``: none,
    the constant ``control[:nv]``, the PD law of ``control[nv:]`` (:func:`pd_torque`, ``scratch (nq + nv)``) or the
    compiled ``controller(t, q, v, τ)``. Returns whether they are finite."""
    nv = v.shape[0]
    if kind == CONSTANT:
        for c in range(nv):
            tau[c] = control[c]
    elif kind == PD:
        pd_torque(joints, t, q, v, control[nv:], tau, scratch)
    elif kind == FUNCTION and controller is not None:
        for c in range(nv):
            tau[c] = 0.0
        controller(t, q, v, tau)
    else:
        for c in range(nv):
            tau[c] = 0.0
    return kind == NO_CONTROL or kind == CONSTANT or all_finite(tau)


@njit(cache=True, error_model="numpy")
def stage_rates(joints, reals, frames, program, charts, damped, damping, y, maps, tau, step, step_ws, rates, K_i):
    """A stage's rates ``K_i = [δ̇, ẇ] (2 nv,)`` at the state :func:`stage_state` put in ``maps``, with joint forces
    ``τ`` (less ``D v`` when ``damped``): the accelerations ``a`` by :func:`multibody.kernels.kkt.constrained_accelerations`
    (``program`` of constraints) or ABA, then ``ẇ = T (a + κ)``, ``δ̇ = chart_rate(δ, w)``
    (:func:`multibody.kernels.integration.chart_rates`), or without ``charts`` ``[w, a]``. Returns whether the step
    solved and the rates are finite."""
    nv = y.shape[0] // 2
    nq = maps.shape[0] - 2 * nv - nv * nv
    q, v = maps[:nq], maps[nq : nq + nv]
    if damped:
        # − D v
        for c in range(nv):
            tau[c] = tau[c] - damping[c] * v[c]
    step_columns = step.shape[1]
    if program.shape[0] > 0:
        kkt.constrained_accelerations(joints, reals, frames, q, v, tau, program, step, step_ws)
        status = step[0, step_columns - 1]
    else:
        aba.forward_dynamics(joints, reals, frames, q, v, tau, program, step, step_ws)
        status = 0.0
    if charts:
        T = maps[nq + 2 * nv :].reshape((nv, nv))
        kappa = maps[nq + nv : nq + 2 * nv].reshape((1, nv))
        integration.chart_rates(joints, reals, frames, y, v, kappa, T, step[0, :nv], status, rates)
        for c in range(2 * nv):
            K_i[c] = rates[0, c]
    else:
        for c in range(nv):
            K_i[c] = y[nv + c]
            K_i[nv + c] = step[0, c]
    return status == kkt.SOLVED and all_finite(K_i)


@njit(cache=True, error_model="numpy")
def settle(joints, reals, frames, program, settings, tolerance, near_singular, nq, end, projected, projection_ws, io):
    """The state ``end = [q, v] (nq + nv,)`` of a step's end projected onto the constraints
    (:func:`multibody.kernels.kkt.project`, ``settings``) when that moves a coordinate by more than ``tolerance``, in
    place. Returns ``(status, near)``: :data:`COMPLETED`, :data:`NOT_CONVERGED` (``|φ|`` in ``io[IO_VALUE]``) or
    :data:`PROJECTION_UNSOLVED`; and whether the rows' conditioning there is below ``near_singular``."""
    size = end.shape[0]
    columns = projected.shape[1]
    kkt.project(joints, reals, frames, end[:nq], end[nq:], settings, program, projected, projection_ws)
    status = projected[0, columns - 1]
    if status == kkt.NOT_CONVERGED:
        io[IO_VALUE] = projected[0, columns - 2]
        return NOT_CONVERGED, False
    if status != kkt.SOLVED:
        return PROJECTION_UNSOLVED, False
    moved = 0.0
    for c in range(size):
        moved = max(moved, abs(projected[0, c] - end[c]))
    if moved > tolerance:
        for c in range(size):
            end[c] = projected[0, c]
    return COMPLETED, projected[0, columns - 3] < near_singular


@njit(cache=True, error_model="numpy")
def advance(controller, joints, reals, frames, program, times, plan, control, states, io, ws):
    """Steps ``io[IO_STEP]`` up to ``io[IO_STOP]`` (exclusive) of one trajectory: ``states (n, nq + nv)`` holds
    ``[q, v]`` at ``times (n,)``, each step ``k`` from ``states[k − 1]`` into ``states[k]``. Returns with the
    status in ``io`` (module docstring) and ``io[IO_STEP]`` the first step not taken.

    The accelerations come from :func:`multibody.kernels.aba.forward_dynamics` without constraints (``program`` of
    length 0), else from :func:`multibody.kernels.kkt.constrained_accelerations`; ``controller(t, q, v, out)`` is
    the plan's ``FUNCTION`` controller (``None`` where the plan has another, whose code is then left out). ``plan``:
    the run's header and blocks (:data:`PLAN_HEADER`); ``control``: ``[τ (nv) | PD block]``; ``ws``:
    :func:`workspace_size`, kept between the calls of a Python controller's run."""
    nq, nv = int(plan[PLAN_NQ]), int(plan[PLAN_NV])
    charts = plan[PLAN_CHARTS] != 0.0
    s = int(plan[PLAN_STAGES])
    kind = int(plan[PLAN_CONTROL])
    project = plan[PLAN_PROJECT] != 0.0
    tolerance, near_singular = plan[PLAN_PROJECTION_TOLERANCE], plan[PLAN_NEAR_SINGULAR]
    damped = plan[PLAN_DAMPED] != 0.0
    start = int(plan[PLAN_TABLEAU])
    c_nodes = plan[start : start + s]
    a_delta = plan[start + s : start + s + s * s].reshape((s, s))
    a_w = plan[start + s + s * s : start + s + 2 * s * s].reshape((s, s))
    b_delta = plan[start + s + 2 * s * s : start + 2 * s + 2 * s * s]
    b_w = plan[start + 2 * s + 2 * s * s : start + 3 * s + 2 * s * s]
    accelerations = plan[start + 3 * s + 2 * s * s : start + 4 * s + 2 * s * s]
    damping = plan[int(plan[PLAN_DAMPING]) : int(plan[PLAN_DAMPING]) + nv]
    m = int(program[1]) if program.shape[0] > 0 else 0
    settings = plan[int(plan[PLAN_SETTINGS]) : int(plan[PLAN_SETTINGS]) + 2 + m]
    step_columns, step_size = int(plan[PLAN_STEP_COLUMNS]), int(plan[PLAN_STEP_WORKSPACE])
    projection_columns, projection_size = int(plan[PLAN_PROJECTION_COLUMNS]), int(plan[PLAN_PROJECTION_WORKSPACE])
    none = plan[:0]
    # workspace
    at = 0
    y0 = ws[at : at + 2 * nv]
    at += 2 * nv
    K = ws[at : at + s * 2 * nv].reshape((s, 2 * nv))
    at += s * 2 * nv
    y = ws[at : at + 2 * nv]
    at += 2 * nv
    y_end = ws[at : at + 2 * nv]
    at += 2 * nv
    maps = ws[at : at + nq + 2 * nv + nv * nv]
    at += nq + 2 * nv + nv * nv
    rates = ws[at : at + 2 * nv + 1].reshape((1, 2 * nv + 1))
    at += 2 * nv + 1
    tau = ws[at : at + nv]
    at += nv
    scratch = ws[at : at + nq + nv]
    at += nq + nv
    step = ws[at : at + step_columns].reshape((1, step_columns))
    at += step_columns
    step_ws = ws[at : at + step_size]
    at += step_size
    projected = ws[at : at + projection_columns].reshape((1, projection_columns))
    at += projection_columns
    projection_ws = ws[at : at + projection_size]
    # the stage state's q and v (views of the chart maps' block, which unchart fills in the same layout)
    q = maps[:nq]
    v = maps[nq : nq + nv]
    io_q, io_v, io_tau = io[IO_HEADER : IO_HEADER + nq], io[IO_HEADER + nq : IO_HEADER + nq + nv], \
        io[IO_HEADER + nq + nv : IO_HEADER + nq + 2 * nv]

    k, stop = int(io[IO_STEP]), int(io[IO_STOP])
    first_stage = int(io[IO_STAGE])
    given = io[IO_TORQUE_GIVEN] != 0.0
    io[IO_TORQUE_GIVEN] = 0.0
    while k < stop:
        t0 = times[k - 1]
        h = times[k] - t0
        q_chart = states[k - 1, :nq]
        if first_stage == 0 and not given:
            # y₀ = [0, T(q₀) v₀]
            for c in range(nv):
                y0[c] = 0.0
            if charts:
                aligned(joints, reals, frames, q_chart, states[k - 1, nq:], maps[nq + 2 * nv :].reshape((nv, nv)),
                        y0[nv:])
            else:
                for c in range(nv):
                    y0[nv + c] = states[k - 1, nq + c]
        for i in range(first_stage, s):
            t = t0 + c_nodes[i] * h
            resumed = given and i == first_stage
            if not resumed:
                # y_i = y₀ + h Σ_j a_ij K_j, positions and velocities by their own coefficients
                weighted_sum(y0, h, a_delta[i, :i], K, 0, nv, y)
                weighted_sum(y0, h, a_w[i, :i], K, nv, 2 * nv, y)
            if accelerations[i] == 0.0:
                # δ̇ alone: chart_rate(δ_i, w_i)
                if charts:
                    configuration.chart_rate(joints, reals, frames, y[:nv], y[nv:], none, none, rates, none)
                    for c in range(nv):
                        K[i, c] = rates[0, c]
                else:
                    for c in range(nv):
                        K[i, c] = y[nv + c]
                for c in range(nv):
                    K[i, nv + c] = 0.0
                continue
            if not resumed:
                if not all_finite(y):
                    io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, STAGE_UNSOLVED
                    return
                stage_state(joints, reals, frames, charts, q_chart, y, maps)
            # the joint forces
            if kind == PYTHON:
                if not resumed:
                    io[IO_TIME] = t
                    for c in range(nq):
                        io_q[c] = q[c]
                    for c in range(nv):
                        io_v[c] = v[c]
                    io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, i, NEED_TORQUE
                    return
                for c in range(nv):
                    tau[c] = io_tau[c]
            elif not stage_torque(controller, joints, kind, control, t, q, v, tau, scratch):
                io[IO_TIME] = t
                for c in range(nv):
                    io_tau[c] = tau[c]
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NON_FINITE_TORQUE
                return
            if not stage_rates(joints, reals, frames, program, charts, damped, damping, y, maps, tau, step, step_ws,
                               rates, K[i]):
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, STAGE_UNSOLVED
                return
        first_stage, given = 0, False
        # y⁺ = y₀ + h Σ_i b_i K_i, and the state [q, v] it stands for
        weighted_sum(y0, h, b_delta, K, 0, nv, y_end)
        weighted_sum(y0, h, b_w, K, nv, 2 * nv, y_end)
        end = states[k]
        stage_state(joints, reals, frames, charts, q_chart, y_end, maps)
        for c in range(nq + nv):
            end[c] = maps[c]
        if not all_finite(end):
            io[IO_TIME] = times[k]
            io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NON_FINITE_STATE
            return
        near = False
        if project:
            status, near = settle(joints, reals, frames, program, settings, tolerance, near_singular, nq, end,
                                  projected, projection_ws, io)
            if status != COMPLETED:
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, status
                return
        k += 1
        if near:
            io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NEAR_SINGULAR
            return
    io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, COMPLETED


# ----------------------------------------------------------------------------- entry points

@njit(cache=True, error_model="numpy")
def run(joints, reals, frames, program, times, plan, control, states, io, ws):
    """:func:`advance` of one trajectory whose controller is none, constant, PD or Python."""
    advance(None, joints, reals, frames, program, times, plan, control, states, io, ws)


@njit(cache=True, error_model="numpy")
def controller_rows(controller, t, q, v, out):
    """``controller(t, q[r], v[r], out[r])`` for every row ``r`` of ``q (N, nq)``, ``v (N, nv)``, ``out (N, nv)``
    (zeroed first): a compiled controller on a batch of states."""
    for r in range(q.shape[0]):
        for c in range(out.shape[1]):
            out[r, c] = 0.0
        controller(t, q[r], v[r], out[r])
