"""Contact and joint limits: unilateral constraints, simulated by velocity-level time stepping.

:class:`Ground`, :class:`ContactPair` and :class:`JointLimits` go in a
:class:`~multibody.constrained.ConstrainedSystem`'s list beside the bilateral constraints (they add no bilateral
rows). :func:`multibody.simulate` then takes Moreau–Jean steps of ``dt`` (:mod:`multibody.kernels.timestepping`,
where the equations are): contact detection at the step's start, one frictional contact problem with the bilateral
rows (:mod:`multibody.kernels.complementarity`), the new velocities, then the positions. Every step is compiled; a
batch of initial states runs each trajectory on its own on all cores.

The trajectory gains :attr:`~multibody.Trajectory.contacts` (each step's contact points, normals and forces, and the
joint limits' generalized forces) and :attr:`~multibody.Trajectory.complementarity` (each step's residual of its
contact problem, m/s).
"""

from __future__ import annotations

import math
import operator
import time
import warnings
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numba import prange, types

from . import driver
from .integrators import CONTROLLER_FUNCTION, control_rows, controller_function
from .driver import TREE_FLOATS, TREE_INTS
from .contact_problem import STATUS_MESSAGES
from .kernels import collision, stepping, timestepping
from .model import Model
from .runs import (FIRST_CHUNK, Progress, by_state, next_chunk, non_finite, projected_start,
                   warn_projected_starts)
from .trajectory import Contacts, Trajectory, recorded_names
from .tree import CompiledTree, frame_rows

#: The one time-stepping method of systems with unilateral constraints (``simulate(..., method=...)``).
METHOD = "Moreau-Jean"
#: Default tolerance of each step's contact problem (m/s): its residual (:mod:`multibody.kernels.complementarity`).
TOLERANCE = 1e-12
#: Default iterations of each step's solver.
MAX_ITERATIONS = 20000
#: Distance (m, or rad for a joint limit) within which a contact or limit enters a step beyond what its speed
#: can close in the step (its rows are inactive while it stays open).
MARGIN = 1e-3
#: Depth (m or rad) of a step's end penetration that its position correction removes (shallower is left alone).
PENETRATION = 1e-10
#: Rows (limits and contacts) of each output step's record at a run's start: a step with more widens every record
#: of the run to at least twice as many (at most the rows the system can have) and the run goes on from that step.
#: The step's workspaces are sized by the records' rows (:meth:`ContactProgram.workspaces`) and grow with them.
#: Four rows hold a box resting on a face or a quadruped on its feet; a batch's records are most of the memory its
#: steps write (4 rows: 352 bytes per step, beside a state's 8 (nq + nv) bytes).
RECORD_CAPACITY = 4


class Unilateral:
    """Base class of the unilateral constraints: contact and joint limits. They take part in a
    :class:`~multibody.constrained.ConstrainedSystem` without bilateral rows; :meth:`bind` checks one against the
    model and returns it as it applies there."""

    name = "Unilateral"

    def bind(self, system):
        raise NotImplementedError

    def __repr__(self):
        return self.name


def _coefficient(owner, name, value, upper=None):
    """``value`` as a finite float ≥ 0 (and ≤ ``upper``), or ``ValueError`` naming ``owner`` and ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be a number, got {value!r}") from None
    if not math.isfinite(number) or number < 0.0 or (upper is not None and number > upper):
        bounds = f"in [0, {upper:g}]" if upper is not None else ">= 0"
        raise ValueError(f"{owner}: {name} must be {bounds}, got {value!r}")
    return number


def _model_of(system, owner):
    model = getattr(system, "model", system)
    if not isinstance(model, Model):
        raise TypeError(f"{owner} needs a multibody Model (bodies and their collision geometry), got "
                        f"{type(model).__name__}")
    return model


def _body(model, owner, body):
    """The body name of ``body`` (a name or an index) in ``model``, or ``ValueError`` naming ``owner`` and the close
    matches."""
    try:
        return model.body_names[model.body_index(body)]
    except ValueError as error:
        raise ValueError(f"{owner}: {error}") from None


def _geometries_of(model, owner, body):
    """The indices of ``body``'s collision geometries in :func:`multibody.geometry.collision_table`, or
    ``ValueError`` naming ``owner`` when it has none."""
    from .geometry import collision_table

    names = collision_table(model).names
    found = [g for g, name in enumerate(names) if name == body]
    if not found:
        with_geometry = sorted(set(names))
        raise ValueError(f"{owner}: body {body!r} has no collision geometry (bodies with one: "
                         f"{', '.join(map(repr, with_geometry)) if with_geometry else 'none'})")
    return found


class Ground(Unilateral):
    """The half-space ``normal · x ≥ height`` (world axes, m) against every collision geometry of ``bodies`` (names
    or indices; default ``None``: every body with one), with Coulomb friction ``friction`` (≥ 0) and Newton's
    restitution ``restitution`` (in [0, 1]).

    Raises ``ValueError`` naming the constraint for a friction below 0, a restitution outside [0, 1], a normal that
    is zero or not finite, a height that is not finite, and (when bound to a model) an unknown body (with the close
    matches) or a body without collision geometry."""

    def __init__(self, normal=(0.0, 0.0, 1.0), height=0.0, *, friction=0.5, restitution=0.0, bodies=None):
        self.name = "Ground"
        n = np.asarray(normal, dtype=float)
        if n.shape != (3,) or not np.isfinite(n).all() or not np.linalg.norm(n) > 0.0:
            raise ValueError(f"{self.name}: normal must be a non-zero, finite 3-vector, got {normal!r}")
        self.normal = n / np.linalg.norm(n)
        try:
            self.height = float(height)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: height must be a finite number (m), got {height!r}") from None
        if not math.isfinite(self.height):
            raise ValueError(f"{self.name}: height must be a finite number (m), got {height!r}")
        self.friction = _coefficient(self.name, "friction", friction)
        self.restitution = _coefficient(self.name, "restitution", restitution, 1.0)
        if isinstance(bodies, str | int | np.integer):
            bodies = [bodies]
        self.bodies = None if bodies is None else list(bodies)
        self.geometries = None

    def bind(self, system):
        """This ground with its geometries on ``system``'s model: ``geometries``, their indices in
        :func:`multibody.geometry.collision_table`."""
        from .geometry import collision_table

        model = _model_of(system, self.name)
        bound = _copy(self)
        if self.bodies is None:
            bound.geometries = list(range(len(collision_table(model).names)))
        else:
            bound.geometries = [g for body in self.bodies
                                for g in _geometries_of(model, self.name, _body(model, self.name, body))]
        return bound


class ContactPair(Unilateral):
    """The collision geometries of ``body_a`` against those of ``body_b`` (names or indices), with Coulomb friction
    ``friction`` (≥ 0) and Newton's restitution ``restitution`` (in [0, 1]). Contact forces are reported on
    ``body_a``; the normal points from ``body_b`` into ``body_a``.

    Raises ``ValueError`` naming the pair for a friction below 0, a restitution outside [0, 1], and (when bound to a
    model) an unknown body (with the close matches), a body without collision geometry, or a body paired with
    itself."""

    def __init__(self, body_a, body_b, *, friction=0.5, restitution=0.0):
        self.name = f"ContactPair({body_a!r}, {body_b!r})"
        self.body_a, self.body_b = body_a, body_b
        self.friction = _coefficient(self.name, "friction", friction)
        self.restitution = _coefficient(self.name, "restitution", restitution, 1.0)
        self.pairs = None

    def bind(self, system):
        """This pair on ``system``'s model: ``pairs``, the ``(geometry a, geometry b)`` index pairs."""
        model = _model_of(system, self.name)
        a, b = _body(model, self.name, self.body_a), _body(model, self.name, self.body_b)
        if a == b:
            raise ValueError(f"{self.name}: a body cannot be in contact with itself ({a!r})")
        bound = _copy(self)
        bound.pairs = [(ga, gb) for ga in _geometries_of(model, self.name, a) for gb in _geometries_of(model, self.name, b)]
        return bound


class JointLimits(Unilateral):
    """``model.lower ≤ q ≤ model.upper`` of the named one-coordinate joints (revolute, prismatic; names or indices;
    default ``None``: every such joint with a finite limit) as unilateral constraints, with Newton's restitution
    ``restitution`` (in [0, 1]). The limit's generalized force is reported per step (negative at an upper limit).

    Raises ``ValueError`` naming the constraint for a restitution outside [0, 1], and (when bound to a model) an
    unknown joint (with the close matches), a joint of more than one coordinate, or one without a finite limit."""

    def __init__(self, joints=None, *, restitution=0.0):
        self.name = "JointLimits"
        self.restitution = _coefficient(self.name, "restitution", restitution, 1.0)
        if isinstance(joints, str | int | np.integer):
            joints = [joints]
        self.joints = None if joints is None else list(joints)
        self.limits = None

    def bind(self, system):
        """These limits on ``system``'s model: ``limits``, rows ``(joint index, iq, iv, lower, upper)``."""
        model = _model_of(system, self.name)

        def limited(i):
            joint = model.joints[i]
            iq = model.idx_q[i]
            return joint.nq == 1 and joint.nv == 1 and (np.isfinite(model.lower[iq]) or np.isfinite(model.upper[iq]))

        if self.joints is None:
            chosen = [i for i in range(model.njoints) if limited(i)]
        else:
            chosen = []
            for joint in self.joints:
                try:
                    i = model.joint_index(joint)
                except ValueError as error:
                    raise ValueError(f"{self.name}: {error}") from None
                name = model.joint_names[i]
                if model.joints[i].nq != 1 or model.joints[i].nv != 1:
                    raise ValueError(f"{self.name}: joint {name!r} has {model.joints[i].nq} coordinates; limits apply "
                                     "to one-coordinate joints (revolute, prismatic)")
                if not limited(i):
                    raise ValueError(f"{self.name}: joint {name!r} has no finite limit (lower "
                                     f"{model.lower[model.idx_q[i]]}, upper {model.upper[model.idx_q[i]]})")
                chosen.append(i)
        bound = _copy(self)
        bound.limits = [(i, int(model.idx_q[i]), int(model.idx_v[i]), float(model.lower[model.idx_q[i]]),
                         float(model.upper[model.idx_q[i]])) for i in chosen]
        return bound


def enforced_coordinates(constrained):
    """The indices into ``q`` of the coordinates whose limits ``constrained``'s :class:`JointLimits` enforce."""
    return sorted({iq for c in constrained.unilateral if isinstance(c, JointLimits) for _, iq, _, _, _ in c.limits})


def _copy(constraint):
    bound = object.__new__(type(constraint))
    bound.__dict__.update(constraint.__dict__)
    return bound


# ============================================================================= the program of a system


@dataclass
class ContactProgram:
    """What the compiled step of a system with unilateral constraints reads (:mod:`multibody.kernels.timestepping`):
    the model's compiled tree, the bilateral program and its frames, the geometry rows and vertices, and the plan
    without its controller."""

    tree: CompiledTree
    program: np.ndarray
    frames: np.ndarray
    geometry: np.ndarray
    vertices: np.ndarray
    plan: np.ndarray
    records: int
    bilateral: int
    body_names: tuple
    joint_names: tuple

    def workspaces(self, record):
        """Floats and integers of one step's workspace with records of ``record`` rows
        (:func:`multibody.kernels.timestepping.workspace_sizes`): they grow with the records."""
        return timestepping.workspace_sizes(self.plan, len(self.frames), record)


#: Each model's geometry rows (:func:`geometry_rows`), built on the first call and kept with the model.
_GEOMETRY_ROWS = weakref.WeakKeyDictionary()


def geometry_rows(model):
    """The rows ``(G, GEOMETRY_COLUMNS)`` (read-only) of :mod:`multibody.kernels.timestepping`'s layout of
    ``model``'s collision geometries (:func:`multibody.geometry.collision_table`): each one's frame row, size, shape,
    bounding radius (m), vertex range and body; built on the first call and kept with the model."""
    from .geometry import collision_table

    geometry = _GEOMETRY_ROWS.get(model)
    if geometry is not None:
        return geometry
    table = collision_table(model)
    geometry = np.zeros((len(table.names), timestepping.GEOMETRY_COLUMNS))
    if len(table.names):
        placements = [(int(b), np.asarray(X, dtype=float)) for b, X in zip(table.frames, table.placements)]
        geometry[:, : 13] = frame_rows(model, placements)
        geometry[:, timestepping.GEOMETRY_SIZE : timestepping.GEOMETRY_SIZE + 3] = table.sizes
        geometry[:, timestepping.GEOMETRY_SHAPE] = table.shapes
        geometry[:, timestepping.GEOMETRY_VERTEX_START : timestepping.GEOMETRY_VERTEX_START + 2] = table.vertex_ranges
        geometry[:, timestepping.GEOMETRY_BODY] = table.frames
        for g in range(len(table.names)):
            start, count = table.vertex_ranges[g]
            geometry[g, timestepping.GEOMETRY_RADIUS] = collision.bounding_radius(
                int(table.shapes[g]), np.ascontiguousarray(table.sizes[g]),
                np.ascontiguousarray(table.vertices[start : start + count]))
    geometry.setflags(write=False)
    _GEOMETRY_ROWS[model] = geometry
    return geometry


def contact_program(constrained, *, tolerance=TOLERANCE, max_iterations=MAX_ITERATIONS, margin=MARGIN,
                    penetration=PENETRATION, damping=None):
    """The :class:`ContactProgram` of ``constrained`` (a :class:`~multibody.constrained.ConstrainedSystem` on a
    :class:`~multibody.model.Model` with unilateral constraints); ``damping (nv,)``: joint damping, or ``None``."""
    from .geometry import collision_table

    model = constrained.system.model
    nq, nv = model.nq, model.nv
    table = collision_table(model)
    geometry = geometry_rows(model)
    grounds, pairs, limits = [], [], []
    for c in constrained.unilateral:
        if isinstance(c, Ground):
            grounds += [[g, *c.normal, c.height, c.friction, c.restitution] for g in c.geometries]
        elif isinstance(c, ContactPair):
            pairs += [[ga, gb, c.friction, c.restitution] for ga, gb in c.pairs]
        elif isinstance(c, JointLimits):
            limits += [[iq, iv, lower, upper, c.restitution, j] for j, iq, iv, lower, upper in c.limits]
    # the bilateral rows' program, frames and projection at a step's end (project's defaults): the constrained step's
    step = constrained.compiled_step
    if step is None:
        names = [c.name for c in constrained.constraints]
        raise ValueError(f"simulate with contact or joint limits needs bilateral constraints with compiled rows "
                         f"(built-in, fixed in time); {names} are not all")
    blocks = [np.ravel(np.array(x, dtype=float)) for x in (grounds, pairs, limits)]
    header = np.zeros(timestepping.PLAN_HEADER)
    starts = np.cumsum([timestepping.PLAN_HEADER] + [b.size for b in blocks])
    header[[timestepping.PLAN_NQ, timestepping.PLAN_NV, timestepping.PLAN_GROUNDS, timestepping.PLAN_PAIRS,
            timestepping.PLAN_LIMITS, timestepping.PLAN_MARGIN, timestepping.PLAN_TOLERANCE,
            timestepping.PLAN_MAX_ITERATIONS, timestepping.PLAN_BILATERAL, timestepping.PLAN_DAMPED,
            timestepping.PLAN_GROUND_START, timestepping.PLAN_PAIR_START, timestepping.PLAN_LIMIT_START,
            timestepping.PLAN_DAMPING_START, timestepping.PLAN_PENETRATION, timestepping.PLAN_KINEMATICS_WORKSPACE,
            timestepping.PLAN_PASSES_WORKSPACE, timestepping.PLAN_SETTINGS_START,
            timestepping.PLAN_PROJECTION_WORKSPACE]] = (
        nq, nv, len(grounds), len(pairs), len(limits), margin, tolerance, max_iterations, constrained.num_rows,
        damping is not None, starts[0], starts[1], starts[2], starts[3], penetration,
        *timestepping.pass_workspaces(model.njoints, nv), starts[3] + nv, step.projection_workspace)
    plan = np.concatenate([header, *blocks, np.zeros(nv) if damping is None else np.asarray(damping, dtype=float),
                           step.settings])
    # (without bilateral rows the step reads no frames: the unconstrained step's, the bodies', would size the step's
    # frame motions for nothing)
    frames = step.frames if constrained.num_rows else np.zeros((0, 13))
    return ContactProgram(step.tree, np.ascontiguousarray(step.program, dtype=float),
                          np.ascontiguousarray(frames, dtype=float), np.ascontiguousarray(geometry),
                          np.ascontiguousarray(table.vertices, dtype=float), np.ascontiguousarray(plan),
                          # a record's most rows: every contact point and both limits of each limited coordinate
                          timestepping.max_contacts(len(grounds), len(pairs)) + 2 * len(limits), constrained.num_rows,
                          tuple(model.body_names), tuple(model.joint_names))


# ============================================================================= the compiled run

_RUN_TYPES = (CONTROLLER_FUNCTION, TREE_INTS, TREE_FLOATS, types.float64[:, ::1], types.float64[::1],
              types.float64[:, ::1], types.float64[:, ::1], types.float64[::1], types.float64[::1], types.float64[::1],
              types.float64[:, ::1], types.float64[:, :, ::1], types.float64[:, ::1], types.float64[::1],
              types.float64[::1], types.int64[::1])
_TRAJECTORIES_TYPES = (types.FunctionType(types.none(*_RUN_TYPES)), CONTROLLER_FUNCTION, TREE_INTS, TREE_FLOATS,
                       types.float64[:, ::1], types.float64[::1], types.float64[:, ::1], types.float64[:, ::1],
                       types.float64[::1], types.float64[:, ::1], types.float64[::1], types.float64[:, :, ::1],
                       types.float64[:, :, :, ::1], types.float64[:, :, ::1], types.float64[:, ::1], types.int64,
                       types.int64, types.int64)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _trajectories(run, controller, joints, reals, frames, program, geometry, vertices, plan, control, times, states,
                  records, summaries, io, workspace, int_workspace, shares):
    # ``run`` (multibody.kernels.timestepping.run) is a first-class function, so that this loop's cached machine
    # code holds none of the kernels' (whose cache multibody.kernels renews when their sources change)
    n = states.shape[0]
    for share in prange(shares):
        ws = np.empty(workspace)
        iws = np.zeros(int_workspace, dtype=np.int64)
        for r in range(share * n // shares, (share + 1) * n // shares):
            run(controller, joints, reals, frames, program, geometry, vertices, plan,
                control[r if control.shape[0] > 1 else 0], times, states[r], records[r], summaries[r], io[r], ws, iws)


_GAPS_TYPES = (TREE_INTS, TREE_FLOATS, types.float64[:, ::1], types.float64[:, ::1], types.float64[::1],
               types.float64[:, ::1], types.float64[::1], types.float64[::1])

#: The compiled run's functions that Python calls or passes as first-class functions (``multibody compile``).
ENTRY_POINTS = ((timestepping.run, _RUN_TYPES), (_trajectories, _TRAJECTORIES_TYPES),
                (timestepping.deepest_gaps, _GAPS_TYPES))

#: Messages of a run's status (:mod:`multibody.kernels.timestepping`).
_STATUS = {
    timestepping.NOT_POSITIVE_DEFINITE: "the mass matrix is not positive definite",
    timestepping.UNDEFINED: "a bilateral constraint's rows are undefined at this configuration",
    timestepping.NON_FINITE_STATE: "the state is not finite",
    timestepping.NON_FINITE_TORQUE: "the joint forces are not finite",
    timestepping.NOT_PROJECTED: "the projection onto the bilateral constraints did not converge",
}


class ContactRecord(Sequence):
    """:attr:`Trajectory.contacts <multibody.Trajectory.contacts>` of one trajectory: a sequence of
    :class:`~multibody.trajectory.Contacts`, entry ``k`` the contact rows of the step that ends at ``t[k]`` (entry 0
    empty). It reads the compiled run's record (:mod:`multibody.kernels.timestepping`) and builds each entry the first
    time it is read (then keeps it), so a run whose contacts are never read pays nothing for them.

    ``records (n, R, RECORD_COLUMNS)``: each step's rows (body, other, point, normal, force), the first ``counts[k]``
    of step ``k`` filled; ``counts (n,)`` ints; ``names``: the names that a row's codes index, the model's bodies,
    then its joints (a limit's body), then ``"ground"`` and ``"limit"`` (a row's other); ``bodies``: how many of them
    are bodies. Indexing, slicing (a list
    of entries), iteration and ``==`` (against any sequence of entries, such as a list) behave as a list's."""

    def __init__(self, records, counts, names, bodies):
        self._records, self._counts, self._names, self._bodies = records, counts, names, bodies
        self._entries = {}
        self._indices = None

    def __len__(self):
        return len(self._counts)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        n = len(self)
        i = operator.index(k)
        if not -n <= i < n:
            raise IndexError(f"contacts index {k} out of range for {n} output times")
        i %= n
        entry = self._entries.get(i)
        if entry is None:
            entry = self._entries[i] = self._entry(i)
        return entry

    def __eq__(self, other):
        if not isinstance(other, Sequence) or isinstance(other, str | bytes):
            return NotImplemented
        return len(self) == len(other) and all(a == b for a, b in zip(self, other))

    __hash__ = None

    def __repr__(self):
        return f"ContactRecord({len(self)} output times, {int(np.sum(self._counts))} contact rows)"

    def _entry(self, k):
        """The :class:`~multibody.trajectory.Contacts` of step ``k``: its rows' codes named, its arrays copied."""
        if self._indices is None:
            self._indices = _name_indices(self._records, self._bodies, len(self._names) - self._bodies - 2)
        body, other = self._indices
        c = int(self._counts[k])
        rows = self._records[k, :c]
        return Contacts(self._names[body[k, :c]], self._names[other[k, :c]],
                        rows[:, timestepping.RECORD_POINT : timestepping.RECORD_POINT + 3].copy(),
                        rows[:, timestepping.RECORD_NORMAL : timestepping.RECORD_NORMAL + 3].copy(),
                        rows[:, timestepping.RECORD_FORCE : timestepping.RECORD_FORCE + 3].copy())


def _name_indices(records, bodies, joints):
    """The indices into a :class:`ContactRecord`'s names (``bodies`` body names, ``joints`` joint names, then
    ``"ground"`` and ``"limit"``) of the body and the other of every row of ``records (..., R, RECORD_COLUMNS)``:
    ``(..., R)`` each. A limit's body code is its joint's index and its other code
    :data:`~multibody.kernels.timestepping.LIMIT`; a ground's other code is
    :data:`~multibody.kernels.timestepping.GROUND`; any other code is a body's index."""
    code, other = records[..., timestepping.RECORD_BODY], records[..., timestepping.RECORD_OTHER]
    limit = other == timestepping.LIMIT
    body = np.where(limit, bodies + code, code).astype(np.intp)
    other = np.where(limit, bodies + joints + 1, np.where(other == timestepping.GROUND, bodies + joints, other))
    return body, other.astype(np.intp)


def contact_records(records, summaries, program):
    """The :class:`ContactRecord` of each trajectory of ``records (N, n, R, RECORD_COLUMNS)`` and ``summaries (N, n,
    ·)`` (a list of ``N``), naming rows by ``program``'s bodies and joints."""
    names = np.array(list(program.body_names) + list(program.joint_names) + ["ground", "limit"], dtype=str)
    counts = np.nan_to_num(summaries[..., timestepping.SUMMARY_COUNT]).astype(np.int64)
    return [ContactRecord(records[r], counts[r], names, len(program.body_names)) for r in range(len(records))]


def separate_initial(constrained, program, q):
    """``q`` with its penetrations (contacts and joint limits) removed by :func:`multibody.kernels.timestepping.step`'s
    position correction at ``dt → 0`` (a zero-length step moves nothing but the correction), repeated until the
    deepest gap is above the tolerance (curvature needs a few passes), and the deepest penetration found (m or rad,
    ≥ 0)."""
    nq, nv = constrained.nq, constrained.nv
    deepest = 0.0
    for _ in range(20):
        states = np.zeros((2, nq + nv))
        states[0, :nq], states[0, nq:] = q, 0.0
        records = np.zeros((2, max(program.records, 1), timestepping.RECORD_COLUMNS))
        summaries = np.zeros((2, timestepping.SUMMARY_COLUMNS + program.bilateral))
        io = np.zeros(timestepping.IO_SIZE)
        io[timestepping.IO_STEP], io[timestepping.IO_STOP] = 1, 2
        # a step of 1e-300 s: the free motion and the impulses move nothing; the correction moves q
        times = np.array([0.0, 1e-300])
        _call_run(program, stepping.NO_CONTROL, np.zeros((1, nv)), None, times, states, records, summaries, io)
        depth = -summaries[1, timestepping.SUMMARY_SEPARATION]
        if not depth > 0.0:
            break
        deepest = max(deepest, depth)
        q = states[1, :nq].copy()
    return q, deepest


def initial_gaps(program, q):
    """The deepest gap (m, or rad to a joint limit; at most the margin) of each configuration of ``q (N, nq)``
    (:func:`multibody.kernels.timestepping.deepest_gap`): ``(N,)``, negative where it penetrates."""
    gaps = np.empty(len(q))
    size = timestepping.gap_workspace_size(program.tree.njoints, program.tree.nv, timestepping.max_contacts(
        int(program.plan[timestepping.PLAN_GROUNDS]), int(program.plan[timestepping.PLAN_PAIRS])))
    driver.entry_point(timestepping.deepest_gaps, _GAPS_TYPES)(
        program.tree.joints, program.tree.reals, program.geometry, program.vertices, program.plan,
        np.ascontiguousarray(q), gaps, np.empty(size))
    return gaps


def _leading(program, kind, controller):
    """The arguments of :func:`multibody.kernels.timestepping.run` before its control row: the controller's
    first-class function, the tree's arrays, the frames, program, geometry, vertices and the plan with the controller
    ``kind``."""
    plan = program.plan.copy()
    plan[timestepping.PLAN_CONTROL] = kind
    return (controller_function(kind, controller), program.tree.joints, program.tree.reals, program.frames,
            program.program, program.geometry, program.vertices, plan)


def _call_run(program, kind, control, controller, times, states, records, summaries, io):
    """One trajectory's steps ``io[IO_STEP]`` up to ``io[IO_STOP]`` by :func:`multibody.kernels.timestepping.run`."""
    floats, ints = program.workspaces(records.shape[1])
    driver.entry_point(timestepping.run, _RUN_TYPES)(*_leading(program, kind, controller), control[0], times, states,
                                                     records, summaries, io, np.empty(floats),
                                                     np.zeros(ints, dtype=np.int64))


def _run_batch(program, kind, control, controller, times, states, records, summaries, io, device=False):
    """The steps of every trajectory of ``states (N, n, nq + nv)`` on all cores, each on its own, or (``device``) on
    the GPU, one trajectory per thread (:func:`multibody.gpu.contact_batch`)."""
    pointer, *arrays = _leading(program, kind, controller)
    floats, ints = program.workspaces(records.shape[2])
    if device:
        from . import gpu
        launcher = gpu.run_launcher(gpu.contact_run_source, timestepping.run,
                                    controller.function if kind == stepping.FUNCTION else None, pointer,
                                    dict(ENTRY_POINTS)[timestepping.run])
        gpu.contact_batch(launcher, (*arrays, control, times), floats, ints, states, records, summaries, io)
        return
    shares = max(1, min(driver.get_num_threads(), len(states)))
    entry = driver.entry_point(_trajectories, _TRAJECTORIES_TYPES)
    with driver.parallel_shares(shares):
        entry(driver.first_class(timestepping.run, _RUN_TYPES), pointer, *arrays, control, times, states, records,
              summaries, io, floats, ints, shares)


def run(constrained, q, v, times, controller, torque, batch, damping=None, tolerance=TOLERANCE,
        max_iterations=MAX_ITERATIONS, device=False, progress=None):
    """The Moreau–Jean steps (:mod:`multibody.kernels.timestepping`) of ``constrained`` from the checked initial
    states ``q (N, nq)``, ``v (N, nv)`` at the output ``times (n,)`` (s; one step per interval): a
    :class:`~multibody.Trajectory` (one, for ``batch`` ``None``, or of ``batch`` trajectories) whose ``status``
    says where each stopped (a non-finite state or joint forces: which coordinates, by joint,
    :func:`multibody.runs.non_finite`). ``controller``: ``None``, joint forces ``(nv,)`` or ``(N, nv)``, a bound PD or a
    compiled controller, run inside the step; or ``torque(t, q, v)``, a Python function of the state at each step's
    start (``controller`` then ``None``). ``damping (nv,)`` or ``None``: joint damping ``−D v``. ``tolerance`` (m/s)
    and ``max_iterations``: each step's contact problem; a step that does not reach the tolerance ends its
    trajectory before it (its record stays in ``contacts``, its residual in ``complementarity``). An initial state
    off the bilateral constraints is projected onto them with a warning (:func:`multibody.runs.projected_start`: the
    distance and the coordinates that moved most; a batch: :func:`multibody.runs.warn_projected_starts`), and one in
    penetration is projected out (the smallest move in the metric of ``M``) with a warning giving the depth; the
    warnings point at the caller of the function that called this one (:func:`multibody.simulate`'s caller).
    ``device``: the batch's steps on the GPU, one trajectory per thread (a ``controller`` the GPU computes, not
    ``torque``), in one launch. ``progress``: a :class:`~multibody.runs.Progress` bar over the simulated time
    (``None``, ``True`` or ``False``, as :func:`multibody.simulate` takes it); the compiled steps run in calls of
    about :data:`~multibody.runs.CHUNK_SECONDS` (:func:`~multibody.runs.next_chunk`), between which the bar moves
    and an interrupt (Ctrl-C) stops the run, a Python ``torque`` one step per call."""
    model = constrained.system.model
    nq, nv = constrained.nq, constrained.nv
    program = contact_program(constrained, tolerance=tolerance, max_iterations=max_iterations, damping=damping)
    count = len(q)
    q, v = model.normalize(np.array(q, dtype=float)), np.array(v, dtype=float)
    # an initial state in penetration, projected out (and onto the bilateral constraints); the zero-length steps of
    # separate_initial only for the states whose gaps show a penetration it would remove
    refused = {}  # a batch's trajectories whose initial state could not be projected: the error's message
    if constrained.num_rows and batch is None:
        q[0], v[0], _ = projected_start(constrained, q[0], v[0], times[0], stacklevel=4)
    elif constrained.num_rows:
        # a batch's initial state whose projection fails stops its trajectory before its first step, which sees it at
        # rest in the neutral configuration (as simulate's smooth batch does); the others go on. All in one call on
        # all cores where none fails (the compiled rows project each state as alone), else each state alone
        projected, refused = by_state(
            lambda q_r, v_r: np.concatenate(constrained.project(q_r, v_r, times[0]), axis=-1), (q, v), (nq + nv,),
            constrained.batched)
        moved = np.abs(projected - np.concatenate([q, v], axis=1)).max(axis=1, initial=0.0)
        moved[list(refused)] = 0.0
        warn_projected_starts(moved, stacklevel=4)
        q[:], v[:] = projected[:, :nq], projected[:, nq:]
        q[list(refused)], v[list(refused)] = model.neutral(), 0.0
    for r in np.flatnonzero(initial_gaps(program, q) < -program.plan[timestepping.PLAN_PENETRATION]):
        if r in refused:
            continue
        q[r], depth = separate_initial(constrained, program, q[r])
        if depth > 0.0:
            where = "" if batch is None else f" (trajectory {r})"
            warnings.warn(f"the initial state{where} penetrates by {depth:.3g} (m, or rad past a joint limit); "
                          "projected out of penetration", UserWarning, stacklevel=3)
    n = len(times)
    # (the steps fill the states; those a trajectory does not reach are NaN'd with its status below)
    states = np.empty((count, n, nq + nv))
    states[:, 0, :nq], states[:, 0, nq:] = q, v
    records = np.zeros((count, n, min(RECORD_CAPACITY, max(program.records, 1)), timestepping.RECORD_COLUMNS))
    summaries = np.zeros((count, n, timestepping.SUMMARY_COLUMNS + program.bilateral))
    io = np.zeros((count, timestepping.IO_SIZE))
    io[:, timestepping.IO_STEP], io[:, timestepping.IO_STOP] = 1, n
    io[list(refused), timestepping.IO_STEP], io[list(refused), timestepping.IO_STATUS] = 0, timestepping.NOT_PROJECTED
    bar = Progress(progress, times[0], times[-1])
    forces = {}  # a Python controller's joint forces (nv,) that stopped a trajectory, by trajectory
    try:
        if torque is not None:
            # a Python controller: its joint forces at each step's start, then that one step compiled
            for k in range(1, n):
                live = io[:, timestepping.IO_STATUS] == timestepping.COMPLETED
                if not live.any():
                    break
                # a stopped trajectory's row holds its last state (the initial one where it never started)
                last = states[np.arange(count), np.maximum(np.minimum(io[:, timestepping.IO_STEP], k) - 1, 0)
                              .astype(np.int64)]
                at = (last[:, :nq], last[:, nq:]) if batch is not None else (last[0, :nq], last[0, nq:])
                value = torque(times[k - 1], *at)
                control = np.ascontiguousarray(np.broadcast_to(np.zeros(nv) if value is None else value, (count, nv)),
                                               dtype=float)
                # a trajectory whose row of joint forces is not finite stops before the step (the compiled step
                # takes constant joint forces as checked), its forces kept for its status
                bad = live & ~np.isfinite(control).all(axis=1)
                forces.update({r: control[r].copy() for r in np.flatnonzero(bad)})
                io[bad, timestepping.IO_STEP], io[bad, timestepping.IO_STATUS] = k, timestepping.NON_FINITE_TORQUE
                io[bad, timestepping.IO_TIME] = times[k - 1]
                live &= ~bad
                if live.any():
                    io[live, timestepping.IO_STEP], io[live, timestepping.IO_STOP] = k, k + 1
                    records = _dispatch(program, stepping.CONSTANT, control, None, times, states, records, summaries,
                                        io, batch, live)
                bar.update(times[k])
        else:
            kind, control = control_rows(controller, nv)
            records = _chunked(program, kind, control, controller, times, states, records, summaries, io, batch, bar,
                               device)
    finally:
        bar.close()
    statuses = []
    for r in range(count):
        status = int(io[r, timestepping.IO_STATUS])
        last = int(io[r, timestepping.IO_STEP])
        if status == timestepping.COMPLETED:
            statuses.append("completed")
            continue
        if r in refused:
            statuses.append(f"the projection onto the bilateral constraints failed at t = {times[0]:.6g} s: "
                            f"{refused[r]}")
        elif status == timestepping.NOT_SOLVED:
            summary = summaries[r, last]
            solver = int(summary[timestepping.SUMMARY_STATUS])
            statuses.append(f"the contact problem of the step from t = {times[last - 1]:.6g} s did not reach the "
                            f"tolerance {tolerance:.3g} m/s in {int(summary[timestepping.SUMMARY_ITERATIONS])} "
                            f"iterations (residual {summary[timestepping.SUMMARY_RESIDUAL]:.3g} m/s: "
                            f"{STATUS_MESSAGES.get(solver, 'failed')})")
        else:
            message = f"{_STATUS[status]} at t = {io[r, timestepping.IO_TIME]:.6g} s"
            system = constrained.system
            if status == timestepping.NON_FINITE_STATE:
                # the state the step ended in, before it is dropped below
                named = [non_finite(system, states[r, last, :nq]), non_finite(system, states[r, last, nq:], rate=True)]
                message += ": " + ", ".join(x for x in named if x)
            elif status == timestepping.NON_FINITE_TORQUE:
                at = forces.get(r)
                if at is None:
                    at = _controller_forces(controller, r, io[r, timestepping.IO_TIME], states[r, last - 1, :nq],
                                            states[r, last - 1, nq:])
                message += ": " + non_finite(system, at, force=True)
            statuses.append(message)
            summaries[r, last, timestepping.SUMMARY_RESIDUAL] = np.nan
        # the steps not taken: no state, no residual (the failed step's record and residual stay, as the solver left
        # them)
        states[r, last:] = np.nan
        summaries[r, last + 1 :, timestepping.SUMMARY_RESIDUAL] = np.nan
    return _trajectory(constrained, program, times, states, records, summaries, io[:, timestepping.IO_STEP], statuses,
                       batch)


def _controller_forces(controller, r, t, q, v):
    """The joint forces ``(nv,)`` that ``controller`` (joint forces ``(nv,)`` or ``(N, nv)``, a bound PD or a
    compiled controller) gives trajectory ``r`` at ``t`` (s) and ``q (nq,)``, ``v (nv,)``: by the code the compiled
    step runs (:class:`~multibody.integrators.PDController`, :class:`~multibody.integrators.CompiledController`)."""
    value = controller if isinstance(controller, np.ndarray) else np.asarray(controller(t, q, v))
    return value[r if len(value) > 1 else 0] if value.ndim == 2 else value


def _chunked(program, kind, control, controller, times, states, records, summaries, io, batch, bar, device=False):
    """Every trajectory's steps from ``io[:, IO_STEP]`` to the end of ``times (n,)`` by :func:`_dispatch`, in calls
    of about :data:`~multibody.runs.CHUNK_SECONDS` (:func:`~multibody.runs.next_chunk`; on the GPU, ``device``, all
    in one launch), telling ``bar`` (a :class:`~multibody.runs.Progress`) after each call the time every trajectory
    still running has reached; returns the records (widened where a step needed more rows)."""
    n = len(times)
    chunk = FIRST_CHUNK
    while True:
        going = (io[:, timestepping.IO_STATUS] == timestepping.COMPLETED) & (io[:, timestepping.IO_STEP] < n)
        if not going.any():
            return records
        # a trajectory that stopped is given no step (its stop at its next step), which the run reports as completed:
        # its status is put back after the call, so that the batch's calls need not copy the trajectories still going
        stopped = io[~going, timestepping.IO_STATUS].copy()
        step = io[:, timestepping.IO_STEP]
        io[:, timestepping.IO_STOP] = np.where(going, n if device else np.minimum(n, step + chunk), step)
        started = time.perf_counter()
        records = _dispatch(program, kind, control, controller, times, states, records, summaries, io, batch, None,
                            device)
        chunk = next_chunk(chunk, time.perf_counter() - started)
        io[~going, timestepping.IO_STATUS] = stopped
        going = (io[:, timestepping.IO_STATUS] == timestepping.COMPLETED) & (io[:, timestepping.IO_STEP] < n)
        bar.update(times[int(io[going, timestepping.IO_STEP].min(initial=n)) - 1])


def _dispatch(program, kind, control, controller, times, states, records, summaries, io, batch, live, device=False):
    """The steps of one trajectory (``batch`` ``None``) or of the ``live`` trajectories of a batch (``None``: all), on
    the GPU where ``device``, each stopped by a step with more rows than ``records (N, n, R, RECORD_COLUMNS)`` holds
    going on from that step with every record widened (:data:`RECORD_CAPACITY`); returns the records."""
    _dispatch_once(program, kind, control, controller, times, states, records, summaries, io, batch, live, device)
    while True:
        full = io[:, timestepping.IO_STATUS] == timestepping.RECORD_FULL
        if not full.any():
            return records
        rows = np.flatnonzero(full)
        needed = int(summaries[rows, io[rows, timestepping.IO_STEP].astype(np.int64), timestepping.SUMMARY_COUNT].max())
        width = min(max(needed, 2 * records.shape[2]), max(program.records, 1))
        grown = np.zeros(records.shape[:2] + (width, timestepping.RECORD_COLUMNS))
        grown[:, :, : records.shape[2]] = records
        records = grown
        io[rows, timestepping.IO_STATUS] = timestepping.COMPLETED
        _dispatch_once(program, kind, control, controller, times, states, records, summaries, io, batch, full, device)


def _dispatch_once(program, kind, control, controller, times, states, records, summaries, io, batch, live,
                   device=False):
    """The steps of one trajectory (``batch`` ``None``) or of the ``live`` trajectories of a batch (``None``: all), on
    the GPU where ``device``."""
    if batch is None:
        _call_run(program, kind, control, controller, times, states[0], records[0], summaries[0], io[0])
        return
    if live is None or live.all():
        _run_batch(program, kind, control, controller, times, states, records, summaries, io, device)
        return
    rows = np.flatnonzero(live)
    parts = [np.ascontiguousarray(x[rows]) for x in (states, records, summaries, io)]
    _run_batch(program, kind, np.ascontiguousarray(control[rows]) if len(control) > 1 else control, controller,
               times, *parts, device)
    for x, part in zip((states, records, summaries, io), parts):
        x[rows] = part


def _trajectory(constrained, program, times, states, records, summaries, reached, statuses, batch):
    """The :class:`~multibody.Trajectory` of the runs (one, or ``batch`` of them), each with ``reached (N,)`` states
    (finite, the rest NaN)."""
    nq, m = constrained.nq, constrained.num_rows
    q, v = states[..., :nq], states[..., nq:]
    finite = np.arange(len(times)) < reached[:, None]
    # the energy of each state that a step started from is in its summary row (the step's kinematics pass); the last
    # state each trajectory reached, which no step started from, computed here
    energy = np.where(finite, summaries[..., timestepping.SUMMARY_ENERGY], np.nan)
    # (NaN where it cannot be computed, as for velocities that overflow it; none where no state was reached)
    started = np.flatnonzero(reached > 0)
    ends = (started, reached[started].astype(np.int64) - 1)
    energy[ends] = by_state(constrained.energy, (np.ascontiguousarray(q[ends]), np.ascontiguousarray(v[ends])), (),
                            constrained.batched)[0]
    if m:
        # (C-contiguous, as the batched kernels read them)
        safe_q = np.ascontiguousarray(np.where(finite[..., None], q, constrained.system.model.neutral()))
        safe_v = np.ascontiguousarray(np.where(finite[..., None], v, 0.0))
        residual = np.where(finite, constrained.residual(safe_q, safe_v, times), np.nan)
    else:
        residual = np.where(finite, 0.0, np.nan)
    # (the multipliers of the states reached; NaN after a trajectory stopped, as its states are)
    lam = np.where(finite[..., None], summaries[..., timestepping.SUMMARY_COLUMNS :], np.nan)
    complementarity_ = summaries[..., timestepping.SUMMARY_RESIDUAL].copy()
    # (no step ends at t[0]: 0 there, but NaN for a trajectory that never started, as all its outputs are)
    complementarity_[..., 0] = np.where(reached > 0, 0.0, np.nan)
    trajectory = Trajectory(t=np.array(times, dtype=float), q=q, v=v, lam=lam, energy=energy, residual=residual,
                            row_names=list(constrained.row_names), status=statuses,
                            joint_names=recorded_names(constrained),
                            contacts=contact_records(records, summaries, program), complementarity=complementarity_)
    # (one trajectory is a batch of one, whose result loses the batch axis)
    return trajectory if batch is not None else trajectory.select(0)
