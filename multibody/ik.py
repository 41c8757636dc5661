"""Inverse kinematics: configurations that place body frames at target poses or positions, batched over
leading axes of the targets.

The problem and its error
-------------------------
``targets`` maps frame names (``model.body_names``) to a world pose ``X_WT (..., 4, 4)`` or a world
position ``p_WT (..., 3)`` (m). For a pose target the error of the frame F is the logarithm of the
relative pose (J. Solà, J. Deray and D. Atchuthan, "A micro Lie theory for state estimation in
robotics", arXiv:1812.01537, 2018, App. D for SE(3)'s ``exp`` and ``log``)::

    e_F = log(X_WT⁻¹ X_WF) = [ρ; θ]  ∈ se(3)        (6,), m and rad, the target frame's axes

(``θ`` the rotation vector of ``R_WTᵀ R_WF``, ``ρ = V(θ)⁻¹ R_WTᵀ (p_WF − p_WT)``), zero exactly when
``X_WF = X_WT``; for a position target it is ``e_F = p_WF − p_WT (3,)`` in world axes. The errors of
all targets are stacked into ``e (m,)``, and the solver drives ``½ ‖e‖²`` to zero.

The Jacobian of the error
-------------------------
A tangent step ``δ (nv,)``, ``q ← q ⊕ δ = model.integrate(q, δ)``, moves F by the body twist
``J_F δ`` with the LOCAL Jacobian ``J_F`` (:func:`multibody.jacobian` with ``reference="local"``):
``X_WF(q ⊕ δ) ≈ X_WF exp(J_F δ)``. With the right Jacobian ``J_r`` of SE(3) (Solà et al., App. D;
closed form in :mod:`multibody.kernels.ik`), ``log(E exp(τ)) ≈ log(E) + J_r(log E)⁻¹ τ``, so that::

    ∂e_F/∂δ = J_r(e_F)⁻¹ J_F                                         (6, nv)

Pinocchio calls ``J_r⁻¹`` ``Jlog6``. For a position target ``∂e_F/∂δ`` is the linear rows of the
LOCAL_WORLD_ALIGNED Jacobian. Both are exact, which is what lets the step below converge
quadratically near a solution.

The step: damped least squares (Levenberg–Marquardt)
----------------------------------------------------
With ``A = ∂e/∂δ (m, nv)``, each iteration solves the damped least-squares problem
``min ‖e + A δ‖² + μ ‖δ‖²`` (Y. Nakamura and H. Hanafusa, "Inverse kinematic solutions with singularity
robustness for robot manipulator control", J. Dyn. Sys. Meas. Control 108 (1986) 163–171; C. W.
Wampler, "Manipulator inverse kinematic solutions based on vector formulations and damped
least-squares methods", IEEE Trans. SMC 16 (1986) 93–101)::

    δ = −Aᵀ (A Aᵀ + μ I)⁻¹ e  =  −(Aᵀ A + μ I)⁻¹ Aᵀ e

(the smaller of the two systems is solved), with the damping ``μ = λ ‖e‖² + μ₀`` of Yamashita and
Fukushima (Computing Suppl. 15 (2001) 239–249), as T. Sugihara uses it for inverse kinematics
("Solvability-unconcerned inverse kinematics by the Levenberg–Marquardt method", IEEE Trans. Robotics
27 (2011) 984–991): large far from a solution or at an unreachable target, vanishing as ``e → 0`` so
that the last steps are Gauss–Newton steps. ``λ`` starts at ``damping`` and adapts to the gain ratio
``ρ = (‖e‖² − ‖e_new‖²) / (‖e‖² − ‖e + A δ‖²)``: a step that does not lower ``‖e‖`` is refused and
``λ`` grows fourfold; a step that the linear model predicts well (``ρ > ¾``) lets ``λ`` shrink
fourfold (J. J. Moré, "The Levenberg–Marquardt algorithm: implementation and theory", 1978).
``μ₀ = 1e-12`` keeps the system regular where ``A`` loses rank.

Joint limits: a projected step
------------------------------
``model.lower`` and ``model.upper`` bound the angles and displacements (the coordinates of revolute,
prismatic and translation joints, ``±inf`` when unbounded); quaternions and planar ``(cos θ, sin θ)``
pairs have no limits to keep. The start is projected into the box; each step is cut, coordinate by
coordinate, at the box (so every iterate, and the result, lies within the limits); and a coordinate
that sits on a bound while the gradient ``Aᵀ e`` pushes it outward is frozen for that step (its column
of ``A`` left out), so that the other coordinates do the work instead of being dragged by a step that
the bound would cut (a projected Levenberg–Marquardt step with the active set of bound constraints).

Null-space posture
------------------
``posture=q_ref`` picks, among the configurations that meet the targets (a redundant robot has a
continuum of them), one nearest to ``q_ref``. Once ``‖e‖ ≤ tol``, the solver alternates a step along
the motion towards ``q_ref`` that the targets do not see (A. Liégeois, "Automatic supervisory control of
the configuration and behavior of multibody mechanisms", IEEE Trans. SMC 7 (1977) 868–871)::

    n = N (w (q_ref ⊖ q)),    N = I − Aᵀ (A Aᵀ + ε I)⁻¹ A    (ε = 1e-6: the projector onto the null space of A)

taken as ``β n`` (``w = posture_weight``; ``β ≤ 1`` halves when the step would raise ``‖e‖`` above
1e-2, which the curvature of the solution set does at second order, and doubles after a kept step), with
the Gauss–Newton steps on the targets that bring ``‖e‖`` back below ``tol`` (one or two: they converge
quadratically). It stops when a step brings ``q`` less than 1e-9 nearer to ``q_ref``
(``‖q_ref ⊖ q‖``, rad and m), and returns the nearest configuration that met the targets: a local
minimum of the distance to the posture on the solution set, within the limits. The targets alone
decide ``converged``. Without a posture the solver stops at the first configuration that meets them.

Restarts
--------
Damped least squares is a local method: from a poor start it may settle in a local minimum of
``‖e‖``, often with a joint on a limit (from random starts within the limits, a 6-axis UR5 or a 7-axis
Panda reaches a random reachable pose on its first try about half the time; from the middle of its
limits the Panda does so four times in five). A try that stalls (its step vanishes, or ``‖e‖`` has not
halved over the last five steps) starts again from the best, by ``‖e‖``, of eight random
configurations within the limits, up to ``restarts`` times, within ``max_iterations`` steps in all, as
practical solvers do (P. Beeson and B. Ames, "TRAC-IK: an open-source library for improved solving of generic
inverse kinematics", IEEE-RAS Humanoids 2015). A problem that converges on its first try is a purely
local solve from ``q0``; ``restarts=0`` makes every problem one. The result is the best configuration
of all tries: for an unreachable target, the closest one found, with ``converged`` false.

Batches
-------
Target arrays may carry leading batch axes, which broadcast with each other and with those of ``q0``
and ``posture``: each problem of the batch is solved on its own (a batched call equals the single
calls), by the compiled loop of :mod:`multibody.kernels.ik` run in parallel through the batch driver.
Each problem stops as soon as it has converged, so a batch costs the sum of its problems' steps.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from . import driver
from .kernels import ik as kernels

#: Tolerance (on ``|Rᵀ R − I|`` entries) for a target's rotation.
ROTATION_TOLERANCE = 1e-6
#: A try stalls when its step is shorter than this (rad or m) ...
_STEP_TOL = 1e-14
#: ... or when ‖e‖ has not fallen by the factor _PROGRESS over the last _WINDOW steps.
_WINDOW, _PROGRESS = 5, 0.5
#: Each restart starts from the best (smallest error) of this many random configurations.
_CANDIDATES = 8
#: Restart configurations drawn for a model, by (count, integer rng): drawing them costs more than a solve.
_RESTART_TABLES = weakref.WeakKeyDictionary()
#: How many frame names an unknown-frame error lists.
_NAMES_SHOWN = 8


@dataclass(frozen=True)
class InverseKinematicsResult:
    """The outcome of :func:`inverse_kinematics`, batch shape ``B`` (the targets', ``q0``'s and
    ``posture``'s batch axes broadcast; ``()`` for one problem).

    Attributes:
        q: ``B + (nq,)`` the configurations found, within ``model.lower`` and ``model.upper``.
        error: ``B`` the norm ``‖e‖`` of the stacked error of all targets (m and rad together).
        frame_errors: frame name -> ``B + (6,)`` pose error ``log(X_WT⁻¹ X_WF) = [ρ; θ]`` (m, rad; the
            target frame's axes), or ``B + (3,)`` position error ``p_WF − p_WT`` (m, world axes).
        converged: ``B`` bool, ``error ≤ tol``.
        iterations: ``B`` int, the steps tried (accepted or refused, restarts included).
    """

    q: np.ndarray
    error: np.ndarray
    frame_errors: MappingProxyType
    converged: np.ndarray
    iterations: np.ndarray


# ----------------------------------------------------------------------------- input checking

def _frame_names_hint(model):
    """A few of ``model.body_names``, for an error message."""
    names = list(model.body_names)
    shown = ", ".join(map(repr, names[:_NAMES_SHOWN]))
    return shown + (f", ... ({len(names)} in all: model.body_names)" if len(names) > _NAMES_SHOWN else "")


def _target(name, value):
    """A target as a float array and whether it is a pose: ``(..., 4, 4)`` or ``(..., 3)``; ``ValueError``
    naming the frame otherwise."""
    x = np.asarray(value)
    if x.dtype == object or not np.issubdtype(x.dtype, np.number) or np.iscomplexobj(x):
        raise ValueError(f"target of frame {name!r} must be a real numeric array, got dtype {x.dtype}")
    x = x.astype(float, copy=False)
    is_pose = x.ndim >= 2 and x.shape[-2:] == (4, 4)
    if not is_pose and not (x.ndim >= 1 and x.shape[-1] == 3):
        raise ValueError(f"target of frame {name!r} must have shape (..., 4, 4) (a pose) or (..., 3) (a position), "
                         f"got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"target of frame {name!r} contains NaN or infinite values")
    if is_pose:
        if np.any(x[..., 3, :] != (0.0, 0.0, 0.0, 1.0)):
            raise ValueError(f"target pose of frame {name!r} must have the last row [0, 0, 0, 1]")
        R = x[..., :3, :3]
        off = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0)
        if off > ROTATION_TOLERANCE or np.any(np.linalg.det(R) < 0.0):
            raise ValueError(f"target pose of frame {name!r} must hold a rotation (orthonormal, determinant +1) in "
                             f"its upper-left 3×3 block; RᵀR − I is off by {off:.1e}")
    return x, is_pose


def _configuration(model, q, name):
    """A configuration argument ``(..., nq)``, checked (unit quaternions) and finite."""
    x = np.asarray(q) if q is not None else np.zeros(0)
    if x.ndim == 0 or x.shape[-1] != model.nq:
        raise ValueError(f"{name} must have shape (..., {model.nq}) for this model's nq = {model.nq}, got {x.shape}")
    x = model.check_configuration(x, name)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return x


def _positive_number(value, name, *, integer=False, upper=None, zero=False):
    """``value`` as a float (or int), with ``ValueError`` naming ``name`` unless it is in range."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if (integer and number != int(number)) or not (number >= 0.0 if zero else number > 0.0) or (
            upper is not None and number > upper) or not np.isfinite(number):
        kind = "a non-negative integer" if integer else ("non-negative" if zero else "positive")
        bound = f" and at most {upper}" if upper is not None else ""
        raise ValueError(f"{name} must be {kind}{bound}, got {value!r}")
    return int(number) if integer else number


def _limits(model):
    """``(lower, upper) (nq,)``: the limits of the angles and displacements, ``∓inf`` for the others."""
    lower, upper = np.full(model.nq, -np.inf), np.full(model.nq, np.inf)
    index = np.array([s + k for joint, s in zip(model.joints, model.idx_q) if joint.vector_space
                      for k in range(joint.nq)], dtype=int)
    lower[index], upper[index] = model.lower[index], model.upper[index]
    return lower, upper


def _restart_table(model, count, rng):
    """``(count, nq)`` random configurations within the limits (:meth:`Model.random_configuration`), kept
    per model for an integer ``rng`` (the same integer draws the same configurations)."""
    if not isinstance(rng, (int, np.integer)):
        return model.random_configuration(np.random.default_rng(rng), (count,))
    tables = _RESTART_TABLES.setdefault(model, {})
    key = (int(count), int(rng))
    if key not in tables:
        table = model.random_configuration(np.random.default_rng(int(rng)), (count,))
        table.setflags(write=False)
        tables[key] = table
    return tables[key]


def default_start(model):
    """The default start ``q0 (nq,)`` of :func:`inverse_kinematics`: the middle of the limits of each
    coordinate limited on both sides, the neutral configuration elsewhere."""
    lower, upper = _limits(model)
    q = model.neutral()
    both = np.isfinite(lower) & np.isfinite(upper)
    q[both] = 0.5 * (lower[both] + upper[both])
    return np.clip(q, lower, upper)


# ----------------------------------------------------------------------------- the solver

def inverse_kinematics(model, targets, q0=None, *, tol=1e-10, max_iterations=1000, damping=1e-2, posture=None,
                       posture_weight=1.0, restarts=50, rng=0):
    """Configurations that place body frames at target poses or positions (module docstring).

    Args:
        model: a :class:`~multibody.Model`.
        targets: mapping frame name (``model.body_names``) -> world pose ``X_WT (..., 4, 4)`` (homogeneous,
            m) or world position ``p_WT (..., 3)`` (m) of that frame's origin. Leading batch axes give many
            problems at once; they broadcast between the targets, ``q0`` and ``posture``.
        q0: start ``(..., nq)``, projected into the limits; default :func:`default_start` (the middle of
            the joint limits).
        tol: convergence threshold on ``‖e‖``, the norm of the stacked errors (m and rad).
        max_iterations: most steps tried per problem, restarts included.
        damping: initial factor ``λ`` of the damping ``μ = λ ‖e‖² + 1e-12`` (then adapted).
        posture: reference configuration ``(..., nq)``: among the configurations that meet the targets,
            one nearest to it is returned (pursued in the null space of the targets); ``None``: the first
            one found.
        posture_weight: fraction ``w`` (0 to 1] of the way to ``posture`` taken, projected, at each posture
            step (1: all of it, the fastest; smaller values move more gently).
        restarts: most restarts per problem from random configurations after a stalled try (0: none).
        rng: ``numpy.random.Generator`` or integer that draws the restart configurations (the default
            makes results reproducible).

    Returns:
        :class:`InverseKinematicsResult` with ``q``, ``error``, ``frame_errors``, ``converged`` and
        ``iterations``. A problem whose targets cannot be reached ends with ``converged`` false, the closest
        configuration found and its error.

    Joint limits ``model.lower`` and ``model.upper`` bound every iterate of the angles and displacements
    (projected steps; module docstring). The same problem gives the same result alone or in a batch.
    """
    if not hasattr(targets, "items") or len(targets) == 0:
        raise ValueError("targets must be a non-empty mapping from frame names to (4, 4) poses or (3,) positions")
    checked = {}
    for name, value in targets.items():
        if name not in model.body_names:
            raise ValueError(f"unknown frame {name!r}; frames are the model's bodies: {_frame_names_hint(model)}")
        checked[name] = _target(name, value)
    tol = _positive_number(tol, "tol", zero=True)
    max_iterations = _positive_number(max_iterations, "max_iterations", integer=True, zero=True)
    damping = _positive_number(damping, "damping")
    posture_weight = _positive_number(posture_weight, "posture_weight", upper=1.0)
    restarts = _positive_number(restarts, "restarts", integer=True, zero=True)

    lower, upper = _limits(model)
    q0 = default_start(model) if q0 is None else np.clip(_configuration(model, q0, "q0"), lower, upper)
    posture = None if posture is None else _configuration(model, posture, "posture")
    names = list(checked) + ["q0"] + ([] if posture is None else ["posture"])
    shapes = [x.shape[:-2] if is_pose else x.shape[:-1] for x, is_pose in checked.values()] + [q0.shape[:-1]]
    shapes += [] if posture is None else [posture.shape[:-1]]
    try:
        batch = np.broadcast_shapes(*shapes)
    except ValueError:
        raise ValueError("the batch axes of the targets, q0 and posture do not broadcast: "
                         + ", ".join(f"{name} {shape}" for name, shape in zip(names, shapes))) from None

    # per problem: [R_WT (9), p_WT (3)] per frame (a position target leaves R_WT zero)
    packed = np.zeros(batch + (len(checked), 12))
    # each target's rows of the stacked error e: 6 for a pose, 3 for a position
    sizes = [6 if is_pose else 3 for _, is_pose in checked.values()]
    rows_start, m = np.cumsum([0] + sizes), sum(sizes)
    for k, (x, is_pose) in enumerate(checked.values()):
        if is_pose:
            packed[..., k, :9] = x[..., :3, :3].reshape(x.shape[:-2] + (9,))
            packed[..., k, 9:] = x[..., :3, 3]
        else:
            packed[..., k, 9:] = x
    target_kinds = [kernels.POSE if is_pose else kernels.POSITION for _, is_pose in checked.values()]
    packed = packed.reshape(batch + (12 * len(checked),))
    table = _restart_table(model, restarts * _CANDIDATES, rng)
    header = np.empty(kernels.KINDS)
    header[[kernels.TOL, kernels.MAX_ITERATIONS, kernels.DAMPING, kernels.POSTURE_WEIGHT, kernels.RESTARTS,
            kernels.STEP_TOL, kernels.WINDOW, kernels.PROGRESS, kernels.CANDIDATES]] = (
        tol, max_iterations, damping, posture_weight, restarts, _STEP_TOL, _WINDOW, _PROGRESS, _CANDIDATES)
    options = np.concatenate([header, target_kinds, np.clip(lower, -kernels.BIG, kernels.BIG),
                              np.clip(upper, -kernels.BIG, kernels.BIG), np.clip(table, lower, upper).reshape(-1)])
    rows = np.ascontiguousarray(model.tree.bodies[[model.body_names.index(name) for name in checked]])
    out = driver.evaluate(kernels.inverse_kinematics, model.tree, (q0, packed, posture, options),
                          (1, kernels.output_columns(model.nq, m)), batch, rows,
                          workspace=kernels.workspace_size(model.njoints, model.nq, model.nv, m))[..., 0, :]

    q, e = out[..., : model.nq].copy(), out[..., model.nq : model.nq + m]
    error = np.linalg.norm(e, axis=-1)
    frame_errors = {name: e[..., start : start + size].copy() for name, start, size in zip(checked, rows_start, sizes)}
    return InverseKinematicsResult(q=q, error=error, frame_errors=MappingProxyType(frame_errors),
                                   converged=error <= tol, iterations=out[..., -1].astype(int))
