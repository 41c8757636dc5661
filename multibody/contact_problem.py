"""The velocity-level contact problem from Python: inputs checked, then the compiled solver.

:func:`solve` takes a Delassus matrix ``G``, a free velocity ``c`` and the kinds of the blocks of rows,
and calls :func:`multibody.kernels.complementarity.solve` (the problem, the method and the residual are
described there). :data:`STATUS_MESSAGES` says what each status of the solver means.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .kernels import complementarity
from .kernels.complementarity import (
    BILATERAL,
    CONTACT,
    CONVERGED,
    DIVERGED,
    INDEFINITE,
    MAX_ITERATIONS,
    NOT_FINITE,
    UNILATERAL,
)

__all__ = ["BILATERAL", "UNILATERAL", "CONTACT", "STATUS_MESSAGES", "ContactSolution", "block_starts", "solve"]

#: What each status of :func:`multibody.kernels.complementarity.solve` means.
STATUS_MESSAGES = {
    CONVERGED: "converged: the contact problem's residual is within the tolerance",
    MAX_ITERATIONS: "not converged: the residual is above the tolerance after the largest number of iterations",
    NOT_FINITE: "not solved: the Delassus matrix, the free velocity, a friction coefficient or the warm start "
                "has a NaN or infinite entry",
    INDEFINITE: "not solved: the Delassus matrix is not positive semi-definite",
    DIVERGED: "not solved: the iteration diverged with every penalty (its residual grew without bound or "
              "overflowed: the Delassus matrix is not positive semi-definite, the problem has no solution, or its "
              "magnitudes are near the largest float); the finite iterate of least residual is returned",
}

#: Names accepted for the kinds of block.
KIND_NAMES = {"bilateral": BILATERAL, "unilateral": UNILATERAL, "contact": CONTACT}


class ContactSolution(NamedTuple):
    """Result of :func:`solve`: impulses ``x (m,)`` (N·s), velocities ``u = G x + c (m,)`` (m/s), the solver's
    ``status`` (a key of :data:`STATUS_MESSAGES`) and its ``message``, the ``iterations`` run and the
    ``residual`` (m/s, as :mod:`multibody.kernels.complementarity` defines it)."""

    x: np.ndarray
    u: np.ndarray
    status: int
    message: str
    iterations: int
    residual: float


def block_starts(kinds):
    """The first row of each block of ``kinds (nb,)`` (codes), and the number of rows."""
    rows = np.where(np.asarray(kinds) == CONTACT, 3, 1)
    starts = np.concatenate([[0], np.cumsum(rows)[:-1]]).astype(np.int64) if len(rows) else np.zeros(0, np.int64)
    return starts, int(rows.sum())


def _kinds(kinds):
    codes = []
    for b, kind in enumerate(kinds):
        if isinstance(kind, str) and kind.lower() in KIND_NAMES:
            codes.append(KIND_NAMES[kind.lower()])
        elif not isinstance(kind, (str, bool, np.bool_)) and isinstance(kind, (int, np.integer)) and kind in (
                BILATERAL, UNILATERAL, CONTACT):
            codes.append(int(kind))
        else:
            raise ValueError(f"kinds[{b}] must be 'bilateral', 'unilateral' or 'contact' (or the codes "
                             f"{BILATERAL}, {UNILATERAL}, {CONTACT}), got {kind!r}")
    return np.array(codes, dtype=np.int64)


def solve(G, c, kinds, mu=None, *, tolerance=1e-12, max_iterations=1000, warm_start=None) -> ContactSolution:
    """Solve the contact problem ``u = G x + c`` with the blocks ``kinds`` (see
    :mod:`multibody.kernels.complementarity`).

    ``G (m, m)``: the Delassus matrix (m/s per N·s), symmetric positive semi-definite; ``c (m,)``: the free
    velocity (m/s); ``kinds``: one entry per block, in the order of the rows, ``"bilateral"`` (1 row),
    ``"unilateral"`` (1 row) or ``"contact"`` (3 rows: normal, two tangents), or the codes
    :data:`BILATERAL`, :data:`UNILATERAL`, :data:`CONTACT`; ``mu (nb,)`` or a number: the friction
    coefficient of each block (≥ 0, read for contacts only; default 0); ``tolerance`` (m/s, > 0);
    ``max_iterations`` (≥ 1); ``warm_start (m,)`` impulses to start from (default zero).
    Returns a :class:`ContactSolution`; a status other than converged is reported there, not raised.
    """
    codes = _kinds(kinds)
    starts, m = block_starts(codes)
    G = np.array(G, dtype=float, copy=True, order="C")
    c = np.array(c, dtype=float, copy=True)
    if G.shape != (m, m):
        raise ValueError(f"G must have shape ({m}, {m}) for the blocks of kinds ({m} rows), got {G.shape}")
    if c.shape != (m,):
        raise ValueError(f"c must have shape ({m},) for the blocks of kinds, got {c.shape}")
    if mu is None:
        mu = 0.0
    mu = np.array(np.broadcast_to(np.asarray(mu, dtype=float), (len(codes),)) if np.ndim(mu) == 0 else mu,
                  dtype=float, copy=True)
    if mu.shape != (len(codes),):
        raise ValueError(f"mu must be a number or have shape ({len(codes)},), one per block, got {mu.shape}")
    bad = np.flatnonzero(~(mu >= 0.0) & np.isfinite(mu))
    if bad.size:
        raise ValueError(f"mu[{bad[0]}] must be ≥ 0, got {mu[bad[0]]}")
    if warm_start is None:
        x = np.zeros(m)
    else:
        x = np.array(warm_start, dtype=float, copy=True)
        if x.shape != (m,):
            raise ValueError(f"warm_start must have shape ({m},), got {x.shape}")
    if not (np.isscalar(tolerance) and tolerance > 0.0):
        raise ValueError(f"tolerance must be a positive number (m/s), got {tolerance!r}")
    if isinstance(max_iterations, (bool, np.bool_)) or not isinstance(max_iterations, (int, np.integer)) \
            or max_iterations < 1:
        raise ValueError(f"max_iterations must be an integer ≥ 1, got {max_iterations!r}")
    if np.all(np.isfinite(G)):
        asymmetry = np.max(np.abs(G - G.T), initial=0.0)
        if asymmetry > 1e-12 * max(np.max(np.abs(G), initial=0.0), np.finfo(float).tiny):
            raise ValueError(f"G must be symmetric, got |G - Gᵀ| up to {asymmetry:.3g}")
    u = np.zeros(m)
    ws = np.zeros(complementarity.workspace_size(m))
    status, iterations, residual = complementarity.solve(G, c, codes, starts, mu, float(tolerance),
                                                         int(max_iterations), x, u, ws)
    return ContactSolution(x, u, int(status), STATUS_MESSAGES[int(status)], int(iterations), float(residual))
