"""The mechanical-system interface that the simulation, linearization and shooting layers read: a
:class:`~multibody.model.Model` as a mechanical system (:class:`ModelSystem`), and the chart maps of one
(:class:`Charts`), in which the integrators take their steps. This module sits below
:mod:`multibody.constrained`, which builds on it."""

from __future__ import annotations

import numpy as np

from . import driver, dynamics, spatial
from .kernels import stepping
from .model import Model
from .spatial import matvec, transpose


def _model_method(name):
    """A member of :class:`ModelSystem` that is the method ``name`` of its model."""
    return property(lambda system: getattr(system.model, name),
                    doc=f"The model's :meth:`~multibody.model.Model.{name}`.")


class ModelSystem:
    """The mechanical-system interface of a :class:`Model`, as :class:`ConstrainedSystem` uses it.

    Any other system (e.g. ``LagrangianSystem.numeric()``) provides the same members: ``nq``, ``nv``,
    ``mass_matrix(q)``, ``bias_forces(q, v)``, ``integrate(q, v, dt)``, ``configuration_rate(q, v)``,
    ``normalize(q)``, ``neutral()`` and ``energy(q, v)``; the chart maps ``chart``, ``chart_rate``,
    ``velocity_alignment``, ``velocity_coupling`` and ``chart_magnitude`` (see :meth:`Model.chart`) only when its
    configurations are not a vector space with ``q̇ = v``, and optionally ``chart_coordinates``, which lets
    ``simulate`` evaluate stages on the constraints near a singular configuration.
    """

    def __init__(self, model: Model):
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        self.vector_space = model.is_vector_space

    def mass_matrix(self, q):
        return dynamics.mass_matrix(self.model, q)

    def mass_matrix_and_bias(self, q, v):
        """``(M (..., nv, nv), h (..., nv))`` together, for one state or a batch, from one pass down the
        tree (:func:`multibody.dynamics.mass_matrix_and_bias`)."""
        return dynamics.mass_matrix_and_bias(self.model, q, v)

    def bias_forces(self, q, v):
        return dynamics.bias_forces(self.model, q, v)

    def forward_dynamics(self, q, v, tau=None):
        """``a = M⁻¹ (τ − h)`` by the Articulated Body Algorithm (:func:`multibody.dynamics.forward_dynamics`):
        an unconstrained step without forming ``M``. Float arrays ``q (..., nq)``, ``v (..., nv)``, ``tau
        (..., nv)`` or ``None`` (zero), as :meth:`ConstrainedSystem.solve` checked them."""
        return dynamics.articulated_body_accelerations(self.model, q, v, tau, None, spatial.batch_shape(
            q.shape[:-1], v.shape[:-1], () if tau is None else tau.shape[:-1]))

    # the configuration maps, and the charts for Lie-group integration (see Model.chart), are the model's
    integrate = _model_method("integrate")
    configuration_rate = _model_method("configuration_rate")
    normalize = _model_method("normalize")
    chart = _model_method("chart")
    chart_coordinates = _model_method("chart_coordinates")
    chart_rate = _model_method("chart_rate")
    velocity_alignment = _model_method("velocity_alignment")
    velocity_coupling = _model_method("velocity_coupling")
    chart_magnitude = _model_method("chart_magnitude")

    def energy(self, q, v):
        """Kinetic plus gravitational potential energy ``E = T + U`` (J) of ``q (..., nq)``, ``v (..., nv)``:
        ``(...)``, a float64 scalar for one state; in one pass down the tree
        (:func:`multibody.dynamics.mechanical_energy`)."""
        return dynamics.mechanical_energy(self.model, q, v)


#: Largest angle (rad) that an adaptive method's step may turn a rotation vector of its chart, at the angular
#: speed of the step's start. Rotation vectors are singular at 2π (``J_l(δ)⁻¹`` holds ``cot(|δ|/2)``), and a
#: step whose chart comes near it loses digits in its stages and dense output: the box of the tests spinning at
#: 5 rad/s, DOP853 at rtol 1e-10, has orientation errors of 3e-13 with steps turning up to 4 rad, 1e-10 up to
#: 6 rad and 1e-7 with a step of 6.3 rad, though each step's end error stays near rtol. π keeps the chart where
#: ``chart_coordinates`` inverts it and leaves the angular speed room to double within a step.
CHART_TURN = np.pi


class Charts:
    """The chart maps of a mechanical system (see :meth:`multibody.model.Model.chart`); a system without
    them is a vector space with ``q̇ = v``: ``q = q_c + δ``, ``w = v`` (``velocity_alignment`` ``None``),
    magnitudes ``|q|``."""

    def __init__(self, system):
        self.nq, self.nv = system.nq, system.nv
        self.curved = hasattr(system, "chart") and not getattr(system, "vector_space", False)
        if not hasattr(system, "chart") and system.nq != system.nv:
            raise ValueError(f"{type(system).__name__} has nq = {system.nq} != nv = {system.nv} but no chart maps: "
                             "simulate integrates a curved configuration space through chart, chart_rate, "
                             "velocity_alignment, velocity_coupling and chart_magnitude (see multibody.model.Model.chart)")
        if self.curved:
            self.chart, self.chart_rate = system.chart, system.chart_rate
            self.velocity_alignment, self.velocity_coupling = system.velocity_alignment, system.velocity_coupling
            self.chart_magnitude = system.chart_magnitude
            # (optional in the mechanical-system interface: without it no stage is evaluated on the constraints)
            self.chart_coordinates = getattr(system, "chart_coordinates", None)
        else:
            self.chart, self.chart_rate = (lambda q0, delta: q0 + delta), (lambda delta, w: w)
            self.velocity_alignment, self.chart_magnitude = (lambda q: None), np.abs
            self.chart_coordinates = lambda q0, q: q - q0
        self.invertible = self.chart_coordinates is not None
        # the rotation vectors of a Model's charts (free-flyer and spherical joints): (k, 3) indices in v
        model = getattr(system, "model", None) if self.curved else None
        # a Model's charts take their states by the kernels a compiled run takes them by, so that both give the
        # same numbers (multibody.kernels.stepping.chart_state and aligned_velocity)
        self.tree = None if model is None else model.tree
        starts = [] if model is None else [start + (3 if joint.kind == "free-flyer" else 0)
                                           for joint, start in zip(model.joints, model.idx_v)
                                           if joint.kind in ("free-flyer", "spherical")]
        self.rotations = np.array(starts, dtype=int).reshape(-1, 1) + np.arange(3)

    def step_limit(self, state):
        """The longest step (s) from ``state = [q, v] (nq + nv,)`` in which no rotation vector of the chart turns
        by more than :data:`CHART_TURN` at the angular speeds there; ``inf`` without rotation vectors."""
        if not len(self.rotations):
            return np.inf
        speed = float(np.linalg.norm(state[self.nq + self.rotations], axis=-1).max())
        return CHART_TURN / speed if speed > 0.0 else np.inf

    def unchart(self, q_chart, y):
        """``(q, T(q), v)`` of chart states ``y = [δ, w] (..., 2 nv)``: ``q = chart(q_c, δ)``, ``v = Tᵀ w``."""
        q, v = self.state(q_chart, y)
        return q, self.velocity_alignment(q), v

    def state(self, q_chart, y):
        """``(q, v)`` of chart states ``y = [δ, w] (..., 2 nv)``: ``q = chart(q_c, δ)``, ``v = T(q)ᵀ w``."""
        nv = self.nv
        if self.tree is not None:
            batch = np.broadcast_shapes(np.shape(q_chart)[:-1], y.shape[:-1])
            nq = self.nq
            state = driver.evaluate(stepping.chart_state, self.tree, (q_chart, y), (1, nq + nv), batch,
                                    workspace=nq + 2 * nv + nv * nv).reshape(batch + (nq + nv,))
            return state[..., :nq], state[..., nq:]
        q = self.chart(q_chart, y[..., :nv])
        T = self.velocity_alignment(q)
        w = y[..., nv:]
        return q, (w if T is None else matvec(transpose(T), w))

    def coordinates(self, q_chart, q, v):
        """``y = [δ, w] (..., 2 nv)`` of the states ``(q, v)`` in the charts around ``q_chart``: the inverse of
        :meth:`unchart` (``δ`` by the system's ``chart_coordinates``)."""
        T = self.velocity_alignment(q)
        return np.concatenate([self.chart_coordinates(q_chart, q), v if T is None else matvec(T, v)], axis=-1)

    def to_chart(self, state):
        """``y = [0, w] (..., 2 nv)`` of states ``[q, v] (..., nq + nv)`` in the chart around their own ``q``."""
        nq = self.nq
        if not self.curved:
            # w = v
            y = state.copy()
            y[..., :nq] = 0.0
            return y
        if self.tree is not None:
            nv = self.nv
            w = driver.evaluate(stepping.aligned_velocity, self.tree, (state[..., :nq], state[..., nq:]), (1, nv),
                                state.shape[:-1], workspace=nv * nv).reshape(state.shape[:-1] + (nv,))
        else:
            T = self.velocity_alignment(state[..., :nq])
            w = state[..., nq:] if T is None else matvec(T, state[..., nq:])
        return np.concatenate([np.zeros_like(w), w], axis=-1)

    def from_chart(self, q_chart, y):
        """States ``[q, v] (..., nq + nv)`` of chart states ``y (..., 2 nv)``."""
        if not self.curved and np.shape(q_chart)[:-1] == y.shape[:-1]:
            # q = q_c + δ, v = w
            state = y.copy()
            state[..., : self.nq] += q_chart
            return state
        return np.concatenate(self.state(q_chart, y), axis=-1)


def system_parts(system):
    """``(constrained system or None, mechanical system, Model or None)`` of a :class:`Model` or a
    :class:`~multibody.constrained.ConstrainedSystem`, which is known by its members (``system``, ``model`` and
    ``forward_dynamics_derivatives``: this module is imported by the one that defines it); ``TypeError`` for
    anything else."""
    if isinstance(system, Model):
        return None, ModelSystem(system), system
    if all(hasattr(system, name) for name in ("system", "model", "forward_dynamics_derivatives")):
        return system, system.system, system.model
    raise TypeError(f"system must be a Model or a ConstrainedSystem, got {type(system).__name__}")
