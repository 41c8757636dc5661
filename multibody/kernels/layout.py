"""The layout of the compiled tree: a :class:`~multibody.model.Model` flattened once
(:func:`multibody.tree.compile_tree`) into immutable arrays that the kernels read.

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

PARENT, KIND, IQ, IV, NQ, NV = range(6)
ROTATION, POSITION, AXIS, INERTIA, ARMATURE = 0, 9, 12, 15, 25
#: Columns of a row of ``reals``: a joint has at most six coordinates, each with its armature
REAL_SIZE = ARMATURE + 6
GRAVITY = 0
#: Columns of a frame row: the joint that moves it, then its pose in that joint's frame
FRAME_JOINT, FRAME_ROTATION, FRAME_POSITION = 0, 1, 10
FRAME_SIZE = 13


class CompiledTree(NamedTuple):
    """The arrays of a compiled tree (module docstring) and its sizes."""

    joints: np.ndarray
    reals: np.ndarray
    bodies: np.ndarray
    joint_frames: np.ndarray
    nq: int
    nv: int
    njoints: int
