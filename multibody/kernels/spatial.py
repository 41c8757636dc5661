"""Spatial algebra on tuples, for the kernels.

A 3-vector is a 3-tuple, a rotation ``R`` a 9-tuple in row-major order, a motion vector
``m = (v, ω)`` and a force ``f = (f, n)`` 6-tuples, linear part first (``docs/conventions.md``).
A pose ``X_AB = (R_AB, p_AB)`` places frame B in frame A. A rigid-body inertia about a frame's
origin is the 10-tuple ``(m, h, Ī)`` of its mass, first moment ``h = m c`` and rotational inertia
``Ī = (Ixx, Ixy, Ixz, Iyy, Iyz, Izz)`` about the origin, in that frame's axes:
``I = [[m 1, −[h]×], [[h]×, Ī]]`` (RBDA eq. 2.63, linear rows first).

Formulas: R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, §2.8–2.13.
"""

from __future__ import annotations

import math

from .jit import njit

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@njit(cache=True, error_model="numpy")
def load3(x, start):
    """``x[start : start + 3]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2])


@njit(cache=True, error_model="numpy")
def load6(x, start):
    """``x[start : start + 6]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2], x[start + 3], x[start + 4], x[start + 5])


@njit(cache=True, error_model="numpy")
def load9(x, start):
    """``x[start : start + 9]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2], x[start + 3], x[start + 4], x[start + 5],
            x[start + 6], x[start + 7], x[start + 8])


@njit(cache=True, error_model="numpy")
def load10(x, start):
    """``x[start : start + 10]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2], x[start + 3], x[start + 4], x[start + 5],
            x[start + 6], x[start + 7], x[start + 8], x[start + 9])


@njit(cache=True, error_model="numpy")
def store(x, start, values):
    """``x[start : start + len(values)] = values``."""
    for k in range(len(values)):
        x[start + k] = values[k]


@njit(cache=True, error_model="numpy")
def add3(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, error_model="numpy")
def sub3(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, error_model="numpy")
def scale3(s, a):
    return (s * a[0], s * a[1], s * a[2])


@njit(cache=True, error_model="numpy")
def dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, error_model="numpy")
def add6(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5])


@njit(cache=True, error_model="numpy")
def sub6(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5])


@njit(cache=True, error_model="numpy")
def scale6(s, a):
    return (s * a[0], s * a[1], s * a[2], s * a[3], s * a[4], s * a[5])


@njit(cache=True, error_model="numpy")
def dot6(a, b):
    """``aᵀ b``: the power of a force on a motion (or any 6-vector product)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


@njit(cache=True, error_model="numpy")
def cross(a, b):
    """``a × b``."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, error_model="numpy")
def rotate(R, x):
    """``R x``."""
    return (R[0] * x[0] + R[1] * x[1] + R[2] * x[2],
            R[3] * x[0] + R[4] * x[1] + R[5] * x[2],
            R[6] * x[0] + R[7] * x[1] + R[8] * x[2])


@njit(cache=True, error_model="numpy")
def rotate_back(R, x):
    """``Rᵀ x``."""
    return (R[0] * x[0] + R[3] * x[1] + R[6] * x[2],
            R[1] * x[0] + R[4] * x[1] + R[7] * x[2],
            R[2] * x[0] + R[5] * x[1] + R[8] * x[2])


@njit(cache=True, error_model="numpy")
def compose_rotations(A, B):
    """``A B``."""
    return (A[0] * B[0] + A[1] * B[3] + A[2] * B[6], A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
            A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
            A[3] * B[0] + A[4] * B[3] + A[5] * B[6], A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
            A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
            A[6] * B[0] + A[7] * B[3] + A[8] * B[6], A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
            A[6] * B[2] + A[7] * B[5] + A[8] * B[8])


@njit(cache=True, error_model="numpy")
def compose(R_AB, p_AB, R_BC, p_BC):
    """``X_AC = X_AB X_BC``: ``(R_AB R_BC, p_AB + R_AB p_BC)``."""
    return compose_rotations(R_AB, R_BC), add3(p_AB, rotate(R_AB, p_BC))


@njit(cache=True, error_model="numpy")
def motion_cross(m1, m2):
    """``m1 × m2 = [ω1 × v2 + v1 × ω2; ω1 × ω2]`` (RBDA eq. 2.31)."""
    v1, w1 = (m1[0], m1[1], m1[2]), (m1[3], m1[4], m1[5])
    v2, w2 = (m2[0], m2[1], m2[2]), (m2[3], m2[4], m2[5])
    return add3(cross(w1, v2), cross(v1, w2)) + cross(w1, w2)


@njit(cache=True, error_model="numpy")
def force_cross(m, f):
    """``m ×* f = [ω × f; ω × n + v × f]`` (RBDA eq. 2.32)."""
    v, w = (m[0], m[1], m[2]), (m[3], m[4], m[5])
    lin, ang = (f[0], f[1], f[2]), (f[3], f[4], f[5])
    return cross(w, lin) + add3(cross(w, ang), cross(v, lin))


@njit(cache=True, error_model="numpy")
def motion_to_child(R, p, m):
    """``ᶜX_P m``: a motion vector in parent coordinates P expressed in child coordinates C, where
    ``X_PC = (R, p)``: ``[Rᵀ (v + ω × p); Rᵀ ω]`` (RBDA eq. 2.24)."""
    v, w = (m[0], m[1], m[2]), (m[3], m[4], m[5])
    return rotate_back(R, add3(v, cross(w, p))) + rotate_back(R, w)


@njit(cache=True, error_model="numpy")
def motion_to_parent(R, p, m):
    """``ᴾX_C m``: ``[R v + p × R ω; R ω]`` with ``X_PC = (R, p)``."""
    v, w = rotate(R, (m[0], m[1], m[2])), rotate(R, (m[3], m[4], m[5]))
    return add3(v, cross(p, w)) + w


@njit(cache=True, error_model="numpy")
def force_to_parent(R, p, f):
    """``ᴾX_C* f``: ``[R f; R n + p × R f]`` with ``X_PC = (R, p)`` (RBDA eq. 2.25)."""
    lin, ang = rotate(R, (f[0], f[1], f[2])), rotate(R, (f[3], f[4], f[5]))
    return lin + add3(ang, cross(p, lin))


@njit(cache=True, error_model="numpy")
def force_to_child(R, p, f):
    """``ᶜX_P* f``: ``[Rᵀ f; Rᵀ (n − p × f)]`` with ``X_PC = (R, p)``."""
    lin, ang = (f[0], f[1], f[2]), (f[3], f[4], f[5])
    return rotate_back(R, lin) + rotate_back(R, sub3(ang, cross(p, lin)))


@njit(cache=True, error_model="numpy")
def symmetric_times(S, x):
    """``S x`` for a symmetric 3×3 ``S = (Sxx, Sxy, Sxz, Syy, Syz, Szz)``."""
    return (S[0] * x[0] + S[1] * x[1] + S[2] * x[2],
            S[1] * x[0] + S[3] * x[1] + S[4] * x[2],
            S[2] * x[0] + S[4] * x[1] + S[5] * x[2])


@njit(cache=True, error_model="numpy")
def inertia_times(I, m):
    """``I m`` for a rigid-body inertia ``I = (mass, h, Ī)``: ``[mass v − h × ω; h × v + Ī ω]``."""
    mass, h, inertia = I[0], (I[1], I[2], I[3]), (I[4], I[5], I[6], I[7], I[8], I[9])
    v, w = (m[0], m[1], m[2]), (m[3], m[4], m[5])
    return sub3(scale3(mass, v), cross(h, w)) + add3(cross(h, v), symmetric_times(inertia, w))


@njit(cache=True, error_model="numpy", inline="always")
def inertia_to_parent(R, p, I):
    """``ᴾX_C* I ᶜX_P``: a rigid-body inertia about the child frame's origin, in its axes, moved to the
    parent frame (``X_PC = (R, p)``) (RBDA eq. 2.66).

    With ``h' = R h``: mass unchanged, ``h_P = h' + m p``,
    ``Ī_P = R Ī Rᵀ − m [p]×² − [p]× [h']× − [h']× [p]×``.
    """
    mass = I[0]
    h = rotate(R, (I[1], I[2], I[3]))
    Ixx, Ixy, Ixz, Iyy, Iyz, Izz = I[4], I[5], I[6], I[7], I[8], I[9]
    # R Ī Rᵀ, column by column: R Ī = rows of R times Ī
    a = symmetric_times((Ixx, Ixy, Ixz, Iyy, Iyz, Izz), (R[0], R[1], R[2]))
    b = symmetric_times((Ixx, Ixy, Ixz, Iyy, Iyz, Izz), (R[3], R[4], R[5]))
    c = symmetric_times((Ixx, Ixy, Ixz, Iyy, Iyz, Izz), (R[6], R[7], R[8]))
    rxx = dot3((R[0], R[1], R[2]), a)
    rxy = dot3((R[3], R[4], R[5]), a)
    rxz = dot3((R[6], R[7], R[8]), a)
    ryy = dot3((R[3], R[4], R[5]), b)
    ryz = dot3((R[6], R[7], R[8]), b)
    rzz = dot3((R[6], R[7], R[8]), c)
    # −m [p]×² = m (|p|² 1 − p pᵀ);  −[p]×[h']× − [h']×[p]× = 2 (pᵀh') 1 − p h'ᵀ − h' pᵀ
    pp, ph = dot3(p, p), dot3(p, h)
    return (mass, h[0] + mass * p[0], h[1] + mass * p[1], h[2] + mass * p[2],
            rxx + mass * (pp - p[0] * p[0]) + 2.0 * ph - 2.0 * p[0] * h[0],
            rxy - mass * p[0] * p[1] - p[0] * h[1] - h[0] * p[1],
            rxz - mass * p[0] * p[2] - p[0] * h[2] - h[0] * p[2],
            ryy + mass * (pp - p[1] * p[1]) + 2.0 * ph - 2.0 * p[1] * h[1],
            ryz - mass * p[1] * p[2] - p[1] * h[2] - h[1] * p[2],
            rzz + mass * (pp - p[2] * p[2]) + 2.0 * ph - 2.0 * p[2] * h[2])


@njit(cache=True, error_model="numpy")
def inertia_rate(I, m):
    """``İ = m ×* I − I m×``: the rate of change of the inertia ``I = (mass, h, Ī)`` about a fixed origin O
    of a body moving with the twist ``m = (v, ω)``, both in O's coordinates, as a 10-tuple of the same
    layout (Carpentier & Mansard, RSS 2018, the variation of a spatial inertia).

    From ``h = Σ μ x`` and ``Ī = Σ μ (|x|² 1 − x xᵀ)`` over the body's mass elements ``μ`` at ``x``,
    moving as ``ẋ = v + ω × x``: ``ṁ = 0``, ``ḣ = mass v + ω × h``,
    ``d/dt Ī = [ω]× Ī − Ī [ω]× + 2 (hᵀv) 1 − v hᵀ − h vᵀ``.
    """
    mass, h = I[0], (I[1], I[2], I[3])
    v, w = (m[0], m[1], m[2]), (m[3], m[4], m[5])
    h_dot = add3(scale3(mass, v), cross(w, h))
    # W = [ω]× Ī column by column; [ω]× Ī − Ī [ω]× = W + Wᵀ since Ī is symmetric
    c0 = cross(w, (I[4], I[5], I[6]))
    c1 = cross(w, (I[5], I[7], I[8]))
    c2 = cross(w, (I[6], I[8], I[9]))
    hv = dot3(h, v)
    return (0.0, h_dot[0], h_dot[1], h_dot[2],
            2.0 * c0[0] + 2.0 * hv - 2.0 * v[0] * h[0],
            c1[0] + c0[1] - v[0] * h[1] - h[0] * v[1],
            c2[0] + c0[2] - v[0] * h[2] - h[0] * v[2],
            2.0 * c1[1] + 2.0 * hv - 2.0 * v[1] * h[1],
            c2[1] + c1[2] - v[1] * h[2] - h[1] * v[2],
            2.0 * c2[2] + 2.0 * hv - 2.0 * v[2] * h[2])


@njit(cache=True, error_model="numpy")
def add10(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8], a[9] + b[9])


# Loaders of a row's entries by (row, column) index, so that the loops over joints take no row views
# ``X[i]``: each view is a reference-counted array on the CPU, its counting dearer than the arithmetic.

@njit(cache=True, error_model="numpy")
def row3(X, i, s):
    """``X[i, s : s + 3]`` as a tuple."""
    return (X[i, s], X[i, s + 1], X[i, s + 2])


@njit(cache=True, error_model="numpy")
def row6(X, i, s):
    """``X[i, s : s + 6]`` as a tuple."""
    return (X[i, s], X[i, s + 1], X[i, s + 2], X[i, s + 3], X[i, s + 4], X[i, s + 5])


@njit(cache=True, error_model="numpy")
def row9(X, i, s):
    """``X[i, s : s + 9]`` as a tuple."""
    return (X[i, s], X[i, s + 1], X[i, s + 2], X[i, s + 3], X[i, s + 4], X[i, s + 5], X[i, s + 6], X[i, s + 7],
            X[i, s + 8])


@njit(cache=True, error_model="numpy")
def row10(X, i, s):
    """``X[i, s : s + 10]`` as a tuple."""
    return (X[i, s], X[i, s + 1], X[i, s + 2], X[i, s + 3], X[i, s + 4], X[i, s + 5], X[i, s + 6], X[i, s + 7],
            X[i, s + 8], X[i, s + 9])


@njit(cache=True, error_model="numpy")
def store_row(X, i, s, values):
    """``X[i, s : s + len(values)] = values``."""
    for k in range(len(values)):
        X[i, s + k] = values[k]


@njit(cache=True, error_model="numpy")
def larger(a, b):
    """The larger of the scalars ``a`` and ``b``: ``b if b > a else a``, which is Python's and Numba's builtin
    ``max(a, b)``, ``a`` where either is NaN, so ``larger(larger(a, b), c)`` is ``max(a, b, c)``. The kernels
    call it because Numba's CUDA target does not compile the builtin on floats."""
    return b if b > a else a


@njit(cache=True, error_model="numpy")
def smaller(a, b):
    """The smaller of the scalars ``a`` and ``b``: ``b if b < a else a``, which is Python's and Numba's builtin
    ``min(a, b)``, ``a`` where either is NaN, so ``smaller(smaller(a, b), c)`` is ``min(a, b, c)``. The
    kernels call it because Numba's CUDA target does not compile the builtin on floats."""
    return b if b < a else a


@njit(cache=True, error_model="numpy")
def all_finite(x):
    """Whether every entry of the vector ``x`` is finite."""
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            return False
    return True


@njit(cache=True, error_model="numpy")
def nan_unless_finite(x0, x1, x2, x3, out):
    """Fill ``out`` with NaN when an input vector has a NaN or infinite entry, so that such a state's
    whole output is NaN, also where its arithmetic would not carry the NaN (the mass matrix does not
    depend on the position of a floating base). Every kernel ends with it."""
    if all_finite(x0) and all_finite(x1) and all_finite(x2) and all_finite(x3):
        return
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            out[r, c] = math.nan
