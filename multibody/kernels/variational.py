"""One Newton iterate of the variational integrator's midpoint step, for a model and compiled constraint rows.

The terms that :func:`multibody.variational._step` evaluates at each iterate ``Δ`` of a step from ``q_k``
(module docstring of :mod:`multibody.variational`, midpoint rule, no forces), in one compiled call:

    q̄ = q_k ⊕ Δ/2,   q_{k+1} = q_k ⊕ Δ,   ξ = Δ/h,
    start = J_l(Δ)⁻ᵀ (M(q̄) ξ − (h/2) J_l(Δ/2)ᵀ ∂L/∂q(q̄, ξ))        (= M ξ − (h/2) ∂L/∂q on a vector space),

with ``⊕`` the integrator's group (SO(3) × R³ for a free flyer, its velocities ``w`` with the linear part in
the parent frame: :func:`multibody.kernels.lagrangian.lagrangian_terms`), and the constraint rows of the
step: the holonomic rows at ``q_{k+1}``, ``φ(q_{k+1}) = 0`` linearised by ``A(q_{k+1}) J_l(−Δ)``, the
nonholonomic rows at the midpoint, ``A(q̄) ξ = 0`` linearised by ``A(q̄)/h``, both in the group velocities
(``A T``). The rows are fixed in time (``b = 0``: the compiled rows, :mod:`multibody.kernels.constraints`).
``M`` holds the joints' armature on its diagonal (:func:`multibody.kernels.crba.mass_matrix`).
"""

from __future__ import annotations

import math

from ..tree import IQ, IV, KIND
from . import configuration, constraints, lagrangian
from . import joints as kinds
from .jit import njit
from .spatial import nan_unless_finite


def output_columns(nq, nv, m):
    """Columns of :func:`midpoint_iterate`'s output row (its docstring gives the layout)."""
    return nv + 1 + 2 * nq + 6 * nv * nv + nv + 3 * m + 2 * m * nv + 1


def workspace_size(nj, nv, nframes, m):
    """Floats of workspace one iterate needs: the Lagrangian's terms, ``J_l(−Δ)``, two rows of constraint
    levels, two vectors, and the largest workspace of the kernels it calls."""
    return ((nv + 1) * nv + 2 * nv * nv + 2 * constraints.levels_columns(nv, m) + 2 * nv
            + max(lagrangian.workspace_size(nj, nv), constraints.workspace_size(nj, nv, nframes),
                  configuration.workspace_size(nj, nv)))


@njit(cache=True, error_model="numpy")
def advance(joints, reals, frames, q, x, scale, out, ws):
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
        size = max(size, abs(x[c]))
    return size


@njit(cache=True, error_model="numpy")
def midpoint_iterate(joints, reals, frames, q0, delta, settings, program, out, ws):
    """The midpoint step's terms at the iterate ``Δ = delta (nv,)`` from ``q0 (nq,)`` (module docstring) into
    ``out[0]``, in order:

    ``start (nv)``, ``scale`` (``max(|M ξ|, (h/2) |∂L/∂q|)``), ``q̄ (nq)``, ``q_{k+1} (nq)``, ``M(q̄) (nv²)``,
    ``∂L/∂q(q̄, ξ) (nv)``, ``Ad_exp(Δ)``, ``J_l(Δ)``, ``Ad_exp(Δ/2)``, ``J_l(Δ/2)`` (``nv²`` each), the rows'
    residuals ``c (m)``, their linearisation ``C (m nv)`` and scales ``(m)``, the rows at ``q_{k+1}``: ``φ
    (m)`` and ``A T (m nv)``, and a status: 0, or ``constraints.UNDEFINED`` where a row is undefined.

    ``settings``: ``[h, group, holonomic₀ … holonomic_{m−1}]``: the step ``h`` (s), 1 for the group
    velocities of a free flyer (0: the joints' own), and 1 for each holonomic row; ``program``: the rows'
    program (:mod:`multibody.kernels.constraints`; length 0 for none). The scales are those of
    :func:`multibody.variational._step`: ``max(1, |q_{k+1}|)`` for a holonomic row, ``max(|A| |ξ|,
    max|A_row| |ξ|_∞, 1e-300)`` for a nonholonomic one.
    """
    nq, nv = q0.shape[0], delta.shape[0]
    h, grouped = settings[0], settings[1] > 0.0
    m = int(program[1]) if program.shape[0] > 0 else 0
    row = out[0]
    # the output's blocks
    start = row[:nv]
    o = nv + 1
    q_mid, q1 = row[o : o + nq], row[o + nq : o + 2 * nq]
    o += 2 * nq
    M = row[o : o + nv * nv].reshape((nv, nv))
    o += nv * nv
    pull = row[o : o + nv]
    o += nv
    exponentials = row[o : o + 4 * nv * nv].reshape((4 * nv, nv))  # [Ad(Δ); J_l(Δ); Ad(Δ/2); J_l(Δ/2)]
    o += 4 * nv * nv
    c, C = row[o : o + m], row[o + m : o + m + m * nv].reshape((m, nv))
    o += m + m * nv
    scales = row[o : o + m]
    o += m
    phi1, A1 = row[o : o + m], row[o + m : o + m + m * nv].reshape((m, nv))
    # the workspace's blocks
    terms = ws[: (nv + 1) * nv].reshape((nv + 1, nv))
    w = (nv + 1) * nv
    back = ws[w : w + 2 * nv * nv].reshape((2 * nv, nv))  # [Ad(−Δ); J_l(−Δ)]
    w += 2 * nv * nv
    columns = m * nv + 2 * m + 1  # constraints.levels_columns(nv, m)
    levels = ws[w : w + 2 * columns].reshape((2, columns))
    w += 2 * columns
    xi, y = ws[w : w + nv], ws[w + nv : w + 2 * nv]
    scratch = ws[w + 2 * nv :]
    for r in range(nv):
        xi[r] = delta[r] / h
    # q̄ = q_k ⊕ Δ/2,  q_{k+1} = q_k ⊕ Δ
    advance(joints, reals, frames, q0, delta, 0.5, q_mid.reshape((1, nq)), scratch)
    advance(joints, reals, frames, q0, delta, 1.0, q1.reshape((1, nq)), scratch)
    # M(q̄), ∂L/∂q(q̄, ξ)
    lagrangian.lagrangian_terms(joints, reals, frames, q_mid, xi, settings[1:2] if grouped else settings[:0],
                                settings[:0], terms, scratch)
    for r in range(nv):
        for k in range(nv):
            M[r, k] = terms[r, k]
        pull[r] = terms[nv, r]
    configuration.exponential_terms(joints, reals, frames, delta, delta[:0], delta[:0], delta[:0],
                                    exponentials[: 2 * nv], scratch)
    for r in range(nv):
        y[r] = 0.5 * delta[r]
    configuration.exponential_terms(joints, reals, frames, y, delta[:0], delta[:0], delta[:0],
                                    exponentials[2 * nv :], scratch)
    # start = J_l(Δ)⁻ᵀ (M ξ − (h/2) J_l(Δ/2)ᵀ ∂L/∂q)
    J_half = exponentials[3 * nv :]
    size_momentum, size_pull = 0.0, largest(pull)
    for r in range(nv):
        momentum = 0.0
        for k in range(nv):
            momentum += M[r, k] * xi[k]
        size_momentum = max(size_momentum, abs(momentum)) if math.isfinite(momentum) else math.nan
        pulled = 0.0
        for k in range(nv):
            pulled += J_half[k, r] * pull[k]
        y[r] = momentum - 0.5 * h * pulled
    solve_transposed_blocks(joints, exponentials[nv : 2 * nv], y, start)
    row[nv] = max(size_momentum, 0.5 * abs(h) * size_pull) if size_momentum == size_momentum else math.nan
    status = 0.0
    if m > 0:
        # the rows at q_{k+1} and at q̄, in the group velocities
        constraints.constraint_levels(joints, reals, frames, q1, delta[:0], delta[:0], program, levels[0:1], scratch)
        constraints.constraint_levels(joints, reals, frames, q_mid, delta[:0], delta[:0], program, levels[1:2], scratch)
        status = max(levels[0, columns - 1], levels[1, columns - 1])
        A_end = levels[0, : m * nv].reshape((m, nv))
        A_mid = levels[1, : m * nv].reshape((m, nv))
        if grouped:
            lagrangian.to_group_velocities(joints, q1, A_end)
            lagrangian.to_group_velocities(joints, q_mid, A_mid)
        for r in range(m):
            phi1[r] = levels[0, m * nv + m + r]
            for k in range(nv):
                A1[r, k] = A_end[r, k]
        for r in range(nv):
            y[r] = -delta[r]
        configuration.exponential_terms(joints, reals, frames, y, delta[:0], delta[:0], delta[:0], back, scratch)
        size_q1, size_xi = largest(q1), largest(xi)
        for r in range(m):
            if settings[2 + r] > 0.0:
                # φ(q_{k+1}) = 0, linearised by A(q_{k+1}) J_l(−Δ)
                c[r] = phi1[r]
                for k in range(nv):
                    total = 0.0
                    for j in range(nv):
                        total += A_end[r, j] * back[nv + j, k]
                    C[r, k] = total
                scales[r] = max(1.0, size_q1) if size_q1 == size_q1 else math.nan
            else:
                # A(q̄) ξ = 0, linearised by A(q̄)/h
                total, weighted, entry = 0.0, 0.0, 0.0
                for k in range(nv):
                    total += A_mid[r, k] * xi[k]
                    weighted += abs(A_mid[r, k]) * abs(xi[k])
                    entry = max(entry, abs(A_mid[r, k]))
                    C[r, k] = A_mid[r, k] / h
                c[r] = total
                scales[r] = max(weighted, entry * size_xi, 1e-300)
    row[row.shape[0] - 1] = status
    nan_unless_finite(q0, delta, settings, program, out)
