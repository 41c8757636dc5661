"""First-order dynamics about a state, restricted to the constraints, in minimal coordinates.

A perturbed state is ``q ⊕ δq``, ``v + δv`` with ``δq, δv`` of size ``nv`` (the tangent space, as the
derivatives of :mod:`multibody.derivatives` take it: ``q ⊕ δq = q exp(δq)`` with the joints' body-frame
velocities). The constraints, position rows ``φ(q, t) = 0`` with Jacobian ``A_h (m_h, nv)`` and velocity
rows ``A(q, t) v + b(q, t) = 0`` (all ``m`` rows: the holonomic ones at velocity level and the
nonholonomic ones), hold to first order when

    A_h δq = 0,        A δv + C δq = 0,        C = ∂(A v + b)/∂q (m, nv).

Minimal coordinates parameterise exactly these perturbations. With orthonormal bases

    P = null(A_h) (nv, p),        V = null(A) (nv, k),        W = Pᵀ V (p, k),

where ``V`` lies inside ``span P`` because ``A`` holds the rows of ``A_h`` (``V = P W``; ``V = P`` when every
independent row has a position level; :func:`aligned_null_space` picks each basis),

    δq = P s,        δv = V u + D s,        D = −A⁺ C P (nv, p),                                     (1)

``D s`` the minimum-norm velocity that the rows ask for when the configuration moves (zero at rest
under rows that do not move in time; on a steady motion, moving the configuration changes the rates the
constraints allow). ``s`` has ``p = nv − rank A_h`` entries, ``u`` has ``k = nv − rank A``; ``k < p`` when
nonholonomic rows restrict velocities but not positions.

The linearized motion in the tangent space is (the configuration moving as ``q̇ = q v``; with
``q_ε = q exp(ε δq)``, ``d/dt q_ε = q_ε (v + ε δv)`` gives ``exp(ε δq)˙ = exp(ε δq)(v + ε δv) − v exp(ε δq)``,
whose first order in ε is)

    δq̇ = δv − ad_v δq,        δv̇ = ∂a/∂q δq + ∂a/∂v δv + ∂a/∂τ δτ,                                (2)

where ``ad_v`` is the Lie bracket ``[v, ·]`` of the joints' velocity groups (:func:`lie_bracket`: ``ω×`` for
a spherical joint, ``[[ω×, v×], [0, ω×]]`` for a free flyer on SE(3), zero for angles and displacements;
Solà, Deray and Atchuthan, *A micro Lie theory for state estimation in robotics*, 2018) and ``∂a`` are the
derivatives of the constrained accelerations (:meth:`multibody.ConstrainedSystem.forward_dynamics_derivatives`,
or :func:`multibody.forward_dynamics_derivatives` for a model). Projecting (2) on the coordinates (1), with
the bases held at the state (``P⁺ = Pᵀ``, ``V⁺ = Vᵀ``):

    ṡ = Pᵀ (δv − ad_v P s) = Pᵀ (D − ad_v P) s + W u,
    u̇ = Vᵀ (δv̇ − D ṡ) = Vᵀ (∂a/∂q P + ∂a/∂v D) s + Vᵀ ∂a/∂v V u + Vᵀ ∂a/∂τ δτ,                  (3)

where ``Vᵀ D = 0`` (the columns of ``A⁺`` lie in the row space of ``A``) removes ``D ṡ``. This is the
null-space (minimal-coordinate) method of constrained dynamics (Laulusa and Bauchau, *Review of classical
approaches for constraint enforcement in multibody systems*, J. Comput. Nonlinear Dynam. 3, 2008, §4),
applied to the variational equations.

One step of a fixed-step method, ``(q, v) ↦ (q⁺, v⁺)`` with derivatives ``∂(δq⁺, δv⁺)/∂(δq, δv, δτ)``
(:func:`multibody.rk4_step_derivatives`, ``δq⁺`` in the tangent space at ``q⁺``), maps the coordinates (1) the
same way: ``s⁺ = Pᵀ δq⁺``, ``u⁺ = Vᵀ (δv⁺ − D s⁺) = Vᵀ δv⁺``, with the bases of the step's start.

The bases are those at the state: ``A`` gives the rates of the coordinates of a perturbation measured in
them. Along an equilibrium, or a steady motion whose rows do not change in the velocity coordinates (the
Chaplygin sleigh gliding straight, in its body frame), the bases stay the same and the eigenvalues of ``A``
decide the motion's linear stability; where the rows turn with the motion (a coin whose contact point runs
round its rim in the body frame), ``A`` is the instantaneous rate only.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from . import derivatives, driver
from .kernels import configuration
from .mechanical import ModelSystem, system_parts
from .shooting import rk4_step_derivatives

#: Largest constraint violation ``max(|φ|, |A v + b|)`` (m, rad; m/s, rad/s) of a state to linearize about:
#: the projection (:meth:`multibody.ConstrainedSystem.project`) brings states within ``1e-12``.
CONSISTENCY_TOLERANCE = 1e-8

#: The fixed-step methods whose one step :func:`linearize` differentiates (``dt=``).
STEP_METHODS = ("RK4",)


@dataclass(frozen=True, eq=False)
class Linearization:
    """The first-order dynamics about a state in minimal coordinates ``x = [s; u]`` (:func:`linearize`).

    A perturbed state is ``q ⊕ δq``, ``v + δv`` with ``δq = position_basis s`` and
    ``δv = velocity_basis u + dependent_rates s``; the perturbation evolves as ``dx/dt = A x + B δτ``
    (``dt`` ``None``), or over one step of ``dt`` seconds as ``x⁺ = A x + B δτ``. A batch of states gives
    every array leading axes ``(...)``.

    Attributes:
        A: ``(..., p + k, p + k)``: ``d[s; u]/dt`` per unit of ``[s; u]`` (``s`` in the units of ``δq``, m and
            rad; ``u`` in those of ``δv``, m/s and rad/s), or the step's map ``[s; u]⁺`` per unit of ``[s; u]``.
        B: ``(..., p + k, nv)``: the same per unit of joint force ``δτ`` (N, N·m).
        position_basis: ``P (..., nv, p)``, orthonormal: tangent directions of the holonomic constraint
            manifold (the null space of the position rows' Jacobian).
        velocity_basis: ``V (..., nv, k)``, orthonormal: the velocities every row admits (the null space of
            the velocity rows, holonomic and nonholonomic), inside the span of ``P``.
        dependent_rates: ``D (..., nv, p)``: the velocity change that the rows require per unit of ``s``
            (minimum norm, orthogonal to ``V``); zero at rest under rows fixed in time.
        p, k: the numbers of position and velocity coordinates (``k ≤ p ≤ nv``).
        q, v, tau: the state ``(..., nq)``, ``(..., nv)`` and joint forces ``(..., nv)`` it was taken at;
        t: the time (s).
        dt: the step (s) of a discrete linearization; ``None`` for the continuous one.
        method: the integration method of a discrete linearization; ``None`` for the continuous one.
    """

    A: np.ndarray
    B: np.ndarray
    position_basis: np.ndarray
    velocity_basis: np.ndarray
    dependent_rates: np.ndarray
    p: int
    k: int
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    t: float = 0.0
    dt: float | None = None
    method: str | None = None

    def perturbation(self, x):
        """``(δq (..., nv), δv (..., nv))`` of minimal coordinates ``x = [s; u] (..., p + k)``, by (1) of
        :mod:`multibody.linearization`: ``δq = P s``, ``δv = V u + D s``."""
        x = np.asarray(x, dtype=float)
        if x.shape[-1:] != (self.p + self.k,):
            raise ValueError(f"x must have shape (..., {self.p + self.k}) (p + k), got {x.shape}")
        s, u = x[..., : self.p, None], x[..., self.p :, None]
        return (self.position_basis @ s)[..., 0], (self.velocity_basis @ u + self.dependent_rates @ s)[..., 0]

    def coordinates(self, dq, dv):
        """Minimal coordinates ``[s; u] (..., p + k)`` of a perturbation ``δq, δv (..., nv)`` (tangent space;
        ``δq = model.difference(q, q')`` for a nearby configuration ``q'``): ``s = Pᵀ δq``,
        ``u = Vᵀ (δv − D s)``, the inverse of :meth:`perturbation` on admissible perturbations and their
        least-squares coordinates otherwise."""
        dq, dv = np.asarray(dq, dtype=float), np.asarray(dv, dtype=float)
        nv = self.position_basis.shape[-2]
        for name, value in (("dq", dq), ("dv", dv)):
            if value.shape[-1:] != (nv,):
                raise ValueError(f"{name} must have shape (..., {nv}), got {value.shape}")
        s = (np.swapaxes(self.position_basis, -1, -2) @ dq[..., None])[..., 0]
        u = (np.swapaxes(self.velocity_basis, -1, -2) @ (dv[..., None] - self.dependent_rates @ s[..., None]))[..., 0]
        # (u depends on s, so its leading axes hold those of s)
        return np.concatenate([np.broadcast_to(s, u.shape[:-1] + s.shape[-1:]), u], axis=-1)


def lie_bracket(model, v):
    """``ad_v (..., nv, nv)``: the Lie bracket ``[v, ·]`` of the joints' velocity groups, in which the
    tangent-space perturbation of a moving configuration turns, ``δq̇ = δv − ad_v δq`` (:mod:`module docstring
    <multibody.linearization>`, eq. 2). SO(3) for a spherical joint (``ω×``), SE(3) for a free flyer
    (``[[ω×, v×], [0, ω×]]`` on ``[v_lin, ω]``), SE(2) for a planar joint (``[[0, −ω, v_y], [ω, 0, −v_x], [0, 0,
    0]]``), zero for angles and displacements. Row ``i`` is ``ad_vᵀ e_i``, from the compiled coadjoint map
    (:func:`multibody.kernels.configuration.coadjoint`). ``v (..., nv)`` (m/s, rad/s) -> 1/s."""
    v = model.check_velocity(v)
    nv = model.nv
    rows = driver.evaluate(configuration.coadjoint, model.tree, (v[..., None, :], np.eye(nv)), (1, nv),
                           v.shape[:-1] + (nv,))
    return rows[..., 0, :]


def linearize(system, q, v, tau=None, t=0.0, *, dt=None, method="RK4"):
    """The first-order dynamics about ``(q, v, τ)`` restricted to the constraints, in minimal coordinates:
    a :class:`Linearization` with ``A (p + k, p + k)``, ``B (p + k, nv)``, ``position_basis (nv, p)``,
    ``velocity_basis (nv, k)`` and ``dependent_rates (nv, p)``, such that ``δq = position_basis s``,
    ``δv = velocity_basis u + dependent_rates s`` and ``d[s; u]/dt = A [s; u] + B δτ``. The derivation, eqs.
    (1)–(3), is in the docstring of :mod:`multibody.linearization`. Without constraints ``p = k = nv``, both
    bases are the identity and ``A = [[−ad_v, I], [∂a/∂q, ∂a/∂v]]``, ``B = [[0], [M⁻¹]]``.

    Analytic: ``∂a`` from the constrained dynamics' derivatives (analytical for a :class:`Model`; their
    constraint terms and ``C = ∂(A v + b)/∂q``, :meth:`ConstrainedSystem.velocity_error_derivative`, by
    five-point differences of the rows, about ``1e-11`` relative). Ranks are decided as
    :meth:`ConstrainedSystem.rank` decides them.

    With ``dt`` (s): the map of one step of ``method`` (:data:`STEP_METHODS`; the step
    :func:`multibody.simulate` takes, before its projection onto the constraints, with ``τ`` held over the
    step) in the same coordinates, ``[s; u]⁺ = A [s; u] + B δτ``, from :func:`multibody.rk4_step_derivatives`.

    Args:
        system: a :class:`Model` or a :class:`ConstrainedSystem`.
        q: ``(..., nq)``; with ``v (..., nv)`` a state on the constraints (within
            :data:`CONSISTENCY_TOLERANCE`; :meth:`ConstrainedSystem.project` gives one).
        v: ``(..., nv)`` (m/s, rad/s).
        tau: joint forces ``(..., nv)`` (N, N·m), or ``None`` (zero).
        t: time (s).
        dt: ``None`` (continuous), or the step (s) of a discrete linearization.
        method: the discrete linearization's method (``"RK4"``).

    Leading axes of ``q``, ``v``, ``tau`` broadcast to a batch; every state of it must have the same ``p``
    and ``k`` (``ValueError`` naming the states otherwise).
    """
    constrained, mechanical, model = _parts(system)
    q, v, tau, batch = _state(mechanical, model, q, v, tau)
    if dt is not None:
        if method not in STEP_METHODS:
            raise ValueError(f"method must be one of {STEP_METHODS} for a discrete linearization, got {method!r}")
        if not isinstance(dt, (int, float, np.floating, np.integer)) or not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        dt = float(dt)
    t = float(t)
    if batch and constrained is not None and not constrained.batched:
        # a system that takes one state at a time: each state alone, stacked
        parts = [_linearize_one(system, constrained, mechanical, model, q[i], v[i], tau[i], t, dt, method)
                 for i in np.ndindex(batch)]
        _require_same_dimensions(batch, [(part.p, part.k) for part in parts])
        stacked = {name: np.stack([getattr(part, name) for part in parts]).reshape(batch + getattr(parts[0], name).shape)
                   for name in ("A", "B", "position_basis", "velocity_basis", "dependent_rates")}
        return Linearization(**stacked, p=parts[0].p, k=parts[0].k, q=q, v=v, tau=tau, t=t, dt=dt,
                             method=None if dt is None else method)
    return _linearize_one(system, constrained, mechanical, model, q, v, tau, t, dt, method)


def _parts(system):
    """``(constrained system or None, mechanical system, Model or None)`` of a :class:`Model` or a
    :class:`ConstrainedSystem`."""
    constrained, mechanical, model = system_parts(system)
    if (not isinstance(mechanical, ModelSystem) and hasattr(mechanical, "chart")
            and not getattr(mechanical, "vector_space", False)):
        raise TypeError(f"linearize needs the Lie bracket of a curved configuration space, which only a Model "
                        f"provides; {type(mechanical).__name__} has charts (its q is not a vector space)")
    return constrained, mechanical, model


def _state(mechanical, model, q, v, tau):
    """``q (..., nq)``, ``v``, ``tau (..., nv)`` as finite float arrays broadcast to one batch shape, and that
    shape; ``ValueError`` naming the argument otherwise. A :class:`Model` checks them as its own functions do
    (real numbers, unit quaternions)."""
    nq, nv = mechanical.nq, mechanical.nv
    arrays = {}
    for name, value, size in (("q", q, nq), ("v", v, nv), ("tau", np.zeros(nv) if tau is None else tau, nv)):
        if model is not None:
            with warnings.catch_warnings():
                # (the model warns of non-finite entries; they are refused below, by name)
                warnings.simplefilter("ignore", RuntimeWarning)
                value = model.check_configuration(value) if name == "q" else model.check_velocity(value, name)
        else:
            try:
                value = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be real numbers, got {value!r}") from None
            if value.ndim == 0 or value.shape[-1] != size:
                raise ValueError(f"{name} must have shape (..., {size}), got {value.shape}")
        bad = np.argwhere(~np.isfinite(value))
        if len(bad):
            entries = ", ".join(f"{name}[{', '.join(map(str, index))}] = {value[tuple(index)]}" for index in bad[:5])
            raise ValueError(f"{name} must be finite: {entries}{' …' if len(bad) > 5 else ''}")
        arrays[name] = value
    try:
        batch = np.broadcast_shapes(*(value.shape[:-1] for value in arrays.values()))
    except ValueError:
        raise ValueError(f"the leading axes of q {arrays['q'].shape}, v {arrays['v'].shape} and tau "
                         f"{arrays['tau'].shape} do not broadcast to one batch") from None
    # (copies: the result keeps them, whatever the caller does to its arrays afterwards)
    q, v, tau = (np.array(np.broadcast_to(value, batch + value.shape[-1:])) for value in arrays.values())
    return q, v, tau, batch


def _require_same_dimensions(batch, dimensions):
    """``ValueError`` naming the states of a batch whose ``(p, k)`` differ from the first state's."""
    groups = {}
    for index, pair in zip(np.ndindex(batch), dimensions):
        groups.setdefault(pair, []).append(index if len(batch) != 1 else index[0])
    if len(groups) > 1:
        parts = [f"p = {p}, k = {k} at state{'s' if len(states) > 1 else ''} "
                 f"{', '.join(map(str, states[:5]))}{' …' if len(states) > 5 else ''}"
                 for (p, k), states in groups.items()]
        raise ValueError(f"the constraint rows' rank changes across the batch ({'; '.join(parts)}): the minimal "
                         "coordinates differ in number, so the states cannot share one array; linearize them "
                         "separately")


def aligned_null_space(A, rank):
    """Orthonormal basis ``(..., n, n − rank)`` of the null space of ``A (..., m, n)`` of rank ``rank``, its
    vectors following the coordinate axes that the rows leave free.

    The null space is spanned by the right singular vectors beyond the ``rank`` largest singular values,
    an arbitrary rotation of it; its projector ``Π = N Nᵀ`` does not depend on that rotation. Column-pivoted
    QR of ``Π`` (Golub and Van Loan, *Matrix Computations*, 4th ed., §5.4.2) takes the coordinate axes in the
    order of their projections' lengths and orthonormalizes them, ``Π E = Q R``: the first ``n − rank``
    columns of ``Q``, each turned to point along its axis (``R_jj > 0``). The axes come first that the rows
    restrict least, as coordinate partitioning picks independent coordinates (Wehage and Haug, *J. Mech.
    Des.* 104, 1982): the sleigh's velocity basis is its forward speed and its turn (with the sideways
    velocity the blade makes it), not a mixture of them.
    """
    n = A.shape[-1]
    N = np.swapaxes(np.linalg.svd(A, full_matrices=True)[2][..., rank:, :], -1, -2)
    if rank == 0:
        return np.broadcast_to(np.eye(n), A.shape[:-2] + (n, n)).copy()
    projector = N @ np.swapaxes(N, -1, -2)
    basis = np.empty(N.shape)
    for index in np.ndindex(A.shape[:-2]):
        Q, R, _ = scipy.linalg.qr(projector[index], pivoting=True)
        basis[index] = Q[:, : n - rank] * np.where(np.diag(R)[: n - rank] < 0, -1.0, 1.0)
    return basis


def _bases(constrained, q, v, t, batch, nv):
    """``(P, V, D, p, k)`` of (1) at the states ``q``, ``v``."""
    identity = np.broadcast_to(np.eye(nv), batch + (nv, nv))
    if constrained is None or not constrained.num_rows:
        return identity, identity, np.zeros(batch + (nv, nv)), nv, nv
    residual = np.asarray(constrained.residual(q, v, t))
    if not (residual <= CONSISTENCY_TOLERANCE).all():
        if batch:
            off = [index if len(batch) > 1 else index[0] for index in zip(*np.nonzero(~(residual <= CONSISTENCY_TOLERANCE)))]
            where = (f" at state{'s' if len(off) > 1 else ''} {', '.join(map(str, off[:5]))}{' …' if len(off) > 5 else ''}"
                     f" (largest {np.nanmax(residual):.3g})")
        else:
            where = f" by {float(residual):.3g}"
        raise ValueError(f"the state is off the constraints{where}, the largest |φ| or |A v + b|, more than "
                         f"{CONSISTENCY_TOLERANCE:g}: linearize about a consistent state (system.project(q, v))")
    holonomic = constrained.position_rows
    rank, position_rank = (np.asarray(constrained.rank(q, t, rows=rows)) for rows in (None, holonomic))
    dimensions = np.broadcast_to(nv - position_rank, batch), np.broadcast_to(nv - rank, batch)
    _require_same_dimensions(batch, zip(dimensions[0].ravel().tolist(), dimensions[1].ravel().tolist()))
    rank, position_rank = int(rank.ravel()[0]), int(position_rank.ravel()[0])
    A = constrained.jacobian(q, t)
    # P = null(A_h); V = null(A), inside span P since A holds the rows of A_h; V = P when every independent
    # row has a position level
    P = aligned_null_space(A[..., holonomic, :], position_rank)
    V = aligned_null_space(A, rank) if rank > position_rank else P
    p, k = nv - position_rank, nv - rank
    # D = −A⁺ C P with A⁺ = W_r Σ_r⁻¹ U_rᵀ over the rank kept: the minimum-norm solution of A δv = −C P s
    U, sigma, Wh = np.linalg.svd(A, full_matrices=False)
    pseudo_inverse = np.swapaxes(Wh[..., :rank, :], -1, -2) / sigma[..., None, :rank] @ np.swapaxes(U[..., :, :rank], -1, -2)
    D = -pseudo_inverse @ constrained.velocity_error_derivative(q, v, t) @ P
    return P, V, D, p, k


def _linearize_one(system, constrained, mechanical, model, q, v, tau, t, dt, method):
    """:func:`linearize` of one state, or of a batch that ``system`` takes in one call."""
    batch, nv = q.shape[:-1], mechanical.nv
    P, V, D, p, k = _bases(constrained, q, v, t, batch, nv)
    if dt is None:
        # (2): δq̇ = δv − ad_v δq,  δv̇ = ∂a/∂q δq + ∂a/∂v δv + ∂a/∂τ δτ
        if constrained is not None:
            d = constrained.forward_dynamics_derivatives(q, v, tau, t)
            da_dq, da_dv, da_dtau = d.da_dq, d.da_dv, d.da_dtau
        else:
            da_dq, da_dv, da_dtau = derivatives.forward_dynamics_derivatives(model, q, v, tau)
        curved = isinstance(mechanical, ModelSystem) and not mechanical.vector_space
        dq_dq = -lie_bracket(model, v) if curved else np.zeros(batch + (nv, nv))
        dq_dv = np.broadcast_to(np.eye(nv), batch + (nv, nv))
        dq_dtau = np.zeros(batch + (nv, nv))
        dv_dq, dv_dv, dv_dtau = da_dq, da_dv, da_dtau
    else:
        _, d = rk4_step_derivatives(system, q, v, tau, dt, t)
        dq_dq, dq_dv, dq_dtau, dv_dq, dv_dv, dv_dtau = d.dq_dq, d.dq_dv, d.dq_dtau, d.dv_dq, d.dv_dv, d.dv_dtau
    P_T, V_T = np.swapaxes(P, -1, -2), np.swapaxes(V, -1, -2)
    # (3), and the step's map alike: s⁺ = Pᵀ δq⁺ and u⁺ = Vᵀ δv⁺ (Vᵀ D = 0) for δq = P s, δv = V u + D s
    A = np.concatenate([
        np.concatenate([P_T @ (dq_dq @ P + dq_dv @ D), P_T @ dq_dv @ V], axis=-1),
        np.concatenate([V_T @ (dv_dq @ P + dv_dv @ D), V_T @ dv_dv @ V], axis=-1)], axis=-2)
    B = np.concatenate([P_T @ dq_dtau, V_T @ dv_dtau], axis=-2)
    return Linearization(A, B, np.array(P), np.array(V), D, p, k, q, v, tau, t, dt, None if dt is None else method)
