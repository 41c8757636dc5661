"""The compiled tree: a :class:`~multibody.model.Model` flattened once into immutable arrays that the
kernels (:mod:`multibody.kernels`) read, in the layout of :mod:`multibody.kernels.layout`.
"""

from __future__ import annotations

import numpy as np

from .joints import kind_code
from .kernels.layout import (ARMATURE, AXIS, FRAME_JOINT, FRAME_POSITION, FRAME_ROTATION, FRAME_SIZE, GRAVITY, INERTIA,
                             IQ, IV, KIND, NQ, NV, PARENT, POSITION, REAL_SIZE, ROTATION, CompiledTree)

__all__ = ["ARMATURE", "AXIS", "FRAME_JOINT", "FRAME_POSITION", "FRAME_ROTATION", "FRAME_SIZE", "GRAVITY", "INERTIA", "IQ",
           "IV", "KIND", "NQ", "NV", "PARENT", "POSITION", "REAL_SIZE", "ROTATION", "CompiledTree", "compile_tree",
           "frame_rows", "kind_code"]


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
        reals[i, INERTIA:ARMATURE] = (inertia.mass, *(inertia.mass * c), *rotational[np.triu_indices(3)])
        reals[i, ARMATURE:ARMATURE + joint.nv] = model.armature[model.idx_v[i] : model.idx_v[i] + joint.nv]
    reals[nj, GRAVITY:GRAVITY + 3] = model.gravity
    bodies = frame_rows(model, [(b, np.eye(4)) if model.body_joints[b] >= 0 else (None, model.body_placements[b])
                                for b in range(model.nbodies)])
    joint_frames = np.zeros((nj, FRAME_SIZE))
    joint_frames[:, FRAME_JOINT] = np.arange(nj)
    joint_frames[:, FRAME_ROTATION:FRAME_POSITION] = np.eye(3).reshape(9)
    return CompiledTree(_frozen(joints), _frozen(reals), _frozen(bodies), _frozen(joint_frames), model.nq, model.nv, nj)
