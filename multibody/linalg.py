"""Dense linear algebra on one small matrix or a stack of them: ``(..., n, n)``.

``numpy.linalg`` loops over stacks in compiled code, but for one matrix its argument handling costs
several microseconds per call, more than factoring a robot-sized matrix (n ≤ 50). A single matrix
therefore goes straight to LAPACK (through ``scipy.linalg.lapack``), a stack to ``numpy.linalg``;
both run the same LAPACK routines and return the same results up to rounding.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


def cholesky(M):
    """Lower Cholesky factor ``L`` of symmetric positive-definite ``M = L Lᵀ``: ``(..., n, n)``.

    Raises ``numpy.linalg.LinAlgError`` when a matrix is not positive definite.
    """
    if M.ndim != 2:
        return np.linalg.cholesky(M)
    # (potrf reads the lower triangle and zeroes the upper one)
    L, info = lapack.dpotrf(M, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    return L


def cholesky_solve(L, rhs):
    """``M⁻¹ rhs`` from the Cholesky factor ``L`` of ``M`` (:func:`cholesky`): ``rhs (..., n, k)``.

    Two triangular solves, ``L y = rhs`` and ``Lᵀ x = y``.
    """
    if L.ndim != 2 or rhs.ndim != 2:
        return np.linalg.solve(np.swapaxes(L, -1, -2), np.linalg.solve(L, rhs))
    x, info = lapack.dpotrs(L, rhs, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"LAPACK dpotrs failed (info {info})")
    return x


def solve(M, rhs):
    """``M⁻¹ rhs`` by LU with partial pivoting: ``M (..., n, n)``, ``rhs (..., n, k)``.

    Raises ``numpy.linalg.LinAlgError`` when a matrix is exactly singular.
    """
    if M.ndim != 2 or rhs.ndim != 2:
        return np.linalg.solve(M, rhs)
    _, _, x, info = lapack.dgesv(M, rhs)
    if info != 0:
        raise np.linalg.LinAlgError("singular matrix")
    return x


def eigh(G):
    """Eigenvalues in ascending order ``(..., n)`` and orthonormal eigenvectors ``(..., n, n)`` (columns)
    of symmetric ``G``, read from its lower triangle."""
    if G.ndim != 2:
        return np.linalg.eigh(G)
    w, V, info = lapack.dsyevd(G, compute_v=1, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"eigenvalue decomposition did not converge (LAPACK dsyevd info {info})")
    return w, V


def lower_triangular_solve(L, rhs):
    """``L⁻¹ rhs`` for lower-triangular ``L (..., n, n)`` (a Cholesky factor), ``rhs (..., n, k)``.

    One matrix goes through :func:`solve` (LU), not LAPACK's triangular ``dtrtrs``: OpenBLAS runs the
    latter's ``trsm`` on its thread pool even for a 6×6 system, and on a machine whose cores are busy
    (a batch running beside it) one call then waits milliseconds for its threads instead of taking two
    microseconds; the LU of a triangular matrix costs no more at these sizes.
    """
    if L.ndim != 2 or rhs.ndim != 2:
        return np.linalg.solve(L, rhs)
    return solve(L, rhs)
