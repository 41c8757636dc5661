"""Joint types. A joint is data: its sizes, transform, motion subspace and configuration-space maps
(the compiled maps of its kind, :mod:`multibody.kernels.joints`).

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

import math
from dataclasses import dataclass, field
from functools import cache, cached_property
from typing import ClassVar

import numpy as np

from .kernels import joints as kinds
from .kernels.layout import AXIS, FRAME_POSITION, FRAME_ROTATION, FRAME_SIZE, INERTIA, POSITION, REAL_SIZE, ROTATION, \
    CompiledTree
from .spatial import float_array

#: Largest accepted ``| |q| − 1 |`` for a quaternion or a planar ``(cos θ, sin θ)`` pair.
UNIT_NORM_TOLERANCE = 1e-6
UNIT_SQUARED_NORMS = ((1.0 - UNIT_NORM_TOLERANCE) ** 2, (1.0 + UNIT_NORM_TOLERANCE) ** 2)

# Position range used by random_configuration for an unbounded translation (m).
_DEFAULT_TRANSLATION_RANGE = 1.0

def _unit(axis, what):
    axis = np.array(axis, dtype=float).reshape(-1)
    # three numbers: Python's arithmetic costs less than NumPy's reductions (model loaders make many joints)
    values = axis.tolist()
    if len(values) != 3 or not all(math.isfinite(x) for x in values):
        raise ValueError(f"{what} axis must be 3 finite numbers, got {values}")
    norm = math.sqrt(values[0] * values[0] + values[1] * values[1] + values[2] * values[2])
    if norm < 1e-12:
        raise ValueError(f"{what} axis must be non-zero, got {values}")
    axis = axis / norm
    axis.setflags(write=False)
    return axis


def _set_axis(joint, start, what):
    """Set ``joint.axis`` to its unit ``(3,)`` and ``joint.motion_subspace`` ``(6, 1)`` to it from row ``start``, read-only."""
    axis, subspace = _unit(joint.axis, what), np.zeros((6, 1))
    subspace[start : start + 3, 0] = axis
    subspace.setflags(write=False)
    object.__setattr__(joint, "axis", axis)
    object.__setattr__(joint, "motion_subspace", subspace)


def _constant(array):
    array = np.array(array, dtype=float)
    array.setflags(write=False)
    return array


@cache
def _default_limits(nq, unit_norm):
    """:attr:`Joint.default_limits` of a joint of ``nq`` coordinates whose ``unit_norm`` slice has norm 1 (made once)."""
    lower, upper = np.full(nq, -np.inf), np.full(nq, np.inf)
    if unit_norm is not None:
        lower[unit_norm[0] : unit_norm[1]], upper[unit_norm[0] : unit_norm[1]] = -1.0, 1.0
    return _constant(lower), _constant(upper)


def _require_unit_norm(values, joint_name, what):
    # |‖x‖ − 1| > tol  ⟺  ‖x‖² outside [(1 − tol)², (1 + tol)²]; squared norms avoid a square root per state.
    # One state: a dot product and Python's comparisons (NumPy's reductions cost microseconds each).
    single = values.ndim == 1
    squared = float(values @ values) if single else np.einsum("...i,...i->...", values, values)
    bad = (squared < UNIT_SQUARED_NORMS[0]) | (squared > UNIT_SQUARED_NORMS[1])  # (NaN passes)
    if bad if single else bad.any():
        raise ValueError(
            f"joint {joint_name!r}: {what} must have unit norm (tolerance {UNIT_NORM_TOLERANCE:g}), "
            f"got norm {np.sqrt(np.atleast_1d(squared)[np.atleast_1d(bad)][0]):.9g}; normalise it or use "
            "model.normalize(q)"
        )


def _random_uniform(rng, lower, upper, default_half_range, shape):
    """Uniform samples in [lower, upper]. An infinite side is replaced by ±default_half_range, or, when
    the other side is finite, by a range of that width from it (a joint limited only from above at
    −4 rad samples [−4 − 2π, −4])."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    width = 2.0 * default_half_range
    low = np.where(np.isfinite(lower), lower, np.where(np.isfinite(upper), np.minimum(upper - width, -default_half_range),
                                                       -default_half_range))
    high = np.where(np.isfinite(upper), upper, np.where(np.isfinite(lower), np.maximum(lower + width, default_half_range),
                                                        default_half_range))
    return rng.uniform(low, high, size=shape + np.shape(lower))


def _random_unit_quaternion(rng, shape):
    """Uniformly distributed rotations (normalised Gaussian 4-vectors), ``w ≥ 0``."""
    quat = rng.standard_normal(shape + (4,))
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    return np.where(quat[..., 3:] < 0.0, -quat, quat)


@dataclass(frozen=True, eq=False)
class Joint:
    """Base class of joint types. Subclasses set ``kind``, ``nq``, ``nv``, ``vector_space`` and
    ``motion_subspace``; the configuration-space maps below are those of the joint's compiled kind.

    Shapes: ``q (..., nq)``, ``v (..., nv)``; ``transform`` returns ``R (..., 3, 3)`` and
    ``p (..., 3)``, the pose ``X_PJ`` of the joint frame in the pre-joint frame.
    """

    kind: ClassVar[str]
    nq: ClassVar[int]
    nv: ClassVar[int]
    #: whether ``q`` is angles and displacements: ``q̇ = v``, charts add, ``velocity_alignment`` is the identity
    vector_space: ClassVar[bool] = True
    #: motion subspace in joint-frame coordinates, ``(6, nv)``
    motion_subspace: ClassVar[np.ndarray]
    #: ``(start, stop, what)``: the slice of ``q`` that must have unit norm and what it is, or ``None``
    unit_norm: ClassVar[tuple[int, int, str] | None] = None

    def neutral(self) -> np.ndarray:
        return np.zeros(self.nq)

    def transform(self, q):
        """Pose ``(R (..., 3, 3), p (..., 3))`` of the joint frame in the pre-joint frame, by the compiled
        joint transform (:func:`multibody.kernels.joints.transform`), state by state."""
        q = np.asarray(q, dtype=float)
        rows = np.ascontiguousarray(q.reshape(-1, self.nq))
        code, axis = kind_code(self), tuple(float(x) for x in getattr(self, "axis", (0.0, 0.0, 1.0)))
        poses = [kinds.transform(code, axis, row, 0) for row in rows]
        R = np.array([pose[0] for pose in poses]).reshape(q.shape[:-1] + (3, 3))
        p = np.array([pose[1] for pose in poses]).reshape(q.shape[:-1] + (3,))
        return R, p

    # Configuration-space maps: each the compiled map of the joint's kind (multibody.kernels.joints), run
    # through the batch driver (leading axes broadcast) on a model of this joint alone. Shapes are checked,
    # unit norms are not (Model.integrate and the like check them). Charts for Lie-group integration
    # (multibody.simulation): near a chart point q₀ the configuration is chart(q₀, δ), δ (..., nv), a
    # rotation vector applied in the parent frame for the rotational joints; velocities are integrated as
    # w = T(q) v, rotated into the parent frame, where (unlike body-frame velocities) they do not turn
    # with a fast-spinning body.

    def integrate(self, q, v):
        """Configuration reached from ``q`` by moving with constant velocity ``v`` for unit time."""
        return self._map("integrate", (q, self.nq, "q"), (v, self.nv, "v"), (self.nq,))

    def difference(self, q0, q1):
        """Velocity ``v`` such that ``integrate(q0, v) = q1``."""
        return self._map("difference", (q0, self.nq, "q0"), (q1, self.nq, "q1"), (self.nv,))

    def configuration_rate(self, q, v):
        """``q̇`` of the configuration moving with velocity ``v`` (``(..., nq)``)."""
        return self._map("configuration_rate", (q, self.nq, "q"), (v, self.nv, "v"), (self.nq,))

    def chart(self, q0, delta):
        """Configuration at chart coordinates ``delta (..., nv)`` around ``q0 (..., nq)``."""
        return self._map("chart", (q0, self.nq, "q0"), (delta, self.nv, "delta"), (self.nq,))

    def chart_coordinates(self, q0, q):
        """Chart coordinates ``δ (..., nv)`` of ``q`` around ``q0``: the inverse of :meth:`chart`."""
        return self._map("chart_coordinates", (q0, self.nq, "q0"), (q, self.nq, "q"), (self.nv,))

    def chart_rate(self, delta, w):
        """``δ̇`` of chart coordinates ``delta`` moving with parent-aligned velocity ``w`` (``(..., nv)``)."""
        return self._map("chart_rate", (delta, self.nv, "delta"), (w, self.nv, "w"), (self.nv,))

    def velocity_alignment(self, q):
        """Orthogonal ``T(q) (..., nv, nv)`` with ``w = T v`` the velocity in parent-frame axes; ``None``
        when it is the identity (``v`` is already expressed there)."""
        return None if self.vector_space else self._map("velocity_alignment", (q, self.nq, "q"), None,
                                                         (self.nv, self.nv))

    def velocity_coupling(self, v):
        """``κ(v) (..., nv)`` with ``ẇ = T (v̇ + κ(v))``, the rate of the aligned velocity, as ``Ṫ = T [κ]``
        for the rotating frame; ``None`` when ``T`` is the identity."""
        return None if self.vector_space else self._map("velocity_coupling", (v, self.nv, "v"), None, (self.nv,))

    def chart_magnitude(self, q):
        """Size ``(..., nv)`` of the configuration in each chart direction, against which an integrator
        measures relative errors of ``δ``: ``|q|`` for angles and displacements (as for ``q`` itself),
        1 (rad) for rotations."""
        return self._map("chart_magnitude", (q, self.nq, "q"), None, (self.nv,))

    def normalize(self, q):
        """Project ``q`` back onto the configuration manifold (unit quaternions)."""
        return self._map("normalize", (q, self.nq, "q"), None, (self.nq,))

    def _map(self, name, a, b, shape):
        """The kernel ``name`` of :mod:`multibody.kernels.configuration` on the inputs ``a`` and ``b``,
        each ``(array, size, name)`` (``b``: ``None`` when unused), on :attr:`_tree`: ``(..., *shape)``."""
        from . import driver
        from .kernels import configuration

        a = float_array(*a)
        b = None if b is None else float_array(*b)
        return driver.configuration_map(getattr(configuration, name), self._tree, a, b, shape)

    @cached_property
    def _tree(self) -> CompiledTree:
        """The compiled tree of this joint alone (at the world's origin, without inertia), which runs its
        configuration-space maps (:mod:`multibody.kernels.layout`)."""
        joints = np.array([[-1, kind_code(self), 0, 0, self.nq, self.nv]], dtype=np.int64)
        reals = np.zeros((2, REAL_SIZE))
        reals[0, ROTATION:POSITION] = np.eye(3).reshape(9)
        reals[0, AXIS:INERTIA] = getattr(self, "axis", (0.0, 0.0, 1.0))
        frame = np.zeros((1, FRAME_SIZE))
        frame[0, FRAME_ROTATION:FRAME_POSITION] = np.eye(3).reshape(9)
        arrays = [np.ascontiguousarray(x) for x in (joints, reals, frame, frame.copy())]
        for x in arrays:
            x.setflags(write=False)
        return CompiledTree(*arrays, self.nq, self.nv, 1)

    def random(self, rng, lower, upper, shape=()):
        """Random configurations within ``[lower, upper]`` (each ``(nq,)``), batch ``shape``."""
        return _random_uniform(rng, lower, upper, _DEFAULT_TRANSLATION_RANGE, shape)

    def validate(self, q, joint_name):
        """Raise ``ValueError`` if ``q`` is not a valid configuration of this joint (its :attr:`unit_norm`
        part off the unit sphere)."""
        if self.unit_norm is not None:
            start, stop, what = self.unit_norm
            _require_unit_norm(q[..., start:stop], joint_name, what)

    @property
    def default_limits(self):
        """``(lower, upper)`` position limits, ``(nq,)`` each (read-only), when the description gives none:
        unbounded, but ``±1`` on the :attr:`unit_norm` components, which can never leave them."""
        return _default_limits(self.nq, self.unit_norm)

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
        _set_axis(self, 3, f"{self.kind} joint")

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
        _set_axis(self, 0, "prismatic joint")

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
    vector_space: ClassVar[bool] = False
    motion_subspace: ClassVar[np.ndarray] = _constant(
        [[1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 1]]
    )
    unit_norm: ClassVar[tuple[int, int, str]] = (2, 4, "planar (cos θ, sin θ)")

    def neutral(self):
        return np.array([0.0, 0.0, 1.0, 0.0])

    def random(self, rng, lower, upper, shape=()):
        xy = _random_uniform(rng, lower[:2], upper[:2], _DEFAULT_TRANSLATION_RANGE, shape)
        theta = rng.uniform(-np.pi, np.pi, size=shape)
        return np.concatenate([xy, np.cos(theta)[..., None], np.sin(theta)[..., None]], axis=-1)


@dataclass(frozen=True, eq=False)
class Spherical(Joint):
    """Ball joint: ``q`` a unit quaternion ``[qx, qy, qz, qw]`` (rotation of J in P), ``v = ω`` in J."""

    kind: ClassVar[str] = "spherical"
    nq: ClassVar[int] = 4
    nv: ClassVar[int] = 3
    vector_space: ClassVar[bool] = False
    motion_subspace: ClassVar[np.ndarray] = _constant(np.vstack([np.zeros((3, 3)), np.eye(3)]))
    unit_norm: ClassVar[tuple[int, int, str]] = (0, 4, "quaternion")

    def neutral(self):
        return np.array([0.0, 0.0, 0.0, 1.0])

    def random(self, rng, lower, upper, shape=()):
        return _random_unit_quaternion(rng, shape)


@dataclass(frozen=True, eq=False)
class FreeFlyer(Joint):
    """Six-DoF joint: ``q = [p, quat]`` (pose of J in P), ``v = [v_lin, ω]`` in J; ``S = I₆``.

    ``integrate`` is the SE(3) exponential ``X(q) exp(v)``, as in Pinocchio.
    """

    kind: ClassVar[str] = "free-flyer"
    nq: ClassVar[int] = 7
    nv: ClassVar[int] = 6
    vector_space: ClassVar[bool] = False
    motion_subspace: ClassVar[np.ndarray] = _constant(np.eye(6))
    unit_norm: ClassVar[tuple[int, int, str]] = (3, 7, "quaternion")

    def neutral(self):
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

    def random(self, rng, lower, upper, shape=()):
        p = _random_uniform(rng, lower[:3], upper[:3], _DEFAULT_TRANSLATION_RANGE, shape)
        return np.concatenate([p, _random_unit_quaternion(rng, shape)], axis=-1)


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


_KIND_CODES = {Revolute: kinds.REVOLUTE, Continuous: kinds.REVOLUTE, Prismatic: kinds.PRISMATIC, Spherical: kinds.SPHERICAL,
               FreeFlyer: kinds.FREE_FLYER, Planar: kinds.PLANAR, Translation: kinds.TRANSLATION}


def kind_code(joint) -> int:
    """The kernel kind code (:mod:`multibody.kernels.joints`) of a joint."""
    try:
        return _KIND_CODES[type(joint)]
    except KeyError:
        raise TypeError(f"joint type {type(joint).__name__} has no compiled kind") from None
