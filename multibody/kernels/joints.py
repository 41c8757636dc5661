"""Joint kinds: the one place that dispatches on a joint's kind code.

Each kind has its transform ``X_J(q)`` (the pose of the joint frame J in the pre-joint frame),
its motion subspace ``S`` (constant in J for every kind here, so the joint's bias ``c_J = Ṡ q̇``
vanishes: RBDA §4.4), and its configuration maps (``integrate``, ``difference``,
``configuration_rate``, the charts ``chart``, ``chart_rate``, ``velocity_alignment``,
``velocity_coupling``, ``chart_magnitude``, and ``normalize``), each selected by the integer code that
:mod:`multibody.tree` gives the joint; :mod:`multibody.kernels.configuration` runs the maps over a
tree. Configuration layouts are Pinocchio's (``docs/conventions.md``); quaternions ``[x, y, z, w]``
(4-tuples) and planar ``(cos θ, sin θ)`` pairs are used as normalised; rotation vectors are in rad.

Sources of the configuration maps: J. Solà, J. Deray, D. Atchuthan, *A micro Lie theory for state
estimation in robotics* (2018), App. B (SO(3): quaternion exp/log, left Jacobian ``J_l`` and its
inverse), App. C (SE(2)) and App. D (SE(3), eq. 172); Pinocchio's ``integrate``/``difference``
(``liegroup/special-euclidean.hpp``, ``special-orthogonal.hpp``), whose layouts and conventions these
are: a velocity is expressed in the moving joint frame and acts on the right, ``q ⊕ v = q exp(v)``.
"""

from __future__ import annotations

import math

from .jit import njit
from .spatial import (IDENTITY, add3, compose, compose_rotations, cross, dot3, load3, motion_to_parent, rotate,
                      rotate_back, scale3, store, sub3)

REVOLUTE = 0
PRISMATIC = 1
SPHERICAL = 2
FREE_FLYER = 3
PLANAR = 4
TRANSLATION = 5

#: Below this angle (rad) the ratios of ``quat_log``, ``J_l⁻¹`` and the SE(2) ``V(θ)``, which lose
#: digits there, take their series or limit (as :mod:`multibody.spatial`).
SMALL_ANGLE = 1e-4
#: Below this angle the coefficients of the SE(3) ``V(ω)``, whose closed forms cancel digits, use three
#: terms of their Taylor series (truncation error ~θ⁶/10⁶ < 1e-17).
SERIES_ANGLE = 1e-2


@njit(cache=True, error_model="numpy")
def quaternion_rotation(x, y, z, w):
    """Rotation matrix (9-tuple) of the quaternion ``(x, y, z, w)``, divided by its squared norm so that
    a quaternion within rounding of unit norm gives an orthogonal matrix."""
    s = 2.0 / (x * x + y * y + z * z + w * w)
    return (1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
            s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w),
            s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y))


@njit(cache=True, error_model="numpy")
def axis_rotation(axis, angle):
    """Rodrigues: ``R = 1 + sin θ [a]× + (1 − cos θ) [a]×²`` for a unit ``axis`` (3-tuple)."""
    x, y, z = axis
    s, c = math.sin(angle), math.cos(angle)
    t = 1.0 - c
    return (c + t * x * x, t * x * y - s * z, t * x * z + s * y,
            t * x * y + s * z, c + t * y * y, t * y * z - s * x,
            t * x * z - s * y, t * y * z + s * x, c + t * z * z)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", inline="always")
def principal_axis(axis):
    """``(a, σ)`` for a unit ``axis = σ e_a`` along a principal axis of its frame (``a`` 0, 1 or 2 for x, y, z,
    ``σ = ±1``); ``(−1, 0.0)`` for any other axis."""
    x, y, z = axis
    if y == 0.0 and z == 0.0 and (x == 1.0 or x == -1.0):
        return 0, x
    if x == 0.0 and z == 0.0 and (y == 1.0 or y == -1.0):
        return 1, y
    if x == 0.0 and y == 0.0 and (z == 1.0 or z == -1.0):
        return 2, z
    return -1, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def placed_transform(kind, axis, q, iq, R_T, p_T):
    """``X_T X_J(q) = (R_T R_J, p_T + R_T p_J)``: the joint frame's pose in the parent's, for a joint placed at
    ``X_T = (R_T, p_T)`` (RBDA §4.1), from ``q[iq:]``.

    A revolute or prismatic joint about a principal axis ``σ e_a`` of its frame takes a faster branch of the same
    product: the rotation by ``θ`` about ``σ e_a`` turns only the columns ``j, k`` after ``a`` (cyclically) of
    ``R_T``, ``R_T R_J = [.., c t_j + σ s t_k, −σ s t_j + c t_k, ..]`` with ``t_j`` the columns of ``R_T``, and
    the slide by ``d`` along it adds ``σ d t_a`` to ``p_T``."""
    if kind == REVOLUTE or kind == PRISMATIC:
        a, sign = principal_axis(axis)
        if a >= 0:
            x = q[iq]
            if kind == PRISMATIC:
                # p = p_T + σ d t_a
                d = sign * x
                return R_T, (p_T[0] + d * R_T[a], p_T[1] + d * R_T[3 + a], p_T[2] + d * R_T[6 + a])
            c, s = math.cos(x), sign * math.sin(x)
            t0, t1, t2, t3, t4, t5, t6, t7, t8 = R_T
            if a == 2:
                R = (c * t0 + s * t1, c * t1 - s * t0, t2,
                     c * t3 + s * t4, c * t4 - s * t3, t5,
                     c * t6 + s * t7, c * t7 - s * t6, t8)
            elif a == 0:
                R = (t0, c * t1 + s * t2, c * t2 - s * t1,
                     t3, c * t4 + s * t5, c * t5 - s * t4,
                     t6, c * t7 + s * t8, c * t8 - s * t7)
            else:
                R = (c * t0 - s * t2, t1, c * t2 + s * t0,
                     c * t3 - s * t5, t4, c * t5 + s * t3,
                     c * t6 - s * t8, t7, c * t8 + s * t6)
            return R, p_T
    R_J, p_J = transform(kind, axis, q, iq)
    return compose(R_T, p_T, R_J, p_J)


@njit(cache=True, error_model="numpy", inline="always")
def subspace_column_to_parent(kind, axis, k, R, p):
    """``ᴾX_J S_k``: column ``k`` of the motion subspace moved from the joint frame J to a frame P in which J sits at
    ``X_PJ = (R, p)`` (6-tuple ``[v; ω]``): ``[p × R a; R a]`` of a revolute joint about ``a``, ``[R a; 0]`` of a
    prismatic one, :func:`multibody.kernels.spatial.motion_to_parent` of the column otherwise."""
    if kind == REVOLUTE:
        w = rotate(R, axis)
        return cross(p, w) + w
    if kind == PRISMATIC:
        return rotate(R, axis) + (0.0, 0.0, 0.0)
    return motion_to_parent(R, p, subspace_column(kind, axis, k))


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def motion(kind, axis, nv, x, iv):
    """``S x[iv : iv + nv]``: the joint's spatial motion for the rates ``x`` (joint frame, 6-tuple)."""
    m = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for k in range(nv):
        s, xk = subspace_column(kind, axis, k), x[iv + k]
        m = (m[0] + s[0] * xk, m[1] + s[1] * xk, m[2] + s[2] * xk,
             m[3] + s[3] * xk, m[4] + s[4] * xk, m[5] + s[5] * xk)
    return m


@njit(cache=True, error_model="numpy")
def project_force(kind, axis, nv, f, out, iv):
    """``out[iv : iv + nv] = Sᵀ f``: the joint's share of the force ``f`` (joint frame)."""
    for k in range(nv):
        s = subspace_column(kind, axis, k)
        out[iv + k] = s[0] * f[0] + s[1] * f[1] + s[2] * f[2] + s[3] * f[3] + s[4] * f[4] + s[5] * f[5]


# ----------------------------------------------------------------------------- quaternions and SO(3)

@njit(cache=True, error_model="numpy")
def load4(x, start):
    """``x[start : start + 4]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2], x[start + 3])


@njit(cache=True, error_model="numpy")
def quat_multiply(a, b):
    """Hamilton product ``a ⊗ b = (w_a u_b + w_b u_a + u_a × u_b, w_a w_b − u_a·u_b)`` of ``[x, y, z, w]`` quaternions."""
    return (a[3] * b[0] + b[3] * a[0] + a[1] * b[2] - a[2] * b[1],
            a[3] * b[1] + b[3] * a[1] + a[2] * b[0] - a[0] * b[2],
            a[3] * b[2] + b[3] * a[2] + a[0] * b[1] - a[1] * b[0],
            a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2])


@njit(cache=True, error_model="numpy")
def quat_conjugate(quat):
    """``q* = [−u, w]``: the inverse rotation of a unit quaternion."""
    return (-quat[0], -quat[1], -quat[2], quat[3])


@njit(cache=True, error_model="numpy")
def quat_normalized(quat):
    """``quat / |quat|``."""
    norm = math.sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3])
    return (quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm)


@njit(cache=True, error_model="numpy")
def quat_rotation(quat):
    """Rotation matrix (9-tuple, row-major) of ``quat / |quat|``."""
    return quaternion_rotation(quat[0], quat[1], quat[2], quat[3])


@njit(cache=True, error_model="numpy")
def quat_exp(w):
    """Unit quaternion of the rotation vector ``w`` (rad): ``[sin(θ/2) w/θ, cos(θ/2)]``, ``θ = |w|``."""
    theta = math.sqrt(dot3(w, w))
    # sin(θ/2)/θ loses no digits for small θ; only θ = 0 needs its limit ½.
    sinc_half = math.sin(0.5 * theta) / theta if theta > 0.0 else 0.5
    return (sinc_half * w[0], sinc_half * w[1], sinc_half * w[2], math.cos(0.5 * theta))


@njit(cache=True, error_model="numpy")
def quat_log(quat):
    """Rotation vector (rad, angle in ``[0, π]``) of a unit quaternion; inverse of :func:`quat_exp`."""
    # q and −q are the same rotation: take the one with w ≥ 0 so that the angle is ≤ π.
    sign = -1.0 if quat[3] < 0.0 else 1.0
    u, w = (sign * quat[0], sign * quat[1], sign * quat[2]), sign * quat[3]
    n = math.sqrt(dot3(u, u))
    if n < SMALL_ANGLE:
        # 2 atan2(n, w)/n → 2/w (1 − n²/(3w²)) as n → 0
        factor = 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    else:
        # θ = 2 atan2(|u|, w);  log q = θ u/|u|
        factor = 2.0 * math.atan2(n, w) / n
    return scale3(factor, u)


@njit(cache=True, error_model="numpy")
def quat_rotate(quat, x):
    """``R(q) x`` without forming ``R``: ``x + w t + u × t`` with ``t = 2 u × x / |q|²`` (the rotation of ``q/|q|``)."""
    u = (quat[0], quat[1], quat[2])
    t = scale3(2.0 / (quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]), cross(u, x))
    return add3(add3(x, scale3(quat[3], t)), cross(u, t))


@njit(cache=True, error_model="numpy")
def quat_rate(quat, omega):
    """``q̇ = ½ q ⊗ (ω, 0) = ½ [w ω + u × ω; −u·ω]`` for a body-frame angular velocity ``ω``."""
    u = (quat[0], quat[1], quat[2])
    du = add3(scale3(quat[3], omega), cross(u, omega))
    return (0.5 * du[0], 0.5 * du[1], 0.5 * du[2], -0.5 * dot3(u, omega))


@njit(cache=True, error_model="numpy")
def rotation_to_quat(R):
    """Unit quaternion ``[x, y, z, w]`` with ``w ≥ 0`` of a rotation matrix (9-tuple, row-major).

    Shepperd's method: of the four candidates, each proportional to the quaternion, take the one
    whose leading component (``4w², 4x², 4y², 4z²`` up to a factor) is largest, for accuracy.
    """
    trace = R[0] + R[4] + R[8]
    best, leading = 0, trace
    if R[0] > leading:
        best, leading = 1, R[0]
    if R[4] > leading:
        best, leading = 2, R[4]
    if R[8] > leading:
        best = 3
    if best == 0:
        quat = (R[7] - R[5], R[2] - R[6], R[3] - R[1], 1.0 + trace)
    elif best == 1:
        quat = (1.0 + R[0] - R[4] - R[8], R[1] + R[3], R[2] + R[6], R[7] - R[5])
    elif best == 2:
        quat = (R[1] + R[3], 1.0 - R[0] + R[4] - R[8], R[5] + R[7], R[2] - R[6])
    else:
        quat = (R[2] + R[6], R[5] + R[7], 1.0 - R[0] - R[4] + R[8], R[3] - R[1])
    quat = quat_normalized(quat)
    if quat[3] < 0.0:
        return (-quat[0], -quat[1], -quat[2], -quat[3])
    return quat


@njit(cache=True, error_model="numpy")
def transpose_rotation(R):
    """``Rᵀ`` of a row-major 9-tuple."""
    return (R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8])


@njit(cache=True, error_model="numpy")
def so3_left_jacobian_times(w, x):
    """``J_l(w) x = V(w) x = x + a w × x + b w × (w × x)`` with ``a = (1 − cos θ)/θ²``,
    ``b = (θ − sin θ)/θ³`` (Solà et al. 2018, App. B), the ``V`` of the SE(3) exponential."""
    theta = math.sqrt(dot3(w, w))
    t2 = theta * theta
    if theta < SERIES_ANGLE:
        a = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
        b = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    else:
        # 1 − cos θ = 2 sin²(θ/2) avoids the cancellation of the plain form
        s = math.sin(0.5 * theta)
        a = 2.0 * s * s / t2
        b = (theta - math.sin(theta)) / (t2 * theta)
    w_x = cross(w, x)
    return add3(add3(x, scale3(a, w_x)), scale3(b, cross(w, w_x)))


@njit(cache=True, error_model="numpy")
def so3_left_jacobian_inverse_times(w, x):
    """``J_l(w)⁻¹ x = x − ½ w × x + c w × (w × x)``, ``c = (1/θ²)(1 − (θ/2) cot(θ/2))`` (Solà et al.
    2018, App. B): the rate ``ẇ`` of a rotation vector turning with fixed-frame angular velocity ``x``,
    and the ``V⁻¹`` of the SE(3) logarithm (finite for ``θ < 2π``)."""
    theta = math.sqrt(dot3(w, w))
    if theta < SMALL_ANGLE:
        # c = 1/12 + θ²/720 + …; the term c w × (w × x) has size c θ² |x|, so 1/12 keeps its digits
        c = 1.0 / 12.0
    else:
        half = 0.5 * theta
        c = (1.0 - half / math.tan(half)) / (theta * theta)
    w_x = cross(w, x)
    return add3(sub3(x, scale3(0.5, w_x)), scale3(c, cross(w, w_x)))


@njit(cache=True, error_model="numpy")
def se2_v(theta):
    """``(a, b)`` of ``V(θ) = [[a, −b], [b, a]]`` of the SE(2) exponential (Solà et al. 2018, App. C):
    ``a = sin θ/θ``, ``b = (1 − cos θ)/θ``."""
    if abs(theta) < SMALL_ANGLE:
        return 1.0 - theta * theta / 6.0, 0.5 * theta - theta * theta * theta / 24.0
    # 1 − cos θ = 2 sin²(θ/2) avoids the cancellation of the plain form (which keeps only ~ε/θ of b's digits)
    s = math.sin(0.5 * theta)
    return math.sin(theta) / theta, 2.0 * s * s / theta


# ----------------------------------------------------------------------------- configuration maps per kind

@njit(cache=True, error_model="numpy")
def integrate(kind, nv, q, v, iq, iv, out):
    """``out[iq : iq + nq] = q ⊕ v``: the joint's configuration ``q[iq:]`` moved with constant velocity
    ``v[iv:]`` (joint frame) for unit time; quaternions and planar ``(cos θ, sin θ)`` come out unit."""
    if kind == SPHERICAL:
        # q ⊗ exp(ω): the body-frame angular velocity acts on the right
        store(out, iq, quat_normalized(quat_multiply(load4(q, iq), quat_exp(load3(v, iv)))))
    elif kind == FREE_FLYER:
        quat = load4(q, iq + 3)
        v_lin, omega = load3(v, iv), load3(v, iv + 3)
        # X(q) exp(v): p = p₀ + R(q₀) V(ω) v_lin  (SE(3) exponential, Solà et al. 2018 eq. 172)
        store(out, iq, add3(load3(q, iq), rotate(quat_rotation(quat), so3_left_jacobian_times(omega, v_lin))))
        # quat = q₀ ⊗ exp(ω)
        store(out, iq + 3, quat_normalized(quat_multiply(quat, quat_exp(omega))))
    elif kind == PLANAR:
        norm = math.hypot(q[iq + 2], q[iq + 3])
        c0, s0 = q[iq + 2] / norm, q[iq + 3] / norm
        theta = v[iv + 2]
        a, b = se2_v(theta)
        # displacement in the moving frame, V(θ) (vx, vy), rotated into the plane's frame by R(θ₀)
        dx = a * v[iv] - b * v[iv + 1]
        dy = b * v[iv] + a * v[iv + 1]
        c1, s1 = math.cos(theta), math.sin(theta)
        out[iq] = q[iq] + c0 * dx - s0 * dy
        out[iq + 1] = q[iq + 1] + s0 * dx + c0 * dy
        # R(θ₀ + θ)
        out[iq + 2] = c0 * c1 - s0 * s1
        out[iq + 3] = s0 * c1 + c0 * s1
    else:
        # angles and displacements: q + v
        for k in range(nv):
            out[iq + k] = q[iq + k] + v[iv + k]


@njit(cache=True, error_model="numpy", inline="always")
def difference(kind, nv, q0, q1, iq, iv, out):
    """``out[iv : iv + nv] = q₁ ⊖ q₀``: the velocity ``v`` with ``q₀ ⊕ v = q₁`` (inverse of
    :func:`integrate`; rotation angles in ``[0, π]``). Angles and displacements (revolute, prismatic and
    translation joints) subtract in place, inlined into the caller's loop over joints; the other kinds call
    :func:`group_difference`."""
    if kind == SPHERICAL or kind == FREE_FLYER or kind == PLANAR:
        group_difference(kind, nv, q0, q1, iq, iv, out)
    else:
        # angles and displacements: q₁ − q₀
        for k in range(nv):
            out[iv + k] = q1[iq + k] - q0[iq + k]


@njit(cache=True, error_model="numpy")
def group_difference(kind, nv, q0, q1, iq, iv, out):
    """:func:`difference` of a spherical, free-flyer or planar joint (a rotation in its configuration)."""
    if kind == SPHERICAL:
        # log(q₀* ⊗ q₁)
        store(out, iv, quat_log(quat_multiply(quat_conjugate(load4(q0, iq)), load4(q1, iq))))
    elif kind == FREE_FLYER:
        R0, R1 = quat_rotation(load4(q0, iq + 3)), quat_rotation(load4(q1, iq + 3))
        # X₀⁻¹ X₁ = (R₀ᵀ R₁, R₀ᵀ (p₁ − p₀))
        R = compose_rotations(transpose_rotation(R0), R1)
        p = sub3(rotate_back(R0, load3(q1, iq)), rotate_back(R0, load3(q0, iq)))
        # log: ω = log R,  v_lin = V(ω)⁻¹ p  (Solà et al. 2018, App. D)
        omega = quat_log(rotation_to_quat(R))
        store(out, iv, so3_left_jacobian_inverse_times(omega, p))
        store(out, iv + 3, omega)
    elif kind == PLANAR:
        n0, n1 = math.hypot(q0[iq + 2], q0[iq + 3]), math.hypot(q1[iq + 2], q1[iq + 3])
        c0, s0 = q0[iq + 2] / n0, q0[iq + 3] / n0
        c1, s1 = q1[iq + 2] / n1, q1[iq + 3] / n1
        # θ = θ₁ − θ₀ in (−π, π]
        theta = math.atan2(c0 * s1 - s0 * c1, c0 * c1 + s0 * s1)
        # displacement in the frame of q₀, then V(θ)⁻¹ = [[a, b], [−b, a]] / (a² + b²)
        ex, ey = q1[iq] - q0[iq], q1[iq + 1] - q0[iq + 1]
        dx, dy = c0 * ex + s0 * ey, -s0 * ex + c0 * ey
        a, b = se2_v(theta)
        det = a * a + b * b
        out[iv] = (a * dx + b * dy) / det
        out[iv + 1] = (-b * dx + a * dy) / det
        out[iv + 2] = theta


@njit(cache=True, error_model="numpy")
def configuration_rate(kind, nv, q, v, iq, iv, out):
    """``out[iq : iq + nq] = q̇``: the rate of the joint's configuration ``q[iq:]`` moving with velocity ``v[iv:]``."""
    if kind == SPHERICAL:
        # q̇ = ½ q ⊗ (ω, 0), ω in the joint frame
        store(out, iq, quat_rate(load4(q, iq), load3(v, iv)))
    elif kind == FREE_FLYER:
        quat = load4(q, iq + 3)
        # ṗ = R v_lin (v_lin in the body frame);  q̇ = ½ q ⊗ (ω, 0)
        store(out, iq, quat_rotate(quat, load3(v, iv)))
        store(out, iq + 3, quat_rate(quat, load3(v, iv + 3)))
    elif kind == PLANAR:
        c, s = q[iq + 2], q[iq + 3]
        # (ẋ, ẏ) = R(θ) (vx, vy);  d/dt (cos θ, sin θ) = ω (−sin θ, cos θ)
        out[iq] = c * v[iv] - s * v[iv + 1]
        out[iq + 1] = s * v[iv] + c * v[iv + 1]
        out[iq + 2] = -s * v[iv + 2]
        out[iq + 3] = c * v[iv + 2]
    else:
        # q̇ = v
        for k in range(nv):
            out[iq + k] = v[iv + k]


@njit(cache=True, error_model="numpy")
def chart(kind, nv, q0, delta, iq, iv, out):
    """``out[iq : iq + nq]``: the configuration at chart coordinates ``delta[iv:]`` around ``q0[iq:]``.
    Angles and displacements add; a quaternion becomes ``exp(δ) ⊗ q₀`` (``δ`` a rotation vector in the
    parent frame) and a planar angle turns by ``δ_θ``."""
    if kind == SPHERICAL:
        # exp(δ) ⊗ q₀, unit
        store(out, iq, quat_normalized(quat_multiply(quat_exp(load3(delta, iv)), load4(q0, iq))))
    elif kind == FREE_FLYER:
        # p₀ + δ_p;  exp(δ_θ) ⊗ q₀, unit
        store(out, iq, add3(load3(q0, iq), load3(delta, iv)))
        store(out, iq + 3, quat_normalized(quat_multiply(quat_exp(load3(delta, iv + 3)), load4(q0, iq + 3))))
    elif kind == PLANAR:
        norm = math.sqrt(q0[iq + 2] * q0[iq + 2] + q0[iq + 3] * q0[iq + 3])
        c0, s0 = q0[iq + 2] / norm, q0[iq + 3] / norm
        c, s = math.cos(delta[iv + 2]), math.sin(delta[iv + 2])
        # (x, y) displaced in the plane's frame; R(δ_θ) R(θ₀)
        out[iq] = q0[iq] + delta[iv]
        out[iq + 1] = q0[iq + 1] + delta[iv + 1]
        out[iq + 2] = c * c0 - s * s0
        out[iq + 3] = s * c0 + c * s0
    else:
        # q₀ + δ
        for k in range(nv):
            out[iq + k] = q0[iq + k] + delta[iv + k]


@njit(cache=True, error_model="numpy")
def chart_coordinates(kind, nv, q0, q, iq, iv, out):
    """``out[iv : iv + nv] = δ``: the chart coordinates of ``q[iq:]`` around ``q0[iq:]``, the inverse of
    :func:`chart` (``chart(q₀, δ) = q``; rotation angles in ``[0, π]``)."""
    if kind == SPHERICAL:
        # exp(δ) = q ⊗ q₀*
        store(out, iv, quat_log(quat_multiply(load4(q, iq), quat_conjugate(load4(q0, iq)))))
    elif kind == FREE_FLYER:
        # δ_p = p − p₀;  exp(δ_θ) = q ⊗ q₀*
        store(out, iv, sub3(load3(q, iq), load3(q0, iq)))
        store(out, iv + 3, quat_log(quat_multiply(load4(q, iq + 3), quat_conjugate(load4(q0, iq + 3)))))
    elif kind == PLANAR:
        c0, s0, c1, s1 = q0[iq + 2], q0[iq + 3], q[iq + 2], q[iq + 3]
        # (x, y) − (x₀, y₀);  δ_θ = θ − θ₀ in (−π, π]
        out[iv] = q[iq] - q0[iq]
        out[iv + 1] = q[iq + 1] - q0[iq + 1]
        out[iv + 2] = math.atan2(c0 * s1 - s0 * c1, c0 * c1 + s0 * s1)
    else:
        # q − q₀
        for k in range(nv):
            out[iv + k] = q[iq + k] - q0[iq + k]


@njit(cache=True, error_model="numpy")
def chart_rate(kind, nv, delta, w, iv, out):
    """``out[iv : iv + nv] = δ̇``: the rate of the chart coordinates ``delta[iv:]`` moving with the
    parent-aligned velocity ``w[iv:]``."""
    if kind == SPHERICAL:
        # δ̇ = J_l(δ)⁻¹ ω_P
        store(out, iv, so3_left_jacobian_inverse_times(load3(delta, iv), load3(w, iv)))
    elif kind == FREE_FLYER:
        # ṗ = R v_lin = w_lin;  δ̇_θ = J_l(δ_θ)⁻¹ ω_P
        store(out, iv, load3(w, iv))
        store(out, iv + 3, so3_left_jacobian_inverse_times(load3(delta, iv + 3), load3(w, iv + 3)))
    else:
        # angles, displacements and the planar joint: δ̇ = w
        for k in range(nv):
            out[iv + k] = w[iv + k]


@njit(cache=True, error_model="numpy")
def velocity_alignment(kind, nv, q, iq, iv, T):
    """``T[iv : iv + nv, iv : iv + nv]``: the joint's orthogonal block of ``w = T v``, which rotates its
    velocity coordinates into its parent frame (the identity for angles and displacements). Entries
    outside the block are not written."""
    if kind == SPHERICAL or kind == FREE_FLYER:
        # ω_P = R ω_J, and for a free flyer also v_lin,P = R v_lin: diag(R) or diag(R, R)
        R = quat_rotation(load4(q, iq + 3 if kind == FREE_FLYER else iq))
        for r in range(nv):
            for c in range(nv):
                T[iv + r, iv + c] = R[3 * (r % 3) + c % 3] if r // 3 == c // 3 else 0.0
    elif kind == PLANAR:
        cos_t, sin_t = q[iq + 2], q[iq + 3]
        # (vx, vy) turned by R(θ); ω about z unchanged
        T[iv, iv], T[iv, iv + 1], T[iv, iv + 2] = cos_t, -sin_t, 0.0
        T[iv + 1, iv], T[iv + 1, iv + 1], T[iv + 1, iv + 2] = sin_t, cos_t, 0.0
        T[iv + 2, iv], T[iv + 2, iv + 1], T[iv + 2, iv + 2] = 0.0, 0.0, 1.0
    else:
        for r in range(nv):
            for c in range(nv):
                T[iv + r, iv + c] = 1.0 if r == c else 0.0


@njit(cache=True, error_model="numpy")
def velocity_coupling(kind, nv, v, iv, out):
    """``out[iv : iv + nv] = κ(v)`` with ``d/dt (T v) = T (v̇ + κ(v))``: ``Ṫ = T [κ]`` of the rotating frame."""
    if kind == FREE_FLYER:
        # d/dt (R v_lin) = R (v̇_lin + ω × v_lin)
        store(out, iv, cross(load3(v, iv + 3), load3(v, iv)))
        store(out, iv + 3, (0.0, 0.0, 0.0))
    elif kind == PLANAR:
        # d/dt R(θ) = R(θ) ω [[0, −1], [1, 0]]
        out[iv] = -v[iv + 2] * v[iv + 1]
        out[iv + 1] = v[iv + 2] * v[iv]
        out[iv + 2] = 0.0
    else:
        # spherical (ω × ω = 0), angles and displacements: none
        for k in range(nv):
            out[iv + k] = 0.0


@njit(cache=True, error_model="numpy")
def chart_magnitude(kind, nv, q, iq, iv, out):
    """``out[iv : iv + nv]``: the joint's size in each chart direction: ``|q|`` for angles and
    displacements, 1 (rad) for rotations."""
    if kind == SPHERICAL:
        store(out, iv, (1.0, 1.0, 1.0))
    elif kind == FREE_FLYER:
        store(out, iv, (abs(q[iq]), abs(q[iq + 1]), abs(q[iq + 2]), 1.0, 1.0, 1.0))
    elif kind == PLANAR:
        store(out, iv, (abs(q[iq]), abs(q[iq + 1]), 1.0))
    else:
        for k in range(nv):
            out[iv + k] = abs(q[iq + k])


@njit(cache=True, error_model="numpy")
def normalize(kind, nv, q, iq, out):
    """``out[iq : iq + nq]``: ``q[iq:]`` with its quaternion or planar ``(cos θ, sin θ)`` scaled to unit norm."""
    if kind == SPHERICAL:
        store(out, iq, quat_normalized(load4(q, iq)))
    elif kind == FREE_FLYER:
        store(out, iq, load3(q, iq))
        store(out, iq + 3, quat_normalized(load4(q, iq + 3)))
    elif kind == PLANAR:
        c, s = q[iq + 2], q[iq + 3]
        norm = math.sqrt(c * c + s * s)
        store(out, iq, (q[iq], q[iq + 1], c / norm, s / norm))
    else:
        for k in range(nv):
            out[iq + k] = q[iq + k]
