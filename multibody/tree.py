"""The compiled tree: a :class:`~multibody.model.Model` flattened once into immutable arrays that the
kernels (:mod:`multibody.kernels`) read.

``joints (nj, 6) int64``, one row per moving joint, parents before children:

=========  ==============================================================
column     meaning
=========  ==============================================================
PARENT     index of the parent joint, ``-1`` for the world
KIND       kind code of :mod:`multibody.kernels.joints`
IQ, IV     start of the joint's block in ``q`` and in ``v``
NQ, NV     sizes of those blocks
=========  ==============================================================

``reals (nj + 1, 31) float64``: row ``i < nj`` holds joint i's placement ``X_λ(i),P = (R_T, p_T)``
(the pose of its pre-joint frame in the parent joint's frame: ``R_T`` row-major at ``ROTATION``,
``p_T`` at ``POSITION``), its unit ``AXIS`` (revolute and prismatic kinds), the ``INERTIA`` of the
rigid body it moves, ``(m, h, Ī)`` about the joint frame's origin in its axes (see
:mod:`multibody.kernels.spatial`), and at ``ARMATURE + k`` the armature of its coordinate ``k``
(``model.armature``, kg m² or kg; zero past the joint's ``NV``), which the kernels read through
:func:`multibody.kernels.placement.armature`. Row ``nj`` is the world: ``GRAVITY`` (m/s², world axes).

``bodies (nb, 13) float64``: per URDF link, the joint that moves it (``-1`` when fixed to the world)
and its pose ``(R_JB, p_JB)`` in that joint's frame (in the world frame when fixed to it), as
``[joint, R (9), p (3)]``: the layout of every frame a kernel is asked about. ``joint_frames (nj, 13)``
holds the rows of the joint frames themselves.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import joints as jt
from .kernels import joints as kinds

PARENT, KIND, IQ, IV, NQ, NV = range(6)
ROTATION, POSITION, AXIS, INERTIA, ARMATURE = 0, 9, 12, 15, 25
#: Columns of a row of ``reals``: a joint has at most six coordinates, each with its armature
REAL_SIZE = ARMATURE + 6
GRAVITY = 0
#: Columns of a frame row: the joint that moves it, then its pose in that joint's frame
FRAME_JOINT, FRAME_ROTATION, FRAME_POSITION = 0, 1, 10
FRAME_SIZE = 13

_KIND_CODES = {jt.Revolute: kinds.REVOLUTE, jt.Continuous: kinds.REVOLUTE, jt.Prismatic: kinds.PRISMATIC,
               jt.Spherical: kinds.SPHERICAL, jt.FreeFlyer: kinds.FREE_FLYER, jt.Planar: kinds.PLANAR,
               jt.Translation: kinds.TRANSLATION}


class CompiledTree(NamedTuple):
    """The arrays of a compiled tree (module docstring) and its sizes."""

    joints: np.ndarray
    reals: np.ndarray
    bodies: np.ndarray
    joint_frames: np.ndarray
    nq: int
    nv: int
    njoints: int


def kind_code(joint) -> int:
    """The kernel kind code of a :mod:`multibody.joints` joint."""
    try:
        return _KIND_CODES[type(joint)]
    except KeyError:
        raise TypeError(f"joint type {type(joint).__name__} has no compiled kind") from None


def frame_rows(model, frames):
    """``(k, 13)`` frame rows (read-only) (module docstring) of ``(body index or None, X_BF (4, 4))`` pairs: each
    frame's joint and its pose in that joint's frame (in the world when fixed to it)."""
    rows = np.zeros((len(frames), FRAME_SIZE))
    for row, (b, X_BF) in zip(rows, frames):
        if b is None:
            joint, X_JF = -1, X_BF
        else:
            joint, X_JF = model.body_joints[b], model.body_placements[b] @ X_BF
        row[FRAME_JOINT] = joint
        row[FRAME_ROTATION:FRAME_POSITION] = X_JF[:3, :3].reshape(9)
        row[FRAME_POSITION:FRAME_SIZE] = X_JF[:3, 3]
    return _frozen(rows)


def _frozen(array):
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


def compile_tree(model) -> CompiledTree:
    """Flatten ``model`` into a :class:`CompiledTree`."""
    nj = model.njoints
    joints = np.zeros((nj, 6), dtype=np.int64)
    reals = np.zeros((nj + 1, REAL_SIZE))
    for i, joint in enumerate(model.joints):
        joints[i] = (model.parents[i], kind_code(joint), model.idx_q[i], model.idx_v[i], joint.nq, joint.nv)
        X_T = model.joint_placements[i]
        reals[i, ROTATION:POSITION] = X_T[:3, :3].reshape(9)
        reals[i, POSITION:AXIS] = X_T[:3, 3]
        reals[i, AXIS:INERTIA] = getattr(joint, "axis", (0.0, 0.0, 1.0))
        inertia = model.joint_inertias[i]
        # Ī about the joint frame's origin: Ī_c − m [c]×²
        c = inertia.com
        rotational = inertia.rotational + inertia.mass * (c @ c * np.eye(3) - np.outer(c, c))
        reals[i, INERTIA:ARMATURE] = (inertia.mass, *(inertia.mass * c), rotational[0, 0], rotational[0, 1],
                                      rotational[0, 2], rotational[1, 1], rotational[1, 2], rotational[2, 2])
        reals[i, ARMATURE:ARMATURE + joint.nv] = model.armature[model.idx_v[i] : model.idx_v[i] + joint.nv]
    reals[nj, GRAVITY:GRAVITY + 3] = model.gravity
    bodies = frame_rows(model, [(b, np.eye(4)) if model.body_joints[b] >= 0 else (None, model.body_placements[b])
                                for b in range(model.nbodies)])
    joint_frames = np.zeros((nj, FRAME_SIZE))
    joint_frames[:, FRAME_JOINT] = np.arange(nj)
    joint_frames[:, FRAME_ROTATION:FRAME_POSITION] = np.eye(3).reshape(9)
    return CompiledTree(_frozen(joints), _frozen(reals), _frozen(bodies), _frozen(joint_frames), model.nq, model.nv, nj)
