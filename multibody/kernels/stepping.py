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

An adaptive run (:func:`adaptive`) takes the steps of an embedded pair with step-size control and dense output by the
same stages and projection, to the end of the run in one call; it runs as Python too (``adaptive.py_func``), with
the system's maps from Python, for the systems and steps its compiled form does not take.
"""

from __future__ import annotations

import numpy as np

from .layout import IQ, IV, KIND, NV
from . import aba, configuration, integration, kkt
from . import joints as kinds
from .jit import njit
from .spatial import all_finite, larger, nan_unless_finite, smaller

# ----------------------------------------------------------------------------- layouts

#: The plan's header (one float each): sizes, the kind of run, the controller, the projection rule and
#: the offsets of the blocks that follow.
(PLAN_NQ, PLAN_NV, PLAN_CHARTS, PLAN_STAGES, PLAN_CONTROL, PLAN_PROJECT, PLAN_PROJECTION_TOLERANCE, PLAN_NEAR_SINGULAR,
 PLAN_DAMPED, PLAN_TABLEAU, PLAN_DAMPING, PLAN_SETTINGS, PLAN_STEP_COLUMNS, PLAN_STEP_WORKSPACE,
 PLAN_PROJECTION_COLUMNS, PLAN_PROJECTION_WORKSPACE) = range(16)
#: An adaptive run's header goes on (:func:`adaptive`): whether the configuration space is curved (a new chart at
#: every step's end), the tolerances ``rtol``, ``atol``, the longest step (s), the largest turn of a rotation vector
#: in a step (rad), and the offset and count of the rotation vectors' first indices in ``v``.
(PLAN_CURVED, PLAN_RTOL, PLAN_ATOL, PLAN_MAX_STEP, PLAN_CHART_TURN, PLAN_ROTATIONS, PLAN_ROTATION_COUNT) = range(16, 23)
#: Whether a fixed-step run records the energy of each step's start in ``io`` (:func:`advance`).
PLAN_ENERGY = 23
PLAN_HEADER = 24

#: Controllers: no joint forces, constant ones (the control row's first ``nv``), the PD law of the control
#: row (:func:`pd_torque`), a compiled function, joint forces from Python.
NO_CONTROL, CONSTANT, PD, FUNCTION, PYTHON = range(5)

#: The entries of a run's ``io`` vector: the next step (in and out), the step to stop before, the status
#: (out), the stage that waits for joint forces and whether they are given (in and out), the time of what
#: the status reports (s), a value it reports, then ``q (nq)``, ``v (nv)`` and ``τ (nv)``, and after them, where
#: the plan asks for it (:data:`PLAN_ENERGY`), the energy (J) of each output state (n) the run took a step from.
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
#: Status of an adaptive run: the step size fell below ten roundings of the time (``IO_TIME``); the last
#: :data:`STALLED_STEPS` steps advanced less than :data:`STALLED_SPAN` of the run (``IO_TIME`` the last one's end,
#: ``IO_VALUE`` how far they went); a run with Python stages handed the next step back to the compiled run.
STEP_TOO_SMALL, STALLED, HANDED_BACK = range(8, 11)

#: An adaptive run has stalled when its last ``STALLED_STEPS`` steps together advance the time by less than
#: ``STALLED_SPAN`` of the whole run: at that pace the run would take a billion steps.
STALLED_STEPS, STALLED_SPAN = 1000, 1e-6

#: The step-size controller of the adaptive run (HNW §II.4, eq. (4.13)): ``h_new = h min(MAX_FACTOR, max(MIN_FACTOR,
#: SAFETY err^(−1/(q+1))))``, with SciPy's factors, so that runs stay comparable with ``scipy.integrate.solve_ivp``.
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0


def io_size(nq, nv, n=0):
    """Floats of a run's ``io`` vector, with room for the energies of ``n`` output states."""
    return IO_HEADER + nq + 2 * nv + n


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
def manifold_error(joints, pd, at, s, q, scratch):
    """``q_ref ⊖ q`` into ``scratch[nq:] (nv,)`` for :func:`pd_torque` on a configuration space with rotations:
    ``q_ref = q_i ⊕ s (q_{i+1} ⊖ q_i)`` with ``q_i`` the table row at ``pd[at:]`` (``q_ref`` itself into
    ``scratch[:nq]``), by the joints' maps (:func:`multibody.kernels.joints.difference`, ``integrate``)."""
    nq, nv = q.shape[0], scratch.shape[0] - q.shape[0]
    row, following = pd[at : at + nq], pd[at + nq : at + 2 * nq]
    reference, error = scratch[:nq], scratch[nq:]
    if s == 0.0:
        for c in range(nq):
            reference[c] = row[c]
    else:
        # q_ref = q_i ⊕ s (q_{i+1} ⊖ q_i)
        for j in range(joints.shape[0]):
            kinds.difference(joints[j, KIND], joints[j, NV], row, following, joints[j, IQ], joints[j, IV], error)
        for c in range(nv):
            error[c] *= s
        for j in range(joints.shape[0]):
            kinds.integrate(joints[j, KIND], joints[j, NV], row, error, joints[j, IQ], joints[j, IV], reference)
    # q_ref ⊖ q
    for j in range(joints.shape[0]):
        kinds.difference(joints[j, KIND], joints[j, NV], q, reference, joints[j, IQ], joints[j, IV], error)


@njit(cache=True, error_model="numpy", inline="always")
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
    i, s = interval(pd[start : start + n], n, t)
    # the rows i of q_ref and v_ref (the next rows follow them)
    at_q, at_v = start + n + i * nq, start + n + n * nq + i * nv
    error = scratch[nq : nq + nv]
    if nq == nv:
        # angles and displacements alone (every rotation joint has more coordinates than velocities), where ⊕ and
        # ⊖ add and subtract: q_ref ⊖ q = q_i + (q_{i+1} − q_i) s − q, read in place
        for c in range(nv):
            reference = pd[at_q + c]
            if s != 0.0:
                reference += (pd[at_q + nq + c] - pd[at_q + c]) * s
            error[c] = reference - q[c]
    else:
        manifold_error(joints, pd, at_q, s, q, scratch[: nq + nv])
    for c in range(nv):
        v_ref = pd[at_v + c]
        if s != 0.0:
            v_ref += s * (pd[at_v + nv + c] - pd[at_v + c])
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

@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def stage_rates(joints, reals, frames, program, charts, damped, damping, y, maps, tau, step, step_ws, rates, K_i,
                energy):
    """A stage's rates ``K_i = [δ̇, ẇ] (2 nv,)`` at the state :func:`stage_state` put in ``maps``, with joint forces
    ``τ`` (less ``D v`` when ``damped``): the accelerations ``a`` by :func:`multibody.kernels.kkt.constrained_accelerations`
    (``program`` of constraints) or ABA, then ``ẇ = T (a + κ)``, ``δ̇ = chart_rate(δ, w)``
    (:func:`multibody.kernels.integration.chart_rates`), or without ``charts`` ``[w, a]``. ``energy`` of length 1 (ABA
    only) receives the state's mechanical energy (J), which ABA's pass down the tree gives on the way; of length 0,
    nothing. Returns whether the step solved and the rates are finite."""
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
        # (aba.forward_dynamics, with the energy where asked for)
        recorded = energy.shape[0] > 0
        aba.articulated_body(joints, reals, q, v, tau, program, step[0], step_ws, recorded)
        nan_unless_finite(q, v, tau, program, step)
        if recorded:
            energy[0] = aba.recorded_energy(step_ws, joints.shape[0])
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
    place. Returns ``(status, near, projected)``: :data:`COMPLETED`, :data:`NOT_CONVERGED` (``|φ|`` in
    ``io[IO_VALUE]``) or :data:`PROJECTION_UNSOLVED`; whether the rows' conditioning there is below
    ``near_singular``; and whether the state moved."""
    size = end.shape[0]
    columns = projected.shape[1]
    kkt.project(joints, reals, frames, end[:nq], end[nq:], settings, program, projected, projection_ws)
    status = projected[0, columns - 1]
    if status == kkt.NOT_CONVERGED:
        io[IO_VALUE] = projected[0, columns - 2]
        return NOT_CONVERGED, False, False
    if status != kkt.SOLVED:
        return PROJECTION_UNSOLVED, False, False
    moved = 0.0
    for c in range(size):
        moved = larger(moved, abs(projected[0, c] - end[c]))
    if moved > tolerance:
        for c in range(size):
            end[c] = projected[0, c]
    return COMPLETED, projected[0, columns - 3] < near_singular, moved > tolerance


@njit(cache=True, error_model="numpy", inline="always")
def vector_space_steps(controller, joints, reals, times, s, kind, control, damped, damping, c_nodes, a_delta, a_w,
                       b_delta, b_w, accelerations, states, io, K, y, tau, scratch, step_ws, energies, recorded):
    """:func:`advance`'s steps on a vector space without constraints (``nq = nv``, no chart: ``q = q₀ + δ``,
    ``v = w``, each stage's rates ``K_i = [v_i, a_i]`` by ABA alone) with a controller that is not Python: the same
    stages, written straight into a stage state ``[q_i, v_i]`` (``states[k − 1]`` holds ``[q₀, v₀]``),

        q_i = q₀ + h Σ_j a^δ_ij v_j,     v_i = v₀ + h Σ_j a^w_ij a_j,     a_i = ABA(q_i, v_i, τ(t_i, q_i, v_i) − D v_i)

    and ``[q⁺, v⁺]`` into ``states[k]`` by the weights ``b``: the arithmetic of the chart state (``δ₀ = 0``), without
    its copies. ABA writes ``a_i`` into ``K_i``; ``y (2 nv)`` holds the stage state, ``scratch`` the PD law's. The
    status is :func:`advance`'s. Where ``recorded``, the energy (J) of each state a step starts from goes into
    ``energies``, and that of the last output state too, once the run reaches it."""
    nv = K.shape[1] // 2
    k, stop = int(io[IO_STEP]), int(io[IO_STOP])
    none = K[0, :0]
    while k < stop:
        t0 = times[k - 1]
        h = times[k] - t0
        start = states[k - 1]
        q, v = y[:nv], y[nv:]
        for i in range(s):
            t = t0 + c_nodes[i] * h
            # v_i = v₀ + h Σ_j a^w_ij a_j
            weighted_sum(start, h, a_w[i, :i], K, nv, 2 * nv, y)
            if accelerations[i] == 0.0:
                # v_i alone
                for c in range(nv):
                    K[i, c] = v[c]
                    K[i, nv + c] = 0.0
                continue
            # q_i = q₀ + h Σ_j a^δ_ij v_j
            weighted_sum(start, h, a_delta[i, :i], K, 0, nv, y)
            if not all_finite(y):
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, STAGE_UNSOLVED
                return
            if not stage_torque(controller, joints, kind, control, t, q, v, tau, scratch):
                io[IO_TIME] = t
                for c in range(nv):
                    io[IO_HEADER + 2 * nv + c] = tau[c]
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NON_FINITE_TORQUE
                return
            if damped:
                # − D v
                for c in range(nv):
                    tau[c] = tau[c] - damping[c] * v[c]
            # a_i, and the energy of the step's start from its first stage's ABA at exactly that state
            energy = recorded and i == 0
            a = K[i, nv:]
            aba.articulated_body(joints, reals, q, v, tau, none, a, step_ws, energy)
            if energy:
                energies[k - 1] = aba.recorded_energy(step_ws, joints.shape[0])
            for c in range(nv):
                K[i, c] = v[c]
            if not all_finite(a):
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, STAGE_UNSOLVED
                return
        # [q⁺, v⁺] = [q₀, v₀] + h Σ_i [b^δ_i v_i, b^w_i a_i]
        end = states[k]
        weighted_sum(start, h, b_delta, K, 0, nv, end)
        weighted_sum(start, h, b_w, K, nv, 2 * nv, end)
        if not all_finite(end):
            io[IO_TIME] = times[k]
            io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NON_FINITE_STATE
            return
        k += 1
    if recorded and k == times.shape[0]:
        # the energy of the last output state, from which no step starts: ABA's pass down the tree at it
        last = states[k - 1]
        aba.articulated_body(joints, reals, last[:nv], last[nv:], none, none, K[0, nv:], step_ws, True)
        energies[k - 1] = aba.recorded_energy(step_ws, joints.shape[0])
    io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, COMPLETED


@njit(cache=True, error_model="numpy")
def advance(controller, joints, reals, frames, program, times, plan, control, states, io, ws):
    """Steps ``io[IO_STEP]`` up to ``io[IO_STOP]`` (exclusive) of one trajectory: ``states (n, nq + nv)`` holds
    ``[q, v]`` at ``times (n,)``, each step ``k`` from ``states[k − 1]`` into ``states[k]``. Returns with the
    status in ``io`` (module docstring) and ``io[IO_STEP]`` the first step not taken.

    The accelerations come from :func:`multibody.kernels.aba.forward_dynamics` without constraints (``program`` of
    length 0), else from :func:`multibody.kernels.kkt.constrained_accelerations`; ``controller(t, q, v, out)`` is
    the plan's ``FUNCTION`` controller (``None`` where the plan has another, whose code is then left out). ``plan``:
    the run's header and blocks (:data:`PLAN_HEADER`); ``control``: ``[τ (nv) | PD block]``; ``ws``:
    :func:`workspace_size`, kept between the calls of a Python controller's run. Where the plan asks for it
    (:data:`PLAN_ENERGY`) and ``io`` has room for ``n`` energies, a run by ABA in a vector space records the energy
    (J) of ``states[k − 1]`` there at step ``k``'s first stage, which evaluates ABA at exactly that state."""
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
    # energies of the output states, recorded where a stage evaluates ABA at the step's start itself: in a vector
    # space (no chart) without constraints
    energies = io[IO_HEADER + nq + 2 * nv :]
    recorded = (plan[PLAN_ENERGY] != 0.0 and not charts and program.shape[0] == 0 and accelerations[0] != 0.0
                and energies.shape[0] >= times.shape[0])

    if not charts and program.shape[0] == 0 and nq == nv and kind != PYTHON and not project:
        vector_space_steps(controller, joints, reals, times, s, kind, control, damped, damping, c_nodes, a_delta, a_w,
                           b_delta, b_w, accelerations, states, io, K, maps[: 2 * nv], tau, scratch, step_ws, energies,
                           recorded)
        return
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
            # the energy of the step's start, from its first stage's ABA at exactly that state (q₀ + 0, w₀)
            energy = energies[k - 1 : k] if recorded and i == 0 else energies[:0]
            if not stage_rates(joints, reals, frames, program, charts, damped, damping, y, maps, tau, step, step_ws,
                               rates, K[i], energy):
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
            status, near, _ = settle(joints, reals, frames, program, settings, tolerance, near_singular, nq, end,
                                     projected, projection_ws, io)
            if status != COMPLETED:
                io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, status
                return
        k += 1
        if near:
            io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, NEAR_SINGULAR
            return
    io[IO_STEP], io[IO_STAGE], io[IO_STATUS] = k, 0, COMPLETED


# ----------------------------------------------------------------------------- adaptive runs

#: The scalars an adaptive run keeps at the start of its workspace between calls: the time of the next step's
#: start (s), its proposed size (s; NaN: none yet), whether the rows are near singular there, the phase, whether a
#: restart takes the rate of the last step's end, whether the step was rejected once, whether it is a new step,
#: the number of steps taken, the longest step of the chart (s), the accepted step (s) and its end (s).
(S_T, S_H_ABS, S_NEAR, S_PHASE, S_REUSE, S_REJECTED, S_FRESH, S_STEPS, S_LONGEST, S_H, S_T_NEW) = range(11)
SCALARS = 11

#: The phases of an adaptive run, where a call goes on from: a new chart at the current state, a step (its
#: attempts), the outputs and the projection after an accepted step.
PHASE_RESTART, PHASE_STEP, PHASE_ACCEPTED = range(3)


def adaptive_workspace_size(nq, nv, rows, degree, step_columns, step_workspace, projection_columns,
                            projection_workspace):
    """Floats of an adaptive run's workspace (:func:`adaptive`) for a pair of ``rows`` evaluations per step and a
    dense output of ``degree``: the scalars, the chart's centre, the current state, ``y₀``, the rates, a stage
    state, the end's, the tolerances, the sizes, the error estimates, the tangent maps at both ends, the dense output's
    coefficients, the end state, the latest steps' ends, then a stage's blocks as :func:`workspace_size` has them."""
    size = 2 * nv
    return (SCALARS + nq + (nq + nv) + size * (rows + 7) + nv + 2 * size * size + degree * size + (nq + nv)
            + STALLED_STEPS + (nq + 2 * nv + nv * nv) + (size + 1) + nv + (nq + nv) + step_columns + step_workspace
            + projection_columns + projection_workspace)


@njit(cache=True, error_model="numpy")
def compiled_stage(controller, joints, reals, frames, program, plan, control, q_chart, t, y, K_i, maps, rates, tau,
                   scratch, step, step_ws, io):
    """The rates ``K_i (2 nv,)`` of the chart state ``y`` around ``q_chart`` at ``t`` (s) by the plan's compiled step
    (:func:`stage_state`, :func:`stage_torque`, :func:`stage_rates`): :data:`COMPLETED`, :data:`STAGE_UNSOLVED`, or
    :data:`NON_FINITE_TORQUE` (its time and joint forces in ``io``)."""
    nq, nv = q_chart.shape[0], y.shape[0] // 2
    charts = plan[PLAN_CHARTS] != 0.0
    damping = plan[int(plan[PLAN_DAMPING]) : int(plan[PLAN_DAMPING]) + nv]
    if not all_finite(y):
        return STAGE_UNSOLVED
    stage_state(joints, reals, frames, charts, q_chart, y, maps)
    if not stage_torque(controller, joints, int(plan[PLAN_CONTROL]), control, t, maps[:nq], maps[nq : nq + nv], tau,
                        scratch):
        io[IO_TIME] = t
        for c in range(nv):
            io[IO_HEADER + nq + nv + c] = tau[c]
        return NON_FINITE_TORQUE
    if not stage_rates(joints, reals, frames, program, charts, plan[PLAN_DAMPED] != 0.0, damping, y, maps, tau, step,
                       step_ws, rates, K_i, y[:0]):
        return STAGE_UNSOLVED
    return COMPLETED


@njit(cache=True, error_model="numpy")
def copy_into(source, target):
    """``target[:] = source``."""
    for c in range(source.shape[0]):
        target[c] = source[c]


@njit(cache=True, error_model="numpy")
def chart_tolerances(atol, rtol, magnitude, out):
    """The absolute tolerances ``(2 nv,)`` of a chart state ``[δ, w]``: ``atol + rtol |q|`` for ``δ``, measured against
    the configuration's size ``magnitude (nv,)`` in each chart direction as when integrating ``q`` itself (``δ`` is
    zero at every chart's centre), and ``atol`` for ``w``."""
    nv = magnitude.shape[0]
    for c in range(nv):
        out[c] = atol + rtol * magnitude[c]
        out[nv + c] = atol


@njit(cache=True, error_model="numpy")
def step_limit(v, rotations, turn, max_step):
    """The longest step (s) from a state of velocity ``v (nv,)``: ``max_step``, and no rotation vector of the chart
    (three entries of ``v`` from each of ``rotations``) turning by more than ``turn`` (rad) at its angular speed."""
    speed = 0.0
    for k in range(rotations.shape[0]):
        r = int(rotations[k])
        speed = larger(speed, (v[r] * v[r] + v[r + 1] * v[r + 1] + v[r + 2] * v[r + 2]) ** 0.5)
    return smaller(max_step, turn / speed) if speed > 0.0 else max_step


@njit(cache=True, error_model="numpy")
def reuse_rate(y0, K, s):
    """``K₀ = [w, ẇ]``: the rate at a new chart's centre ``y₀ = [0, w]`` of the state the last step ended at, whose
    ``ẇ = T (a + κ)`` that step's rate ``K_s`` holds (the same state: ``δ̇ = chart_rate(0, w) = w``)."""
    nv = y0.shape[0] // 2
    for c in range(nv):
        K[0, c] = y0[nv + c]
        K[0, nv + c] = K[s, nv + c]


@njit(cache=True, error_model="numpy")
def go_on(y0, y_new, K, s):
    """The next step in the same chart: ``y₀ = y₁`` and ``K₀ = K_s`` (first same as last)."""
    for c in range(y0.shape[0]):
        y0[c] = y_new[c]
        K[0, c] = K[s, c]


@njit(cache=True, error_model="numpy")
def scaled_norm(x, y0, atol, rtol):
    """``‖x / (atol + rtol |y₀|)‖``, the root mean square (HNW eq. (4.11))."""
    total = 0.0
    for c in range(x.shape[0]):
        ratio = x[c] / (atol[c] + rtol * abs(y0[c]))
        total += ratio * ratio
    return (total / x.shape[0]) ** 0.5


@njit(cache=True, error_model="numpy")
def initial_trial(y0, f0, atol, rtol, interval, y1):
    """The first trial step ``h₀`` (s) of HNW §II.4 (p. 169, a) and b)), no longer than ``interval``, and
    ``y₁ = y₀ + h₀ f₀`` into ``y1``: ``h₀ = 0.01 d₀ / d₁`` with ``d₀ = ‖y₀‖``, ``d₁ = ‖f₀‖``, or ``10⁻⁶`` where
    either is below ``10⁻⁵``."""
    d0, d1 = scaled_norm(y0, y0, atol, rtol), scaled_norm(f0, y0, atol, rtol)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = smaller(h0, interval)
    for c in range(y0.shape[0]):
        y1[c] = y0[c] + h0 * f0[c]
    return h0


@njit(cache=True, error_model="numpy")
def initial_step(y0, f0, f1, atol, rtol, h0, error_order, interval, longest, scratch):
    """The first step (s) of HNW §II.4 (p. 169, c)–f)) from the rates ``f₀`` at ``y₀`` and ``f₁`` at ``y₀ + h₀ f₀``:
    ``d₂ = ‖f₁ − f₀‖ / h₀``, ``h₁ = (0.01 / max(d₁, d₂))^(1/(q+1))`` (``q``: ``error_order``; ``max(10⁻⁶,
    10⁻³ h₀)`` where both are below ``10⁻¹⁵``), and ``min(100 h₀, h₁, interval, longest)``."""
    d1 = scaled_norm(f0, y0, atol, rtol)
    for c in range(y0.shape[0]):
        scratch[c] = f1[c] - f0[c]
    d2 = scaled_norm(scratch, y0, atol, rtol) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = larger(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / larger(d1, d2)) ** (1.0 / (error_order + 1.0))
    return smaller(smaller(smaller(100.0 * h0, h1), interval), longest)


@njit(cache=True, error_model="numpy")
def combination(weights, K, out):
    """``out = Σ_j weights_j K_j (n,)`` over the rows of ``K``, the terms of non-zero weight in the order of the
    stages (as :func:`weighted_sum` sums them)."""
    for c in range(out.shape[0]):
        out[c] = 0.0
    for j in range(weights.shape[0]):
        weight = weights[j]
        if weight != 0.0:
            for c in range(out.shape[0]):
                out[c] += weight * K[j, c]


@njit(cache=True, error_model="numpy")
def tangent_part(tangent, x, scratch):
    """``x ← Π x`` for the map ``tangent = Π (n, n)``."""
    n = x.shape[0]
    for r in range(n):
        total = 0.0
        for c in range(n):
            total += tangent[r, c] * x[c]
        scratch[r] = total
    for r in range(n):
        x[r] = scratch[r]


@njit(cache=True, error_model="numpy")
def error_norm(K, e, e3, two_estimates, h, y0, y1, atol, rtol, near, tangent, err, err3, scratch):
    """The norm of a step's local error estimate from its rates ``K (s + 1, n)``, with the scale ``sc_i = atol_i +
    rtol max(|y₀ᵢ|, |y₁ᵢ|)`` (HNW eq. (4.10)–(4.11)):

        ‖h Σ_j e_j K_j / sc‖ (root mean square), or with ``e3`` (DOP853) |h| ‖e₅‖² / √(n (‖e₅‖² + 0.01 ‖e₃‖²))

    (squared sums ``‖·‖²``; E. Hairer's DOP853). ``near``: the estimates first mapped by ``tangent (n, n)``, the
    part on the constraints' tangent space, which the projection at the step's end keeps (Hairer & Wanner, Solving
    ODEs II, §VII.2). ``err``, ``err3``, ``scratch``: ``(n,)``."""
    n = y0.shape[0]
    combination(e, K, err)
    if two_estimates:
        combination(e3, K, err3)
    if near:
        tangent_part(tangent, err, scratch)
        if two_estimates:
            tangent_part(tangent, err3, scratch)
    fifth, third = 0.0, 0.0
    for c in range(n):
        scale = atol[c] + larger(abs(y0[c]), abs(y1[c])) * rtol
        if two_estimates:
            x5, x3 = err[c] / scale, err3[c] / scale
            fifth += x5 * x5
            third += x3 * x3
        else:
            x = err[c] * h / scale
            fifth += x * x
    if not two_estimates:
        return (fifth / n) ** 0.5
    if fifth == 0.0 and third == 0.0:
        return 0.0
    return abs(h) * fifth / ((fifth + 0.01 * third) * n) ** 0.5


@njit(cache=True, error_model="numpy")
def dense_coefficients(dense, K, F):
    """``F_k = Σ_j dense[j, k] K_j`` into ``F (degree, n)`` of the rates ``K (rows, n)``."""
    for k in range(F.shape[0]):
        combination(dense[:, k], K, F[k])


@njit(cache=True, error_model="numpy")
def dense_point(y0, h, x, F, flips, out):
    """The dense output ``y(x) = y₀ + h x (F₀ + g₁(x) (F₁ + g₂(x) (F₂ + …)))`` at the fraction ``x`` of the step
    ``h`` (s) into ``out``, ``g_k(x) = x`` or, where ``flips[k]``, ``1 − x`` (HNW §II.6)."""
    degree = F.shape[0]
    for c in range(y0.shape[0]):
        total = F[degree - 1, c]
        for k in range(degree - 1, 0, -1):
            total = F[k - 1, c] + (1.0 - x if flips[k] != 0.0 else x) * total
        out[c] = y0[c] + h * x * total


@njit(cache=True, error_model="numpy")
def adaptive(python, controller, joints, reals, frames, program, times, plan, control, states, io, ws):
    """An adaptive run: steps of an embedded Runge–Kutta pair (:class:`multibody.integrators.EmbeddedPair`, the plan's
    block at ``PLAN_TABLEAU``) with step-size control (HNW §II.4, eq. (4.10)–(4.13)), from the state its workspace
    holds to ``times[-1]``, filling ``states (n, nq + nv)`` at the output ``times (n,)`` from ``io[IO_STEP]`` on: those
    inside a step from its dense output (HNW §II.6), one at a step's end from that end. Each step runs in the chart
    around its start (:func:`multibody.kernels.integration.unchart`) and its end state is projected onto the
    constraints (:func:`settle`); a new chart starts at every end on a curved configuration space (and where the end
    was projected, or the rows became near singular or ceased to be), with the step size the controller proposed.
    The step's error is measured in the chart: ``δ`` against the configuration's size (:func:`chart_tolerances`).

    Returns after the step that fills the output ``io[IO_STOP] − 1`` with the status in ``io`` (:data:`COMPLETED`,
    a failure, or :data:`NEAR_SINGULAR`, :data:`STAGE_UNSOLVED`, :data:`PROJECTION_UNSOLVED`: steps the compiled run
    leaves to Python), ``io[IO_STEP]`` the first output not filled; the workspace (:func:`adaptive_workspace_size`,
    its scalars :data:`S_T` ...) holds where the next call goes on from, whichever way it runs.

    ``python`` ``None``: compiled, the stages by the plan's step (:func:`compiled_stage`), with ``controller`` as
    :func:`advance` has it. Otherwise this function runs as Python (``adaptive.py_func``) and ``python`` gives the
    system's maps: ``restart(t, state, near, y0, magnitude)`` (the chart state ``y₀`` of ``state`` in the chart
    around it and the chart magnitudes; ``near``: the stages of the steps from there go through the constraints),
    ``rates(t, q_chart, y, out)``, ``tangent(t, q_chart, y, out)`` (the map of :func:`error_norm` at a chart state,
    near a singular configuration: the error is the larger of those on the tangent spaces at the step's start and
    end), ``unchart(q_chart, y, out)``, ``settle(t, state) -> (projected, near)`` (in
    place) and ``hand_back`` (return :data:`HANDED_BACK` after a step that ends away from a singular configuration);
    they raise the errors of a failure."""
    nq, nv = int(plan[PLAN_NQ]), int(plan[PLAN_NV])
    size = 2 * nv
    charts = plan[PLAN_CHARTS] != 0.0
    curved = plan[PLAN_CURVED] != 0.0
    project = plan[PLAN_PROJECT] != 0.0
    tolerance, near_singular = plan[PLAN_PROJECTION_TOLERANCE], plan[PLAN_NEAR_SINGULAR]
    rtol, atol, max_step, turn = plan[PLAN_RTOL], plan[PLAN_ATOL], plan[PLAN_MAX_STEP], plan[PLAN_CHART_TURN]
    rotations = plan[int(plan[PLAN_ROTATIONS]) : int(plan[PLAN_ROTATIONS]) + int(plan[PLAN_ROTATION_COUNT])]
    m = int(program[1]) if program.shape[0] > 0 else 0
    settings = plan[int(plan[PLAN_SETTINGS]) : int(plan[PLAN_SETTINGS]) + 2 + m]
    step_columns, step_size = int(plan[PLAN_STEP_COLUMNS]), int(plan[PLAN_STEP_WORKSPACE])
    projection_columns, projection_size = int(plan[PLAN_PROJECTION_COLUMNS]), int(plan[PLAN_PROJECTION_WORKSPACE])
    none = plan[:0]
    # the pair
    start = int(plan[PLAN_TABLEAU])
    s, rows, degree = int(plan[start]), int(plan[start + 1]), int(plan[start + 2])
    error_order = plan[start + 3]
    exponent = -1.0 / (error_order + 1.0)
    two_estimates = plan[start + 4] != 0.0
    at = start + 5
    c_nodes = plan[at : at + rows]
    at += rows
    a = plan[at : at + rows * rows].reshape((rows, rows))
    at += rows * rows
    e = plan[at : at + s + 1]
    at += s + 1
    e3 = plan[at : at + s + 1]
    at += s + 1
    dense = plan[at : at + rows * degree].reshape((rows, degree))
    at += rows * degree
    flips = plan[at : at + degree]
    # workspace
    scalars = ws[:SCALARS]
    at = SCALARS
    q_chart = ws[at : at + nq]
    at += nq
    current = ws[at : at + nq + nv]
    at += nq + nv
    y0 = ws[at : at + size]
    at += size
    K = ws[at : at + rows * size].reshape((rows, size))
    at += rows * size
    y = ws[at : at + size]
    at += size
    y_new = ws[at : at + size]
    at += size
    atol_chart = ws[at : at + size]
    at += size
    magnitude = ws[at : at + nv]
    at += nv
    err = ws[at : at + size]
    at += size
    err3 = ws[at : at + size]
    at += size
    scratch = ws[at : at + size]
    at += size
    tangent = ws[at : at + size * size].reshape((size, size))
    at += size * size
    tangent_end = ws[at : at + size * size].reshape((size, size))
    at += size * size
    F = ws[at : at + degree * size].reshape((degree, size))
    at += degree * size
    end = ws[at : at + nq + nv]
    at += nq + nv
    recent = ws[at : at + STALLED_STEPS]
    at += STALLED_STEPS
    maps = ws[at : at + nq + 2 * nv + nv * nv]
    at += nq + 2 * nv + nv * nv
    rates = ws[at : at + size + 1].reshape((1, size + 1))
    at += size + 1
    tau = ws[at : at + nv]
    at += nv
    pd_scratch = ws[at : at + nq + nv]
    at += nq + nv
    step = ws[at : at + step_columns].reshape((1, step_columns))
    at += step_columns
    step_ws = ws[at : at + step_size]
    at += step_size
    projected_row = ws[at : at + projection_columns].reshape((1, projection_columns))
    at += projection_columns
    projection_ws = ws[at : at + projection_size]

    n = times.shape[0]
    t_final = times[n - 1]
    span = t_final - times[0]
    done, stop = int(io[IO_STEP]), int(io[IO_STOP])
    while done < stop:
        t = scalars[S_T]
        near = scalars[S_NEAR] != 0.0
        if python is None and near:
            io[IO_STATUS] = NEAR_SINGULAR
            return
        if scalars[S_PHASE] == PHASE_RESTART:
            # a new chart at the current state: y₀ = [0, T(q) v], the tolerances of δ against the size of q
            if python is None:
                for c in range(nq):
                    q_chart[c] = current[c]
                for c in range(nv):
                    y0[c] = 0.0
                if charts:
                    aligned(joints, reals, frames, q_chart, current[nq:], maps[nq + 2 * nv :].reshape((nv, nv)),
                            y0[nv:])
                else:
                    for c in range(nv):
                        y0[nv + c] = current[nq + c]
                configuration.chart_magnitude(joints, reals, frames, q_chart, none, none, none,
                                              magnitude.reshape((1, nv)), none)
            else:
                copy_into(current[:nq], q_chart)
                python.restart(t, current, near, y0, magnitude)
            chart_tolerances(atol, rtol, magnitude, atol_chart)
            longest = step_limit(current[nq:], rotations, turn, max_step)
            scalars[S_LONGEST] = longest
            # the rate at the chart's centre: that of the last step's end where it is the same state, else evaluated
            if scalars[S_REUSE] != 0.0:
                reuse_rate(y0, K, s)
            elif python is None:
                status = compiled_stage(controller, joints, reals, frames, program, plan, control, q_chart, t, y0,
                                        K[0], maps, rates, tau, pd_scratch, step, step_ws, io)
                if status != COMPLETED:
                    io[IO_STEP], io[IO_STATUS] = done, status
                    return
            else:
                python.rates(t, q_chart, y0, K[0])
            h_abs = scalars[S_H_ABS]
            if np.isnan(h_abs):
                # the first step, from the sizes of y₀, f₀ and of f's change over a trial step (HNW §II.4)
                h0 = initial_trial(y0, K[0], atol_chart, rtol, t_final - t, y)
                if python is None:
                    status = compiled_stage(controller, joints, reals, frames, program, plan, control, q_chart,
                                            t + h0, y, K[1], maps, rates, tau, pd_scratch, step, step_ws, io)
                    if status != COMPLETED:
                        io[IO_STEP], io[IO_STATUS] = done, status
                        return
                else:
                    python.rates(t + h0, q_chart, y, K[1])
                h_abs = initial_step(y0, K[0], K[1], atol_chart, rtol, h0, error_order, t_final - t, longest, scratch)
            else:
                h_abs = smaller(smaller(h_abs, t_final - t), longest)
            scalars[S_H_ABS] = h_abs
            scalars[S_PHASE], scalars[S_FRESH] = PHASE_STEP, 1.0
        if scalars[S_PHASE] == PHASE_STEP:
            longest = scalars[S_LONGEST]
            min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
            h_abs = scalars[S_H_ABS]
            if scalars[S_FRESH] != 0.0:
                scalars[S_FRESH], scalars[S_REJECTED] = 0.0, 0.0
                if h_abs > longest:
                    h_abs = longest
                elif h_abs < min_step:
                    h_abs = min_step
                if near and python is not None:
                    python.tangent(t, q_chart, y0, tangent)
            while True:
                if h_abs < min_step:
                    io[IO_TIME] = t
                    io[IO_STEP], io[IO_STATUS] = done, STEP_TOO_SMALL
                    return
                t_new = smaller(t + h_abs, t_final)
                h = t_new - t
                h_abs = abs(h)
                scalars[S_H_ABS] = h_abs
                # the stages and the end: K_i = f(t₀ + c_i h, y₀ + h Σ_j a_ij K_j)
                for i in range(1, s + 1):
                    target = y_new if i == s else y
                    weighted_sum(y0, h, a[i, :i], K, 0, size, target)
                    if python is None:
                        status = compiled_stage(controller, joints, reals, frames, program, plan, control, q_chart,
                                                t + c_nodes[i] * h, target, K[i], maps, rates, tau, pd_scratch, step,
                                                step_ws, io)
                        if status != COMPLETED:
                            io[IO_STEP], io[IO_STATUS] = done, status
                            return
                    else:
                        python.rates(t + c_nodes[i] * h, q_chart, target, K[i])
                error = error_norm(K[: s + 1], e, e3, two_estimates, h, y0, y_new, atol_chart, rtol, near, tangent, err,
                                   err3, scratch)
                if near and python is not None:
                    # and on the tangent space at the step's end, where the projection removes the normal part: a
                    # step through the singular configuration turns the rows
                    python.tangent(t_new, q_chart, y_new, tangent_end)
                    error = larger(error, error_norm(K[: s + 1], e, e3, two_estimates, h, y0, y_new, atol_chart,
                                                     rtol, near, tangent_end, err, err3, scratch))
                # h_new = h · min(MAX_FACTOR, max(MIN_FACTOR, SAFETY · err^(−1/(q+1)))), no growth after a rejection
                if error < 1.0:
                    factor = MAX_FACTOR if error == 0.0 else smaller(MAX_FACTOR, SAFETY * error ** exponent)
                    if scalars[S_REJECTED] != 0.0:
                        factor = smaller(1.0, factor)
                    scalars[S_H_ABS] = h_abs * factor
                    break
                h_abs *= larger(MIN_FACTOR, SAFETY * error ** exponent)
                scalars[S_H_ABS], scalars[S_REJECTED] = h_abs, 1.0
            scalars[S_H], scalars[S_T_NEW], scalars[S_PHASE] = h, t_new, PHASE_ACCEPTED
            # stalled: the last STALLED_STEPS steps advanced less than STALLED_SPAN of the run
            count = int(scalars[S_STEPS])
            recent[count % STALLED_STEPS] = t_new
            count += 1
            scalars[S_STEPS] = count
            if count >= STALLED_STEPS and t_new - recent[count % STALLED_STEPS] < STALLED_SPAN * span:
                io[IO_TIME], io[IO_VALUE] = t_new, t_new - recent[count % STALLED_STEPS]
                io[IO_STEP], io[IO_STATUS] = done, STALLED
                return
        # the outputs inside the step, from the dense output with its own stages
        t_new, h = scalars[S_T_NEW], scalars[S_H]
        if done < n and times[done] < t_new:
            for i in range(s + 1, rows):
                weighted_sum(y0, h, a[i, :i], K, 0, size, y)
                if python is None:
                    status = compiled_stage(controller, joints, reals, frames, program, plan, control, q_chart,
                                            t + c_nodes[i] * h, y, K[i], maps, rates, tau, pd_scratch, step, step_ws,
                                            io)
                    if status != COMPLETED:
                        io[IO_STEP], io[IO_STATUS] = done, status
                        return
                else:
                    python.rates(t + c_nodes[i] * h, q_chart, y, K[i])
            dense_coefficients(dense, K, F)
            while done < n and times[done] < t_new:
                dense_point(y0, h, (times[done] - t) / h, F, flips, y)
                if python is None:
                    stage_state(joints, reals, frames, charts, q_chart, y, maps)
                    for c in range(nq + nv):
                        states[done, c] = maps[c]
                else:
                    python.unchart(q_chart, y, states[done])
                done += 1
                io[IO_STEP] = done
        # the end, projected onto the constraints where that moves it
        if python is None:
            stage_state(joints, reals, frames, charts, q_chart, y_new, maps)
            for c in range(nq + nv):
                end[c] = maps[c]
            if not all_finite(end):
                io[IO_TIME] = t_new
                io[IO_STEP], io[IO_STATUS] = done, NON_FINITE_STATE
                return
            now_near, projected = False, False
            if project:
                status, now_near, projected = settle(joints, reals, frames, program, settings, tolerance,
                                                     near_singular, nq, end, projected_row, projection_ws, io)
                if status != COMPLETED:
                    io[IO_STEP], io[IO_STATUS] = done, status
                    return
        else:
            python.unchart(q_chart, y_new, end)
            projected, now_near = python.settle(t_new, end)
        if done < n and times[done] == t_new:
            copy_into(end, states[done])
            done += 1
            io[IO_STEP] = done
        # the next step: in a new chart on a curved space, where the end was projected or the stages change
        copy_into(end, current)
        scalars[S_T], scalars[S_NEAR] = t_new, 1.0 if now_near else 0.0
        if projected or curved or now_near != near:
            scalars[S_PHASE] = PHASE_RESTART
            scalars[S_REUSE] = 1.0 if not projected and now_near == near else 0.0
        else:
            go_on(y0, y_new, K, s)
            scalars[S_PHASE], scalars[S_FRESH] = PHASE_STEP, 1.0
        if python is None:
            if now_near:
                io[IO_STEP], io[IO_STATUS] = done, NEAR_SINGULAR
                return
        elif python.hand_back and not now_near:
            io[IO_STEP], io[IO_STATUS] = done, HANDED_BACK
            return
    io[IO_STEP], io[IO_STATUS] = done, COMPLETED


@njit(cache=True, error_model="numpy")
def adaptive_run(joints, reals, frames, program, times, plan, control, states, io, ws):
    """:func:`adaptive`, compiled, of a run whose controller is none, constant or PD."""
    adaptive(None, None, joints, reals, frames, program, times, plan, control, states, io, ws)


@njit(cache=True, error_model="numpy")
def adaptive_run_function(controller, joints, reals, frames, program, times, plan, control, states, io, ws):
    """:func:`adaptive`, compiled, of a run whose controller is the compiled ``controller(t, q, v, out)`` (a
    first-class function)."""
    adaptive(None, controller, joints, reals, frames, program, times, plan, control, states, io, ws)


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
