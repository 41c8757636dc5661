"""Joint types. A joint is data: its sizes, transform, motion subspace and configuration-space maps.

Each joint connects a *pre-joint* frame P (fixed in the parent body) to the *joint frame* J (fixed in
the child body). At the neutral configuration J coincides with P. For every type here the motion
subspace ``S`` is constant when expressed in J, so the joint's spatial velocity in J-coordinates is
``v_J = S v`` and its apparent derivative ``Ṡ`` vanishes (RBDA §4.4).

Configuration conventions follow Pinocchio (see ``docs/conventions.md``):

=============  ====  ====  ===========================================  ==========================
type           nq    nv    q                                            v
=============  ====  ====  ===========================================  ==========================
Revolute       1     1     angle (rad)                                  angular rate (rad/s)
Continuous     1     1     angle (rad), unbounded                       angular rate (rad/s)
Prismatic      1     1     displacement (m)                             rate (m/s)
Planar         4     3     ``[x, y, cos θ, sin θ]``                     ``[vx, vy, ω]`` in J
Spherical      4     3     quaternion ``[qx, qy, qz, qw]``              ``ω`` in J
FreeFlyer      7     6     ``[x, y, z, qx, qy, qz, qw]``                ``[v_lin, ω]`` in J
Translation    3     3     ``[x, y, z]`` in P                           ``[vx, vy, vz]``
Fixed          0     0     —                                            —
=============  ====  ====  ===========================================  ==========================

Quaternions (and the ``(cos θ, sin θ)`` pair of a planar joint) must have unit norm to within
:data:`UNIT_NORM_TOLERANCE`; inside it they are used as normalised, outside it a ``ValueError`` is
raised. ``integrate`` always returns normalised values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar


import numpy as np

from . import spatial

#: Largest accepted ``| |q| − 1 |`` for a quaternion or a planar ``(cos θ, sin θ)`` pair.
UNIT_NORM_TOLERANCE = 1e-6
_UNIT_SQUARED_NORMS = ((1.0 - UNIT_NORM_TOLERANCE) ** 2, (1.0 + UNIT_NORM_TOLERANCE) ** 2)

# Position range used by random_configuration for an unbounded translation (m).
_DEFAULT_TRANSLATION_RANGE = 1.0

def _unit(axis, what):
    axis = np.array(axis, dtype=float).reshape(-1)
    if axis.shape != (3,) or not np.all(np.isfinite(axis)):
        raise ValueError(f"{what} axis must be 3 finite numbers, got {axis.tolist()}")
    norm = np.linalg.norm(axis)
    if norm < 1e-12:
        raise ValueError(f"{what} axis must be non-zero, got {axis.tolist()}")
    axis = axis / norm
    axis.setflags(write=False)
    return axis


def _constant(array):
    array = np.array(array, dtype=float)
    array.setflags(write=False)
    return array


def _require_unit_norm(values, joint_name, what):
    # |‖x‖ − 1| > tol  ⟺  ‖x‖² outside [(1 − tol)², (1 + tol)²]; squared norms avoid a square root per state.
    # One state: a dot product and Python's comparisons (NumPy's reductions cost microseconds each).
    single = values.ndim == 1
    squared = float(values @ values) if single else np.einsum("...i,...i->...", values, values)
    bad = (squared < _UNIT_SQUARED_NORMS[0]) | (squared > _UNIT_SQUARED_NORMS[1])  # (NaN passes)
    if bad if single else bad.any():
        raise ValueError(
            f"joint {joint_name!r}: {what} must have unit norm (tolerance {UNIT_NORM_TOLERANCE:g}), "
            f"got norm {np.sqrt(np.atleast_1d(squared)[np.atleast_1d(bad)][0]):.9g}; normalise it or use "
            "model.normalize(q)"
        )


def _turned(quat, delta):
    """``exp(δ) ⊗ quat``, unit: the quaternion turned by the rotation vector ``δ`` in the parent frame
    (the rotation chart of spherical and free-flyer joints)."""
    turned = spatial.quat_multiply(spatial.quat_exp(delta), quat)
    return turned / np.linalg.norm(turned, axis=-1, keepdims=True)


def _random_uniform(rng, lower, upper, default_half_range, shape):
    """Uniform samples in [lower, upper], replacing infinite bounds by ±default_half_range."""
    lower = np.where(np.isfinite(lower), lower, -default_half_range)
    upper = np.where(np.isfinite(upper), upper, default_half_range)
    return rng.uniform(lower, upper, size=shape + np.shape(lower))


def _random_unit_quaternion(rng, shape):
    """Uniformly distributed rotations (normalised Gaussian 4-vectors), ``w ≥ 0``."""
    quat = rng.standard_normal(shape + (4,))
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    return np.where(quat[..., 3:] < 0.0, -quat, quat)


@dataclass(frozen=True, eq=False)
class Joint:
    """Base class of joint types. Subclasses set ``kind``, ``nq`` and ``nv`` and the maps below.

    Shapes: ``q (..., nq)``, ``v (..., nv)``; ``transform`` returns ``R (..., 3, 3)`` and
    ``p (..., 3)``, the pose ``X_PJ`` of the joint frame in the pre-joint frame.
    """

    kind: ClassVar[str]
    nq: ClassVar[int]
    nv: ClassVar[int]
    #: motion subspace in joint-frame coordinates, ``(6, nv)``
    motion_subspace: ClassVar[np.ndarray]

    def neutral(self) -> np.ndarray:
        return np.zeros(self.nq)

    def transform(self, q):
        """Pose ``(R (..., 3, 3), p (..., 3))`` of the joint frame in the pre-joint frame, by the compiled
        joint transform (:func:`multibody.kernels.joints.transform`), state by state."""
        from .kernels import joints as kinds
        from .tree import kind_code

        q = np.asarray(q, dtype=float)
        rows = np.ascontiguousarray(q.reshape(-1, self.nq))
        code, axis = kind_code(self), tuple(float(x) for x in getattr(self, "axis", (0.0, 0.0, 1.0)))
        poses = [kinds.transform(code, axis, row, 0) for row in rows]
        R = np.array([pose[0] for pose in poses]).reshape(q.shape[:-1] + (3, 3))
        p = np.array([pose[1] for pose in poses]).reshape(q.shape[:-1] + (3,))
        return R, p

    def integrate(self, q, v):
        """Configuration reached from ``q`` by moving with constant velocity ``v`` for unit time."""
        return q + v

    def difference(self, q0, q1):
        """Velocity ``v`` such that ``integrate(q0, v) = q1``."""
        return q1 - q0

    def configuration_rate(self, q, v):
        """``q̇`` of the configuration moving with velocity ``v`` (``(..., nq)``)."""
        return v

    # Charts for Lie-group integration (multibody.simulation). Near a chart point q₀ the
    # configuration is chart(q₀, δ), δ (..., nv), a rotation vector applied in the parent frame for
    # the rotational joints; velocities are integrated as w = T(q) v, rotated into the parent frame,
    # where (unlike body-frame velocities) they do not turn with a fast-spinning body.

    def chart(self, q0, delta):
        """Configuration at chart coordinates ``delta (..., nv)`` around ``q0 (..., nq)``."""
        return q0 + delta

    def chart_rate(self, delta, w):
        """``δ̇`` of chart coordinates ``delta`` moving with parent-aligned velocity ``w`` (``(..., nv)``)."""
        return w

    def velocity_alignment(self, q):
        """Orthogonal ``T(q) (..., nv, nv)`` with ``w = T v`` the velocity in parent-frame axes; ``None``
        when it is the identity (``v`` is already expressed there)."""
        return None

    def velocity_coupling(self, v):
        """``κ(v) (..., nv)`` with ``ẇ = T (v̇ + κ(v))``, the rate of the aligned velocity, as ``Ṫ = T [κ]``
        for the rotating frame; ``None`` when zero."""
        return None

    def chart_magnitude(self, q):
        """Size ``(..., nv)`` of the configuration in each chart direction, against which an integrator
        measures relative errors of ``δ``: ``|q|`` for angles and displacements (as for ``q`` itself),
        1 (rad) for rotations."""
        return np.abs(q)

    def random(self, rng, lower, upper, shape=()):
        """Random configurations within ``[lower, upper]`` (each ``(nq,)``), batch ``shape``."""
        return _random_uniform(rng, lower, upper, _DEFAULT_TRANSLATION_RANGE, shape)

    def validate(self, q, joint_name):
        """Raise ``ValueError`` if ``q`` is not a valid configuration of this joint."""

    def normalize(self, q):
        """Project ``q`` back onto the configuration manifold (unit quaternions)."""
        return q

    @property
    def default_limits(self):
        """``(lower, upper)`` position limits, ``(nq,)`` each, when the description gives none."""
        return np.full(self.nq, -np.inf), np.full(self.nq, np.inf)

    def describe(self) -> str:
        """Type and axis for printing."""
        return self.kind


@dataclass(frozen=True, eq=False)
class Revolute(Joint):
    """Rotation by ``q`` rad about a unit ``axis`` of the joint frame; ``S = [0; axis]``."""

    axis: np.ndarray = field(default=(0.0, 0.0, 1.0))
    kind: ClassVar[str] = "revolute"
    nq: ClassVar[int] = 1
    nv: ClassVar[int] = 1

    def __post_init__(self):
        axis = _unit(self.axis, f"{self.kind} joint")
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "motion_subspace", _constant(np.concatenate([np.zeros(3), axis])[:, None]))

    def random(self, rng, lower, upper, shape=()):
        return _random_uniform(rng, lower, upper, np.pi, shape)

    def describe(self):
        return f"{self.kind} axis {np.round(self.axis, 6).tolist()}"


@dataclass(frozen=True, eq=False)
class Continuous(Revolute):
    """An unbounded revolute joint (URDF ``continuous``). Its ``q`` is the angle itself (nq = 1)."""

    kind: ClassVar[str] = "continuous"


@dataclass(frozen=True, eq=False)
class Prismatic(Joint):
    """Translation by ``q`` m along a unit ``axis`` of the joint frame; ``S = [axis; 0]``."""

    axis: np.ndarray = field(default=(0.0, 0.0, 1.0))
    kind: ClassVar[str] = "prismatic"
    nq: ClassVar[int] = 1
    nv: ClassVar[int] = 1

    def __post_init__(self):
        axis = _unit(self.axis, "prismatic joint")
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "motion_subspace", _constant(np.concatenate([axis, np.zeros(3)])[:, None]))

    def describe(self):
        return f"{self.kind} axis {np.round(self.axis, 6).tolist()}"


@dataclass(frozen=True, eq=False)
class Translation(Joint):
    """Free translation in 3-D without rotation; ``q = v``-integral, ``S = [I; 0]``."""

    kind: ClassVar[str] = "translation"
    nq: ClassVar[int] = 3
    nv: ClassVar[int] = 3
    motion_subspace: ClassVar[np.ndarray] = _constant(np.vstack([np.eye(3), np.zeros((3, 3))]))



@dataclass(frozen=True, eq=False)
class Planar(Joint):
    """Motion in the x–y plane of the joint frame: ``q = [x, y, cos θ, sin θ]``, ``v = [vx, vy, ω]``.

    ``(vx, vy)`` is expressed in the moving joint frame and ``ω`` is about its z axis, so
    ``S = [e_x, e_y, 0; 0, 0, e_z]`` and the configuration map is the SE(2) exponential.
    """

    kind: ClassVar[str] = "planar"
    nq: ClassVar[int] = 4
    nv: ClassVar[int] = 3
    motion_subspace: ClassVar[np.ndarray] = _constant(
        [[1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 1]]
    )

    def neutral(self):
        return np.array([0.0, 0.0, 1.0, 0.0])

    @staticmethod
    def _se2_v(theta):
        """``V(θ) = [[sin θ/θ, −(1 − cos θ)/θ], [(1 − cos θ)/θ, sin θ/θ]]`` of the SE(2) exponential."""
        small = np.abs(theta) < 1e-4
        t = np.where(small, 1.0, theta)
        a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
        b = np.where(small, 0.5 * theta - theta**3 / 24.0, (1.0 - np.cos(t)) / t)
        return a, b

    def integrate(self, q, v):
        c0, s0 = q[..., 2], q[..., 3]
        norm = np.hypot(c0, s0)
        c0, s0 = c0 / norm, s0 / norm
        theta = v[..., 2]
        a, b = self._se2_v(theta)
        # Displacement in the moving frame, V(θ) [vx, vy], rotated into the plane's frame by R(θ₀).
        dx = a * v[..., 0] - b * v[..., 1]
        dy = b * v[..., 0] + a * v[..., 1]
        c1, s1 = np.cos(theta), np.sin(theta)
        return np.stack(
            [q[..., 0] + c0 * dx - s0 * dy, q[..., 1] + s0 * dx + c0 * dy, c0 * c1 - s0 * s1, s0 * c1 + c0 * s1],
            axis=-1,
        )

    def configuration_rate(self, q, v):
        c, s = q[..., 2], q[..., 3]
        # (ẋ, ẏ) = R(θ) (vx, vy);  d/dt (cos θ, sin θ) = ω (−sin θ, cos θ)
        return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], -s * v[..., 2], c * v[..., 2]], -1)

    def chart(self, q0, delta):
        # (x, y) displaced in the plane's frame; (cos θ, sin θ) turned by δ_θ
        unit = self.normalize(q0)
        c0, s0 = unit[..., 2], unit[..., 3]
        c, s = np.cos(delta[..., 2]), np.sin(delta[..., 2])
        return np.stack([q0[..., 0] + delta[..., 0], q0[..., 1] + delta[..., 1], c * c0 - s * s0, s * c0 + c * s0], -1)

    def velocity_alignment(self, q):
        c, s = q[..., 2], q[..., 3]
        T = np.zeros(q.shape[:-1] + (3, 3))
        T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1], T[..., 2, 2] = c, -s, s, c, 1.0
        return T

    def velocity_coupling(self, v):
        # d/dt R(θ) = R(θ) ω [[0, −1], [1, 0]]
        return np.stack([-v[..., 2] * v[..., 1], v[..., 2] * v[..., 0], np.zeros(v.shape[:-1])], -1)

    def chart_magnitude(self, q):
        return np.concatenate([np.abs(q[..., :2]), np.ones(q.shape[:-1] + (1,))], -1)

    def difference(self, q0, q1):
        c0, s0 = q0[..., 2] / np.hypot(q0[..., 2], q0[..., 3]), q0[..., 3] / np.hypot(q0[..., 2], q0[..., 3])
        c1, s1 = q1[..., 2] / np.hypot(q1[..., 2], q1[..., 3]), q1[..., 3] / np.hypot(q1[..., 2], q1[..., 3])
        theta = np.arctan2(c0 * s1 - s0 * c1, c0 * c1 + s0 * s1)
        # Displacement expressed in the frame of q0, then V(θ)⁻¹ applied to it.
        ex, ey = q1[..., 0] - q0[..., 0], q1[..., 1] - q0[..., 1]
        dx, dy = c0 * ex + s0 * ey, -s0 * ex + c0 * ey
        a, b = self._se2_v(theta)
        det = a * a + b * b
        return np.stack([(a * dx + b * dy) / det, (-b * dx + a * dy) / det, theta], axis=-1)

    def random(self, rng, lower, upper, shape=()):
        xy = _random_uniform(rng, lower[:2], upper[:2], _DEFAULT_TRANSLATION_RANGE, shape)
        theta = rng.uniform(-np.pi, np.pi, size=shape)
        return np.concatenate([xy, np.cos(theta)[..., None], np.sin(theta)[..., None]], axis=-1)

    def validate(self, q, joint_name):
        _require_unit_norm(q[..., 2:4], joint_name, "planar (cos θ, sin θ)")

    def normalize(self, q):
        return np.concatenate([q[..., :2], q[..., 2:4] / np.linalg.norm(q[..., 2:4], axis=-1, keepdims=True)], -1)

    @property
    def default_limits(self):
        return np.array([-np.inf, -np.inf, -1.0, -1.0]), np.array([np.inf, np.inf, 1.0, 1.0])


@dataclass(frozen=True, eq=False)
class Spherical(Joint):
    """Ball joint: ``q`` a unit quaternion ``[qx, qy, qz, qw]`` (rotation of J in P), ``v = ω`` in J."""

    kind: ClassVar[str] = "spherical"
    nq: ClassVar[int] = 4
    nv: ClassVar[int] = 3
    motion_subspace: ClassVar[np.ndarray] = _constant(np.vstack([np.zeros((3, 3)), np.eye(3)]))

    def neutral(self):
        return np.array([0.0, 0.0, 0.0, 1.0])

    def integrate(self, q, v):
        # q ⊗ exp(ω): the body-frame angular velocity acts on the right.
        quat = spatial.quat_multiply(q, spatial.quat_exp(v))
        return quat / np.linalg.norm(quat, axis=-1, keepdims=True)

    def difference(self, q0, q1):
        return spatial.quat_log(spatial.quat_multiply(spatial.quat_conjugate(q0), q1))

    def chart(self, q0, delta):
        return _turned(q0, delta)

    def chart_rate(self, delta, w):
        # ω_P = J_l(δ) δ̇
        return spatial.so3_left_jacobian_inverse_times(delta, w)

    def velocity_alignment(self, q):
        # ω_P = R ω_J (and ω_J × ω_J = 0: no coupling)
        return spatial.quat_to_rotation(q)

    def chart_magnitude(self, q):
        return np.ones(q.shape[:-1] + (3,))

    def configuration_rate(self, q, v):
        # q̇ = ½ q ⊗ (ω, 0), ω in the joint frame
        return spatial.quat_rate(q, v)

    def random(self, rng, lower, upper, shape=()):
        return _random_unit_quaternion(rng, shape)

    def validate(self, q, joint_name):
        _require_unit_norm(q, joint_name, "quaternion")

    def normalize(self, q):
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    @property
    def default_limits(self):
        return -np.ones(4), np.ones(4)


@dataclass(frozen=True, eq=False)
class FreeFlyer(Joint):
    """Six-DoF joint: ``q = [p, quat]`` (pose of J in P), ``v = [v_lin, ω]`` in J; ``S = I₆``.

    ``integrate`` is the SE(3) exponential ``X(q) exp(v)``, as in Pinocchio.
    """

    kind: ClassVar[str] = "free-flyer"
    nq: ClassVar[int] = 7
    nv: ClassVar[int] = 6
    motion_subspace: ClassVar[np.ndarray] = _constant(np.eye(6))

    def neutral(self):
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

    def integrate(self, q, v):
        R0 = spatial.quat_to_rotation(q[..., 3:])
        _, dp = spatial.se3_exp(v)
        quat = spatial.quat_multiply(q[..., 3:], spatial.quat_exp(v[..., 3:]))
        quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
        return np.concatenate([q[..., :3] + spatial.matvec(R0, dp), quat], axis=-1)

    def configuration_rate(self, q, v):
        # ṗ = R v_lin (v_lin is in the body frame);  q̇ = ½ q ⊗ (ω, 0)
        quat = q[..., 3:]
        return np.concatenate([spatial.quat_rotate(quat, v[..., :3]), spatial.quat_rate(quat, v[..., 3:])], axis=-1)

    def chart(self, q0, delta):
        # p₀ + δ_p and the quaternion turned by the rotation vector δ_θ
        return np.concatenate([q0[..., :3] + delta[..., :3], _turned(q0[..., 3:], delta[..., 3:])], -1)

    def chart_rate(self, delta, w):
        # ṗ = R v_lin = w_lin ;  ω_P = J_l(δ_θ) δ̇_θ
        return np.concatenate([w[..., :3], spatial.so3_left_jacobian_inverse_times(delta[..., 3:], w[..., 3:])], -1)

    def velocity_alignment(self, q):
        # [R v_lin; R ω]
        R = spatial.quat_to_rotation(q[..., 3:])
        T = np.zeros(q.shape[:-1] + (6, 6))
        T[..., :3, :3], T[..., 3:, 3:] = R, R
        return T

    def velocity_coupling(self, v):
        # d/dt (R v_lin) = R (v̇_lin + ω × v_lin)
        return np.concatenate([spatial.cross(v[..., 3:], v[..., :3]), np.zeros(v.shape[:-1] + (3,))], -1)

    def chart_magnitude(self, q):
        return np.concatenate([np.abs(q[..., :3]), np.ones(q.shape[:-1] + (3,))], -1)

    def difference(self, q0, q1):
        R0, R1 = spatial.quat_to_rotation(q0[..., 3:]), spatial.quat_to_rotation(q1[..., 3:])
        R_rel, p_rel = spatial.compose(*spatial.inverse_pose(R0, q0[..., :3]), R1, q1[..., :3])
        return spatial.se3_log(R_rel, p_rel)

    def random(self, rng, lower, upper, shape=()):
        p = _random_uniform(rng, lower[:3], upper[:3], _DEFAULT_TRANSLATION_RANGE, shape)
        return np.concatenate([p, _random_unit_quaternion(rng, shape)], axis=-1)

    def validate(self, q, joint_name):
        _require_unit_norm(q[..., 3:], joint_name, "quaternion")

    def normalize(self, q):
        return np.concatenate([q[..., :3], q[..., 3:] / np.linalg.norm(q[..., 3:], axis=-1, keepdims=True)], -1)

    @property
    def default_limits(self):
        return (np.array([-np.inf] * 3 + [-1.0] * 4), np.array([np.inf] * 3 + [1.0] * 4))


@dataclass(frozen=True, eq=False)
class Fixed(Joint):
    """A rigid attachment (no motion). Bodies attached by it are lumped into their moving parent."""

    kind: ClassVar[str] = "fixed"
    nq: ClassVar[int] = 0
    nv: ClassVar[int] = 0
    motion_subspace: ClassVar[np.ndarray] = _constant(np.zeros((6, 0)))

    def transform(self, q):
        q = np.asarray(q, dtype=float)
        return np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3)).copy(), np.zeros(q.shape[:-1] + (3,))
