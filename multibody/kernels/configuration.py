"""Configuration-space maps: the exponential ``q ⊕ v`` and logarithm ``q₁ ⊖ q₀`` of the joints'
configuration manifolds, the configuration rate ``q̇(q, v)``, and the charts of the Lie-group
integrator (``docs/conventions.md``, "Charts for integration").

Sources: J. Solà, J. Deray, D. Atchuthan, *A micro Lie theory for state estimation in robotics*
(2018), App. B (SO(3): quaternion exp/log, left Jacobian ``J_l`` and its inverse), App. C (SE(2)) and
App. D (SE(3), eq. 172); Pinocchio's ``integrate``/``difference`` (``liegroup/special-euclidean.hpp``,
``special-orthogonal.hpp``), whose layouts and conventions these are: a velocity is expressed in the
moving joint frame and acts on the right, ``q ⊕ v = q exp(v)``.

Every kernel has the uniform signature ``kernel(joints, reals, frames, x0, x1, x2, x3, out, ws)`` of
:mod:`multibody.driver` and loops over the joints; per joint it calls a ``joint_*`` function that
dispatches on the joint's kind code (:mod:`multibody.kernels.joints`) and writes that joint's block of
``out`` at the joint's offset (``IQ`` for ``q``-shaped results, ``IV`` for ``v``-shaped ones).
Quaternions are ``[x, y, z, w]`` 4-tuples; rotation vectors in rad; planar angles as ``(cos θ, sin θ)``.
None of the kernels needs a workspace.
"""

from __future__ import annotations

import math

from numba import njit

from ..tree import IQ, IV, KIND, NV
from .joints import FREE_FLYER, PLANAR, SPHERICAL, quaternion_rotation
from .spatial import add3, compose_rotations, cross, dot3, load3, rotate, rotate_back, scale3, store, sub3

#: Below this angle (rad) the ratios of ``quat_log``, ``J_l⁻¹`` and the SE(2) ``V(θ)``, which lose
#: digits there, take their series or limit (as :mod:`multibody.spatial`).
SMALL_ANGLE = 1e-4
#: Below this angle the coefficients of the SE(3) ``V(ω)``, whose closed forms cancel digits, use three
#: terms of their Taylor series (truncation error ~θ⁶/10⁶ < 1e-17).
SERIES_ANGLE = 1e-2


def workspace_size(nj, nv):
    """Floats of workspace one state needs: none."""
    return 0


# ----------------------------------------------------------------------------- quaternions and SO(3)

@njit(cache=True)
def load4(x, start):
    """``x[start : start + 4]`` as a tuple."""
    return (x[start], x[start + 1], x[start + 2], x[start + 3])


@njit(cache=True)
def quat_multiply(a, b):
    """Hamilton product ``a ⊗ b = (w_a u_b + w_b u_a + u_a × u_b, w_a w_b − u_a·u_b)`` of ``[x, y, z, w]`` quaternions."""
    return (a[3] * b[0] + b[3] * a[0] + a[1] * b[2] - a[2] * b[1],
            a[3] * b[1] + b[3] * a[1] + a[2] * b[0] - a[0] * b[2],
            a[3] * b[2] + b[3] * a[2] + a[0] * b[1] - a[1] * b[0],
            a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2])


@njit(cache=True)
def quat_normalized(quat):
    """``quat / |quat|``."""
    norm = math.sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3])
    return (quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm)


@njit(cache=True)
def quat_rotation(quat):
    """Rotation matrix (9-tuple, row-major) of ``quat / |quat|``."""
    return quaternion_rotation(quat[0], quat[1], quat[2], quat[3])


@njit(cache=True)
def quat_exp(w):
    """Unit quaternion of the rotation vector ``w`` (rad): ``[sin(θ/2) w/θ, cos(θ/2)]``, ``θ = |w|``."""
    theta = math.sqrt(dot3(w, w))
    # sin(θ/2)/θ loses no digits for small θ; only θ = 0 needs its limit ½.
    sinc_half = math.sin(0.5 * theta) / theta if theta > 0.0 else 0.5
    return (sinc_half * w[0], sinc_half * w[1], sinc_half * w[2], math.cos(0.5 * theta))


@njit(cache=True)
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


@njit(cache=True)
def quat_rotate(quat, x):
    """``R(q) x`` without forming ``R``: ``x + w t + u × t`` with ``t = 2 u × x / |q|²`` (the rotation of ``q/|q|``)."""
    u = (quat[0], quat[1], quat[2])
    t = scale3(2.0 / (quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]), cross(u, x))
    return add3(add3(x, scale3(quat[3], t)), cross(u, t))


@njit(cache=True)
def quat_rate(quat, omega):
    """``q̇ = ½ q ⊗ (ω, 0) = ½ [w ω + u × ω; −u·ω]`` for a body-frame angular velocity ``ω``."""
    u = (quat[0], quat[1], quat[2])
    du = add3(scale3(quat[3], omega), cross(u, omega))
    return (0.5 * du[0], 0.5 * du[1], 0.5 * du[2], -0.5 * dot3(u, omega))


@njit(cache=True)
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


@njit(cache=True)
def transpose_rotation(R):
    """``Rᵀ`` of a row-major 9-tuple."""
    return (R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8])


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def se2_v(theta):
    """``(a, b)`` of ``V(θ) = [[a, −b], [b, a]]`` of the SE(2) exponential (Solà et al. 2018, App. C):
    ``a = sin θ/θ``, ``b = (1 − cos θ)/θ``."""
    if abs(theta) < SMALL_ANGLE:
        return 1.0 - theta * theta / 6.0, 0.5 * theta - theta * theta * theta / 24.0
    return math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta


# ----------------------------------------------------------------------------- per joint kind

@njit(cache=True)
def joint_integrate(kind, nv, q, v, iq, iv, out):
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


@njit(cache=True)
def joint_difference(kind, nv, q0, q1, iq, iv, out):
    """``out[iv : iv + nv] = q₁ ⊖ q₀``: the velocity ``v`` with ``q₀ ⊕ v = q₁`` (inverse of
    :func:`joint_integrate`; rotation angles in ``[0, π]``)."""
    if kind == SPHERICAL:
        # log(q₀* ⊗ q₁)
        quat0 = load4(q0, iq)
        store(out, iv, quat_log(quat_multiply((-quat0[0], -quat0[1], -quat0[2], quat0[3]), load4(q1, iq))))
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
    else:
        # angles and displacements: q₁ − q₀
        for k in range(nv):
            out[iv + k] = q1[iq + k] - q0[iq + k]


@njit(cache=True)
def joint_configuration_rate(kind, nv, q, v, iq, iv, out):
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


@njit(cache=True)
def joint_chart(kind, nv, q0, delta, iq, iv, out):
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


@njit(cache=True)
def joint_chart_rate(kind, nv, delta, w, iv, out):
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


@njit(cache=True)
def joint_velocity_alignment(kind, nv, q, iq, iv, T):
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


@njit(cache=True)
def joint_velocity_coupling(kind, nv, v, iv, out):
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


@njit(cache=True)
def joint_chart_magnitude(kind, nv, q, iq, iv, out):
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


@njit(cache=True)
def joint_normalize(kind, nv, q, iq, out):
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


# ----------------------------------------------------------------------------- kernels

@njit(cache=True)
def integrate(joints, reals, frames, q, v, x2, x3, out, ws):
    """Configuration exponential ``q ⊕ v`` into ``out[0] (nq,)`` (Solà et al. 2018 App. B–D, Pinocchio's
    ``integrate``): each joint moves with constant ``v`` for unit time (scale ``v`` by ``dt`` first).

    ``q (nq,)``, ``v (nv,)`` joint-frame velocities (rad/s, m/s). ``reals``, ``frames``, ``x2``, ``x3``,
    ``ws`` are unused.
    """
    for i in range(joints.shape[0]):
        joint_integrate(joints[i, KIND], joints[i, NV], q, v, joints[i, IQ], joints[i, IV], out[0])


@njit(cache=True)
def difference(joints, reals, frames, q0, q1, x2, x3, out, ws):
    """Configuration logarithm ``q₁ ⊖ q₀`` into ``out[0] (nv,)``: the ``v`` with ``q₀ ⊕ v = q₁``
    (Solà et al. 2018 App. B–D, Pinocchio's ``difference``). ``q0, q1 (nq,)``."""
    for i in range(joints.shape[0]):
        joint_difference(joints[i, KIND], joints[i, NV], q0, q1, joints[i, IQ], joints[i, IV], out[0])


@njit(cache=True)
def configuration_rate(joints, reals, frames, q, v, x2, x3, out, ws):
    """``q̇ (nq,)`` into ``out[0]`` of the configuration ``q (nq,)`` moving with velocity ``v (nv,)``:
    ``v`` for angles and displacements, ``½ q ⊗ (ω, 0)`` for quaternions (Solà et al. 2018 App. B),
    ``R v_lin`` for free-flyer positions and ``R(θ) (vx, vy)``, ``ω (−sin θ, cos θ)`` for planar joints."""
    for i in range(joints.shape[0]):
        joint_configuration_rate(joints[i, KIND], joints[i, NV], q, v, joints[i, IQ], joints[i, IV], out[0])


@njit(cache=True)
def chart(joints, reals, frames, q0, delta, x2, x3, out, ws):
    """Configuration ``(nq,)`` into ``out[0]`` at chart coordinates ``delta (nv,)`` around ``q0 (nq,)``
    (``docs/conventions.md``, charts): ``q₀ + δ`` for angles and displacements, ``exp(δ) ⊗ q₀`` for
    quaternions (``δ`` a rotation vector in the parent frame, rad), planar angles turned by ``δ_θ``."""
    for i in range(joints.shape[0]):
        joint_chart(joints[i, KIND], joints[i, NV], q0, delta, joints[i, IQ], joints[i, IV], out[0])


@njit(cache=True)
def chart_rate(joints, reals, frames, delta, w, x2, x3, out, ws):
    """``δ̇ (nv,)`` into ``out[0]`` of chart coordinates ``delta (nv,)`` moving with the parent-aligned
    velocity ``w (nv,)``: ``w``, but ``J_l(δ)⁻¹ ω`` for rotation vectors (Solà et al. 2018 App. B)."""
    for i in range(joints.shape[0]):
        joint_chart_rate(joints[i, KIND], joints[i, NV], delta, w, joints[i, IV], out[0])


@njit(cache=True)
def velocity_alignment(joints, reals, frames, q, x1, x2, x3, out, ws):
    """The block-diagonal orthogonal ``T(q)`` into ``out (nv, nv)``, with ``w = T v`` the velocities in
    their parent frames' axes: ``diag(R, R)`` for a free flyer, ``R`` for a spherical joint, ``R(θ)``
    on a planar joint's ``(vx, vy)``, 1 for angles and displacements (``docs/conventions.md``, charts)."""
    n = out.shape[0]
    for r in range(n):
        for c in range(n):
            out[r, c] = 0.0
    for i in range(joints.shape[0]):
        joint_velocity_alignment(joints[i, KIND], joints[i, NV], q, joints[i, IQ], joints[i, IV], out)


@njit(cache=True)
def velocity_coupling(joints, reals, frames, v, x1, x2, x3, out, ws):
    """``κ(v) (nv,)`` into ``out[0]`` with ``d/dt (T v) = T (v̇ + κ(v))`` (see :func:`velocity_alignment`):
    ``[ω × v_lin; 0]`` for a free flyer, ``ω (−vy, vx, 0)`` for a planar joint, zero elsewhere."""
    for i in range(joints.shape[0]):
        joint_velocity_coupling(joints[i, KIND], joints[i, NV], v, joints[i, IV], out[0])


@njit(cache=True)
def chart_magnitude(joints, reals, frames, q, x1, x2, x3, out, ws):
    """Size ``(nv,)`` into ``out[0]`` of the configuration ``q (nq,)`` in each chart direction, against which
    an integrator measures relative errors of ``δ``: ``|q|`` for angles and displacements, 1 rad for
    rotation vectors (``docs/conventions.md``, charts)."""
    for i in range(joints.shape[0]):
        joint_chart_magnitude(joints[i, KIND], joints[i, NV], q, joints[i, IQ], joints[i, IV], out[0])


@njit(cache=True)
def normalize(joints, reals, frames, q, x1, x2, x3, out, ws):
    """``q (nq,)`` with every quaternion and planar ``(cos θ, sin θ)`` scaled to unit norm, into ``out[0]``."""
    for i in range(joints.shape[0]):
        joint_normalize(joints[i, KIND], joints[i, NV], q, joints[i, IQ], out[0])
