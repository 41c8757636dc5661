"""Dense linear algebra on one small matrix or a stack of them: ``(..., n, n)``.

``numpy.linalg`` loops over stacks in compiled code, but for one matrix its argument handling costs
several microseconds per call, more than factoring a robot-sized matrix (n ≤ 50). A single matrix
therefore goes straight to LAPACK (through ``scipy.linalg.lapack``), a stack to ``numpy.linalg``;
both run the same LAPACK routines and return the same results up to rounding.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


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
