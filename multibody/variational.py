"""Variational integrators: the discrete Hamilton's principle, ``simulate(..., method="variational")``.

Instead of discretising the equations of motion, discretise the action (J. E. Marsden and M. West,
*Discrete mechanics and variational integrators*, Acta Numerica 10 (2001) 357–514):
a *discrete Lagrangian* approximates the action over one step of size ``h``,

    L_d(q_k, q_{k+1}) ≈ ∫_{t_k}^{t_k+h} L(q, q̇) dt,

and the discrete path ``q_0 … q_N`` that makes ``Σ_k L_d(q_k, q_{k+1})`` stationary satisfies the
discrete Euler–Lagrange equations ``D2 L_d(q_{k−1}, q_k) + D1 L_d(q_k, q_{k+1}) = 0`` (``Dᵢ``: the
derivative with respect to the i-th argument). With the discrete Legendre transforms they read, in
*position–momentum form*, with the discrete Lagrange–d'Alembert forces ``f_k^±`` (the virtual work
of the forces over a step, lumped on its two ends):

    p_k     = −D1 L_d(q_k, q_{k+1}) − f_k⁻        (solved for q_{k+1}: Newton's method)
    p_{k+1} =  D2 L_d(q_k, q_{k+1}) + f_k⁺.

The map ``(q_k, p_k) → (q_{k+1}, p_{k+1})`` is symplectic when ``f = 0``; a momentum whose
coordinate does not appear in ``L`` is conserved exactly (the discrete Noether theorem), and the
energy error stays bounded over exponentially long times instead of drifting (backward error
analysis: Hairer, Lubich and Wanner, *Geometric Numerical Integration*, 2nd ed. 2006, Chapter IX).

Here ``L = ½ vᵀ M(q) v − U(q)`` with ``v = q̇``, so

    ∂L/∂v = M(q) v,        ∂L/∂q = C(q, v)ᵀ v − g(q)

(``C`` the Christoffel-consistent Coriolis matrix, ``Ṁ = C + Cᵀ`` and ``Cᵀ v = ½ vᵀ (∂M/∂q) v``;
``g = ∂U/∂q``). Two quadrature rules of order 2 give ``L_d`` (``ξ = (q_{k+1} − q_k)/h``):

* ``rule="midpoint"``: ``L_d = h L(q̄, ξ)``, ``q̄ = (q_k + q_{k+1})/2``:

      −D1 L_d = M(q̄) ξ − (h/2) ∂L/∂q(q̄, ξ),       D2 L_d = M(q̄) ξ + (h/2) ∂L/∂q(q̄, ξ),
      f_k⁻ = f_k⁺ = (h/2) τ(t_k + h/2, q̄, ξ);

* ``rule="trapezoidal"``: ``L_d = (h/2) [L(q_k, ξ) + L(q_{k+1}, ξ)]`` (Störmer–Verlet for separable ``L``):

      −D1 L_d = ½ (M(q_k) + M(q_{k+1})) ξ − (h/2) ∂L/∂q(q_k, ξ),
       D2 L_d = ½ (M(q_k) + M(q_{k+1})) ξ + (h/2) ∂L/∂q(q_{k+1}, ξ),
      f_k⁻ = (h/2) τ(t_k, q_k, ξ),     f_k⁺ = (h/2) τ(t_{k+1}, q_{k+1}, ξ).

Both are symmetric, so Yoshida's triple jump ``Φ_{w₁h} ∘ Φ_{w₀h} ∘ Φ_{w₁h}``, ``w₁ = 1/(2 − 2^{1/3})``,
``w₀ = −2^{1/3} w₁`` (H. Yoshida, Phys. Lett. A 150 (1990) 262; Hairer, Lubich and Wanner §II.4)
raises the order to 4 (``order=4``, systems without constraints).

**Constraints.** Constraint forces act at the nodes, along ``A(q_k)ᵀ``, as discrete multipliers
(Marsden and West; RATTLE, Hairer, Lubich and Wanner §VII.1): the node's impulse is split into
``A(q_k)ᵀ μ_k⁺``, which ends the step into ``q_k`` so that the output velocity
``v_k = M(q_k)⁻¹ p_k`` satisfies ``A(q_k, t_k) v_k + b = 0``, and ``A(q_k)ᵀ μ_k⁻``, which starts the
next step (a term ``− A(q_k)ᵀ μ_k⁻`` in the first equation, ``+ A(q_{k+1})ᵀ μ_{k+1}⁺`` in the second).
``μ_k⁻`` is found with ``q_{k+1}`` in the Newton iteration, from one condition per row:

* holonomic rows ``φ(q, t) = 0``: ``φ(q_{k+1}, t_{k+1}) = 0`` (RATTLE);
* nonholonomic rows ``A(q, t) v + b = 0``: the discrete constraint with the distribution at the midpoint,
  ``A(q̄, t_k + h/2) ξ + b = 0``, so that the configurations follow the discrete Lagrange–d'Alembert
  principle with constraint forces in the annihilator at the nodes (J. Cortés and S. Martínez,
  Nonlinearity 14 (2001) 1365) and a discrete constraint symmetric in ``q_k``, ``q_{k+1}`` (R. McLachlan
  and M. Perlmutter, J. Nonlinear Sci. 16 (2006) 283, discuss these choices).

Splitting the node's impulse this way changes no configuration; it only defines ``p_k``, so that the
output velocities lie on the constraints and no projection is needed (a split into equal halves
would leave ``p`` a period-two oscillation of size ``O(h)``). The reported multipliers are forces
(N, N·m, per row): the node's impulse over the time it stands for,
``λ_k = 2 (μ_k⁺ + μ_k⁻) / (h_{k−1} + h_k)``, a second-order approximation of the continuous
``λ(t_k)``; the two ends, which meet one step only, are extrapolated from their two nearest inner nodes.

**Lie-group joints.** Spherical and planar joints move on SO(3) and SE(2), with ``q ⊕ x = q exp(x)``
(:meth:`multibody.Model.integrate`) and joint velocities in the moving frame; a free flyer moves on
SO(3) × R³, its position by ``x_lin`` in the parent frame and its rotation by ``R exp(ω)``, with the group
velocity ``w = (ṗ, ω)`` and the joint velocity ``v = T(q) w``, ``T = diag(Rᵀ, 1)`` (:class:`_GroupLagrangian`
gives ``L`` in ``w``). The exponential of SE(3) would move a spinning body along a screw, a path that
neither a body in free flight nor a rolling one follows: its error grows with ``(h ω)²``, while on
SO(3) × R³ a thrown body's centre keeps its parabola and the rolling ball its closed form to rounding. The
step is ``q_{k+1} = q_k ⊕ Δ``, the discrete Lagrangian ``L_d = h L(q_k ⊕ Δ/2, Δ/h)`` with
``Δ = log(q_k⁻¹ q_{k+1})`` (the exponential's straight path has the constant joint velocity ``ξ = Δ/h``),
and variations are left-trivialised, ``q → q exp(ε η)`` (N. Bou-Rabee and J. E. Marsden,
*Hamilton–Pontryagin integrators on Lie groups*, Found. Comput. Math. 9 (2009) 197; T. Lee, M. Leok and
N. H. McClamroch, *Lie group variational integrators for the full body problem*, Comput. Methods Appl.
Mech. Engrg. 196 (2007) 2907). Varying ``q_k`` changes ``Δ`` by ``−J_l(Δ)⁻¹ η`` and the midpoint by
``Ad_exp(−Δ/2) η + ½ J_r(Δ/2) δΔ``; varying ``q_{k+1}`` changes ``Δ`` by ``J_r(Δ)⁻¹ η``
(:class:`_LieGroupChart` gives ``Ad``, ``J_l`` and ``J_r(x) = J_l(−x)``). With ``Π̄ = ∂L/∂q(q̄, ξ) + τ̄``,
the identities ``J_l(x) = Ad_exp(x) J_r(x)`` and ``½ J_r(Δ/2) − Ad_exp(Δ/2) J_r(Δ) = −½ J_l(Δ/2)`` turn the
discrete Legendre transforms into

    J_l(Δ)ᵀ p_k = M(q̄) ξ − (h/2) J_l(Δ/2)ᵀ Π̄,        p_{k+1} = Ad_exp(Δ)ᵀ p_k + h Ad_exp(Δ/2)ᵀ Π̄

(midpoint), and ``J_l(Δ)ᵀ (p_k + (h/2) Π_k) = ½ (M(q_k) + M(q_{k+1})) ξ``,
``p_{k+1} = Ad_exp(Δ)ᵀ (p_k + (h/2) Π_k) + (h/2) Π_{k+1}`` (trapezoidal); on the commutative joints
``Ad = J_l = 1`` and they are the equations above. Here ``∂L/∂q`` is left-trivialised,
``d/dε L(q exp(ε η), v) = (C(q, v)ᵀ v − g(q) − ad_vᵀ M(q) v)·η`` (from ``Ṁ = C + Cᵀ``, which the
Coriolis matrix keeps on every joint kind), plus ``(0, p_lin × v_lin)`` on a free flyer in ``w``. The
discrete Lagrangian is invariant under moving the whole system, so a free system's spatial momentum is
conserved by the solution of the discrete equations, to the tolerance of its Newton solve: about 1e-16
of the momentum per step at the default ``tolerance=1e-12``, 1e-12 over 10⁵ steps at ``1e-14``.

**Newton's method.** The unknown of a step is the increment ``Δ`` (not ``q_{k+1}``, whose difference
``q_{k+1} − q_k`` would lose the digits of a large angle). The Jacobian of ``−D1 L_d − f⁻`` with respect
to ``Δ`` is, for the midpoint rule, to first order in ``Δ``,

    J = M(q̄)/h + ½ (K − S) − (h/4) ∂²L/∂q² − ∂f⁻/∂Δ,      K = ∂(M(q) ξ)/∂q,  S = ∂(C(q, ξ)ᵀ ξ)/∂ξ at q̄

(``S = Kᵀ`` on a vector space; the terms in ``ad`` cancel to first order; in a free flyer's group
velocities ``K``, ``H`` and ``S = Kᵀ`` also carry the derivatives of ``T(q)``:
:meth:`_GroupLagrangian.jacobian_terms`), and for the trapezoidal rule
``J = (M(q_k) + M(q_{k+1}))/(2h) + ½ K(q_{k+1}) − ½ S(q_k) − ∂f⁻/∂Δ``.
For a :class:`~multibody.model.Model`, ``K = ∂τ/∂q|_{v=0, a=ξ} − ∂g/∂q`` from the analytical
derivatives (:func:`multibody.inverse_dynamics_derivatives`, :func:`multibody.gravity_derivatives`),
and ``∂²L/∂q²`` is taken as ``−∂g/∂q``: the term ``½ ξᵀ (∂²M/∂q²) ξ`` is left out, a relative error
of order ``h² |ξ|²`` that makes the iteration converge linearly with that ratio (a quasi-Newton
method); symbolic systems give their exact Hessians. ``∂f⁻/∂Δ`` of a callable ``τ`` is taken by
forward differences. The Jacobian is formed once per step, at the predictor, and formed anew when an
iteration reduces the residual less than tenfold. The iteration stops when the residual of the first
equation is at most ``tolerance`` (default ``1e-12``) times the size of its momentum terms, and the
holonomic rows at most ``tolerance · max(1, |q_{k+1}|)``; otherwise :class:`SimulationError`.

For a :class:`~multibody.model.Model` without constraints or with built-in rows fixed in time, whose joint forces
are none, constant, a :class:`~multibody.integrators.PD` controller or a ``numba.njit`` function ``f(t, q, v, out)``
(with the joints' damping), every step, Newton's iteration included, is compiled
(:func:`multibody.kernels.variational.advance`, one call per chunk of steps); other systems (symbolic ones, user
constraints) and joint forces from a Python callable take the same steps here, in Python.

Limitations: a system other than a :class:`~multibody.model.Model` needs configurations in a vector
space with ``q̇ = v``; ``order=4`` is for systems without constraints.
"""

from __future__ import annotations

import functools
import math
import time
import warnings

import numpy as np

from . import driver, linalg, numba_hooks, spatial
from .integrators import CONTROLLER_FUNCTION, CompiledController, PDController, control_rows, controller_function
from .constrained import ConstrainedSystem, ConstraintError
from .mechanical import ModelSystem
from .model import all_finite
from .runs import (FIRST_CHUNK, Progress, SimulationError, checked_timing, joint_damping_of, next_chunk,
                   non_finite_torque, output_times, projected_start, report_limits, require_finite, torque_function,
                   with_joint_damping)
from .tree import IQ, IV, KIND
from .kernels import configuration, coriolis, crba
from .kernels import lagrangian as lagrangian_kernels
from .kernels import variational as iteration_kernels
from .kernels import joints as kinds
from .kernels import derivatives as derivative_kernels

RULES = ("midpoint", "trapezoidal")
ORDERS = (2, 4)

#: Yoshida's triple jump (Phys. Lett. A 150 (1990) 262): the weights of the three
#: sub-steps ``w₁ h, w₀ h, w₁ h`` of the fourth-order composition of a symmetric second-order step.
YOSHIDA_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
YOSHIDA_W0 = -(2.0 ** (1.0 / 3.0)) * YOSHIDA_W1

_EMPTY = np.zeros(0)  # an unused kernel input (zero velocity, acceleration, no external forces)
_GROUP = np.ones(1)  # lagrangian_terms' flag: the velocities are the group velocities of _GroupLagrangian

#: Relative size of the forward-difference step of ``∂τ/∂Δ`` (about √ε).
_FORCE_DIFFERENCE_STEP = 1.5e-8


# ============================================================================= the Lagrangian's terms

class _ModelLagrangian:
    """``M``, ``∂L/∂q`` and the Newton-Jacobian terms of a :class:`~multibody.model.Model` with ``q̇ = v``.

    The compiled kernels are called one state each (:func:`multibody.driver.evaluate_one`): the Newton
    iteration calls them a few times per step with float arrays it made itself, for which the public
    functions' checks and batch handling would cost more than the algorithms.
    """

    def __init__(self, model):
        self.model = model
        self.nv = model.nv
        #: the chart of the Lie-group joints, ``None`` when the configurations form a vector space
        self.chart = None if model.is_vector_space else _LieGroupChart(model)

    def _run(self, kernel, shape, q, v=_EMPTY, a=_EMPTY):
        # (the step's own C-contiguous float64 vectors: the types driver.evaluate_one's callers guarantee)
        return driver.evaluate_one(kernel, self.model.tree, shape, np.ascontiguousarray(q, dtype=float), v, a)

    def mass_matrix(self, q):
        # CRBA (RBDA Table 6.2): multibody.mass_matrix
        return self._run(crba.mass_matrix, (self.nv, self.nv), q)

    def terms(self, q, v, group=False):
        """``(M(q), ∂L/∂q(q, v))`` by one compiled call (:func:`multibody.kernels.lagrangian.lagrangian_terms`):
        ``∂L/∂q = C(q, v)ᵀ v − g(q)`` (``C`` Christoffel-consistent: ``Cᵀ v = ½ vᵀ (∂M/∂q) v``), less
        ``ad_vᵀ M v`` on Lie-group joints (module docstring, "Lie-group joints"). ``group``: ``v`` are
        the group velocities of :class:`_GroupLagrangian`, which then gets its ``M_G`` and ``∂L_G/∂q``."""
        nv = self.nv
        out = self._run(lagrangian_kernels.lagrangian_terms, (nv + 1, nv), q, np.ascontiguousarray(v, dtype=float),
                        _GROUP if group else _EMPTY)
        return out[:nv], out[nv]

    def gradient(self, q, v):
        """``∂L/∂q (nv,)`` at ``(q, v)`` (:meth:`terms`)."""
        return self.terms(q, v)[1]

    def momentum_terms(self, q, v):
        """``(K, H)`` of :meth:`jacobian_terms`: ``K = ∂τ/∂q|_{v=0, a=v} − ∂g/∂q`` and ``H = −∂g/∂q``."""
        nv = self.nv
        kernel = derivative_kernels.inverse_dynamics_derivatives
        dg_dq = self._run(kernel, (nv, nv), q)
        return self._run(kernel, (2 * nv, nv), q, np.zeros(nv), np.ascontiguousarray(v, dtype=float))[:nv] - dg_dq, -dg_dq

    def jacobian_terms(self, q, v):
        """``(K, H, S)``: ``K = ∂(M(q) v)/∂q``, ``H ≈ ∂²L/∂q²`` and ``S = ∂(C(q, v)ᵀ v)/∂v``, all ``(nv, nv)``.

        RNEA with zero velocity and acceleration ``v`` is ``M(q) v + g(q)``, so its ``q``-derivative
        (:func:`multibody.inverse_dynamics_derivatives`) less ``∂g/∂q`` (:func:`multibody.gravity_derivatives`)
        is ``K``. ``H = −∂g/∂q`` leaves out ``½ vᵀ (∂²M/∂q²) v`` (no analytical second derivatives of
        ``M``), a quasi-Newton approximation. ``S = Kᵀ`` on a vector space (``Cᵀ v = ½ Kᵀ v``); on Lie-group
        joints, from ``Ṁ = C + Cᵀ`` and ``Ṁ v = K v``, ``S = C + Cᵀ + K − ∂(C v)/∂v``, the last term the
        velocity derivative of RNEA at zero acceleration.
        """
        nv = self.nv
        kernel = derivative_kernels.inverse_dynamics_derivatives
        v = np.ascontiguousarray(v, dtype=float)
        K, H = self.momentum_terms(q, v)
        if self.chart is None:
            return K, H, K.T
        C = self._run(coriolis.coriolis_matrix, (nv, nv), q, v)
        dCv_dv = self._run(kernel, (2 * nv, nv), q, v, np.zeros(nv))[nv:]
        return K, H, C + C.T + K - dCv_dv


class _SystemLagrangian:
    """The same terms of a system that provides them (``LagrangianSystem.numeric()``): ``mass_matrix(q)``,
    ``lagrangian_gradient(q, v)``, and optionally ``momentum_jacobian(q, v)``, ``lagrangian_hessian(q, v)``
    (exact Newton terms) and ``generalized_forces(q, v)`` (forces without a potential, ``Q``)."""

    def __init__(self, system):
        self.system = system
        self.nv = system.nv
        self.chart = None
        self.has_forces = hasattr(system, "generalized_forces") and _has_nonzero_forces(system)

    def mass_matrix(self, q):
        return np.asarray(self.system.mass_matrix(q), dtype=float).reshape(self.nv, self.nv)

    def gradient(self, q, v):
        return np.asarray(self.system.lagrangian_gradient(q, v), dtype=float).reshape(self.nv)

    def terms(self, q, v):
        return self.mass_matrix(q), self.gradient(q, v)

    def jacobian_terms(self, q, v):
        zero = np.zeros((self.nv, self.nv))
        K = self.system.momentum_jacobian(q, v) if hasattr(self.system, "momentum_jacobian") else zero
        H = self.system.lagrangian_hessian(q, v) if hasattr(self.system, "lagrangian_hessian") else zero
        K = np.asarray(K, dtype=float)
        return K, np.asarray(H, dtype=float), K.T


def _has_nonzero_forces(system):
    """Whether a system's generalized forces ``Q`` may be non-zero: ``False`` only for a symbolic system whose
    ``Q`` are zero expressions (which saves their evaluation at every Newton iteration)."""
    lagrangian = getattr(system, "symbolic_lagrangian", None)
    if lagrangian is None:
        return True
    return any(entry != 0 for entry in lagrangian[3])


def _lagrangian_of(mechanical):
    """The terms of ``L`` that the discrete equations need, or ``ValueError`` explaining what is missing."""
    if isinstance(mechanical, ModelSystem):
        return _ModelLagrangian(mechanical.model)
    if hasattr(mechanical, "chart") and not getattr(mechanical, "vector_space", False):
        raise ValueError(f"method='variational' needs configurations in a vector space with q̇ = v; "
                         f"{type(mechanical).__name__} has chart maps (a curved configuration space): the Lie-group "
                         "variational integrator is available for a Model's free-flyer, spherical and planar joints, "
                         "whose group structure it knows, not for a system's own charts")
    if mechanical.nq != mechanical.nv:
        raise ValueError(f"method='variational' needs q̇ = v, but {type(mechanical).__name__} has nq = {mechanical.nq} "
                         f"!= nv = {mechanical.nv}")
    # (a NumericLagrangian made by hand, without its Lagrangian, has the methods but cannot answer them)
    if getattr(mechanical, "symbolic_lagrangian", True) is None or not hasattr(mechanical, "lagrangian_gradient"):
        raise ValueError(
            f"method='variational' needs the Lagrangian's gradient ∂L/∂q, which {type(mechanical).__name__} does not "
            "provide: use a Model, LagrangianSystem.numeric(), or a system with lagrangian_gradient(q, v) (and "
            "optionally momentum_jacobian(q, v), lagrangian_hessian(q, v), generalized_forces(q, v))")
    return _SystemLagrangian(mechanical)


# ============================================================================= Lie-group joints

class _LieGroupChart:
    """The group operations that the discrete equations of a model with Lie-group joints need.

    The integrator's group: SO(3) for a spherical joint and SE(2) for a planar one, stepped by
    :meth:`multibody.Model.integrate` (``X exp(x)``), and SO(3) × R³ for a free flyer (:meth:`advance`);
    ``q + x`` on the other joints; ``x (nv,)`` in the velocity coordinates ``ω`` (spherical),
    ``[vx, vy, ω]`` (planar), ``[ṗ, ω]`` (free flyer, ``ṗ`` in the parent frame: :meth:`alignment`).
    The model's own SE(3) exponential of a free flyer (``[v_lin, ω]`` in the body frame) gives
    ``ad_xᵀ p`` of its Lagrangian (:func:`multibody.kernels.lagrangian.lagrangian_terms`). The Lie algebras'
    adjoints are

        SE(3): ad_(v,ω) = [[ω×, v×], [0, ω×]],   SO(3): ad_ω = ω×,   SE(2): ad_(u,ω) = [[ω E, −E u], [0, 0]]

    (``E`` the quarter turn of the plane; ``ad = 0`` on the commutative joints), and the step needs
    (J. Solà, J. Deray and D. Atchuthan, *A micro Lie theory for state estimation in robotics*, 2018,
    eqs. 41–46; Hairer, Lubich and Wanner, *Geometric Numerical Integration*, §III.4):

        Ad_exp(x) = exp(ad_x) = Σ_{j≥0} ad_x^j / j!,          J_l(x) = dexp_x = Σ_{j≥0} ad_x^j / (j + 1)!,

    ``Ad`` the adjoint of the group element ``exp(x)`` and ``J_l`` the left Jacobian of the exponential:
    ``exp(x + δ) = exp(J_l(x) δ) exp(x)``; the right Jacobian is ``J_r(x) = J_l(−x)``, with
    ``exp(x + δ) = exp(x) exp(J_r(x) δ)``.
    """

    def __init__(self, model):
        tree = self._tree = model.tree
        self.nq, self.nv = tree.nq, tree.nv
        #: each free flyer's ``(iq, iv)``: its position and linear velocity offsets
        self.free_flyers = [(int(row[IQ]), int(row[IV])) for row in tree.joints if row[KIND] == kinds.FREE_FLYER]
        #: ``T(q)`` of the step's configurations, keyed by their bytes: a Newton iteration asks for the
        #: alignment of the same few configurations several times (mass matrix, gradient, rows)
        self._alignments = {}

    def advance(self, q, x):
        """``q ⊕ x (nq,)`` on the integrator's group: :meth:`multibody.Model.integrate` (its compiled
        kernel), but a free flyer's position moves by ``x_lin`` in the parent frame (SO(3) × R³; its
        rotation ``R exp(ω)`` does not depend on the linear part)."""
        q, x = np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(x, dtype=float)
        moved = driver.evaluate_one(configuration.integrate, self._tree, (1, self.nq), q, x)[0]
        for iq, iv in self.free_flyers:
            moved[iq:iq + 3] = q[iq:iq + 3] + x[iv:iv + 3]  # (the rotation is Model.integrate's, R exp(ω))
        return moved

    def alignment(self, q):
        """``T(q) (nv, nv)`` with the joint velocities ``v = T w`` of the group velocities ``w``: ``Rᵀ`` on a
        free flyer's linear velocity (the group's is in the parent frame), the identity elsewhere; ``None``
        without free flyers."""
        if not self.free_flyers:
            return None
        q = np.ascontiguousarray(q, dtype=float)
        key = q.tobytes()
        T = self._alignments.get(key)
        if T is not None:
            return T
        # the compiled velocity_alignment holds each free flyer's R (parent from body) on its diagonal
        aligned = driver.evaluate_one(configuration.velocity_alignment, self._tree, (self.nv, self.nv), q)
        T = np.eye(self.nv)
        for _, iv in self.free_flyers:
            T[iv:iv + 3, iv:iv + 3] = aligned[iv:iv + 3, iv:iv + 3].T
        T.setflags(write=False)
        if len(self._alignments) >= 8:
            self._alignments.clear()
        self._alignments[key] = T
        return T

    def exponential_terms(self, x):
        """``(Ad_exp(x), J_l(x))``, both ``(nv, nv)`` (:func:`multibody.kernels.configuration.exponential_terms`)."""
        out = driver.evaluate_one(configuration.exponential_terms, self._tree, (2 * self.nv, self.nv),
                                  np.ascontiguousarray(x, dtype=float))
        return out[:self.nv], out[self.nv:]


class _GroupLagrangian:
    """The Lagrangian's terms in the integrator's group velocities ``w``, with ``v = T(q) w``
    (:meth:`_LieGroupChart.alignment`: a free flyer's linear velocity in the parent frame):

        M_G = Tᵀ M T,      ∂L/∂q|_G = Tᵀ ∂L/∂q(q, T w) + (0, p_lin × v_lin)  (p = M v, on each free flyer),

    the second from ``L_G(q, w) = L(q, T(q) w)``: turning a free flyer by ``exp(ε η)`` at a fixed
    parent-frame velocity turns its body-frame velocity by ``−ε η × v_lin``."""

    def __init__(self, lagrangian):
        self.inner, self.chart, self.nv = lagrangian, lagrangian.chart, lagrangian.nv

    def mass_matrix(self, q):
        """``M_G = Tᵀ M T`` (:meth:`terms` at rest)."""
        return self.terms(q, np.zeros(self.nv))[0]

    def gradient(self, q, w):
        return self.terms(q, w)[1]

    def terms(self, q, w):
        """``(M_G, ∂L/∂q|_G)`` at one configuration, by one compiled call (:meth:`_ModelLagrangian.terms`)."""
        return self.inner.terms(q, w, group=True)

    def jacobian_terms(self, q, w):
        """``(K_G, H_G, S_G)`` of ``L_G(q, w) = L(q, T(q) w)``, from the model's ``K``, ``H = −∂g/∂q`` (in its own
        tangent, a free flyer's translation in the body frame: ``δ = T η`` for the group's variation ``η``)
        and the derivatives of ``T`` itself. Under ``q exp(ε η)`` a free flyer's ``R`` turns by ``exp(ε [η_ω]×)``,
        so ``d(T w) = E η`` with ``E = [v_lin]×`` in the (linear, angular) block, and ``d(Tᵀ f) = −R [f_lin]× η_ω``
        for a fixed joint-velocity covector ``f``. Then

            K_G = d(M_G w) = Tᵀ K T + Tᵀ M E + D(M v),       H_G = Tᵀ H T + D(−g),       S_G = K_Gᵀ,

        ``D(f)`` the block ``−R [f_lin]×``; ``S_G = ∂(∂L_G/∂q)/∂w = K_Gᵀ`` since both are mixed second
        derivatives of ``½ wᵀ M_G(q) w``. ``D(−g)`` turns the gravity of the quasi-Newton ``H`` with ``T``, as
        ``H`` leaves out the velocity terms of ``∂L/∂q`` (with them the iteration converges more slowly:
        they belong with the second derivatives of ``M`` that ``H`` leaves out)."""
        T = self.chart.alignment(q)
        v = T @ w
        K, H = self.inner.momentum_terms(q, v)
        M, minus_g = self.inner.terms(q, np.zeros(self.nv))  # ∂L/∂q at rest is −g
        E, D_momentum, D_gravity = (np.zeros((self.nv, self.nv)) for _ in range(3))
        p = M @ v
        for _, iv in self.chart.free_flyers:
            lin, ang = slice(iv, iv + 3), slice(iv + 3, iv + 6)
            R = T[lin, lin].T
            E[lin, ang] = spatial.skew(v[lin])
            D_momentum[lin, ang] = -R @ spatial.skew(p[lin])
            D_gravity[lin, ang] = -R @ spatial.skew(minus_g[lin])
        K_G = T.T @ (K @ T + M @ E) + D_momentum
        return K_G, T.T @ H @ T + D_gravity, K_G.T


def _group_force(force, chart):
    """``τ_G(t, q, w) = T(q)ᵀ τ(t, q, T(q) w)``: the forces' virtual work in the group velocities."""
    if force is None:
        return None

    def group_force(t, q, w):
        T = chart.alignment(q)
        return T.T @ np.asarray(force(t, q, T @ w), dtype=float)

    return group_force


# ============================================================================= one step

class _Rows:
    """The constraint rows of a :class:`ConstrainedSystem`, split into holonomic (``H``: ``φ(q, t) = 0``,
    RATTLE-type) and nonholonomic (``N``: ``A v + b = 0`` only, midpoint distribution)."""

    def __init__(self, constrained):
        self.constrained = constrained
        self.m = constrained.num_rows
        mask = constrained.position_rows
        #: the indices of each kind of row: ``slice(None)`` when all rows are of that kind (which indexes
        #: without the copy and the search of a mask)
        self.holonomic = slice(None) if mask.all() else np.flatnonzero(mask)
        self.nonholonomic = slice(None) if not mask.any() else np.flatnonzero(~mask)
        self.any_holonomic = bool(mask.any())
        self.any_nonholonomic = not mask.all()

    def levels(self, q, t):
        """``(φ (m,), A (m, nv), b (m,))`` at ``(q, t)``."""
        return self.constrained.position_and_velocity_levels(q, t)

    def independent(self, q, A):
        """Whether the rows ``A (m, nv)`` at ``q`` are independent, by the system's one rank decision
        (:meth:`ConstrainedSystem.rank`'s singular values of ``A`` in the metric of ``M(q)``)."""
        return self.constrained.rank(q, A=A) == self.m


class _GroupRows(_Rows):
    """Constraint rows in the group velocities: ``A T(q)`` (see :class:`_GroupLagrangian`)."""

    def __init__(self, constrained, chart):
        super().__init__(constrained)
        self.chart = chart

    def levels(self, q, t):
        phi, A, b = super().levels(q, t)
        return phi, A @ self.chart.alignment(q), b

    def independent(self, q, A):
        return super().independent(q, A @ self.chart.alignment(q).T)


def _norm(x):
    """``max |xᵢ|`` of a short vector (NaN when it holds one); a Python loop is quicker than NumPy's
    reductions for the few coordinates of a step."""
    values = x.tolist()
    return max(map(abs, values), default=0.0) if math.isfinite(sum(values)) else math.nan


def _step(lagrangian, rows, rule, force, t, h, q0, p0, levels0, guess, tolerance, max_iterations, impulse_guess=None):
    """One step ``(q_k, p_k) → (q_{k+1}, p_{k+1})`` of size ``h`` (s, may be negative in a composition).

    Args:
        lagrangian: :class:`_ModelLagrangian` or :class:`_SystemLagrangian`.
        rows: :class:`_Rows` or ``None`` (no constraints).
        force: ``force(t, q, v) -> (nv,)`` or ``None``: joint forces plus the system's own ``Q``.
        q0, p0: configuration ``(nq,)`` and momentum ``p = M v`` ``(nv,)`` (kg m/s, kg m²/s per coordinate),
            in the velocities of ``lagrangian`` (a free flyer's group velocities under :class:`_GroupLagrangian`).
        levels0: ``(φ, A, b)`` of the rows at ``(q0, t)`` (``None`` without rows).
        guess: predicted increment ``Δ`` ``(nv,)``, ``q_{k+1} = q_k ⊕ Δ``.
        impulse_guess: predicted start impulses ``μ⁻ (m,)`` (the last step's, scaled to this step), or
            ``None`` (zero).
    Returns:
        ``(q1, p1, v1, μ⁻ (m,), μ⁺ (m,), levels1, Δ)``: the impulses ``μ`` (N s per row) that act at the
        start and at the end of the step, and the step's increment ``Δ (nv,)``, ``q1 = q0 ⊕ Δ``.
    Raises:
        _NotConverged: the Newton iteration did not meet the tolerance.
    """
    nv = p0.shape[0]
    m = 0 if rows is None else rows.m
    chart = lagrangian.chart
    advance = np.add if chart is None else chart.advance  # (q ⊕ Δ = q + Δ in a vector space)
    H_rows = rows.holonomic if m else None
    N_rows = rows.nonholonomic if m else None
    # every row's impulse at the start acts along A(q_k)ᵀ: constraint forces at the nodes
    B = levels0[1] if m else None
    # independent rows give their impulses by a direct solve; redundant ones the minimum-norm impulses
    solve_rows = None
    if m:
        solve_rows = (_direct_solve if rows.independent(q0, B) else _least_squares)

    if rule == "trapezoidal":
        M0 = lagrangian.mass_matrix(q0)

    def evaluate(delta):
        """The first discrete equation's terms at ``Δ``: ``(start, scale, state)``, ``start = −D1 L_d − f⁻``."""
        xi = delta / h
        if rule == "midpoint":
            q_mid = advance(q0, 0.5 * delta)
            M, Lq = lagrangian.terms(q_mid, xi)
            f = None if force is None else force(t + 0.5 * h, q_mid, xi)
            M_xi = M @ xi
            pull = Lq if f is None else Lq + f
            if chart is None:
                # −D1 L_d − f⁻ = M(q̄) ξ − (h/2) (∂L/∂q(q̄, ξ) + τ̄)
                start, exponentials = M_xi - 0.5 * h * pull, None
            else:
                # −D1 L_d − f⁻ = J_l(Δ)⁻ᵀ (M(q̄) ξ − (h/2) J_l(Δ/2)ᵀ (∂L/∂q(q̄, ξ) + τ̄))
                exponentials = chart.exponential_terms(delta), chart.exponential_terms(0.5 * delta)
                start = linalg.solve(exponentials[0][1].T, (M_xi - 0.5 * h * (exponentials[1][1].T @ pull))[:, None])[:, 0]
            scale = max(_norm(M_xi), 0.5 * abs(h) * _norm(Lq), 0.0 if f is None else 0.5 * abs(h) * _norm(f))
            return start, scale, (q_mid, xi, M, pull, exponentials)
        q1 = advance(q0, delta)
        M1 = lagrangian.mass_matrix(q1)
        Lq0 = lagrangian.gradient(q0, xi)
        f0 = None if force is None else force(t, q0, xi)
        pull = Lq0 if f0 is None else Lq0 + f0
        M_xi = 0.5 * (M0 + M1) @ xi
        if chart is None:
            # −D1 L_d − f⁻ = ½ (M(q_k) + M(q_{k+1})) ξ − (h/2) (∂L/∂q(q_k, ξ) + τ(t_k, q_k, ξ))
            start, exponentials = M_xi - 0.5 * h * pull, None
        else:
            # −D1 L_d − f⁻ = J_l(Δ)⁻ᵀ ½ (M(q_k) + M(q_{k+1})) ξ − (h/2) (∂L/∂q(q_k, ξ) + τ(t_k, q_k, ξ))
            exponentials = (chart.exponential_terms(delta),)
            start = linalg.solve(exponentials[0][1].T, M_xi[:, None])[:, 0] - 0.5 * h * pull
        scale = max(_norm(M_xi), 0.5 * abs(h) * _norm(Lq0), 0.0 if f0 is None else 0.5 * abs(h) * _norm(f0))
        return start, scale, (q1, xi, M1, pull, exponentials)

    def start_force(delta):
        """``f⁻ (nv,)`` of the step at ``Δ`` (for its forward differences)."""
        xi = delta / h
        if rule == "midpoint":
            return 0.5 * h * np.asarray(force(t + 0.5 * h, advance(q0, 0.5 * delta), xi), dtype=float)
        return 0.5 * h * np.asarray(force(t, q0, xi), dtype=float)

    def jacobian(delta, state):
        """``∂(−D1 L_d − f⁻)/∂Δ (nv, nv)``, see the module docstring."""
        xi = delta / h
        if rule == "midpoint":
            q_mid, _, M, _, _ = state
            K, H, S = lagrangian.jacobian_terms(q_mid, xi)
            J = M / h + 0.5 * (K - S) - 0.25 * h * H
        else:
            q1, _, M1, _, _ = state
            K1, _, _ = lagrangian.jacobian_terms(q1, xi)
            _, _, S0 = lagrangian.jacobian_terms(q0, xi)
            J = 0.5 * (M0 + M1) / h + 0.5 * (K1 - S0)
        if force is not None:
            # forward differences of f⁻ along each coordinate of Δ
            base = start_force(delta)
            step = _FORCE_DIFFERENCE_STEP * max(_norm(delta), abs(h) * 1e-8, 1e-300)
            for j in range(nv):
                shifted = delta.copy()
                shifted[j] += step
                J[:, j] -= (start_force(shifted) - base) / step
        return J

    def constraint_terms(delta, state):
        """Rows of the step's constraints at ``Δ`` (``state``: :func:`evaluate`'s at ``Δ``): ``(c, C, scales,
        levels1, q1)`` with the residuals ``c (m,)``, their linearisation ``C (m, nv)`` in ``Δ``, the rows' scales,
        and the levels at ``q_{k+1}`` and ``q_{k+1}`` itself (``None`` without holonomic rows, which alone need
        them while iterating). The scales: ``max(1, |q_{k+1}|)`` for ``φ`` (its units are those of ``q``), the size
        of the terms of ``A ξ + b`` and ``max|A_row| · max|ξ|`` for the nonholonomic rows."""
        levels1 = q1 = None
        c, C, scales = np.empty(m), np.empty((m, nv)), np.empty(m)
        if rows.any_holonomic:
            q1 = state[0] if rule != "midpoint" else advance(q0, delta)
            levels1 = rows.levels(q1, t + h)
            # φ(q_{k+1}, t_{k+1}) = 0
            c[H_rows] = levels1[0][H_rows]
            # (∂(q_k ⊕ Δ)/∂Δ = J(Δ) in the tangent at q_{k+1})
            C[H_rows] = (levels1[1][H_rows] if chart is None
                         else levels1[1][H_rows] @ chart.exponential_terms(-delta)[1])
            scales[H_rows] = max(1.0, _norm(q1))
        if rows.any_nonholonomic:
            # A(q̄, t̄) ξ + b(q̄, t̄) = 0: the discrete constraint with the distribution at the midpoint
            q_mid = state[0] if rule == "midpoint" else advance(q0, 0.5 * delta)
            _, A_mid, b_mid = rows.levels(q_mid, t + 0.5 * h)
            A_N, b_N = A_mid[N_rows], b_mid[N_rows]
            xi = delta / h
            c[N_rows] = A_N @ xi + b_N
            C[N_rows] = A_N / h
            # (the largest entry of a row times the largest velocity as well: a row that reads one coordinate,
            # such as a knife edge's sideways velocity in its body frame, is measured against the whole motion)
            magnitudes = np.abs(A_N)
            scales[N_rows] = np.maximum(np.maximum(magnitudes @ np.abs(xi), magnitudes.max(axis=1, initial=0.0) * _norm(xi)),
                                        np.maximum(np.abs(b_N), 1e-300))
        return c, C, scales, levels1, q1

    delta = np.array(guess, dtype=float)
    p0_size = _norm(p0)
    mu = np.zeros(m) if impulse_guess is None else np.array(impulse_guess, dtype=float)
    previous = np.inf
    J_inverse, fresh = None, False  # fresh: J_inverse is this step's analytical one (Broyden-updated since)
    delta_before = F_before = None  # the previous iterate and its −D1 L_d − f⁻ − p_k, for Broyden's update
    for iteration in range(1, max_iterations + 1):
        start, scale, state = evaluate(delta)
        if m:
            c, C, row_scales, levels1, q1 = constraint_terms(delta, state)
        residual = start - p0
        if m:
            impulse = B.T @ mu
            residual = residual - impulse
            scale = max(scale, _norm(impulse))
        scale = max(scale, p0_size, 1e-300)
        error = _norm(residual) / scale
        if m:
            row_error = _norm(c / row_scales)
            error = max(error, row_error)
        if not math.isfinite(error):
            raise _NotConverged(error, iteration, "the residual is not finite")
        if error <= tolerance:
            break
        F = start - p0
        if J_inverse is None or (error > 0.1 * previous and not fresh):
            J_inverse = linalg.solve(jacobian(delta, state), np.eye(nv))
            fresh = True
        elif delta_before is not None:
            # Broyden's update of J⁻¹ from the last step s and the change y of −D1 L_d − f⁻ (Dennis and
            # Schnabel, Numerical Methods for Unconstrained Optimization, 1983, Chapter 8, inverted by
            # Sherman–Morrison): it supplies the second derivatives the analytical J leaves out
            s_step, y = delta - delta_before, F - F_before
            Ji_y = J_inverse @ y
            denominator = s_step @ Ji_y
            if denominator != 0.0:
                J_inverse = J_inverse + np.outer(s_step - Ji_y, s_step @ J_inverse) / denominator
        previous, delta_before, F_before = error, delta, F
        if m:
            # J δ − Bᵀ μ_new = −(start − p_k),  C δ = −c:  the Schur complement gives μ_new (minimum norm
            # when rows are redundant), then δ.
            Ji_F = J_inverse @ F
            Ji_Bt = J_inverse @ B.T
            schur = C @ Ji_Bt
            mu = solve_rows(schur, C @ Ji_F - c)
            delta = delta - Ji_F + Ji_Bt @ mu
        else:
            delta = delta - J_inverse @ residual
    else:
        raise _NotConverged(error, max_iterations, None)

    # p_{k+1} = p_k + (D1 L_d + D2 L_d) + f⁻ + f⁺ + impulses: the momentum balance of the step, which keeps a
    # cyclic momentum exactly whatever the Newton residual left; on Lie-group joints
    # p_{k+1} = Ad_exp(Δ)ᵀ p_k + h Ad_exp(Δ/2)ᵀ (∂L/∂q(q̄, ξ) + τ̄) (midpoint), which keeps a momentum map
    if not m or q1 is None:  # (the holonomic rows' last evaluation placed it)
        q1 = advance(q0, delta)
    _, xi, M_state, pull, exponentials = state
    p_start = p0 + B.T @ mu if m else p0  # with the impulses A(q_k)ᵀ μ⁻ at the start
    if rule == "midpoint":
        M1 = lagrangian.mass_matrix(q1)
        if chart is None:
            p1 = p_start + h * pull  # D1 L_d + D2 L_d + f⁻ + f⁺ = h (∂L/∂q(q̄, ξ) + τ̄)
        else:
            p1 = exponentials[0][0].T @ p_start + h * (exponentials[1][0].T @ pull)
    else:
        M1 = M_state
        Lq1 = lagrangian.gradient(q1, xi)
        f1 = None if force is None else force(t + h, q1, xi)
        pull1 = Lq1 if f1 is None else Lq1 + f1
        # (h/2) (∂L/∂q(q_k, ξ) + ∂L/∂q(q_{k+1}, ξ) + τ_k + τ_{k+1}); on Lie-group joints
        # p_{k+1} = Ad_exp(Δ)ᵀ (p_k + (h/2) (∂L/∂q(q_k, ξ) + τ_k)) + (h/2) (∂L/∂q(q_{k+1}, ξ) + τ_{k+1})
        half_step = p_start + 0.5 * h * pull
        p1 = (half_step if chart is None else exponentials[0][0].T @ half_step) + 0.5 * h * pull1
    if not m:
        levels1, mu = None, np.zeros(0)
    elif levels1 is None:
        levels1 = rows.levels(q1, t + h)
    v1 = linalg.solve(M1, p1[:, None])[:, 0]
    mu_plus = np.zeros(m)
    if m:
        # p_{k+1} += A(q_{k+1})ᵀ μ⁺ with A v_{k+1} + b = 0 at t_{k+1}: the M-orthogonal projection of the
        # velocity (levels1: the rows at the converged q_{k+1}, from the last iteration)
        A1, b1 = levels1[1], levels1[2]
        M_inv_At = linalg.solve(M1, np.ascontiguousarray(A1.T))
        mu_plus = solve_rows(A1 @ M_inv_At, -(A1 @ v1 + b1))
        p1 = p1 + A1.T @ mu_plus
        v1 = v1 + M_inv_At @ mu_plus
    return q1, p1, v1, mu, mu_plus, levels1, delta


def _direct_solve(G, rhs):
    """``G⁻¹ rhs`` for the ``(m, m)`` matrix of independent rows."""
    return linalg.solve(G, rhs[:, None])[:, 0]


def _least_squares(G, rhs):
    """The minimum-norm least-squares ``G⁺ rhs`` for redundant rows (singular values below ``1e-10`` of
    the largest dropped)."""
    return np.linalg.lstsq(G, rhs, rcond=1e-10)[0]


class _NotConverged(Exception):
    def __init__(self, error, iterations, reason):
        super().__init__(reason or "")
        self.error, self.iterations, self.reason = error, iterations, reason


# ============================================================================= the compiled run

#: The argument types of :func:`multibody.kernels.variational.advance`: a compiled controller, the tree's arrays and
#: the constraint frames (read-only), the program, times, plan, control row, states, impulses, io and workspace.
ADVANCE_TYPES = (CONTROLLER_FUNCTION, driver.TREE_INTS, driver.TREE_FLOATS, driver.TREE_FLOATS, driver.VECTOR,
                 driver.VECTOR, driver.VECTOR, driver.VECTOR, driver.MATRIX, driver.MATRIX, driver.VECTOR, driver.VECTOR)
#: The compiled run's entry point, which ``multibody compile`` compiles beside the kernels.
ENTRY_POINTS = ((iteration_kernels.advance, ADVANCE_TYPES),)


class _CompiledSteps:
    """Every step of a run by :func:`multibody.kernels.variational.advance`, in calls of about
    :data:`multibody.runs.CHUNK_SECONDS` (:func:`multibody.runs.next_chunk`): a
    :class:`~multibody.model.Model` without constraints or with compiled rows fixed in time, and joint forces
    none, constant, :class:`~multibody.integrators.PD` or a ``numba.njit`` function (with the joints' damping)."""

    def __init__(self, model, constrained, tau, damping, rule, weights, tolerance, max_iterations, grouped, times):
        nq, nv, m = model.nq, model.nv, constrained.num_rows
        step, holonomic = constrained.compiled_step, constrained.position_rows.astype(float)
        self.model, self.times, self.m = model, np.ascontiguousarray(times, dtype=float), m
        self.program, self.frames = np.ascontiguousarray(step.program, dtype=float), step.frames
        # (the kind of controller, its control row and the compiled controller, as the compiled run of simulate)
        kind, control = control_rows(tau if tau is None or callable(tau) else np.asarray(tau, dtype=float), nv)
        self.control, self.pointer = control[0], controller_function(kind, tau)
        header = np.zeros(iteration_kernels.PLAN_HEADER)
        header[[iteration_kernels.PLAN_NQ, iteration_kernels.PLAN_NV, iteration_kernels.PLAN_M,
                iteration_kernels.PLAN_TRAPEZOIDAL, iteration_kernels.PLAN_GROUPED, iteration_kernels.PLAN_CHART,
                iteration_kernels.PLAN_CONTROL, iteration_kernels.PLAN_DAMPED, iteration_kernels.PLAN_TOLERANCE,
                iteration_kernels.PLAN_MAX_ITERATIONS, iteration_kernels.PLAN_RANK_TOLERANCE,
                iteration_kernels.PLAN_SUBSTEPS]] = (
            nq, nv, m, rule == "trapezoidal", grouped, not model.is_vector_space, kind, damping is not None, tolerance,
            max_iterations, constrained.rank_tolerance, len(weights))
        header[iteration_kernels.PLAN_WEIGHTS : iteration_kernels.PLAN_WEIGHTS + len(weights)] = weights
        self.plan = np.concatenate([header, holonomic, np.zeros(nv) if damping is None else damping])
        self.ws = np.empty(iteration_kernels.workspace_size(model.njoints, nq, nv, m, len(step.frames)))
        self.io = np.zeros(iteration_kernels.io_size(nv))

    @staticmethod
    def applies(lagrangian, constrained, tau):
        """Whether the compiled run takes the steps: a model's Lagrangian, no rows or only compiled ones, and
        joint forces that are data or compiled (a Python callable is called from the Python loop)."""
        return (isinstance(lagrangian, _ModelLagrangian)
                and constrained.compiled_step is not None
                and (tau is None or isinstance(tau, (PDController, CompiledController)) or not callable(tau)))

    def run(self, qs, vs, mu_start, mu_end, bar, mechanical):
        """All the steps, into ``qs (n, nq)``, ``vs (n, nv)`` (their first rows the initial state) and the impulses
        ``mu_start``, ``mu_end (n, m)``: ``(the states done, None)``, or the message of the failure that stopped
        the run at the first state not done."""
        n, nq, m, io = len(self.times), qs.shape[1], self.m, self.io
        states = np.zeros((n, nq + vs.shape[1]))
        states[0, :nq], states[0, nq:] = qs[0], vs[0]
        impulses = np.zeros((n, 2 * m))
        tree = self.model.tree
        with warnings.catch_warnings():
            # (Numba's note, when it compiles the run, that passing the controller on as a first-class function is
            # an experimental feature: the fixed-step run relies on it as well)
            warnings.simplefilter("ignore", numba_hooks.NumbaExperimentalFeatureWarning)
            entry = driver.entry_point(iteration_kernels.advance, ADVANCE_TYPES)
        k, status, chunk = 1, iteration_kernels.COMPLETED, FIRST_CHUNK
        # (calls of about CHUNK_SECONDS each: the bar moves, and an interrupt is answered, between them)
        while k < n and status == iteration_kernels.COMPLETED:
            io[iteration_kernels.IO_STEP], io[iteration_kernels.IO_STOP] = k, min(n, k + chunk)
            started = time.perf_counter()
            entry(self.pointer, tree.joints, tree.reals, self.frames, self.program, self.times, self.plan, self.control,
                  states, impulses, io, self.ws)
            chunk = next_chunk(chunk, time.perf_counter() - started)
            k, status = int(io[iteration_kernels.IO_STEP]), int(io[iteration_kernels.IO_STATUS])
            bar.update(self.times[k - 1])
        qs[:k], vs[:k] = states[:k, :nq], states[:k, nq:]
        mu_start[:k], mu_end[:k] = impulses[:k, :m], impulses[:k, m:]
        if status == iteration_kernels.COMPLETED:
            return n, None
        t, h = io[iteration_kernels.IO_TIME], io[iteration_kernels.IO_STEP_SIZE]
        error, iterations = io[iteration_kernels.IO_ERROR], int(io[iteration_kernels.IO_ITERATIONS])
        reasons = {
            iteration_kernels.NON_FINITE_RESIDUAL: "the residual is not finite",
            iteration_kernels.SINGULAR: "the Newton Jacobian or the constraints' Schur complement is singular",
            iteration_kernels.NOT_POSITIVE_DEFINITE: "the mass matrix is not positive definite",
            iteration_kernels.UNDEFINED_ROW: "a constraint row is undefined at the step's configuration",
        }
        if status == iteration_kernels.NOT_CONVERGED:
            message = _failure_message(_NotConverged(error, iterations, None), t, h, self.plan[
                iteration_kernels.PLAN_TOLERANCE])
        elif status == iteration_kernels.NON_FINITE_TORQUE:
            message = non_finite_torque(mechanical, t, io[iteration_kernels.IO_HEADER :].copy())
        elif status == iteration_kernels.NON_FINITE_STATE:
            message = f"the state became non-finite at t = {t:.6g} s"
        else:
            message = _failure_message(_NotConverged(error, iterations, reasons[status]), t, h, 0.0)
        return k, message


# ============================================================================= simulate

def simulate(system, q0, v0, t_final, *, dt=None, tau=None, rule="midpoint", order=2, t0=0.0, joint_damping=False,
             limits="warn", progress=None, tolerance=1e-12, max_iterations=25):
    """Integrate from ``(q0, v0)`` at ``t0`` to ``t_final`` with a variational integrator of step ``dt``.

    ``mb.simulate(system, q0, v0, t_final, method="variational", dt=h, ...)`` calls this function; the
    module docstring gives the equations.

    Args:
        system: a :class:`~multibody.model.Model` (any joints: free-flyer, spherical and planar joints
            by the Lie-group form of the module docstring), a :class:`ConstrainedSystem` on one, or a
            ``LagrangianSystem.numeric()`` system (with or without constraints).
        q0, v0: initial state ``(nq,)``, ``(nv,)``; an inconsistent one is projected onto the
            constraints with a warning, as ``mb.simulate`` does.
        t_final: end time (s).
        dt: the step ``h`` (s), also the output interval (every step is returned); the last step is
            shortened to end at ``t_final``. Default ``(t_final − t0) / 500``. With ``order=4`` one
            step is three sub-steps ``w₁ h, w₀ h, w₁ h``.
        tau: joint forces ``None``, ``(nv,)`` or ``tau(t, q, v) -> (nv,)`` (N, N·m), entering through
            the discrete Lagrange–d'Alembert principle (``f_k^±`` of the module docstring).
        rule: ``"midpoint"`` or ``"trapezoidal"`` quadrature of the action (both order 2).
        order: 2, or 4 by Yoshida's triple jump (systems without constraints).
        t0: start time (s).
        joint_damping, limits, progress: as :func:`multibody.simulate`.
        tolerance: Newton's tolerance, relative to the momentum terms of the discrete equations
            (``φ``: times ``max(1, |q|)``). A momentum that the discrete equations conserve (a cyclic
            coordinate's, a free system's spatial momentum) is kept to about this per step where the
            update does not carry it exactly (on free flyers): ``1e-14`` keeps it to 1e-12 over 10⁵ steps.
        max_iterations: Newton iterations allowed per step.

    Returns:
        :class:`~multibody.trajectory.Trajectory`: ``t (n,)``, ``q (n, nq)``, ``v = M(q)⁻¹ p (n, nv)``,
        ``lam (n, m)`` the discrete multipliers as forces (module docstring), ``energy`` ``T + U`` (J)
        at ``(q_k, v_k)``, ``residual`` ``max(|φ|, |A v + b|)``.

    Discrete energy and work. With the midpoint rule, ``M(q̄) ξ = (p_k + p_{k+1})/2`` and
    ``p_{k+1} − p_k = h (∂L/∂q(q̄, ξ) + τ̄)``. For a constant ``M`` (a pendulum, particles) that makes

        T_{k+1} − T_k + ∇U(q̄_k)·(q_{k+1} − q_k) = W_k,       W_k = τ̄_k·(q_{k+1} − q_k),

    exactly: the discrete energy ``E_k = T_k + U^d_k``, with ``U^d_{k+1} = U^d_k + ∇U(q̄_k)·(q_{k+1} − q_k)``
    the midpoint quadrature of the potential along the path (``|U^d_k − U(q_k)| = O(h²)``, ``U^d_0 =
    U(q_0)``), changes by exactly the discrete work ``W_k`` of the forces ``τ̄_k = τ(t_k + h/2, q̄_k, ξ_k)``
    (``W_k = (f_k⁻ + f_k⁺)·ξ_k``) up to the Newton tolerance.

    Raises:
        ValueError: a system with its own chart maps (not a Model), a system without ``∂L/∂q``,
            ``order=4`` with constraints, or invalid arguments (non-finite ``q0``, ``v0`` or array ``tau``
            among them, named by joint).
        SimulationError: a step whose Newton iteration did not converge (it names the time and the
            residual), joint forces ``tau(t, q, v)`` that are not finite (it names the time and the joints),
            or a state that is not; ``.trajectory`` holds the states before it.
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    if order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS} (4: Yoshida's composition of the order-2 step), got {order!r}")
    constrained = system if isinstance(system, ConstrainedSystem) else ConstrainedSystem(system)
    mechanical = constrained.system
    lagrangian = _lagrangian_of(mechanical)
    nq, nv, m = constrained.nq, constrained.nv, constrained.num_rows
    if order == 4 and m:
        raise ValueError("order=4 (Yoshida's composition) is for systems without constraints; "
                         f"this system has {m} constraint rows: use order=2")
    dt = checked_timing(t0, t_final, dt, progress, limits)
    if not 0.0 < tolerance < 1.0:
        raise ValueError(f"tolerance must be in (0, 1), got {tolerance}")
    model = getattr(mechanical, "model", None)
    damping = joint_damping_of(mechanical, joint_damping)
    # (checks an array tau: its shape, and that it is finite)
    force = _total_force(tau, nv, lagrangian, functools.partial(torque_function, system=mechanical))
    compiled = _CompiledSteps.applies(lagrangian, constrained, tau)
    if damping is not None:
        force = _total_force(with_joint_damping(torque_function(tau, nv, system=mechanical), damping), nv, lagrangian,
                             functools.partial(torque_function, system=mechanical))

    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    chart = lagrangian.chart
    if q.shape != (nq,) or v.shape != (nv,):
        raise ValueError(f"q0 and v0 must have shapes ({nq},) and ({nv},), got {q.shape} and {v.shape} "
                         "(method='variational' integrates one state at a time)")
    require_finite(mechanical, "q0", q)
    require_finite(mechanical, "v0", v, rate=True)
    if m:
        q, v, _ = projected_start(constrained, q, v, t0, stacklevel=4)

    times = output_times(t0, t_final, dt)
    qs, vs = np.empty((len(times), nq)), np.empty((len(times), nv))
    mu_start, mu_end = np.zeros((len(times), m)), np.zeros((len(times), m))  # impulses at each node
    qs[0], vs[0] = q, v
    rows = _Rows(constrained) if m else None
    # free flyers step on SO(3) × R³, in their group velocities w = T(q)ᵀ v (_GroupLagrangian)
    aligned = chart is not None and chart.alignment(q) is not None
    if aligned:
        lagrangian, force = _GroupLagrangian(lagrangian), _group_force(force, chart)
        rows = None if rows is None else _GroupRows(constrained, chart)
        v = chart.alignment(q).T @ v
    weights = (YOSHIDA_W1, YOSHIDA_W0, YOSHIDA_W1) if order == 4 else (1.0,)
    done = 1
    bar = Progress(progress, t0, t_final)
    try:
        if compiled:
            steps = _CompiledSteps(model, constrained, tau, damping, rule, weights, tolerance, max_iterations, aligned,
                                   times)
            done, failure = steps.run(qs, vs, mu_start, mu_end, bar, mechanical)
            if failure is not None:
                raise SimulationError(failure, None)
        else:
            levels = rows.levels(q, t0) if m else None
            p = lagrangian.mass_matrix(q) @ v
            last_velocity, last_h, last_impulse = v, None, None
            increments = []  # the last three steps' (h, Δ), newest first
            for k in range(1, len(times)):
                step = times[k] - times[k - 1]
                t = times[k - 1]
                for weight in weights:
                    h = weight * step
                    guess = _predict(h, v, last_velocity, last_h, increments)
                    # the constraint impulses change little from step to step: the last one, per unit time
                    impulse_guess = None if last_impulse is None else last_impulse * (h / last_h)
                    try:
                        q, p, v_new, start, end, levels, delta = _step(
                            lagrangian, rows, rule, force, t, h, q, p, levels, guess, tolerance, max_iterations,
                            impulse_guess)
                    except _NotConverged as failure:
                        raise SimulationError(_failure_message(failure, t, h, tolerance), None) from None
                    except (np.linalg.LinAlgError, ConstraintError, FloatingPointError) as error:
                        raise SimulationError(f"variational step failed at t = {t:.6g} s (h = {h:.3g} s): {error}",
                                              None) from error
                    last_velocity, last_h, v, last_impulse = v, h, v_new, (start if m else None)
                    increments = [(h, delta)] + increments[:2]
                    t = t + h
                if m:
                    mu_start[k - 1] += start
                    mu_end[k] = end
                qs[k], vs[k] = q, (chart.alignment(q) @ v if aligned else v)
                # (a step's equations can hold with v = M⁻¹ p overflowing: such a state is not kept)
                if not (all_finite(qs[k]) and all_finite(vs[k])):
                    raise SimulationError(f"the state became non-finite at t = {times[k]:.6g} s", None)
                done = k + 1
                bar.update(times[k])
    except SimulationError as error:
        message = f"simulation stopped at t = {times[done - 1]:.6g} s: {error}"
        partial = _trajectory(constrained, times[:done], qs[:done], vs[:done], mu_start[:done], mu_end[:done], message)
        raise SimulationError(message, partial) from None
    finally:
        bar.close()
    trajectory = _trajectory(constrained, times, qs, vs, mu_start, mu_end, "completed")
    if model is not None and limits != "ignore":
        report_limits(mechanical, trajectory, limits)
    return trajectory


def _total_force(tau, nv, lagrangian, torque_function):
    """``force(t, q, v) -> (nv,)``: the joint forces ``τ`` plus the system's own forces ``Q`` (symbolic
    forces without a potential), or ``None`` when both are absent."""
    torque = None if tau is None else torque_function(tau, nv)
    has_forces = isinstance(lagrangian, _SystemLagrangian) and lagrangian.has_forces
    if torque is None and not has_forces:
        return None

    def force(t, q, v):
        total = np.zeros(nv)
        if torque is not None:
            applied = torque(t, q, v)
            if applied is not None:
                total = total + np.asarray(applied, dtype=float).reshape(nv)
        if has_forces:
            total = total + np.asarray(lagrangian.system.generalized_forces(q, v), dtype=float).reshape(nv)
        return total

    return force


def _predict(h, v, v_before, h_before, increments=()):
    """Predicted increment ``Δ (nv,)`` of a step of size ``h`` from the node velocity ``v``.

    After three steps of this size (``increments``: the last steps' ``(h, Δ)``, newest first), the
    quadratic extrapolation ``Δ_k ≈ 3 Δ_{k−1} − 3 Δ_{k−2} + Δ_{k−3}``: the increments sample one smooth
    function of time (``h`` times the discrete velocity at each step's midpoint), so this is within
    ``O(h⁴)`` of the solution, and the first Newton step of a smooth motion usually meets the tolerance.
    Otherwise ``Δ ≈ h v + h²/2 a`` with ``a`` the last step's ``(v − v_before)/h_before``: within
    ``O(h³)``. (Mixing the node velocity with the increments would not do better: they sample two
    functions that differ by ``O(h²)``.)"""
    if len(increments) == 3 and all(abs(h_k - h) <= 1e-9 * abs(h) for h_k, _ in increments):
        (_, newest), (_, middle), (_, oldest) = increments
        return 3.0 * (newest - middle) + oldest
    if h_before is None:
        return h * v
    return h * v + 0.5 * h * h * (v - v_before) / h_before


def _failure_message(failure, t, h, tolerance):
    if failure.reason:
        return f"variational step at t = {t:.6g} s (h = {h:.3g} s) failed: {failure.reason}"
    return (f"Newton's method of the variational step at t = {t:.6g} s (h = {h:.3g} s) did not converge: relative "
            f"residual {failure.error:.3g} > tolerance {tolerance:.3g} after {failure.iterations} iterations; take a "
            "smaller step dt")


def _trajectory(constrained, times, q, v, mu_start, mu_end, status):
    """The :class:`~multibody.trajectory.Trajectory` of the states, with the node impulses turned into
    forces ``λ_k = 2 (μ_k⁺ + μ_k⁻) / (h_{k−1} + h_k)`` (extrapolated from the two nearest inner nodes at
    the two ends)."""
    from .trajectory import Trajectory, recorded_names

    n, m = len(times), constrained.num_rows
    steps = np.diff(times)
    # the time each node's impulse stands for: half of each adjacent step
    span = np.zeros(n)
    span[:-1] += 0.5 * steps
    span[1:] += 0.5 * steps
    span = np.where(span > 0.0, span, np.inf)
    lam = (mu_start + mu_end) / span[:, None] if m else np.zeros((n, 0))
    if m and n >= 4:
        # An end node meets one step only, and its one-sided impulse is a first-order approximation of the
        # force there; the two ends are extrapolated linearly from their two nearest inner nodes instead,
        # whose two-sided averages are second order.
        for node, (a, b) in ((0, (1, 2)), (n - 1, (n - 2, n - 3))):
            weight = (times[node] - times[a]) / (times[b] - times[a])
            lam[node] = lam[a] + weight * (lam[b] - lam[a])
    if constrained.batched and n:
        energy = np.broadcast_to(constrained.energy(q, v), (n,)).astype(float)
        residual = constrained.residual(q, v, times) if m else np.zeros(n)
    else:
        energy = np.array([constrained.energy(q_k, v_k) for q_k, v_k in zip(q, v)], dtype=float).reshape(n)
        residual = (np.array([constrained.residual(q_k, v_k, t) for q_k, v_k, t in zip(q, v, times)], dtype=float)
                    if m else np.zeros(n))
    return Trajectory(t=np.array(times, dtype=float), q=q.copy(), v=v.copy(), lam=np.asarray(lam, dtype=float),
                      energy=energy, residual=np.asarray(residual, dtype=float).reshape(n),
                      row_names=list(constrained.row_names), status=status, projection_tolerance=None,
                      joint_names=recorded_names(constrained))
