"""One constrained step: ``M a + h = τ + Aᵀ λ`` with ``A a = γ``, from one compiled pass.

Eliminating ``a`` (R. Featherstone, *Rigid Body Dynamics Algorithms*, §8.1, eq. 8.7, with the sign
of λ of :class:`multibody.ConstrainedSystem`):

    a_free = M⁻¹ (τ − h)
    G λ = γ − A a_free,   G = A M⁻¹ Aᵀ          (minimum-norm λ when A is rank deficient)
    a = a_free + M⁻¹ Aᵀ λ

``M`` comes from CRBA, ``h`` from RNEA, the constraint frames from one forward pass, and the rows from
:mod:`multibody.kernels.constraints`. ``M = L Lᵀ`` by Cholesky; ``G = B Bᵀ`` with ``B = A L⁻ᵀ``, never
formed, so that no step squares the condition number. Where a row-pivoted LQ factor of ``B`` proves
that every singular value exceeds the rank tolerance times the largest, ``λ`` comes from two
triangular solves with that factor. Otherwise one-sided Jacobi rotations make the rows of ``B``
orthogonal, ``B = V diag(σ) Pᵀ``, and ``λ = V diag(σ²)⁺ Vᵀ rhs`` drops the directions with
``σ ≤ rank tolerance · max σ``. That solve (:func:`solve_rows`) is the only one: rows from a compiled
constraint program (:func:`constrained_accelerations`) and rows evaluated in Python and passed as arrays
(:func:`solve_arrays`) both go through it, and the projection (:func:`project`, :func:`correction_arrays`)
takes its corrections from the same factorisation (:func:`metric_correction`). Every failure is a status in
the output row (:data:`TAIL`), which :data:`multibody.constrained.STATUS_ERRORS` turns into its message.
``M`` holds the joints' armature on its diagonal (:func:`multibody.kernels.crba.mass_matrix`).
"""

from __future__ import annotations

import math

from .layout import IQ, IV, KIND, NV
from . import crba, kinematics, rnea
from . import joints as kinds
from .constraints import UNDEFINED, failing_entry
from .jit import njit
from .spatial import larger, nan_unless_finite, smaller

#: Status of a step: solved; ``M`` not positive definite; constraints that no acceleration meets;
#: a constraint without a defined direction (``UNDEFINED``, see :mod:`multibody.kernels.constraints`); a
#: projection (:func:`project`) whose positions did not converge; an input with a NaN or infinite entry.
SOLVED, NOT_POSITIVE_DEFINITE, INCONSISTENT, NOT_CONVERGED, NON_FINITE = 0, 1, 2, 4, 5
#: The unit roundoff of float64: singular values below ``m ε σ_max`` are rounding (a redundant row).
EPSILON = 2.0**-52


@njit(cache=True, error_model="numpy")
def output_columns(nv, m):
    """Columns of the step's output row: ``a (nv) | λ (m) | A (m nv, row-major) | γ (m) |`` the :data:`TAIL`
    (rank, row, conditioning, value, status)."""
    return nv + m + m * nv + m + TAIL


def workspace_size(nj, nv, nframes, m):
    """Floats of workspace of one step with ``nframes`` constraint frames and ``m`` rows."""
    passes = max(crba.workspace_size(nj, nv), rnea.workspace_size(nj, nv), kinematics.workspace_size(nj, nv))
    return (nv * nv + nv + nframes * kinematics.motion_columns(nv) + m * nv + 2 * m + solve_rows_workspace_size(m, nv)
            + passes)


@njit(cache=True, error_model="numpy")
def cholesky(M, n):
    """``M = L Lᵀ`` in place (lower triangle; Golub & Van Loan, *Matrix Computations*, 4th ed., Alg. 4.2.2).
    Returns ``False`` when ``M`` is not positive definite."""
    for j in range(n):
        # L_jj = √(M_jj − Σ_k<j L_jk²)
        d = M[j, j]
        for k in range(j):
            d -= M[j, k] * M[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        M[j, j] = d
        # L_ij = (M_ij − Σ_k<j L_ik L_jk) / L_jj
        for i in range(j + 1, n):
            s = M[i, j]
            for k in range(j):
                s -= M[i, k] * M[j, k]
            M[i, j] = s / d
    return True


@njit(cache=True, error_model="numpy")
def forward_substitution(L, n, x):
    """``x ← L⁻¹ x`` for the lower-triangular factor of :func:`cholesky`."""
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model="numpy")
def back_substitution(L, n, x):
    """``x ← L⁻ᵀ x`` for the lower-triangular factor of :func:`cholesky`."""
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model="numpy")
def cholesky_solve(L, n, x):
    """``x ← M⁻¹ x`` from the factor of :func:`cholesky`: ``L y = x``, then ``Lᵀ x = y``."""
    forward_substitution(L, n, x)
    back_substitution(L, n, x)


@njit(cache=True, error_model="numpy")
def row_dot(B, p, r, n):
    """``B[p] · B[r]`` over the first ``n`` columns, summed in four interleaved parts so that the additions
    do not wait on each other."""
    s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
    end = n - n % 4
    for c in range(0, end, 4):
        s0 += B[p, c] * B[r, c]
        s1 += B[p, c + 1] * B[r, c + 1]
        s2 += B[p, c + 2] * B[r, c + 2]
        s3 += B[p, c + 3] * B[r, c + 3]
    for c in range(end, n):
        s0 += B[p, c] * B[r, c]
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, error_model="numpy")
def longest_first(B, n, norms, p, m):
    """Row ``p`` of ``B`` (its first ``n`` columns) and ``norms[p]`` swapped with the row of largest
    ``norms`` among ``p … m − 1``; returns the index that row came from."""
    longest = p
    for r in range(p + 1, m):
        if norms[r] > norms[longest]:
            longest = r
    if longest != p:
        norms[p], norms[longest] = norms[longest], norms[p]
        for c in range(n):
            B[p, c], B[longest, c] = B[longest, c], B[p, c]
    return longest


@njit(cache=True, error_model="numpy")
def orthogonalize_rows(B, U, sigma, m):
    """``B = U diag(σ) Pᵀ`` for ``B (m, n)`` by one-sided Jacobi rotations of its rows (Hestenes; Golub
    & Van Loan, *Matrix Computations*, 4th ed., §8.6.3): pairs of rows are rotated until all are
    orthogonal, ``B ← Uᵀ B``. ``U (m, m)`` gets the left singular vectors as columns and ``sigma (m,)``
    the singular values (the final row norms, in no particular order); ``B Bᵀ = U diag(σ²) Uᵀ`` without
    forming it. Each sweep takes the rows longest first (P. P. M. de Rijk, SIAM J. Sci. Stat. Comput. 10,
    1989), which needs fewer sweeps than the cyclic order."""
    n = B.shape[1]
    # sigma holds the squared row norms until the end, each summed afresh from the row whenever it changes
    for i in range(m):
        for j in range(m):
            U[i, j] = 1.0 if i == j else 0.0
        s = 0.0
        for c in range(n):
            s += B[i, c] * B[i, c]
        sigma[i] = s
    for sweep in range(60):
        rotated = False
        for p in range(m - 1):
            # de Rijk's pivoting: the longest remaining row goes first, which cuts the number of sweeps
            longest = longest_first(B, n, sigma, p, m)
            if longest != p:
                for k in range(m):
                    U[p, k], U[longest, k] = U[longest, k], U[p, k]
            for r in range(p + 1, m):
                alpha, beta = sigma[p], sigma[r]
                gamma = row_dot(B, p, r, n)
                if gamma == 0.0 or abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                # the rotation (c, s) that makes rows p and r orthogonal: ζ = (β − α)/(2γ), t = sign(ζ)/(|ζ| + √(1 + ζ²))
                zeta = (beta - alpha) / (2.0 * gamma)
                t = 1.0 / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                if zeta < 0.0:
                    t = -t
                cos = 1.0 / math.sqrt(1.0 + t * t)
                sin = t * cos
                for c in range(n):
                    b_p, b_r = B[p, c], B[r, c]
                    B[p, c] = cos * b_p - sin * b_r
                    B[r, c] = sin * b_p + cos * b_r
                sigma[p], sigma[r] = row_dot(B, p, p, n), row_dot(B, r, r, n)
                # (U is kept transposed while it is built, so that a rotation reads two of its rows)
                for k in range(m):
                    u_p, u_r = U[p, k], U[r, k]
                    U[p, k] = cos * u_p - sin * u_r
                    U[r, k] = sin * u_p + cos * u_r
        if not rotated:
            break
    for i in range(m):
        sigma[i] = math.sqrt(sigma[i])
        for j in range(i):
            U[i, j], U[j, i] = U[j, i], U[i, j]


@njit(cache=True, error_model="numpy")
def minimum_norm(V, sigma, rhs, rank_tolerance, m, coefficients, magnitudes, lam):
    """Minimum-norm ``λ = G⁺ rhs`` into ``lam (m,)`` for ``G = A M⁻¹ Aᵀ = B Bᵀ = V diag(σ²) Vᵀ`` from
    :func:`orthogonalize_rows`: ``λ = V diag(σ²)⁺ Vᵀ rhs``, keeping the directions with
    ``σ > rank_tolerance · max σ``. Returns the rank; ``coefficients[j] = V_jᵀ rhs`` and
    ``magnitudes[j] = Σ_i |V_ij rhs_i|`` on the kept directions (zero on the others)."""
    sigma_max = 0.0
    for i in range(m):
        sigma_max = larger(sigma_max, sigma[i])
        lam[i] = 0.0
    rank = 0
    for j in range(m):
        coefficients[j] = 0.0
        magnitudes[j] = 0.0
        if sigma[j] > rank_tolerance * sigma_max:
            rank += 1
            for i in range(m):
                coefficients[j] += V[i, j] * rhs[i]
                magnitudes[j] += abs(V[i, j] * rhs[i])
            for i in range(m):
                lam[i] += V[i, j] * coefficients[j] / (sigma[j] * sigma[j])
    return rank


@njit(cache=True, error_model="numpy")
def pivoted_lq(B, m, n, order, norms):
    """``Π B = L Q`` for the first ``m`` rows of ``B (·, n)``, in place: Householder reflections from the
    right, the remaining row of largest norm first at each step (Businger and Golub, Numer. Math. 7,
    1965; Golub & Van Loan, *Matrix Computations*, 4th ed., Alg. 5.4.1, transposed). On return the lower
    triangle of ``B[:m, :m]`` holds ``L`` and ``order[k]`` is the row of ``B`` that ``Π`` puts at ``k``
    (as a float); ``norms (m,)`` is scratch."""
    for i in range(m):
        order[i] = i
        norms[i] = row_dot(B, i, i, n)
    for k in range(m):
        # the remaining row of largest norm over columns k … n − 1 goes next
        p = longest_first(B, n, norms, k, m)
        order[k], order[p] = order[p], order[k]
        # the reflection H = I − τ u uᵀ with x H = (α, 0, …, 0), x = B[k, k:], u = x − α e_k
        s = 0.0
        for c in range(k, n):
            s += B[k, c] * B[k, c]
        alpha = -math.sqrt(s) if B[k, k] > 0.0 else math.sqrt(s)
        if alpha == 0.0:
            continue
        x_k = B[k, k]
        B[k, k] = x_k - alpha  # u, kept in row k while the rows below are reflected
        tau = 1.0 / (alpha * (alpha - x_k))  # 2 / uᵀu, with uᵀu = 2 α (α − x_k)
        for r in range(k + 1, m):
            d = 0.0
            for c in range(k, n):
                d += B[r, c] * B[k, c]
            f = tau * d
            t = 0.0
            for c in range(k, n):
                B[r, c] -= f * B[k, c]
                if c > k:
                    t += B[r, c] * B[r, c]
            norms[r] = t
        B[k, k] = alpha
        for c in range(k + 1, n):
            B[k, c] = 0.0


@njit(cache=True, error_model="numpy")
def certified_conditioning(L, m, inverse_row):
    """A lower bound on ``σ_min / σ_max`` of ``L (m, m)`` lower-triangular: ``σ_min ≥ 1/‖L⁻¹‖_F`` and
    ``σ_max ≤ ‖L‖_F``, so ``σ_min / σ_max ≥ 1 / (‖L⁻¹‖_F ‖L‖_F)`` (within a factor ``m`` of the ratio
    itself); 0 where a diagonal entry is zero. ``inverse_row (m,)`` is scratch."""
    norm = 0.0
    for i in range(m):
        if L[i, i] == 0.0:
            return 0.0
        for j in range(i + 1):
            norm += L[i, j] * L[i, j]
    # ‖L⁻¹‖_F² by the rows of L⁻¹: e_iᵀ L⁻¹ solves xᵀ L = e_iᵀ (back substitution on Lᵀ)
    inverse = 0.0
    for i in range(m):
        for j in range(i, -1, -1):
            s = 1.0 if j == i else 0.0
            for k in range(j + 1, i + 1):
                s -= inverse_row[k] * L[k, j]
            inverse_row[j] = s / L[j, j]
            inverse += inverse_row[j] * inverse_row[j]
    return 1.0 / math.sqrt(inverse * norm)


@njit(cache=True, error_model="numpy")
def metric_solve(L, A, W, Y, scratch, V, sigma, rhs, rank_tolerance, m, n, coefficients, magnitudes, lam, order,
                 norms):
    """Minimum-norm ``λ = G⁺ rhs`` into ``lam (m,)`` for ``G = A M⁻¹ Aᵀ = B Bᵀ`` of the first ``m`` rows of
    ``A (·, n)``, with the rows in the metric of ``M = L Lᵀ`` (:func:`cholesky`): ``W_i = L⁻¹ A_iᵀ``, the
    rows of ``B = A L⁻ᵀ``, and ``Y_i = L⁻ᵀ W_i = M⁻¹ A_iᵀ``, which the caller reads afterwards (``A`` and
    ``Y`` may be one array). Returns the rank, whether every row counted, and the conditioning of the rows:
    the smallest singular value above rounding (``m ε σ_max``) over the largest, or a lower bound on it
    (below).

    Where a row-pivoted LQ of ``B`` (:func:`pivoted_lq`, ``Π B = T Q`` with ``T`` lower triangular, so
    ``G = Πᵀ T Tᵀ Π``) certifies that every singular value exceeds ``rank_tolerance`` times the largest
    (:func:`certified_conditioning`, whose bound is then the conditioning returned), ``Π λ = T⁻ᵀ T⁻¹ Π rhs``
    by two triangular solves: ``T`` has the singular values of ``B``, so this does not square the condition
    number either. Otherwise the one-sided Jacobi rotations of ``W`` (:func:`orthogonalize_rows`, which then
    holds ``V``, ``σ``) and :func:`minimum_norm` drop the directions below the tolerance.
    ``scratch (m, n)``, ``order``, ``norms (m,)`` are scratch."""
    for i in range(m):
        for c in range(n):
            W[i, c] = A[i, c]
        forward_substitution(L, n, W[i])
        for c in range(n):
            Y[i, c] = W[i, c]
            scratch[i, c] = W[i, c]
        back_substitution(L, n, Y[i])
    pivoted_lq(scratch, m, n, order, norms)
    conditioning = certified_conditioning(scratch, m, norms)
    if conditioning > rank_tolerance:
        for k in range(m):
            norms[k] = rhs[int(order[k])]
        forward_substitution(scratch, m, norms)
        back_substitution(scratch, m, norms)
        for k in range(m):
            lam[int(order[k])] = norms[k]
        return m, True, conditioning
    orthogonalize_rows(W, V, sigma, m)
    rank = minimum_norm(V, sigma, rhs, rank_tolerance, m, coefficients, magnitudes, lam)
    # the smallest singular value above rounding over the largest: a direction dropped by the rank
    # tolerance near a singular configuration still shows how close it is, a redundant row does not
    largest, smallest = 0.0, math.inf
    for j in range(m):
        largest = larger(largest, sigma[j])
    for j in range(m):
        if sigma[j] > m * EPSILON * largest:
            smallest = smaller(smallest, sigma[j])
    return rank, False, (smallest / largest if largest > 0.0 else 0.0)


@njit(cache=True, error_model="numpy")
def metric_workspace_size(m, nv):
    """Floats of :func:`metric_workspace`: ``3 m nv + m² + 7 m``."""
    return 3 * m * nv + m * m + 7 * m


@njit(cache=True, error_model="numpy")
def metric_workspace(ws, start, m, nv):
    """The arrays of the minimum-norm solves, carved from ``ws[start:]`` (:func:`metric_workspace_size`):
    ``W``, ``Y (m, nv)`` of :func:`metric_solve`; ``V (m, m)`` and ``σ`` of :func:`orthogonalize_rows`;
    ``rhs``, ``coefficients`` and ``magnitudes`` of :func:`minimum_norm`; the scratch ``(m, nv)``, ``order``
    and ``norms`` of :func:`metric_solve`; the multipliers ``λ (m,)``; and where the next array starts."""
    W = ws[start : start + m * nv].reshape((m, nv))  # rows: L⁻¹ A_iᵀ, then rotated
    start += m * nv
    Y = ws[start : start + m * nv].reshape((m, nv))  # rows: M⁻¹ A_iᵀ
    start += m * nv
    V = ws[start : start + m * m].reshape((m, m))
    start += m * m
    scratch = ws[start : start + m * nv].reshape((m, nv))
    start += m * nv
    vectors = ws[start : start + 7 * m]
    return (W, Y, V, vectors[:m], vectors[m : 2 * m], vectors[2 * m : 3 * m], vectors[3 * m : 4 * m], scratch,
            vectors[4 * m : 5 * m], vectors[5 * m : 6 * m], vectors[6 * m :], start + 7 * m)


@njit(cache=True, error_model="numpy")
def solve_workspace_size(m, nv):
    """Floats of :func:`solve_workspace`: ``4 m nv + m² + 9 m``."""
    return m * nv + 2 * m + metric_workspace_size(m, nv)


@njit(cache=True, error_model="numpy")
def solve_workspace(ws, start, m, nv):
    """The rows ``A (m, nv)``, ``γ``, ``φ (m,)`` and the arrays of :func:`metric_workspace` but ``λ``, carved from
    ``ws[start:]`` (:func:`solve_workspace_size`), for a caller that evaluates rows and solves with them
    (:func:`multibody.kernels.variational.advance`); and where the next array starts."""
    A = ws[start : start + m * nv].reshape((m, nv))
    gamma, phi = ws[start + m * nv : start + m * nv + m], ws[start + m * nv + m : start + m * nv + 2 * m]
    (W, Y, V, sigma, rhs, coefficients, magnitudes, scratch, order, norms, _,
     start) = metric_workspace(ws, start + m * nv + 2 * m, m, nv)
    return A, gamma, phi, W, Y, V, sigma, rhs, coefficients, magnitudes, scratch, order, norms, start


#: The last columns of every solve's output row (:func:`solve_rows`, :func:`project`): the rank of the rows, the
#: row a failure concerns (the inconsistent row, or the first row of the constraint whose rows are undefined; −1
#: for none), the rows' conditioning (:func:`metric_solve`), a value the status reports (how far that row is
#: off, or the ``|φ|`` a projection left) and the status.
RANK, ROW, CONDITIONING, VALUE, STATUS = -5, -4, -3, -2, -1
TAIL = 5


@njit(cache=True, error_model="numpy")
def solve_rows_workspace_size(m, nv):
    """Floats of workspace of :func:`solve_rows`."""
    return nv + m + metric_workspace_size(m, nv)


@njit(cache=True, error_model="numpy")
def solve_rows(M, h, tau, A, gamma, rank_tolerance, check, row, ws):
    """The constrained accelerations and multipliers of ``M a + h = τ + Aᵀ λ``, ``A a = γ`` into ``row``:
    ``a (nv)`` in ``row[:nv]``, ``λ (m)`` in ``row[nv : nv + m]`` and the last :data:`TAIL` columns (rank, row,
    conditioning, value, status). Returns the status: ``SOLVED``, ``NOT_POSITIVE_DEFINITE`` or, with
    ``check``, ``INCONSISTENT`` (``a`` and ``λ`` are then the minimum-norm ones, the row and how far it is off
    reported). The one solve of every caller, whether the rows come from a compiled program
    (:func:`constrained_accelerations`) or from arrays (:func:`solve_arrays`).

    Featherstone, *Rigid Body Dynamics Algorithms*, §8.1, eq. 8.7 (module docstring): ``M = L Lᵀ`` by
    :func:`cholesky` (``M (nv, nv)`` is overwritten with ``L``), ``λ = G⁺ (γ − A a_free)`` by
    :func:`metric_solve`'s rank rule, ``a = a_free + M⁻¹ Aᵀ λ``. ``h``, ``tau (nv,)`` or length 0 (zero);
    ``A (m, nv)``, ``gamma (m,)``; ``ws``: :func:`solve_rows_workspace_size` floats."""
    nv, m = M.shape[0], A.shape[0]
    a_free, scale = ws[:nv], ws[nv : nv + m]
    (W, Y, V, sigma, rhs, coefficients, magnitudes, scratch, order, norms, _,
     _) = metric_workspace(ws, nv + m, m, nv)
    a, lam = row[:nv], row[nv : nv + m]
    end = row.shape[0]
    row[end + ROW] = -1.0
    if not cholesky(M, nv):
        row[end + STATUS] = NOT_POSITIVE_DEFINITE
        return NOT_POSITIVE_DEFINITE
    # a_free = M⁻¹ (τ − h)
    for c in range(nv):
        a_free[c] = (tau[c] if tau.shape[0] > 0 else 0.0) - (h[c] if h.shape[0] > 0 else 0.0)
    cholesky_solve(M, nv, a_free)
    # rhs = γ − A a_free
    for i in range(m):
        A_a_free = 0.0
        for c in range(nv):
            A_a_free += A[i, c] * a_free[c]
        rhs[i] = gamma[i] - A_a_free
        scale[i] = larger(larger(abs(gamma[i]), abs(A_a_free)), 1.0)
    # G = A M⁻¹ Aᵀ = B Bᵀ ;  λ = G⁺ rhs, keeping the directions with σ > tolerance · max σ
    rank, every_row, conditioning = metric_solve(M, A, W, Y, scratch, V, sigma, rhs, rank_tolerance, m, nv,
                                                 coefficients, magnitudes, lam, order, norms)
    # the part of rhs in the dropped directions cannot be met, judged against the terms that make it: the
    # row's own (scale) and those of the part met, Σ_j |V_ij| Σ_k |V_kj rhs_k|, whose rounding leaks
    # into every row that V mixes (a row of small rhs beside one of 1e12 at a fast joint); with every row
    # counted, none is dropped. The row reported is the one furthest off relative to its terms.
    status = SOLVED
    worst = 0.0
    for i in range(m if check and not every_row else 0):
        met, terms = 0.0, 0.0
        for j in range(m):
            met += V[i, j] * coefficients[j]
            terms += abs(V[i, j]) * magnitudes[j]
        off = rhs[i] - met
        bound = larger(scale[i], terms)
        if abs(off) > 1e-8 * bound:
            status = INCONSISTENT
            if abs(off) / bound > worst:
                worst = abs(off) / bound
                row[end + ROW] = i
                row[end + VALUE] = off
    # a = a_free + M⁻¹ Aᵀ λ
    for c in range(nv):
        s = a_free[c]
        for i in range(m):
            s += Y[i, c] * lam[i]
        a[c] = s
    row[end + RANK] = rank
    row[end + CONDITIONING] = conditioning
    row[end + STATUS] = status
    return status


@njit(cache=True, error_model="numpy")
def status_unless_finite(x0, x1, x2, x3, out):
    """:func:`~multibody.kernels.spatial.nan_unless_finite`, with the status ``NON_FINITE`` where an input has a
    NaN or infinite entry (every other column NaN)."""
    nan_unless_finite(x0, x1, x2, x3, out)
    last = out.shape[1] - 1
    if out[0, last] != out[0, last]:
        out[0, last] = NON_FINITE


def arrays_columns(nv, m):
    """Columns of :func:`solve_arrays`' output row: ``a (nv) | λ (m) |`` the :data:`TAIL`."""
    return nv + m + TAIL


def arrays_workspace_size(nv, m):
    """Floats of workspace of :func:`solve_arrays`."""
    return nv * nv + solve_rows_workspace_size(m, nv)


@njit(cache=True, error_model="numpy")
def solve_arrays(joints, reals, frames, options, h, tau, rows, out, ws):
    """:func:`solve_rows` on rows given as arrays (a constraint evaluated in Python), into ``out[0]`` (layout
    :func:`arrays_columns`): ``options = [rank tolerance, check, M (nv², row-major)]`` (check: 1.0 to report
    inconsistent rows, 0.0 for the minimum-norm solution alone), ``h (nv,)``, ``tau (nv,)`` or length 0
    (zero), ``rows = [A (m nv, row-major) | γ (m)]``. The tree's arrays are unused."""
    nv = h.shape[0]
    m = rows.shape[0] // (nv + 1)
    M = ws[: nv * nv].reshape((nv, nv))
    for i in range(nv):
        for c in range(nv):
            M[i, c] = options[2 + i * nv + c]
    A = rows[: m * nv].reshape((m, nv))
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    solve_rows(M, h, tau, A, rows[m * nv :], options[0], options[1] != 0.0, row, ws[nv * nv :])
    status_unless_finite(options, h, tau, rows, out)


@njit(cache=True, error_model="numpy")
def constrained_accelerations(joints, reals, frames, q, v, tau, program, out, ws):
    """One constrained step into ``out[0]`` (layout :func:`output_columns`): ``a`` (m/s², rad/s²), ``λ``,
    ``A``, ``γ`` and the :data:`TAIL` (rank, row, conditioning, value, status: ``SOLVED``,
    ``NOT_POSITIVE_DEFINITE``, ``INCONSISTENT``, ``constraints.UNDEFINED`` or ``NON_FINITE``; the other entries
    are meaningful only when solved).

    ``q (nq,)``, ``v (nv,)``, ``tau (nv,)`` or length 0 (zero), ``program`` as
    :mod:`multibody.kernels.constraints`; ``frames`` are the constraint frames it indexes. Baumgarte
    stabilisation ``γ ← γ − 2α A v − β² φ`` with ``(α, β)`` from the program's header. The solve is
    :func:`solve_rows`, as for rows given as arrays.
    """
    m = int(program[1])
    nv = (out.shape[1] - TAIL - 2 * m) // (1 + m)
    alpha, beta, rank_tolerance = program[2], program[3], program[4]
    none = program[:0]
    cols = kinematics.motion_columns(nv)
    # workspace
    start = 0
    M = ws[start : start + nv * nv].reshape((nv, nv))
    start += nv * nv
    h = ws[start : start + nv].reshape((1, nv))
    start += nv
    motions = ws[start : start + frames.shape[0] * cols].reshape((frames.shape[0], cols))
    start += frames.shape[0] * cols
    A = ws[start : start + m * nv].reshape((m, nv))
    start += m * nv
    gamma, phi = ws[start : start + m], ws[start + m : start + 2 * m]
    start += 2 * m
    solve_ws = ws[start : start + solve_rows_workspace_size(m, nv)]
    passes = ws[start + solve_rows_workspace_size(m, nv) :]
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    end = row.shape[0]

    crba.mass_matrix(joints, reals, frames, q, none, none, none, M, passes)
    rnea.inverse_dynamics(joints, reals, frames, q, v, none, none, h, passes)
    kinematics.frame_motions(joints, reals, frames, q, v, none, none, motions, passes)
    undefined = failing_entry(program, motions, q, v, A, gamma, phi)
    if undefined >= 0:
        row[end + STATUS] = UNDEFINED
        row[end + ROW] = undefined
        status_unless_finite(q, v, tau, program, out)
        return
    # Baumgarte: γ ← γ − 2α A v − β² φ
    if alpha != 0.0 or beta != 0.0:
        for i in range(m):
            Av = 0.0
            for c in range(nv):
                Av += A[i, c] * v[c]
            gamma[i] -= 2.0 * alpha * Av + beta * beta * phi[i]
    solve_rows(M, h[0], tau, A, gamma, rank_tolerance, True, row, solve_ws)
    base = nv + m
    for i in range(m):
        for c in range(nv):
            row[base + i * nv + c] = A[i, c]
        row[base + m * nv + i] = gamma[i]
    status_unless_finite(q, v, tau, program, out)


@njit(cache=True, error_model="numpy")
def metric_correction(L, A, rhs, mask, rank_tolerance, step, ws):
    """``δ = M⁻¹ A_Sᵀ (A_S M⁻¹ A_Sᵀ)⁺ rhs_S`` into ``step (nv,)`` over the rows ``S`` of ``A (m, nv)`` whose
    ``mask`` entry is not zero (``mask`` of length 0: every row), with ``M = L Lᵀ`` (:func:`cholesky`) and the
    rank rule of :func:`metric_solve`: the smallest move in the kinetic-energy metric that meets ``A_S δ =
    rhs_S``. Returns ``(max |δ|, max |rhs_S|, conditioning of the rows S)``. ``ws``:
    :func:`metric_workspace_size` floats."""
    m, nv = A.shape[0], A.shape[1]
    W, Y, V, sigma, rhs_s, coefficients, magnitudes, scratch, order, norms, lam, _ = metric_workspace(ws, 0, m, nv)
    k, error = 0, 0.0
    for i in range(m):
        if mask.shape[0] == 0 or mask[i] != 0.0:
            for c in range(nv):
                Y[k, c] = A[i, c]
            rhs_s[k] = rhs[i]
            error = larger(error, abs(rhs[i]))
            k += 1
    _, _, conditioning = metric_solve(L, Y, W, Y, scratch, V, sigma, rhs_s, rank_tolerance, k, nv, coefficients,
                                      magnitudes, lam, order, norms)
    size = 0.0
    for c in range(nv):
        s = 0.0
        for i in range(k):
            s += Y[i, c] * lam[i]
        step[c] = s
        size = larger(size, abs(s))
    return size, error, conditioning


@njit(cache=True, error_model="numpy")
def settled(error, size, previous, tolerance):
    """Whether Gauss–Newton on the position rows has settled: ``|φ| ≤ tol`` and the step ``size`` is below
    ``tol`` too (in the coordinates' units) or stopped shrinking (by half from the ``previous`` step), which
    is where rounding decides it near a singular configuration."""
    return error <= tolerance and (size <= tolerance or size > 0.5 * previous)


def correction_columns(nv):
    """Columns of :func:`correction_arrays`' output row: ``δ (nv) | max |δ| | settled |`` the :data:`TAIL`."""
    return nv + 2 + TAIL


def correction_workspace_size(nv, m):
    """Floats of workspace of :func:`correction_arrays`."""
    return nv * nv + metric_workspace_size(m, nv)


@njit(cache=True, error_model="numpy")
def correction_arrays(joints, reals, frames, options, rows, mask, x3, out, ws):
    """One correction of a projection on rows given as arrays (a constraint evaluated in Python), into
    ``out[0]`` (layout :func:`correction_columns`): :func:`metric_correction` ``δ``, its size, and whether
    Gauss–Newton has :func:`settled`, with the conditioning of the rows, ``max |rhs|`` (in the value column)
    and a status (``SOLVED``, ``NOT_POSITIVE_DEFINITE``, ``NON_FINITE``). ``options = [rank tolerance,
    tolerance, previous step size, M (nv², row-major)]``, ``rows = [A (m nv, row-major) | rhs (m)]``,
    ``mask (m,)`` or length 0 (every row). :meth:`multibody.ConstrainedSystem.project` iterates it where the
    rows come from Python, as :func:`project` iterates :func:`metric_correction` on compiled rows."""
    nv = out.shape[1] - 2 - TAIL
    m = rows.shape[0] // (nv + 1)
    L = ws[: nv * nv].reshape((nv, nv))
    for i in range(nv):
        for c in range(nv):
            L[i, c] = options[3 + i * nv + c]
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    end = row.shape[0]
    row[end + ROW] = -1.0
    if not cholesky(L, nv):
        row[end + STATUS] = NOT_POSITIVE_DEFINITE
    else:
        size, error, conditioning = metric_correction(L, rows[: m * nv].reshape((m, nv)), rows[m * nv :], mask,
                                                      options[0], row[:nv], ws[nv * nv :])
        row[nv] = size
        row[nv + 1] = 1.0 if settled(error, size, options[2], options[1]) else 0.0
        row[end + CONDITIONING] = conditioning
        row[end + VALUE] = error
        row[end + STATUS] = SOLVED
    # (the previous step size starts infinite)
    status_unless_finite(options[3:], rows, mask, x3, out)


@njit(cache=True, error_model="numpy")
def projection_columns(nq, nv):
    """Columns of :func:`project`'s output row: ``q' (nq) | v' (nv) |`` the :data:`TAIL` (its rank column
    unused)."""
    return nq + nv + TAIL


def projection_workspace_size(nj, nq, nv, nframes, m):
    """Floats of workspace of :func:`project` with ``nframes`` constraint frames and ``m`` rows."""
    passes = max(crba.workspace_size(nj, nv), kinematics.workspace_size(nj, nv))
    return (nv * nv + nframes * kinematics.motion_columns(nv) + m * nv + 3 * m + 2 * nv + nq
            + metric_workspace_size(m, nv) + passes)


@njit(cache=True, error_model="numpy")
def project(joints, reals, frames, q, v, settings, program, out, ws):
    """The nearest consistent state into ``out[0]`` (layout :func:`projection_columns`), from ``q`` with its
    unit-norm blocks normalised (as :func:`multibody.kernels.configuration.normalize`): ``φ(q') = 0``
    and ``A(q') v' = 0`` for the rows of ``program`` (fixed in time, ``b = 0``), with the conditioning of
    the rows at ``q'`` (as :func:`metric_solve` returns it: near 0 close to a singular configuration), the
    largest ``|φ|`` left (value column) and a status (``SOLVED``, ``NOT_CONVERGED``, ``NOT_POSITIVE_DEFINITE``,
    ``constraints.UNDEFINED`` with the constraint's first row, or ``NON_FINITE``).

    Positions by Gauss–Newton steps on the rows with a position level, the smallest moves in the
    kinetic-energy metric (Hairer, Lubich & Wanner, *Geometric Numerical Integration*, §IV.4):

        δ = M⁻¹ Aᵀ (A M⁻¹ Aᵀ)⁺ φ,   q ← q ⊕ (−δ)

    until they have :func:`settled`. Then the velocities by the ``M``-orthogonal projection
    ``v' = v − M⁻¹ Aᵀ (A M⁻¹ Aᵀ)⁺ A v``. Both corrections are :func:`metric_correction`, whose minimum-norm
    solve is that of :func:`solve_rows` (:func:`metric_solve`), with the same rank decision; rows given as
    arrays take the same correction and the same rule, one call of :func:`correction_arrays` per iteration.

    ``q (nq,)``, ``v (nv,)``; ``settings = [tol, max_iterations, position mask (m)]``: whether each row
    has a position level (1.0) or not (0.0).
    """
    m = int(program[1])
    nq, nv = q.shape[0], v.shape[0]
    rank_tolerance = program[4]
    tolerance, iterations = settings[0], int(settings[1])
    mask = settings[2:]
    cols = kinematics.motion_columns(nv)
    # workspace
    start = 0
    L = ws[start : start + nv * nv].reshape((nv, nv))
    start += nv * nv
    motions = ws[start : start + frames.shape[0] * cols].reshape((frames.shape[0], cols))
    start += frames.shape[0] * cols
    A = ws[start : start + m * nv].reshape((m, nv))
    start += m * nv
    gamma, phi, Av = ws[start : start + m], ws[start + m : start + 2 * m], ws[start + 2 * m : start + 3 * m]
    start += 3 * m
    zeros = ws[start : start + nv]
    start += nv
    step = ws[start : start + nv]
    start += nv
    moved = ws[start : start + nq]
    start += nq
    metric = ws[start : start + metric_workspace_size(m, nv)]
    passes = ws[start + metric_workspace_size(m, nv) :]
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    q_new, v_new = row[:nq], row[nq : nq + nv]
    end = row.shape[0]
    row[end + ROW] = -1.0
    # every quaternion and planar (cos θ, sin θ) of q scaled to unit norm first
    for i in range(joints.shape[0]):
        kinds.normalize(joints[i, KIND], joints[i, NV], q, joints[i, IQ], q_new)
    for c in range(nv):
        zeros[c] = 0.0
    holonomic = False
    for i in range(m):
        holonomic = holonomic or mask[i] != 0.0

    none = program[:0]
    previous = math.inf
    converged, status = not holonomic, SOLVED
    for iteration in range(iterations + 1 if holonomic else 1):
        # the rows A, φ at q and the Cholesky factor L of M(q)
        kinematics.frame_motions(joints, reals, frames, q_new, zeros, none, none, motions, passes)
        undefined = failing_entry(program, motions, q_new, zeros, A, gamma, phi)
        if undefined >= 0:
            status = UNDEFINED
            row[end + ROW] = undefined
            break
        crba.mass_matrix(joints, reals, frames, q_new, none, none, none, L, passes)
        if not cholesky(L, nv):
            status = NOT_POSITIVE_DEFINITE
            break
        if converged or iteration == iterations:
            break
        # δ = M⁻¹ Aᵀ (A M⁻¹ Aᵀ)⁺ φ over the rows with a position level
        size, error, _ = metric_correction(L, A, phi, mask, rank_tolerance, step, metric)
        row[end + VALUE] = error
        if settled(error, size, previous, tolerance):
            converged = True
            break
        previous = size
        # q ← q ⊕ (−δ)
        for c in range(nv):
            step[c] = -step[c]
        for i in range(joints.shape[0]):
            kinds.integrate(joints[i, KIND], joints[i, NV], q_new, step, joints[i, IQ], joints[i, IV], moved)
        for c in range(nq):
            q_new[c] = moved[c]
    if status == SOLVED and not converged:
        status = NOT_CONVERGED
        error = 0.0
        for i in range(m):
            if mask[i] != 0.0:
                error = larger(error, abs(phi[i]))
        row[end + VALUE] = error
    if status != SOLVED:
        row[end + STATUS] = status
        status_unless_finite(q, v, settings, program, out)
        return
    # v' = v − M⁻¹ Aᵀ (A M⁻¹ Aᵀ)⁺ A v over every row
    for i in range(m):
        s = 0.0
        for c in range(nv):
            s += A[i, c] * v[c]
        Av[i] = s
    _, _, conditioning = metric_correction(L, A, Av, none, rank_tolerance, step, metric)
    for c in range(nv):
        v_new[c] = v[c] - step[c]
    row[end + CONDITIONING] = conditioning
    row[end + STATUS] = SOLVED
    status_unless_finite(q, v, settings, program, out)
