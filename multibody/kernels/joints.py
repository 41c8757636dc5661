"""Joint kinds: the one place that dispatches on a joint's kind code.

Each kind has its transform ``X_J(q)`` (the pose of the joint frame J in the pre-joint frame),
its motion subspace ``S`` (constant in J for every kind here, so the joint's bias ``c_J = Ṡ q̇``
vanishes: RBDA §4.4), and its configuration maps (``integrate``, ``difference``), each selected by
the integer code that :mod:`multibody.tree` gives the joint. Configuration layouts are Pinocchio's
(``docs/conventions.md``); quaternions ``[x, y, z, w]`` and planar ``(cos θ, sin θ)`` pairs are used
as normalised.
"""

from __future__ import annotations

import math

from numba import njit

from .spatial import IDENTITY

REVOLUTE = 0
PRISMATIC = 1
SPHERICAL = 2
FREE_FLYER = 3
PLANAR = 4
TRANSLATION = 5


@njit(cache=True)
def quaternion_rotation(x, y, z, w):
    """Rotation matrix (9-tuple) of the quaternion ``(x, y, z, w)``, divided by its squared norm so that
    a quaternion within rounding of unit norm gives an orthogonal matrix."""
    s = 2.0 / (x * x + y * y + z * z + w * w)
    return (1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
            s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w),
            s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y))


@njit(cache=True)
def axis_rotation(axis, angle):
    """Rodrigues: ``R = 1 + sin θ [a]× + (1 − cos θ) [a]×²`` for a unit ``axis`` (3-tuple)."""
    x, y, z = axis
    s, c = math.sin(angle), math.cos(angle)
    t = 1.0 - c
    return (c + t * x * x, t * x * y - s * z, t * x * z + s * y,
            t * x * y + s * z, c + t * y * y, t * y * z - s * x,
            t * x * z - s * y, t * y * z + s * x, c + t * z * z)


@njit(cache=True)
def transform(kind, axis, q, iq):
    """``X_J(q) = (R_J, p_J)``: pose of the joint frame in the pre-joint frame, from ``q[iq:]``."""
    if kind == REVOLUTE:
        return axis_rotation(axis, q[iq]), (0.0, 0.0, 0.0)
    if kind == PRISMATIC:
        d = q[iq]
        return IDENTITY, (d * axis[0], d * axis[1], d * axis[2])
    if kind == SPHERICAL:
        return quaternion_rotation(q[iq], q[iq + 1], q[iq + 2], q[iq + 3]), (0.0, 0.0, 0.0)
    if kind == FREE_FLYER:
        return quaternion_rotation(q[iq + 3], q[iq + 4], q[iq + 5], q[iq + 6]), (q[iq], q[iq + 1], q[iq + 2])
    if kind == PLANAR:
        c, s = q[iq + 2], q[iq + 3]
        norm = math.sqrt(c * c + s * s)
        c, s = c / norm, s / norm
        return (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0), (q[iq], q[iq + 1], 0.0)
    # TRANSLATION
    return IDENTITY, (q[iq], q[iq + 1], q[iq + 2])


@njit(cache=True)
def subspace_column(kind, axis, k):
    """Column ``k`` of the motion subspace ``S`` in joint-frame coordinates (6-tuple ``[v; ω]``)."""
    if kind == REVOLUTE:
        return (0.0, 0.0, 0.0, axis[0], axis[1], axis[2])
    if kind == PRISMATIC:
        return (axis[0], axis[1], axis[2], 0.0, 0.0, 0.0)
    if kind == PLANAR:
        # [e_x, e_y | 0] linear, e_z angular
        return (1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 0.0, 0.0, 0.0, 1.0 if k == 2 else 0.0)
    # spherical: [0; e_k];  translation: [e_k; 0];  free flyer: e_k
    j = k + 3 if kind == SPHERICAL else k
    return (1.0 if j == 0 else 0.0, 1.0 if j == 1 else 0.0, 1.0 if j == 2 else 0.0,
            1.0 if j == 3 else 0.0, 1.0 if j == 4 else 0.0, 1.0 if j == 5 else 0.0)


@njit(cache=True)
def motion(kind, axis, nv, x, iv):
    """``S x[iv : iv + nv]``: the joint's spatial motion for the rates ``x`` (joint frame, 6-tuple)."""
    m = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for k in range(nv):
        s, xk = subspace_column(kind, axis, k), x[iv + k]
        m = (m[0] + s[0] * xk, m[1] + s[1] * xk, m[2] + s[2] * xk,
             m[3] + s[3] * xk, m[4] + s[4] * xk, m[5] + s[5] * xk)
    return m


@njit(cache=True)
def project_force(kind, axis, nv, f, out, iv):
    """``out[iv : iv + nv] = Sᵀ f``: the joint's share of the force ``f`` (joint frame)."""
    for k in range(nv):
        s = subspace_column(kind, axis, k)
        out[iv + k] = s[0] * f[0] + s[1] * f[1] + s[2] * f[2] + s[3] * f[3] + s[4] * f[4] + s[5] * f[5]
