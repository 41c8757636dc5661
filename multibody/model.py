"""The kinematic-tree model (immutable) and the builder that makes one.

Frames. Every moving joint ``i`` owns a *joint frame* fixed in the rigid body it moves; that body is
the lump of every link attached to it by fixed joints. ``joint_placements[i]`` is the pose of joint
frame i in the joint frame of its parent ``parents[i]`` (the world when ``-1``) at the joint's
neutral configuration. Each link ("body") sits at ``body_placements[b]`` in the joint frame of
``body_joints[b]`` (the world frame when ``-1``). See ``docs/conventions.md``.
"""

from __future__ import annotations

import collections
import dataclasses
import difflib
import math
import warnings
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from . import driver, spatial
from . import joints as jt
from .geometry import COLLISION_SHAPES, hull_vertices
from .inertia import Inertia
from .kernels import configuration

STANDARD_GRAVITY = (0.0, 0.0, -9.81)

#: Largest input whose finiteness check sums a Python list rather than reducing in NumPy
_PYTHON_SUM_SIZE = 64
_FLOAT = np.dtype(np.float64)
#: An argument that is not there (:meth:`Model.is_one_state`, the dynamics functions' checks): ``None`` is a value,
#: which the checks refuse.
NOT_GIVEN = object()


def all_finite(x) -> bool:
    """Whether every entry of the float64 array ``x`` is finite, from one sum: a non-finite entry makes it
    non-finite. Python sums a few numbers for a fraction of a NumPy reduction's cost; only a sum of finite
    entries that overflows is settled entry by entry (without NumPy's warning about the sum)."""
    if x.size <= _PYTHON_SUM_SIZE:
        total = sum(x.reshape(-1).tolist())
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            total = np.add.reduce(x, axis=None)
    return math.isfinite(total) or bool(np.isfinite(x).all())


@dataclass(frozen=True, eq=False)
class Geometry:
    """A visual or collision shape attached to a body (loaded on demand, see :mod:`multibody.geometry`).

    ``kind`` is ``"visual"`` or ``"collision"``; ``shape`` is ``"mesh"``, ``"box"``, ``"sphere"``,
    ``"cylinder"``, ``"capsule"``, ``"ellipsoid"`` or ``"convex"`` (the convex hull of ``vertices``);
    ``placement`` the 4×4 pose of the shape (the geometry frame) in the body frame; ``filename`` the resolved
    mesh path (``None`` if it could not be found), ``uri`` the mesh reference as written; ``scale`` (3,);
    ``size`` the primitive's dimensions in m (box: edge lengths; sphere: radius; cylinder: radius, length
    along z; capsule: radius, length of its cylinder along z between the centres of its hemispheres;
    ellipsoid: semi-axes; convex: none); ``vertices`` ``(k, 3)`` the vertices of a convex shape's hull in the
    geometry frame, m (``None`` for the other shapes; a mesh's hull is read from its file, when contact
    detection first needs it, by :func:`multibody.geometry.convex_vertices`).
    """

    body: str
    kind: str
    shape: str
    placement: np.ndarray
    uri: str | None = None
    filename: str | None = None
    scale: tuple = (1.0, 1.0, 1.0)
    size: tuple = ()
    vertices: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Mimic:
    """A URDF mimic relation ``q[joint] = multiplier · q[mimicked] + offset``.

    The model keeps both joints as independent coordinates (as Pinocchio's ``buildModelFromUrdf``
    does by default); the relation is recorded so that it can be enforced as a coupling constraint.
    """

    joint: str
    mimicked: str
    multiplier: float = 1.0
    offset: float = 0.0


def unknown_name(what, name, names, plural):
    """The ``ValueError`` for a ``what`` (``"body"``, ``"joint"``) called ``name`` that is not among ``names``
    (``plural`` says what they are): the close matches first (:func:`difflib.get_close_matches`), so that
    a misspelling shows at a glance, then every valid name."""
    close = difflib.get_close_matches(str(name), [str(n) for n in names], n=3)
    hint = f"; did you mean {' or '.join(map(repr, close))}?" if close else ";"
    return ValueError(f"unknown {what} {name!r}{hint} {plural} are {list(names)}")


def _frozen(array, dtype=float):
    array = np.array(array, dtype=dtype)
    array.setflags(write=False)
    return array


def _per_dof_problem(values, size, finite):
    """What is wrong with per-coordinate joint parameters ``values`` (damping, friction, effort and
    velocity limits: an array, a list of floats, or a number for each coordinate), or ``None``: they must have
    shape ``(size,)`` and be non-negative, and finite when ``finite`` (a limit may be ``inf``: none)."""
    values = [float(values)] * size if isinstance(values, (int, float)) else values
    shape, entries = (values.shape, values.tolist()) if isinstance(values, np.ndarray) else ((len(values),), values)
    if shape != (size,):
        return f"must have shape ({size},), got {shape}"
    # (a NaN fails both comparisons and goes on to the checks that name it)
    if all(0.0 <= x < math.inf for x in entries) if finite else all(0.0 <= x for x in entries):
        return None
    if any(math.isnan(x) for x in entries) or (finite and not all(math.isfinite(x) for x in entries)):
        return f"must be {'finite' if finite else 'numbers (inf for none)'}, got {entries}"
    # (what is left to fail the comparisons above is a negative entry)
    return f"must not be negative, got {entries}"


@dataclass(frozen=True, eq=False)
class Model:
    """An immutable kinematic tree with mass properties.

    Attributes (``nj`` moving joints, ``nb`` bodies):
        name: model name.
        joints: joint types, ``(nj,)`` in model order (parents before children).
        joint_names: ``(nj,)`` names of the moving joints.
        parents: ``(nj,)`` index of each joint's parent joint, ``-1`` for the world.
        joint_placements: ``(nj, 4, 4)`` pose of each joint frame in its parent joint frame (neutral q).
        body_names: ``(nb,)`` names of every body (URDF link), including fixed-attached ones.
        body_joints: ``(nb,)`` joint that moves each body, ``-1`` if fixed to the world.
        body_placements: ``(nb, 4, 4)`` pose of each body frame in its joint frame.
        body_inertias: ``(nb,)`` :class:`Inertia` of each body in its own frame.
        lower, upper: ``(nq,)`` configuration limits (``±inf`` when unbounded; ``±1`` on the unit-norm
            quaternion and planar ``(cos θ, sin θ)`` components, which can never leave them).
        gravity: ``(3,)`` gravitational acceleration in the world frame, m/s².
        geometries: visual and collision shapes of the model file, the viewer's (see :class:`Geometry`).
        collision_geometries: the shapes contact detection uses (see :mod:`multibody.geometry`), each a
            :class:`Geometry` of kind ``"collision"`` naming its body: a URDF's ``<collision>`` elements, an
            MJCF's colliding geoms (``contype`` or ``conaffinity`` not 0), and those of
            :meth:`ModelBuilder.add_collision`; a mesh whose file is not found is left out (with a warning).
        mimic: recorded mimic relations (see :class:`Mimic`).
        damping: ``(nv,)`` viscous joint damping, N·m·s/rad or N·s/m (default zeros); the force
            ``−damping · v`` when :func:`multibody.simulate` is given ``joint_damping=True``.
        friction: ``(nv,)`` joint (Coulomb) friction, N·m or N (default zeros); recorded, not applied.
        effort_limit: ``(nv,)`` largest joint force, N·m or N (``inf`` when none is given).
        velocity_limit: ``(nv,)`` largest joint speed, rad/s or m/s (``inf`` when none is given).
        armature: ``(nv,)`` rotor inertia of each coordinate, kg m² (angles) or kg (displacements), default
            zeros (a URDF has none): added to the diagonal of the mass matrix ``M`` in every algorithm, so
            that the equations of motion read ``(M_bodies + diag(armature)) a + h = τ`` and the kinetic
            energy ``½ vᵀ M v`` counts it too. It belongs to no body: the bodies' momenta, centroidal
            quantities and the forces :func:`multibody.joint_reaction_forces` reports leave it out (see
            ``docs/theory.md``).

        equality_constraints: the model file's own constraints, built-in constraints of
            :mod:`multibody.constraints` (an MJCF ``<equality>``: see :func:`multibody.load_mjcf`); empty for a
            URDF. They are data: pass them to :class:`~multibody.ConstrainedSystem` to enforce them.

    Those five are Pinocchio's ``damping``, ``friction``, ``effortLimit``, ``velocityLimit`` and
    ``armature`` (the last MuJoCo's ``dof_armature``); ``lower`` and ``upper`` its ``lowerPositionLimit``
    and ``upperPositionLimit`` (see :func:`multibody.load_urdf` for what a URDF gives them).
    """

    name: str
    joints: tuple
    joint_names: tuple
    parents: np.ndarray
    joint_placements: np.ndarray
    body_names: tuple
    body_joints: np.ndarray
    body_placements: np.ndarray
    body_inertias: tuple
    lower: np.ndarray
    upper: np.ndarray
    gravity: np.ndarray = field(default_factory=lambda: _frozen(STANDARD_GRAVITY))
    geometries: tuple = ()
    collision_geometries: tuple = ()
    mimic: tuple = ()
    damping: np.ndarray | None = None
    friction: np.ndarray | None = None
    effort_limit: np.ndarray | None = None
    velocity_limit: np.ndarray | None = None
    armature: np.ndarray | None = None
    equality_constraints: tuple = ()

    def __post_init__(self):
        nj, nb = len(self.joints), len(self.body_names)
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        for name in ("joints", "joint_names", "body_names", "body_inertias", "equality_constraints", "geometries",
                     "collision_geometries"):
            set_(name, tuple(getattr(self, name)))
        for name, dtype, shape in (("parents", int, nj), ("body_joints", int, nb), ("joint_placements", float, (nj, 4, 4)),
                                   ("body_placements", float, (nb, 4, 4)), ("gravity", float, 3), ("lower", float, -1),
                                   ("upper", float, -1)):
            set_(name, _frozen(getattr(self, name), dtype).reshape(shape))
        if len(self.joint_names) != nj or len(self.body_inertias) != nb:
            raise ValueError("Model: joints/joint_names and body_names/body_inertias must have equal lengths")
        if any(not -1 <= p < i for i, p in enumerate(self.parents.tolist())):
            raise ValueError("Model: every joint's parent must come before it (parents[i] < i)")
        if any(not -1 <= j < nj for j in self.body_joints.tolist()):
            raise ValueError("Model: body_joints must index joints (or be -1 for the world)")
        if self.lower.shape != (self.nq,) or self.upper.shape != (self.nq,):
            raise ValueError(f"Model: lower and upper limits must have shape ({self.nq},)")
        for name, default, bounded in (("damping", 0.0, True), ("friction", 0.0, True),
                                       ("effort_limit", np.inf, False), ("velocity_limit", np.inf, False),
                                       ("armature", 0.0, True)):
            value = getattr(self, name)
            set_(name, _frozen(np.full(self.nv, default) if value is None else value).reshape(-1))
            problem = _per_dof_problem(getattr(self, name), self.nv, bounded)
            if problem:
                raise ValueError(f"Model: {name} {problem}")
        for names, what in ((self.joint_names, "joint"), (self.body_names, "body")):
            if len(set(names)) != len(names):
                raise ValueError(f"Model: {what} names must be unique")

    # ------------------------------------------------------------------ sizes and indices

    @cached_property
    def nq(self) -> int:
        """Size of the configuration vector ``q``."""
        return int(sum(j.nq for j in self.joints))

    @cached_property
    def nv(self) -> int:
        """Size of the velocity vector ``v``."""
        return int(sum(j.nv for j in self.joints))

    @property
    def njoints(self) -> int:
        """Number of moving joints."""
        return len(self.joints)

    @property
    def nbodies(self) -> int:
        """Number of bodies (links), fixed-attached ones included."""
        return len(self.body_names)

    @cached_property
    def idx_q(self) -> np.ndarray:
        """``(nj,)`` start of each joint's block in ``q``."""
        return _frozen(np.cumsum([0] + [j.nq for j in self.joints])[:-1], int)

    @cached_property
    def idx_v(self) -> np.ndarray:
        """``(nj,)`` start of each joint's block in ``v``."""
        return _frozen(np.cumsum([0] + [j.nv for j in self.joints])[:-1], int)

    @cached_property
    def dof_joint(self) -> np.ndarray:
        """``(nv,)`` index of the joint each velocity coordinate belongs to."""
        return _frozen(np.repeat(np.arange(self.njoints), [j.nv for j in self.joints]), int)

    @cached_property
    def motion_subspaces(self) -> np.ndarray:
        """``(nv, 6)``: column ``k`` of its joint's motion subspace, in that joint's frame."""
        if self.nv == 0:
            return _frozen(np.zeros((0, 6)))
        return _frozen(np.concatenate([j.motion_subspace.T for j in self.joints], axis=0))

    @cached_property
    def ancestors(self) -> np.ndarray:
        """``(nj, nj)`` boolean: ``ancestors[i, j]`` is true when joint j is i or lies between i and the world."""
        out = np.zeros((self.njoints, self.njoints), dtype=bool)
        for i, parent in enumerate(self.parents):
            if parent >= 0:
                out[i] = out[parent]
            out[i, i] = True
        return _frozen(out, bool)

    @cached_property
    def joint_support(self) -> np.ndarray:
        """``(nj, nv)`` boolean: velocity coordinate k moves joint frame i."""
        return _frozen(self.ancestors[:, self.dof_joint], bool)

    @cached_property
    def body_support(self) -> np.ndarray:
        """``(nb, nv)`` boolean: velocity coordinate k moves body b."""
        out = np.zeros((self.nbodies, self.nv), dtype=bool)
        moving = self.body_joints >= 0
        out[moving] = self.joint_support[self.body_joints[moving]]
        return _frozen(out, bool)

    def body_index(self, body) -> int:
        """Index of a body given by name or index; ``ValueError`` names the valid choices."""
        if isinstance(body, str) and (index := self._body_indices.get(body)) is not None:
            return index
        if isinstance(body, (int, np.integer)):
            if not -self.nbodies <= body < self.nbodies:
                raise ValueError(f"body index {body} out of range for {self.nbodies} bodies")
            return int(body) % self.nbodies
        raise unknown_name("body", body, self.body_names, "bodies")

    @cached_property
    def _body_indices(self):
        """``{name: index}`` of the bodies."""
        return {name: index for index, name in enumerate(self.body_names)}

    def joint_index(self, joint) -> int:
        """Index of a moving joint given by name or index."""
        if isinstance(joint, (int, np.integer)):
            if not -self.njoints <= joint < self.njoints:
                raise ValueError(f"joint index {joint} out of range for {self.njoints} joints")
            return int(joint) % self.njoints
        try:
            return self.joint_names.index(joint)
        except ValueError:
            raise unknown_name("joint", joint, self.joint_names, "moving joints") from None

    @cached_property
    def tree(self):
        """The model flattened into the arrays the compiled kernels read (:mod:`multibody.tree`)."""
        from .tree import compile_tree
        return compile_tree(self)

    @cached_property
    def _body_frames(self):
        """``{name or index: frame row (1, 13)}`` of :attr:`tree` of each body, the frame a kernel is asked about."""
        rows = [self.tree.bodies[b : b + 1] for b in range(self.nbodies)]
        return {**dict(zip(self.body_names, rows)), **dict(enumerate(rows))}

    def body_frame_row(self, body) -> np.ndarray:
        """The frame row ``(1, 13)`` of :attr:`tree` (``tree.bodies``) that a kernel reads as the frame of
        ``body``, a name or an index; ``ValueError`` as :meth:`body_index`."""
        if type(body) is str or type(body) is int:  # (a bool, a float or an unknown name gets body_index's check)
            row = self._body_frames.get(body)
            if row is not None:
                return row
        return self._body_frames[self.body_index(body)]

    # ------------------------------------------------------------------ mass properties

    @cached_property
    def joint_inertias(self) -> tuple:
        """``(nj,)`` :class:`Inertia` of each moving rigid body (its links lumped), in its joint frame."""
        lumped = [Inertia.zero() for _ in self.joints]
        for b, j in enumerate(self.body_joints):
            if j >= 0:
                lumped[j] = lumped[j] + self.body_inertias[b].transformed(self.body_placements[b])
        return tuple(lumped)

    @cached_property
    def spatial_inertias(self) -> np.ndarray:
        """``(nj, 6, 6)`` spatial inertia of each moving body about its joint-frame origin."""
        if self.njoints == 0:
            return _frozen(np.zeros((0, 6, 6)))
        return _frozen(np.stack([inertia.spatial for inertia in self.joint_inertias]))

    @property
    def total_mass(self) -> float:
        """Sum of all body masses (kg), links fixed to the world included."""
        return float(sum(inertia.mass for inertia in self.body_inertias))

    def with_gravity(self, gravity) -> "Model":
        """A new model equal to this one but for its gravity; this one is unchanged (models are immutable).

        ``gravity``: ``(3,)`` finite gravitational acceleration in the world frame, m/s² (e.g.
        ``(0, 0, -1.62)`` on the Moon, zeros for none).
        """
        try:
            g = np.asarray(gravity, dtype=float)
        except (TypeError, ValueError):  # (text, or a ragged sequence)
            g = None
        if g is None or g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"gravity must be 3 finite numbers (m/s², world frame), got {gravity!r}")
        return dataclasses.replace(self, gravity=g)

    def with_armature(self, armature) -> "Model":
        """A new model equal to this one but for its :attr:`armature`; this one is unchanged.

        ``armature``: ``(nv,)`` finite, non-negative rotor inertia per velocity coordinate, kg m² or kg
        (a number for every coordinate), in the model's ``v`` order.
        """
        try:
            values = np.asarray(armature, dtype=float)
        except (TypeError, ValueError):  # (text, or a ragged sequence)
            raise ValueError(f"armature must be numbers, one per velocity coordinate ({self.nv}), got "
                             f"{armature!r}") from None
        values = np.full(self.nv, float(values)) if values.ndim == 0 else values
        problem = _per_dof_problem(values, self.nv, True)
        if problem:
            raise ValueError(f"armature {problem}")
        return dataclasses.replace(self, armature=values)

    # ------------------------------------------------------------------ configuration space

    def neutral(self) -> np.ndarray:
        """Neutral configuration ``(nq,)``: zero angles and displacements, identity quaternions."""
        return np.concatenate([j.neutral() for j in self.joints]) if self.joints else np.zeros(0)

    def random_configuration(self, rng=None, shape=()) -> np.ndarray:
        """Random configurations ``shape + (nq,)`` within the limits.

        Unbounded angles are drawn in ``[−π, π]``, unbounded translations in ``[−1, 1]`` m, and
        quaternions uniformly over rotations. ``rng`` is a ``numpy.random.Generator`` or a seed.
        """
        rng = np.random.default_rng(rng)
        shape = tuple(np.atleast_1d(shape)) if shape != () else ()
        blocks = [
            joint.random(rng, self.lower[s : s + joint.nq], self.upper[s : s + joint.nq], shape)
            for joint, s in zip(self.joints, self.idx_q)
        ]
        return np.concatenate(blocks, axis=-1) if blocks else np.zeros(shape + (0,))

    def integrate(self, q, v, dt=1.0) -> np.ndarray:
        """Configuration exponential ``q ⊕ v dt``: each joint moves with constant ``v`` for ``dt``.

        Quaternions stay on the unit sphere. ``q (..., nq)``, ``v (..., nv)`` -> ``(..., nq)``.
        """
        q = self.check_configuration(q)
        v = self.check_velocity(v) * dt
        return driver.configuration_map(configuration.integrate, self.tree, q, v, (self.nq,))

    def difference(self, q0, q1) -> np.ndarray:
        """Configuration logarithm: the ``v`` with ``integrate(q0, v) = q1``. ``-> (..., nv)``."""
        q0, q1 = self.check_configuration(q0, "q0"), self.check_configuration(q1, "q1")
        return driver.configuration_map(configuration.difference, self.tree, q0, q1, (self.nv,))

    def configuration_rate(self, q, v) -> np.ndarray:
        """``q̇`` of a configuration moving with velocity ``v``: ``(..., nq)``.

        Equal to ``v`` for angles and displacements; quaternions get ``½ q ⊗ (ω, 0)``, free-flyer
        positions ``R v_lin``, planar joints ``R(θ) (vx, vy)`` and ``ω (−sin θ, cos θ)``.
        """
        q, v = self.check_configuration(q), self.check_velocity(v)
        return driver.configuration_map(configuration.configuration_rate, self.tree, q, v, (self.nq,))

    # ------------------------------------------------------------------ charts for Lie-group integration

    def chart(self, q0, delta) -> np.ndarray:
        """Configuration at chart coordinates ``delta (..., nv)`` around ``q0 (..., nq)``: ``(..., nq)``.

        Angles and displacements add; quaternions become ``exp(δ) ⊗ q₀`` (a rotation vector in the
        parent frame) and planar angles turn by ``δ_θ``, so every configuration stays on its manifold.
        :func:`multibody.simulate` integrates ``δ`` with :meth:`chart_rate` and starts a new chart
        at the end of every step.
        """
        q0, delta = spatial.float_array(q0, self.nq, "q0"), spatial.float_array(delta, self.nv, "delta")
        return driver.configuration_map(configuration.chart, self.tree, q0, delta, (self.nq,))

    def chart_coordinates(self, q0, q) -> np.ndarray:
        """Chart coordinates ``δ (..., nv)`` of ``q (..., nq)`` around ``q0 (..., nq)``: the inverse of
        :meth:`chart`, ``chart(q0, δ) = q`` (rotation vectors of angle at most π). ``q − q0`` for angles
        and displacements; ``log(q ⊗ q₀*)`` for quaternions, in the parent frame (rad)."""
        q0, q = self.check_configuration(q0, "q0"), self.check_configuration(q, "q")
        return driver.configuration_map(configuration.chart_coordinates, self.tree, q0, q, (self.nv,))

    def chart_rate(self, delta, w) -> np.ndarray:
        """``δ̇ (..., nv)`` of chart coordinates ``delta`` moving with aligned velocity ``w`` (see
        :meth:`velocity_alignment`): ``w`` itself, but ``J_l(δ)⁻¹ ω`` for rotation vectors."""
        delta, w = spatial.float_array(delta, self.nv, "delta"), spatial.float_array(w, self.nv, "w")
        return driver.configuration_map(configuration.chart_rate, self.tree, delta, w, (self.nv,))

    def velocity_alignment(self, q) -> np.ndarray:
        """Orthogonal ``T(q) (..., nv, nv)`` that rotates free-flyer, spherical and planar velocity
        coordinates into their parent frames: ``w = T v`` (block diagonal, the identity elsewhere).

        Body-frame velocities turn with a spinning body; aligned ones change only as the motion does,
        which lets an integrator take steps of half a revolution (its charts' rotation vectors are singular
        at 2π: :data:`multibody.mechanical.CHART_TURN`). Their rate is
        ``ẇ = T (a + κ(v))`` (:meth:`velocity_coupling`).
        """
        return driver.configuration_map(configuration.velocity_alignment, self.tree, spatial.float_array(q, self.nq, "q"), None,
                                       (self.nv, self.nv))

    def velocity_coupling(self, v) -> np.ndarray:
        """``κ(v) (..., nv)`` with ``d/dt (T v) = T (v̇ + κ(v))`` (see :meth:`velocity_alignment`):
        ``[ω × v_lin; 0]`` for a free flyer, ``ω (−vy, vx, 0)`` for a planar joint, zero for spherical
        joints, angles and displacements."""
        return driver.configuration_map(configuration.velocity_coupling, self.tree, spatial.float_array(v, self.nv, "v"), None, (self.nv,))

    def chart_magnitude(self, q) -> np.ndarray:
        """Size ``(..., nv)`` of the configuration ``q`` in each chart direction (see :meth:`chart`): ``|q|``
        for angles and displacements, 1 (rad) for rotation vectors. :func:`multibody.simulate` measures
        the relative error of the chart coordinates ``δ`` against it, as against ``q`` itself, rather
        than against ``δ``, which starts at zero in every step."""
        return driver.configuration_map(configuration.chart_magnitude, self.tree, spatial.float_array(q, self.nq, "q"), None, (self.nv,))

    @cached_property
    def is_vector_space(self) -> bool:
        """Whether every configuration coordinate is an angle or displacement (``q̇ = v``; charts add and
        :meth:`velocity_alignment` is the identity)."""
        return all(joint.vector_space for joint in self.joints)

    def normalize(self, q) -> np.ndarray:
        """``q`` with every quaternion (and planar ``(cos θ, sin θ)`` pair) scaled to unit norm."""
        return driver.configuration_map(configuration.normalize, self.tree, spatial.float_array(q, self.nq, "q"), None, (self.nq,))

    # ------------------------------------------------------------------ input checking

    @staticmethod
    def _as_float_array(x, name):
        if not (type(x) is np.ndarray and x.dtype == np.float64):
            x = np.asarray(x)
            if x.dtype == object or not (np.issubdtype(x.dtype, np.number) or x.dtype == bool):
                raise ValueError(f"{name} must be a real numeric array, got dtype {x.dtype}")
            if np.iscomplexobj(x):
                raise ValueError(f"{name} must be real, got dtype {x.dtype}")
            x = x.astype(float, copy=False)
        if not all_finite(x):
            warnings.warn(f"{name} contains NaN or infinite values; results will contain NaN", RuntimeWarning, stacklevel=3)
        return x

    def is_one_state(self, q, v=NOT_GIVEN, w=NOT_GIVEN, finite=True) -> bool:
        """Whether ``q`` and the velocities ``v``, ``w`` (each :data:`NOT_GIVEN` when not there) make
        one state that :meth:`check_configuration` and :meth:`check_velocity` would pass unchanged: C-contiguous
        float64 arrays of shapes ``(nq,)`` and ``(nv,)`` with finite entries (not looked at with ``finite=False``),
        and ``q``'s :attr:`unit_norm_slices` of unit norm within tolerance. Plain Python on the state's few numbers, a
        fraction of the checks' cost; ``False`` sends the caller to the full checks, which convert,
        warn and raise."""
        total = 0.0
        if q is not NOT_GIVEN:
            if (type(q) is not np.ndarray or q.dtype is not _FLOAT or q.ndim != 1 or len(q) != self.nq
                    or not q.flags.c_contiguous):
                return False
            slices = self.unit_norm_slices
            if slices or finite:
                values = q.tolist()
                lower, upper = jt.UNIT_SQUARED_NORMS
                for start, stop in slices:
                    if not lower <= sum([c * c for c in values[start:stop]]) <= upper:
                        return False
                total = sum(values)
        if v is NOT_GIVEN:
            v, w = w, NOT_GIVEN
        if v is not NOT_GIVEN:
            nv = self.nv
            if (type(v) is not np.ndarray or v.dtype is not _FLOAT or v.ndim != 1 or len(v) != nv
                    or not v.flags.c_contiguous):
                return False
            if w is not NOT_GIVEN and (type(w) is not np.ndarray or w.dtype is not _FLOAT or w.ndim != 1
                                       or len(w) != nv or not w.flags.c_contiguous):
                return False
            if finite:
                total += sum(v.tolist()) + (0.0 if w is NOT_GIVEN else sum(w.tolist()))
        # One non-finite entry makes the sum non-finite (and so may an overflow, which the full checks pass).
        return not finite or math.isfinite(total)

    def check_configuration(self, q, name="q") -> np.ndarray:
        """``q`` as a float array of shape ``(..., nq)``, or ``ValueError``.

        Quaternions must have unit norm within :data:`multibody.joints.UNIT_NORM_TOLERANCE`
        (they are then used as normalised). Non-finite values warn and propagate as NaN.
        """
        if self.is_one_state(q):
            return q
        q = self._as_float_array(q, name)
        spatial.require_last_axis(q, self.nq, name)
        # NaN norms compare false, so non-finite entries pass here and propagate (with the warning above).
        for joint, joint_name, start in self._unit_norm_blocks:
            joint.validate(q[..., start : start + joint.nq], joint_name)
        return q

    @cached_property
    def _unit_norm_blocks(self):
        """``(joint, name, start in q)`` of the joints whose configuration must have unit norm."""
        return tuple((joint, name, start) for joint, name, start in zip(self.joints, self.joint_names, self.idx_q)
                     if joint.unit_norm is not None)

    @cached_property
    def unit_norm_slices(self):
        """``((start, stop), ...)``: the slice of ``q`` of each block that must have unit norm (a quaternion, a
        planar joint's ``(cos θ, sin θ)``)."""
        return tuple((start + joint.unit_norm[0], start + joint.unit_norm[1]) for joint, _, start in self._unit_norm_blocks)

    def check_velocity(self, v, name="v") -> np.ndarray:
        """``v`` as a float array of shape ``(..., nv)``, or ``ValueError``."""
        if self.is_one_state(NOT_GIVEN, v):
            return v
        v = self._as_float_array(v, name)
        spatial.require_last_axis(v, self.nv, name)
        return v

    def check_external_forces(self, f_ext, name="f_ext") -> np.ndarray:
        """``f_ext`` as a float array of shape ``(..., njoints, 6)`` (one spatial force per moving joint, in its
        frame: N, N m), or ``ValueError``."""
        f_ext = self._as_float_array(f_ext, name)
        if f_ext.shape[-2:] != (self.njoints, 6):
            raise ValueError(f"{name} must have shape (..., {self.njoints}, 6) (one spatial force per moving "
                             f"joint, in its frame), got {f_ext.shape}")
        return f_ext

    def __repr__(self):
        return (
            f"Model({self.name!r}: {self.njoints} joints, {self.nbodies} bodies, nq={self.nq}, nv={self.nv}, "
            f"mass={self.total_mass:.6g} kg)"
        )


# ============================================================================= builder

#: What the size of each shape of :meth:`ModelBuilder.add_collision` holds, in order (m).
_COLLISION_SIZES = {"sphere": ("radius",), "box": ("x", "y", "z"), "cylinder": ("radius", "length"),
                    "capsule": ("radius", "length"), "convex": ()}
#: the mass properties of a body given none, and the pose of a frame in itself (immutable, so shared)
_MASSLESS, _IDENTITY = Inertia.zero(), _frozen(np.eye(4))

#: What :meth:`ModelBuilder.add_body` keeps of a body: its limits and per-coordinate parameters as lists of floats
_BodySpec = collections.namedtuple("_BodySpec", "name parent joint joint_name placement inertia lower upper damping "
                                                "friction effort_limit velocity_limit armature")


class ModelBuilder:
    """Build a :class:`Model` body by body.

    Example (a planar double pendulum swinging about y, links of 1 m, point masses at the tips)::

        b = ModelBuilder("double_pendulum")
        b.add_body("link1", joint=Revolute([0, 1, 0]), inertia=point_mass(1.0, [0, 0, -1]))
        b.add_body("link2", parent="link1", joint=Revolute([0, 1, 0]),
                   placement=pose_from_xyz_rpy([0, 0, -1]), inertia=point_mass(1.0, [0, 0, -1]))
        model = b.build()

    Bodies must be added parents first; the joints of the model come in the order their bodies
    were added. Bodies attached by :class:`~multibody.joints.Fixed` joints are lumped into their
    moving parent but keep their names and placements. The built-in constraints (:mod:`multibody.constraints`)
    appended to ``equality_constraints`` become the model's :attr:`Model.equality_constraints`.
    """

    def __init__(self, name: str = "model", gravity=STANDARD_GRAVITY):
        self.name = name
        self.gravity = np.array(gravity, dtype=float).reshape(3)
        self._bodies: list[_BodySpec] = []
        self._names: set[str] = set()
        self._joint_names: set[str] = set()
        self.geometries: list[Geometry] = []
        self.collision_geometries: list[Geometry] = []
        self.mimic: list[Mimic] = []
        self.equality_constraints: list = []

    def add_body(self, name, joint=None, *, parent=None, placement=None, inertia=None, joint_name=None,
                 lower=None, upper=None, damping=0.0, friction=0.0, effort_limit=np.inf,
                 velocity_limit=np.inf, armature=0.0) -> str:
        """Add a body moved by ``joint`` relative to ``parent``.

        Args:
            name: unique body name.
            joint: a :mod:`multibody.joints` instance; default :class:`~multibody.joints.Fixed`.
            parent: name of the parent body, or ``None`` for the world.
            placement: 4×4 pose of the joint's pre-joint frame in the parent body frame (default
                identity). At the neutral configuration the new body's frame is this frame.
            inertia: :class:`Inertia` in the new body's frame (default massless).
            joint_name: unique name of the joint (default ``name + "_joint"``).
            lower, upper: configuration limits, ``(joint.nq,)`` (default: the joint's own, unbounded
                but for unit-norm components).
            damping: viscous damping per velocity coordinate, N·m·s/rad or N·s/m: a number or
                ``(joint.nv,)``, non-negative (default none).
            friction: joint friction, N·m or N, likewise (default none; recorded, not applied).
            effort_limit, velocity_limit: largest joint force (N·m or N) and speed (rad/s or m/s),
                likewise; ``inf`` (the default) for none.
            armature: rotor inertia per velocity coordinate, kg m² or kg, likewise, finite and
                non-negative (default none): added to the mass matrix's diagonal (:attr:`Model.armature`).
        Returns:
            ``name``.
        """
        joint = jt.Fixed() if joint is None else joint
        if not isinstance(joint, jt.Joint):
            raise TypeError(f"joint must be a multibody.joints.Joint, got {type(joint).__name__}")
        if name in self._names:
            raise ValueError(f"duplicate body name {name!r}")
        if parent is not None and parent not in self._names:
            raise ValueError(f"parent body {parent!r} of {name!r} has not been added (add parents first)")
        joint_name = f"{name}_joint" if joint_name is None else joint_name
        if joint_name in self._joint_names:
            raise ValueError(f"duplicate joint name {joint_name!r}")
        placement = np.eye(4) if placement is None else np.array(placement, dtype=float)
        if placement.shape != (4, 4):
            raise ValueError(f"placement must have shape (4, 4), got {placement.shape}")
        default_lower, default_upper = joint.default_limits
        lower = default_lower if lower is None else np.array(lower, dtype=float).reshape(-1)
        upper = default_upper if upper is None else np.array(upper, dtype=float).reshape(-1)
        if lower.shape != (joint.nq,) or upper.shape != (joint.nq,):
            raise ValueError(f"limits of joint {joint_name!r} must have shape ({joint.nq},)")
        per_dof = {}
        for key, value, finite in (("damping", damping, True), ("friction", friction, True),
                                   ("effort_limit", effort_limit, False), ("velocity_limit", velocity_limit, False),
                                   ("armature", armature, True)):
            if isinstance(value, (int, float)) and ((0.0 <= value < math.inf) if finite else 0.0 <= value):
                per_dof[key] = [float(value)] * joint.nv  # (a number stands for each coordinate: one comparison)
                continue
            if not isinstance(value, (int, float)):
                try:
                    value = np.array(value, dtype=float)
                except (TypeError, ValueError):  # (text, or a ragged sequence)
                    raise ValueError(f"{key} of joint {joint_name!r} must be numbers, got {value!r}") from None
                value = value.reshape(-1).tolist() if value.ndim else float(value)
            problem = _per_dof_problem(value, joint.nv, finite)
            if problem:
                raise ValueError(f"{key} of joint {joint_name!r} {problem}")
            per_dof[key] = value if isinstance(value, list) else [float(value)] * joint.nv  # (a number for each)
        self._bodies.append(_BodySpec(name, parent, joint, joint_name, placement,
                                      _MASSLESS if inertia is None else inertia, lower.tolist(), upper.tolist(), **per_dof))
        self._names.add(name)
        self._joint_names.add(joint_name)
        return name

    def add_geometry(self, geometry: Geometry):
        """Attach a visual or collision :class:`Geometry` to an existing body."""
        if geometry.body not in self._names:
            raise ValueError(f"geometry attached to unknown body {geometry.body!r}")
        self.geometries.append(geometry)

    def add_collision_geometry(self, geometry: Geometry):
        """Attach a collision :class:`Geometry` (kind ``"collision"``, a shape of
        :data:`multibody.geometry.COLLISION_SHAPES`) to an existing body, as a model file gives it: its sizes
        are checked when :func:`multibody.geometry.collision_table` reads them (:meth:`add_collision`
        checks them at once)."""
        if geometry.body not in self._names:
            raise unknown_name("body", geometry.body, [spec.name for spec in self._bodies], "bodies")
        if geometry.kind != "collision" or geometry.shape not in COLLISION_SHAPES:
            raise ValueError(f"collision geometry of body {geometry.body!r} must be of kind 'collision' and shape "
                             f"{', '.join(COLLISION_SHAPES)}; got kind {geometry.kind!r}, shape {geometry.shape!r}")
        self.collision_geometries.append(geometry)

    def add_collision(self, body, shape, size=None, placement=None, *, vertices=None) -> Geometry:
        """Attach a collision shape to an existing body (:attr:`Model.collision_geometries`).

        Args:
            body: name of the body, already added.
            shape: ``"sphere"``, ``"box"``, ``"cylinder"``, ``"capsule"`` or ``"convex"``.
            size: the dimensions in m, positive: sphere ``(radius,)``; box ``(x, y, z)``, its edge lengths;
                cylinder ``(radius, length)`` along the geometry frame's z; capsule ``(radius, length)``,
                the length of its cylinder between the centres of its hemispheres, along z; ``None`` (or
                ``()``) for ``"convex"``. A number stands for a one-number size.
            placement: 4×4 pose of the geometry frame in the body frame (default identity).
            vertices: ``"convex"`` only: ``(k, 3)`` points in the geometry frame, m, at least 4 and not all
                in one plane; the shape is their convex hull, and only the hull's vertices are kept.
        Returns:
            the :class:`Geometry` added.
        Raises:
            ValueError: an unknown body or shape, sizes not positive and finite or not as many as the shape
                has, a placement that is not a finite rigid pose, or vertices missing, not finite, fewer
                than 4 or in one plane; the message names the argument and the body.
        """
        if body not in self._names:
            raise ValueError(f"add_collision: {unknown_name('body', body, [s.name for s in self._bodies], 'bodies')}")
        where = f"collision geometry of body {body!r}"
        if shape not in _COLLISION_SIZES:
            raise ValueError(f"{where}: shape must be one of {', '.join(_COLLISION_SIZES)}, got {shape!r}")
        names = _COLLISION_SIZES[shape]
        try:
            size = np.array(() if size is None else size, dtype=float).reshape(-1)
        except (TypeError, ValueError):  # (text, or a ragged sequence)
            raise ValueError(f"{where}: size of a {shape} must be numbers, got {size!r}") from None
        if len(size) != len(names):
            raise ValueError(f"{where}: size of a {shape} must be {len(names)} number(s) "
                             f"({', '.join(names) or 'none: the vertices give it'}), got {len(size)}")
        if not np.all(np.isfinite(size) & (size > 0.0)):
            raise ValueError(f"{where}: size of a {shape} ({', '.join(names)}) must be positive and finite, "
                             f"got {size.tolist()}")
        try:
            placement = np.eye(4) if placement is None else np.array(placement, dtype=float)
        except (TypeError, ValueError):  # (text, or a ragged sequence)
            raise ValueError(f"{where}: placement must be a 4×4 pose, got {placement!r}") from None
        problem = spatial.pose_problem(placement)
        if problem:
            raise ValueError(f"{where}: placement {problem}")
        if (shape == "convex") != (vertices is not None):
            raise ValueError(f"{where}: vertices are given for a convex shape, and only for one"
                             + (f" (not a {shape})" if shape != "convex" else ""))
        if vertices is not None:
            try:
                vertices = hull_vertices(vertices)
            except ValueError as problem:
                raise ValueError(f"{where}: vertices {problem}") from None
        geometry = Geometry(body, "collision", shape, _frozen(placement), size=tuple(size.tolist()),
                            vertices=vertices)
        self.add_collision_geometry(geometry)
        return geometry

    def add_mimic(self, mimic: Mimic):
        """Record a mimic relation between two joints (both stay independent coordinates)."""
        self.mimic.append(mimic)

    def build(self, check_inertia=True, hidden=()) -> Model:
        """Lump fixed attachments and return the immutable :class:`Model`.

        With ``check_inertia`` a moving rigid body (a link with everything fixed to it) whose mass
        properties no real body can have raises ``ValueError`` (see :func:`inertia_problems`). ``hidden``:
        the names of massless bodies without geometries added only to carry a joint (between the joints of one
        MJCF body), left out of the model's bodies; the joints they carry stay. A name that is no such body raises
        ``ValueError`` naming it and why.
        """
        if isinstance(hidden, str):
            raise TypeError(f"hidden must be a collection of body names, got the string {hidden!r}")
        # (a set, read once: an iterator would be empty by the second reading, a list searched once per body)
        hidden = set(hidden)
        masses = {spec.name: spec.inertia.mass for spec in self._bodies}
        drawn = {geometry.body for geometry in self.geometries + self.collision_geometries}
        wrong = [f"{name!r} (" + ("not a body" if name not in masses else f"mass {masses[name]} kg" if masses[name]
                                  else "has geometries") + ")"
                 for name in sorted(hidden, key=str) if name not in masses or masses[name] or name in drawn]
        if wrong:
            raise ValueError(f"hidden must name massless bodies of the builder without geometries, got {', '.join(wrong)}")
        moving, parents, joint_placements = [], [], []
        body_joint, body_placement = {}, {}
        for spec in self._bodies:
            if spec.parent is None:
                parent_joint, X_parent = -1, _IDENTITY
            else:
                parent_joint, X_parent = body_joint[spec.parent], body_placement[spec.parent]
            # Pose of the pre-joint frame in the frame of the joint that moves the parent body.
            X_joint_pre = spec.placement if X_parent is _IDENTITY else X_parent @ spec.placement
            if spec.joint.nv == 0:
                body_joint[spec.name], body_placement[spec.name] = parent_joint, X_joint_pre
                continue
            body_joint[spec.name], body_placement[spec.name] = len(moving), _IDENTITY
            moving.append(spec)
            parents.append(parent_joint)
            joint_placements.append(X_joint_pre)
        bodies = [spec for spec in self._bodies if spec.name not in hidden]
        names = [spec.name for spec in bodies]
        model = Model(
            name=self.name,
            joints=tuple(spec.joint for spec in moving),
            joint_names=tuple(spec.joint_name for spec in moving),
            parents=np.array(parents, dtype=int),
            joint_placements=np.array(joint_placements).reshape(-1, 4, 4),
            body_names=tuple(names),
            body_joints=np.array([body_joint[n] for n in names], dtype=int),
            body_placements=np.array([body_placement[n] for n in names]).reshape(-1, 4, 4),
            body_inertias=tuple(spec.inertia for spec in bodies),
            gravity=self.gravity,
            geometries=tuple(self.geometries),
            collision_geometries=tuple(self.collision_geometries),
            mimic=tuple(self.mimic),
            equality_constraints=tuple(self.equality_constraints),
            # the joints' limits (nq each) and parameters per velocity coordinate, in joint order
            **{key: np.array([x for spec in moving for x in getattr(spec, key)], dtype=float)
               for key in ("lower", "upper", "damping", "friction", "effort_limit", "velocity_limit", "armature")},
        )
        if check_inertia:
            problems = inertia_problems(model)
            if problems:
                raise ValueError("invalid mass properties: " + "; ".join(
                    f"body of joint {model.joint_names[j]!r} ({', '.join(links)}): {', '.join(text)}"
                    for j, links, text in problems))
        return model


def inertia_problems(model):
    """Physically impossible mass properties of the moving rigid bodies of ``model``.

    Checked per rigid body that the dynamics integrates (a moving link lumped with the links
    fixed to it), with :meth:`Inertia.problems`. Returns a list of
    ``(joint index, names of the links with mass in that body, problems)``.
    """
    out = []
    for j, inertia in enumerate(model.joint_inertias):
        problems = inertia.problems()
        if problems:
            links = [model.body_names[b] for b in np.flatnonzero(model.body_joints == j)
                     if model.body_inertias[b].mass > 0.0 or np.any(model.body_inertias[b].rotational)]
            out.append((j, links, problems))
    return out


def suspicious_inertias(model, placeholder_mass=1e-5):
    """Mass properties that are legal but probably not what the author meant, as messages.

    Reported per link: impossible numbers (see :meth:`Inertia.problems`), placeholder masses below
    ``placeholder_mass`` kg, and point masses (mass without rotational inertia). Reported per
    moving rigid body: no mass at all with no massive body further down the tree, which makes the
    mass matrix singular, unless armature on each of its coordinates keeps it regular.
    """
    out = []
    for b, (name, inertia) in enumerate(zip(model.body_names, model.body_inertias)):
        out += [f"link {name!r}: {problem}" for problem in inertia.problems()]
        if 0.0 < inertia.mass < placeholder_mass:
            out.append(f"link {name!r}: placeholder mass {inertia.mass:g} kg")
        if inertia.mass > 0.0 and not np.any(inertia.rotational) and model.body_joints[b] >= 0:
            out.append(f"link {name!r}: point mass ({inertia.mass:g} kg, zero rotational inertia)")
    subtree_mass = np.array([inertia.mass for inertia in model.joint_inertias])
    for i in range(model.njoints - 1, -1, -1):
        if model.parents[i] >= 0:
            subtree_mass[model.parents[i]] += subtree_mass[i]
    for i, mass in enumerate(subtree_mass):
        if mass == 0.0 and not np.all(model.armature[model.idx_v[i] : model.idx_v[i] + model.joints[i].nv] > 0.0):
            out.append(f"joint {model.joint_names[i]!r} moves no mass: the mass matrix is singular")
    return out
