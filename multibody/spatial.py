"""Spatial (6-D) algebra, rotations and rigid transforms, batched over leading axes.

Conventions (see ``docs/conventions.md``):

* A spatial **motion** vector is ``m = [v; ω]`` (linear first, then angular), shape ``(..., 6)``;
  a spatial **force** vector is ``f = [f; n]`` (force first, then moment), shape ``(..., 6)``.
  This is Pinocchio's ordering.
* A pose ``X_AB = (R_AB, p_AB)`` is the placement of frame B in frame A:
  a point with B-coordinates ``x_B`` has A-coordinates ``x_A = R_AB x_B + p_AB``.
  Homogeneous 4×4 matrices hold the same pose as ``[[R, p], [0, 1]]``.
* Quaternions are stored ``[qx, qy, qz, qw]`` (Pinocchio's order).

References: R. Featherstone, *Rigid Body Dynamics Algorithms* (RBDA), Springer 2008, ch. 2;
J. Solà et al., *A micro Lie theory for state estimation in robotics* (2018) for exp/log.
Every function accepts arbitrary leading batch axes.
"""

from __future__ import annotations

import numpy as np

# Below this angle (rad) the ratios of quat_log and J_l⁻¹, which lose digits there, take their series or limit.
_SMALL_ANGLE = 1e-4


# ----------------------------------------------------------------------------- 3-D basics

# Row-major entries of [w]×: w_{index} times sign (index 0 with sign 0 on the diagonal).
_SKEW_INDEX = np.array([0, 2, 1, 2, 0, 0, 1, 0, 0])
_SKEW_SIGN = np.array([0.0, -1.0, 1.0, 1.0, 0.0, -1.0, -1.0, 1.0, 0.0])


def batch_shape(*shapes):
    """The common batch shape of arrays with leading batch axes ``shapes`` (``np.broadcast_shapes``,
    which costs microseconds, only when they differ: equal shapes are the usual case)."""
    return shapes[0] if shapes.count(shapes[0]) == len(shapes) else np.broadcast_shapes(*shapes)


def require_last_axis(x, size, name):
    """``ValueError`` naming ``name`` unless the array ``x`` has the shape ``(..., size)``."""
    if x.ndim == 0 or x.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got {x.shape}")


def float_array(x, size, name):
    """``x`` as a float array of shape ``(..., size)``, or ``ValueError`` naming ``name`` (the maps that take
    any numbers)."""
    x = np.asarray(x, dtype=float)
    require_last_axis(x, size, name)
    return x


def skew(w):
    """Cross-product matrix ``[w]×`` with ``[w]× x = w × x``. ``(..., 3) -> (..., 3, 3)``."""
    w = np.asarray(w, dtype=float)
    return (w.take(_SKEW_INDEX, axis=-1) * _SKEW_SIGN).reshape(w.shape[:-1] + (3, 3))


_NEXT = np.array([1, 2, 0])
_PREVIOUS = np.array([2, 0, 1])


def cross(a, b):
    """Batched 3-D cross product ``a × b``, ``(..., 3), (..., 3) -> (..., 3)`` (cheaper than ``np.cross``)."""
    # (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}
    return a.take(_NEXT, -1) * b.take(_PREVIOUS, -1) - a.take(_PREVIOUS, -1) * b.take(_NEXT, -1)


def matvec(A, x):
    """Batched matrix–vector product ``A x``. ``(..., n, k), (..., k) -> (..., n)``."""
    return (A @ x[..., None])[..., 0]


def transpose(A):
    """Swap the last two axes of a batch of matrices."""
    return np.asarray(A).swapaxes(-1, -2)


def axis_angle_rotation(axis, angle):
    """Rotation by ``angle`` (rad) about the unit vector ``axis`` (Rodrigues' formula).

    ``R = I + sin θ [a]× + (1 − cos θ) [a]×²``.  ``axis (3,)``, ``angle (...)`` -> ``(..., 3, 3)``.
    """
    K = skew(np.asarray(axis, dtype=float))
    angle = np.asarray(angle, dtype=float)[..., None, None]
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def rpy_to_rotation(rpy):
    """URDF roll-pitch-yaw (fixed axes X, Y, Z) to a rotation: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    ``(..., 3) -> (..., 3, 3)``.
    """
    rpy = np.asarray(rpy, dtype=float)
    return (
        axis_angle_rotation([0.0, 0.0, 1.0], rpy[..., 2])
        @ axis_angle_rotation([0.0, 1.0, 0.0], rpy[..., 1])
        @ axis_angle_rotation([1.0, 0.0, 0.0], rpy[..., 0])
    )


# ----------------------------------------------------------------------------- quaternions

def _rotation_tensor():
    """``Q (3, 3, 4, 4)`` with ``R_ij |q|² = Σ_kl Q_ijkl q_k q_l`` for ``q = [u, w]``:
    ``R |q|² = (w² − |u|²) I + 2 u uᵀ + 2 w [u]×`` (each product split evenly over both orders)."""
    Q = np.zeros((3, 3, 4, 4))
    for i in range(3):
        Q[i, i, 3, 3] = 1.0
        Q[i, i, [0, 1, 2], [0, 1, 2]] -= 1.0
        for j in range(3):
            Q[i, j, i, j] += 1.0
            Q[i, j, j, i] += 1.0
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        # [u]×_ij = −ε_ijk u_k
        for a, b, sign in ((i, j, -1.0), (j, i, 1.0)):
            Q[a, b, 3, k] += sign
            Q[a, b, k, 3] += sign
    return Q


_ROTATION = _rotation_tensor()


def quat_to_rotation(quat):
    """Rotation matrix of the quaternion ``[x, y, z, w]``. ``(..., 4) -> (..., 3, 3)``.

    ``R = ((w² − |u|²) I + 2 u uᵀ + 2 w [u]×) / |q|²`` with ``u = (x, y, z)``: one contraction of the
    quadratic form; dividing by ``|q|²`` makes the result the rotation of ``q / |q|``, so a
    quaternion that drifted off the unit sphere by rounding still gives an exact rotation.
    """
    quat = np.asarray(quat, dtype=float)
    return np.einsum("ijkl,...k,...l->...ij", _ROTATION, quat, quat) / np.einsum("...i,...i->...", quat, quat)[..., None, None]


def rotation_to_quat(R):
    """Unit quaternion ``[x, y, z, w]`` with ``w ≥ 0`` of a rotation matrix. ``(..., 3, 3) -> (..., 4)``.

    Shepperd's method: pick the largest of ``4w², 4x², 4y², 4z²`` to divide by, for accuracy.
    """
    R = np.asarray(R, dtype=float)
    trace = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    # Four candidate solutions, each well conditioned when its leading component is large.
    candidates = np.stack(
        [
            np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                      R[..., 1, 0] - R[..., 0, 1], 1.0 + trace], axis=-1),
            np.stack([1.0 + R[..., 0, 0] - R[..., 1, 1] - R[..., 2, 2], R[..., 0, 1] + R[..., 1, 0],
                      R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] - R[..., 1, 2]], axis=-1),
            np.stack([R[..., 0, 1] + R[..., 1, 0], 1.0 - R[..., 0, 0] + R[..., 1, 1] - R[..., 2, 2],
                      R[..., 1, 2] + R[..., 2, 1], R[..., 0, 2] - R[..., 2, 0]], axis=-1),
            np.stack([R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1],
                      1.0 - R[..., 0, 0] - R[..., 1, 1] + R[..., 2, 2], R[..., 1, 0] - R[..., 0, 1]], axis=-1),
        ],
        axis=-2,
    )
    leading = np.stack([trace, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], axis=-1)
    best = np.argmax(leading, axis=-1)
    quat = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    return np.where(quat[..., 3:4] < 0.0, -quat, quat)


def _hamilton_tensor():
    """``H (4, 4, 4)`` with ``(q1 ⊗ q2)_i = Σ_jk H_ijk q1_j q2_k``, from
    ``(u1, w1)(u2, w2) = (w1 u2 + w2 u1 + u1 × u2, w1 w2 − u1·u2)``."""
    H = np.zeros((4, 4, 4))
    for i in range(3):
        H[i, 3, i] = H[i, i, 3] = 1.0  # w1 u2 + w2 u1
        j, k = (i + 1) % 3, (i + 2) % 3
        H[i, j, k], H[i, k, j] = 1.0, -1.0  # u1 × u2
        H[3, i, i] = -1.0  # − u1·u2
    H[3, 3, 3] = 1.0  # w1 w2
    return H


_HAMILTON = _hamilton_tensor()


def quat_multiply(q1, q2):
    """Hamilton product ``q1 ⊗ q2`` of ``[x, y, z, w]`` quaternions. ``(..., 4), (..., 4) -> (..., 4)``.

    One contraction with the constant tensor of the product (bilinear in its factors).
    """
    return np.einsum("ijk,...j,...k->...i", _HAMILTON, q1, q2)


def quat_rotate(quat, x):
    """``R(q) x`` without forming ``R``: ``x + w t + u × t`` with ``t = 2 u × x / |q|²`` (the rotation of
    ``q / |q|``, as :func:`quat_to_rotation`). ``(..., 4), (..., 3) -> (..., 3)``."""
    u, w = quat[..., :3], quat[..., 3:]
    t = (2.0 / np.sum(quat * quat, axis=-1, keepdims=True)) * cross(u, x)
    return x + w * t + cross(u, t)


def quat_rate(quat, omega):
    """``q̇ = ½ q ⊗ (ω, 0)`` of a quaternion turning with body-frame angular velocity ``ω``:
    ``½ [w ω + u × ω; −u·ω]``. ``(..., 4), (..., 3) -> (..., 4)``."""
    u, w = quat[..., :3], quat[..., 3:]
    return 0.5 * np.concatenate([w * omega + cross(u, omega), -np.sum(u * omega, axis=-1, keepdims=True)], axis=-1)


def quat_conjugate(quat):
    """``[x, y, z, w] -> [−x, −y, −z, w]``."""
    quat = np.asarray(quat, dtype=float)
    return np.concatenate([-quat[..., :3], quat[..., 3:]], axis=-1)


def quat_exp(w):
    """Unit quaternion of the rotation vector ``w`` (rad): ``[sin(θ/2) w/θ, cos(θ/2)]``, ``θ = |w|``."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1, keepdims=True)
    # sin(θ/2)/θ loses no digits for small θ; only θ = 0 needs its limit ½.
    turning = theta > 0.0
    safe = np.where(turning, theta, 1.0)
    sinc_half = np.where(turning, np.sin(0.5 * safe) / safe, 0.5)
    return np.concatenate([sinc_half * w, np.cos(0.5 * theta)], axis=-1)


def quat_log(quat):
    """Rotation vector (rad, angle in ``[0, π]``) of a unit quaternion; inverse of :func:`quat_exp`."""
    quat = np.asarray(quat, dtype=float)
    # q and −q are the same rotation: take the one with w ≥ 0 so that the angle is ≤ π.
    quat = np.where(quat[..., 3:4] < 0.0, -quat, quat)
    u, w = quat[..., :3], quat[..., 3:]
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    small = n < _SMALL_ANGLE
    safe_n = np.where(small, 1.0, n)
    # θ = 2 atan2(|u|, w); w_vec = θ u/|u|, and 2 atan2(n, w)/n → 2/w (1 − n²/(3w²)) as n → 0.
    safe_w = np.where(small, w, 1.0)
    factor = np.where(small, 2.0 / safe_w * (1.0 - n**2 / (3.0 * safe_w**2)), 2.0 * np.arctan2(n, w) / safe_n)
    return factor * u


# ----------------------------------------------------------------------------- SO(3), SE(3) exp / log

def so3_exp(w):
    """Rotation matrix ``exp([w]×)`` of a rotation vector. ``(..., 3) -> (..., 3, 3)``."""
    return quat_to_rotation(quat_exp(w))


def so3_log(R):
    """Rotation vector ``w`` with ``exp([w]×) = R``, ``|w| ≤ π``. ``(..., 3, 3) -> (..., 3)``."""
    return quat_log(rotation_to_quat(R))


# Below this angle the coefficients of V(ω) and V(ω)⁻¹, whose closed forms cancel digits, use
# three terms of their Taylor series (truncation error ~θ⁶/10⁶ < 1e-17).
_SERIES_ANGLE = 1e-2


def _so3_left_jacobian_terms(w):
    """Coefficients ``a = (1 − cos θ)/θ²`` and ``b = (θ − sin θ)/θ³`` of ``V(w) = I + a [w]× + b [w]×²``."""
    theta = np.linalg.norm(w, axis=-1)
    small = theta < _SERIES_ANGLE
    t = np.where(small, 1.0, theta)
    t2 = theta**2
    # 1 − cos θ = 2 sin²(θ/2) avoids the cancellation of the plain form.
    a = np.where(small, 0.5 - t2 / 24.0 + t2**2 / 720.0, 2.0 * np.sin(0.5 * t) ** 2 / t**2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0, (t - np.sin(t)) / t**3)
    return a, b


def se3_exp(motion):
    """Pose ``exp(m)`` of a twist ``m = [v; ω]`` (Solà et al. 2018, eq. 172).

    ``R = exp([ω]×)``, ``p = V(ω) v`` with ``V = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²``.
    ``(..., 6) -> (R (..., 3, 3), p (..., 3))``.
    """
    motion = np.asarray(motion, dtype=float)
    v, w = motion[..., :3], motion[..., 3:]
    a, b = _so3_left_jacobian_terms(w)
    W = skew(w)
    V = np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)
    return so3_exp(w), matvec(V, v)


def se3_log(R, p):
    """Twist ``m = [v; ω]`` with ``exp(m) = (R, p)``; inverse of :func:`se3_exp`. ``-> (..., 6)``.

    ``v = V(ω)⁻¹ p`` with ``V⁻¹ = I − ½[ω]× + (1/θ²)(1 − θ sin θ / (2(1 − cos θ))) [ω]×²``.
    """
    w = so3_log(R)
    return np.concatenate([so3_left_jacobian_inverse_times(w, p), w], axis=-1)


def so3_left_jacobian_inverse_times(w, x):
    """``J_l(w)⁻¹ x`` with the inverse of the left Jacobian of SO(3) (Solà et al. 2018, App. B),
    ``J_l(w)⁻¹ = V(w)⁻¹ = I − ½[w]× + c [w]×²``, ``c = (1/θ²)(1 − θ sin θ / (2(1 − cos θ)))``:
    ``x − ½ w × x + c w × (w × x)``. ``(..., 3), (..., 3) -> (..., 3)``.

    ``J_l`` relates the rate of a rotation vector to the angular velocity it produces:
    ``d/dt exp([w]×) = [J_l(w) ẇ]× exp([w]×)``, so ``ẇ = J_l(w)⁻¹ ω`` for ``ω`` in the fixed frame
    (finite for ``θ < 2π``).
    """
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1, keepdims=True)
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    # θ sin θ / (2(1 − cos θ)) = (θ/2) cot(θ/2). For small θ, c θ² = 1 − (θ/2) cot(θ/2) keeps its
    # absolute digits though not its relative ones, and the term c w × (w × x), of size c θ² |x|,
    # needs no more; below _SMALL_ANGLE c = 1/12 + θ²/720 + … is 1/12 to 2e-10.
    half = 0.5 * t
    c = np.where(small, 1.0 / 12.0, (1.0 - half / np.tan(half)) / (t * t))
    w_x = cross(w, x)
    return x - 0.5 * w_x + c * cross(w, w_x)


# ----------------------------------------------------------------------------- poses

def pose_matrix(R, p):
    """Homogeneous 4×4 matrix ``[[R, p], [0, 1]]``. ``(..., 3, 3), (..., 3) -> (..., 4, 4)``."""
    R, p = np.asarray(R, dtype=float), np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    X = np.zeros(shape + (4, 4))
    X[..., :3, :3] = R
    X[..., :3, 3] = p
    X[..., 3, 3] = 1.0
    return X


def pose_problem(X, tolerance=1e-9):
    """What keeps the float array ``X`` from being one rigid pose, as a phrase, or ``None``: shape ``(4, 4)``,
    finite entries, last row ``[0, 0, 0, 1]`` and a rotation ``R`` (``RᵀR = I`` within ``tolerance``,
    ``det R = +1``) in the upper-left 3×3 block."""
    if X.shape != (4, 4):
        return f"must have shape (4, 4), got {X.shape}"
    if not np.all(np.isfinite(X)):
        return "must be finite, got NaN or infinite entries"
    if np.any(X[3] != (0.0, 0.0, 0.0, 1.0)):
        return f"must have the last row [0, 0, 0, 1], got {X[3].tolist()}"
    R = X[:3, :3]
    off = np.abs(R.T @ R - np.eye(3)).max()
    if off > tolerance or np.linalg.det(R) < 0.0:
        return f"must hold a rotation (orthonormal, determinant +1) in its upper-left 3×3 block; RᵀR − I is off by {off:.1e}"
    return None


def pose_from_xyz_rpy(xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)):
    """4×4 pose from a translation and URDF roll-pitch-yaw angles (rad)."""
    return pose_matrix(rpy_to_rotation(rpy), xyz)


def compose(R_AB, p_AB, R_BC, p_BC):
    """``X_AC = X_AB X_BC`` on ``(R, p)`` pairs: ``R_AC = R_AB R_BC``, ``p_AC = R_AB p_BC + p_AB``."""
    return R_AB @ R_BC, matvec(R_AB, p_BC) + p_AB


def inverse_pose(R_AB, p_AB):
    """``X_BA = X_AB⁻¹``: ``R_BA = R_ABᵀ``, ``p_BA = −R_ABᵀ p_AB``."""
    R_BA = transpose(R_AB)
    return R_BA, -matvec(R_BA, p_AB)


# ----------------------------------------------------------------------------- spatial vectors

def motion_cross(m1, m2):
    """Spatial motion cross product ``m1 × m2`` (RBDA eq. 2.31, linear-first ordering).

    ``[v1; ω1] × [v2; ω2] = [ω1 × v2 + v1 × ω2; ω1 × ω2]``. ``(..., 6), (..., 6) -> (..., 6)``.
    """
    v1, w1 = m1[..., :3], m1[..., 3:]
    v2, w2 = m2[..., :3], m2[..., 3:]
    return np.concatenate([cross(w1, v2) + cross(v1, w2), cross(w1, w2)], axis=-1)


def force_cross(m, f):
    """Spatial force cross product ``m ×* f = −(m ×)ᵀ f`` (RBDA eq. 2.32).

    ``[v; ω] ×* [f; n] = [ω × f; ω × n + v × f]``. ``(..., 6), (..., 6) -> (..., 6)``.
    """
    v, w = m[..., :3], m[..., 3:]
    lin, ang = f[..., :3], f[..., 3:]
    return np.concatenate([cross(w, lin), cross(w, ang) + cross(v, lin)], axis=-1)


def motion_cross_matrix(m):
    """6×6 matrix ``[m×]`` with ``[m×] x = m × x``: ``[[[ω]×, [v]×], [0, [ω]×]]``. ``(..., 6) -> (..., 6, 6)``."""
    m = np.asarray(m, dtype=float)
    W, V = skew(m[..., 3:]), skew(m[..., :3])
    out = np.zeros(m.shape[:-1] + (6, 6))
    out[..., :3, :3] = W
    out[..., :3, 3:] = V
    out[..., 3:, 3:] = W
    return out


def force_cross_matrix(m):
    """6×6 matrix ``[m×*] = −[m×]ᵀ`` (motion/force duality). ``(..., 6) -> (..., 6, 6)``."""
    return -transpose(motion_cross_matrix(m))


def motion_transform(R_AB, p_AB):
    """6×6 matrix ``ᴬX_B`` mapping motion vectors from B- to A-coordinates (RBDA eq. 2.24).

    ``[v_A; ω_A] = [R v_B + p × (R ω_B); R ω_B]``, i.e. ``X = [[R, [p]× R], [0, R]]``.
    """
    return _pose_transform(R_AB, p_AB, (slice(0, 3), slice(3, 6)))


def force_transform(R_AB, p_AB):
    """6×6 matrix ``ᴬX_B* = ᴬX_B⁻ᵀ`` mapping force vectors from B- to A-coordinates.

    ``[f_A; n_A] = [R f_B; R n_B + p × (R f_B)]``, i.e. ``X* = [[R, 0], [[p]× R, R]]``.
    """
    return _pose_transform(R_AB, p_AB, (slice(3, 6), slice(0, 3)))


def _pose_transform(R_AB, p_AB, coupling):
    """``[[R, 0], [0, R]]`` with ``[p]× R`` in the block ``coupling`` (rows, columns): the motion and
    force transforms of a pose. ``(..., 3, 3), (..., 3) -> (..., 6, 6)``."""
    R_AB, p_AB = np.asarray(R_AB, dtype=float), np.asarray(p_AB, dtype=float)
    X = np.zeros(batch_shape(R_AB.shape[:-2], p_AB.shape[:-1]) + (6, 6))
    X[..., :3, :3] = R_AB
    X[..., 3:, 3:] = R_AB
    X[(...,) + coupling] = skew(p_AB) @ R_AB
    return X


def transform_force(R_AB, p_AB, f_B):
    """Force vector from B- to A-coordinates without forming the 6×6 matrix: ``[R f_B; R n_B + p × (R f_B)]``."""
    f_A = matvec(R_AB, f_B[..., :3])
    return np.concatenate([f_A, matvec(R_AB, f_B[..., 3:]) + cross(p_AB, f_A)], axis=-1)


def inverse_transform_force(R_AB, p_AB, f_A):
    """Force vector from A- to B-coordinates: ``[Rᵀ f_A; Rᵀ (n_A − p × f_A)]``."""
    R_BA = transpose(R_AB)
    lin = f_A[..., :3]
    return np.concatenate([matvec(R_BA, lin), matvec(R_BA, f_A[..., 3:] - cross(p_AB, lin))], axis=-1)


# ----------------------------------------------------------------------------- spatial inertia

def spatial_inertia(mass, com, inertia_com):
    """6×6 spatial inertia of a body about the origin of its frame (RBDA eq. 2.63, linear first).

    ``I = [[m 1, −m [c]×], [m [c]×, I_c − m [c]×²]]`` where ``c`` is the centre of mass and ``I_c``
    the rotational inertia about it, both in the body frame.
    Shapes: ``mass (...)``, ``com (..., 3)``, ``inertia_com (..., 3, 3)`` -> ``(..., 6, 6)``.
    """
    mass = np.asarray(mass, dtype=float)[..., None, None]
    C = skew(com)
    inertia_com = np.asarray(inertia_com, dtype=float)
    shape = np.broadcast_shapes(mass.shape[:-2], C.shape[:-2], inertia_com.shape[:-2])
    out = np.zeros(shape + (6, 6))
    out[..., :3, :3] = mass * np.eye(3)
    out[..., :3, 3:] = -mass * C
    out[..., 3:, :3] = mass * C
    out[..., 3:, 3:] = inertia_com - mass * (C @ C)
    return out


def transform_inertia(R_AB, p_AB, I_B):
    """Spatial inertia from B- to A-coordinates: ``I_A = ᴬX_B* I_B ᴮX_A`` (RBDA eq. 2.66)."""
    X_star = force_transform(R_AB, p_AB)
    return X_star @ I_B @ transpose(X_star)
