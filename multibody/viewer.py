"""A 3-D view of a model and of its motion in the browser, served by Viser (``pip install multibody[viz]``).

::

    viewer = mb.view(model, trajectory=trajectory, constraints=system, trace=["ball"])
    print(viewer.url)              # open it in a browser; several browsers may watch at once
    viewer.time = 1.5              # show t = 1.5 s (the slider follows)
    viewer.save_html("ball.html")  # one self-contained page that replays the motion offline
    viewer.close()                 # stops the server and frees the port

The page shows, in world coordinates (z up, metres), with the camera on the bodies as they are at the
first frame (their bounding box then, which also sets the size of frames, arrows and grid cells), not
on everything the motion reaches:

* every body at its pose from :func:`multibody.forward_kinematics`, computed once for the whole
  trajectory: its visual shapes (URDF ``<visual>`` meshes through trimesh, resolved through
  ``package_dirs`` when the model was loaded; boxes, cylinders; spheres painted in two-coloured
  octants, so that a rolling ball's turning shows), or, for a body without any, the *equivalent-inertia
  box*: the uniform box with the body's mass and principal moments of inertia, centred at its centre of
  mass along its principal axes. A massive body with no rotational inertia (a point mass) is a small
  sphere; a massless link is drawn as its frame only;
* each body's frame (x red, y green, z blue), the world frame, and a ground grid at ``z = 0`` (under the
  lowest point instead when the motion reaches below, as a hanging pendulum does); when the constraints
  include planes (rolling spheres and discs) those planes are drawn instead of the ground;
* for a :class:`~multibody.trajectory.Trajectory`: a play/pause button, a time slider spanning the
  trajectory's times, the playback speed, and checkboxes that show or hide each layer;
* ``trace=[...]``: the paths of chosen body points over the whole trajectory;
* ``constraints=...``: the constraint forces at the current time, as arrows drawn to scale (m per N,
  printed in the panel). Each constraint's multipliers (``trajectory.lam``, sign convention
  ``M a + h = τ + Aᵀ λ``) give the spatial forces it exerts on the bodies
  (``Constraint.body_forces``), one per body; each is drawn as an arrow on its line of action: from the
  contact point for rolling constraints, otherwise from the point of that line nearest to the point the
  constraint acts on (the bead, the rod's end, the frame origin of a loop closure). A force's couple
  about that line (loop closures that hold orientations) is not drawn. Constraints that act on
  coordinates rather than through body points (joint couplings, user constraints) have no arrows; the
  panel names them;
* for a trajectory with contact (``trajectory.contacts``, see :mod:`multibody.contact`): at each frame the
  contact points of the step ending then, as small spheres, and the contact forces on ``body`` (N, world
  axes), as arrows from those points along the force, drawn to the same scale as the constraint forces.
  Joint-limit rows are not drawn (they act on a coordinate). A ``contacts`` checkbox hides both.

The arrows' length per newton (m/N) is the ``force scale`` box in the panel (``Viewer.force_scale``),
starting at ``force_scale=`` when given.

The handle, :class:`Viewer`, is also the programmatic interface: ``time``, ``play()``, ``pause()``,
``layers`` (the show/hide checkboxes), ``save_html(path)``, ``close()``. Scene computation
(:func:`scene_of`) is separate from serving it and needs no Viser.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import math
import os
import threading
import time as _time
from dataclasses import dataclass, field

import numpy as np

from . import spatial

#: What a missing Viser installation is told.
INSTALL_HINT = "the 3-D viewer needs Viser: pip install multibody[viz] (or pip install viser)"

#: Colours (RGB, 0–255): shapes without their own, the two octant colours of spheres, the paths, and
#: the force arrows of successive constraints.
SHAPE_COLOR = (130, 150, 190)
SPHERE_COLORS = ((220, 60, 50), (245, 245, 240))
TRACE_COLORS = ((230, 120, 20), (20, 150, 120), (150, 60, 200), (200, 40, 120))
FORCE_COLORS = ((200, 30, 30), (30, 90, 200), (20, 150, 60), (180, 120, 0))
#: Colours of the contact points and of the contact force arrows.
CONTACT_POINT_COLOR = (250, 190, 0)
CONTACT_FORCE_COLOR = (220, 40, 160)

#: Above this many frames, the offline page (:meth:`Viewer.save_html`) keeps every k-th.
OFFLINE_FRAMES = 1000


@dataclass(frozen=True)
class Shape:
    """One drawn shape of a body: ``vertices (k, 3)`` (m, body frame), ``faces (f, 3)`` and one ``color`` (RGB),
    or ``mesh``, a mesh with its own materials (a loaded file, or a sphere painted in octants).
    ``kind``: ``"visual"`` (the model's), ``"inertia box"`` or ``"point mass"`` (stand-ins)."""

    vertices: np.ndarray
    faces: np.ndarray
    color: tuple = SHAPE_COLOR
    mesh: object = None
    kind: str = "visual"


@dataclass(frozen=True)
class Scene:
    """Everything the page draws, computed once (no Viser involved).

    Attributes (``n`` frames, ``nb`` bodies, ``k`` force arrows):
        body_names: ``(nb,)`` the model's bodies, one scene node each.
        times: ``(n,)`` s; ``(1,)`` holding 0 for a single configuration.
        positions: ``(n, nb, 3)`` body origins in the world (m); wxyz: ``(n, nb, 4)`` body orientations
            as Viser's quaternions ``[w, x, y, z]``.
        shapes: body name -> tuple of :class:`Shape`.
        traces: label -> ``(n, 3)`` world path of a traced point (m).
        arrows: ``(n, k, 2, 3)`` tail and head of each force arrow (m), already scaled.
        arrow_labels: ``(k,)`` constraint and body of each arrow; arrow_colors: ``(k, 3)``.
        contact_points: per frame, ``(c, 3)`` the contact points (m, world) of ``trajectory.contacts``' entry,
            joint limits left out; ``()`` for a trajectory without contacts.
        contact_arrows: per frame, ``(a, 2, 3)`` tail and head (m) of the arrows of the nonzero contact forces
            of those points, already scaled; ``()`` without contacts.
        force_scale: arrow length per force (m/N), of the constraint and contact arrows alike.
        largest_force: largest force drawn (N).
        no_arrows: names of constraints with no body forces to draw.
        planes: ``(E (3, 3), origin (3,))`` of each constraint plane: columns ``[t₁ t₂ n]`` and a point.
        low, high: ``(3,)`` corners of the bounding box of the bodies (origins and shapes) over the whole
            motion (m).
        start_low, start_high: ``(3,)`` corners of their bounding box at the first frame (m): what the
            camera frames, and the scale of frames, arrows and grid cells, whatever a body does later (a
            part that flies off in a failed simulation).
    """

    body_names: tuple
    times: np.ndarray
    positions: np.ndarray
    wxyz: np.ndarray
    shapes: dict
    traces: dict = field(default_factory=dict)
    arrows: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 2, 3)))
    arrow_labels: tuple = ()
    arrow_colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.uint8))
    contact_points: tuple = ()
    contact_arrows: tuple = ()
    force_scale: float = 0.0
    largest_force: float = 0.0
    no_arrows: tuple = ()
    planes: tuple = ()
    low: np.ndarray = field(default_factory=lambda: np.zeros(3))
    high: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start_low: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start_high: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def frames(self) -> int:
        """Number of frames ``n``."""
        return len(self.times)

    @property
    def center(self) -> np.ndarray:
        """``(3,)`` the centre of the bodies' bounding box at the first frame (m), where the camera looks."""
        return 0.5 * (self.start_low + self.start_high)

    @property
    def size(self) -> float:
        """The diagonal of the bodies' bounding box at the first frame (m), at least 0.1: the camera's
        distance scale and the scale of frames, arrows and grid cells."""
        return _extent(self.start_low, self.start_high)


def _extent(low, high):
    """The diagonal of the box with corners ``low``, ``high`` (m), at least 0.1."""
    return max(float(np.linalg.norm(high - low)), 0.1)


# ----------------------------------------------------------------------------- shapes of the bodies

def equivalent_inertia_box(inertia):
    """``(edge lengths (3,), pose (4, 4))`` of the uniform box with ``inertia``'s mass and principal
    moments, in the body frame: ``a_i² = 6 (I_j + I_k − I_i) / m`` along the principal axes, centred at
    the centre of mass. ``None`` for a massless body."""
    if not inertia.mass > 0.0:
        return None
    moments, axes = np.linalg.eigh(0.5 * (inertia.rotational + inertia.rotational.T))
    if np.linalg.det(axes) < 0.0:
        axes[:, 2] = -axes[:, 2]
    # I_i = m (a_j² + a_k²) / 12 for a box of edges a, solved for the edges.
    edges = np.sqrt(np.maximum(6.0 * (moments.sum() - 2.0 * moments) / inertia.mass, 0.0))
    return edges, spatial.pose_matrix(axes, inertia.com)


def _painted_sphere(trimesh, mesh):
    """The sphere's vertices coloured by octant of its own frame (where the URDF placed it), so that
    its turning shows."""
    local = mesh.vertices - mesh.bounding_sphere.primitive.center
    parity = (np.prod(np.sign(local + 1e-12), axis=1) > 0).astype(int)
    colors = np.asarray(SPHERE_COLORS, dtype=np.uint8)[parity]
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colors, process=False)


def body_shapes(model, point_radius):
    """The shapes drawn for each body (body frame): ``{body name: (Shape, ...)}``.

    Visual geometry first (:func:`multibody.geometry.load_meshes`; a mesh that cannot be read warns and
    counts as absent); a body without any gets its :func:`equivalent_inertia_box`, or a sphere of
    ``point_radius`` (m) when it has mass but no rotational inertia. Massless links get none.
    """
    import trimesh

    from .geometry import load_meshes

    shapes = {name: [] for name in model.body_names}
    for geometry, mesh in load_meshes(model, "visual"):
        if mesh is None:
            continue
        if geometry.shape == "sphere":
            mesh = _painted_sphere(trimesh, mesh)
        # a file's mesh and the painted sphere keep their materials; the other primitives are drawn in SHAPE_COLOR
        kept = mesh if geometry.shape in ("sphere", "mesh") else None
        shapes[geometry.body].append(Shape(np.asarray(mesh.vertices), np.asarray(mesh.faces), mesh=kept))
    for name, inertia in zip(model.body_names, model.body_inertias):
        if shapes[name]:
            continue
        box = equivalent_inertia_box(inertia)
        if box is None:
            continue
        edges, pose = box
        if edges.max() > 1e-9:
            mesh = trimesh.creation.box(extents=np.maximum(edges, 1e-3 * edges.max()), transform=pose)
            kind = "inertia box"
        else:
            mesh = trimesh.creation.icosphere(subdivisions=2, radius=point_radius)
            mesh.apply_translation(inertia.com)
            kind = "point mass"
        shapes[name].append(Shape(np.asarray(mesh.vertices), np.asarray(mesh.faces), kind=kind))
    return {name: tuple(found) for name, found in shapes.items()}


# ----------------------------------------------------------------------------- the scene

def _states(model, q, trajectory):
    """``(times (n,), q (n, nq))`` of what is shown, with clear errors."""
    if q is not None and trajectory is not None:
        raise ValueError("give a configuration q or a trajectory, not both")
    if trajectory is None:
        q = model.neutral() if q is None else model.check_configuration(q)
        if np.shape(q) != (model.nq,):
            raise ValueError(f"q must be one configuration of shape ({model.nq},), got {np.shape(q)}; "
                             f"for a motion pass trajectory=")
        return np.zeros(1), np.asarray(q, dtype=float)[None]
    if not hasattr(trajectory, "q"):
        raise TypeError(f"trajectory must be a multibody Trajectory, got {type(trajectory).__name__}")
    t, q = np.asarray(trajectory.t, dtype=float), np.asarray(trajectory.q, dtype=float)
    if q.ndim != 2 or t.shape != q.shape[:1]:
        raise ValueError(f"view one trajectory at a time: t must be (n,) and q (n, nq), got shapes {t.shape} "
                         f"and {q.shape} (of N trajectories run together, trajectory.select(k) is the k-th)")
    if q.shape[1] != model.nq:
        raise ValueError(f"the trajectory has nq = {q.shape[1]} but the model {model.name!r} has nq = {model.nq}"
                         + (" (a free body: load the model with floating_base=True)" if q.shape[1] == model.nq + 7
                            else ""))
    if len(t) == 0:
        raise ValueError("the trajectory is empty")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0.0):
        raise ValueError("the trajectory's times must be finite and non-decreasing")
    finite = np.all(np.isfinite(q), axis=1)
    if not finite.all():
        # A failed run keeps NaN rows after its last good state (SimulationError.trajectory).
        raise ValueError(f"the trajectory has non-finite configurations from t = {t[np.argmin(finite)]:g} s on; "
                         f"view the part before it (trajectory.q[:k])")
    return t, model.check_configuration(q)


def _trace_points(model, trace):
    """``[(label, body index, point (3,))]`` of the traced points: body names, or ``(body, point)`` pairs."""
    points = []
    for item in trace:
        body, point = (item, np.zeros(3)) if isinstance(item, (str, int, np.integer)) else item
        if isinstance(body, str) and body not in model.body_names:
            raise ValueError(f"trace: no body {body!r} in model {model.name!r}; its bodies are {list(model.body_names)}")
        index = model.body_index(body)
        point = np.asarray(point, dtype=float)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f"trace: the point on {body!r} must be a finite (3,) body-frame position (m), got {point!r}")
        label = model.body_names[index] + ("" if not point.any() else f" {np.round(point, 4).tolist()}")
        points.append((label, index, point))
    return points


def _constraint_list(model, constraints):
    """The constraints as a tuple, from a list or a ``ConstrainedSystem`` (whose model must be ``model``)."""
    if constraints is None:
        return ()
    system = getattr(constraints, "system", None)
    if system is not None:  # a ConstrainedSystem, on a model (wrapped in a ModelSystem) or another system
        if (getattr(system, "nq", None), getattr(system, "nv", None)) != (model.nq, model.nv):
            raise ValueError(f"constraints: the ConstrainedSystem has nq = {system.nq}, nv = {system.nv}, but the "
                             f"model viewed has nq = {model.nq}, nv = {model.nv}")
        constraints = constraints.constraints
    from .constraints import Constraint

    constraints = tuple(constraints)
    for c in constraints:
        if not isinstance(c, Constraint):
            raise TypeError(f"constraints must be multibody constraints or a ConstrainedSystem, got {type(c).__name__}")
    return constraints


def _nice(x):
    """The largest of 1, 2, 5 times a power of ten not above ``x > 0``."""
    power = 10.0 ** math.floor(math.log10(x))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= x * (1 + 1e-12))


def _constraint_forces(model, constraints, q, lam, X_WB):
    """World forces of the constraints on the bodies, with their points: ``(forces (n, k, 3) N,
    points (n, k, 3) m, labels (k,), constraint of each arrow (k,), constraints without body forces)``.

    A force is drawn on its line of action: at the contact point of a rolling constraint, otherwise at
    the point of the line nearest to the point the constraint acts on in that body (or the joint origin).
    """
    from .kinematics import joint_world_poses

    n = len(q)
    lam = np.asarray(lam, dtype=float).reshape(n, -1)
    rows = [c.rows(model) for c in constraints]
    if sum(rows) != lam.shape[1]:
        raise ValueError(f"constraints: they have {sum(rows)} rows but the trajectory's lam has {lam.shape[1]} "
                         f"columns; pass the constraints that were simulated, in their order")
    offsets = np.cumsum([0, *rows])
    R_WJ, p_WJ = joint_world_poses(model, q)
    forces, points, labels, owners, without = [], [], [], [], []
    for k, c in enumerate(constraints):
        try:
            wrenches = np.array([c.body_forces(model, q[i], lam[i, offsets[k]:offsets[k + 1]]) for i in range(n)])
        except TypeError:  # acts on coordinates, not through body points
            without.append(c.name)
            continue
        # [f_W; n_O]: the force in world axes and its moment about the world origin
        world = spatial.transform_force(R_WJ, p_WJ, wrenches)
        f_W, n_O = world[..., :3], world[..., 3:]
        contact = (np.array([c.contact_point(model, q[i]) for i in range(n)])
                   if hasattr(c, "contact_point") else None)
        # the world position of the point the constraint acts on, per joint that carries it
        acting = {}
        for body, placement in getattr(c, "body_frames", ()):
            if body is not None:
                b = model.body_index(body)
                acting[model.body_joints[b]] = spatial.matvec(X_WB[:, b, :3, :3], placement[:3, 3]) + X_WB[:, b, :3, 3]
        for joint in np.flatnonzero(np.abs(f_W).max(axis=(0, 2)) > 0.0):
            f = f_W[:, joint]
            if contact is not None:
                point = contact
            else:
                reference = acting.get(joint, p_WJ[:, joint])
                # the point of the line of action nearest to the reference p: p + f × n_p / |f|², with
                # n_p = n_O − p × f the moment about p
                n_p = n_O[:, joint] - spatial.cross(reference, f)
                f2 = np.sum(f * f, axis=-1, keepdims=True)
                point = reference + spatial.cross(f, n_p) / np.where(f2 > 0.0, f2, np.inf)
            forces.append(f)
            points.append(point)
            body_name = model.body_names[int(np.flatnonzero(model.body_joints == joint)[0])]
            labels.append(f"{c.name} on {body_name}")
            owners.append(k)
    stack = lambda arrays: np.stack(arrays, axis=1) if arrays else np.zeros((n, 0, 3))  # noqa: E731
    return stack(forces), stack(points), tuple(labels), owners, tuple(without)


def _contact_forces(trajectory, n):
    """``(points, forces)``: per frame, the contact points ``(c, 3)`` (m, world) and the forces on their
    bodies ``(c, 3)`` (N, world axes) of ``trajectory.contacts``, joint-limit rows (``other == "limit"``)
    left out; ``None`` for a trajectory without contacts."""
    entries = getattr(trajectory, "contacts", None)
    if entries is None:
        return None
    if len(entries) != n:
        raise ValueError(f"trajectory.contacts has {len(entries)} entries but the trajectory {n} times; "
                         f"view one trajectory at a time (trajectory.select(k))")
    points, forces = [], []
    for k, entry in enumerate(entries):
        try:
            other, point, force = (np.asarray(getattr(entry, name)) for name in ("other", "point", "force"))
        except AttributeError:
            raise TypeError(f"trajectory.contacts[{k}] must have other (c,), point (c, 3) and force (c, 3), "
                            f"got {type(entry).__name__}") from None
        c = len(other)
        if other.shape != (c,) or point.shape != (c, 3) or force.shape != (c, 3):
            raise ValueError(f"trajectory.contacts[{k}]: other, point and force must have shapes (c,), (c, 3) and "
                             f"(c, 3), got {other.shape}, {point.shape} and {force.shape}")
        touching = other.astype(str) != "limit"
        point, force = point[touching].astype(float), force[touching].astype(float)
        if not (np.all(np.isfinite(point)) and np.all(np.isfinite(force))):
            raise ValueError(f"trajectory.contacts[{k}] (t = {trajectory.t[k]:g} s) has non-finite points or forces")
        points.append(point)
        forces.append(force)
    return points, forces


def _planes(constraints):
    """``(E, point)`` of the planes of rolling constraints."""
    return tuple((np.asarray(c.frame, dtype=float), np.asarray(c.plane_point, dtype=float))
                 for c in constraints if hasattr(c, "contact_point") and hasattr(c, "frame"))


def scene_of(model, q=None, trajectory=None, *, constraints=None, trace=(), force_scale=None, point_radius=None):
    """What :func:`view` draws: a :class:`Scene`. Arguments as in :func:`view`."""
    from .model import Model
    from .kinematics import forward_kinematics

    if not isinstance(model, Model):
        raise TypeError(f"model must be a multibody Model (mb.load_urdf, mb.robots.load), got {type(model).__name__}")
    times, qs = _states(model, q, trajectory)
    traced = _trace_points(model, [trace] if isinstance(trace, str) else trace)
    constraints = _constraint_list(model, constraints)
    if constraints and trajectory is None:
        raise ValueError("constraints: their forces come from a trajectory's multipliers; pass trajectory=")

    X_WB = forward_kinematics(model, qs)                       # (n, nb, 4, 4), once for every frame
    positions = X_WB[..., :3, 3]
    wxyz = _wxyz(X_WB[..., :3, :3])
    traces = {label: spatial.matvec(X_WB[:, b, :3, :3], point) + X_WB[:, b, :3, 3] for label, b, point in traced}

    # The bodies' origins and the eight corners of each shape's box, in the world at every frame: (n, k, 3).
    shapes = body_shapes(model, point_radius or 0.02 * _extent(positions[0].min(axis=0), positions[0].max(axis=0)))
    points = [positions]
    for b, name in enumerate(model.body_names):
        for shape in shapes[name]:
            corners = np.array(list(itertools.product(*zip(shape.vertices.min(axis=0), shape.vertices.max(axis=0)))))
            points.append(np.einsum("nij,kj->nki", X_WB[:, b, :3, :3], corners) + X_WB[:, b, None, :3, 3])
    points = np.concatenate(points, axis=1)
    low, high = points.min(axis=(0, 1)), points.max(axis=(0, 1))
    # The first frame's box sets the view and the scale, so that a body flying off frames nothing.
    start_low, start_high = points[0].min(axis=0), points[0].max(axis=0)
    size = _extent(start_low, start_high)

    if force_scale is not None and not (np.isfinite(force_scale) and force_scale > 0.0):
        raise ValueError(f"force_scale must be a positive length per force (m/N), got {force_scale!r}")
    forces, points, labels, owners, without = np.zeros((len(times), 0, 3)), np.zeros((len(times), 0, 3)), (), [], ()
    if constraints:
        forces, points, labels, owners, without = _constraint_forces(model, constraints, qs, trajectory.lam, X_WB)
    contacts = _contact_forces(trajectory, len(times)) if trajectory is not None else None
    if contacts is not None and not any(len(frame) for frame in contacts[0]):
        contacts = None                                        # joint limits only: nothing to draw
    largest = max([float(np.linalg.norm(forces, axis=-1).max(initial=0.0))]
                  + ([float(np.linalg.norm(f, axis=-1).max(initial=0.0)) for f in contacts[1]] if contacts else []))
    weight = model.total_mass * float(np.linalg.norm(model.gravity))
    scale = 0.0
    if force_scale is not None:
        scale = float(force_scale)
    elif contacts and weight > 0.0:
        # the weight as long as the bodies' size, so that each of a few supports' shares shows; an impact's
        # impulse / dt, hundreds of weights, sets no scale
        scale = _nice(size / weight)
    elif forces.shape[1] or contacts:
        # the largest force a quarter of the bodies' size long, rounded to 1, 2 or 5 × 10^k m/N
        scale = _nice(0.25 * size / largest) if largest > 0.0 else 1.0
    arrows = np.stack([points, points + scale * forces], axis=2)
    colors = np.array([FORCE_COLORS[k % len(FORCE_COLORS)] for k in owners], dtype=np.uint8).reshape(-1, 3)
    contact_points, contact_arrows = (), ()
    if contacts:
        contact_points = tuple(contacts[0])
        # a zero force (a contact the step found but did not push) has no direction to draw
        pushing = [np.linalg.norm(f, axis=-1) > 0.0 for f in contacts[1]]
        contact_arrows = tuple(np.stack([p[m], p[m] + scale * f[m]], axis=1) for p, f, m in zip(*contacts, pushing))
    return Scene(body_names=tuple(model.body_names), times=times, positions=positions, wxyz=wxyz, shapes=shapes,
                 traces=traces, arrows=arrows, arrow_labels=tuple(labels), arrow_colors=colors,
                 contact_points=contact_points, contact_arrows=contact_arrows, force_scale=scale,
                 largest_force=largest, no_arrows=without, planes=_planes(constraints), low=low, high=high,
                 start_low=start_low, start_high=start_high)


# ----------------------------------------------------------------------------- serving it

def _import_viser():
    try:
        import viser
    except ImportError as error:
        raise ImportError(INSTALL_HINT) from error
    return viser


def _quiet():
    """Viser prints a banner when it starts and a line when it stops, whatever its ``verbose``; the
    viewer's URL is ``Viewer.url``, and the command line prints it."""
    return contextlib.redirect_stdout(io.StringIO())


def _node_name(body):
    """A scene-tree name for a body: Viser reads ``/`` as nesting."""
    return "/bodies/" + str(body).replace("/", "_").replace(" ", "_")


def _identities(count):
    """``(count, 4)`` Viser's ``[w, x, y, z]`` of the identity rotation, one per instance."""
    return np.tile([1.0, 0.0, 0.0, 0.0], (count, 1))


def _wxyz(R):
    """Viser's quaternions ``[w, x, y, z] (..., 4)`` of the rotations ``R (..., 3, 3)``."""
    return np.roll(spatial.rotation_to_quat(R), 1, axis=-1)


class Viewer:
    """A running 3-D view (see the module docstring); made by :func:`view`.

    Attributes:
        scene: the :class:`Scene` drawn.
        server: the ``viser.ViserServer``.
        url: where to open it; port: the port it listens on.
        nodes: body name -> its Viser frame node (the body's shapes hang below it).
        slider: the time slider (``None`` for a single configuration); layers: name -> show/hide checkbox.
    """

    def __init__(self, scene, *, host="127.0.0.1", port=8080, speed=1.0, frames=True, title=None):
        viser = _import_viser()
        if not isinstance(port, (int, np.integer)) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise ValueError(f"port must be an integer in 0..65535 (0: any free port), got {port!r}")
        if not (np.isfinite(speed) and speed > 0.0):
            raise ValueError(f"speed must be a positive factor of real time, got {speed!r}")
        self.scene = scene
        self._lock = threading.RLock()
        self._closed = threading.Event()
        self._frame = 0
        self._playing = False
        self._speed = float(speed)
        with _quiet():
            self.server = viser.ViserServer(host=host, port=int(port), label=title or "multibody", verbose=False)
        self.port = self.server.get_port()
        self.url = f"http://{'localhost' if host in ('127.0.0.1', '0.0.0.0', 'localhost') else host}:{self.port}"
        try:
            self._build(frames)
        except BaseException:
            with _quiet():
                self.server.stop()
            raise
        self._player = None
        if scene.frames > 1:
            self._player = threading.Thread(target=self._play_loop, name="multibody viewer playback", daemon=True)
            self._player.start()

    # ------------------------------------------------------------------ building the page

    def _build(self, frames):
        scene, server = self.scene, self.server
        s = scene.size
        server.initial_camera.look_at = tuple(scene.center)
        server.initial_camera.position = tuple(scene.center + s * np.array([0.5, -0.7, 0.4]))
        server.scene.add_frame("/world", axes_length=0.12 * s, axes_radius=0.004 * s)
        # cells on the bodies' scale, the grid around where they start and wide enough for the whole motion
        cell = _nice(s / 10.0)
        reach = np.linalg.norm(np.maximum(np.abs(scene.low - scene.center), np.abs(scene.high - scene.center)))
        extent = 2.0 * cell * math.ceil(max(0.6 * s, reach) / cell)
        if scene.planes:
            ground = []
            for k, (E, point) in enumerate(scene.planes):
                # centred under the bodies: their centre projected onto the plane
                normal = E[:, 2]
                origin = scene.center - ((scene.center - point) @ normal) * normal
                ground.append(server.scene.add_grid(f"/ground/plane_{k}", extent, extent, cell_size=cell,
                                                    section_size=5 * cell, plane_color=(225, 230, 240),
                                                    plane_opacity=0.6, wxyz=_wxyz(E), position=origin))
        else:
            # at z = 0, or under the lowest point of a motion that reaches below it (a hanging pendulum)
            origin = np.array([scene.center[0], scene.center[1], min(0.0, scene.low[2])])
            ground = [server.scene.add_grid("/ground/z0", extent, extent, cell_size=cell, section_size=5 * cell,
                                            position=origin)]
        self.nodes = {}
        for b, name in enumerate(scene.body_names):
            node = server.scene.add_frame(_node_name(name), show_axes=frames, axes_length=0.06 * s,
                                          axes_radius=0.002 * s, wxyz=scene.wxyz[0, b], position=scene.positions[0, b])
            self.nodes[name] = node
            for k, shape in enumerate(scene.shapes[name]):
                child = f"{_node_name(name)}/shape_{k}"
                if shape.mesh is not None:
                    server.scene.add_mesh_trimesh(child, shape.mesh)
                else:
                    server.scene.add_mesh_simple(child, shape.vertices.astype(np.float32), shape.faces.astype(np.uint32),
                                                 color=shape.color, flat_shading=False)
        self._traces = []
        for k, (label, path) in enumerate(scene.traces.items()):
            segments = np.stack([path[:-1], path[1:]], axis=1) if len(path) > 1 else np.zeros((0, 2, 3))
            if len(segments):
                self._traces.append(server.scene.add_line_segments(
                    f"/paths/path_{k}", segments, TRACE_COLORS[k % len(TRACE_COLORS)], thickness=2.0,
                    thickness_units="screen"))
        self._arrows = None
        arrow_shape = dict(shaft_radius=0.004 * s, head_radius=0.01 * s, head_length=0.025 * s)
        if scene.arrows.shape[1]:
            self._arrows = server.scene.add_arrows("/forces", scene.arrows[0], scene.arrow_colors, **arrow_shape)
        self._contacts = []
        if scene.contact_points:
            import trimesh

            dot = trimesh.creation.icosphere(subdivisions=2, radius=0.012 * s)
            self._contacts = [
                server.scene.add_batched_meshes_simple(
                    "/contacts/points", dot.vertices.astype(np.float32), dot.faces.astype(np.uint32),
                    batched_wxyzs=_identities(len(scene.contact_points[0])), batched_positions=scene.contact_points[0],
                    batched_colors=CONTACT_POINT_COLOR, cast_shadow=False, receive_shadow=False),
                server.scene.add_arrows("/contacts/forces", scene.contact_arrows[0], CONTACT_FORCE_COLOR, **arrow_shape)]

        gui = server.gui
        self.slider = None
        if scene.frames > 1:
            t0, t1 = float(scene.times[0]), float(scene.times[-1])
            step = float(np.min(np.diff(scene.times)[np.diff(scene.times) > 0.0], initial=max(t1 - t0, 1.0)))
            self._button = gui.add_button("Play")
            self._button.on_click(lambda _: self.pause() if self._playing else self.play())
            self.slider = gui.add_slider("time (s)", min=t0, max=t1, step=min(step, t1 - t0) if t1 > t0 else 1.0,
                                         initial_value=t0)
            self.slider.on_update(lambda _: self._show(self._nearest(self.slider.value)))
            self._speed_input = gui.add_number("speed (× real time)", initial_value=self._speed, min=0.01, max=100.0,
                                               step=0.01)
            self._speed_input.on_update(lambda _: setattr(self, "_speed", float(self._speed_input.value)))
        # each checkbox sets one property of its nodes: whether they show, or whether a body shows its axes
        shown = {"bodies": (list(self.nodes.values()), "visible", True),
                 "body frames": (list(self.nodes.values()), "show_axes", frames),
                 "ground": (ground, "visible", True), "paths": (self._traces, "visible", True),
                 "forces": ([self._arrows] if self._arrows is not None else [], "visible", True),
                 "contacts": (self._contacts, "visible", True)}
        self.layers = {}
        for name, (nodes, prop, initial) in shown.items():
            if nodes:
                box = gui.add_checkbox(name, initial_value=bool(initial))
                box.on_update(lambda _, nodes=nodes, prop=prop, box=box: [setattr(node, prop, box.value) for node in nodes])
                self.layers[name] = box
        self._force_scale = scene.force_scale
        self._scale_input = None
        if self._arrows is not None or self._contacts:
            # steps of a hundredth of the starting scale, down to one step
            fine = scene.force_scale / 100.0
            self._scale_input = gui.add_number("force scale (m/N)", initial_value=scene.force_scale, min=fine, step=fine)
            self._scale_input.on_update(lambda _: self._set_force_scale(max(self._scale_input.value, fine)))
        notes = []
        if self._traces:
            notes.append("paths: " + ", ".join(scene.traces))
        if self._arrows is not None or self._contacts:
            notes.append(f"force arrows: largest force {scene.largest_force:.3g} N")
        if self._contacts:
            notes.append("contacts: points and forces on the bodies (joint limits not drawn)")
        if scene.no_arrows:
            notes.append("no force arrows (they act on coordinates): " + ", ".join(scene.no_arrows))
        if notes:
            gui.add_markdown("  \n".join(notes))

    # ------------------------------------------------------------------ showing a time

    @property
    def times(self):
        """``(n,)`` the frames' times (s)."""
        return self.scene.times

    @property
    def frame(self):
        """Index of the frame shown."""
        return self._frame

    @property
    def time(self):
        """The time shown (s); setting it shows the frame nearest to it and moves the slider."""
        return float(self.scene.times[self._frame])

    @time.setter
    def time(self, t):
        if not np.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        k = self._nearest(t)
        self._show(k)
        if self.slider is not None:
            with self._lock:
                self.slider.value = float(self.scene.times[k])

    def _nearest(self, t):
        times = self.scene.times
        k = int(np.clip(np.searchsorted(times, t), 1, max(len(times) - 1, 1)))
        return k - 1 if len(times) == 1 or abs(times[k - 1] - t) <= abs(times[k] - t) else k

    def _show(self, k):
        """Pose every node as at frame ``k``."""
        scene = self.scene
        with self._lock:
            if self._closed.is_set():
                return
            self._frame = k
            with self.server.atomic():
                for b, name in enumerate(scene.body_names):
                    node = self.nodes[name]
                    node.wxyz = scene.wxyz[k, b]
                    node.position = scene.positions[k, b]
                if self._arrows is not None:
                    self._arrows.points = self._scaled(scene.arrows[k])
                if self._contacts:
                    points, arrows = self._contacts
                    # the instances' count follows the entry's: orientations and positions change together
                    points.batched_wxyzs = _identities(len(scene.contact_points[k]))
                    points.batched_positions = scene.contact_points[k]
                    arrows.points = self._scaled(scene.contact_arrows[k])

    @property
    def force_scale(self):
        """The force arrows' length per force (m/N); setting it redraws them and sets the panel's box."""
        return self._force_scale

    @force_scale.setter
    def force_scale(self, scale):
        self._set_force_scale(scale)
        if self._scale_input is not None:
            self._scale_input.value = float(scale)

    def _set_force_scale(self, scale):
        if not (np.isfinite(scale) and scale > 0.0):
            raise ValueError(f"force_scale must be a positive length per force (m/N), got {scale!r}")
        with self._lock:
            self._force_scale = float(scale)
            self._show(self._frame)

    def _scaled(self, arrows):
        """``(k, 2, 3)`` float32 tails and heads of ``arrows`` (drawn at the scene's scale) at the chosen
        force scale: the tails stay, the heads move along the forces."""
        if self._force_scale == self.scene.force_scale:
            return arrows.astype(np.float32)
        tails = arrows[:, 0]
        heads = tails + (self._force_scale / self.scene.force_scale) * (arrows[:, 1] - tails)
        return np.stack([tails, heads], axis=1).astype(np.float32)

    # ------------------------------------------------------------------ playback

    @property
    def playing(self):
        return self._playing

    def play(self):
        """Play the trajectory from the time shown, looping, at the chosen speed."""
        if self.scene.frames > 1:
            self._playing = True
            self._button.label = "Pause"

    def pause(self):
        self._playing = False
        if self.scene.frames > 1:
            self._button.label = "Play"

    def _play_loop(self):
        times = self.scene.times
        last = _time.perf_counter()
        while not self._closed.wait(1.0 / 30.0):
            now = _time.perf_counter()
            if self._playing:
                t = self.time + (now - last) * self._speed
                if t > times[-1]:
                    t = times[0]
                try:
                    self.time = t
                except Exception:  # the server was stopped under us
                    if self._closed.is_set():
                        return
                    raise
            last = now

    # ------------------------------------------------------------------ saving and closing

    def save_html(self, path):
        """Write one self-contained HTML page that shows the scene and replays the trajectory offline
        (Viser's scene recording, with its own play/pause and time bar, looping); returns the path.

        The page holds the shapes and every frame's poses (at most :data:`OFFLINE_FRAMES` frames; longer
        trajectories keep every k-th), played at the viewer's speed. Browsers watching the live page
        see the motion run through while it is recorded; the time shown is restored afterwards.
        """
        path = os.fspath(path)
        if self._closed.is_set():
            raise RuntimeError("the viewer is closed")
        was_playing, shown = self._playing, self._frame
        self.pause()
        times = self.scene.times
        indices = np.arange(0, len(times), max(1, math.ceil(len(times) / OFFLINE_FRAMES)))
        with self._lock:
            self._show(int(indices[0]))
            serializer = self.server.get_scene_serializer()
            for previous, k in zip(indices[:-1], indices[1:]):
                serializer.insert_sleep(float(times[k] - times[previous]) / self._speed)
                self._show(int(k))
            if len(indices) > 1:
                serializer.insert_sleep(float(times[indices[-1]] - times[indices[-2]]) / self._speed)
            html = serializer.as_html()
            self._show(shown)
        with open(path, "w", encoding="utf-8") as file:
            file.write(html)
        if was_playing:
            self.play()
        return path

    @property
    def closed(self):
        return self._closed.is_set()

    def close(self):
        """Stop playback and the server, and free the port. Closing twice does nothing."""
        if self._closed.is_set():
            return
        with self._lock:
            self._closed.set()
            self._playing = False
        if self._player is not None:
            self._player.join(timeout=2.0)
        with _quiet():
            self.server.stop()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        state = "closed" if self.closed else self.url
        return f"Viewer({len(self.scene.body_names)} bodies, {self.scene.frames} frames, {state})"


def view(model, q=None, trajectory=None, *, constraints=None, port=8080, **options):
    """Serve a 3-D view of ``model`` in the browser (Viser) and return its :class:`Viewer`.

    Args:
        model: a :class:`~multibody.model.Model`.
        q: one configuration ``(nq,)`` to show (default ``model.neutral()``); not with ``trajectory``.
        trajectory: a :class:`~multibody.trajectory.Trajectory` (``t (n,)``, ``q (n, nq)``) to play; its
            ``contacts``, when it has them, are drawn as points and force arrows.
        constraints: the constraints that were simulated (a ``ConstrainedSystem`` or a list, in its order),
            to draw their forces from ``trajectory.lam`` as arrows (see the module docstring).
        port: where to listen (the next free one when taken; ``0``: any free port). ``viewer.port`` is
            the one used.
        **options:
            trace: bodies whose paths are drawn: names, or ``(name, point (3,) in the body frame, m)``.
            force_scale: arrow length per newton (m/N) of the constraint and contact forces; default: the
                largest force a quarter as long as the bodies' bounding box at the first frame, or, with
                contacts, the model's weight (total mass × |g|) as long (an impact's impulse / dt can
                be hundreds of weights), rounded to 1, 2 or 5 × 10^k. The panel's box changes it.
            speed: playback speed, a factor of real time (default 1).
            frames: draw each body's frame axes (default ``True``).
            host: the interface to listen on (default ``"127.0.0.1"``, this machine only; ``"0.0.0.0"``:
                every interface).
            title: the label of the control panel.
            point_radius: radius (m) of the sphere drawn for a point mass (default 2 % of the scene).

    Raises:
        ImportError: Viser is not installed (``pip install multibody[viz]``).
        TypeError, ValueError: input that does not fit the model (named in the message).
    """
    known = {"trace", "force_scale", "speed", "frames", "host", "title", "point_radius"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise TypeError(f"view() got unknown options {unknown}; it takes {sorted(known)}")
    _import_viser()
    scene = scene_of(model, q, trajectory, constraints=constraints, trace=options.get("trace", ()),
                     force_scale=options.get("force_scale"), point_radius=options.get("point_radius"))
    return Viewer(scene, host=options.get("host", "127.0.0.1"), port=port, speed=options.get("speed", 1.0),
                  frames=options.get("frames", True), title=options.get("title"))
