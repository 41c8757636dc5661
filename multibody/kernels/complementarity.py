"""The velocity-level frictional contact problem, with bilateral and unilateral rows, solved by ADMM.

Given the Delassus matrix ``G (m, m)`` (symmetric positive semi-definite, in m/s per N·s; singular
for redundant contacts) and the free velocity ``c (m,)`` (m/s), find impulses ``x (m,)`` (N·s) and
velocities ``u = G x + c`` with, for each block of rows (M. Jean, *Comput. Methods Appl. Mech. Engrg.*
177, 1999; V. Acary & B. Brogliato, *Numerical Methods for Nonsmooth Dynamical Systems*, Springer
2008, §13.3; the lecture note's contact chapter):

* ``BILATERAL`` (1 row): ``u = 0``, ``x`` free;
* ``UNILATERAL`` (1 row, a frictionless contact or a joint limit): ``0 ≤ x ⊥ u ≥ 0``;
* ``CONTACT`` (3 rows: the normal, then two tangents; friction ``μ``): De Saxcé's formulation
  (G. De Saxcé & Z.-Q. Feng, *Math. Comput. Model.* 28, 1998)

      K_μ ∋ x ⊥ û ∈ K_μ*,   û = u + μ ‖u_T‖ e_N,
      K_μ = {‖x_T‖ ≤ μ x_N},   K_μ* = {μ ‖û_T‖ ≤ û_N},

  which holds exactly when the contact separates (``x = 0``, ``u_N ≥ 0``), sticks (``u = 0``,
  ``‖x_T‖ ≤ μ x_N``) or slides (``u_N = 0``, ``x_T = −μ x_N u_T/‖u_T‖``: maximum dissipation).

With ``K`` the product of the blocks' cones (``ℝ`` bilateral, ``ℝ₊`` unilateral, ``K_μ`` contact) and
the shift ``s`` of De Saxcé held fixed, these are the optimality conditions of the convex problem
``min ½ xᵀ G x + (c + s)ᵀ x`` over ``x ∈ K``. The solver is ADMM on that problem with a proximal term and
over-relaxation (J. Carpentier, Q. Le Lidec, L. Montaut et al., "From compliant to rigid contact
simulation: a unified and efficient approach", RSS 2024, Alg. 1; S. Boyd et al., *Found. Trends Mach.
Learn.* 3, 2011, §3.4.3), the shift updated after every iteration from the iteration's own estimate of
the velocity, its multiplier ``y``:

    (G + (ρ + η) I) x̃ = −(c + s) + y + ρ z + η x          (proximal step on the quadratic)
    x⁺ = α x̃ + (1 − α) z                                   (over-relaxation, α = RELAX)
    z⁺ = P_K(x⁺ − y/ρ)                                     (projection on the cones)
    y⁺ = y + ρ (z⁺ − x⁺)                                   (the velocity multiplier)
    s⁺ = μ ‖y⁺_T‖ e_N                                      (De Saxcé's shift)

By Moreau's decomposition ``z⁺ ∈ K``, ``y⁺ ∈ K*`` and ``z⁺ ⊥ y⁺`` after every iteration, so the iteration
has converged when ``y⁺`` is the velocity ``û`` at ``z⁺``. The shift is taken from ``y`` (as Pinocchio's
``ADMMConstraintSolver`` does) rather than from the velocity ``G z⁺ + c`` of the projected impulse: ``y``
moves by ``ρ (z⁺ − x⁺)`` a step, while ``G z⁺ + c`` jumps with every change of the projection's active
set, and a shift that jumps with it makes the iteration cycle on strongly coupled contacts with large
``μ`` (a box landing flat on four corners with ``μ = 1``).

The penalty is the spectral rule of the RSS 2024 paper above (Pinocchio 4's ``ADMMSpectralUpdateRule``),
from the largest and smallest eigenvalues of ``G + η I``: ``ρ = √(λ_max λ_min) (λ_max/λ_min)^p`` with
``p =`` :data:`PENALTY_POWER`. ``λ_max`` is estimated by power iterations; ``λ_min`` is taken as ``η``, its value
for a singular ``G`` (redundant contacts) and a lower bound otherwise, so that ``ρ = λ_max``
``PROXIMAL^(1/2 − p)``: about ``2·10⁻³ λ_max``. ``ρ`` is held for a whole run of the iteration: changing
it by residual balancing changes the fixed point map of the shifted iteration and, on random problems
with ``μ`` up to 1.5, made more of them stall than it made converge faster. Which ``ρ`` lets the shifted
iteration converge on a hard problem is erratic (a change of ``G`` by 10⁻⁹ of itself can turn a cycle
into convergence), so a run that has not converged after :data:`RESTART` iterations is followed by one from
the warm start again with another ``ρ`` (:data:`PENALTY_STEP`, :data:`PENALTIES`), each run twice as long
as the one before. ``G + (ρ + η) I`` is factored by Cholesky (:func:`multibody.kernels.kkt.cholesky`)
once a run.

ADMM converges linearly; from time to time (:data:`POLISH_FIRST`) a few damped semismooth Newton steps
on the natural map ``x − P_K(x − r û(x)) = 0`` (:func:`polish`) take its iterate to the tolerance
quadratically once the contacts' modes (separating, sticking, sliding) are found, and ADMM goes on from
the better of the two otherwise. Neither is proven to converge on De Saxcé's problem, which is not convex
(the shift depends on the solution): a problem can end at :data:`MAX_ITERATIONS` with the iterate of
least residual found, and where the runs with every penalty diverge (the residual growing past
:data:`DIVERGENCE` times the problem's own scale of velocity, or overflowing: ``G`` not positive
semi-definite, or no solution) the solve ends at :data:`DIVERGED`.

Singular ``G`` (a box flat on the ground touching at four corners, redundant bilateral rows): the
impulses are then not unique, and the solver returns the one its iterations reach from the warm start:
the proximal rule. Each x-update is a step of Rockafellar's proximal point method (``η``, and ``ρ``
through ``z``, pull ``x⁺`` towards the previous iterate) and each Newton step is damped
(Levenberg–Marquardt, solved as a least-squares problem by Householder reflections: the normal
equations' rounding, ``ε/λ`` of the step, would move it along those directions), so along the directions
that change no velocity the iterates move only as far from the warm start as the conditions demand; from
``x = 0`` a symmetric problem gets the symmetric solution. The velocities ``u`` are unique.

The residual returned (and compared with the tolerance, m/s) is the largest over the blocks of the
problem's natural residual at the returned ``x`` (which is in ``K`` exactly, being a projection):
the distance of ``û`` from ``K*`` (``|u|`` for a bilateral row, ``max(−u, 0)`` for a unilateral one)
and the complementarity ``|x·û| / ‖x‖`` (0 where ``x = 0``) of the block.
"""

from __future__ import annotations

import math

from .jit import njit
from .kkt import back_substitution, cholesky, cholesky_solve
from .spatial import all_finite, larger

#: Kinds of block: one row with ``u = 0``; one row with ``0 ≤ x ⊥ u ≥ 0``; three rows of a Coulomb contact.
BILATERAL, UNILATERAL, CONTACT = 0, 1, 2
#: Statuses of :func:`solve`: the residual is within the tolerance; it is not after ``max_iterations``;
#: an input (``G``, ``c``, ``μ``, the warm start) has a NaN or infinite entry; ``G`` is not positive
#: semi-definite (the Cholesky factorisation of ``G + (ρ + η) I`` failed); the iteration diverged (its
#: residual grew past :data:`DIVERGENCE` times the problem's scale of velocity, or overflowed).
CONVERGED, MAX_ITERATIONS, NOT_FINITE, INDEFINITE, DIVERGED = 0, 1, 2, 3, 4

#: The proximal weight ``η`` relative to the largest eigenvalue ``λ_max`` of ``G``.
PROXIMAL = 1e-9
#: The power ``p`` of the spectral penalty rule ``ρ = √(λ_max λ_min) (λ_max/λ_min)^p`` (Pinocchio's default).
PENALTY_POWER = 0.2
#: The iteration has diverged when its residual exceeds this many times the larger of ``‖c‖_∞`` and the
#: residual at the warm start (both m/s): far beyond the transients of a converging iteration.
DIVERGENCE = 1e10
#: The runs of ADMM: the first has :data:`RESTART` iterations, each next one twice as many as the one before,
#: from the warm start again with ``ρ`` times ``PENALTY_STEP`` to the powers ``0, 1, −1, 2, −2`` in turn
#: (:data:`PENALTIES` of them).
RESTART = 200
PENALTY_STEP = 5.0
PENALTIES = 5
#: Power iterations estimating the largest eigenvalue of ``G``.
POWER_ITERATIONS = 12
#: Over-relaxation ``α`` of ADMM (Boyd et al. §3.4.3 recommend 1.5 to 1.8).
RELAX = 1.5
#: The polish (:func:`polish`) runs after this many ADMM iterations (at once from a nonzero warm start),
#: then after twice as many as before each time, at most :data:`POLISH_STEPS` Newton steps each time.
POLISH_FIRST = 1
POLISH_STEPS = 50
#: The Levenberg–Marquardt damping ``λ = ‖f‖/‖x‖`` of the polish (dimensionless: ``f`` is in impulse
#: units), within these bounds, against ``Jᵀ J`` whose largest eigenvalues are about 1 (``r = 1/λ_max``).
#: Small enough that Newton steps stay nearly full along the small eigenvalues of a stack of boxes, and
#: ``‖f‖/‖x‖`` itself near the solution, so that where ``G`` is singular the steps move ``x`` along the
#: null space of ``J`` no further than the conditions demand.
DAMPING = 1e-7
DAMPING_FLOOR = 1e-14
#: Halvings of a polish step before the polish gives up.
LINE_SEARCH = 12


@njit(cache=True, error_model="numpy")
def workspace_size(m):
    """Floats of workspace of :func:`solve` for ``m`` rows: two ``(m, m)`` matrices (the ADMM factor and the
    polish's Jacobian), the polish's least-squares matrix ``(m + 1, 2m)`` and eleven vectors."""
    return 4 * m * m + 13 * m


@njit(cache=True, error_model="numpy")
def block_rows(kind):
    """Rows of a block of the given kind."""
    return 3 if kind == CONTACT else 1


@njit(cache=True, error_model="numpy")
def project_primal(kind, mu, w, z, i):
    """``z[i:i+k] = P_K(w[i:i+k])``, the Euclidean projection on the block's cone: ``ℝ``, ``ℝ₊`` or
    ``K_μ = {‖x_T‖ ≤ μ x_N}``. On the cone's boundary (Boyd & Vandenberghe, *Convex Optimization*,
    exercise 8.3(c), scaled by ``μ``): ``x_N = (w_N + μ ‖w_T‖) / (1 + μ²)``,
    ``x_T = μ x_N w_T / ‖w_T‖``."""
    if kind == BILATERAL:
        z[i] = w[i]
        return
    if kind == UNILATERAL:
        z[i] = larger(w[i], 0.0)
        return
    n, t1, t2 = w[i], w[i + 1], w[i + 2]
    # (hypot: squares of impulses of 1e-160 N·s would underflow, and the cone's test with them)
    t = math.hypot(t1, t2)
    if t <= mu * n:
        z[i], z[i + 1], z[i + 2] = n, t1, t2
    elif mu * t <= -n:
        # the polar cone −K_μ* projects on the apex
        z[i], z[i + 1], z[i + 2] = 0.0, 0.0, 0.0
    else:
        # x_N = (w_N + μ‖w_T‖)/(1 + μ²),  x_T = μ x_N w_T/‖w_T‖  (t > 0 here)
        normal = (n + mu * t) / (1.0 + mu * mu)
        z[i], z[i + 1], z[i + 2] = normal, mu * normal * (t1 / t), mu * normal * (t2 / t)


@njit(cache=True, error_model="numpy")
def dual_distance(n, t, mu):
    """Distance of a vector with normal part ``n`` and tangential norm ``t`` from ``K_μ* = {μ ‖t‖ ≤ n}``
    (by symmetry, that of the point ``(n, t)`` from the plane cone ``{μ t ≤ n}``): 0 inside, ``‖(n, t)‖``
    in its polar cone ``{t ≤ −μ n}`` (nearest point: the apex), else the distance to the boundary ray
    ``n = μ t``, ``(μ t − n) / √(1 + μ²)``."""
    if mu * t <= n:
        return 0.0
    if t <= -mu * n:
        return math.hypot(n, t)
    return (mu * t - n) / math.sqrt(1.0 + mu * mu)


@njit(cache=True, error_model="numpy")
def shift_and_residual(kinds, starts, mu, x, u, s):
    """De Saxcé's shift ``s = μ ‖u_T‖ e_N`` of each contact block into ``s`` (zero on the other rows), and
    the natural residual (m/s) at ``x ∈ K`` with ``u = G x + c``: the largest over the blocks of the
    distance of ``û = u + s`` from ``K*`` and of ``|x·û| / ‖x‖``."""
    residual = 0.0
    for b in range(kinds.shape[0]):
        kind, i = kinds[b], starts[b]
        if kind == BILATERAL:
            s[i] = 0.0
            residual = larger(residual, abs(u[i]))
        elif kind == UNILATERAL:
            s[i] = 0.0
            # K* = ℝ₊; complementarity |x u|/|x| = |u| where x ≠ 0
            residual = larger(residual, larger(-u[i], 0.0))
            if x[i] != 0.0:
                residual = larger(residual, abs(u[i]))
        else:
            tangential = math.hypot(u[i + 1], u[i + 2])
            # û = u + μ ‖u_T‖ e_N
            s[i], s[i + 1], s[i + 2] = mu[b] * tangential, 0.0, 0.0
            normal = u[i] + s[i]
            residual = larger(residual, dual_distance(normal, tangential, mu[b]))
            size = math.hypot(x[i], math.hypot(x[i + 1], x[i + 2]))
            if size > 0.0:
                residual = larger(residual, abs(x[i] * normal + x[i + 1] * u[i + 1] + x[i + 2] * u[i + 2]) / size)
    return residual


@njit(cache=True, error_model="numpy")
def multiplier_shift(kinds, starts, mu, y, s):
    """De Saxcé's shift ``s = μ ‖y_T‖ e_N`` of each contact block from the velocity multiplier ``y`` of the
    ADMM iteration (zero on the other rows)."""
    for b in range(kinds.shape[0]):
        i = starts[b]
        if kinds[b] == CONTACT:
            s[i], s[i + 1], s[i + 2] = mu[b] * math.hypot(y[i + 1], y[i + 2]), 0.0, 0.0
        else:
            s[i] = 0.0


@njit(cache=True, error_model="numpy")
def velocities(G, c, x, u, m):
    """``u = G x + c``."""
    for i in range(m):
        total = c[i]
        for j in range(m):
            total += G[i, j] * x[j]
        u[i] = total


@njit(cache=True, error_model="numpy")
def factor(G, F, shift, m):
    """``F = chol(G + shift I)`` (lower triangle, :func:`multibody.kernels.kkt.cholesky`); ``False`` when
    that matrix is not positive definite."""
    for i in range(m):
        for j in range(i + 1):
            F[i, j] = G[i, j]
        F[i, i] += shift
    return cholesky(F, m)


@njit(cache=True, error_model="numpy")
def largest_eigenvalue(G, m, v, w):
    """An estimate of ``λ_max(G)`` by :data:`POWER_ITERATIONS` power iterations from the all-ones vector
    (Golub & Van Loan, *Matrix Computations*, 4th ed., §8.2.1), at least the largest diagonal entry
    (a Rayleigh quotient itself); ``v``, ``w (m,)`` are scratch."""
    estimate = 0.0
    for i in range(m):
        estimate = larger(estimate, G[i, i])
        v[i] = 1.0 / math.sqrt(m)
    for _ in range(POWER_ITERATIONS):
        # w = G v,  λ ≈ vᵀ G v,  v = w/‖w‖
        size, rayleigh = 0.0, 0.0
        for i in range(m):
            total = 0.0
            for j in range(m):
                total += G[i, j] * v[j]
            w[i] = total
            rayleigh += v[i] * total
            size += total * total
        estimate = larger(estimate, rayleigh)
        if not size > 0.0:
            break
        size = math.sqrt(size)
        for i in range(m):
            v[i] = w[i] / size
    return estimate


@njit(cache=True, error_model="numpy")
def natural_map(G, c, kinds, starts, mu, r, x, u, s, w, f):
    """``f = x − P_K(x − r û)`` with ``u = G x + c``, ``û = u + s`` (De Saxcé's shift ``s``), and ``w`` the
    point projected; returns ``‖f‖²``. ``f = 0`` exactly at a solution (Moreau: ``x ∈ K``, ``û ∈ K*``,
    ``x ⊥ û``), ``r > 0`` (N·s per m/s) weighing velocities against impulses."""
    m = c.shape[0]
    velocities(G, c, x, u, m)
    shift_and_residual(kinds, starts, mu, x, u, s)
    for i in range(m):
        w[i] = x[i] - r * (u[i] + s[i])
    for b in range(kinds.shape[0]):
        project_primal(kinds[b], mu[b], w, f, starts[b])
    norm = 0.0
    for i in range(m):
        f[i] = x[i] - f[i]
        norm += f[i] * f[i]
    return norm


@njit(cache=True, error_model="numpy")
def natural_map_jacobian(G, kinds, starts, mu, r, u, w, J):
    """An element of the generalized Jacobian of :func:`natural_map` at the point that gave ``u`` and ``w``:
    ``J = I − D (I − r (I + S) G)``, with ``S = ∂s/∂u`` (the row ``μ u_Tᵀ/‖u_T‖`` on a contact's normal,
    zero where ``u_T = 0``) and ``D = ∂P_K/∂w`` block by block: 1 or 0 for a row of ``ℝ`` or ``ℝ₊``; for
    ``K_μ``, ``I`` inside, 0 in the polar cone, and on the boundary part, with ``t̂ = w_T/‖w_T‖``,
    ``k = 1/(1 + μ²)``, ``a = k (w_N + μ ‖w_T‖)`` (the projection ``a (1, μ t̂)``):

        D = [[k, μ k t̂ᵀ], [μ k t̂, μ² k t̂ t̂ᵀ + (μ a/‖w_T‖)(I − t̂ t̂ᵀ)]]

    (J.-S. Pang & D. Sun's derivative of the second-order cone projection; Hayashi, Yamashita &
    Fukushima, *SIAM J. Optim.* 15, 2005, §4)."""
    m = u.shape[0]
    # J = I − r (I + S) G, row by row
    for i in range(m):
        for j in range(m):
            J[i, j] = (1.0 if i == j else 0.0) - r * G[i, j]
    for b in range(kinds.shape[0]):
        i = starts[b]
        if kinds[b] == CONTACT:
            tangential = math.hypot(u[i + 1], u[i + 2])
            if tangential > 0.0:
                # S: ∂(μ‖u_T‖)/∂u_T = μ u_T/‖u_T‖ on the normal row
                e1, e2 = mu[b] * u[i + 1] / tangential, mu[b] * u[i + 2] / tangential
                for j in range(m):
                    J[i, j] -= r * (e1 * G[i + 1, j] + e2 * G[i + 2, j])
    # J ← I − D J, block by block
    for b in range(kinds.shape[0]):
        kind, i = kinds[b], starts[b]
        if kind == BILATERAL or (kind == UNILATERAL and w[i] > 0.0):
            for j in range(m):
                J[i, j] = (1.0 if i == j else 0.0) - J[i, j]
        elif kind == UNILATERAL:
            for j in range(m):
                J[i, j] = 1.0 if i == j else 0.0
        else:
            n, t1, t2 = w[i], w[i + 1], w[i + 2]
            t = math.hypot(t1, t2)
            friction = mu[b]
            if t <= friction * n:
                d00, d01, d02, d11, d12, d22 = 1.0, 0.0, 0.0, 1.0, 0.0, 1.0
            elif friction * t <= -n:
                d00, d01, d02, d11, d12, d22 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            else:
                k = 1.0 / (1.0 + friction * friction)
                a = k * (n + friction * t)
                h1, h2 = t1 / t, t2 / t
                ratio = friction * a / t
                d00, d01, d02 = k, friction * k * h1, friction * k * h2
                d11 = friction * friction * k * h1 * h1 + ratio * (1.0 - h1 * h1)
                d12 = friction * friction * k * h1 * h2 - ratio * h1 * h2
                d22 = friction * friction * k * h2 * h2 + ratio * (1.0 - h2 * h2)
            for j in range(m):
                b0, b1, b2 = J[i, j], J[i + 1, j], J[i + 2, j]
                J[i, j] = (1.0 if i == j else 0.0) - (d00 * b0 + d01 * b1 + d02 * b2)
                J[i + 1, j] = (1.0 if i + 1 == j else 0.0) - (d01 * b0 + d11 * b1 + d12 * b2)
                J[i + 2, j] = (1.0 if i + 2 == j else 0.0) - (d02 * b0 + d12 * b1 + d22 * b2)


@njit(cache=True, error_model="numpy")
def damped_least_squares(B, m):
    """The ``δ (m,)`` minimising ``‖J δ − b‖² + λ ‖δ‖²``, i.e. ``‖A δ − (b, 0)‖`` with ``A = [J; √λ I]``
    ``(2m, m)``, by Householder reflections (Golub & Van Loan, *Matrix Computations*, 4th ed., Alg. 5.3.2,
    transposed), in place in ``B (m + 1, 2m)``: on entry ``B[:m] = Aᵀ`` and ``B[m] = (b, 0)``; on return
    ``δ`` in ``B[m, :m]``. With ``Aᵀ Q = [L 0]`` (reflections from the right, applied to the row ``B[m]``
    too), ``A = Q [Lᵀ; 0]`` and ``Lᵀ δ = (Qᵀ (b, 0))[:m]``. Unlike the normal equations
    ``(Jᵀ J + λ I) δ = Jᵀ b`` this does not square the conditioning: their rounding, ``ε/λ`` of the step,
    would move ``δ`` along the null space of ``J``."""
    for k in range(m):
        # the reflection H = I − τ v vᵀ with x H = (α, 0, …, 0), x = B[k, k:], v = x − α e_k. Row k is zero
        # right of column m + k (its √λ is there, and the reflections before touched only columns up to m + k − 1),
        # so v lives on the columns k … m − 1 and m … m + k.
        size = 0.0
        for col in range(k, m):
            size += B[k, col] * B[k, col]
        for col in range(m, m + k + 1):
            size += B[k, col] * B[k, col]
        alpha = -math.sqrt(size) if B[k, k] > 0.0 else math.sqrt(size)
        if alpha == 0.0:
            continue
        first = B[k, k]
        B[k, k] = first - alpha
        tau = 1.0 / (alpha * (alpha - first))  # 2 / vᵀv, with vᵀv = 2 α (α − x_k)
        for row in range(k + 1, m + 1):
            d = 0.0
            for col in range(k, m):
                d += B[row, col] * B[k, col]
            for col in range(m, m + k + 1):
                d += B[row, col] * B[k, col]
            d *= tau
            for col in range(k, m):
                B[row, col] -= d * B[k, col]
            for col in range(m, m + k + 1):
                B[row, col] -= d * B[k, col]
        B[k, k] = alpha
    # Lᵀ δ = (Qᵀ b)[:m], L the lower triangle of B[:m, :m]
    back_substitution(B, m, B[m])


@njit(cache=True, error_model="numpy")
def polish(G, c, kinds, starts, mu, r, steps, tolerance, x, u, s, w, f, dx, trial, J, B):
    """At most ``steps`` Levenberg–Marquardt steps on the natural map ``f(x) = 0`` (:func:`natural_map`)
    from ``x``, a semismooth Newton method (L. Qi & J. Sun, *Math. Program.* 58, 1993) damped so that
    it also solves singular problems (N. Yamashita & M. Fukushima, *Computing Suppl.* 15, 2001):

        δ = argmin ‖J δ + f‖² + λ ‖δ‖²   (that is, (Jᵀ J + λ I) δ = −Jᵀ f),   x ← x + t δ,

    ``J`` from :func:`natural_map_jacobian`, ``δ`` by :func:`damped_least_squares`, ``λ = ‖f‖/‖x‖`` between
    :data:`DAMPING_FLOOR` and :data:`DAMPING`, ``t`` halved until ``‖f‖²`` falls by ``10⁻⁴ t`` of itself
    (Armijo). Along singular directions of ``G`` the damping keeps the step small: among equal solutions,
    the one near the start. Stops when the natural residual at ``P_K(x)`` is within ``tolerance`` or no step
    decreases ``‖f‖``. Returns ``(steps taken, residual)``, with ``P_K(x)`` in ``trial`` and the velocities
    there in ``u``. ``J (m, m)``, ``B (m + 1, 2m)``, the vectors ``(m,)`` are scratch."""
    m = c.shape[0]
    norm = natural_map(G, c, kinds, starts, mu, r, x, u, s, w, f)
    taken = 0
    for step in range(steps):
        natural_map_jacobian(G, kinds, starts, mu, r, u, w, J)
        size = 0.0
        for i in range(m):
            size += x[i] * x[i]
        damping = math.sqrt(norm / size) if size > 0.0 else DAMPING
        damping = DAMPING if damping > DAMPING else damping
        damping = DAMPING_FLOOR if damping < DAMPING_FLOOR else damping
        # B = [Jᵀ, √λ I; −fᵀ, 0]
        root = math.sqrt(damping)
        for i in range(m):
            for k in range(m):
                B[i, k] = J[k, i]
                B[i, m + k] = root if i == k else 0.0
            B[m, i] = -f[i]
            B[m, m + i] = 0.0
        damped_least_squares(B, m)
        for i in range(m):
            dx[i] = B[m, i]
        taken += 1
        t, accepted = 1.0, False
        for _ in range(LINE_SEARCH):
            for i in range(m):
                trial[i] = x[i] + t * dx[i]
            new = natural_map(G, c, kinds, starts, mu, r, trial, u, s, w, f)
            if new <= (1.0 - 1e-4 * t) * norm:
                accepted = True
                break
            t *= 0.5
        if not accepted:
            break
        for i in range(m):
            x[i] = trial[i]
        norm = new
        # done once the natural residual at P_K(x) is
        for b in range(kinds.shape[0]):
            project_primal(kinds[b], mu[b], x, trial, starts[b])
        velocities(G, c, trial, u, m)
        if shift_and_residual(kinds, starts, mu, trial, u, s) <= tolerance:
            break
        # (u, s, w, f at x again, for the next Jacobian)
        natural_map(G, c, kinds, starts, mu, r, x, u, s, w, f)
    for b in range(kinds.shape[0]):
        project_primal(kinds[b], mu[b], x, trial, starts[b])
    velocities(G, c, trial, u, m)
    return taken, shift_and_residual(kinds, starts, mu, trial, u, s)


@njit(cache=True, error_model="numpy")
def admm(G, c, kinds, starts, mu, tolerance, iterations, warm, largest, eta, rho, scale, F, J, B, start, x, z, y, s,
         u, rhs, w, point, f, dx, trial):
    """At most ``iterations`` iterations (ADMM iterations and Newton steps) of the module docstring's ADMM
    with penalty ``ρ``, proximal weight ``η`` and ``F = chol(G + (ρ + η) I)``, from the impulses ``start`` in
    ``K`` (``warm``: not zero), with the polish (:func:`polish`) after :data:`POLISH_FIRST`, then twice as
    many, iterations (at once from a warm start). Returns ``(status, iterations, residual)``: :data:`CONVERGED`,
    :data:`MAX_ITERATIONS` or :data:`DIVERGED` (a residual above :data:`DIVERGENCE` ``· scale``, m/s, or not
    finite), with the last iterate whose residual is returned in ``z``. The other arrays are scratch."""
    m = c.shape[0]
    # z the start, y the velocity there, û = G z + c + s, and the shift from y
    for i in range(m):
        z[i] = start[i]
        x[i] = start[i]
    velocities(G, c, z, u, m)
    residual = shift_and_residual(kinds, starts, mu, z, u, s)
    for i in range(m):
        y[i] = u[i] + s[i]
    status = MAX_ITERATIONS
    iteration = 0
    polish_at = 0 if warm else POLISH_FIRST
    polish_gap = POLISH_FIRST
    while iteration < iterations:
        if iteration >= polish_at:
            # Newton steps from z, kept if they bring the residual down; ADMM goes on from there otherwise
            polish_at = iteration + polish_gap
            polish_gap *= 2
            for i in range(m):
                point[i] = z[i]
            steps = iterations - iteration if iterations - iteration < POLISH_STEPS else POLISH_STEPS
            taken, polished = polish(G, c, kinds, starts, mu, 1.0 / largest, steps, tolerance, point, u, s, w, f, dx,
                                     trial, J, B)
            iteration += taken
            if polished < residual:
                residual = polished
                for i in range(m):
                    z[i] = trial[i]
                    x[i] = z[i]
                    y[i] = u[i] + s[i]
            multiplier_shift(kinds, starts, mu, y, s)
            if residual <= tolerance:
                status = CONVERGED
                break
            if iteration >= iterations:
                break
        iteration += 1
        # (G + (ρ + η) I) x̃ = −(c + s) + y + ρ z + η x
        for i in range(m):
            rhs[i] = -(c[i] + s[i]) + y[i] + rho * z[i] + eta * x[i]
        cholesky_solve(F, m, rhs)
        # x⁺ = α x̃ + (1 − α) z,  z⁺ = P_K(x⁺ − y/ρ)
        for i in range(m):
            x[i] = RELAX * rhs[i] + (1.0 - RELAX) * z[i]
            w[i] = x[i] - y[i] / rho
        for b in range(kinds.shape[0]):
            project_primal(kinds[b], mu[b], w, point, starts[b])
        # u = G z⁺ + c and the natural residual there
        velocities(G, c, point, u, m)
        found = shift_and_residual(kinds, starts, mu, point, u, s)
        if not (found <= DIVERGENCE * scale and all_finite(point)):
            status = DIVERGED
            break
        residual = found
        # y⁺ = y + ρ (z⁺ − x⁺),  s⁺ = μ ‖y⁺_T‖ e_N
        for i in range(m):
            z[i] = point[i]
            y[i] += rho * (z[i] - x[i])
        if residual <= tolerance:
            status = CONVERGED
            break
        multiplier_shift(kinds, starts, mu, y, s)
    return status, iteration, residual


@njit(cache=True, error_model="numpy")
def solve(G, c, kinds, starts, mu, tolerance, max_iterations, x, u, ws):
    """Impulses ``x (m,)`` (N·s, in: the warm start; out: the solution) and velocities ``u = G x + c`` (m/s,
    out) of the contact problem of the module docstring, by ADMM and Newton steps (:func:`admm`), restarted
    from the warm start with another penalty when a run of it ends unconverged. Returns
    ``(status, iterations, residual)``: :data:`CONVERGED` when the natural residual (m/s) is at most
    ``tolerance``; else :data:`MAX_ITERATIONS` after ``max_iterations`` iterations (ADMM iterations and
    Newton steps, over all runs), :data:`DIVERGED` when the runs with each of the :data:`PENALTIES`
    penalties diverged (both with the iterate of least residual found), :data:`NOT_FINITE` (an input not
    finite: ``x``, ``u`` and the residual NaN) or :data:`INDEFINITE`.

    ``G (m, m)`` symmetric positive semi-definite (m/s per N·s), ``c (m,)`` (m/s); block ``b`` has kind
    ``kinds[b]`` (:data:`BILATERAL`, :data:`UNILATERAL`, :data:`CONTACT`) and starts at row
    ``starts[b]``, the blocks covering the rows in order; ``mu (nb,)`` the friction coefficients (read for
    contact blocks, ≥ 0); ``ws`` of :func:`workspace_size` ``(m)`` floats."""
    m = c.shape[0]
    F = ws[: m * m].reshape((m, m))
    J = ws[m * m : 2 * m * m].reshape((m, m))
    B = ws[2 * m * m : 4 * m * m + 2 * m].reshape((m + 1, 2 * m))
    vectors = ws[4 * m * m + 2 * m :]
    z = vectors[:m]
    y = vectors[m : 2 * m]
    s = vectors[2 * m : 3 * m]
    rhs = vectors[3 * m : 4 * m]
    w = vectors[4 * m : 5 * m]
    point = vectors[5 * m : 6 * m]
    f = vectors[6 * m : 7 * m]
    dx = vectors[7 * m : 8 * m]
    trial = vectors[8 * m : 9 * m]
    start = vectors[9 * m : 10 * m]
    best = vectors[10 * m : 11 * m]
    finite = all_finite(c) and all_finite(x) and all_finite(mu)
    for i in range(m):
        finite = finite and all_finite(G[i])
    if not finite:
        for i in range(m):
            x[i] = math.nan
            u[i] = math.nan
        return NOT_FINITE, 0, math.nan

    # the warm start projected on K, and its residual
    warm = False
    for b in range(kinds.shape[0]):
        project_primal(kinds[b], mu[b], x, start, starts[b])
    for i in range(m):
        warm = warm or start[i] != 0.0
        x[i] = start[i]
        best[i] = start[i]
    velocities(G, c, x, u, m)
    residual = shift_and_residual(kinds, starts, mu, x, u, s)
    if residual <= tolerance:
        return CONVERGED, 0, residual

    # η and the first ρ from the spectrum of G + η I: λ_max, and λ_min ≥ η (= η for a singular G)
    largest = largest_eigenvalue(G, m, rhs, w)
    if not largest > 0.0:
        largest = 1.0
    eta = PROXIMAL * largest
    # ρ = √(λ_max λ_min) (λ_max/λ_min)^p
    spectral = math.sqrt(largest * eta) * (largest / eta) ** PENALTY_POWER
    # the problem's scale of velocity, against which a growing residual is divergence
    scale = residual
    for i in range(m):
        scale = larger(scale, abs(c[i]))

    status = MAX_ITERATIONS
    iteration, run, diverged = 0, 0, 0
    while iteration < max_iterations and status != CONVERGED:
        # run k: ρ times PENALTY_STEP^0, ^1, ^−1, ^2, ^−2, then again, with RESTART · 2^k iterations
        k = run % PENALTIES
        rho = spectral * PENALTY_STEP ** (((k + 1) // 2) * (1 if k % 2 == 1 else -1))
        if not factor(G, F, rho + eta, m):
            status = INDEFINITE
            break
        budget = max_iterations - iteration
        if run < 30 and RESTART * 2 ** run < budget:
            budget = RESTART * 2 ** run
        status, used, found = admm(G, c, kinds, starts, mu, tolerance, budget, warm, largest, eta, rho, scale, F, J, B,
                                   start, x, z, y, s, u, rhs, w, point, f, dx, trial)
        iteration += used
        run += 1
        if found < residual:
            residual = found
            for i in range(m):
                best[i] = z[i]
        if status == DIVERGED:
            diverged += 1
            if diverged == run and run >= PENALTIES:
                break
            status = MAX_ITERATIONS
    for i in range(m):
        x[i] = best[i]
    velocities(G, c, x, u, m)
    return status, iteration, residual
