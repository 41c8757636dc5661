"""Forward kinematics, Jacobians and their time variation, batched over leading axes.

Each function validates its inputs and hands them to a compiled kernel of
:mod:`multibody.kernels.kinematics` through the batch driver. Naming: ``R_WJ, p_WJ`` is the pose of
joint frame J in the world W.

A body's frame F, or with ``point`` the frame at that point with the body's axes (Pinocchio's frame
with that placement), has its velocity and Jacobian in one of Pinocchio's three references
(``reference``, rows always ``[linear; angular]``):

=========================  ===========================================================================
``reference``              velocity ``J v``
=========================  ===========================================================================
``"local_world_aligned"``  ``[ẋ; ω]``: the velocity of F's origin and the angular velocity, world axes
                           (the default; Pinocchio's ``LOCAL_WORLD_ALIGNED``)
``"world"``                the body's spatial velocity in world Plücker coordinates, ``[ẋ − ω × x; ω]``:
                           the velocity of the body point at the world origin (``WORLD``)
``"local"``                ``[R_WFᵀ ẋ; R_WFᵀ ω]``: both in F's axes (``LOCAL``)
=========================  ===========================================================================

``J̇`` is the time derivative of the Jacobian in the same reference (Pinocchio's
``getFrameJacobianTimeVariation``), so ``J a + J̇ v`` is the derivative of the velocity: the classical
acceleration ``[ẍ; ω̇]`` world-aligned, the spatial acceleration in the other two.
"""

from __future__ import annotations

import numpy as np

from . import driver, spatial
from .kernels import kinematics as kernels
from .spatial import matvec
from .tree import frame_rows


def frame_world_placements(model, q, rows, batch, out=None, shape=None):
    """World placements ``(..., k, 4, 4)`` of the frame ``rows (k, 13)`` (``shape``: another shape of one
    state's, such as ``(4, 4)`` for one frame), into ``out`` when given (:func:`multibody.driver.evaluate`)."""
    return driver.evaluate(kernels.frame_placements, model.tree, (q,), (len(rows), 16), batch, rows, out=out,
                           shape=(len(rows), 4, 4) if shape is None else shape)


def joint_world_poses(model, q):
    """World pose of every joint frame: ``R_WJ (..., nj, 3, 3)``, ``p_WJ (..., nj, 3)``."""
    q = model.check_configuration(q)
    X = frame_world_placements(model, q, model.tree.joint_frames, q.shape[:-1])
    return X[..., :3, :3], X[..., :3, 3]


def forward_kinematics(model, q, *, out=None):
    """World placements of every body: ``(..., nbodies, 4, 4)``, in ``model.body_names`` order.

    ``q (..., nq)``; ``out``: a C-contiguous float64 array of the result's shape that receives it and is
    returned. Pinocchio counterpart: ``forwardKinematics`` + ``updateFramePlacements``.
    """
    q = model.check_configuration(q)
    return frame_world_placements(model, q, model.tree.bodies, q.shape[:-1], out)


def _point(point):
    """A body-frame point ``(..., 3)`` (m) as a float array, ``None`` for the body origin."""
    if point is None:
        return None
    if np.iscomplexobj(point):
        raise ValueError(f"point must be real, got {np.asarray(point).dtype}")
    try:
        point = np.asarray(point, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"point must be a real numeric array of shape (..., 3), got {point!r}") from None
    if point.shape[-1:] != (3,):
        raise ValueError(f"point must have shape (..., 3), got {point.shape}")
    return point


#: The kernels' code of each ``reference`` (module docstring), as the one-entry vector they read
_REFERENCES = {"world": kernels.WORLD, "local": kernels.LOCAL, "local_world_aligned": kernels.LOCAL_WORLD_ALIGNED}
_REFERENCE_VECTORS = {name: np.array([float(code)]) for name, code in _REFERENCES.items()}


def _reference(reference):
    """The kernels' vector of a ``reference`` name; ``ValueError`` lists the names."""
    try:
        return _REFERENCE_VECTORS[reference]
    except (KeyError, TypeError):
        raise ValueError(f"reference must be one of {', '.join(map(repr, _REFERENCES))}, got {reference!r}") from None


def frame_placement(model, q, name, *, out=None):
    """World placement of one body's frame: ``(..., 4, 4)`` homogeneous ``X_WF`` (rotation, then
    position in m).

    ``name`` is any URDF link in ``model.body_names`` (links attached by fixed joints included, and
    links fixed to the world), or its index. Computes that frame only; :func:`forward_kinematics`
    gives every body at once. ``out`` as :func:`forward_kinematics`. Pinocchio counterpart:
    ``updateFramePlacements`` + ``data.oMf``.
    """
    q, rows = model.check_configuration(q), model.body_frame_row(name)
    return frame_world_placements(model, q, rows, q.shape[:-1], out, (4, 4))


def jacobian(model, q, body, point=None, reference="local_world_aligned", *, out=None):
    """Jacobian of a body's frame: ``(..., 6, nv)``, rows ``[linear; angular]`` in ``reference``
    (module docstring): ``J(q) v`` is the frame's velocity.

    ``body`` is a name from ``model.body_names`` or an index; ``point (..., 3)`` (body-frame
    coordinates, m; default the body origin) places the frame at that point with the body's axes.
    With the default ``reference="local_world_aligned"``, ``[ẋ; ω] = J v`` in world axes. ``out`` as
    :func:`forward_kinematics`. Pinocchio counterpart: ``getFrameJacobian`` with ``LOCAL_WORLD_ALIGNED``,
    ``WORLD`` or ``LOCAL``.
    """
    if point is None and out is None and model.is_one_state(q, finite=False):
        J = driver.evaluate_one(kernels.frame_jacobian, model.tree, (6, model.nv), q, driver.NO_INPUT,
                                _reference(reference), frames=model.body_frame_row(body))
        if driver.vouches(J):
            return J
    q, rows, point = model.check_configuration(q), model.body_frame_row(body), _point(point)
    batch = q.shape[:-1] if point is None else spatial.batch_shape(q.shape[:-1], point.shape[:-1])
    return driver.evaluate(kernels.frame_jacobian, model.tree, (q, point, _reference(reference)), (6, model.nv),
                           batch, rows, out=out)


def jacobian_time_variation(model, q, v, body, point=None, reference="local_world_aligned", *, out=None):
    """Time derivative ``J̇(q, v)`` of :func:`jacobian`, in the same ``reference``, along the motion:
    ``(..., 6, nv)``.

    ``J a + J̇ v`` is the time derivative of the frame's velocity ``J v``: the classical acceleration
    ``[ẍ; ω̇]`` for ``"local_world_aligned"``, the spatial acceleration for ``"world"`` and ``"local"``.
    ``out`` as :func:`forward_kinematics`. Pinocchio counterpart: ``getFrameJacobianTimeVariation`` with
    the same reference.
    """
    q, v = model.check_configuration(q), model.check_velocity(v)
    rows, point = model.body_frame_row(body), _point(point)
    shapes = (q.shape[:-1], v.shape[:-1]) + (() if point is None else (point.shape[:-1],))
    return driver.evaluate(kernels.frame_jacobian_time_variation, model.tree, (q, v, point, _reference(reference)),
                           (6, model.nv), spatial.batch_shape(*shapes), rows, out=out)


def frame_arguments(model, body, placement):
    """``(b, X_BF)``: the index of ``body`` (``None`` for the world) and the frame's 4×4 pose in it,
    validated (identity for ``None``)."""
    X_BF = np.eye(4) if placement is None else np.asarray(placement, dtype=float)
    if X_BF.shape != (4, 4):
        raise ValueError(f"placement must have shape (4, 4), got {X_BF.shape}")
    return (None if body is None else model.body_index(body)), X_BF


def frame_motions(model, q, v, frames, batch):
    """``[(R_WF, p_WF, J, J̇v), ...]`` (see :func:`frame_kinematics`) of ``frames``, ``(body index or None,
    X_BF)`` pairs, from one compiled pass (:func:`multibody.kernels.kinematics.frame_motions`)."""
    nv = model.nv
    out = driver.evaluate(kernels.frame_motions, model.tree, (q, v), (len(frames), kernels.motion_columns(nv)), batch,
                          frame_rows(model, frames))
    J = kernels.MOTION_JACOBIAN
    return [(out[..., k, :J - 3].reshape(batch + (3, 3)), out[..., k, J - 3 : J],
             out[..., k, J : J + 6 * nv].reshape(batch + (6, nv)), out[..., k, J + 6 * nv :]) for k in range(len(frames))]


def frame_kinematics(model, q, v, body, placement=None):
    """Everything a constraint needs about one frame F fixed in a body, from a single tree pass.

    ``placement`` is the 4×4 pose of F in the body frame (default identity); ``body`` a name or
    index, or ``None`` for a frame fixed in the world (then ``placement`` is its world pose).
    Returns ``(R_WF (..., 3, 3), p_WF (..., 3), J (..., 6, nv), J̇v (..., 6))``: the world pose,
    the world-aligned Jacobian of F's origin, and the velocity-product acceleration ``J̇ v``
    (classical linear acceleration of the origin and angular acceleration when ``a = 0``).
    """
    q, v = model.check_configuration(q), model.check_velocity(v)
    return frame_motions(model, q, v, [frame_arguments(model, body, placement)],
                         spatial.batch_shape(q.shape[:-1], v.shape[:-1]))[0]


def point_velocity(model, q, v, body, point=None, reference="local_world_aligned"):
    """Velocity ``J v`` of a body's frame at ``point`` in ``reference`` (module docstring): ``(..., 6)``,
    m/s and rad/s. By default ``[ẋ; ω]`` in world axes.

    Pinocchio counterpart: ``getFrameVelocity`` with the same reference.
    """
    return matvec(jacobian(model, q, body, point, reference), model.check_velocity(v))


def frame_velocity(model, q, v, name, reference="local_world_aligned"):
    """Velocity ``[linear; angular]`` of the frame of the body ``name`` in ``reference`` (module docstring):
    ``(..., 6)``, m/s and rad/s; :func:`point_velocity` at the frame's origin.

    Pinocchio counterpart: ``getFrameVelocity(model, data, frame_id, reference)``.
    """
    return point_velocity(model, q, v, name, None, reference)


def point_acceleration(model, q, v, a, body, point=None, reference="local_world_aligned"):
    """``J a + J̇ v`` of a body's frame at ``point`` in ``reference``: ``(..., 6)``, m/s² and rad/s²; the
    time derivative of :func:`point_velocity`.

    * ``"local_world_aligned"`` (default): ``[ẍ; ω̇]`` in world axes, ``ẍ`` the classical (not spatial)
      acceleration; Pinocchio's ``getFrameClassicalAcceleration(..., LOCAL_WORLD_ALIGNED)``.
    * ``"world"``: the spatial acceleration in world Plücker coordinates; ``getFrameAcceleration(...,
      WORLD)``.
    * ``"local"``: the spatial acceleration in the frame's axes; ``getFrameAcceleration(..., LOCAL)``.

    With ``a = 0`` this is the velocity-product term ``J̇ v`` that acceleration-level constraints need.
    """
    a = model.check_velocity(a, "a")
    return (matvec(jacobian(model, q, body, point, reference), a)
            + matvec(jacobian_time_variation(model, q, v, body, point, reference), v))
