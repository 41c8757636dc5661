"""Constraints enforced through Lagrange multipliers.

Every constraint contributes ``m`` rows to three levels (sign convention in ``docs/conventions.md``):

* velocity: ``A(q, t) v + b(q, t) = 0``;
* acceleration: ``A(q, t) a = γ(q, v, t)``, obtained by differentiating the velocity level in time;
* position (holonomic constraints only): ``φ(q, t) = 0``, with ``A = ∂φ/∂q · ∂q/∂v`` and ``b = ∂φ/∂t``.

The multipliers ``λ`` enter the equations of motion as ``M a + h = τ + Aᵀ λ``; for the built-in
constraints they are the constraint forces named in each class.

A constraint is evaluated for a mechanical *system* (a :class:`~multibody.model.Model`, or any
object with ``nq``, ``nv`` and ``integrate(q, v, dt)``). Its methods take one state (no batch axes
are required of user callables); built-in constraints also accept batches.

Derivatives the user does not supply are taken numerically along the path ``q(s) = q ⊕ v s``,
``t + s`` (constant generalized velocity, ``a = 0``) with fourth-order central differences.
"""

from __future__ import annotations

import numpy as np

from . import driver, kinematics, spatial
from .kernels import constraints as compiled
from .model import Model
from .spatial import matvec, transpose
from .tree import frame_rows

# Steps of the numerical derivatives: fourth-order stencils keep the truncation error near
# (h/L)⁴ for features of size L, and the rounding error near ε/h (first) or ε/h² (second derivative).
FIRST_STEP = 1e-3
_SECOND_STEP = 2e-3


def first_derivative(f, h=FIRST_STEP):
    """``f'(0)`` by the five-point stencil ``(8 (f(h) − f(−h)) − (f(2h) − f(−2h))) / 12h``."""
    return (8.0 * (f(h) - f(-h)) - (f(2.0 * h) - f(-2.0 * h))) / (12.0 * h)


def _second_derivative(f, h=_SECOND_STEP):
    """``f''(0)`` by the five-point stencil ``(−f(2h) + 16 f(h) − 30 f(0) + 16 f(−h) − f(−2h)) / 12h²``."""
    return (-f(2.0 * h) + 16.0 * f(h) - 30.0 * f(0.0) + 16.0 * f(-h) - f(-2.0 * h)) / (12.0 * h * h)


def _along_path(system, q, v, t, fn):
    """``s ↦ fn(q ⊕ v s, t + s)``."""
    return lambda s: fn(system.integrate(q, v, s), t + s)


def path_step(v, step):
    """The stencil step in ``s`` along ``q ⊕ v s``: ``step / max(1, |v|_∞)``, so that one step moves every
    coordinate by at most ``step`` (rad or m) whatever the speed, and time by at most ``step`` s. A step
    in time alone would carry a fast mechanism a radian through one stencil."""
    return step / max(1.0, float(np.abs(v).max(initial=0.0)))


class Constraint:
    """Base class. Subclasses define ``rows(system)``, ``jacobian``, and ``acceleration_rhs``;
    holonomic ones also ``position``.

    Attributes:
        name: label used in errors and in :class:`~multibody.constrained.ConstrainedSystem` rows.
        holonomic: ``True`` when a position-level ``φ(q, t) = 0`` exists.
    """

    holonomic = False

    def __init__(self, name=None):
        self.name = name or type(self).__name__

    def rows(self, system) -> int:
        """Number of rows ``m``."""
        raise NotImplementedError

    def independent_rows(self, system) -> int:
        """How many of the rows are independent by design, away from singular configurations: ``m``, or fewer
        for a constraint written with a redundant row (a bead on a wire: three rows of rank 2). Fewer at a
        state means that it holds less than it should (see :class:`~multibody.constrained.RankDeficientWarning`)."""
        return self.rows(system)

    @property
    def body_frames(self) -> tuple:
        """``(body, placement)`` of the frames whose kinematics :meth:`evaluate` reads (none here): a
        :class:`~multibody.constrained.ConstrainedSystem` computes them in its pass down the tree for
        ``M`` and ``h`` rather than in one pass per frame."""
        return ()

    def _frame_terms(self, system, q, v=None):
        """:func:`frame_terms` ``(R_WF, p_WF, J, J̇v)`` of each of :attr:`body_frames` at ``(q, v)`` (``v``
        ``None``: zero)."""
        return tuple(frame_terms(system, self, q, v, body, placement) for body, placement in self.body_frames)

    def bind(self, system):
        """This constraint checked against ``system`` where the two meet (a
        :class:`~multibody.constrained.ConstrainedSystem`'s construction), and returned as it applies to it:
        itself, or a copy that carries what the model decides (the plane of a planar :class:`LoopClosure`).

        Every body of :attr:`body_frames` must be one of the model's (a misspelled name raises ``ValueError``
        naming the constraint and the close matches); a constraint on bodies needs a :class:`Model`.
        Subclasses that name other parts of the model (joints) check those too.
        """
        bodies = [body for body, _ in self.body_frames if body is not None]
        if bodies:
            model = require_model(system, self)
            for body in bodies:
                try:
                    model.body_index(body)
                except ValueError as error:
                    raise ValueError(f"{self.name}: {error}") from None
        return self

    def position_rows(self, system):
        """``(m,)`` boolean: the rows that have a position level ``φ = 0`` (all of a holonomic
        constraint's, none of a Pfaffian's; a rolling contact's normal row is holonomic)."""
        return np.full(self.rows(system), self.holonomic)

    def position(self, system, q, t=0.0):
        """``φ(q, t)`` ``(..., m)`` (holonomic constraints only)."""
        raise TypeError(f"{self.name} is not holonomic: it has no position level")

    def jacobian(self, system, q, t=0.0):
        """``A(q, t)`` ``(..., m, nv)``."""
        raise NotImplementedError

    def velocity_bias(self, system, q, t=0.0):
        """``b(q, t)`` ``(..., m)`` in ``A v + b = 0`` (zero for scleronomic constraints)."""
        return np.zeros(np.shape(q)[:-1] + (self.rows(system),))

    def acceleration_rhs(self, system, q, v, t=0.0):
        """``γ(q, v, t)`` ``(..., m)`` in ``A a = γ``: ``γ = −(d/dt)(A v + b)`` at ``a = 0``."""
        raise NotImplementedError

    def evaluate(self, system, q, v, t=0.0):
        """``(A, b, γ)`` at one state; built-in constraints share one kinematics pass between them."""
        return self.jacobian(system, q, t), self.velocity_bias(system, q, t), self.acceleration_rhs(system, q, v, t)

    def velocity_level(self, system, q, t=0.0):
        """``(A, b)`` of ``A v + b = 0`` at one configuration."""
        return self.jacobian(system, q, t), self.velocity_bias(system, q, t)

    def position_and_velocity_level(self, system, q, t=0.0):
        """``(φ, A, b)``: ``φ`` ``(..., m)`` is zero in the rows without a position level (see
        :meth:`position_rows`). What a residual check needs; built-in constraints share one kinematics pass."""
        mask = np.asarray(self.position_rows(system), dtype=bool)
        phi = self.position(system, q, t) if mask.any() else np.zeros(np.shape(q)[:-1] + (mask.size,))
        return (phi * mask, *self.velocity_level(system, q, t))

    def branch_error(self, system, q):
        """Why ``q (..., nq)`` lies on a wrong branch of the position rows, a configuration where ``φ`` can vanish
        away from the pose the constraint stands for, or ``None`` (always here: rows without such zeros).
        A :class:`~multibody.constrained.ConstrainedSystem` raises
        :class:`~multibody.constrained.ConstraintError` with it after each projection and where it reports
        ``φ`` (``position_error``, ``residual``); :class:`LoopClosure` gives one for its orientation rows."""
        return None

    def body_forces(self, system, q, lam, t=0.0):
        """Spatial forces the constraint exerts on the bodies for multipliers ``lam (m,)``.

        Returned in the ``f_ext`` layout of :func:`multibody.inverse_dynamics`: ``(njoints, 6)``,
        each body's force in its joint frame, so that ``Σ Jᵀ f = Aᵀ λ``. Only constraints that act
        through body points define it.
        """
        raise TypeError(f"{self.name} acts on generalized coordinates, not through body points: "
                        "it has no body forces (its generalized force is Aᵀ λ)")

    def program_entry(self, model, frame_index):
        """``(kind, parameters, frame a, frame b)`` of this constraint's compiled rows
        (:mod:`multibody.kernels.constraints`), or ``None`` when it has none and is evaluated here, in
        Python. ``frame_index(body, placement)`` gives a frame's index among the system's frames."""
        return None

    def __repr__(self):
        return f"{type(self).__name__}({self.name!r})"


def constraint_program(model, constraints, frames, baumgarte=(0.0, 0.0), rank_tolerance=0.0):
    """The program of ``constraints`` for :mod:`multibody.kernels.constraints` (its layout is there): each
    constraint's :meth:`~Constraint.program_entry`, its rows numbered in order, its frames indexed in
    ``frames`` (``(body, placement)`` pairs, matched by body and pose). ``None`` when a constraint has no
    compiled rows."""
    keys = [frame_key(model, *frame) for frame in frames]
    entries = [c.program_entry(model, lambda body, placement: keys.index(frame_key(model, body, placement)))
               for c in constraints]
    if any(entry is None for entry in entries):
        return None
    rows = [c.rows(model) for c in constraints]
    program = np.zeros(compiled.HEADER + compiled.STRIDE * len(entries))
    program[: compiled.HEADER] = (len(entries), sum(rows), *baumgarte, rank_tolerance)
    first_row = 0
    for k, ((kind, parameters, frame_a, frame_b), m) in enumerate(zip(entries, rows)):
        start = compiled.HEADER + k * compiled.STRIDE
        program[start : start + compiled.PARAMETERS] = (kind, first_row, m, frame_a, frame_b)
        program[start + compiled.PARAMETERS : start + compiled.PARAMETERS + len(parameters)] = parameters
        first_row += m
    return program


def frame_key(model, body, placement):
    """A frame as ``(body index or None, pose bytes)``: equal for the same frame given by other objects."""
    b, X_BF = kinematics.frame_arguments(model, body, placement)
    return b, X_BF.tobytes()


class CompiledRows(Constraint):
    """A built-in constraint whose rows are compiled (:mod:`multibody.kernels.constraints`): ``φ``, ``A`` and
    ``γ`` come from one kernel, for one state or a batch, and a constrained step evaluates them inside
    its compiled pass (:mod:`multibody.kernels.kkt`). Subclasses give :meth:`program_entry` and the
    message for a configuration where the rows have no defined direction. ``b = 0``: the surfaces
    and frames are fixed."""

    batched = True
    undefined = "its rows are undefined at this configuration"

    #: whether the rows also need Python terms (a user function of time: ``b`` and its rate in ``γ``), so
    #: that a constrained step cannot run them compiled
    moving = False

    def _levels(self, system, q, v, t):
        """``(A (..., m, nv), b (..., m), γ (..., m), φ (..., m))`` at ``(q, v, t)`` (``v`` ``None``: zero)."""
        model = require_model(system, self)
        m, nv = self.rows(model), model.nv
        program, rows = self._program_on(model)
        columns, workspace = compiled.levels_columns(nv, m), compiled.workspace_size(model.njoints, nv, len(rows))
        q = model.check_configuration(q)
        v = None if v is None else model.check_velocity(v)
        batch = q.shape[:-1] if v is None else spatial.batch_shape(q.shape[:-1], v.shape[:-1])
        out = driver.evaluate(compiled.constraint_levels, model.tree, (q, v, None, program), (1, columns), batch, rows,
                              workspace)[..., 0, :]
        if (out[..., -1] == compiled.UNDEFINED).any():
            raise ValueError(f"{self.name}: {self.undefined}")
        gamma = out[..., m * nv : m * nv + m]
        return out[..., : m * nv].reshape(batch + (m, nv)), np.zeros(gamma.shape), gamma, out[..., m * nv + m : -1]

    def _program_on(self, model):
        """``(program, frame rows)`` of these rows on ``model`` (:func:`constraint_program`,
        :func:`~multibody.tree.frame_rows`). Both depend on the model and the constraint's own parameters
        only, so they are kept for the last model seen: an integrator evaluates the rows a few times per
        step, and building them costs more than the compiled rows themselves."""
        kept = self.__dict__.get("_kept_program")
        if kept is None or kept[0] is not model:
            frames = self.body_frames
            kept = (model, constraint_program(model, [self], frames),
                    frame_rows(model, [kinematics.frame_arguments(model, *frame) for frame in frames]))
            self._kept_program = kept
        return kept[1], kept[2]

    def position(self, system, q, t=0.0):
        return self._levels(system, q, None, t)[3]

    def jacobian(self, system, q, t=0.0):
        return self._levels(system, q, None, t)[0]

    def velocity_bias(self, system, q, t=0.0):
        return self._levels(system, q, None, t)[1]

    def acceleration_rhs(self, system, q, v, t=0.0):
        return self._levels(system, q, v, t)[2]

    def evaluate(self, system, q, v, t=0.0):
        return self._levels(system, q, v, t)[:3]

    def velocity_level(self, system, q, t=0.0):
        return self._levels(system, q, None, t)[:2]

    def position_and_velocity_level(self, system, q, t=0.0):
        A, b, _, phi = self._levels(system, q, None, t)
        return phi, A, b



# ============================================================================= user constraints

class Holonomic(Constraint):
    """A user constraint ``φ(q, t) = 0`` (scleronomic or rheonomic).

    Args:
        phi: ``phi(q, t) -> (m,)``.
        jacobian: ``jacobian(q, t) -> (m, nv)``, the derivative with respect to ``v``
            (``∂φ/∂q`` when ``v = q̇``); numerical when omitted.
        name: label.
        dphi_dt: ``dphi_dt(q, t) -> (m,)``, the explicit time derivative ``∂φ/∂t``; numerical when
            omitted (exactly zero for a scleronomic ``phi``).
        gamma: ``gamma(q, v, t) -> (m,)``, the acceleration-level right-hand side
            ``γ = −(J̇ v + 2 ∂J/∂t v + ∂²φ/∂t²)``, i.e. ``−d²φ/dt²`` at ``a = 0``; numerical when omitted.
    """

    holonomic = True

    def __init__(self, phi, jacobian=None, name=None, *, dphi_dt=None, gamma=None):
        super().__init__(name or getattr(phi, "__name__", None))
        self.phi, self._jacobian, self._dphi_dt, self._gamma = phi, jacobian, dphi_dt, gamma

    def position(self, system, q, t=0.0):
        return np.atleast_1d(np.asarray(self.phi(q, t), dtype=float))

    def rows(self, system):
        return self.position(system, _neutral(system), 0.0).shape[-1]

    def jacobian(self, system, q, t=0.0):
        if self._jacobian is not None:
            return np.atleast_2d(np.asarray(self._jacobian(q, t), dtype=float))
        # Column k: dφ/dε along q ⊕ ε e_k.
        eye = np.eye(system.nv)
        columns = [first_derivative(lambda s, e=e: self.position(system, system.integrate(q, e, s), t)) for e in eye]
        return np.stack(columns, axis=-1)

    def velocity_bias(self, system, q, t=0.0):
        if self._dphi_dt is not None:
            return np.atleast_1d(np.asarray(self._dphi_dt(q, t), dtype=float))
        return first_derivative(lambda s: self.position(system, q, t + s))

    def acceleration_rhs(self, system, q, v, t=0.0):
        if self._gamma is not None:
            return np.atleast_1d(np.asarray(self._gamma(q, v, t), dtype=float))
        if self._jacobian is not None:
            # γ = −d/ds [J v + ∂φ/∂t] along the path with a = 0.
            return -first_derivative(_along_path(
                system, q, v, t, lambda qs, ts: self.jacobian(system, qs, ts) @ v + self.velocity_bias(system, qs, ts)),
                path_step(v, FIRST_STEP))
        # γ = −d²/ds² φ(q ⊕ v s, t + s)
        return -_second_derivative(_along_path(system, q, v, t, lambda qs, ts: self.position(system, qs, ts)),
                                   path_step(v, _SECOND_STEP))


class Pfaffian(Constraint):
    """A nonholonomic (velocity-level) constraint ``A(q, t) v + b(q, t) = 0``.

    Args:
        A: ``A(q, t) -> (m, nv)``.
        b: ``b(q, t) -> (m,)`` or ``None`` (scleronomic, ``b = 0``).
        name: label.
        gamma: ``gamma(q, v, t) -> (m,)``, ``γ = −(Ȧ v + ḃ)`` at ``a = 0``; numerical when omitted.
    """

    def __init__(self, A, b=None, name=None, *, gamma=None):
        super().__init__(name or getattr(A, "__name__", None))
        self._A, self._b, self._gamma = A, b, gamma

    def rows(self, system):
        return self.jacobian(system, _neutral(system), 0.0).shape[-2]

    def jacobian(self, system, q, t=0.0):
        return np.atleast_2d(np.asarray(self._A(q, t), dtype=float))

    def velocity_bias(self, system, q, t=0.0):
        if self._b is None:
            return np.zeros(self.rows(system))
        return np.atleast_1d(np.asarray(self._b(q, t), dtype=float))

    def acceleration_rhs(self, system, q, v, t=0.0):
        if self._gamma is not None:
            return np.atleast_1d(np.asarray(self._gamma(q, v, t), dtype=float))
        # γ = −d/ds [A v + b] along the path with a = 0.
        return -first_derivative(_along_path(
            system, q, v, t, lambda qs, ts: self.jacobian(system, qs, ts) @ v + self.velocity_bias(system, qs, ts)),
            path_step(v, FIRST_STEP))


def _neutral(system):
    return system.neutral() if hasattr(system, "neutral") else np.zeros(system.nq)


# ============================================================================= built-in holonomic constraints

def require_model(system, constraint):
    """The :class:`Model` behind ``system`` (a Model or its ``ModelSystem`` adapter)."""
    system = getattr(system, "model", system)
    if not isinstance(system, Model):
        raise TypeError(f"{constraint.name} refers to bodies, so it needs a multibody Model, got {type(system).__name__}")
    return system


def frame_terms(system, constraint, q, v, body, placement):
    """``(R_WF, p_WF, J, J̇v)`` of a frame fixed in ``body`` (``None``: the world); see ``frame_kinematics``.

    A system that already holds the frame's kinematics at this very state (``known_frame``: a
    constrained step computes its constraints' :attr:`Constraint.body_frames` together with ``M``
    and ``h``) gives them; ``v`` ``None`` stands for zero.
    """
    known = getattr(system, "known_frame", None)
    value = None if known is None else known(q, v, body, placement)
    if value is not None:
        return value
    model = require_model(system, constraint)
    v = np.zeros(np.shape(q)[:-1] + (model.nv,)) if v is None else v
    return kinematics.frame_kinematics(model, q, v, body, placement)


def wrenches_of_loads(model, q, loads):
    """``f_ext (njoints, 6)`` from world-frame loads ``(body, force (3,), application point (3,), moment (3,))``."""
    R_WJ, p_WJ = kinematics.joint_world_poses(model, q)
    f_ext = np.zeros((model.njoints, 6))
    for body, force, point, moment in loads:
        if body is None:
            continue  # the world takes it
        joint = model.body_joints[model.body_index(body)]
        if joint < 0:
            continue
        # World Plücker force at the origin: [f; p × f + n], then into the joint frame.
        world = np.concatenate([force, spatial.cross(point, force) + moment])
        f_ext[joint] += spatial.inverse_transform_force(R_WJ[joint], p_WJ[joint], world)
    return f_ext


def point_placement(point):
    """The 4×4 placement in its body of a frame at ``point (3,)`` (m, body frame; ``None``: the origin), with the
    body's axes; ``ValueError`` for another shape."""
    placement = np.eye(4)
    if point is not None:
        point = np.asarray(point, dtype=float)
        if point.shape != (3,):
            raise ValueError(f"point must have shape (3,), got {point.shape}")
        placement[:3, 3] = point
    return placement


def _placement(frame):
    if frame is None:
        return np.eye(4)
    frame = np.asarray(frame, dtype=float)
    if frame.shape != (4, 4):
        raise ValueError(f"frame must be a 4x4 pose, got shape {frame.shape}")
    return frame


def _plane_normal(normal):
    """``normal`` as a unit ``(3,)`` vector whose largest component is positive (a plane's normal has no sign;
    this choice changes only where two components tie, away from the axes that normals are usually
    along), or ``ValueError``."""
    n = np.asarray(normal, dtype=float)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or not np.linalg.norm(n) > 0.0:
        raise ValueError(f"normal must be a non-zero, finite 3-vector, got {normal!r}")
    n = n / np.linalg.norm(n)
    return -n if n[np.argmax(np.abs(n))] < 0.0 else n


def _turn_z_to(n):
    """The smallest rotation ``R (3, 3)`` with ``R e_z = n`` for a unit ``n`` of :func:`_plane_normal` (so that
    ``n_z ≥ −1/√2``; Rodrigues: ``I + [k]× + [k]×² / (1 + n_z)`` with ``k = e_z × n``)."""
    k = spatial.skew(np.array([-n[1], n[0], 0.0]))
    return np.eye(3) + k + k @ k / (1.0 + n[2])


def _describe_joint(model, j, columns):
    """``'name' (kind about/along [axis])`` of joint ``j`` for a message; ``columns``: its motion subspace's
    ``(linear, angular)`` parts in world axes, ``(2, 3, k)``."""
    kind = model.joints[j].kind
    linear, angular = columns
    if kind in ("revolute", "continuous"):
        kind += f" about {np.round(angular[:, 0], 3).tolist()}"
    elif kind == "prismatic":
        kind += f" along {np.round(linear[:, 0], 3).tolist()}"
    elif kind == "planar":
        kind += f" about {np.round(angular[:, 2], 3).tolist()}"
    return f"{model.joint_names[j]!r} ({kind})"


class OnBody(Constraint):
    """A constraint on the frame at ``point`` (m, body frame; ``None``: the origin) of ``body`` (its
    :attr:`body_frames`), with the loads it applies there."""

    def __init__(self, body, point, name):
        super().__init__(name)
        self.body, self.placement = body, point_placement(point)

    @property
    def body_frames(self):
        return ((self.body, self.placement),)

    def _load(self, system, q, force, point):
        """``f_ext (njoints, 6)`` of ``force (3,)`` (N, world axes) applied to the body at the world ``point (3,)``
        (m): :meth:`Constraint.body_forces`' layout."""
        return wrenches_of_loads(require_model(system, self), q, [(self.body, force, point, np.zeros(3))])


class PointOnCurve(OnBody):
    """A body point stays on a fixed parametric curve ``r(s)`` (a bead on a wire).

    Position level: ``φ = P(s*) (x − r(s*))`` with ``s*`` the curve parameter closest to the point
    ``x`` and ``P = I − t tᵀ`` the projector normal to the unit tangent ``t``. The three rows have
    rank 2, so the minimum-norm multipliers ``λ`` (3,) are the **normal force** the wire exerts on
    the bead, in world axes (N).

    Args:
        body: body name or index.
        curve: ``curve(s) -> (..., 3)``, vectorised over an array of parameters ``s``.
        point: the point in body coordinates (default the body origin).
        s_range: ``(s_min, s_max)`` parameter interval searched for the closest point.
        samples: number of samples of the coarse search before Newton's refinement.
        derivative, second_derivative: ``r'(s)``, ``r''(s)`` (vectorised); numerical when omitted.
    """

    holonomic = True

    def __init__(self, body, curve, *, point=None, s_range=(0.0, 1.0), samples=2001, derivative=None,
                 second_derivative=None, name=None):
        super().__init__(body, point, name or f"point of {body} on curve")
        self.curve = curve
        self.s_grid = np.linspace(float(s_range[0]), float(s_range[1]), int(samples))
        self._d1 = derivative or (lambda s: first_derivative(lambda h: curve(s + h)))
        self._d2 = second_derivative or (lambda s: _second_derivative(lambda h: curve(s + h)))

    def rows(self, system):
        return 3

    def independent_rows(self, system):
        return 2  # the projector normal to the tangent

    def closest_parameter(self, x):
        """Curve parameter ``s*`` of the point of the curve closest to ``x (..., 3)``: ``(...)``."""
        x = np.asarray(x, dtype=float)
        grid_points = self.curve(self.s_grid)  # (n, 3)
        distances = np.sum((x[..., None, :] - grid_points) ** 2, axis=-1)
        s = self.s_grid[np.argmin(distances, axis=-1)]
        # Newton on g(s) = r'(s)·(x − r(s)) = 0, g'(s) = r''·(x − r) − |r'|².
        for _ in range(50):
            d1, d2, gap = self._d1(s), self._d2(s), x - self.curve(s)
            g = np.sum(d1 * gap, axis=-1)
            dg = np.sum(d2 * gap, axis=-1) - np.sum(d1 * d1, axis=-1)
            step = np.where(dg < 0.0, g / np.where(dg < 0.0, dg, -1.0), 0.0)
            s = s - step
            if np.all(np.abs(step) <= 1e-15 * (1.0 + np.abs(s))):
                break
        low, high = self.s_grid[0], self.s_grid[-1]
        if np.any((s < low) | (s > high)):
            raise ValueError(f"{self.name}: the closest point of the curve lies outside s_range = ({low:g}, {high:g}) "
                             "(the point has left the curve's parameter range); widen s_range")
        return s

    def _geometry(self, x):
        s = self.closest_parameter(x)
        d1 = self._d1(s)
        tangent = d1 / np.linalg.norm(d1, axis=-1, keepdims=True)
        projector = np.eye(3) - tangent[..., :, None] * tangent[..., None, :]
        return s, d1, tangent, projector

    def position(self, system, q, t=0.0):
        (_, x, _, _), = self._frame_terms(system, q)
        s, _, _, projector = self._geometry(x)
        return matvec(projector, x - self.curve(s))

    def body_forces(self, system, q, lam, t=0.0):
        (_, x, _, _), = self._frame_terms(system, q)
        # Aᵀλ = Jᵀ P λ: the force P λ at the bead
        return self._load(system, q, self._geometry(x)[3] @ lam, x)

    def jacobian(self, system, q, t=0.0):
        (_, x, J, _), = self._frame_terms(system, q)
        return self._geometry(x)[3] @ J[..., :3, :]

    def acceleration_rhs(self, system, q, v, t=0.0):
        return self.evaluate(system, q, v, t)[2]

    def evaluate(self, system, q, v, t=0.0):
        (_, x, J, J_dot_v), = self._frame_terms(system, q, v)
        s, d1, tangent, projector = self._geometry(x)
        x_dot = matvec(J[..., :3, :], v)
        # ṫ = P r'' ṡ / |r'| with ṡ = r'·ẋ / |r'|²;  Ṗ ẋ = −ṫ (t·ẋ) − t (ṫ·ẋ)
        speed2 = np.sum(d1 * d1, axis=-1, keepdims=True)
        s_dot = np.sum(d1 * x_dot, axis=-1, keepdims=True) / speed2
        t_dot = matvec(projector, self._d2(s)) * s_dot / np.sqrt(speed2)
        P_dot_x_dot = -t_dot * np.sum(tangent * x_dot, axis=-1, keepdims=True) \
            - tangent * np.sum(t_dot * x_dot, axis=-1, keepdims=True)
        # γ = −P (Ṗ ẋ + J̇v): the rows P J are orthogonal to t, so only γ's normal part can be met
        # (its tangential part vanishes on the velocity manifold anyway).
        gamma = -matvec(projector, P_dot_x_dot + J_dot_v[..., :3])
        return projector @ J[..., :3, :], np.zeros_like(gamma), gamma


class PointOnSurface(OnBody):
    """A body point stays on a fixed implicit surface ``f(x) = 0``.

    One row, ``φ = f(x)``; with a unit-gradient ``f`` (a signed distance) the multiplier is the
    normal force (N) along ``∇f``.

    Args:
        body: body name or index.
        surface: ``f(x) -> (...)`` for points ``x (..., 3)``.
        point: the point in body coordinates (default the body origin).
        gradient: ``∇f(x) -> (..., 3)``; hessian: ``∇²f(x) -> (..., 3, 3)``; numerical when omitted.
    """

    holonomic = True

    def __init__(self, body, surface, *, point=None, gradient=None, hessian=None, name=None):
        super().__init__(body, point, name or f"point of {body} on surface")
        self.surface = surface
        eye = np.eye(3)
        self._gradient = gradient or (lambda x: np.stack(
            [first_derivative(lambda h, e=e: surface(x + h * e)) for e in eye], axis=-1))
        self._hessian = hessian or (lambda x: np.stack(
            [first_derivative(lambda h, e=e: self._gradient(x + h * e)) for e in eye], axis=-1))

    def rows(self, system):
        return 1

    def position(self, system, q, t=0.0):
        (_, x, _, _), = self._frame_terms(system, q)
        return np.asarray(self.surface(x), dtype=float)[..., None]

    def body_forces(self, system, q, lam, t=0.0):
        (_, x, _, _), = self._frame_terms(system, q)
        # Aᵀλ = Jᵀ ∇f λ: the force ∇f λ at the point
        return self._load(system, q, self._gradient(x) * lam[0], x)

    def jacobian(self, system, q, t=0.0):
        (_, x, J, _), = self._frame_terms(system, q)
        return matvec(transpose(J[..., :3, :]), self._gradient(x))[..., None, :]

    def acceleration_rhs(self, system, q, v, t=0.0):
        return self.evaluate(system, q, v, t)[2]

    def evaluate(self, system, q, v, t=0.0):
        (_, x, J, J_dot_v), = self._frame_terms(system, q, v)
        gradient = self._gradient(x)
        x_dot = matvec(J[..., :3, :], v)
        # γ = −(ẋᵀ ∇²f ẋ + ∇f · J̇v)
        curvature = np.einsum("...i,...ij,...j->...", x_dot, self._hessian(x), x_dot)
        gamma = -(curvature + np.sum(gradient * J_dot_v[..., :3], axis=-1))[..., None]
        return matvec(transpose(J[..., :3, :]), gradient)[..., None, :], np.zeros_like(gamma), gamma


class Distance(CompiledRows):
    """Two points (on bodies, or fixed in the world) stay a given distance apart: a massless rod.

    One row, ``φ = d − |x_a − x_b|``; the multiplier is the rod's **tension** (N, positive when it
    pulls the points together).

    Args:
        body_a, body_b: body names or indices, ``None`` for the world.
        distance: ``d`` (m).
        point_a, point_b: points in the bodies' frames (world coordinates for ``None``).
    """

    holonomic = True
    undefined = "the two points coincide, so the rod has no direction"

    def __init__(self, body_a, body_b, distance, *, point_a=None, point_b=None, name=None):
        super().__init__(name or f"distance {body_a}-{body_b}")
        if not distance > 0.0:
            raise ValueError(f"distance must be positive, got {distance!r}")
        self.body_a, self.body_b, self.distance = body_a, body_b, float(distance)
        self.placement_a, self.placement_b = point_placement(point_a), point_placement(point_b)

    def rows(self, system):
        return 1

    @property
    def body_frames(self):
        return ((self.body_a, self.placement_a), (self.body_b, self.placement_b))

    def program_entry(self, model, frame_index):
        return compiled.DISTANCE, [self.distance], *(frame_index(*frame) for frame in self.body_frames)

    def body_forces(self, system, q, lam, t=0.0):
        (_, x_a, _, _), (_, x_b, _, _) = self._frame_terms(system, q)
        u = (x_a - x_b) / np.linalg.norm(x_a - x_b)
        # Aᵀλ = J_aᵀ(−u λ) + J_bᵀ(u λ): the rod pulls a towards b and b towards a
        zero = np.zeros(3)
        return wrenches_of_loads(require_model(system, self), q,
                         [(self.body_a, -u * lam[0], x_a, zero), (self.body_b, u * lam[0], x_b, zero)])


class LoopClosure(CompiledRows):
    """Closes a kinematic loop between frame A (fixed in ``body_a``) and frame B (in ``body_b``).

    Position rows: the position of B's origin relative to A's, expressed in frame A,
    ``r = R_WAᵀ (p_B − p_A)``, keeping the components along ``position_axes`` of A.
    Orientation rows: for each pair ``(i, j)`` in ``aligned_axes``, ``e_i^A · e_j^B = 0`` (axis i of A
    perpendicular to axis j of B).

    ``kind`` chooses both:

    ===========  ==========================  ==========================================  ====
    kind         position axes of A          perpendicular axis pairs (A, B)             rows
    ===========  ==========================  ==========================================  ====
    "point"      x, y, z                     —                                           3
    "planar"     two axes of the loop's      —                                           2
                 plane (below)
    "revolute"   x, y, z                     (x, z), (y, z): B's z stays along A's z     5
    "weld"       x, y, z                     (y, z), (z, x), (x, y): axes stay aligned   6
    ===========  ==========================  ==========================================  ====

    The plane of ``"planar"`` is normal to ``normal`` (frame A's axes) when given. Otherwise it is inferred
    from the model where the constraint meets it (:meth:`bind`, at a ConstrainedSystem's construction): the
    loop's joints, those on the paths from both bodies to their common ancestor, must all turn about one
    axis (revolute, continuous and planar joints, axes parallel) and slide across it (prismatic, planar),
    and the plane is normal to that axis; otherwise ``ValueError`` names the loop's joints and asks for
    ``normal``. The two position rows are along frame A's x and y axes turned by
    the smallest rotation that takes A's z axis to the normal (of the normal's two signs, the one whose
    largest component is positive): A's own x and y when its z is the normal. :meth:`position_directions`
    gives them.

    The multipliers of the position rows are the reaction force on body B at B's origin, along those
    axes of frame A (N); those of the orientation rows are the moments (N m) about ``e_i^A × e_j^B``.

    The orientation rows vanish at other relative rotations ``R = R_WAᵀ R_WB`` too. The weld's hold every ``R``
    with zeros at (y, z), (z, x), (x, y): besides ``I``, the half turns about an axis of A (``diag(1, −1, −1)``
    and its permutations) and the 120° turns about (1, 1, 1), (1, −1, −1), (−1, 1, −1) and (−1, −1, 1) in
    A's axes (B's axes the cyclic permutation x → y → z → x of A's, with signs). The revolute's hold B's z
    along A's z or against it. No three smooth rows on SO(3) vanish at ``I`` alone (the local degrees of a map from a
    closed 3-manifold to R³ sum to zero), so these other zeros are detected rather than removed:
    :meth:`branch_error` checks that the paired axes point the same way, ``e_k^A · e_k^B > BRANCH_COSINE``
    for k = x, y, z (weld) or for z (revolute); on the closed pose's branch these cosines are 1 to first
    order, on the other zeros −1 or 0. A :class:`~multibody.constrained.ConstrainedSystem` raises
    :class:`~multibody.constrained.ConstraintError` where they fail, after a projection (``project``,
    ``simulate``'s initial state) and in ``position_error`` and ``residual``: a projection started far from
    the closed pose can settle on another zero, where ``φ = 0``.

    Args:
        body_a, body_b: body names or indices (``None``: the world).
        frame_a, frame_b: 4×4 poses of A and B in their bodies (world poses for ``None``).
        kind: one of the table's.
        normal: ``(3,)`` the normal of the loop's plane in frame A's axes (``kind="planar"`` only); ``None``
            infers it.
    """

    holonomic = True
    KINDS = {
        "point": ((0, 1, 2), ()),
        "planar": ((0, 1), ()),
        "revolute": ((0, 1, 2), ((0, 2), (1, 2))),
        "weld": ((0, 1, 2), ((1, 2), (2, 0), (0, 1))),
    }

    #: Largest sine of the angle between axes counted as parallel (and cosine counted as perpendicular)
    #: when the plane is inferred: URDF axes and rotations are exact to rounding.
    PARALLEL_TOLERANCE = 1e-9

    #: Smallest cosine ``e_k^A · e_k^B`` between paired axes on the closed pose's branch (:meth:`branch_error`).
    #: The rows' other zeros have cosines of −1 or 0, the latter only to the rows' tolerance (of either sign),
    #: so the threshold sits between 0 and 1: 1/2 passes any state within 60° of the closed pose.
    BRANCH_COSINE = 0.5

    #: The axes whose cosines :meth:`branch_error` checks, for each kind with orientation rows (z; x, y, z).
    BRANCH_AXES = {"revolute": slice(2, 3), "weld": slice(0, 3)}

    def __init__(self, body_a, body_b, *, frame_a=None, frame_b=None, kind="point", normal=None, name=None):
        super().__init__(name or f"{kind} loop closure {body_a}-{body_b}")
        if kind not in self.KINDS:
            raise ValueError(f"kind must be one of {sorted(self.KINDS)}, got {kind!r}")
        if normal is not None and kind != "planar":
            raise ValueError(f"normal gives the plane of kind='planar'; it does not apply to kind={kind!r}")
        self.body_a, self.body_b, self.kind = body_a, body_b, kind
        self.frame_a, self.frame_b = _placement(frame_a), _placement(frame_b)
        self.position_axes, self.aligned_axes = self.KINDS[kind]
        self.normal = None if normal is None else _plane_normal(normal)
        # The rows' frame A: frame_a turned so that its x–y plane is the loop's plane.
        self._turn, self._rows_frame_a = np.eye(3), self.frame_a
        if self.normal is not None:
            self._turn = _turn_z_to(self.normal)
            self._rows_frame_a = self.frame_a.copy()
            self._rows_frame_a[:3, :3] = self.frame_a[:3, :3] @ self._turn

    @property
    def _plane_unknown(self):
        """Whether this is a planar closure whose plane the model has yet to give (see :meth:`bind`)."""
        return self.kind == "planar" and self.normal is None

    def rows(self, system):
        return len(self.position_axes) + len(self.aligned_axes)

    @property
    def body_frames(self):
        return ((self.body_a, self._rows_frame_a), (self.body_b, self.frame_b))

    def bind(self, system):
        """Checks the bodies (:meth:`Constraint.bind`); a planar closure without ``normal`` returns a copy
        with the normal inferred from ``system``'s model (see the class docstring), kept for the last model
        seen."""
        super().bind(system)
        if not self._plane_unknown:
            return self
        model = require_model(system, self)
        kept = self.__dict__.get("_kept_binding")
        if kept is None or kept[0] is not model:
            kept = (model, LoopClosure(self.body_a, self.body_b, frame_a=self.frame_a, frame_b=self.frame_b,
                                       kind=self.kind, normal=self._inferred_normal(model), name=self.name))
            self._kept_binding = kept
        return kept[1]

    def _inferred_normal(self, model):
        """The normal of the loop's plane in frame A's axes, from the joints of the loop at the model's
        neutral configuration (the class docstring says which loops have one), or ``ValueError``."""
        ask = "give the plane's normal in frame A's axes: LoopClosure(..., kind='planar', normal=(nx, ny, nz))"
        where = [None if body is None else int(model.body_joints[model.body_index(body)])
                 for body in (self.body_a, self.body_b)]
        support = [model.ancestors[j] if j is not None and j >= 0 else np.zeros(model.njoints, dtype=bool)
                   for j in where]
        loop = np.flatnonzero(support[0] ^ support[1])
        if not loop.size:
            raise ValueError(f"{self.name}: cannot infer the plane of kind='planar': no joint moves frame B "
                             f"relative to frame A; {ask}")
        q = model.neutral()
        R_WJ, _ = kinematics.joint_world_poses(model, q)
        # each joint's motion subspace columns [linear; angular] in world axes
        columns = {j: R_WJ[j] @ np.reshape(model.joints[j].motion_subspace, (2, 3, -1)) for j in loop}
        turning = [w for j in loop for w in columns[j][1].T if np.linalg.norm(w) > 0.0]
        n = turning[0] / np.linalg.norm(turning[0]) if turning else None
        tolerance = self.PARALLEL_TOLERANCE

        def planar(j):
            linear, angular = columns[j]
            return all(np.linalg.norm(np.cross(w, n)) <= tolerance * np.linalg.norm(w) for w in angular.T) and \
                all(abs(u @ n) <= tolerance * np.linalg.norm(u) for u in linear.T)

        if n is None or not all(planar(j) for j in loop):
            joints = ", ".join(_describe_joint(model, j, columns[j]) for j in loop)
            problem = "only slide: none turns about an axis normal to a plane" if n is None else \
                "do not all turn about one axis and slide across it"
            raise ValueError(f"{self.name}: cannot infer the plane of kind='planar': the loop's joints ({joints}; "
                             f"world axes at the neutral configuration) {problem}; {ask}")
        R_WA = self.frame_a[:3, :3]
        if self.body_a is not None:
            R_WA = kinematics.forward_kinematics(model, q)[model.body_index(self.body_a), :3, :3] @ R_WA
        return R_WA.T @ n

    def position_directions(self, system=None):
        """``(k, 3)``: the directions of the position rows in frame A's axes, along which their multipliers
        act: frame A's axes, or for ``"planar"`` the two axes of the plane (the class docstring). ``system``
        is needed only by a planar closure whose plane is inferred."""
        if self._plane_unknown:
            return self.bind(system).position_directions()
        return self._turn[:, list(self.position_axes)].T

    def _levels(self, system, q, v, t):
        if self._plane_unknown:
            return self.bind(system)._levels(system, q, v, t)
        return super()._levels(system, q, v, t)

    def branch_error(self, system, q):
        """Where frame B's axes point away from frame A's at ``q (..., nq)``, on another zero of the orientation
        rows (the class docstring): the message naming the axis, the angle and the turn between the frames
        (for a batch, of the state with the smallest cosine); ``None`` on the closed pose's branch, for a
        kind without orientation rows, or where ``q`` is not finite."""
        axes = self.BRANCH_AXES.get(self.kind)
        if axes is None:
            return None
        model = require_model(system, self)
        q = model.check_configuration(q)
        # World placements (..., 2, 4, 4) of frames A and B: one compiled pass for both.
        X = kinematics.frame_world_placements(model, q, self._program_on(model)[1], q.shape[:-1])
        # e_k^A · e_k^B: the sum over world axes of the products of the columns k of R_WA and R_WB
        cosines = (X[..., 0, :3, axes] * X[..., 1, :3, axes]).sum(axis=-2)
        wrong = cosines <= self.BRANCH_COSINE  # (NaN states compare False: they have no branch)
        if not wrong.any():
            return None
        worst = np.unravel_index(np.argmin(np.where(wrong, cosines, np.inf)), cosines.shape)
        state = worst[:-1]
        cosine, name = float(cosines[worst]), "xyz"[axes.start + worst[-1]]
        where = f"at state {tuple(int(i) for i in state) if len(state) > 1 else int(state[0])}: " if state else ""
        if self.kind == "revolute":
            found = (f"frame B's z axis is {np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))):.1f}° from frame A's "
                     f"(e_z^A · e_z^B = {cosine:.3g}); the orientation rows also vanish with the z axes antiparallel")
        else:
            turn = spatial.so3_log(X[state][0, :3, :3].T @ X[state][1, :3, :3])
            angle = float(np.linalg.norm(turn))
            # (+ 0.0 turns a rounded −0.0 into 0.0)
            about = (np.round(turn / angle, 3) + 0.0).tolist() if angle > 0.0 else [0.0, 0.0, 1.0]
            found = (f"frame B is turned {np.degrees(angle):.1f}° from frame A about {about} (frame A's axes), its "
                     f"{name} axis at e_{name}^A · e_{name}^B = {cosine:.3g}; the orientation rows also vanish at "
                     "half turns about an axis of A and at 120° turns about four diagonals of its axes")
        held = "e_z^A · e_z^B" if self.kind == "revolute" else "each e_k^A · e_k^B"
        return (f"{where}{found}, away from the closed pose; start the projection nearer the closed pose "
                f"({held} > {self.BRANCH_COSINE:g})")

    def program_entry(self, model, frame_index):
        axes = list(self.position_axes) + [0] * (3 - len(self.position_axes))
        pairs = [index for pair in self.aligned_axes for index in pair]
        parameters = [len(self.position_axes), *axes, len(self.aligned_axes), *pairs, *[0] * (6 - len(pairs))]
        return compiled.LOOP_CLOSURE, parameters, *(frame_index(*frame) for frame in self.body_frames)

    def body_forces(self, system, q, lam, t=0.0):
        if self._plane_unknown:
            return self.bind(system).body_forces(system, q, lam, t)
        (R_a, _, _, _), (R_b, p_b, _, _) = self._frame_terms(system, q)
        k = len(self.position_axes)
        # Position rows: the force R_a Sᵀ λ on B at p_B, and its opposite on A at the same point.
        force = R_a[:, list(self.position_axes)] @ lam[:k]
        # Orientation rows: the moment Σ (e_i × f_j) λ on A, and its opposite on B.
        moment = sum((spatial.cross(R_a[:, i], R_b[:, j]) * lam[k + r] for r, (i, j) in enumerate(self.aligned_axes)),
                     np.zeros(3))
        return wrenches_of_loads(require_model(system, self), q,
                         [(self.body_b, force, p_b, -moment), (self.body_a, -force, p_b, moment)])


class JointCoupling(CompiledRows):
    """Two one-coordinate joints geared together: ``q_b = ratio · q_a + offset`` (a URDF mimic), or by a
    polynomial of degree up to 4, ``q_b = Σₖ cₖ (q_a − reference)ᵏ`` (``coefficients = (c₀, …, c₄)``:
    MuJoCo's joint equality, ``q₁ − q₁,ref = Σₖ cₖ (q₂ − q₂,ref)ᵏ``, has ``joint_b = q₁``,
    ``reference = q₂,ref`` and ``c₀`` raised by ``q₁,ref``). With ``joint_a=None``, joint b is held at
    ``offset`` (or ``c₀``).

    One row, ``φ = q_b − p(q_a − reference)`` with ``p(x) = Σₖ cₖ xᵏ``; the multiplier is the coupling
    torque (or force) on joint b, with ``−p′`` times it on joint a. The row is ``e_b − p′ e_a`` and
    ``γ = p″ v_a²`` (the derivative of ``v_b − p′ v_a`` at ``a = 0``).

    Args:
        joint_a, joint_b: joint names or indices (joint a may be ``None``); each must have one coordinate.
        ratio, offset: ``p(x) = offset + ratio x`` (with ``reference`` 0 unless given).
        coefficients: ``(c₀, …, c₄)``, up to five numbers (missing ones zero), instead of ``ratio`` and
            ``offset``.
        reference: the value of ``q_a`` where ``x = 0`` (rad or m).
    """

    holonomic = True
    DEGREE = 4

    def __init__(self, joint_a, joint_b, ratio=1.0, offset=0.0, name=None, *, coefficients=None, reference=0.0):
        super().__init__(name or f"coupling {joint_a}-{joint_b}")
        if coefficients is None:
            coefficients = (offset, ratio)
        elif (ratio, offset) != (1.0, 0.0):
            raise ValueError(f"{self.name}: give ratio and offset, or coefficients, not both")
        values = np.zeros(self.DEGREE + 1)
        try:
            given = np.array(coefficients, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: coefficients must be numbers, got {coefficients!r}") from None
        if given.size > values.size or not np.all(np.isfinite(given)) or not np.isfinite(reference):
            raise ValueError(f"{self.name}: coefficients must be at most {values.size} finite numbers and the "
                             f"reference finite, got {coefficients!r} and {reference!r}")
        values[: given.size] = given
        if joint_a is None:
            # joint b alone: held at c₀
            values[1:] = 0.0
        self.joint_a, self.joint_b = joint_a, joint_b
        self.coefficients, self.reference = values, float(reference)
        self.coefficients.setflags(write=False)

    @property
    def ratio(self) -> float:
        """``c₁``, the gear ratio ``p′(0)`` (read from :attr:`coefficients`, the one copy the rows use)."""
        return float(self.coefficients[1])

    @property
    def offset(self) -> float:
        """``c₀``, joint b's position at ``q_a = reference`` (rad or m; from :attr:`coefficients`)."""
        return float(self.coefficients[0])

    def rows(self, system):
        return 1

    def bind(self, system):
        self._indices(system)
        return super().bind(system)

    def _indices(self, system):
        model = require_model(system, self)
        out = []
        for joint in (self.joint_a, self.joint_b):
            if joint is None:
                out.append((-1, -1))
                continue
            try:
                i = model.joint_index(joint)
            except ValueError as error:
                raise ValueError(f"{self.name}: {error}") from None
            if model.joints[i].nq != 1 or model.joints[i].nv != 1:
                raise ValueError(f"{self.name}: joint {model.joint_names[i]!r} must have one coordinate")
            out.append((model.idx_q[i], model.idx_v[i]))
        return out

    def program_entry(self, model, frame_index):
        (qa, va), (qb, vb) = self._indices(model)
        return compiled.JOINT_COUPLING, [qa, va, qb, vb, self.reference, *self.coefficients], 0, 0


def mimic_constraints(model):
    """One :class:`JointCoupling` per recorded URDF mimic relation of ``model``."""
    return [JointCoupling(m.mimicked, m.joint, m.multiplier, m.offset, name=f"mimic {m.joint}") for m in model.mimic]
