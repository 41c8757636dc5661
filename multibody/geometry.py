"""Visual and collision shapes: meshes loaded with trimesh only when asked for, and the collision table.

The dynamics never needs these: a model loads without reading any mesh, and a mesh that cannot be
found or read is a warning for the viewer (:func:`load_meshes`). Contact detection reads the model's
collision shapes (:attr:`multibody.model.Model.collision_geometries`) once, as the arrays of a
:class:`CollisionTable` (:func:`collision_table`), the convex hull of each collision mesh included.
"""

from __future__ import annotations

import functools
import warnings
import weakref
from typing import NamedTuple

import numpy as np

from .kernels.collision import BOX, CAPSULE, CONVEX, CYLINDER, SPHERE

#: The shapes a collision geometry may have: primitives, a mesh (its convex hull) and a convex set of vertices.
COLLISION_SHAPES = ("sphere", "box", "capsule", "cylinder", "mesh", "convex")

#: The shape code of each collision shape (a mesh is the convex hull of its vertices).
SHAPE_CODES = {"sphere": SPHERE, "box": BOX, "capsule": CAPSULE, "cylinder": CYLINDER, "mesh": CONVEX,
               "convex": CONVEX}

#: How many numbers give the size of each primitive (:class:`multibody.model.Geometry`).
_SIZE_COUNTS = {"sphere": 1, "box": 3, "capsule": 2, "cylinder": 2}

#: Relative size of the smallest principal extent of a point set below which it counts as flat (no volume).
_FLAT = 1e-9


class CollisionTable(NamedTuple):
    """A model's collision geometries as C-contiguous arrays, in the order of ``model.collision_geometries``
    (``G`` geometries, ``V`` vertices in all):

    * ``shapes (G,) int64``: :data:`SPHERE`, :data:`BOX`, :data:`CAPSULE`, :data:`CYLINDER` or :data:`CONVEX`;
    * ``frames (G,) int64``: the index of the geometry's body in ``model.body_names``;
    * ``placements (G, 4, 4) float64``: the pose of the geometry frame in its body frame (m);
    * ``sizes (G, 3) float64``: m, as the kernels read them: sphere ``(r, 0, 0)``; box its half-extents
      ``(hx, hy, hz)``; capsule ``(r, h, 0)`` and cylinder ``(r, h, 0)`` with ``h`` half the length along z
      (a capsule's between the centres of its hemispheres); convex ``(0, 0, 0)``;
    * ``vertex_ranges (G, 2) int64``: ``(start, count)`` of a convex geometry's hull vertices in ``vertices``,
      count 0 for a primitive;
    * ``vertices (V, 3) float64``: the hull vertices, each in its geometry frame (m); one row of zeros when no
      geometry is convex, so that the array is never empty;
    * ``names (G,)``: a tuple of the geometries' body names, for messages.
    """

    shapes: np.ndarray
    frames: np.ndarray
    placements: np.ndarray
    sizes: np.ndarray
    vertex_ranges: np.ndarray
    vertices: np.ndarray
    names: tuple


# One table per model (models are immutable; the table goes with its model).
_TABLES = weakref.WeakKeyDictionary()


def collision_table(model) -> CollisionTable:
    """The :class:`CollisionTable` of ``model.collision_geometries``, built on the first call and kept with
    the model.

    Raises ``ValueError`` naming the body and the shape of a geometry without positive size (a URDF box of
    size 0, say), and naming the body and the file of a mesh whose convex hull cannot be read.
    """
    table = _TABLES.get(model)
    if table is None:
        table = _TABLES[model] = _build_table(model)
    return table


def _build_table(model):
    geometries = model.collision_geometries
    count = len(geometries)
    shapes, frames = np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
    placements, sizes = np.zeros((count, 4, 4)), np.zeros((count, 3))
    vertex_ranges, hulls, start = np.zeros((count, 2), dtype=np.int64), [], 0
    for g, geometry in enumerate(geometries):
        shapes[g], frames[g] = SHAPE_CODES[geometry.shape], model.body_index(geometry.body)
        placements[g] = geometry.placement
        if shapes[g] == CONVEX:
            hull = convex_vertices(geometry)
            vertex_ranges[g] = start, len(hull)
            hulls.append(hull)
            start += len(hull)
            continue
        size = np.asarray(geometry.size, dtype=float)
        if len(size) != _SIZE_COUNTS[geometry.shape] or not np.all(size > 0.0):
            raise ValueError(f"collision geometry of body {geometry.body!r}: a {geometry.shape} needs "
                             f"{_SIZE_COUNTS[geometry.shape]} positive size(s), got {tuple(geometry.size)}")
        # The kernels measure from the centre: a box's half-extents, half a cylinder's or capsule's length.
        if shapes[g] == SPHERE:
            sizes[g, 0] = size[0]
        elif shapes[g] == BOX:
            sizes[g] = 0.5 * size
        else:
            sizes[g, :2] = size[0], 0.5 * size[1]
    vertices = np.concatenate(hulls) if hulls else np.zeros((1, 3))
    arrays = [np.ascontiguousarray(a) for a in (shapes, frames, placements, sizes, vertex_ranges, vertices)]
    for array in arrays:
        array.setflags(write=False)
    return CollisionTable(*arrays, tuple(geometry.body for geometry in geometries))


def convex_vertices(geometry) -> np.ndarray:
    """``(k, 3)`` vertices of the convex hull of a ``"convex"`` or ``"mesh"`` :class:`~multibody.model.Geometry`
    in its geometry frame, m: its ``vertices``, or its mesh file's hull, scaled (:func:`mesh_hull`).
    ``ValueError`` naming the body and the file when that cannot be read or has no volume."""
    if geometry.vertices is not None:
        return geometry.vertices
    try:
        return mesh_hull(geometry.filename, tuple(geometry.scale))
    except ValueError as problem:
        raise ValueError(f"collision mesh {geometry.filename!r} of body {geometry.body!r}: {problem}") from None


@functools.lru_cache(maxsize=256)
def mesh_hull(filename, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """``(k, 3)`` vertices of the convex hull of the mesh file ``filename`` (read by trimesh) scaled by
    ``scale`` (3,), in the mesh's frame (m); read once per file and scale. ``ValueError`` when the file
    cannot be read or its hull has no volume."""
    import trimesh

    try:
        mesh = trimesh.load(filename, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ValueError(f"cannot be read: {exc}") from None
    if len(mesh.vertices) == 0:
        raise ValueError("cannot be read: trimesh finds no vertices in it")
    return hull_vertices(np.asarray(mesh.vertices, dtype=float) * np.asarray(scale, dtype=float))


def hull_vertices(points) -> np.ndarray:
    """The vertices of the convex hull of ``points (k, 3)``, ``(h, 3)`` float64 in the order they come in,
    read-only (Qhull, :class:`scipy.spatial.ConvexHull`).

    ``ValueError`` saying what is wrong when ``points`` is not ``(k, 3)`` finite numbers with ``k ≥ 4`` or
    they lie in one plane (a hull without volume).
    """
    from scipy.spatial import ConvexHull, QhullError

    try:
        points = np.array(points, dtype=float)
    except (TypeError, ValueError):  # (text, or a ragged sequence)
        raise ValueError(f"must be (k, 3) numbers, got {points!r}") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"must have shape (k, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("must be finite, got NaN or infinite entries")
    if len(points) < 4:
        raise ValueError(f"must be at least 4 points for a solid hull, got {len(points)}")
    # The principal extents of the centred points: the smallest is zero for points in one plane.
    extents = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if extents[2] <= _FLAT * extents[0]:
        raise ValueError(f"lie in one plane (principal extents {extents.tolist()}): a convex hull needs volume")
    try:
        hull = ConvexHull(points)
    except QhullError as exc:
        raise ValueError(f"have no convex hull: {str(exc).strip().splitlines()[0]}") from None
    out = np.ascontiguousarray(points[np.sort(hull.vertices)])
    out.setflags(write=False)
    return out


def load_meshes(model, kind="visual"):
    """Meshes of the model's ``kind`` (``"visual"`` or ``"collision"``) shapes, in their body frames.

    Returns a list of ``(geometry, mesh)`` pairs, where ``mesh`` is a ``trimesh.Trimesh`` already
    scaled and placed in the frame of ``geometry.body`` (metres), or ``None`` (with a warning) when
    the file is missing or unreadable.
    """
    import trimesh

    if kind not in ("visual", "collision"):
        raise ValueError(f"kind must be 'visual' or 'collision', got {kind!r}")
    out = []
    for geometry in model.geometries:
        if geometry.kind != kind:
            continue
        mesh = _primitive(trimesh, geometry) if geometry.shape != "mesh" else _read(trimesh, geometry)
        if mesh is not None:
            mesh.apply_transform(geometry.placement)
        out.append((geometry, mesh))
    return out


def _primitive(trimesh, geometry):
    if geometry.shape == "box":
        return trimesh.creation.box(extents=geometry.size)
    if geometry.shape == "sphere":
        return trimesh.creation.icosphere(radius=geometry.size[0])
    if geometry.shape == "ellipsoid":
        # the unit sphere stretched along its axes by the semi-axes
        mesh = trimesh.creation.icosphere(radius=1.0)
        mesh.apply_scale(np.asarray(geometry.size, dtype=float))
        return mesh
    radius, length = geometry.size
    if geometry.shape == "capsule":
        return trimesh.creation.capsule(height=length, radius=radius)
    return trimesh.creation.cylinder(radius=radius, height=length)


def _read(trimesh, geometry):
    if geometry.filename is None:
        warnings.warn(f"mesh {geometry.uri!r} of body {geometry.body!r} not found (see package_dirs)",
                      UserWarning, stacklevel=3)
        return None
    try:
        mesh = trimesh.load(geometry.filename, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        warnings.warn(f"mesh {geometry.filename!r} of body {geometry.body!r} could not be read: {exc}",
                      UserWarning, stacklevel=3)
        return None
    mesh.apply_scale(np.asarray(geometry.scale, dtype=float))
    return mesh
