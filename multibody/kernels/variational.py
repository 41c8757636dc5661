"""The variational integrator's run, compiled: every step of a trajectory, Newton's iteration included.

The equations are those of :mod:`multibody.variational` (module docstring there), for a
:class:`~multibody.model.Model` with compiled constraint rows fixed in time (``b = 0``,
:mod:`multibody.kernels.constraints`) or none, and joint forces from data or compiled code (none, constant,
the PD law of :func:`multibody.kernels.stepping.pd_torque`, a compiled function ``f(t, q, v, out)``; less
viscous damping ``D v``). With ``Δ`` the step's increment, ``q_{k+1} = q_k ⊕ Δ``, ``ξ = Δ/h``, ``⊕`` the
integrator's group (SO(3) × R³ for a free flyer, whose velocities ``w`` then have the linear part in the parent
frame, ``v = T(q) w``), the first discrete equation

    midpoint:     J_l(Δ)⁻ᵀ (M(q̄) ξ − (h/2) J_l(Δ/2)ᵀ (∂L/∂q(q̄, ξ) + τ̄)) − Bᵀ μ⁻ = p_k,     q̄ = q_k ⊕ Δ/2
    trapezoidal:  J_l(Δ)⁻ᵀ ½ (M(q_k) + M(q_{k+1})) ξ − (h/2) (∂L/∂q(q_k, ξ) + τ_k) − Bᵀ μ⁻ = p_k

(``B = A(q_k)``) is solved with the rows ``φ(q_{k+1}) = 0`` (holonomic) and ``A(q̄) ξ = 0`` (nonholonomic) by
Newton's method: the Jacobian ``J`` of :func:`newton_jacobian` once per step, Broyden's update of ``J⁻¹`` after
(J. E. Dennis and R. B. Schnabel, *Numerical Methods for Unconstrained Optimization*, 1983, Chapter 8), and
the impulses by the Schur complement ``C J⁻¹ Bᵀ`` of the rows' linearisation ``C``. The momentum balance then
gives ``p_{k+1}``, and the ``M``-orthogonal projection of ``v_{k+1} = M(q_{k+1})⁻¹ p_{k+1}`` onto the rows at
``q_{k+1}`` the end impulses ``μ⁺`` (:func:`multibody.kernels.kkt.metric_solve`).

:func:`advance` takes the steps of one trajectory from ``io[IO_STEP]`` to ``io[IO_STOP]`` and returns with a
status (:data:`COMPLETED` or the failure that stopped it, with its time, step and residual in ``io``), its
state between calls in the workspace's first :func:`memory_size` floats. ``M`` holds the joints' armature on
its diagonal (:func:`multibody.kernels.crba.mass_matrix`).
"""

from __future__ import annotations

import math

from .layout import IQ, IV, KIND
from . import configuration, constraints, coriolis, derivatives, kkt, lagrangian, stepping
from . import joints as kinds
from .jit import njit
from .spatial import all_finite, larger, smaller

#: The plan's header (one float each): sizes, the rule (0 midpoint, 1 trapezoidal), whether the velocities are a
#: free flyer's group velocities, whether the configurations step on a group, the controller
#: (:data:`multibody.kernels.stepping.NO_CONTROL` …), whether it has damping, Newton's tolerance and iterations,
#: the rank tolerance of the rows, and the sub-steps (1, or 3 for Yoshida's composition) with their weights.
(PLAN_NQ, PLAN_NV, PLAN_M, PLAN_TRAPEZOIDAL, PLAN_GROUPED, PLAN_CHART, PLAN_CONTROL, PLAN_DAMPED, PLAN_TOLERANCE,
 PLAN_MAX_ITERATIONS, PLAN_RANK_TOLERANCE, PLAN_SUBSTEPS, PLAN_WEIGHTS) = range(13)
#: After the header (its three weights): whether each row is holonomic ``(m)``, then the damping ``D (nv)``.
PLAN_HEADER = PLAN_WEIGHTS + 3

#: The entries of ``io``: the next step (in and out), the step to stop before, the status (out), the time (s) and
#: step (s) of the sub-step that failed, its relative residual and iterations, the evaluations of the discrete
#: equations since the run's start (one per Newton iterate), then the joint forces ``τ (nv)`` where they were
#: not finite.
IO_STEP, IO_STOP, IO_STATUS, IO_TIME, IO_STEP_SIZE, IO_ERROR, IO_ITERATIONS, IO_EVALUATIONS = range(8)
IO_HEADER = 8

#: Status of a run: it reached the step to stop before; Newton's method did not meet the tolerance; its residual
#: is not finite; a singular Jacobian or Schur complement; a mass matrix that is not positive definite; a
#: non-finite state at a step's end; non-finite joint forces of the controller; an undefined constraint row.
(COMPLETED, NOT_CONVERGED, NON_FINITE_RESIDUAL, SINGULAR, NOT_POSITIVE_DEFINITE, NON_FINITE_STATE, NON_FINITE_TORQUE,
 UNDEFINED_ROW) = range(8)

#: Relative size of the forward-difference step of ``∂f⁻/∂Δ`` (about √ε).
FORCE_DIFFERENCE_STEP = 1.5e-8


def io_size(nv):
    """Floats of a run's ``io`` vector."""
    return IO_HEADER + nv


def memory_size(nq, nv, m):
    """Floats of the state a run keeps between its calls, at the workspace's start: ``q``, ``p``, ``w`` and the
    last node's ``w`` (``nq + 3 nv``), the last sub-step ``h``, the count of the last equal sub-steps' increments
    and their ``h`` (3) and ``Δ`` (``3 nv``), the last start impulses ``μ⁻ (m)`` and whether there are any."""
    return nq + 3 * nv + 1 + 1 + 3 + 3 * nv + m + 1


def workspace_size(nj, nq, nv, m, nframes):
    """Floats of a run's workspace: :func:`memory_size`, the step's vectors and matrices (the layout of
    :func:`advance`), the constraint solves' (:func:`multibody.kernels.kkt.solve_workspace`), and the largest
    workspace of the kernels it calls."""
    columns = m * nv + 2 * m + 1  # constraints.levels_columns(nv, m)
    vectors = 16 * nv + 3 * nq + 7 * m + (nv + 1) * nv
    matrices = 18 * nv * nv + 3 * columns + 4 * m * nv + 2 * m * m
    solves = kkt.solve_workspace_size(m, nv)
    kernels = max(lagrangian.workspace_size(nj, nv), derivatives.workspace_size(nj, nv), coriolis.workspace_size(nj, nv),
                  configuration.workspace_size(nj, nv), constraints.workspace_size(nj, nv, nframes), nq + nv)
    return memory_size(nq, nv, m) + vectors + matrices + solves + kernels


@njit(cache=True, error_model="numpy")
def move(joints, reals, frames, q, x, scale, out, ws):
    """``q ⊕ scale x`` on the integrator's group into ``out (1, nq)``: the model's exponential, but a free
    flyer's position moves by ``scale x_lin`` in the parent frame. ``ws`` holds ``nv`` floats."""
    nv = x.shape[0]
    step = ws[:nv]
    for c in range(nv):
        step[c] = scale * x[c]
    configuration.integrate(joints, reals, frames, q, step, step[:0], step[:0], out, ws[nv:nv])
    for i in range(joints.shape[0]):
        if joints[i, KIND] == kinds.FREE_FLYER:
            iq, iv = joints[i, IQ], joints[i, IV]
            for k in range(3):
                out[0, iq + k] = q[iq + k] + step[iv + k]


@njit(cache=True, error_model="numpy")
def solve_transposed_blocks(joints, J, y, x):
    """``x = J⁻ᵀ y`` for a block-diagonal ``J`` of :func:`multibody.kernels.configuration.exponential_terms`
    (3×3 blocks on the rotation groups, the identity elsewhere), block by block (Cramer's rule)."""
    for c in range(y.shape[0]):
        x[c] = y[c]
    for i in range(joints.shape[0]):
        b = configuration.rotation_block(joints[i, KIND], joints[i, IV])
        if b < 0:
            continue
        # Jᵀ's block is the transpose of J's: a_rc = J[b + c, b + r]
        a00, a01, a02 = J[b, b], J[b + 1, b], J[b + 2, b]
        a10, a11, a12 = J[b, b + 1], J[b + 1, b + 1], J[b + 2, b + 1]
        a20, a21, a22 = J[b, b + 2], J[b + 1, b + 2], J[b + 2, b + 2]
        y0, y1, y2 = y[b], y[b + 1], y[b + 2]
        det = a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)
        x[b] = (y0 * (a11 * a22 - a12 * a21) - a01 * (y1 * a22 - a12 * y2) + a02 * (y1 * a21 - a11 * y2)) / det
        x[b + 1] = (a00 * (y1 * a22 - a12 * y2) - y0 * (a10 * a22 - a12 * a20) + a02 * (a10 * y2 - y1 * a20)) / det
        x[b + 2] = (a00 * (a11 * y2 - y1 * a21) - a01 * (a10 * y2 - y1 * a20) + y0 * (a10 * a21 - a11 * a20)) / det


@njit(cache=True, error_model="numpy")
def largest(x):
    """``max |xᵢ|``, NaN when an entry is not finite."""
    size = 0.0
    for c in range(x.shape[0]):
        if not math.isfinite(x[c]):
            return math.nan
        size = larger(size, abs(x[c]))
    return size




# ----------------------------------------------------------------------------- linear algebra

@njit(cache=True, error_model="numpy")
def lu_factor(A, n, pivots):
    """``P A = L U`` of ``A[:n, :n]`` in place by Gaussian elimination with partial pivoting (G. H. Golub and
    C. F. Van Loan, *Matrix Computations*, 4th ed., Alg. 3.4.1): ``U`` in the upper triangle, the multipliers of
    the unit lower ``L`` below it, ``pivots[k]`` the row swapped with row ``k``. Returns ``False`` where a pivot is
    zero or not finite (a singular ``A``)."""
    for k in range(n):
        p = k
        for r in range(k + 1, n):
            if abs(A[r, k]) > abs(A[p, k]):
                p = r
        pivots[k] = p
        if A[p, k] == 0.0 or not math.isfinite(A[p, k]):
            return False
        if p != k:
            for c in range(n):
                A[k, c], A[p, c] = A[p, c], A[k, c]
        for r in range(k + 1, n):
            f = A[r, k] / A[k, k]
            A[r, k] = f
            for c in range(k + 1, n):
                A[r, c] -= f * A[k, c]
    return True


@njit(cache=True, error_model="numpy")
def lu_solve(LU, n, pivots, x):
    """``x ← A⁻¹ x`` with the factors of :func:`lu_factor`: ``L y = P x``, then ``U x = y``."""
    for k in range(n):
        p = int(pivots[k])
        if p != k:
            x[k], x[p] = x[p], x[k]
    for r in range(n):
        for c in range(r):
            x[r] -= LU[r, c] * x[c]
    for r in range(n - 1, -1, -1):
        s = x[r]
        for c in range(r + 1, n):
            s -= LU[r, c] * x[c]
        x[r] = s / LU[r, r]


@njit(cache=True, error_model="numpy")
def minimum_norm_solve(S, U, sigma, rhs, relative, x):
    """The minimum-norm least-squares ``x = S⁺ rhs (m,)`` of a square ``S (m, m)`` (overwritten), singular values
    at most ``relative`` times the largest dropped (NumPy's ``lstsq`` with ``rcond = relative``): with the rows
    made orthogonal, ``S = U S'`` (:func:`multibody.kernels.kkt.orthogonalize_rows`, ``S'`` rows of norms ``σ_j``),
    ``x = Σ_j S'_j (U_jᵀ rhs) / σ_j²``. ``U (m, m)``, ``sigma (m,)`` are scratch."""
    m = S.shape[0]
    kkt.orthogonalize_rows(S, U, sigma, m)
    largest = 0.0
    for j in range(m):
        largest = larger(largest, sigma[j])
        x[j] = 0.0
    for j in range(m):
        if sigma[j] > relative * largest:
            coefficient = 0.0
            for i in range(m):
                coefficient += U[i, j] * rhs[i]
            coefficient /= sigma[j] * sigma[j]
            for c in range(m):
                x[c] += coefficient * S[j, c]


# ----------------------------------------------------------------------------- the group's velocities and forces

@njit(cache=True, error_model="numpy")
def group_alignment(joints, q, T):
    """``T(q) (nv, nv)`` with the joint velocities ``v = T w`` of the group velocities ``w``: the identity, but
    ``Rᵀ`` on a free flyer's linear block (its group velocity is in the parent frame)."""
    nv = T.shape[0]
    for r in range(nv):
        for c in range(nv):
            T[r, c] = 1.0 if r == c else 0.0
    for i in range(joints.shape[0]):
        if joints[i, KIND] == kinds.FREE_FLYER:
            R, iv = kinds.quat_rotation(kinds.load4(q, joints[i, IQ] + 3)), joints[i, IV]
            for j in range(3):
                for k in range(3):
                    T[iv + j, iv + k] = R[3 * k + j]


@njit(cache=True, error_model="numpy")
def joint_forces(controller, joints, plan, control, t, q, w, T, v, tau, out, scratch, io):
    """The forces' virtual work in the step's velocities into ``out (nv,)``: ``τ_G = Tᵀ (τ(t, q, v) − D v)`` with
    ``v = T w`` (``T``: :func:`group_alignment` at ``q`` where the velocities are a free flyer's group velocities,
    else ``v = w``), ``τ`` from the plan's controller. Returns ``False`` where ``τ`` is not finite, with ``t`` and
    ``τ`` in ``io``."""
    nv = w.shape[0]
    grouped = plan[PLAN_GROUPED] != 0.0
    kind = int(plan[PLAN_CONTROL])
    if grouped:
        for r in range(nv):
            total = 0.0
            for c in range(nv):
                total += T[r, c] * w[c]
            v[r] = total
    else:
        for r in range(nv):
            v[r] = w[r]
    if not stepping.stage_torque(controller, joints, kind, control, t, q, v, tau, scratch):
        io[IO_TIME] = t
        for c in range(nv):
            io[IO_HEADER + c] = tau[c]
        return False
    if plan[PLAN_DAMPED] != 0.0:
        # − D v
        m = int(plan[PLAN_M])
        for c in range(nv):
            tau[c] -= plan[PLAN_HEADER + m + c] * v[c]
    if grouped:
        for c in range(nv):
            total = 0.0
            for r in range(nv):
                total += T[r, c] * tau[r]
            out[c] = total
    else:
        for c in range(nv):
            out[c] = tau[c]
    return True


@njit(cache=True, error_model="numpy")
def jacobian_terms(joints, reals, frames, plan, q, w, K, H, S, T, work, terms, v, p, ws):
    """``(K, H, S)`` of the Newton Jacobian at ``(q, w)``, each ``(nv, nv)`` (the velocities ``w`` of the step):
    ``K = ∂(M(q) w)/∂q``, ``H ≈ ∂²L/∂q²``, ``S = ∂(C(q, w)ᵀ w)/∂w`` (:meth:`multibody.variational._ModelLagrangian.jacobian_terms`,
    and :meth:`multibody.variational._GroupLagrangian.jacobian_terms` in a free flyer's group velocities):

        K = ∂τ/∂q|_{v=0, a=v} − ∂g/∂q,   H = −∂g/∂q,   S = Kᵀ (vector space),   S = C + Cᵀ + K − ∂(C v)/∂v (group)

    and in group velocities ``K_G = Tᵀ (K T + M E) + D(M v)``, ``H_G = Tᵀ H T + D(−g)``, ``S_G = K_Gᵀ`` with
    ``E = [v_lin]×`` and ``D(f) = −R [f_lin]×`` in each free flyer's (linear, angular) block.
    ``work (2 nv, nv)``, ``terms (nv + 1, nv)``, ``v``, ``p (nv,)`` are scratch."""
    nv = w.shape[0]
    grouped = plan[PLAN_GROUPED] != 0.0
    none = w[:0]
    # ∂g/∂q into H (RNEA's derivative at rest)
    derivatives.inverse_dynamics_derivatives(joints, reals, frames, q, none, none, none, H, ws)
    if grouped:
        group_alignment(joints, q, T)
        for r in range(nv):
            total = 0.0
            for c in range(nv):
                total += T[r, c] * w[c]
            v[r] = total
    else:
        for r in range(nv):
            v[r] = w[r]
    for c in range(nv):
        p[c] = 0.0
    # K = ∂τ/∂q at zero velocity and acceleration v, less ∂g/∂q;  H = −∂g/∂q
    derivatives.inverse_dynamics_derivatives(joints, reals, frames, q, p, v, none, work, ws)
    for r in range(nv):
        for c in range(nv):
            K[r, c] = work[r, c] - H[r, c]
            H[r, c] = -H[r, c]
    if grouped:
        # M and −g in the joints' velocities: ∂L/∂q at rest
        lagrangian.lagrangian_terms(joints, reals, frames, q, p, none, none, terms, ws)
        for r in range(nv):
            total = 0.0
            for c in range(nv):
                total += terms[r, c] * v[c]
            p[r] = total
        # work[:nv] = K T + M E,  work[nv:] = H T
        for r in range(nv):
            for c in range(nv):
                k_t, h_t = 0.0, 0.0
                for j in range(nv):
                    k_t += K[r, j] * T[j, c]
                    h_t += H[r, j] * T[j, c]
                work[r, c], work[nv + r, c] = k_t, h_t
        for i in range(joints.shape[0]):
            if joints[i, KIND] != kinds.FREE_FLYER:
                continue
            iv = joints[i, IV]
            x, y, z = v[iv], v[iv + 1], v[iv + 2]
            # (M E)[r, ang] = M[r, lin] [v_lin]×
            for r in range(nv):
                a, b, c = terms[r, iv], terms[r, iv + 1], terms[r, iv + 2]
                work[r, iv + 3] += b * z - c * y
                work[r, iv + 4] += c * x - a * z
                work[r, iv + 5] += a * y - b * x
        # K_G = Tᵀ work[:nv], H_G = Tᵀ work[nv:]
        for r in range(nv):
            for c in range(nv):
                k_g, h_g = 0.0, 0.0
                for j in range(nv):
                    k_g += T[j, r] * work[j, c]
                    h_g += T[j, r] * work[nv + j, c]
                K[r, c], H[r, c] = k_g, h_g
        for i in range(joints.shape[0]):
            if joints[i, KIND] != kinds.FREE_FLYER:
                continue
            iv = joints[i, IV]
            for pair in range(2):
                # D(f) = −R [f_lin]×: f = M v onto K, f = −g onto H
                if pair == 0:
                    f0, f1, f2 = p[iv], p[iv + 1], p[iv + 2]
                else:
                    f0, f1, f2 = terms[nv, iv], terms[nv, iv + 1], terms[nv, iv + 2]
                for r in range(3):
                    # R = T_linᵀ: R[r, j] = T[iv + j, iv + r]
                    r0, r1, r2 = T[iv, iv + r], T[iv + 1, iv + r], T[iv + 2, iv + r]
                    d0 = -(r1 * f2 - r2 * f1)
                    d1 = -(r2 * f0 - r0 * f2)
                    d2 = -(r0 * f1 - r1 * f0)
                    if pair == 0:
                        K[iv + r, iv + 3] += d0
                        K[iv + r, iv + 4] += d1
                        K[iv + r, iv + 5] += d2
                    else:
                        H[iv + r, iv + 3] += d0
                        H[iv + r, iv + 4] += d1
                        H[iv + r, iv + 5] += d2
        for r in range(nv):
            for c in range(nv):
                S[r, c] = K[c, r]
    elif plan[PLAN_CHART] != 0.0:
        # S = C + Cᵀ + K − ∂(C v)/∂v, the last the velocity derivative of RNEA at zero acceleration
        coriolis.coriolis_matrix(joints, reals, frames, q, v, none, none, S, ws)
        for c in range(nv):
            p[c] = 0.0
        derivatives.inverse_dynamics_derivatives(joints, reals, frames, q, v, p, none, work, ws)
        for r in range(nv):
            for c in range(r, nv):
                symmetric = S[r, c] + S[c, r]
                S[r, c], S[c, r] = symmetric, symmetric
        for r in range(nv):
            for c in range(nv):
                S[r, c] += K[r, c] - work[nv + r, c]
    else:
        for r in range(nv):
            for c in range(nv):
                S[r, c] = K[c, r]


# ----------------------------------------------------------------------------- one step

@njit(cache=True, error_model="numpy")
def equations(controller, joints, reals, frames, program, plan, control, t, h, q0, delta, M0, xi, q_mid, q1, M, pull,
              start, exponentials, back, terms, T, forces, v, tau, y, rows, c, C, scales, A1, io, ws):
    """The step's equations at the iterate ``Δ = delta``: ``start = −D1 L_d − f⁻ (nv,)`` (module docstring, the
    rule of the plan) and, with rows, their residuals ``c (m)``, linearisation ``C (m, nv)`` in ``Δ``, scales and
    the rows ``A1 (m, nv)`` at ``q_{k+1}``. Fills ``ξ``, ``q̄``, ``q_{k+1}``, ``M`` (``M(q̄)``, trapezoidal
    ``M(q_{k+1})``), ``pull`` (``∂L/∂q + τ`` at ``q̄``, trapezoidal at ``q_k``) and the exponential terms
    ``[Ad(Δ); J_l(Δ); Ad(Δ/2); J_l(Δ/2)] (4 nv, nv)``. Returns ``(status, scale)``: 0 or the status that stops
    the run, and the size of the momentum terms (``max(|M ξ|, (h/2) |∂L/∂q|, (h/2) |τ|)``)."""
    nv = delta.shape[0]
    m = int(plan[PLAN_M])
    trapezoidal = plan[PLAN_TRAPEZOIDAL] != 0.0
    grouped = plan[PLAN_GROUPED] != 0.0
    forced = plan[PLAN_CONTROL] != stepping.NO_CONTROL or plan[PLAN_DAMPED] != 0.0
    group = plan[PLAN_GROUPED : PLAN_GROUPED + 1] if grouped else plan[:0]
    none = plan[:0]
    for r in range(nv):
        xi[r] = delta[r] / h
    # q̄ = q_k ⊕ Δ/2,  q_{k+1} = q_k ⊕ Δ
    move(joints, reals, frames, q0, delta, 0.5, q_mid.reshape((1, q_mid.shape[0])), ws)
    move(joints, reals, frames, q0, delta, 1.0, q1.reshape((1, q1.shape[0])), ws)
    configuration.exponential_terms(joints, reals, frames, delta, none, none, none, exponentials[: 2 * nv], ws)
    for r in range(nv):
        y[r] = 0.5 * delta[r]
    configuration.exponential_terms(joints, reals, frames, y, none, none, none, exponentials[2 * nv :], ws)
    if not trapezoidal:
        # M(q̄), ∂L/∂q(q̄, ξ), τ̄ = τ(t_k + h/2, q̄, ξ)
        lagrangian.lagrangian_terms(joints, reals, frames, q_mid, xi, group, none, terms, ws)
        force_time, force_at = t + 0.5 * h, q_mid
    else:
        # M(q_{k+1}), then ∂L/∂q(q_k, ξ), τ_k = τ(t_k, q_k, ξ)
        for r in range(nv):
            y[r] = 0.0
        lagrangian.lagrangian_terms(joints, reals, frames, q1, y, group, none, terms, ws)
        for r in range(nv):
            for k in range(nv):
                M[r, k] = terms[r, k]
        lagrangian.lagrangian_terms(joints, reals, frames, q0, xi, group, none, terms, ws)
        force_time, force_at = t, q0
    size_force = 0.0
    if forced:
        if grouped:
            group_alignment(joints, force_at, T)
        if not joint_forces(controller, joints, plan, control, force_time, force_at, xi, T, v, tau, forces, ws, io):
            return NON_FINITE_TORQUE, 0.0
        size_force = largest(forces)
    for r in range(nv):
        pull[r] = terms[nv, r] + (forces[r] if forced else 0.0)
    J_l, J_half = exponentials[nv : 2 * nv], exponentials[3 * nv :]
    size_momentum = 0.0
    if not trapezoidal:
        for r in range(nv):
            for k in range(nv):
                M[r, k] = terms[r, k]
        # start = J_l(Δ)⁻ᵀ (M(q̄) ξ − (h/2) J_l(Δ/2)ᵀ (∂L/∂q(q̄, ξ) + τ̄))   (J_l = 1 on a vector space)
        for r in range(nv):
            momentum = 0.0
            for k in range(nv):
                momentum += M[r, k] * xi[k]
            size_momentum = larger(size_momentum, abs(momentum)) if math.isfinite(momentum) else math.nan
            pulled = 0.0
            for k in range(nv):
                pulled += J_half[k, r] * pull[k]
            y[r] = momentum - 0.5 * h * pulled
        solve_transposed_blocks(joints, J_l, y, start)
    else:
        # start = J_l(Δ)⁻ᵀ ½ (M(q_k) + M(q_{k+1})) ξ − (h/2) (∂L/∂q(q_k, ξ) + τ_k)
        for r in range(nv):
            momentum = 0.0
            for k in range(nv):
                momentum += 0.5 * (M0[r, k] + M[r, k]) * xi[k]
            size_momentum = larger(size_momentum, abs(momentum)) if math.isfinite(momentum) else math.nan
            y[r] = momentum
        solve_transposed_blocks(joints, J_l, y, start)
        for r in range(nv):
            start[r] -= 0.5 * h * pull[r]
    terms_size = largest(terms[nv])
    scale = larger(larger(size_momentum, 0.5 * abs(h) * terms_size), 0.5 * abs(h) * size_force)
    if not (size_momentum == size_momentum and terms_size == terms_size):
        scale = math.nan
    if m == 0:
        return 0, scale
    # the rows at q_{k+1} and at q̄, in the step's velocities
    columns = m * nv + 2 * m + 1
    constraints.constraint_levels(joints, reals, frames, q1, none, none, program, rows[0:1], ws)
    constraints.constraint_levels(joints, reals, frames, q_mid, none, none, program, rows[1:2], ws)
    if rows[0, columns - 1] != 0.0 or rows[1, columns - 1] != 0.0:
        return UNDEFINED_ROW, scale
    A_end = rows[0, : m * nv].reshape((m, nv))
    A_mid = rows[1, : m * nv].reshape((m, nv))
    if grouped:
        lagrangian.to_group_velocities(joints, q1, A_end)
        lagrangian.to_group_velocities(joints, q_mid, A_mid)
    for r in range(nv):
        y[r] = -delta[r]
    configuration.exponential_terms(joints, reals, frames, y, none, none, none, back, ws)
    size_q1, size_xi = largest(q1), largest(xi)
    for r in range(m):
        for k in range(nv):
            A1[r, k] = A_end[r, k]
        if plan[PLAN_HEADER + r] != 0.0:
            # φ(q_{k+1}) = 0, linearised by A(q_{k+1}) J_l(−Δ)
            c[r] = rows[0, m * nv + m + r]
            for k in range(nv):
                total = 0.0
                for j in range(nv):
                    total += A_end[r, j] * back[nv + j, k]
                C[r, k] = total
            scales[r] = larger(1.0, size_q1) if size_q1 == size_q1 else math.nan
        else:
            # A(q̄) ξ = 0, linearised by A(q̄)/h
            total, weighted, entry = 0.0, 0.0, 0.0
            for k in range(nv):
                total += A_mid[r, k] * xi[k]
                weighted += abs(A_mid[r, k]) * abs(xi[k])
                entry = larger(entry, abs(A_mid[r, k]))
                C[r, k] = A_mid[r, k] / h
            c[r] = total
            scales[r] = larger(larger(weighted, entry * size_xi), 1e-300)
    return 0, scale


@njit(cache=True, error_model="numpy")
def start_force(controller, joints, reals, frames, plan, control, t, h, q0, delta, xi, q_shift, T, v, tau, out, ws,
                io):
    """``f⁻ (nv,)`` of the step at ``Δ`` into ``out``: ``(h/2) τ(t_k + h/2, q_k ⊕ Δ/2, ξ)`` (midpoint) or
    ``(h/2) τ(t_k, q_k, ξ)`` (trapezoidal), for the forward differences of :func:`newton_jacobian`."""
    nv = delta.shape[0]
    for r in range(nv):
        xi[r] = delta[r] / h
    if plan[PLAN_TRAPEZOIDAL] != 0.0:
        at, time = q0, t
    else:
        move(joints, reals, frames, q0, delta, 0.5, q_shift.reshape((1, q_shift.shape[0])), ws)
        at, time = q_shift, t + 0.5 * h
    if plan[PLAN_GROUPED] != 0.0:
        group_alignment(joints, at, T)
    if not joint_forces(controller, joints, plan, control, time, at, xi, T, v, tau, out, ws, io):
        return False
    for r in range(nv):
        out[r] *= 0.5 * h
    return True


@njit(cache=True, error_model="numpy")
def newton_jacobian(controller, joints, reals, frames, plan, control, t, h, q0, delta, q_mid, q1, M0, M, J, K, H, S,
                    K1, T, work, terms, xi, v, p, q_shift, base, shifted, f, tau, ws, io):
    """``J = ∂(−D1 L_d − f⁻)/∂Δ (nv, nv)`` at ``Δ`` (:mod:`multibody.variational`, "Newton's method"):

        midpoint:     J = M(q̄)/h + ½ (K − S) − (h/4) H − ∂f⁻/∂Δ               (K, H, S at q̄)
        trapezoidal:  J = (M(q_k) + M(q_{k+1}))/(2h) + ½ (K(q_{k+1}) − S(q_k)) − ∂f⁻/∂Δ

    with :func:`jacobian_terms`, and ``∂f⁻/∂Δ`` by forward differences where there are forces. Returns ``False``
    where the forces are not finite."""
    nv = delta.shape[0]
    for r in range(nv):
        xi[r] = delta[r] / h
    if plan[PLAN_TRAPEZOIDAL] == 0.0:
        jacobian_terms(joints, reals, frames, plan, q_mid, xi, K, H, S, T, work, terms, v, p, ws)
        for r in range(nv):
            for c in range(nv):
                J[r, c] = M[r, c] / h + 0.5 * (K[r, c] - S[r, c]) - 0.25 * h * H[r, c]
    else:
        jacobian_terms(joints, reals, frames, plan, q1, xi, K1, H, S, T, work, terms, v, p, ws)
        jacobian_terms(joints, reals, frames, plan, q0, xi, K, H, S, T, work, terms, v, p, ws)
        for r in range(nv):
            for c in range(nv):
                J[r, c] = 0.5 * (M0[r, c] + M[r, c]) / h + 0.5 * (K1[r, c] - S[r, c])
    if plan[PLAN_CONTROL] != stepping.NO_CONTROL or plan[PLAN_DAMPED] != 0.0:
        # forward differences of f⁻ along each coordinate of Δ
        if not start_force(controller, joints, reals, frames, plan, control, t, h, q0, delta, xi, q_shift, T, v, tau,
                           base, ws, io):
            return False
        step = FORCE_DIFFERENCE_STEP * larger(larger(largest(delta), abs(h) * 1e-8), 1e-300)
        for j in range(nv):
            for r in range(nv):
                shifted[r] = delta[r]
            shifted[j] += step
            if not start_force(controller, joints, reals, frames, plan, control, t, h, q0, shifted, xi, q_shift, T, v,
                               tau, f, ws, io):
                return False
            for r in range(nv):
                J[r, j] -= (f[r] - base[r]) / step
    return True


@njit(cache=True, error_model="numpy")
def predict(h, w, memory_w_before, h_before, count, increment_h, increments, out):
    """The predicted increment ``Δ (nv,)`` of a step of size ``h`` from the node velocity ``w``
    (:func:`multibody.variational._predict`): after three steps of this size (``increments (3, nv)`` newest
    first, of sizes ``increment_h``) ``3 Δ_{k−1} − 3 Δ_{k−2} + Δ_{k−3}``; else ``h w + h²/2 (w − w_before)/h_before``,
    or ``h w`` at the start (``h_before = 0``)."""
    nv = w.shape[0]
    equal = count == 3
    for j in range(3 if equal else 0):
        if abs(increment_h[j] - h) > 1e-9 * abs(h):
            equal = False
    for r in range(nv):
        if equal:
            out[r] = 3.0 * (increments[0, r] - increments[1, r]) + increments[2, r]
        elif h_before == 0.0:
            out[r] = h * w[r]
        else:
            out[r] = h * w[r] + 0.5 * h * h * (w[r] - memory_w_before[r]) / h_before


# ----------------------------------------------------------------------------- the run

@njit(cache=True, error_model="numpy")
def advance(controller, joints, reals, frames, program, times, plan, control, states, impulses, io, ws):
    """Steps ``io[IO_STEP]`` up to ``io[IO_STOP]`` (exclusive) of one trajectory: ``states (n, nq + nv)`` holds
    ``[q, v]`` at ``times (n,)``, each step ``k`` from ``states[k − 1]`` into ``states[k]``, and ``impulses (n, 2 m)``
    the impulses ``[μ⁻ | μ⁺]`` (N s per row) that act at each node, at the start of the step from it and at the
    end of the step into it. Returns with the status in ``io`` (:data:`COMPLETED` …) and ``io[IO_STEP]`` the first
    step not taken. A call at step 1 starts from ``states[0]``; a later one goes on from the state the last call
    left in ``ws`` (:func:`memory_size`, then :func:`workspace_size`).

    ``controller(t, q, v, out)``: the plan's compiled controller (``FUNCTION``; called for no other);
    ``plan``: :data:`PLAN_HEADER` and its blocks; ``control``: ``[τ (nv) | PD block]``
    (:func:`multibody.kernels.stepping.pd_torque`)."""
    nq, nv, m = int(plan[PLAN_NQ]), int(plan[PLAN_NV]), int(plan[PLAN_M])
    grouped = plan[PLAN_GROUPED] != 0.0
    trapezoidal = plan[PLAN_TRAPEZOIDAL] != 0.0
    tolerance, max_iterations = plan[PLAN_TOLERANCE], int(plan[PLAN_MAX_ITERATIONS])
    rank_tolerance = plan[PLAN_RANK_TOLERANCE]
    substeps = int(plan[PLAN_SUBSTEPS])
    group = plan[PLAN_GROUPED : PLAN_GROUPED + 1] if grouped else plan[:0]
    none = plan[:0]
    columns = m * nv + 2 * m + 1
    # the state kept between calls
    at = 0
    q = ws[at : at + nq]
    at += nq
    p = ws[at : at + nv]
    at += nv
    w = ws[at : at + nv]
    at += nv
    w_before = ws[at : at + nv]
    at += nv
    history = ws[at : at + 5]  # h_before, the count of equal increments, their three h
    at += 5
    increments = ws[at : at + 3 * nv].reshape((3, nv))
    at += 3 * nv
    last_impulse = ws[at : at + m + 1]  # μ⁻ of the last step, then whether there is one
    at += m + 1
    # the step's vectors
    vectors = ws[at : at + 16 * nv]
    at += 16 * nv
    xi, start, pull, forces = vectors[:nv], vectors[nv : 2 * nv], vectors[2 * nv : 3 * nv], vectors[3 * nv : 4 * nv]
    v, tau, y, delta = vectors[4 * nv : 5 * nv], vectors[5 * nv : 6 * nv], vectors[6 * nv : 7 * nv], vectors[7 * nv : 8 * nv]
    F, F_before = vectors[8 * nv : 9 * nv], vectors[9 * nv : 10 * nv]
    delta_before, residual = vectors[10 * nv : 11 * nv], vectors[11 * nv : 12 * nv]
    base, shifted, f, scratch = (vectors[12 * nv : 13 * nv], vectors[13 * nv : 14 * nv], vectors[14 * nv : 15 * nv],
                                 vectors[15 * nv : 16 * nv])
    q_mid, q1, q_shift = ws[at : at + nq], ws[at + nq : at + 2 * nq], ws[at + 2 * nq : at + 3 * nq]
    at += 3 * nq
    mu, c, scales = ws[at : at + m], ws[at + m : at + 2 * m], ws[at + 2 * m : at + 3 * m]
    rhs, mu_plus, sigma, pivots = (ws[at + 3 * m : at + 4 * m], ws[at + 4 * m : at + 5 * m], ws[at + 5 * m : at + 6 * m],
                                   ws[at + 6 * m : at + 7 * m])
    at += 7 * m
    terms = ws[at : at + (nv + 1) * nv].reshape((nv + 1, nv))
    at += (nv + 1) * nv
    # the step's matrices
    blocks = ws[at : at + 12 * nv * nv].reshape((12 * nv, nv))
    at += 12 * nv * nv
    M0, M, J, J_inverse = blocks[:nv], blocks[nv : 2 * nv], blocks[2 * nv : 3 * nv], blocks[3 * nv : 4 * nv]
    K, H, S, K1 = blocks[4 * nv : 5 * nv], blocks[5 * nv : 6 * nv], blocks[6 * nv : 7 * nv], blocks[7 * nv : 8 * nv]
    T, work = blocks[8 * nv : 9 * nv], blocks[9 * nv : 11 * nv]
    J_pivots = blocks[11 * nv]
    exponentials = ws[at : at + 4 * nv * nv].reshape((4 * nv, nv))
    at += 4 * nv * nv
    back = ws[at : at + 2 * nv * nv].reshape((2 * nv, nv))
    at += 2 * nv * nv
    rows = ws[at : at + 3 * columns].reshape((3, columns))
    at += 3 * columns
    B, C = ws[at : at + m * nv].reshape((m, nv)), ws[at + m * nv : at + 2 * m * nv].reshape((m, nv))
    A1, Ji_Bt = ws[at + 2 * m * nv : at + 3 * m * nv].reshape((m, nv)), ws[at + 3 * m * nv : at + 4 * m * nv].reshape((m, nv))
    at += 4 * m * nv
    schur, U = ws[at : at + m * m].reshape((m, m)), ws[at + m * m : at + 2 * m * m].reshape((m, m))
    at += 2 * m * m
    (A_solve, gamma, phi, W, Y, V, sigma_solve, solve_rhs, coefficients, magnitudes, solve_scratch, order, norms,
     at) = kkt.solve_workspace(ws, at, m, nv)
    kernel_ws = ws[at:]
    weights = plan[PLAN_WEIGHTS : PLAN_WEIGHTS + substeps]

    k, stop = int(io[IO_STEP]), int(io[IO_STOP])
    if k == 1:
        # the run's start: w = T(q)ᵀ v, p = M(q) w, no history
        for r in range(nq):
            q[r] = states[0, r]
        if grouped:
            group_alignment(joints, q, T)
        for r in range(nv):
            total = 0.0
            for j in range(nv):
                total += (T[j, r] if grouped else (1.0 if j == r else 0.0)) * states[0, nq + j]
            w[r] = total
            y[r] = 0.0
        lagrangian.lagrangian_terms(joints, reals, frames, q, y, group, none, terms, kernel_ws)
        for r in range(nv):
            total = 0.0
            for j in range(nv):
                total += terms[r, j] * w[j]
            p[r] = total
        for j in range(5):
            history[j] = 0.0
        last_impulse[m] = 0.0
        io[IO_EVALUATIONS] = 0.0
    while k < stop:
        t = times[k - 1]
        step = times[k] - t
        for sub in range(substeps):
            h = weights[sub] * step
            io[IO_TIME], io[IO_STEP_SIZE] = t, h
            count = int(history[1])
            predict(h, w, w_before, history[0], count, history[2:5], increments, delta)
            # the constraint impulses change little from step to step: the last one, per unit time
            for r in range(m):
                mu[r] = last_impulse[r] * (h / history[0]) if last_impulse[m] != 0.0 else 0.0
            independent = True
            if trapezoidal or m > 0:
                for r in range(nv):
                    y[r] = 0.0
                lagrangian.lagrangian_terms(joints, reals, frames, q, y, group, none, terms, kernel_ws)
                for r in range(nv):
                    for j in range(nv):
                        M0[r, j] = terms[r, j]
            if m > 0:
                # every row's impulse at the start acts along A(q_k)ᵀ; independent rows give their impulses by a
                # direct solve, redundant ones the minimum-norm impulses (the rank decision of the compiled step)
                constraints.constraint_levels(joints, reals, frames, q, none, none, program, rows[2:3], kernel_ws)
                if rows[2, columns - 1] != 0.0:
                    io[IO_STEP], io[IO_STATUS] = k, UNDEFINED_ROW
                    return
                for r in range(m):
                    for j in range(nv):
                        B[r, j] = rows[2, r * nv + j]
                if grouped:
                    lagrangian.to_group_velocities(joints, q, B)
                for r in range(nv):
                    for j in range(nv):
                        work[r, j] = M0[r, j]
                if not kkt.cholesky(work, nv):
                    io[IO_STEP], io[IO_STATUS] = k, NOT_POSITIVE_DEFINITE
                    return
                for r in range(m):
                    solve_rhs[r] = 0.0
                rank, _, _ = kkt.metric_solve(work, B, W, Y, solve_scratch, V, sigma_solve, solve_rhs, rank_tolerance,
                                              m, nv, coefficients, magnitudes, gamma, order, norms)
                independent = rank == m
            # Newton's iteration on Δ (and μ⁻)
            size_p0 = largest(p)
            formed, have_before = False, False
            converged = False
            error = math.nan
            iteration = 0
            for iteration in range(1, max_iterations + 1):
                status, scale = equations(controller, joints, reals, frames, program, plan, control, t, h, q, delta, M0,
                                          xi, q_mid, q1, M, pull, start, exponentials, back, terms, T, forces, v, tau,
                                          y, rows, c, C, scales, A1, io, kernel_ws)
                io[IO_EVALUATIONS] += 1.0
                if status != 0:
                    io[IO_STEP], io[IO_STATUS] = k, status
                    return
                # residual = −D1 L_d − f⁻ − p_k − Bᵀ μ⁻
                impulse_size = 0.0
                for r in range(nv):
                    impulse = 0.0
                    for i in range(m):
                        impulse += B[i, r] * mu[i]
                    impulse_size = larger(impulse_size, abs(impulse))
                    F[r] = start[r] - p[r]
                    residual[r] = F[r] - impulse
                scale = larger(larger(larger(scale, impulse_size), size_p0), 1e-300) if scale == scale else math.nan
                error = largest(residual) / scale
                for i in range(m):
                    ratio = abs(c[i] / scales[i])
                    if error == error and not ratio <= error:  # (a NaN ratio too)
                        error = ratio
                if not math.isfinite(error):
                    io[IO_STEP], io[IO_STATUS], io[IO_ERROR], io[IO_ITERATIONS] = k, NON_FINITE_RESIDUAL, error, iteration
                    return
                if error <= tolerance:
                    converged = True
                    break
                # J⁻¹ of the analytical Jacobian once per step, Broyden's updates after
                if not formed:
                    if not newton_jacobian(controller, joints, reals, frames, plan, control, t, h, q, delta, q_mid, q1,
                                           M0, M, J, K, H, S, K1, T, work, terms, xi, v, scratch, q_shift, base, shifted,
                                           f, tau, kernel_ws, io):
                        io[IO_STEP], io[IO_STATUS] = k, NON_FINITE_TORQUE
                        return
                    # J⁻¹, column by column
                    if not lu_factor(J, nv, J_pivots):
                        io[IO_STEP], io[IO_STATUS] = k, SINGULAR
                        return
                    for j in range(nv):
                        for r in range(nv):
                            y[r] = 1.0 if r == j else 0.0
                        lu_solve(J, nv, J_pivots, y)
                        for r in range(nv):
                            J_inverse[r, j] = y[r]
                    formed = True
                elif have_before:
                    # Broyden's update of J⁻¹ from the last step s and the change y of −D1 L_d − f⁻ (Dennis and
                    # Schnabel 1983, Chapter 8, inverted by Sherman–Morrison): it supplies the second derivatives
                    # the analytical J leaves out.  J⁻¹ += (s − J⁻¹ y) (sᵀ J⁻¹) / (sᵀ J⁻¹ y)
                    denominator = 0.0
                    for r in range(nv):
                        s_r = delta[r] - delta_before[r]
                        total = 0.0
                        for j in range(nv):
                            total += J_inverse[r, j] * (F[j] - F_before[j])
                        base[r] = total  # J⁻¹ y
                        denominator += s_r * total
                    for j in range(nv):
                        total = 0.0
                        for r in range(nv):
                            total += (delta[r] - delta_before[r]) * J_inverse[r, j]
                        shifted[j] = total  # sᵀ J⁻¹
                    if denominator != 0.0:
                        for r in range(nv):
                            s_r = delta[r] - delta_before[r]
                            for j in range(nv):
                                J_inverse[r, j] += (s_r - base[r]) * shifted[j] / denominator
                for r in range(nv):
                    delta_before[r] = delta[r]
                    F_before[r] = F[r]
                have_before = True
                if m > 0:
                    # J δ − Bᵀ μ_new = −(start − p_k),  C δ = −c: the Schur complement C J⁻¹ Bᵀ gives μ_new (minimum
                    # norm when rows are redundant), then δ
                    for r in range(nv):
                        total = 0.0
                        for j in range(nv):
                            total += J_inverse[r, j] * F[j]
                        base[r] = total  # J⁻¹ F
                    for i in range(m):
                        for r in range(nv):
                            total = 0.0
                            for j in range(nv):
                                total += J_inverse[r, j] * B[i, j]
                            Ji_Bt[i, r] = total
                    for i in range(m):
                        total = -c[i]
                        for r in range(nv):
                            total += C[i, r] * base[r]
                        rhs[i] = total
                        for l in range(m):
                            total = 0.0
                            for r in range(nv):
                                total += C[i, r] * Ji_Bt[l, r]
                            schur[i, l] = total
                    if independent:
                        if not lu_factor(schur, m, pivots):
                            io[IO_STEP], io[IO_STATUS] = k, SINGULAR
                            return
                        for i in range(m):
                            mu[i] = rhs[i]
                        lu_solve(schur, m, pivots, mu)
                    else:
                        minimum_norm_solve(schur, U, sigma, rhs, 1e-10, mu)
                    for r in range(nv):
                        total = delta[r] - base[r]
                        for i in range(m):
                            total += Ji_Bt[i, r] * mu[i]
                        delta[r] = total
                else:
                    for r in range(nv):
                        total = 0.0
                        for j in range(nv):
                            total += J_inverse[r, j] * residual[j]
                        y[r] = total
                    for r in range(nv):
                        delta[r] -= y[r]
            if not converged:
                io[IO_STEP], io[IO_STATUS], io[IO_ERROR], io[IO_ITERATIONS] = k, NOT_CONVERGED, error, max_iterations
                return
            # p_{k+1} = p_k + (D1 L_d + D2 L_d) + f⁻ + f⁺ + impulses: the momentum balance of the step; on Lie-group
            # joints p_{k+1} = Ad_exp(Δ)ᵀ p_k + h Ad_exp(Δ/2)ᵀ (∂L/∂q(q̄, ξ) + τ̄) (midpoint)
            for r in range(nv):
                total = p[r]
                for i in range(m):
                    total += B[i, r] * mu[i]
                base[r] = total  # p_k + A(q_k)ᵀ μ⁻
            Ad, Ad_half = exponentials[:nv], exponentials[2 * nv : 3 * nv]
            if not trapezoidal:
                for r in range(nv):
                    total_start, total_pull = 0.0, 0.0
                    for j in range(nv):
                        total_start += Ad[j, r] * base[j]
                        total_pull += Ad_half[j, r] * pull[j]
                    f[r] = total_start + h * total_pull
                # M(q_{k+1})
                for r in range(nv):
                    y[r] = 0.0
                lagrangian.lagrangian_terms(joints, reals, frames, q1, y, group, none, terms, kernel_ws)
                for r in range(nv):
                    for j in range(nv):
                        M[r, j] = terms[r, j]
            else:
                # p_{k+1} = Ad_exp(Δ)ᵀ (p_k + (h/2) (∂L/∂q(q_k, ξ) + τ_k)) + (h/2) (∂L/∂q(q_{k+1}, ξ) + τ_{k+1})
                for r in range(nv):
                    shifted[r] = base[r] + 0.5 * h * pull[r]
                for r in range(nv):
                    total = 0.0
                    for j in range(nv):
                        total += Ad[j, r] * shifted[j]
                    f[r] = total
                for r in range(nv):
                    xi[r] = delta[r] / h
                lagrangian.lagrangian_terms(joints, reals, frames, q1, xi, group, none, terms, kernel_ws)
                if plan[PLAN_CONTROL] != stepping.NO_CONTROL or plan[PLAN_DAMPED] != 0.0:
                    if grouped:
                        group_alignment(joints, q1, T)
                    if not joint_forces(controller, joints, plan, control, t + h, q1, xi, T, v, tau, forces,
                                        kernel_ws, io):
                        io[IO_STEP], io[IO_STATUS] = k, NON_FINITE_TORQUE
                        return
                else:
                    for r in range(nv):
                        forces[r] = 0.0
                for r in range(nv):
                    f[r] += 0.5 * h * (terms[nv, r] + forces[r])
            # v_{k+1} = M(q_{k+1})⁻¹ p_{k+1}
            for r in range(nv):
                for j in range(nv):
                    work[r, j] = M[r, j]
            if not kkt.cholesky(work, nv):
                io[IO_STEP], io[IO_STATUS] = k, NOT_POSITIVE_DEFINITE
                return
            for r in range(nv):
                y[r] = f[r]
            kkt.cholesky_solve(work, nv, y)
            if m > 0:
                # p_{k+1} += A(q_{k+1})ᵀ μ⁺ with A v_{k+1} = 0: the M-orthogonal projection of the velocity
                for i in range(m):
                    total = 0.0
                    for r in range(nv):
                        total += A1[i, r] * y[r]
                    solve_rhs[i] = -total
                kkt.metric_solve(work, A1, W, Y, solve_scratch, V, sigma_solve, solve_rhs, rank_tolerance, m, nv,
                                 coefficients, magnitudes, mu_plus, order, norms)
                for r in range(nv):
                    for i in range(m):
                        f[r] += A1[i, r] * mu_plus[i]
                        y[r] += Y[i, r] * mu_plus[i]
            # the node's history: the last velocity, step and impulses, and the last three increments
            for r in range(nv):
                w_before[r] = w[r]
                w[r] = y[r]
                p[r] = f[r]
            for r in range(nq):
                q[r] = q1[r]
            history[0] = h
            for j in (2, 1):
                history[2 + j] = history[1 + j]
                for r in range(nv):
                    increments[j, r] = increments[j - 1, r]
            history[2] = h
            for r in range(nv):
                increments[0, r] = delta[r]
            history[1] = smaller(count + 1, 3)
            for i in range(m):
                last_impulse[i] = mu[i]
            last_impulse[m] = 1.0
            t = t + h
        for i in range(m):
            impulses[k - 1, i] += mu[i]
            impulses[k, m + i] = mu_plus[i]
        end = states[k]
        for r in range(nq):
            end[r] = q[r]
        if grouped:
            group_alignment(joints, q, T)
        for r in range(nv):
            total = 0.0
            for j in range(nv):
                total += (T[r, j] if grouped else (1.0 if r == j else 0.0)) * w[j]
            end[nq + r] = total
        # (a step's equations can hold with v = M⁻¹ p overflowing: such a state is not kept)
        if not all_finite(end):
            io[IO_TIME] = times[k]
            io[IO_STEP], io[IO_STATUS] = k, NON_FINITE_STATE
            return
        k += 1
    io[IO_STEP], io[IO_STATUS] = k, COMPLETED
