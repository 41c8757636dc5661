"""One constrained step: ``M a + h = τ + Aᵀ λ`` with ``A a = γ``, from one compiled pass.

Eliminating ``a`` (R. Featherstone, *Rigid Body Dynamics Algorithms*, §8.1, eq. 8.7, with the sign
of λ of :class:`multibody.ConstrainedSystem`):

    a_free = M⁻¹ (τ − h)
    G λ = γ − A a_free,   G = A M⁻¹ Aᵀ          (minimum-norm λ when A is rank deficient)
    a = a_free + M⁻¹ Aᵀ λ

``M`` comes from CRBA, ``h`` from RNEA, the constraint frames from one forward pass, and the rows from
:mod:`multibody.kernels.constraints`; ``M`` is factored by Cholesky and ``G`` diagonalised by cyclic
Jacobi rotations, so that ``λ = V diag(w)⁺ Vᵀ rhs`` drops the directions with
``w ≤ rank tolerance · max w``, as :meth:`multibody.ConstrainedSystem.solve` does with LAPACK.
"""

from __future__ import annotations

import math

from numba import njit

from . import crba, kinematics, rnea
from .constraints import constraint_rows
from .spatial import nan_unless_finite

#: Status of a step: solved; ``M`` not positive definite; constraints that no acceleration meets;
#: a constraint without a defined direction (see :mod:`multibody.kernels.constraints`).
SOLVED, NOT_POSITIVE_DEFINITE, INCONSISTENT = 0, 1, 2


@njit(cache=True, error_model="numpy")
def output_columns(nv, m):
    """Columns of the step's output row: ``a (nv) | λ (m) | A (m nv, row-major) | γ (m) | rank | status``."""
    return nv + m + m * nv + m + 2


def workspace_size(nj, nv, nframes, m):
    """Floats of workspace of one step with ``nframes`` constraint frames and ``m`` rows."""
    passes = max(crba.workspace_size(nj, nv), rnea.workspace_size(nj, nv), kinematics.workspace_size(nj, nv))
    return (nv * nv + 2 * nv + nframes * kinematics.motion_columns(nv) + m * nv + 2 * m + nv * m + 2 * m * m + 2 * m
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
def cholesky_solve(L, n, x):
    """``x ← M⁻¹ x`` from the factor of :func:`cholesky`: ``L y = x``, then ``Lᵀ x = y``."""
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model="numpy")
def symmetric_eigen(G, V, w, m):
    """Eigen-decomposition ``G = V diag(w) Vᵀ`` of the symmetric ``G (m, m)`` by cyclic Jacobi rotations
    (Golub & Van Loan, *Matrix Computations*, 4th ed., Alg. 8.5.2 and 8.5.3). ``G`` is overwritten (its
    diagonal ends as ``w``); ``V`` gets the orthonormal eigenvectors as columns."""
    for i in range(m):
        for j in range(m):
            V[i, j] = 1.0 if i == j else 0.0
    for sweep in range(100):
        off, total = 0.0, 0.0
        for i in range(m):
            total += G[i, i] * G[i, i]
            for j in range(i + 1, m):
                off += 2.0 * G[i, j] * G[i, j]
        if off <= 1e-32 * (total + off):
            break
        for p in range(m - 1):
            for r in range(p + 1, m):
                if G[p, r] == 0.0:
                    continue
                # the rotation (c, s) that zeroes G_pr: τ = (G_rr − G_pp) / (2 G_pr), t = sign(τ)/(|τ| + √(1 + τ²))
                tau = (G[r, r] - G[p, p]) / (2.0 * G[p, r])
                t = 1.0 / (abs(tau) + math.sqrt(1.0 + tau * tau))
                if tau < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = t * c
                # G ← Jᵀ G J on rows and columns p and r
                for k in range(m):
                    g_kp, g_kr = G[k, p], G[k, r]
                    G[k, p] = c * g_kp - s * g_kr
                    G[k, r] = s * g_kp + c * g_kr
                for k in range(m):
                    g_pk, g_rk = G[p, k], G[r, k]
                    G[p, k] = c * g_pk - s * g_rk
                    G[r, k] = s * g_pk + c * g_rk
                # V ← V J
                for k in range(m):
                    v_kp, v_kr = V[k, p], V[k, r]
                    V[k, p] = c * v_kp - s * v_kr
                    V[k, r] = s * v_kp + c * v_kr
    for i in range(m):
        w[i] = G[i, i]


@njit(cache=True, error_model="numpy")
def constrained_accelerations(joints, reals, frames, q, v, tau, program, out, ws):
    """One constrained step into ``out[0]`` (layout :func:`output_columns`): ``a`` (m/s², rad/s²), ``λ``,
    ``A``, ``γ``, the rank of ``A`` and a status (``SOLVED``, ``NOT_POSITIVE_DEFINITE``, ``INCONSISTENT``
    or ``constraints.UNDEFINED``; the other entries are meaningful only when solved).

    ``q (nq,)``, ``v (nv,)``, ``tau (nv,)`` or length 0 (zero), ``program`` as
    :mod:`multibody.kernels.constraints`; ``frames`` are the constraint frames it indexes. Baumgarte
    stabilisation ``γ ← γ − 2α A v − β² φ`` with ``(α, β)`` from the program's header.
    """
    m = int(program[1])
    nv = (out.shape[1] - 2 - 2 * m) // (1 + m)
    alpha, beta, rank_tolerance = program[2], program[3], program[4]
    none = program[:0]
    cols = kinematics.motion_columns(nv)
    # workspace
    start = 0
    M = ws[start : start + nv * nv].reshape((nv, nv))
    start += nv * nv
    h = ws[start : start + nv].reshape((1, nv))
    start += nv
    a_free = ws[start : start + nv]
    start += nv
    motions = ws[start : start + frames.shape[0] * cols].reshape((frames.shape[0], cols))
    start += frames.shape[0] * cols
    A = ws[start : start + m * nv].reshape((m, nv))
    start += m * nv
    gamma = ws[start : start + m]
    start += m
    phi = ws[start : start + m]
    start += m
    Y = ws[start : start + m * nv].reshape((m, nv))  # rows: M⁻¹ A_iᵀ
    start += m * nv
    G = ws[start : start + m * m].reshape((m, m))
    start += m * m
    V = ws[start : start + m * m].reshape((m, m))
    start += m * m
    w = ws[start : start + m]
    start += m
    rhs = ws[start : start + m]
    start += m
    passes = ws[start:]
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    a, lam = row[:nv], row[nv : nv + m]
    status_column, rank_column = row.shape[0] - 1, row.shape[0] - 2

    crba.mass_matrix(joints, reals, frames, q, none, none, none, M, passes)
    rnea.inverse_dynamics(joints, reals, frames, q, v, none, none, h, passes)
    kinematics.frame_motions(joints, reals, frames, q, v, none, none, motions, passes)
    status = constraint_rows(program, motions, q, v, A, gamma, phi)
    if status != 0:
        row[status_column] = status
        nan_unless_finite(q, v, tau, program, out)
        return
    # Baumgarte: γ ← γ − 2α A v − β² φ
    if alpha != 0.0 or beta != 0.0:
        for i in range(m):
            Av = 0.0
            for c in range(nv):
                Av += A[i, c] * v[c]
            gamma[i] -= 2.0 * alpha * Av + beta * beta * phi[i]
    if not cholesky(M, nv):
        row[status_column] = NOT_POSITIVE_DEFINITE
        nan_unless_finite(q, v, tau, program, out)
        return
    # a_free = M⁻¹ (τ − h)
    for c in range(nv):
        a_free[c] = (tau[c] if tau.shape[0] > 0 else 0.0) - h[0, c]
    cholesky_solve(M, nv, a_free)
    # Y_i = M⁻¹ A_iᵀ ;  G = A M⁻¹ Aᵀ ;  rhs = γ − A a_free
    for i in range(m):
        for c in range(nv):
            Y[i, c] = A[i, c]
        cholesky_solve(M, nv, Y[i])
    for i in range(m):
        s = gamma[i]
        for c in range(nv):
            s -= A[i, c] * a_free[c]
        rhs[i] = s
        for j in range(i, m):
            g = 0.0
            for c in range(nv):
                g += A[i, c] * Y[j, c]
            G[i, j] = g
            G[j, i] = g
    # λ = V diag(w)⁺ Vᵀ rhs, keeping w > tolerance · max w
    symmetric_eigen(G, V, w, m)
    w_max = 0.0
    for i in range(m):
        w_max = max(w_max, w[i])
    rank = 0
    for i in range(m):
        if w[i] > rank_tolerance * w_max:
            rank += 1
            coefficient = 0.0
            for j in range(m):
                coefficient += V[j, i] * rhs[j]
            coefficient /= w[i]
            for j in range(m):
                lam[j] += V[j, i] * coefficient
    if rank < m:
        # the part of rhs outside the range of G cannot be met: G λ must reproduce rhs
        scale = 1.0
        for i in range(m):
            scale = max(scale, abs(rhs[i]))
        for i in range(m):
            # G's rows, rebuilt from the eigen-decomposition (G itself was overwritten)
            g_lam = 0.0
            for j in range(m):
                g_ij = 0.0
                for k in range(m):
                    g_ij += V[i, k] * w[k] * V[j, k]
                g_lam += g_ij * lam[j]
            if abs(rhs[i] - g_lam) > 1e-8 * scale:
                row[status_column] = INCONSISTENT
    # a = a_free + M⁻¹ Aᵀ λ
    for c in range(nv):
        s = a_free[c]
        for i in range(m):
            s += Y[i, c] * lam[i]
        a[c] = s
    base = nv + m
    for i in range(m):
        for c in range(nv):
            row[base + i * nv + c] = A[i, c]
        row[base + m * nv + i] = gamma[i]
    row[rank_column] = rank
    nan_unless_finite(q, v, tau, program, out)
