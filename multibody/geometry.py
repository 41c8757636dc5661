"""Visual and collision shapes, loaded with trimesh only when asked for.

The dynamics never needs these: a model loads without reading any mesh, and a mesh that cannot be
found or read is a warning here, never an error.
"""

from __future__ import annotations

import warnings

import numpy as np


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
