"""Constrained dynamics: the KKT system of ``M a + h = τ + Aᵀ λ``, ``A a = γ``.

Eliminating ``a`` gives the multipliers from the *Delassus* matrix ``G = A M⁻¹ Aᵀ``
(R. Featherstone, *Rigid Body Dynamics Algorithms*, §8.1, eq. 8.7 with our sign of λ):

    a_free = M⁻¹ (τ − h)
    G λ = γ − A a_free                     (minimum-norm λ when A is rank deficient)
    a = a_free + M⁻¹ Aᵀ λ
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import derivatives, differences, driver, dynamics, kinematics, spatial
from .constraints import CompiledRows, frame_key, constraint_program
from .contact import Unilateral
from .integrators import CompiledStep, vector_space_tree
from .kernels import aba, integration, kkt
from .kernels import constraints as compiled_rows
from .mechanical import ModelSystem
from .model import Model
from .runs import ConstraintError
from .spatial import matvec
from .tree import frame_rows


class RankDeficientWarning(UserWarning):
    """Constraint rows that are not independent at the state a :class:`ConstrainedSystem` is first projected
    at (:meth:`ConstrainedSystem.project`, or the initial state of :func:`multibody.simulate`).

    Redundant rows are supported (their multipliers are the minimum-norm ones): a parallelogram's
    second crank, a car's four wheels. Where the redundancy is intended, filter this warning
    (``warnings.filterwarnings("ignore", category=mb.RankDeficientWarning)``); where it is not, a
    constraint holds less than it seems to (a planar loop closure in a plane that is not the loop's).
    """


#: The tolerance (largest ``|φ|`` left, m or rad) and the iterations of :meth:`ConstrainedSystem.project` by default,
#: which the compiled runs' projection at a step's end takes too (:attr:`ConstrainedSystem.compiled_step`).
PROJECTION_TOLERANCE, PROJECTION_ITERATIONS = 1e-12, 50

#: The tree :func:`multibody.kernels.kkt.solve_arrays` and ``correction_arrays`` are called with: they read no tree.
_NO_TREE = vector_space_tree(0)


def _failing_constraint(system, row):
    """The constraint of ``system`` (a :class:`ConstrainedSystem`) that holds constraint row ``row``."""
    return system.constraints[int(np.searchsorted(np.cumsum(system._rows), row, side="right"))]


#: The one table of the compiled solve's and projection's failures (:mod:`multibody.kernels.kkt`): each status
#: as the exception it raises, from the system and the status outputs: the rank, the row the failure concerns
#: (:data:`~multibody.kernels.kkt.ROW`), the value reported (how far that row is off, or the ``|φ|`` a projection
#: left) and the iterations of the projection. A state with a non-finite input gets NaN results from
#: :meth:`ConstrainedSystem.solve`; a projection of it raises the message below.
STATUS_ERRORS = {
    kkt.NOT_POSITIVE_DEFINITE: lambda system, rank, row, value, iterations: ConstraintError(
        "the mass matrix is not positive definite at this configuration"),
    kkt.INCONSISTENT: lambda system, rank, row, value, iterations: ConstraintError(
        f"inconsistent constraints: no accelerations satisfy all {system.num_rows} rows (rank {int(rank)}); "
        f"row {system.row_names[int(row)]!r} is off by {value:.3g}"),
    kkt.UNDEFINED: lambda system, rank, row, value, iterations: ValueError(
        f"{_failing_constraint(system, row).name}: {_failing_constraint(system, row).undefined}"),
    kkt.NOT_CONVERGED: lambda system, rank, row, value, iterations: ConstraintError(
        f"projection onto the position constraints did not converge: |φ| = {value:.3g} after {int(iterations)} "
        "iterations"),
    kkt.NON_FINITE: lambda system, rank, row, value, iterations: ConstraintError(
        "the constrained step has a non-finite input: a NaN or infinite entry of q, v, tau or the constraint rows"),
}


class _ModelAtState(ModelSystem):
    """A :class:`ModelSystem` that holds the kinematics of some body frames at one state ``(q, v)``,
    computed in the pass down the tree that gave ``M`` and ``h`` (see ``ConstrainedSystem.solve``).

    Constraints read frames through ``known_frame``, which answers for exactly that state (the same
    ``q`` and ``v`` arrays) and ``None`` otherwise, e.g. at the neighbouring states of a numerical
    derivative.
    """

    def __init__(self, model, q, v, frames, values):
        super().__init__(model)
        self._q, self._v, self._frames, self._values = q, v, frames, values
        # A constraint reads its frames by the body and placement objects it declared: found by identity
        # (those objects stay alive in ``frames``), without normalising the placement.
        self._declared = {(body, id(placement)): value for (body, placement), value in zip(frames, values)}

    def known_frame(self, q, v, body, placement):
        if q is not self._q or v is not self._v:
            return None
        value = self._declared.get((body, id(placement)))
        if value is None:  # the same frame given by other objects (a body index, an equal placement)
            key = frame_key(self.model, body, placement)
            value = next((value for frame, value in zip(self._frames, self._values)
                          if frame_key(self.model, *frame) == key), None)
        return value


def as_system(system):
    """The mechanical-system interface of a Model, a ConstrainedSystem, or a system that already has it."""
    if isinstance(system, Model):
        return ModelSystem(system)
    if isinstance(system, ConstrainedSystem):
        return system.system
    missing = [name for name in ("nq", "nv", "mass_matrix", "bias_forces", "integrate") if not hasattr(system, name)]
    if missing:
        raise TypeError(f"{type(system).__name__} is not a mechanical system: it lacks {', '.join(missing)}")
    return system


@dataclass
class KKTSolution:
    """Result of :meth:`ConstrainedSystem.solve`.

    Attributes:
        a: accelerations ``(nv,)``.
        lam: multipliers ``(m,)``, one per constraint row (minimum-norm when rows are redundant).
        rank: rank of the constraint Jacobian ``A`` (``m`` when no row is redundant).
        A: the constraint Jacobian ``(m, nv)``; gamma: ``(m,)``.
    """

    a: np.ndarray
    lam: np.ndarray
    rank: int
    A: np.ndarray
    gamma: np.ndarray


@dataclass(frozen=True)
class KKTDerivatives:
    """Derivatives of :meth:`ConstrainedSystem.forward_dynamics` at one state (or a batch, with leading
    axes): ``a`` and ``λ`` with respect to ``q`` (tangent space, ``q ⊕ δq``), ``v`` and ``τ``.

    Attributes:
        da_dq, da_dv, da_dtau: ``(..., nv, nv)``.
        dlam_dq, dlam_dv, dlam_dtau: ``(..., m, nv)``; the multipliers' units per unit of the coordinate.
    """

    da_dq: np.ndarray
    da_dv: np.ndarray
    da_dtau: np.ndarray
    dlam_dq: np.ndarray
    dlam_dv: np.ndarray
    dlam_dtau: np.ndarray


class ConstrainedSystem:
    """A mechanical system with holonomic and nonholonomic constraints.

    Args:
        model: a :class:`Model`, or any system with ``nq``, ``nv``, ``mass_matrix(q)``,
            ``bias_forces(q, v)`` and ``integrate(q, v, dt)`` (see :class:`ModelSystem`).
        constraints: :mod:`multibody.constraints` instances (holonomic and Pfaffian mix freely).
        baumgarte: ``None`` (no stabilisation), a rate ``α`` (1/s), or ``(α, β)``: the
            acceleration-level rows become ``A a = γ − 2α (A v + b) − β² φ`` (``φ`` for holonomic
            rows only; ``β = α`` when a single number is given, the critically damped choice).
        rank_tolerance: relative singular-value threshold below which constraint rows count as redundant.

    :attr:`compiled_step`, :meth:`chart_derivative`, :meth:`chart_derivatives`, :meth:`projection`,
    :meth:`checked_tau`, :meth:`row_space_projectors` and :meth:`position_and_velocity_levels` serve the simulation
    layer (:mod:`multibody.simulation`, :mod:`multibody.variational`, :mod:`multibody.runs`), so that it reads no
    private member of the system.
    """

    def __init__(self, model, constraints=(), *, baumgarte=None, rank_tolerance=1e-10):
        self.system = as_system(model)
        self.model = model if isinstance(model, Model) else None
        constraints = list(constraints)
        # Contact and joint limits (multibody.contact) add no bilateral rows: simulate steps them at velocity level.
        self.unilateral = [c.bind(self.system) for c in constraints if isinstance(c, Unilateral)]
        # Each constraint checked against the model, as it applies to it (Constraint.bind).
        self.constraints = [c.bind(self.system) for c in constraints if not isinstance(c, Unilateral)]
        self.nq, self.nv = self.system.nq, self.system.nv
        if baumgarte is None:
            self.baumgarte = None
        else:
            alpha, beta = (baumgarte, baumgarte) if np.isscalar(baumgarte) else baumgarte
            if alpha < 0 or beta < 0:
                raise ValueError(f"Baumgarte gains must be non-negative, got {baumgarte!r}")
            self.baumgarte = (float(alpha), float(beta))
        self.rank_tolerance = rank_tolerance
        # whether the rows' rank has been checked, at the first projected state (projection)
        self._rank_checked = False
        self._settings = {}  # kkt.project's settings for each (tolerance, max_iterations): _projection_settings
        self._rows = [c.rows(self.system) for c in self.constraints]
        masks = [np.asarray(c.position_rows(self.system), dtype=bool) for c in self.constraints]
        self._position_mask = np.concatenate(masks) if masks else np.zeros(0, dtype=bool)
        self._has_position = [bool(mask.any()) for mask in masks]
        self.row_names = [f"{c.name}[{k}]" for c, m in zip(self.constraints, self._rows) for k in range(m)]
        # The body frames that constraints evaluated in Python read, once each: solve computes them with M
        # and h before it evaluates those rows (compiled rows compute their own frames).
        frames = {} if not isinstance(self.system, ModelSystem) else {
            frame_key(self.system.model, *frame): frame for c in self.constraints
            if not isinstance(c, CompiledRows) or c.moving for frame in c.body_frames}
        self._body_frames = list(frames.values())

    @cached_property
    def _compiled_step(self):
        """``(program, frame rows, workspace size)`` of the compiled step (:mod:`multibody.kernels.kkt`),
        or ``None`` when a constraint has no compiled rows (a user constraint, a moving surface) or
        the system is not a :class:`Model`."""
        if not self.num_rows or not isinstance(self.system, ModelSystem):
            return None
        if any(getattr(c, "moving", False) for c in self.constraints):
            return None
        model = self.system.model
        frames = list({frame_key(model, *frame): frame for c in self.constraints for frame in c.body_frames}.values())
        alpha, beta = self.baumgarte or (0.0, 0.0)
        program = constraint_program(model, self.constraints, frames, (alpha, beta), self.rank_tolerance)
        if program is None:
            return None
        frames = frame_rows(model, [kinematics.frame_arguments(model, *frame) for frame in frames])
        workspace = kkt.workspace_size(model.njoints, self.nv, len(frames), self.num_rows)
        return program, frames, workspace

    def _compiled_levels(self, q):
        """``(φ (m,), A (m, nv), b (m,))`` of every row at one state ``q``, all compiled and fixed in time
        (``b = 0``), from one call of :func:`multibody.kernels.constraints.constraint_levels` on the step's
        program; ``None`` for anything else, or where a row is undefined or an entry not finite (the
        constraints' own methods then raise or warn)."""
        model = self.system.model
        if not model.is_one_state(q, finite=False):
            return None
        program, frames, _ = self._compiled_step
        nv, m = self.nv, self.num_rows
        row = driver.evaluate_one(compiled_rows.constraint_levels, model.tree, (1, compiled_rows.levels_columns(nv, m)),
                                  q, driver.NO_INPUT, driver.NO_INPUT, program, frames=frames,
                                  workspace=compiled_rows.workspace_size(model.njoints, nv, len(frames)))[0]
        if row[-1] != 0.0:  # (a status NaN: a non-finite input)
            return None
        return row[m * nv + m : m * nv + 2 * m], row[: m * nv].reshape(m, nv), np.zeros(m)

    def _solve_program(self, q, v, tau):
        """``(a, λ, A, γ, tail)`` of :meth:`solve` by the compiled step on the program's rows
        (:func:`multibody.kernels.kkt.constrained_accelerations`), with leading batch axes as ``q`` and ``tau``;
        ``tail (..., TAIL)``: the status outputs (:data:`multibody.kernels.kkt.TAIL`)."""
        program, frames, workspace = self._compiled_step
        nv, m = self.nv, self.num_rows
        batch = q.shape[:-1] if tau is None else spatial.batch_shape(q.shape[:-1], tau.shape[:-1])
        row = driver.evaluate(kkt.constrained_accelerations, self.system.model.tree, (q, v, tau, program),
                              (1, kkt.output_columns(nv, m)), batch, frames, workspace)[..., 0, :]
        return (row[..., :nv], row[..., nv : nv + m], row[..., nv + m : nv + m + m * nv].reshape(batch + (m, nv)),
                row[..., nv + m + m * nv : nv + 2 * m + m * nv], row[..., -kkt.TAIL :])

    def _solve_arrays(self, M, h, tau, A, gamma, check=True):
        """``(a (..., nv), λ (..., m), tail (..., TAIL))`` of ``M a + h = τ + Aᵀ λ``, ``A a = γ`` by the compiled solve
        on rows given as arrays (:func:`multibody.kernels.kkt.solve_arrays`): ``M (..., nv, nv)``, ``h``, ``tau
        (..., nv)`` or ``None`` (zero), ``A (..., m, nv)``, ``gamma (..., m)``, whose leading axes broadcast.
        ``check``: whether inconsistent rows are a failure (else the minimum-norm solution alone)."""
        nv, m = M.shape[-1], A.shape[-2]
        batch = spatial.batch_shape(M.shape[:-2], () if h is None else h.shape[:-1],
                                    () if tau is None else tau.shape[:-1], A.shape[:-2], gamma.shape[:-1])
        options = np.concatenate([np.broadcast_to([self.rank_tolerance, 1.0 if check else 0.0], M.shape[:-2] + (2,)),
                                  M.reshape(M.shape[:-2] + (nv * nv,))], axis=-1)
        lead = spatial.batch_shape(A.shape[:-2], gamma.shape[:-1])
        rows = np.concatenate([np.broadcast_to(A.reshape(A.shape[:-2] + (m * nv,)), lead + (m * nv,)),
                               np.broadcast_to(gamma, lead + (m,))], axis=-1)
        row = driver.evaluate(kkt.solve_arrays, _NO_TREE, (options, np.zeros(nv) if h is None else h, tau, rows),
                              (1, kkt.arrays_columns(nv, m)), batch, workspace=kkt.arrays_workspace_size(nv, m))[..., 0, :]
        return row[..., :nv], row[..., nv : nv + m], row[..., -kkt.TAIL :]

    def _raise_failure(self, tail, iterations=0, non_finite=False):
        """The error of :data:`STATUS_ERRORS` of the first state whose status outputs ``tail (..., TAIL)`` report a
        failure; a non-finite input counts only with ``non_finite``."""
        if tail.ndim == 1:  # (one state: plain floats, a tenth of the array operations' cost)
            status = float(tail[kkt.STATUS])
            if status == kkt.SOLVED or (status == kkt.NON_FINITE and not non_finite):
                return
        status = tail[..., kkt.STATUS]
        failed = (status != kkt.SOLVED) if non_finite else (status != kkt.SOLVED) & (status != kkt.NON_FINITE)
        if failed.any():
            first = tail[failed].reshape(-1, kkt.TAIL)[0]
            raise STATUS_ERRORS[int(first[kkt.STATUS])](self, first[kkt.RANK], first[kkt.ROW], first[kkt.VALUE],
                                                         iterations)

    @cached_property
    def compiled_step(self):
        """The step of this system as the compiled runs take it (:class:`~multibody.integrators.CompiledStep`), with
        the projection at a step's end of :meth:`project`'s default tolerance and iterations; ``None`` where the step
        is not compiled (a constraint without compiled rows, a moving surface, a system that is not a
        :class:`Model`)."""
        if not isinstance(self.system, ModelSystem):
            return None
        model, nv, m = self.system.model, self.nv, self.num_rows
        if not m:
            # without constraints on a vector space (q = q_c + δ, T = 1, κ = 0) the stages skip the chart maps
            return CompiledStep(model.tree, model.tree.bodies, np.zeros(0), nv, aba.workspace_size(model.njoints, nv),
                                np.zeros(2), 0, 0, not self.system.vector_space)
        if self._compiled_step is None:
            return None
        program, frames, workspace = self._compiled_step
        return CompiledStep(model.tree, frames, program, kkt.output_columns(nv, m), workspace,
                            self._projection_settings(PROJECTION_TOLERANCE, PROJECTION_ITERATIONS),
                            *self._projection_sizes, True)

    @cached_property
    def _compiled_motion(self):
        """``(kernel, program, frame rows, workspace size, whether ABA alone)`` of the compiled chart derivative
        (:mod:`multibody.kernels.integration`: ``chart_derivative`` without constraints, its program ``None``, else
        ``constrained_chart_derivative``), or ``None`` when the step is not compiled. ABA alone: no chart maps
        (:attr:`~multibody.integrators.CompiledStep.charts`), so that ``ẏ = [w, a(q_c + δ, w, τ)]`` with the arithmetic
        of the chart derivative, without its maps (a third of its cost)."""
        step = self.compiled_step
        if step is None:
            return None
        kernel = integration.constrained_chart_derivative if self.num_rows else integration.chart_derivative
        return (kernel, step.program if self.num_rows else None, step.frames,
                integration.workspace_size(self.nq, self.nv, step.step_workspace, step.step_columns), not step.charts)

    def chart_derivative(self, q_chart, y, tau, q=None):
        """``ẏ = [δ̇, ẇ] (2 nv,)`` of the chart state ``y = [δ, w] (2 nv,)`` around ``q_chart (nq,)``
        (:meth:`multibody.model.Model.chart`) with constant joint forces ``tau (nv,)`` (N·m or N; ``None``: zero), by
        one compiled call, where :attr:`compiled_step` is not ``None``. A constrained step that fails raises the error
        of its status (:data:`STATUS_ERRORS`); a non-finite input gives non-finite rates. ``None`` where ABA alone
        gives non-finite rates (the caller's :meth:`forward_dynamics` then raises the error that names the joint).
        ``q``: the configuration ``chart(q_chart, δ)``, where the caller has it already."""
        kernel, program, frames, workspace, aba_alone = self._compiled_motion
        nv, tree = self.nv, self.system.model.tree
        y = driver.contiguous(y)
        tau = driver.NO_INPUT if tau is None else driver.contiguous(tau)
        if aba_alone:
            # as in chart_derivatives: ẏ = [w, a(q_c + δ, w, τ)]
            w = y[nv:]
            q = q_chart + y[:nv] if q is None else driver.contiguous(q)
            a = driver.evaluate_one(aba.forward_dynamics, tree, (1, nv), q, w, tau)[0]
            return np.concatenate((w, a)) if math.isfinite(sum(a.tolist())) else None
        row = driver.evaluate_one(kernel, tree, (1, integration.output_columns(nv, self.num_rows)),
                                  driver.contiguous(q_chart), y, tau, driver.NO_INPUT if program is None else program,
                                  frames=frames, workspace=workspace)[0]
        y_dot = row[: 2 * nv]
        if program is None:
            return y_dot if math.isfinite(sum(y_dot.tolist())) else None
        self._raise_failure(row[-kkt.TAIL :])
        return y_dot

    def chart_derivatives(self, q_chart, y, tau):
        """:meth:`chart_derivative` of a batch, in one compiled call on all cores: ``ẏ (n, 2 nv)`` of the
        chart states ``y (n, 2 nv)`` around ``q_chart (n, nq)``, with joint forces ``tau`` (N·m or N) ``(n, nv)``,
        ``(nv,)`` (every state) or ``None`` (zero), and for each state that failed, ``{index: error}``: the error of its
        status (:data:`STATUS_ERRORS`), or ``None`` where ABA alone gave non-finite rates. A state with a
        non-finite input gets non-finite rates and no entry."""
        kernel, program, frames, workspace, aba_alone = self._compiled_motion
        nv = self.nv
        if aba_alone:
            a = driver.evaluate(aba.forward_dynamics, self.system.model.tree, (q_chart + y[:, :nv], y[:, nv:], tau),
                                (1, nv), (len(y),))[:, 0]
            y_dot = np.concatenate([y[:, nv:], a], axis=1)
            return y_dot, {int(j): None for j in np.flatnonzero(~np.isfinite(y_dot).all(axis=1))}
        rows = driver.evaluate(kernel, self.system.model.tree, (q_chart, y, tau, program),
                               (1, integration.output_columns(nv, self.num_rows)), (len(y),), frames, workspace)[:, 0]
        y_dot = rows[:, : 2 * nv]
        if program is None:
            return y_dot, {int(j): None for j in np.flatnonzero(~np.isfinite(y_dot).all(axis=1))}
        failures = {}
        for j in np.flatnonzero((rows[:, -1] != kkt.SOLVED) & (rows[:, -1] != kkt.NON_FINITE)):
            try:
                self._raise_failure(rows[j, -kkt.TAIL :])
            except (ConstraintError, ValueError) as error:
                failures[int(j)] = error
        return y_dot, failures

    @cached_property
    def num_rows(self) -> int:
        """Total number of constraint rows ``m``."""
        return int(sum(self._rows))

    @property
    def position_rows(self) -> np.ndarray:
        """Which rows have a position level ``φ(q, t) = 0`` (holonomic rows): a boolean mask ``(m,)``; the
        others restrict velocities only (nonholonomic rows)."""
        return self._position_mask.copy()

    # ------------------------------------------------------------------ stacked constraint levels

    def _stack(self, pieces, shape):
        if len(pieces) == 1:
            return pieces[0]
        return np.concatenate(pieces, axis=-1 if len(shape) == 1 else -2) if pieces else np.zeros(shape)

    def position_error(self, q, t=0.0):
        """``φ(q, t)`` of the rows with a position level, zeros for the others: ``(m,)``. Raises
        :class:`ConstraintError` where ``q`` is on a wrong branch of a constraint's rows (:meth:`_check_branches`)."""
        self._check_branches(q)
        return self._position_error(q, t)

    def _position_error(self, q, t):
        """:meth:`position_error` without the check of the branch (the Baumgarte terms, at any state)."""
        pieces = [c.position(self.system, q, t) if has_position else np.zeros(np.shape(q)[:-1] + (m,))
                  for c, m, has_position in zip(self.constraints, self._rows, self._has_position)]
        return self._stack(pieces, (0,))

    def _check_branches(self, q):
        """:class:`ConstraintError` naming the constraint where ``q (..., nq)`` lies on another zero of its
        position rows than the pose it stands for
        (:meth:`~multibody.constraints.Constraint.branch_error`): ``φ = 0`` there, so only this check tells."""
        for c, has_position in zip(self.constraints, self._has_position):
            if has_position and (message := c.branch_error(self.system, q)) is not None:
                raise ConstraintError(f"{c.name}: {message}")

    def velocity_level(self, q, t=0.0):
        """Stacked ``(A, b)`` of ``A v + b = 0``: ``(m, nv)``, ``(m,)``."""
        levels = [c.velocity_level(self.system, q, t) for c in self.constraints]
        return (self._stack([level[0] for level in levels], (0, self.nv)),
                self._stack([level[1] for level in levels], (0,)))

    def jacobian(self, q, t=0.0):
        """Stacked ``A(q, t)``: ``(m, nv)``."""
        return self._stack([c.jacobian(self.system, q, t) for c in self.constraints], (0, self.nv))

    def velocity_bias(self, q, t=0.0):
        """Stacked ``b(q, t)``: ``(m,)``."""
        return self.velocity_level(q, t)[1]

    def velocity_error(self, q, v, t=0.0):
        """``A v + b``: ``(m,)``."""
        A, b = self.velocity_level(q, t)
        return matvec(A, v) + b

    def velocity_error_derivative(self, q, v, t=0.0):
        """``∂(A v + b)/∂q (..., m, nv)`` at fixed ``v``, in the tangent space (``q ⊕ δq``): how moving the
        configuration changes what the rows ask of the velocity. By five-point central differences of
        :meth:`velocity_error` with the step :attr:`DERIVATIVE_STEP` ``· max(1, |q|)``, as the row terms of
        :meth:`forward_dynamics_derivatives` (about ``1e-11`` relative): the rows give ``A`` and ``γ``
        analytically, but ``γ = −∂(A v + b)/∂q v − ∂(A v + b)/∂t`` holds only the derivative along ``v``.
        ``q (..., nq)``, ``v (..., nv)``; leading axes need :attr:`batched`."""
        q, v = self._check_state(q, v)
        if not self.num_rows:
            return np.zeros(q.shape[:-1] + (0, self.nv))
        return self._central_differences(lambda q_: self.velocity_error(q_, v, t), q, True)

    def acceleration_level(self, q, v, t=0.0):
        """``(A, γ)``: the stacked rows of ``A a = γ``, Baumgarte terms included: ``(m, nv)``, ``(m,)``."""
        return self._acceleration_level(self.system, q, v, t)

    def _acceleration_level(self, system, q, v, t):
        """:meth:`acceleration_level` with the constraints evaluated for ``system`` (this system's, or
        one that already holds their frames at this state)."""
        levels = [c.evaluate(system, q, v, t) for c in self.constraints]
        A = self._stack([level[0] for level in levels], (0, self.nv))
        gamma = self._stack([level[2] for level in levels], (0,))
        if self.baumgarte is not None and self.num_rows:
            alpha, beta = self.baumgarte
            velocity_error = matvec(A, v) + self._stack([level[1] for level in levels], (0,))
            gamma = gamma - 2.0 * alpha * velocity_error - beta**2 * self._position_error(q, t)
        return A, gamma

    def acceleration_rhs(self, q, v, t=0.0):
        """Stacked ``γ(q, v, t)``, Baumgarte terms included: ``(m,)``."""
        return self.acceleration_level(q, v, t)[1]

    def residual(self, q, v, t=0.0):
        """Largest constraint violation: ``max(|φ|, |A v + b|)`` over all rows (0 without constraints).

        A float for one state; ``(...)`` for a batch ``q (..., nq)``, ``v (..., nv)`` (see :attr:`batched`).
        Raises :class:`ConstraintError` where ``q`` is on a wrong branch of a constraint's rows, where ``φ = 0``
        does not mean closed (:meth:`_check_branches`).
        """
        q, v = self._check_state(q, v)
        if not self.num_rows:
            return 0.0 if q.ndim == 1 else np.zeros(q.shape[:-1])
        self._check_branches(q)
        phi, A, b = self.position_and_velocity_levels(q, t)
        worst = np.maximum(np.abs(phi).max(axis=-1), np.abs(matvec(A, v) + b).max(axis=-1))
        return float(worst) if q.ndim == 1 else worst

    def position_and_velocity_levels(self, q, t=0.0):
        """Stacked ``(φ (..., m), A (..., m, nv), b (..., m))`` at ``q (..., nq)`` and ``t`` (s), each constraint
        evaluated once, without the check of the branch (:meth:`position_error`); those of one state with compiled
        rows by one call of their kernel (:meth:`_compiled_levels`)."""
        if self._compiled_step is not None and (levels := self._compiled_levels(q)) is not None:
            return levels
        levels = [c.position_and_velocity_level(self.system, q, t) for c in self.constraints]
        return (self._stack([level[0] for level in levels], (0,)), self._stack([level[1] for level in levels], (0, self.nv)),
                self._stack([level[2] for level in levels], (0,)))

    # ------------------------------------------------------------------ dynamics

    @property
    def batched(self) -> bool:
        """``True`` when :meth:`solve`, :meth:`residual` and :meth:`energy` take a batch in one call:
        a :class:`Model` whose constraints all declare ``batched`` (their methods accept leading axes)."""
        return isinstance(self.system, ModelSystem) and all(getattr(c, "batched", False) for c in self.constraints)

    def _mass_matrix_and_bias(self, q, v):
        """``(M, h, system)``, where ``system`` holds the constraints' body frames at ``(q, v)`` when they
        came from the same pass down the tree (else it is this system's)."""
        if self._body_frames:
            M, h, values = dynamics.mass_matrix_bias_and_frames(self.system.model, q, v, self._body_frames)
            return M, h, _ModelAtState(self.system.model, q, v, self._body_frames, values)
        if hasattr(self.system, "mass_matrix_and_bias"):
            return *self.system.mass_matrix_and_bias(q, v), self.system
        return self.system.mass_matrix(q), self.system.bias_forces(q, v), self.system

    def row_space_projectors(self, q, t=0.0):
        """``(P_position, P_velocity)``, each ``(nv, nv)``: ``P = M⁻¹Aᵀ (A M⁻¹ Aᵀ)⁺ A`` at one state ``q (nq,)`` and
        ``t`` (s), for ``A`` the rows with a position level and for all rows. ``P δ`` is the part of a velocity-space
        vector ``δ`` that the projection (:meth:`project`, to first order) removes: the ``M``-orthogonal projection
        onto the rows' range, with the rank decision of :meth:`solve`."""
        q = np.asarray(q, dtype=float)
        A, M = self.position_and_velocity_levels(q, t)[1], self.system.mass_matrix(q)

        def projector(rows):
            if not rows.shape[0]:
                return np.zeros((self.nv, self.nv))
            # column j: the accelerations M⁻¹Aᵀ G⁺ A e_j of the solve without forces, whose rows ask A a = A e_j
            return self._solve_arrays(M, None, None, rows, rows.T, check=False)[0].T

        holonomic = self._position_mask
        velocity = projector(A)
        return (velocity if holonomic.all() else projector(A[holonomic])), velocity

    def checked_tau(self, tau, batch=()):
        """Joint forces ``tau`` (N·m or N) as a float array ``(nv,)`` or ``batch + (nv,)``, or ``ValueError`` naming
        its shape."""
        if type(tau) is np.ndarray and tau.dtype == np.float64 and tau.shape == (self.nv,):
            return tau
        tau = np.asarray(tau, dtype=float)
        if tau.shape[-1:] != (self.nv,) or tau.ndim > len(batch) + 1:
            raise ValueError(f"tau must have shape ({self.nv},), got {tau.shape}")
        return tau

    def _check_state(self, q, v):
        model = self.model
        if model is not None and model.is_one_state(q, v):
            return q, v
        q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
        if q.shape[-1:] != (self.nq,) or v.shape[-1:] != (self.nv,) or q.shape[:-1] != v.shape[:-1]:
            raise ValueError(f"q and v must have shapes (..., {self.nq}) and (..., {self.nv}) with the same "
                             f"leading axes, got {q.shape} and {v.shape}")
        if q.ndim > 1 and not self.batched:
            raise ValueError(f"q and v must have shapes ({self.nq},) and ({self.nv},), got {q.shape} and {v.shape}: "
                             "this system takes one state at a time (its mechanical system or one of its "
                             "constraints does not accept batches; see ConstrainedSystem.batched)")
        if self.model is not None:
            # the model's checks too: unit norms, a warning on non-finite values
            q, v = self.model.check_configuration(q), self.model.check_velocity(v)
        return q, v

    def solve(self, q, v, tau=None, t=0.0) -> KKTSolution:
        """Accelerations, multipliers and rank; see :class:`KKTSolution`.

        ``q (..., nq)``, ``v (..., nv)``, ``tau (..., nv)`` and ``t`` (s, scalar or ``(...)``) may carry
        leading batch axes when :attr:`batched`; the results then carry them too. One compiled solve
        (:func:`multibody.kernels.kkt.solve_rows`) takes the rows of the compiled constraint program, or those
        the constraints evaluate in Python, passed as arrays. A failure raises the error of its status
        (:data:`STATUS_ERRORS`); a state with a non-finite input gets NaN results and rank 0.
        """
        q, v = self._check_state(q, v)
        tau = None if tau is None else self.checked_tau(tau, q.shape[:-1])
        if not self.num_rows and hasattr(self.system, "forward_dynamics"):
            batch = q.shape[:-1]
            try:
                a = self.system.forward_dynamics(q, v, tau)
            except np.linalg.LinAlgError as error:
                raise ConstraintError(str(error)) from None
            return KKTSolution(a, np.zeros(batch + (0,)), 0, np.zeros(batch + (0, self.nv)), np.zeros(batch + (0,)))
        if self._compiled_step is not None:
            a, lam, A, gamma, tail = self._solve_program(q, v, tau)
        else:
            M, h, evaluated = self._mass_matrix_and_bias(q, v)
            A, gamma = self._acceleration_level(evaluated, q, v, t)
            a, lam, tail = self._solve_arrays(M, h, tau, A, gamma)
        self._raise_failure(tail)
        if tail.ndim == 1:
            rank = tail[kkt.RANK]
            return KKTSolution(a, lam, int(rank) if rank == rank else 0, A, gamma)
        return KKTSolution(a, lam, np.nan_to_num(tail[..., kkt.RANK]).astype(int), A, gamma)

    def forward_dynamics(self, q, v, tau=None, t=0.0):
        """``(a, λ)`` with ``M a + h = τ + Aᵀ λ`` and ``A a = γ``: ``(nv,)``, ``(m,)`` (``(..., nv)``,
        ``(..., m)`` for a batch, see :meth:`solve`).

        ``tau`` defaults to zero. Redundant rows get the minimum-norm multipliers; inconsistent
        rows raise :class:`ConstraintError`.
        """
        solution = self.solve(q, v, tau, t)
        return solution.a, solution.lam

    #: Step of the five-point central differences of the constraint rows, per unit of ``max(1, |q|)`` (m,
    #: rad) or ``max(1, |v|)`` (:data:`multibody.differences.STEP`).
    DERIVATIVE_STEP = differences.STEP

    def forward_dynamics_derivatives(self, q, v, tau=None, t=0.0) -> KKTDerivatives:
        """Derivatives of ``(a, λ)`` of :meth:`forward_dynamics` with respect to ``q``, ``v`` and ``τ``; see
        :class:`KKTDerivatives`. Derivatives with respect to ``q`` are in the tangent space
        (``system.integrate(q, δq)``), as :func:`multibody.forward_dynamics_derivatives`'.

        Differentiating the KKT system ``M a + h − Aᵀλ = τ``, ``A a = γ`` at the solution gives, for each
        input x, ``[[M, −Aᵀ], [A, 0]] [∂a; ∂λ] = [r₁; r₂]`` with

            r₁ = ∂τ/∂x − ∂(M a + h)/∂x|_a + ∂(Aᵀλ)/∂x|_λ,      r₂ = ∂γ/∂x − ∂(A a)/∂x|_a,

        solved by eliminating ``∂a``: ``G ∂λ = r₂ − A M⁻¹ r₁`` with ``G = A M⁻¹ Aᵀ``, then
        ``∂a = M⁻¹ (r₁ + Aᵀ ∂λ)``. ``∂(M a + h)/∂(q, v)`` is analytical for a :class:`Model`
        (:func:`multibody.inverse_dynamics_derivatives`); the constraint terms ``Aᵀλ`` and ``A a − γ``
        (Baumgarte terms included) are differentiated by five-point central differences in the tangent space
        with the step :attr:`DERIVATIVE_STEP` ``· max(1, |q|)``: exact in ``v`` up to rounding (``γ`` is
        quadratic in ``v``), and to about ``1e-11`` relative in ``q``. Where rows are redundant, ``∂λ`` is the minimum-norm
        solution, by the rank rule of :meth:`solve`. A system that is not a :class:`Model` gets
        ``∂(M a + h)`` by central differences too.

        ``q (..., nq)``, ``v (..., nv)``, ``tau (..., nv)`` or ``None``; leading axes need :attr:`batched`.
        Pinocchio counterpart (holonomic): ``computeConstraintDynamicsDerivatives``.
        """
        solution = self.solve(q, v, tau, t)
        q, v = self._check_state(q, v)
        a, lam, A = solution.a, solution.lam, solution.A
        batch, nv, m = a.shape[:-1], self.nv, self.num_rows
        M = self.system.mass_matrix(q)
        dtau_dq, dtau_dv = self._torque_derivatives(q, v, a)
        if m:
            force_dq, level_dq, level_dv = self._row_derivatives(q, v, a, lam, t)
        else:
            force_dq, level_dq, level_dv = 0.0, np.zeros(batch + (0, nv)), np.zeros(batch + (0, nv))
        identity = np.broadcast_to(np.eye(nv), batch + (nv, nv))
        # r₁ = ∂τ/∂x − ∂(M a + h)/∂x + ∂(Aᵀλ)/∂x ;  r₂ = −∂(A a − γ)/∂x, for x = q, v, τ side by side
        r1 = np.concatenate([force_dq - dtau_dq, -dtau_dv, identity], axis=-1)
        r2 = np.concatenate([-level_dq, -level_dv, np.zeros(batch + (m, nv))], axis=-1)
        # each column is a KKT solve with forces r₁ and rows asking γ = r₂: G ∂λ = r₂ − A M⁻¹ r₁ (minimum norm),
        # ∂a = M⁻¹ (r₁ + Aᵀ ∂λ)
        columns = batch + (3 * nv,)
        da, dlam, tail = self._solve_arrays(M[..., None, :, :], None, np.swapaxes(r1, -1, -2),
                                            np.broadcast_to(A[..., None, :, :], columns + (m, nv)),
                                            np.swapaxes(r2, -1, -2), check=False)
        self._raise_failure(tail)
        da, dlam = np.swapaxes(da, -1, -2), np.swapaxes(dlam, -1, -2)
        return KKTDerivatives(da[..., :nv], da[..., nv : 2 * nv], da[..., 2 * nv :],
                              dlam[..., :nv], dlam[..., nv : 2 * nv], dlam[..., 2 * nv :])

    def linearize(self, q, v, tau=None, t=0.0, *, dt=None, method="RK4"):
        """The first-order dynamics about ``(q, v, τ)`` restricted to the constraints, in minimal coordinates
        ``[s; u]``: a :class:`multibody.linearization.Linearization` (see :func:`multibody.linearize` for the
        derivation). With ``dt`` (s), the map of one step of ``method`` in the same coordinates instead.

        ``q (..., nq)``, ``v (..., nv)``, ``tau (..., nv)`` or ``None`` (zero), a consistent state (see
        :meth:`project`); leading axes give a batch.
        """
        from .linearization import linearize

        return linearize(self, q, v, tau, t, dt=dt, method=method)

    def _torque_derivatives(self, q, v, a):
        """``∂(M a + h)/∂q`` (tangent space) and ``∂(M a + h)/∂v`` at fixed ``a``: analytical for a model,
        central differences otherwise (exact in ``v``, where ``h`` is quadratic)."""
        if isinstance(self.system, ModelSystem):
            return derivatives.inverse_dynamics_derivatives(self.system.model, q, v, a)

        def torque(q_, v_):
            return matvec(self.system.mass_matrix(q_), a) + self.system.bias_forces(q_, v_)

        return self._central_differences(lambda q_: torque(q_, v), q, True), \
            self._central_differences(lambda v_: torque(q, v_), v, False)

    def _row_derivatives(self, q, v, a, lam, t):
        """``∂(Aᵀλ)/∂q (..., nv, nv)`` at fixed ``λ``, ``∂(A a − γ)/∂q`` and ``∂(A a − γ)/∂v (..., m, nv)`` at
        fixed ``a``, by central differences of the rows (Baumgarte terms included)."""

        def force_and_level(q_, v_):
            A, gamma = self.acceleration_level(q_, v_, t)
            return np.concatenate([matvec(np.swapaxes(A, -1, -2), lam), matvec(A, a) - gamma], axis=-1)

        nv = self.nv
        d_dq = self._central_differences(lambda q_: force_and_level(q_, v), q, True)
        d_dv = self._central_differences(lambda v_: force_and_level(q, v_), v, False)
        return d_dq[..., :nv, :], d_dq[..., nv:, :], d_dv[..., nv:, :]

    def _central_differences(self, f, x, tangent):
        """``∂f/∂x (..., k, nv)`` of ``f(x) -> (..., k)`` by five-point central differences
        (:func:`multibody.differences.five_point_jacobian`): ``x`` displaced through ``system.integrate``
        when ``tangent`` (a configuration), by ``x + s`` otherwise, with the step
        ``h = DERIVATIVE_STEP · max(1, |x|)``. All ``4 nv`` displaced states go in one call when the
        system takes batches."""
        nv = self.nv
        h = self.DERIVATIVE_STEP * max(1.0, float(np.abs(x).max(initial=0.0)))

        def displace(steps):
            steps = steps.reshape((4 * nv,) + (1,) * (x.ndim - 1) + (nv,))
            return self.system.integrate(x, steps, 1.0) if tangent else x + steps

        def values(displaced):
            return f(displaced) if self.batched else np.stack([f(state) for state in displaced])

        return differences.five_point_jacobian(values, displace, nv, h)

    def rank(self, q, t=0.0, *, rows=None, A=None):
        """Rank of the constraint Jacobian at ``q``: the number of independent rows, judged as :meth:`solve`
        judges them, by the singular values of ``A L⁻ᵀ`` (``M = L Lᵀ``) above ``rank_tolerance`` times the
        largest.

        ``rows``: a boolean mask ``(m,)`` of the rows to count (e.g. :attr:`position_rows`), or ``None`` for
        all. ``A (..., m, nv)``: the rows at ``q`` and ``t``, where the caller has them already (compiled rows, fixed in
        time, are decided on the program's own). An ``int`` for one state; ``(...)`` ints for a batch ``q (..., nq)``
        (see :attr:`batched`).
        """
        q = np.asarray(q, dtype=float)
        if A is not None and np.shape(A)[-2:] != (self.num_rows, self.nv):
            raise ValueError(f"A must have shape (..., {self.num_rows}, {self.nv}), got {np.shape(A)}")
        if rows is not None:
            rows = np.asarray(rows)
            if rows.dtype != bool or rows.shape != (self.num_rows,):
                raise ValueError(f"rows must be a boolean mask of shape ({self.num_rows},), got "
                                 f"{rows.dtype} of shape {rows.shape}")
        if not self.num_rows or (rows is not None and not rows.any()):
            return 0 if q.ndim == 1 else np.zeros(q.shape[:-1], dtype=int)
        if rows is None and (rank := self._compiled_rank(q)) is not None:
            return rank
        A = self.jacobian(q, t) if A is None else A
        rank = self._row_rank(q, A if rows is None else A[..., rows, :])
        return int(rank) if np.ndim(rank) == 0 else rank

    def _row_rank(self, q, A, M=None):
        """The rank ``(...)`` of rows ``A (..., k, nv)`` in the metric of ``M(q)`` (``M`` where the caller has it), by
        the one rank decision of the compiled solve (:func:`multibody.kernels.kkt.metric_solve`); 0 at a state
        with a non-finite entry."""
        if not A.shape[-2]:
            return np.zeros(A.shape[:-2], dtype=int)
        M = self.system.mass_matrix(q) if M is None else M
        tail = self._solve_arrays(M, None, None, A, np.zeros(A.shape[:-1]), check=False)[2]
        self._raise_failure(tail)
        return np.nan_to_num(tail[..., kkt.RANK]).astype(int)

    def _warn_if_rank_deficient(self, q, t, stacklevel=4):
        """A :class:`RankDeficientWarning` (``stacklevel`` calls up) when the rows at ``q`` (one state or a batch)
        have a lower rank than the constraints' independent rows
        (:meth:`~multibody.constraints.Constraint.independent_rows`), naming each constraint whose own rows fall
        short, with its rank against its rows. Each rank is the lowest over a batch."""
        if not self.num_rows:
            return
        q = np.asarray(q, dtype=float)
        A = self.position_and_velocity_levels(q, t)[1]
        if not np.isfinite(A).all():
            return
        M = self.system.mass_matrix(q)
        rank = int(np.min(self._row_rank(q, A, M)))
        independent = [c.independent_rows(self.system) for c in self.constraints]
        if rank >= sum(independent):
            return
        offsets = np.cumsum([0] + self._rows)
        ranks = [int(np.min(self._row_rank(q, A[..., offsets[k] : offsets[k + 1], :], M))) for k in range(len(self._rows))]
        parts = [f"{c.name!r} has rank {r} of its {m} rows" + (f" ({n} independent by design)" if n < m else "")
                 for c, r, m, n in zip(self.constraints, ranks, self._rows, independent) if r < n]
        if sum(ranks) > rank:
            parts.append(f"{sum(ranks) - rank} row(s) repeat rows of other constraints")
        where = "" if q.ndim == 1 else f" (the lowest of the {int(np.prod(q.shape[:-1]))} states)"
        warnings.warn(f"the constraint rows are not independent at the initial state: rank {rank} of "
                      f"{self.num_rows} rows{where}: {'; '.join(parts)}. Redundant rows get minimum-norm "
                      "multipliers; if the redundancy is not intended, a constraint holds less than it seems to "
                      "(e.g. a planar loop closure in a plane that is not the loop's); if it is, filter "
                      "mb.RankDeficientWarning", RankDeficientWarning, stacklevel=stacklevel)

    def _compiled_rank(self, q):
        """:meth:`rank` at one state ``q`` by the compiled step on the program's rows, with ``M``, in one call;
        ``None`` where it does not apply (no compiled step, a batch)."""
        if self._compiled_step is None or not self.system.model.is_one_state(q, finite=False):
            return None
        tail = self._solve_program(q, np.zeros(self.nv), None)[-1]
        self._raise_failure(tail)
        return int(np.nan_to_num(tail[kkt.RANK]))

    # ------------------------------------------------------------------ projection onto the constraints

    def project(self, q, v, t=0.0, *, tolerance=PROJECTION_TOLERANCE, max_iterations=PROJECTION_ITERATIONS):
        """The nearest consistent state: ``φ(q', t) = 0`` and ``A v' + b = 0``.

        Positions by Gauss–Newton steps ``δ = −M⁻¹Aᵀ (A M⁻¹ Aᵀ)⁺ φ`` on the rows with a position level (the
        smallest move in the kinetic-energy metric), then velocities by the ``M``-orthogonal
        projection ``v' = v − M⁻¹Aᵀ (A M⁻¹ Aᵀ)⁺ (A v + b)``. Raises :class:`ConstraintError` when the
        positions do not converge, or when they converge on a wrong branch of a constraint's rows (a loop
        closure's frames a half turn apart: :meth:`~multibody.constraints.Constraint.branch_error`). ``q``, ``v``
        may carry leading batch axes when :attr:`batched`; each state of a batch stops at its own tolerance, so
        that it equals its projection alone.

        The first projection of this system (here, or at the initial state of :func:`multibody.simulate`)
        gives a :class:`RankDeficientWarning` when the rows at the projected state are not independent.
        """
        return self.projection(q, v, t, tolerance=tolerance, max_iterations=max_iterations)[:2]

    def projection(self, q, v, t=0.0, *, tolerance=PROJECTION_TOLERANCE, max_iterations=PROJECTION_ITERATIONS,
                   stacklevel=3):
        """:meth:`project` of ``q (..., nq)``, ``v (..., nv)`` at ``t`` (s): ``(q, v, conditioning)``, the conditioning
        of the rows at the projected state ``(...)`` being the smallest singular value of ``A L⁻ᵀ`` above rounding
        (``m ε σ_max``, which leaves out redundant rows) over the largest, or (compiled, where the LQ factor decides) a
        lower bound on it within a factor ``m``; 1 without rows. Every projected state is checked for a wrong branch
        (:meth:`_check_branches`), and the first projection of the system checks the rank of the rows at its state
        (:meth:`_warn_if_rank_deficient`, warning ``stacklevel`` calls up from here)."""
        projected = self._projected(q, v, t, tolerance, max_iterations)
        self._check_branches(projected[0])
        if not self._rank_checked:
            self._rank_checked = True
            self._warn_if_rank_deficient(projected[0], t, stacklevel + 1)
        return projected

    def _projected(self, q, v, t, tolerance, max_iterations):
        """:meth:`projection` without the rank check: by one call of :func:`multibody.kernels.kkt.project` per state
        on compiled rows, else by the same Gauss–Newton corrections and rule on rows evaluated in Python
        (:meth:`_project_rows`)."""
        if self._compiled_step is not None and self.system.model.is_one_state(q, v):
            # (the kernel normalises q as below; a state that passes the checks unchanged skips them)
            return self._project_compiled(q, v, tolerance, max_iterations)
        q = self.system.normalize(np.asarray(q, dtype=float)) if hasattr(self.system, "normalize") else np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if not self.num_rows:
            return q, v, np.ones(spatial.batch_shape(q.shape[:-1], v.shape[:-1]))
        q, v = self._check_state(q, v)
        if self._compiled_step is not None:
            return self._project_compiled(q, v, tolerance, max_iterations)
        return self._project_rows(q, v, t, tolerance, max_iterations)

    def _correction(self, q, A, rhs, mask, previous=np.inf, tolerance=0.0):
        """One correction of the projection on rows given as arrays, by one compiled call
        (:func:`multibody.kernels.kkt.correction_arrays`): ``(δ (..., nv), whether Gauss–Newton has settled (...),
        status outputs (..., TAIL))`` for the rows ``A (..., m, nv)`` whose ``mask (m,)`` entry is set (``None``:
        all) with right-hand side ``rhs (..., m)``, in the metric of ``M(q)``; a failure raises its error."""
        nv, m = self.nv, A.shape[-2]
        M = self.system.mass_matrix(q)
        batch = spatial.batch_shape(M.shape[:-2], A.shape[:-2], rhs.shape[:-1], np.shape(previous))
        options = np.empty(batch + (3 + nv * nv,))
        options[..., 0], options[..., 1], options[..., 2] = self.rank_tolerance, tolerance, previous
        options[..., 3:] = M.reshape(M.shape[:-2] + (nv * nv,))
        rows = np.concatenate([np.broadcast_to(A.reshape(A.shape[:-2] + (m * nv,)), batch + (m * nv,)),
                               np.broadcast_to(rhs, batch + (m,))], axis=-1)
        mask = None if mask is None else mask.astype(float)
        row = driver.evaluate(kkt.correction_arrays, _NO_TREE, (options, rows, mask), (1, kkt.correction_columns(nv)),
                              batch, workspace=kkt.correction_workspace_size(nv, m))[..., 0, :]
        self._raise_failure(row[..., -kkt.TAIL :], non_finite=True)
        return row[..., :nv], row[..., nv + 1] != 0.0, row[..., -kkt.TAIL :]

    def _project_rows(self, q, v, t, tolerance, max_iterations):
        """:meth:`_projected` on rows evaluated in Python (a user's constraint, a moving surface, a system that is
        not a :class:`Model`): the loop of :func:`multibody.kernels.kkt.project` in Python, since each iteration
        asks the constraints for their rows at the new ``q``, around the same compiled correction and rule
        (:meth:`_correction`). Each state of a batch stops at its own tolerance, so that it equals its
        projection alone."""
        holonomic = self._position_mask
        # Each pass gives φ, A and b together: A serves both the next position step and, at the end,
        # the velocity projection.
        phi, A, b = self.position_and_velocity_levels(q, t)
        if holonomic.any():
            previous = np.full(q.shape[:-1], np.inf)
            for _ in range(max_iterations):
                dq, settled, _ = self._correction(q, A, phi, holonomic, previous, tolerance)
                off = ~settled
                previous = np.where(off, np.abs(dq).max(axis=-1), previous)
                if not off.any():
                    break
                # Only the states still off the constraints move: each state of a batch takes the steps
                # it would take alone.
                q = np.where(off[..., None], self.system.integrate(q, -dq, 1.0), q)
                phi, A, b = self.position_and_velocity_levels(q, t)
            else:
                raise STATUS_ERRORS[kkt.NOT_CONVERGED](self, 0, -1, np.abs(phi[..., holonomic]).max(), max_iterations)
        dv, _, tail = self._correction(q, A, matvec(A, v) + b, None)
        return q, v - dv, tail[..., kkt.CONDITIONING]

    @cached_property
    def _projection_sizes(self):
        """``(output columns, workspace size)`` of :func:`multibody.kernels.kkt.project` on the compiled step's rows."""
        return (kkt.projection_columns(self.nq, self.nv), kkt.projection_workspace_size(
            self.system.model.njoints, self.nq, self.nv, len(self._compiled_step[1]), self.num_rows))

    def _projection_settings(self, tolerance, max_iterations):
        """``[tolerance, max_iterations, position mask (m)]`` of :func:`multibody.kernels.kkt.project`, made once for
        each pair of options."""
        settings = self._settings.get((tolerance, max_iterations))
        if settings is None:
            settings = self._settings[tolerance, max_iterations] = np.concatenate(
                ([tolerance, max_iterations], self._position_mask.astype(float)))
        return settings

    def _project_compiled(self, q, v, tolerance, max_iterations):
        """:meth:`projection` by one call of :func:`multibody.kernels.kkt.project` per state (on all cores for
        a batch); a failure raises the error of its status (:data:`STATUS_ERRORS`)."""
        (program, frames, _), (columns, workspace) = self._compiled_step, self._projection_sizes
        model, nq, nv = self.system.model, self.nq, self.nv
        out_shape, settings = (1, columns), self._projection_settings(tolerance, max_iterations)
        if q.ndim == 1 and v.ndim == 1 and q.flags.c_contiguous and v.flags.c_contiguous:
            # (float64 arrays of the right sizes, as every caller has checked)
            row = driver.evaluate_one(kkt.project, model.tree, out_shape, q, v, settings, program, frames=frames,
                                      workspace=workspace)[0]
        else:
            batch = spatial.batch_shape(q.shape[:-1], v.shape[:-1])
            row = driver.evaluate(kkt.project, model.tree, (q, v, settings, program), out_shape, batch, frames,
                                  workspace)[..., 0, :]
        self._raise_failure(row[..., -kkt.TAIL :], max_iterations, non_finite=True)
        return row[..., :nq], row[..., nq : nq + nv], row[..., kkt.CONDITIONING]

    def body_forces(self, q, lam, t=0.0):
        """Spatial forces all constraints exert on the bodies: ``f_ext (njoints, 6)`` in joint frames.

        Pass them to :func:`multibody.joint_reaction_forces` (with the accelerations of
        :meth:`forward_dynamics`) to get the loads every joint carries in the closed mechanism.
        """
        lam = np.asarray(lam, dtype=float)
        offsets = np.cumsum([0] + self._rows)
        return sum(c.body_forces(self.system, q, lam[offsets[k]:offsets[k + 1]], t)
                   for k, c in enumerate(self.constraints))

    def energy(self, q, v):
        """Mechanical energy of the underlying system (J), NaN if it does not define one."""
        return self.system.energy(q, v) if hasattr(self.system, "energy") else float("nan")

    def __repr__(self):
        return f"ConstrainedSystem({self.nq=}, {self.nv=}, rows={self.num_rows}, constraints={self.constraints})"

