"""Inverse kinematics of one state: projected Levenberg–Marquardt on SE(3) errors, with restarts.

The method, its sources and its options are described in :mod:`multibody.ik`; this module is its
compiled loop, one problem per call, so that the batch driver runs many problems in parallel and a
problem stops as soon as it has converged.

Inputs of :func:`inverse_kinematics` (the kernel signature of :mod:`multibody.driver`):

* ``frames (k, 13)``: the rows of the targeted frames (:mod:`multibody.tree`);
* ``q0 (nq,)``: the start, within the limits;
* ``targets (12 k,)``: per frame ``[R_WT (9, row-major), p_WT (3)]``, the world pose of the target (a
  position target reads ``p_WT`` only);
* ``posture (nq,)``: the configuration pursued in the null space of the targets (length 0: none);
* ``options``: one vector for every state, laid out as the constants ``TOL`` … ``KINDS`` below, then
  ``kind (k)`` (``POSE`` or ``POSITION``), ``lower (nq)``, ``upper (nq)`` (finite: ``±BIG`` where
  unbounded; read for angles and displacements only) and ``restarts × CANDIDATES`` configurations
  ``(nq)`` to restart from, within the limits.

Output ``out (1, nq + m + 1)``: the best configuration found, its stacked error ``e (m)`` (6 rows per
pose target, ``[ρ; θ]``; 3 per position target) and the number of steps tried.

Errors and Jacobians (``∂e/∂δ`` for the tangent step ``q ⊕ δ``)::

    pose:      e = log(X_WT⁻¹ X_WF) = [ρ; θ],  ∂e/∂δ = J_r(e)⁻¹ J_F        (J_F: LOCAL Jacobian)
    position:  e = p_WF − p_WT,               ∂e/∂δ = linear rows of the LOCAL_WORLD_ALIGNED Jacobian

with the inverse right Jacobian of SE(3) (J. Solà, J. Deray and D. Atchuthan, "A micro Lie theory for
state estimation in robotics", 2018, App. B for SO(3) and App. D for SE(3), where ``J_r(τ) = J_l(−τ)``;
rows ``[linear; angular]``)::

    J_r(ρ, θ)⁻¹ = [[J_r3⁻¹, −J_r3⁻¹ Q_r J_r3⁻¹], [0, J_r3⁻¹]],   J_r3(θ)⁻¹ = I + ½ [θ]× + k [θ]×²,
    k = 1/θ² − (1 + cos θ)/(2 θ sin θ),
    Q_r(ρ, θ) = Q_l(−ρ, −θ),
    Q_l(ρ, θ) = ½ P + c₁ (T P + P T + T P T) + c₂ (T² P + P T² − 3 T P T) + c₃ (T P T² + T² P T)

(``P = [ρ]×``, ``T = [θ]×``, ``c₁ = (θ − sin θ)/θ³``, ``c₂ = (θ² + 2 cos θ − 2)/(2θ⁴)``,
``c₃ = (2θ − 3 sin θ + θ cos θ)/(2θ⁵)``).
"""

from __future__ import annotations

import math

from .layout import IQ, IV, KIND, NQ, NV
from . import joints as kinds
from .jit import njit
from .kinematics import frame_joint, frame_pose, jacobian_columns, joint_placements, mark_supports, world_position
from .kkt import cholesky, cholesky_solve
from .spatial import (IDENTITY, add3, compose_rotations, dot3, larger, load3, load9, nan_unless_finite, rotate,
                      rotate_back, smaller, sub3)

#: Entries of the options vector (module docstring); the frame kinds start at ``KINDS``.
TOL, MAX_ITERATIONS, DAMPING, POSTURE_WEIGHT, RESTARTS, STEP_TOL, WINDOW, PROGRESS, CANDIDATES, KINDS = range(10)
#: Kind of a target.
POSITION, POSE = 0.0, 1.0
#: Stand-in for an infinite limit in the options (which must be finite: a kernel's non-finite input
#: makes its output NaN).
BIG = 1e300
#: Floor ``μ₀`` of the damping ``μ = λ ‖e‖² + μ₀`` (m², rad²): keeps the damped system regular where the
#: Jacobian loses rank.
DAMPING_FLOOR = 1e-12
#: Damping ``ε`` of the null-space projector of the posture step.
PROJECTOR_DAMPING = 1e-6
#: While the posture is pursued, a null-space step may raise ``‖e‖`` to this (m and rad) ...
POSTURE_BAND = 1e-2
#: ... which target steps, at most this many, bring back below ``tol`` ...
RESTORING_STEPS = 10
#: ... until a step brings the configuration less than this nearer to the posture (``‖q_ref ⊖ q‖``, rad or m),
POSTURE_TOL = 1e-9
#: ... or the step towards it, halved after each refusal, falls below this fraction of the full one.
POSTURE_BETA_MIN = 1.0 / 1024.0
#: Bounds of the adaptive factor λ.
LAMBDA_MIN, LAMBDA_MAX = 1e-12, 1e12
#: Below this angle (rad) the coefficients c₁, c₂, c₃ of Q_l, whose closed forms cancel digits (c₃'s loses
#: ~60 ε/θ⁴ relative), take five terms of their Taylor series (truncation ~1e-12 relative at the threshold) ...
SERIES_ANGLE = 0.5
#: ... and the coefficient k of J_r3⁻¹ below this one (closed form ~12 ε/θ², truncation ~1e-20 there).
K_SERIES_ANGLE = 0.1


def workspace_size(nj, nq, nv, m):
    """Floats of workspace one problem needs: the joint poses and the marks of the joints needed
    (``13 nj + 12``), a frame Jacobian (``6 nv``), three configurations, three error vectors, the error
    Jacobian, five velocity-sized vectors, the damped system (``s²``, ``s = min(m, nv)``) and two solver
    vectors."""
    s = min(m, nv)
    return 13 * nj + 12 + 6 * nv + 3 * nq + 3 * m + m * nv + 5 * nv + s * s + 2 * max(m, nv)


def output_columns(nq, m):
    """Columns of the output row: ``q (nq)``, ``e (m)``, the number of steps."""
    return nq + m + 1


# ----------------------------------------------------------------------------- SE(3) right Jacobian

@njit(cache=True, error_model="numpy")
def q_coefficients(theta):
    """``(c₁, c₂, c₃)`` of ``Q_l`` (module docstring) at the angle ``θ ≥ 0``."""
    t2 = theta * theta
    if theta < SERIES_ANGLE:
        c1 = 1.0 / 6.0 + t2 * (-1.0 / 120.0 + t2 * (1.0 / 5040.0 + t2 * (-1.0 / 362880.0 + t2 / 39916800.0)))
        c2 = 1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40320.0 + t2 * (-1.0 / 3628800.0 + t2 / 479001600.0)))
        c3 = 1.0 / 120.0 + t2 * (-1.0 / 2520.0 + t2 * (1.0 / 120960.0 + t2 * (-1.0 / 9979200.0 + t2 / 1245404160.0)))
        return c1, c2, c3
    s, c = math.sin(theta), math.cos(theta)
    return (theta - s) / (t2 * theta), (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2), (2.0 * theta - 3.0 * s + theta * c) / (
        2.0 * t2 * t2 * theta)


@njit(cache=True, error_model="numpy")
def jr3_coefficient(theta):
    """``k = 1/θ² − (1 + cos θ)/(2 θ sin θ)`` of ``J_r3(θ)⁻¹ = I + ½ [θ]× + k [θ]×²`` at the angle ``θ ≥ 0``
    (Solà et al. 2018, App. B); five terms of its series below ``K_SERIES_ANGLE``, where the closed form
    cancels digits."""
    t2 = theta * theta
    if theta < K_SERIES_ANGLE:
        return 1.0 / 12.0 + t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 * (1.0 / 1209600.0 + t2 / 47900160.0)))
    # (1 + cos θ)/sin θ = cot(θ/2), which stays finite at θ = π, the largest angle of a logarithm
    half = 0.5 * theta
    return (1.0 - half / math.tan(half)) / t2


@njit(cache=True, error_model="numpy")
def skew9(x):
    """``[x]×`` as a row-major 9-tuple."""
    return (0.0, -x[2], x[1], x[2], 0.0, -x[0], -x[1], x[0], 0.0)


@njit(cache=True, error_model="numpy")
def combine9(a, A, b, B):
    """``a A + b B`` of two 3×3 row-major 9-tuples."""
    return (a * A[0] + b * B[0], a * A[1] + b * B[1], a * A[2] + b * B[2], a * A[3] + b * B[3], a * A[4] + b * B[4],
            a * A[5] + b * B[5], a * A[6] + b * B[6], a * A[7] + b * B[7], a * A[8] + b * B[8])


@njit(cache=True, error_model="numpy")
def right_jacobian_inverse_blocks(rho, theta):
    """The blocks ``(B, C)`` of ``J_r(ρ, θ)⁻¹ = [[B, C], [0, B]]`` of SE(3) (module docstring) as 3×3 row-major
    9-tuples: ``B = J_r3(θ)⁻¹ = I + ½ T + k T²`` and ``C = −B Q_r B``, where ``Q_r = Q_l(−ρ, −θ)`` is
    ``−½ P + c₁ (T P + P T − T P T) − c₂ (T² P + P T² − 3 T P T) + c₃ (T P T² + T² P T)``
    (``P = [ρ]×``, ``T = [θ]×``)."""
    angle = math.sqrt(dot3(theta, theta))
    c1, c2, c3 = q_coefficients(angle)
    T, P = skew9(theta), skew9(rho)
    TT, TP, PT = compose_rotations(T, T), compose_rotations(T, P), compose_rotations(P, T)
    TPT = compose_rotations(TP, T)
    Q = combine9(-0.5, P, c1, combine9(1.0, combine9(1.0, TP, 1.0, PT), -1.0, TPT))
    Q = combine9(1.0, Q, -c2, combine9(1.0, combine9(1.0, compose_rotations(T, TP), 1.0, compose_rotations(PT, T)),
                                       -3.0, TPT))
    Q = combine9(1.0, Q, c3, combine9(1.0, compose_rotations(TPT, T), 1.0, compose_rotations(T, TPT)))
    B = combine9(1.0, combine9(1.0, IDENTITY, 0.5, T), jr3_coefficient(angle), TT)
    return B, combine9(-1.0, compose_rotations(compose_rotations(B, Q), B), 0.0, B)


# ----------------------------------------------------------------------------- errors

@njit(cache=True, error_model="numpy")
def errors(joints, reals, frames, targets, options, q, pose_ws, e):
    """The stacked error ``e (m,)`` of the targets at ``q`` (module docstring), leaving the joint poses in
    ``pose_ws`` (its first ``12 (nj + 1)`` entries; the next ``nj`` mark the joints needed, see
    :func:`mark_supports`) for :func:`error_jacobian`. Returns ``‖e‖²``."""
    nj = joints.shape[0]
    pose, _ = joint_placements(joints, reals, q, pose_ws, pose_ws[12 * (nj + 1) : 13 * nj + 12])
    r = 0
    for k in range(frames.shape[0]):
        R_WF, p_OF = frame_pose(pose, frames, k)
        p_WF = world_position(pose, p_OF)
        p_WT = load3(targets, 12 * k + 9)
        if options[KINDS + k] == POSITION:
            # e = p_WF − p_WT
            d = sub3(p_WF, p_WT)
            for i in range(3):
                e[r + i] = d[i]
            r += 3
            continue
        R_WT = load9(targets, 12 * k)
        # X_TF = X_WT⁻¹ X_WF = (R_WTᵀ R_WF, R_WTᵀ (p_WF − p_WT)),  e = log X_TF = [V(θ)⁻¹ p_TF; θ]
        R_TF = compose_rotations(kinds.transpose_rotation(R_WT), R_WF)
        p_TF = rotate_back(R_WT, sub3(p_WF, p_WT))
        theta = kinds.quat_log(kinds.rotation_to_quat(R_TF))
        rho = kinds.so3_left_jacobian_inverse_times(theta, p_TF)
        for i in range(3):
            e[r + i] = rho[i]
            e[r + 3 + i] = theta[i]
        r += 6
    cost = 0.0
    for i in range(e.shape[0]):
        cost += e[i] * e[i]
    return cost


@njit(cache=True, error_model="numpy")
def error_jacobian(joints, reals, frames, options, pose_ws, e, J, A):
    """The Jacobian ``A = ∂e/∂δ (m, nv)`` of the errors ``e`` that :func:`errors` has just computed (from
    the joint poses it left in ``pose_ws``); ``J (6, nv)`` holds a frame's Jacobian."""
    nj = joints.shape[0]
    pose = pose_ws[: 12 * (nj + 1)].reshape((nj + 1, 12))
    nv = A.shape[1]
    r = 0
    for k in range(frames.shape[0]):
        R_WF, p_OF = frame_pose(pose, frames, k)
        # world-aligned Jacobian at F's origin (LOCAL_WORLD_ALIGNED)
        jacobian_columns(joints, reals, pose, frame_joint(frames, k), p_OF, J)
        if options[KINDS + k] == POSITION:
            # ∂e/∂δ = J_linear
            for i in range(3):
                for c in range(nv):
                    A[r + i, c] = J[i, c]
            r += 3
            continue
        # ∂e/∂δ = J_r(e)⁻¹ J_local,  J_local = diag(R_WFᵀ, R_WFᵀ) J_world-aligned:
        # [[B, C], [0, B]] diag(R_WFᵀ, R_WFᵀ) = [[B R_WFᵀ, C R_WFᵀ], [0, B R_WFᵀ]]
        B, C = right_jacobian_inverse_blocks((e[r], e[r + 1], e[r + 2]), (e[r + 3], e[r + 4], e[r + 5]))
        R_FW = kinds.transpose_rotation(R_WF)
        BR, CR = compose_rotations(B, R_FW), compose_rotations(C, R_FW)
        for c in range(nv):
            u, w = (J[0, c], J[1, c], J[2, c]), (J[3, c], J[4, c], J[5, c])
            a, b = add3(rotate(BR, u), rotate(CR, w)), rotate(BR, w)
            for i in range(3):
                A[r + i, c] = a[i]
                A[r + 3 + i, c] = b[i]
        r += 6


# ----------------------------------------------------------------------------- the damped step

@njit(cache=True, error_model="numpy")
def damped_solve(A, free, r, mu, G, y, x):
    """``x = A_fᵀ (A_f A_fᵀ + μ I)⁻¹ r = (A_fᵀ A_f + μ I)⁻¹ A_fᵀ r`` with ``A_f`` the columns of
    ``A (m, nv)`` where ``free`` is nonzero (the others give ``x = 0``), by Cholesky of the smaller
    system ``G``; ``y`` is scratch. Returns ``False`` when the factorization fails."""
    m, nv = A.shape
    if m <= nv:
        # G = A_f A_fᵀ + μ I  (m × m),  x = A_fᵀ G⁻¹ r
        for i in range(m):
            for j in range(i + 1):
                s = 0.0
                for c in range(nv):
                    s += A[i, c] * A[j, c] * free[c]
                G[i, j] = s
                G[j, i] = s
            G[i, i] += mu
            y[i] = r[i]
        if not cholesky(G, m):
            return False
        cholesky_solve(G, m, y)
        for c in range(nv):
            s = 0.0
            for i in range(m):
                s += A[i, c] * y[i]
            x[c] = s * free[c]
        return True
    # G = A_fᵀ A_f + μ I  (nv × nv),  x = G⁻¹ A_fᵀ r
    for a in range(nv):
        for b in range(a + 1):
            s = 0.0
            for i in range(m):
                s += A[i, a] * A[i, b]
            G[a, b] = s * free[a] * free[b]
            G[b, a] = G[a, b]
        G[a, a] += mu
        s = 0.0
        for i in range(m):
            s += A[i, a] * r[i]
        x[a] = s * free[a]
    if not cholesky(G, nv):
        return False
    cholesky_solve(G, nv, x)
    return True


@njit(cache=True, error_model="numpy")
def is_vector_space(kind):
    """Whether a joint kind's coordinates are angles and displacements (the ones with limits to keep)."""
    return kind == kinds.REVOLUTE or kind == kinds.PRISMATIC or kind == kinds.TRANSLATION


@njit(cache=True, error_model="numpy")
def set_free(joints, options, lower, q, direction, free):
    """``free[c] = 0`` for each angle or displacement on a bound that ``direction (nv,)`` (the step's
    intent: the steepest descent ``−Aᵀ e`` of the targets, or the way to the posture) points out of,
    ``1`` otherwise (the active set of the bound constraints)."""
    for c in range(free.shape[0]):
        free[c] = 1.0
    upper = lower + q.shape[0]
    for j in range(joints.shape[0]):
        if not is_vector_space(joints[j, KIND]):
            continue
        for k in range(joints[j, NQ]):
            iq, c = joints[j, IQ] + k, joints[j, IV] + k
            if (q[iq] <= options[lower + iq] and direction[c] < 0.0) or (
                    q[iq] >= options[upper + iq] and direction[c] > 0.0):
                free[c] = 0.0


@njit(cache=True, error_model="numpy")
def step_to(joints, options, lower, q, delta, q_new):
    """``q_new = q ⊕ δ`` with the step cut at the box of the angles and displacements:
    ``lower − q ≤ δ ≤ upper − q`` (``δ`` is cut in place)."""
    nq = q.shape[0]
    upper = lower + nq
    for j in range(joints.shape[0]):
        kind, iq, iv = joints[j, KIND], joints[j, IQ], joints[j, IV]
        if is_vector_space(kind):
            for k in range(joints[j, NQ]):
                lo, hi = options[lower + iq + k], options[upper + iq + k]
                delta[iv + k] = smaller(larger(delta[iv + k], lo - q[iq + k]), hi - q[iq + k])
                # the sum may round past a bound by an ulp
                q_new[iq + k] = smaller(larger(q[iq + k] + delta[iv + k], lo), hi)
        else:
            kinds.integrate(kind, joints[j, NV], q, delta, iq, iv, q_new)


@njit(cache=True, error_model="numpy")
def take_best(joints, reals, frames, targets, options, start, count, q, e, cost, pose_ws, q_trial, e_trial):
    """Replace ``q`` (and its errors ``e``) by the configuration of smallest error among the ``count``
    rows of ``nq`` entries of ``options`` from ``start``, if its ``‖e‖²`` is below ``cost``. Returns the
    ``‖e‖²`` of ``q``."""
    nq = q.shape[0]
    for candidate in range(count):
        for i in range(nq):
            q_trial[i] = options[start + candidate * nq + i]
        cost_trial = errors(joints, reals, frames, targets, options, q_trial, pose_ws, e_trial)
        if cost_trial < cost:
            cost = cost_trial
            for i in range(nq):
                q[i] = q_trial[i]
            for i in range(e.shape[0]):
                e[i] = e_trial[i]
    return cost


@njit(cache=True, error_model="numpy")
def predicted_cost(A, e, delta):
    """``‖e + A δ‖²``: the cost the linear model predicts after the step ``δ``."""
    total = 0.0
    for i in range(A.shape[0]):
        t = e[i]
        for c in range(A.shape[1]):
            t += A[i, c] * delta[c]
        total += t * t
    return total


@njit(cache=True, error_model="numpy")
def posture_distance(joints, q, posture, difference):
    """``‖q_ref ⊖ q‖`` (rad and m), leaving ``q_ref ⊖ q`` in ``difference (nv,)``."""
    for j in range(joints.shape[0]):
        kinds.difference(joints[j, KIND], joints[j, NV], q, posture, joints[j, IQ], joints[j, IV], difference)
    total = 0.0
    for c in range(difference.shape[0]):
        total += difference[c] * difference[c]
    return math.sqrt(total)


@njit(cache=True, error_model="numpy")
def null_space_posture(A, free, difference, weight, d, r, G, y, n):
    """``n = N d`` into ``n (nv,)``, ``d = w (q_ref ⊖ q)`` from ``difference = q_ref ⊖ q`` on the free
    coordinates, with the projector ``N = I − A_fᵀ (A_f A_fᵀ + ε I)⁻¹ A_f`` onto the null space of the
    targets (:mod:`multibody.ik`). Returns ``‖n‖²``."""
    nv = d.shape[0]
    for c in range(nv):
        d[c] = weight * difference[c] * free[c]
    for i in range(A.shape[0]):
        t = 0.0
        for c in range(nv):
            t += A[i, c] * d[c]
        r[i] = t
    if not damped_solve(A, free, r, PROJECTOR_DAMPING, G, y, n):
        return 0.0
    norm2 = 0.0
    for c in range(nv):
        n[c] = d[c] - n[c]
        norm2 += n[c] * n[c]
    return norm2


@njit(cache=True, error_model="numpy")
def task_step(joints, reals, frames, targets, options, lower, q, e, A, cost, lam, pose_ws, J, q_trial, e_trial,
              direction, free, delta, r, G, y):
    """One projected Levenberg–Marquardt step on the targets from ``q`` (errors ``e``, Jacobian ``A``,
    ``cost = ‖e‖²``), updating ``q``, ``e``, ``A`` in place when the step is accepted (it lowers the cost).
    Returns ``(cost, λ, solved, ‖δ‖²)``."""
    m, nv = A.shape
    # the steepest descent −Aᵀ e, to freeze the coordinates on a bound that it points out of
    for c in range(nv):
        t = 0.0
        for i in range(m):
            t -= A[i, c] * e[i]
        direction[c] = t
    set_free(joints, options, lower, q, direction, free)
    # δ = −A_fᵀ (A_f A_fᵀ + μ I)⁻¹ e,  μ = λ ‖e‖² + μ₀
    for i in range(m):
        r[i] = -e[i]
    if not damped_solve(A, free, r, lam * cost + DAMPING_FLOOR, G, y, delta):
        return cost, smaller(4.0 * lam, LAMBDA_MAX), False, 0.0
    step_to(joints, options, lower, q, delta, q_trial)
    step2 = 0.0
    for c in range(nv):
        step2 += delta[c] * delta[c]
    cost_trial = errors(joints, reals, frames, targets, options, q_trial, pose_ws, e_trial)
    # gain ratio ρ = (‖e‖² − ‖e_new‖²) / (‖e‖² − ‖e + A δ‖²)
    predicted = cost - predicted_cost(A, e, delta)
    rho = (cost - cost_trial) / predicted if predicted > 0.0 else 0.0
    if rho < 0.25:
        lam = smaller(4.0 * lam, LAMBDA_MAX)
    elif rho > 0.75:
        lam = larger(0.25 * lam, LAMBDA_MIN)
    if cost_trial < cost:
        for i in range(q.shape[0]):
            q[i] = q_trial[i]
        for i in range(m):
            e[i] = e_trial[i]
        # the Jacobian is needed at accepted configurations only (pose_ws holds q_trial's poses)
        error_jacobian(joints, reals, frames, options, pose_ws, e, J, A)
        cost = cost_trial
    return cost, lam, True, step2


@njit(cache=True, error_model="numpy")
def keep(q, e, q_best, e_best):
    """``q_best, e_best ← q, e``."""
    for i in range(q.shape[0]):
        q_best[i] = q[i]
    for i in range(e.shape[0]):
        e_best[i] = e[i]


# ----------------------------------------------------------------------------- the kernel

@njit(cache=True, error_model="numpy")
def inverse_kinematics(joints, reals, frames, q0, targets, posture, options, out, ws):
    """One inverse-kinematics problem (module docstring and :mod:`multibody.ik`): into
    ``out[0] = [q (nq), e (m), steps]``.

    First the targets alone: projected Levenberg–Marquardt steps, restarted from random configurations
    when a try stalls. Then, with a posture and once ``‖e‖ ≤ tol``, null-space steps towards the posture,
    ``β n``, each kept when it leaves ``‖e‖ ≤ POSTURE_BAND`` (``β`` doubles, up to 1; else it halves) and
    followed by the target steps that bring ``‖e‖`` back below ``tol``, until a step brings the
    configuration less than ``POSTURE_TOL`` nearer to the posture. The result is the best configuration
    of the first part, or the nearest to the posture of the second (all of which meet the targets).
    """
    nj, nq = joints.shape[0], q0.shape[0]
    nv = 0
    for j in range(nj):
        nv += joints[j, NV]
    nframes = frames.shape[0]
    m = 0
    for k in range(nframes):
        m += 6 if options[KINDS + k] == POSE else 3
    lower = KINDS + nframes
    restart_table = lower + 2 * nq
    s = smaller(m, nv)
    # carve the workspace
    o = 0
    pose_ws = ws[o : o + 13 * nj + 12]
    o += 13 * nj + 12
    mark_supports(joints, frames, pose_ws[12 * (nj + 1) :])
    J = ws[o : o + 6 * nv].reshape((6, nv))
    o += 6 * nv
    q, q_trial, q_best = ws[o : o + nq], ws[o + nq : o + 2 * nq], ws[o + 2 * nq : o + 3 * nq]
    o += 3 * nq
    e, e_trial, e_best = ws[o : o + m], ws[o + m : o + 2 * m], ws[o + 2 * m : o + 3 * m]
    o += 3 * m
    A = ws[o : o + m * nv].reshape((m, nv))
    o += m * nv
    delta, d, free, n, direction = (ws[o : o + nv], ws[o + nv : o + 2 * nv], ws[o + 2 * nv : o + 3 * nv],
                                    ws[o + 3 * nv : o + 4 * nv], ws[o + 4 * nv : o + 5 * nv])
    o += 5 * nv
    G = ws[o : o + s * s].reshape((s, s))
    o += s * s
    y, r = ws[o : o + larger(m, nv)], ws[o + larger(m, nv) : o + 2 * larger(m, nv)]

    tol2 = options[TOL] * options[TOL]
    max_iterations = int(options[MAX_ITERATIONS])
    damping, weight = options[DAMPING], options[POSTURE_WEIGHT]
    restarts, candidates = int(options[RESTARTS]), int(options[CANDIDATES])
    window, progress2 = int(options[WINDOW]), options[PROGRESS] * options[PROGRESS]
    step_tol2 = options[STEP_TOL] * options[STEP_TOL]
    with_posture = posture.shape[0] == nq

    for i in range(nq):
        q[i] = q0[i]
    cost = errors(joints, reals, frames, targets, options, q, pose_ws, e)
    error_jacobian(joints, reals, frames, options, pose_ws, e, J, A)
    best = cost
    keep(q, e, q_best, e_best)
    lam, age, reference, used = damping, 0, cost, 0
    steps = 0
    # ------------------------------------------------------------------ the targets
    while steps < max_iterations and cost > tol2:
        steps += 1
        cost_before = cost
        cost, lam, solved, step2 = task_step(joints, reals, frames, targets, options, lower, q, e, A, cost, lam,
                                             pose_ws, J, q_trial, e_trial, direction, free, delta, r, G, y)
        if cost < cost_before and cost < best:
            best = cost
            keep(q, e, q_best, e_best)
        if cost <= tol2:
            break
        # a try stalls when it cannot move, or when ‖e‖ has not fallen by the factor PROGRESS over the
        # last WINDOW steps (a local minimum of ‖e‖, often on a joint limit): restart it elsewhere
        age += 1
        slow = False
        if age % window == 0:
            slow = cost > progress2 * reference
            reference = cost
        if (solved and step2 <= step_tol2) or lam >= LAMBDA_MAX or slow:
            if used >= restarts:
                break
            # the next try starts from the candidate of smallest error among the next CANDIDATES rows
            cost = take_best(joints, reals, frames, targets, options, restart_table + used * candidates * nq,
                             candidates, q, e, math.inf, pose_ws, q_trial, e_trial)
            used += 1
            errors(joints, reals, frames, targets, options, q, pose_ws, e)
            error_jacobian(joints, reals, frames, options, pose_ws, e, J, A)
            lam, age, reference = damping, 0, cost
            if cost < best:
                best = cost
                keep(q, e, q_best, e_best)
    # ------------------------------------------------------------------ the posture, targets held
    # From a configuration q = q_best that meets the targets: a null-space step towards the posture, kept
    # when it leaves ‖e‖ within POSTURE_BAND, then the target steps that bring ‖e‖ back below tol
    # (quadratically: one or two); the cycle is kept when it ends nearer to the posture.
    if with_posture and cost <= tol2:
        keep(q, e, q_best, e_best)
        closest = posture_distance(joints, q, posture, direction)
    beta = 1.0
    while with_posture and cost <= tol2 and steps < max_iterations:
        posture_distance(joints, q, posture, direction)
        set_free(joints, options, lower, q, direction, free)
        if null_space_posture(A, free, direction, weight, d, r, G, y, n) <= POSTURE_TOL * POSTURE_TOL:
            break
        steps += 1
        for c in range(nv):
            delta[c] = beta * n[c]
        step_to(joints, options, lower, q, delta, q_trial)
        cost_trial = errors(joints, reals, frames, targets, options, q_trial, pose_ws, e_trial)
        if cost_trial <= POSTURE_BAND * POSTURE_BAND:
            for i in range(nq):
                q[i] = q_trial[i]
            for i in range(m):
                e[i] = e_trial[i]
            error_jacobian(joints, reals, frames, options, pose_ws, e, J, A)
            cost, lam, restoring = cost_trial, damping, 0
            while cost > tol2 and steps < max_iterations and restoring < RESTORING_STEPS:
                steps += 1
                restoring += 1
                cost, lam, solved, step2 = task_step(joints, reals, frames, targets, options, lower, q, e, A, cost,
                                                     lam, pose_ws, J, q_trial, e_trial, direction, free, delta, r, G, y)
            if cost <= tol2:
                distance = posture_distance(joints, q, posture, direction)
                if distance < closest:
                    keep(q, e, q_best, e_best)
                    if distance > closest - POSTURE_TOL:
                        break  # settled: the last cycle brought q less than POSTURE_TOL nearer
                    closest = distance
                    beta = smaller(2.0 * beta, 1.0)
                    continue
            # not nearer, or the targets not restored: back to the last configuration kept
            for i in range(nq):
                q[i] = q_best[i]
            cost = errors(joints, reals, frames, targets, options, q, pose_ws, e)
            error_jacobian(joints, reals, frames, options, pose_ws, e, J, A)
        beta *= 0.5
        if beta < POSTURE_BETA_MIN:
            break
    row = out[0]
    for i in range(nq):
        row[i] = q_best[i]
    for i in range(m):
        row[nq + i] = e_best[i]
    row[nq + m] = steps
    nan_unless_finite(q0, targets, posture, options, out)
