"""Spatial algebra in the *lane* layout that the batched algorithms compute in.

The public functions take arrays with leading batch axes, ``q (..., nq)``. Small matrix products
over such arrays (``np.matmul`` on a stack of 3×3 matrices) are dominated by per-matrix overhead.
Inside the algorithms every state is therefore a *lane*: an array holds each component of a
vector or matrix as one contiguous row over the ``N`` states, with the state axis last:

=================  ========================  ========================================
quantity           public layout             lane layout
=================  ========================  ========================================
configuration      ``(..., nq)``             ``(nq, N)``
rotations          ``(..., nj, 3, 3)``       ``(nj, 3, 3, N)``
spatial vectors    ``(..., nj, 6)``          ``(nj, 6, N)``
spatial inertias   ``(..., nj, 6, 6)``       ``(nj, 6, 6, N)``
=================  ========================  ========================================

A product of two 3×3 matrices then costs a handful of whole-row NumPy operations for all states
and all joints at once. Constants (axes, placements, inertias) carry a lane axis of length 1 and
broadcast. The functions here mirror :mod:`multibody.spatial` (same conventions: motion vectors
``[v; ω]``, force vectors ``[f; n]``) with the component axes just before the lane axis.
"""

from __future__ import annotations

import math

import numpy as np

from . import spatial


# ----------------------------------------------------------------------------- layout changes

def to_lanes(x, components=1, batch=None):
    """``x (..., *c)`` -> ``(*c, N)``: the last ``components`` axes kept, the batch axes flattened into N.

    With ``batch`` given, an ``x`` of a single state (no batch axes, or axes of length one) keeps a
    single lane, which broadcasts against the others, so that what is common to all states is
    computed once; any other ``x`` is first broadcast to ``batch``.
    """
    shape = x.shape[x.ndim - components:]
    if x.size == math.prod(shape):
        return x.reshape(shape + (1,))
    if batch is not None and x.shape[:-components] != batch:
        x = np.broadcast_to(x, batch + shape)
    # np.transpose with explicit axes: np.moveaxis costs several µs of argument handling per call.
    return x.reshape((math.prod(x.shape[:-components]),) + shape).transpose(tuple(range(1, components + 1)) + (0,))


def from_lanes(x, batch):
    """``(*components, N)`` -> ``batch + components``: the inverse of :func:`to_lanes`, contiguous."""
    if x.shape[-1] == 1:
        # (a transposed lane array is a strided view; np.ascontiguousarray would make a 0-d result 1-d)
        return np.asarray(x.reshape(batch + x.shape[:-1]), order="C")
    moved = x.transpose((x.ndim - 1,) + tuple(range(x.ndim - 1)))
    return np.asarray(moved, order="C").reshape(batch + moved.shape[1:])


def concatenate(arrays, axis):
    """``np.concatenate`` of lane arrays along a component ``axis``, a single lane broadcast to the others."""
    n = max(x.shape[-1] for x in arrays)
    return np.concatenate([x if x.shape[-1] == n else np.broadcast_to(x, x.shape[:-1] + (n,)) for x in arrays], axis=axis)


# ----------------------------------------------------------------------------- 3-D algebra

# np.einsum runs these small contractions in compiled loops over the lanes; on lanes it is about
# twice as fast as broadcasting a product and reducing it. With a single lane, though, its inner
# loop has length one and it pays its dispatch for every matrix entry: there np.matmul on the
# matrices themselves (a view without the lane axis) is several times faster.

def matmul(A, B):
    """``A B`` on lanes: ``(..., i, j, N), (..., j, k, N) -> (..., i, k, N)``."""
    if A.shape[-1] == 1 == B.shape[-1]:
        return np.matmul(A[..., 0], B[..., 0])[..., None]
    # (A B)_ik = Σ_j A_ij B_jk
    return np.einsum("...ijn,...jkn->...ikn", A, B)


def matvec(A, x):
    """``A x`` on lanes: ``(..., i, j, N), (..., j, N) -> (..., i, N)``."""
    if A.shape[-1] == 1 == x.shape[-1]:
        return np.matmul(A[..., 0], x)
    return np.einsum("...ijn,...jn->...in", A, x)


def transpose(A):
    """Swap the two matrix axes of ``(..., i, j, N)``."""
    return A.swapaxes(-2, -3)


def dot(a, b):
    """``aᵀ b`` on lanes: ``(..., n, N), (..., n, N) -> (..., N)``."""
    if a.shape[-1] == 1 == b.shape[-1]:
        return np.matmul(a[..., None, :, 0], b)[..., 0, :]
    return np.einsum("...in,...in->...n", a, b)


# (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}: the six products in one pass, then one difference.
# ndarray.take: a gather along one axis costs less than the equivalent fancy index.
_CROSS_LEFT = np.array([1, 2, 0, 2, 0, 1])
_CROSS_RIGHT = np.array([2, 0, 1, 1, 2, 0])


def cross(a, b):
    """``a × b`` on lanes: ``(..., 3, N), (..., 3, N) -> (..., 3, N)``."""
    products = a.take(_CROSS_LEFT, axis=-2) * b.take(_CROSS_RIGHT, axis=-2)
    return products[..., :3, :] - products[..., 3:, :]


# [w]× entries as in multibody.spatial.skew, the sign on the lane axis
_SKEW_INDEX, _SKEW_SIGN = spatial._SKEW_INDEX, spatial._SKEW_SIGN[:, None]


_IDENTITY = np.eye(3)[:, :, None]  # the 3×3 identity as a lane constant


def skew(w):
    """Cross-product matrix ``[w]×`` on lanes: ``(..., 3, N) -> (..., 3, 3, N)``."""
    return (w.take(_SKEW_INDEX, axis=-2) * _SKEW_SIGN).reshape(w.shape[:-2] + (3, 3, w.shape[-1]))


def _block_skew_table(blocks):
    """Gather index and sign ``(36,)`` that fill a 6×6 matrix from a 6-vector, given its 3×3 blocks as
    ``{(row block, column block): (first component, sign)}``: ``sign [x[first:first+3]]×`` each."""
    index, sign = np.zeros((6, 6), dtype=int), np.zeros((6, 6))
    for (row, column), (first, factor) in blocks.items():
        index[3 * row : 3 * row + 3, 3 * column : 3 * column + 3] = first + _SKEW_INDEX.reshape(3, 3)
        sign[3 * row : 3 * row + 3, 3 * column : 3 * column + 3] = factor * _SKEW_SIGN.reshape(3, 3)
    return index.ravel(), sign.reshape(36, 1)


# m × = [[ω×, v×], [0, ω×]] for m = [v; ω] (RBDA eq. 2.31); for a force f = [f; n], the matrix of the
# map m ↦ m ×* f is [[0, −f×], [−f×, −n×]].
_MOTION_CROSS_MATRIX = _block_skew_table({(0, 0): (3, 1.0), (0, 1): (0, 1.0), (1, 1): (3, 1.0)})
_BAR_FORCE_CROSS_MATRIX = _block_skew_table({(0, 1): (0, -1.0), (1, 0): (0, -1.0), (1, 1): (3, -1.0)})


def _block_skew(table, x):
    index, sign = table
    return (x.take(index, axis=-2) * sign).reshape(x.shape[:-2] + (6, 6, x.shape[-1]))


def motion_cross_matrix(m):
    """``[m×] = [[ω×, v×], [0, ω×]]`` on lanes: ``(..., 6, N) -> (..., 6, 6, N)``; ``[m×] m' = m × m'``."""
    return _block_skew(_MOTION_CROSS_MATRIX, m)


def bar_force_cross_matrix(f):
    """Matrix of ``m ↦ m ×* f`` for a fixed force ``f``, on lanes: ``(..., 6, N) -> (..., 6, 6, N)``."""
    return _block_skew(_BAR_FORCE_CROSS_MATRIX, f)


def quat_to_rotation(quat):
    """Rotation matrix of the quaternion ``[x, y, z, w]`` on lanes: ``(..., 4, N) -> (..., 3, 3, N)``.

    ``R = 1 + 2 (w [u]× + u uᵀ − uᵀu 1) / |q|²`` with ``u = (x, y, z)`` (``[u]×² = u uᵀ − uᵀu 1``);
    dividing by ``|q|²`` gives the rotation of ``q / |q|``, as :func:`multibody.spatial.quat_to_rotation`.
    """
    if quat.shape[-1] == 1:
        # one lane: the quadratic form's single contraction, fewer calls
        return spatial.quat_to_rotation(quat[..., 0])[..., None]
    u, w = quat[..., :3, :], quat[..., 3:, :]
    scale = 2.0 / dot(quat, quat)[..., None, None, :]
    R = scale * (w[..., None, :] * skew(u) + u[..., :, None, :] * u[..., None, :, :])
    return R + _IDENTITY * (1.0 - scale * dot(u, u)[..., None, None, :])


def inverse(D):
    """``D⁻¹`` of small symmetric matrices on lanes, ``D (k, n, n, N)`` (the joint-space articulated
    inertias of ABA); a singular ``D`` gives infinite entries, for the caller to report."""
    if D.shape[1] == 1:
        return 1.0 / D
    D = np.moveaxis(D, -1, 1)
    singular = np.linalg.det(D) == 0.0
    # np.linalg.inv would raise on a singular D: invert the identity there and mark it infinite.
    inverse = np.linalg.inv(np.where(singular[..., None, None], np.eye(D.shape[-1]), D))
    inverse[singular] = np.inf
    return np.moveaxis(inverse, 1, -1)


# ----------------------------------------------------------------------------- cosines and sines

# x = k π/2 + r with |r| ≤ π/4 (Cody and Waite's reduction, π/2 split so that k × the high part is
# exact for |k| < 2²⁰ and the low part carries the next 53 bits), then the Taylor series of cos r and
# sin r, whose first omitted terms r¹⁸/18! and r¹⁷/17! stay below 5e-17 on |r| ≤ π/4.
_HALF_PI_HIGH = 1.5707963267341256  # π/2 to 33 bits
_HALF_PI_LOW = 6.077100506506192e-11  # π/2 − _HALF_PI_HIGH
_SIN_SERIES = tuple((-1) ** j / math.factorial(2 * j + 1) for j in range(7, 0, -1))  # r³ … r¹⁵, Horner order
_COS_SERIES = tuple((-1) ** j / math.factorial(2 * j) for j in range(8, 0, -1))  # r² … r¹⁶
# cos and sin of k π/2 by k mod 4
_QUARTER_COS, _QUARTER_SIN = np.array([1.0, 0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0, -1.0])


def _series(z, coefficients):
    """``Σ_j c_j z^(n−j)`` for the n coefficients ``c_0 … c_(n−1)`` (no constant term) by Horner's rule, in place on one temporary."""
    p = z * coefficients[0]
    for c in coefficients[1:]:
        p += c
        p *= z
    return p


def cos_sin(x):
    """``(cos x, sin x)`` of a float array, within an ulp or two of ``np.cos`` and ``np.sin``: twice as
    fast for thousands of numbers (NumPy's double-precision cosine and sine run one element at a time
    on this class of machine), but some thirty NumPy calls, so for a few numbers ``np.cos`` and
    ``np.sin`` are faster. Beyond ``|x| ≈ 1.6e6`` rad, and for non-finite entries, it returns theirs."""
    k = np.rint(x * (2.0 / np.pi))
    if not np.abs(k).max(initial=0.0) < 2.0**20:
        return np.cos(x), np.sin(x)
    r = x - k * _HALF_PI_HIGH
    r -= k * _HALF_PI_LOW
    z = r * r
    sin_r = _series(z, _SIN_SERIES)
    sin_r *= r
    sin_r += r
    cos_r = _series(z, _COS_SERIES)
    cos_r += 1.0
    # cos(k π/2 + r) = C cos r − S sin r ;  sin(k π/2 + r) = S cos r + C sin r, C and S in {0, ±1}: exact
    quarter = k.astype(np.int64) & 3
    C, S = _QUARTER_COS.take(quarter), _QUARTER_SIN.take(quarter)
    cos_x = C * cos_r
    cos_x -= S * sin_r
    sin_x = S * cos_r
    sin_x += C * sin_r
    return cos_x, sin_x


# ----------------------------------------------------------------------------- spatial vectors

# A spatial cross product as products of gathered components: rows [t₁; t₂; t₃; t₄] of six each, the
# result (t₁ − t₂) + (t₃ − t₄). Motion vectors: [v; ω] × [v'; ω'] = [ω × v' + v × ω'; ω × ω'];
# force vectors: [v; ω] ×* [f; n] = [ω × f; ω × n + v × f]. A half with a single cross repeats one
# product in t₃ and t₄, whose difference is exactly zero.
def _spatial_cross_indices(linear, angular):
    """Left and right gather indices ``(24,)``; ``linear`` and ``angular`` list the cross products
    ``x × y`` of each half as the starts ``(x, y)`` of their operands in the two 6-vectors."""
    left, right = np.empty((4, 2, 3), dtype=int), np.empty((4, 2, 3), dtype=int)
    for half, crosses in enumerate((linear, angular)):
        for k, (x, y) in enumerate(crosses):
            # x × y = [x_{i+1} y_{i+2}] − [x_{i+2} y_{i+1}]: rows t_{2k+1} and t_{2k+2}
            left[2 * k, half], right[2 * k, half] = x + _CROSS_LEFT[:3], y + _CROSS_RIGHT[:3]
            left[2 * k + 1, half], right[2 * k + 1, half] = x + _CROSS_LEFT[3:], y + _CROSS_RIGHT[3:]
        if len(crosses) == 1:
            left[2:, half], right[2:, half] = left[0, half], right[0, half]
    return left.reshape(24), right.reshape(24)


_MOTION_CROSS = _spatial_cross_indices(linear=[(3, 0), (0, 3)], angular=[(3, 3)])
_FORCE_CROSS = _spatial_cross_indices(linear=[(3, 0)], angular=[(3, 3), (0, 0)])


#: Fewest numbers per component row from which the spatial cross products go row by row: more NumPy
#: calls, but no gathered copies of the operands (a third of the time for Panda's joints on 4096 lanes).
ROW_BY_ROW = 4096


# The same products on a single lane, as matrices: [m×] = Σ_k m_k [e_k×] and [m×*] = −[m×]ᵀ, so that a
# cross product is two matrix products over the stack, far fewer NumPy calls than the gathers.
# Row k of a map holds the 36 entries of [e_k×] (or [e_k×*]).
_UNIT_MOTION_CROSS = _block_skew(_MOTION_CROSS_MATRIX, np.eye(6)[:, :, None])[..., 0]  # (6, 6, 6): [e_k×]
_MOTION_CROSS_MAP = _UNIT_MOTION_CROSS.reshape(6, 36)
_FORCE_CROSS_MAP = (-_UNIT_MOTION_CROSS.swapaxes(-1, -2)).reshape(6, 36)


def _spatial_cross(indices, cross_map, m, x):
    if m.shape[-1] == 1 == x.shape[-1]:
        # [m×] x = (Σ_k m_k [e_k×]) x
        return (m[..., 0] @ cross_map).reshape(m.shape[:-2] + (6, 6)) @ x
    left, right = indices
    shape = spatial.batch_shape(m.shape, x.shape)
    if math.prod(shape[:-2]) * shape[-1] < ROW_BY_ROW:
        t = m.take(left, axis=-2) * x.take(right, axis=-2)
        return (t[..., 0:6, :] - t[..., 6:12, :]) + (t[..., 12:18, :] - t[..., 18:24, :])
    out = np.empty(shape)
    for row in range(6):
        # t₁ − t₂ (+ t₃ − t₄ unless they repeat t₁, t₂)
        o = out[..., row, :]
        np.multiply(m[..., left[row], :], x[..., right[row], :], out=o)
        o -= m[..., left[6 + row], :] * x[..., right[6 + row], :]
        if (left[12 + row], right[12 + row]) != (left[row], right[row]):
            o += m[..., left[12 + row], :] * x[..., right[12 + row], :]
            o -= m[..., left[18 + row], :] * x[..., right[18 + row], :]
    return out


def motion_cross(m1, m2):
    """Spatial motion cross product ``m1 × m2`` on lanes (RBDA eq. 2.31). ``(..., 6, N)`` each."""
    # [v1; ω1] × [v2; ω2] = [ω1 × v2 + v1 × ω2; ω1 × ω2]
    return _spatial_cross(_MOTION_CROSS, _MOTION_CROSS_MAP, m1, m2)


def force_cross(m, f):
    """Spatial force cross product ``m ×* f`` on lanes (RBDA eq. 2.32). ``(..., 6, N)`` each."""
    # [v; ω] ×* [f; n] = [ω × f; ω × n + v × f]
    return _spatial_cross(_FORCE_CROSS, _FORCE_CROSS_MAP, m, f)


# ----------------------------------------------------------------------------- spatial inertia

def world_inertias(mass, first_moment, rotational, R_WJ, p_WJ):
    """Spatial inertias in world axes of bodies posed at ``(R_WJ, p_WJ)``, about the point ``O`` the
    positions ``p_WJ`` are taken from (the world origin, or the algorithms' reference point).

    Each body is given in its own frame J by its mass ``m (nj,)``, first moment ``m c_J (nj, 3, 1)``
    and rotational inertia about J's origin ``Ī_J (nj, 3, 3, 1)``.
    In world axes, with ``g = R m c_J`` and the body origin at ``p``, the first moment about ``O``
    is ``h = g + m p`` and the rotational inertia about it (parallel-axis theorem, RBDA eq. 2.63)
    ``Ī_O = R Ī_J Rᵀ − [p]×[h]× − [g]×[p]× = R Ī_J Rᵀ − h pᵀ − p gᵀ + pᵀ(h + g) 1``
    (as ``[a]×[b]× = b aᵀ − aᵀb 1``); then ``I = [[m 1, −[h]×], [[h]×, Ī_O]]``. Returns ``(nj, 6, 6, N)``.
    Fewer flops than ``X* I_J X*ᵀ``, which takes fewer NumPy calls on a single lane (see
    :func:`multibody.dynamics._tree`).
    """
    m = mass[:, None, None]
    g = matvec(R_WJ, first_moment)
    h = g + m * p_WJ
    rotational_O = (matmul(matmul(R_WJ, rotational), transpose(R_WJ)) - h[:, :, None] * p_WJ[:, None]
                    - p_WJ[:, :, None] * g[:, None] + _IDENTITY * dot(p_WJ, h + g)[:, None, None])
    H = skew(h)
    out = np.empty(rotational_O.shape[:1] + (6, 6) + rotational_O.shape[-1:])
    out[:, :3, :3] = m[..., None] * _IDENTITY
    out[:, :3, 3:] = -H
    out[:, 3:, :3] = H
    out[:, 3:, 3:] = rotational_O
    return out


def transform_force(R_AB, p_AB, f_B):
    """Force vector from B- to A-coordinates on lanes: ``[R f_B; R n_B + p × (R f_B)]``. ``(..., 6, N)``."""
    f_A = matvec(R_AB, f_B[..., :3, :])
    return np.concatenate([f_A, matvec(R_AB, f_B[..., 3:, :]) + cross(p_AB, f_A)], axis=-2)


def inverse_transform_force(R_AB, p_AB, f_A):
    """Force vector from A- to B-coordinates on lanes: ``[Rᵀ f_A; Rᵀ (n_A − p × f_A)]``. ``(..., 6, N)``."""
    R_BA = transpose(R_AB)
    linear = f_A[..., :3, :]
    return np.concatenate([matvec(R_BA, linear), matvec(R_BA, f_A[..., 3:, :] - cross(p_AB, linear))], axis=-2)


def tree_sum(weights, x):
    """``y_i = Σ_k weights[i, k] x_k`` over the leading axis of ``x (n, ...)``: ``weights (m, n) float -> (m, ...)``.

    One matrix product: far fewer NumPy calls than a level-by-level pass, at ``m n`` rather than
    ``n`` additions per component (see :func:`small_tree_sum`).
    """
    return (weights @ x.reshape(x.shape[0], math.prod(x.shape[1:]))).reshape(weights.shape[:1] + x.shape[1:])


#: Largest ``m n K`` of a tree sum done as one matrix product; OpenBLAS runs products up to this
#: size (65536 × 4) on one thread, and threads waiting on a busy machine cost milliseconds.
SMALL_TREE_SUM = 2**18


def small_tree_sum(weights, x):
    """Whether :func:`tree_sum` of ``x`` with ``weights`` is small enough to beat a level-by-level pass."""
    # m n K = m × (size of x)
    return weights.shape[0] * x.size <= SMALL_TREE_SUM
