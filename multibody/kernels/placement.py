"""What a kernel reads of a joint from the compiled tree: the pose of its frame in its parent's, the
first step of every pass down the tree, and the armature of its coordinates."""

from __future__ import annotations

from .layout import ARMATURE, AXIS, IQ, KIND, POSITION, ROTATION
from . import joints as kinds
from .jit import njit
from .spatial import row3, row9


# (inlined at Numba's IR level: as a call, its pose comes back through memory, about a tenth of ABA's time on Panda)
@njit(cache=True, error_model="numpy", inline="always")
def joint_pose(joints, reals, q, i):
    """``X_λ(i),i = X_T X_J(q_i)`` (RBDA §4.1): joint i's frame in its parent's, ``(R, p)``, from its
    placement ``X_T`` and its joint transform ``X_J``."""
    return kinds.placed_transform(joints[i, KIND], row3(reals, i, AXIS), q, joints[i, IQ], row9(reals, i, ROTATION),
                                  row3(reals, i, POSITION))


@njit(cache=True, error_model="numpy")
def armature(reals, i, k):
    """The armature (rotor inertia, kg m² or kg) of coordinate ``k`` of joint i: the constant that every
    algorithm adds to the diagonal entry of ``M`` of that coordinate (``model.armature``; Pinocchio's
    ``model.armature``, MuJoCo's ``dof_armature``)."""
    return reals[i, ARMATURE + k]
