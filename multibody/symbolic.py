"""The textbook front-end: Lagrangians in generalized coordinates with SymPy, then numbers.

Following the lecture note: pick generalized coordinates ``q_k(t)``, write ``T`` and ``U``, and let
Hamilton's principle ``δ∫(T − U) dt = 0`` give Lagrange's equations

    d/dt ∂L/∂q̇_k − ∂L/∂q_k = Q_k,        L = T − U,

with generalized forces ``Q_k = Σ F·∂x/∂q_k`` for the forces that have no potential. A coordinate
absent from ``L`` is cyclic, and its momentum ``p_k = ∂L/∂q̇_k`` is conserved. The Legendre transform
``H(q, p) = Σ p_k q̇_k − L`` gives Hamilton's equations ``q̇ = ∂H/∂p``, ``ṗ = −∂H/∂q + Q``.

:meth:`LagrangianSystem.numeric` turns the equations into a NumPy system that
:class:`~multibody.constrained.ConstrainedSystem` and :func:`~multibody.simulation.simulate` accept.
See ``docs/theory.md`` for the derivation, step by step. Needs SymPy, the ``[symbolic]`` extra.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

INSTALL_HINT = ('the symbolic front-end (mb.LagrangianSystem, mb.generalized_forces) needs SymPy: '
                'pip install -e ".[symbolic]" from the multibody checkout, or pip install sympy')

try:
    import sympy as sp
    from sympy.core.function import AppliedUndef
    from sympy.physics.mechanics import dynamicsymbols
except ImportError as error:
    raise ImportError(INSTALL_HINT) from error

from .constraints import Holonomic, Pfaffian

_t = dynamicsymbols._t


def generalized_forces(q, points, forces):
    """``Q_k = Σᵢ Fᵢ · ∂xᵢ/∂q_k``: the lecture note's generalized forces from Cartesian ones.

    Args:
        q: the generalized coordinates (functions of time).
        points: positions ``xᵢ(q)`` of the points the forces act on, each a 3-sequence (or
            ``sympy.Matrix``) of expressions.
        forces: the forces ``Fᵢ`` on those points, each a 3-sequence of expressions (they may
            depend on ``q``, ``q̇`` and time: applied or dissipative forces alike).
    Returns:
        list of ``Q_k``, one per coordinate.
    """
    if len(points) != len(forces):
        raise ValueError(f"got {len(points)} points but {len(forces)} forces")
    out = []
    for q_k in q:
        # δW = Σ F·δx = Σ_k Q_k δq_k
        out.append(sp.simplify(sum((sp.Matrix(F).T * sp.Matrix(x).diff(q_k))[0, 0] for x, F in zip(points, forces))))
    return out


class LagrangianSystem:
    """A mechanical system given by its Lagrangian in generalized coordinates.

    Args:
        q: list of generalized coordinates, functions of time
            (``sympy.physics.mechanics.dynamicsymbols``).
        T: kinetic energy, an expression in ``q``, ``q̇`` and parameters, quadratic in ``q̇``.
        U: potential energy, an expression in ``q`` and parameters.
        forces: generalized forces ``Q_k`` (one expression per coordinate) of the forces without a
            potential (see :func:`generalized_forces`), or ``None``.
    """

    def __init__(self, q, T, U=0, forces=None):
        self.q = list(q)
        if not self.q:
            raise ValueError("LagrangianSystem needs at least one generalized coordinate")
        for q_k in self.q:
            if not (isinstance(q_k, AppliedUndef) and q_k.args == (_t,)):
                raise ValueError(f"generalized coordinate {q_k!r} is not a function of time t: "
                                 "make it with sympy.physics.mechanics.dynamicsymbols")
        self.qd = [q_k.diff(_t) for q_k in self.q]
        #: ``{q̈_k: 0}``: what evaluates a derivative of the motion at rest accelerations (``q̈ = 0``)
        self._no_accelerations = {qd_k.diff(_t): 0 for qd_k in self.qd}
        self.T, self.U = sp.sympify(T), sp.sympify(U)
        self.L = self.T - self.U
        if forces is None:
            forces = [0] * len(self.q)
        if len(forces) != len(self.q):
            raise ValueError(f"forces must give one generalized force per coordinate ({len(self.q)}), got {len(forces)}")
        self.forces = [sp.sympify(Q) for Q in forces]

    # ------------------------------------------------------------------ Lagrange

    def momenta(self):
        """Generalized momenta ``p_k = ∂L/∂q̇_k``."""
        return [sp.simplify(self.L.diff(qd_k)) for qd_k in self.qd]

    def equations(self):
        """Lagrange's equations ``d/dt ∂L/∂q̇_k − ∂L/∂q_k = Q_k`` as ``sympy.Eq``, one per coordinate."""
        return [sp.Eq(sp.simplify(p_k.diff(_t) - self.L.diff(q_k)), Q_k)
                for p_k, q_k, Q_k in zip(self.momenta(), self.q, self.forces)]

    def cyclic_coordinates(self):
        """Coordinates that do not appear in ``L`` (``∂L/∂q_k = 0``)."""
        return [q_k for q_k in self.q if sp.simplify(self.L.diff(q_k)) == 0]

    def conserved_momenta(self):
        """``{q_k: p_k}`` for cyclic coordinates with no generalized force: ``ṗ_k = 0``."""
        momenta = dict(zip(self.q, self.momenta()))
        return {q_k: momenta[q_k] for q_k, Q_k in zip(self.q, self.forces)
                if q_k in self.cyclic_coordinates() and sp.simplify(Q_k) == 0}

    def mass_matrix(self):
        """``M_ij = ∂²T/∂q̇_i∂q̇_j`` (symbolic); ``T`` must be quadratic in the rates."""
        return sp.Matrix([[sp.simplify(self.T.diff(a).diff(b)) for b in self.qd] for a in self.qd])

    def bias(self):
        """``h(q, q̇) = d/dt ∂L/∂q̇ − ∂L/∂q − Q`` with ``q̈ = 0``, so that the equations read ``M q̈ + h = 0``."""
        return sp.Matrix([sp.simplify((eq.lhs - eq.rhs).subs(self._no_accelerations)) for eq in self.equations()])

    # ------------------------------------------------------------------ Hamilton

    def _momentum_symbols(self):
        return [sp.Symbol(f"p_{q_k.func.__name__}") for q_k in self.q]

    def _check_legendre(self):
        """Raise ``ValueError`` unless ``T`` is a positive-definite quadratic form in ``q̇``."""
        T = sp.expand(self.T)
        for qd_k in self.qd:
            if not T.is_polynomial(qd_k) or sp.degree(T, qd_k) > 2:
                raise ValueError(f"T is not quadratic in {qd_k}: the Legendre transform is undefined")
        M = self.mass_matrix()
        if sp.simplify(M.det()) == 0:
            raise ValueError("T is not positive definite in the rates (its Hessian ∂²T/∂q̇² is singular): "
                             "the Legendre transform is undefined")
        # Positive definite at a generic point (random positive parameters and coordinates).
        symbols = sorted(M.free_symbols - {_t}, key=str)
        rng = np.random.default_rng(0)
        generic = {s: sp.Float(rng.uniform(0.5, 1.5)) for s in symbols}
        functions = {q_k: sp.Float(rng.uniform(0.5, 1.5)) for q_k in self.q}
        values = np.array(M.subs(functions).subs(generic).evalf(), dtype=float)
        if np.linalg.eigvalsh(0.5 * (values + values.T)).min() <= 0.0:
            raise ValueError("T is not positive definite in the rates: the Legendre transform is undefined")

    def hamiltonian(self):
        """``H(q, p) = Σ p_k q̇_k − L`` with ``q̇`` solved from ``p = ∂L/∂q̇`` (Legendre transform).

        Momenta appear as symbols ``p_<coordinate name>``. Raises ``ValueError`` when ``T`` is not
        a positive-definite quadratic form in the rates.
        """
        self._check_legendre()
        p = self._momentum_symbols()
        solution = sp.solve([sp.Eq(p_k, m_k) for p_k, m_k in zip(p, self.momenta())], self.qd, dict=True)
        if not solution:
            raise ValueError("could not solve p = ∂L/∂q̇ for the rates")
        rates = solution[0]
        H = sum(p_k * qd_k for p_k, qd_k in zip(p, self.qd)) - self.L
        return sp.simplify(H.subs(rates))

    def hamiltons_equations(self):
        """``(q̇_k = ∂H/∂p_k, ṗ_k = −∂H/∂q_k + Q_k)`` as two lists of ``sympy.Eq``."""
        H = self.hamiltonian()
        p = self._momentum_symbols()
        # Q_k may contain rates: express them through the momenta as well.
        rates = {qd_k: sp.simplify(H.diff(p_k)) for qd_k, p_k in zip(self.qd, p)}
        q_dot = [sp.Eq(qd_k, rates[qd_k]) for qd_k in self.qd]
        p_dot = [sp.Eq(sp.Symbol(f"{p_k.name}_dot"), sp.simplify(-H.diff(q_k) + Q_k.subs(rates)))
                 for p_k, q_k, Q_k in zip(p, self.q, self.forces)]
        return q_dot, p_dot

    def hamiltonian_flow(self, **values):
        """Hamilton's equations in numbers: ``(flow, momentum)``.

        ``flow(t, y)`` with ``y = [q, p]`` returns ``[q̇, ṗ]`` (ready for ``scipy.integrate.solve_ivp``);
        ``momentum(q, v)`` returns ``p = ∂L/∂q̇``, to start from the same state as the Lagrangian form.
        """
        substitution = self._substitution(values)
        q_dot, p_dot = self.hamiltons_equations()
        q_symbols, v_symbols, plain = self._plain()
        p = self._momentum_symbols()
        rhs = plain(sp.Matrix([eq.rhs for eq in q_dot + p_dot]).subs(substitution))
        flow = sp.lambdify([q_symbols, p], rhs, "numpy")
        momentum = sp.lambdify([q_symbols, v_symbols], plain(sp.Matrix(self.momenta()).subs(substitution)), "numpy")
        n = len(self.q)
        return (lambda t, y: np.asarray(flow(y[:n], y[n:]), dtype=float).reshape(2 * n),
                lambda q, v: np.asarray(momentum(q, v), dtype=float).reshape(n))

    # ------------------------------------------------------------------ small oscillations

    def linearize(self, equilibrium):
        """Small oscillations about an equilibrium ``{q_k: value}``: ``(M₀, K, ω²)``.

        ``M₀ = M(q₀)``, ``K = ∂²U/∂q² (q₀)`` (at rest the velocity terms vanish to first order), and
        the squared frequencies ``ω²`` are the eigenvalues of ``M₀⁻¹ K``.
        """
        at = {q_k: equilibrium[q_k] for q_k in self.q}
        gradient = [sp.simplify(self.U.diff(q_k).subs(at)) for q_k in self.q]
        if any(g != 0 for g in gradient):
            raise ValueError(f"not an equilibrium: ∂U/∂q = {gradient}")
        M0 = sp.simplify(self.mass_matrix().subs(at))
        K = sp.Matrix([[sp.simplify(self.U.diff(a).diff(b).subs(at)) for b in self.q] for a in self.q])
        return M0, K, [sp.simplify(w2) for w2 in (M0.inv() * K).eigenvals(multiple=True)]

    # ------------------------------------------------------------------ numbers

    def _substitution(self, values, expressions=None):
        """``{symbol: value}`` for the parameters of ``expressions`` (default ``L`` and the forces),
        given by name; an unknown or a missing name raises ``ValueError`` naming it."""
        expressions = [self.L] + self.forces if expressions is None else expressions
        symbols = set().union(*(sp.sympify(e).free_symbols for e in expressions)) - {_t}
        names = {str(s): s for s in symbols}
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; the parameters are {sorted(names)}")
        missing = sorted(set(names) - set(values))
        if missing:
            raise ValueError(f"missing value for parameter(s) {missing}")
        return {names[k]: v for k, v in values.items()}

    def _plain(self):
        """Plain symbols for ``q``, ``q̇`` (functions of time cannot be lambdified directly)."""
        q_symbols = sp.symbols([f"q{k}" for k in range(len(self.q))])
        v_symbols = sp.symbols([f"v{k}" for k in range(len(self.q))])
        rates, coordinates = dict(zip(self.qd, v_symbols)), dict(zip(self.q, q_symbols))
        # Rates first: replacing q_k(t) first would turn dq_k/dt into d(symbol)/dt = 0.
        return q_symbols, v_symbols, lambda e: sp.sympify(e).subs(rates).subs(coordinates)

    def numeric(self, **values):
        """A NumPy system (``nq = nv = len(q)``, ``v = q̇``) for ``ConstrainedSystem`` and ``simulate``.

        Every parameter symbol needs a value, given by name; a missing one raises ``ValueError``
        naming it.
        """
        substitution = self._substitution(values)
        q_symbols, v_symbols, plain = self._plain()
        M = plain(self.mass_matrix().subs(substitution))
        h = plain(self.bias().subs(substitution))
        energy = plain((self.T + self.U).subs(substitution))
        for expression in (M, h, energy):
            if _t in expression.free_symbols:
                raise ValueError("the Lagrangian depends explicitly on time; numeric() needs L(q, q̇)")
        return NumericLagrangian(
            len(self.q),
            sp.lambdify([q_symbols], M, "numpy"),
            sp.lambdify([q_symbols, v_symbols], h, "numpy"),
            sp.lambdify([q_symbols, v_symbols], energy, "numpy"),
            [str(q_k.func.__name__) for q_k in self.q],
            lagrangian=(q_symbols, v_symbols, plain(self.L.subs(substitution)),
                        plain(sp.Matrix(self.forces).subs(substitution))),
        )

    def holonomic(self, phi, name=None, **values):
        """A numeric :class:`~multibody.constraints.Holonomic` for ``φ(q, t) = 0`` given symbolically.

        ``phi``: expression or list of expressions in ``q`` (and ``t``). Its Jacobian, ``∂φ/∂t`` and
        the acceleration term ``γ = −(d²φ/dt²)|_{q̈=0}`` are derived exactly.
        """
        phi = sp.Matrix(phi if isinstance(phi, (list, tuple, sp.MatrixBase)) else [phi])
        phi = phi.subs(self._substitution(values, [phi]))
        return Holonomic(self._function(phi), self._function(phi.jacobian(self.q), rows=True), name=name,
                         # (the explicit time derivative only)
                         dphi_dt=self._function(phi.diff(_t).subs({qd: 0 for qd in self.qd})),
                         gamma=self._function(-phi.diff(_t, 2).subs(self._no_accelerations), rates=True))

    def pfaffian(self, A, b=None, name=None, **values):
        """A numeric :class:`~multibody.constraints.Pfaffian` for ``A(q, t) q̇ + b(q, t) = 0`` given symbolically.

        ``A``: rows of expressions (``m × n``); ``b``: ``m`` expressions or ``None``.
        ``γ = −(Ȧ q̇ + ḃ)`` is derived exactly.
        """
        A = sp.Matrix(A)
        b = sp.zeros(A.rows, 1) if b is None else sp.Matrix(b)
        substitution = self._substitution(values, [A, b])
        A, b = A.subs(substitution), b.subs(substitution)
        gamma = -(A * sp.Matrix(self.qd) + b).diff(_t).subs(self._no_accelerations)
        return Pfaffian(self._function(A, rows=True), self._function(b), name=name,
                        gamma=self._function(gamma, rates=True))

    def _function(self, expression, *, rates=False, rows=False):
        """The NumPy function ``f(q, t)`` (``f(q, v, t)`` with ``rates``) of a SymPy matrix ``expression`` in ``q``,
        ``q̇`` and ``t``: a float vector, or with ``rows`` a 2-D array (one row per constraint row)."""
        q_symbols, v_symbols, plain = self._plain()
        fn = sp.lambdify([q_symbols, v_symbols, _t] if rates else [q_symbols, _t], plain(expression), "numpy")
        if rows:
            return lambda q, t: np.atleast_2d(np.asarray(fn(q, t), dtype=float))
        if rates:
            return lambda q, v, t: np.asarray(fn(q, v, t), dtype=float).reshape(-1)
        return lambda q, t: np.asarray(fn(q, t), dtype=float).reshape(-1)


class NumericLagrangian:
    """A Lagrangian system with numbers: the mechanical-system interface of ``ConstrainedSystem``.

    ``q`` are the generalized coordinates and ``v = q̇`` their rates; ``mass_matrix(q) (n, n)``,
    ``bias_forces(q, v) (n,)`` (so that ``M q̈ + h = τ``), ``energy(q, v) = T + U``; for the variational
    integrator also ``lagrangian_gradient``, ``lagrangian_hessian``, ``momentum_jacobian`` and
    ``generalized_forces`` (derived from ``L`` on first use).

    ``symbolic_lagrangian``: ``(q symbols, v symbols, L(q, v), Q (n,))``, the Lagrangian (J) and the generalized
    forces (N or N·m per coordinate) it was made from by :meth:`LagrangianSystem.numeric`, with every parameter
    given; ``None`` for one made by hand, which then has no ``L`` for the variational integrator's derivatives.
    """

    def __init__(self, n, mass_matrix, bias_forces, energy, names, lagrangian=None):
        self.nq = self.nv = n
        self._M, self._h, self._E = mass_matrix, bias_forces, energy
        self.coordinate_names = names
        # (the variational integrator's derivatives are derived and compiled on first use only: most
        # simulations never ask for them)
        self.symbolic_lagrangian = lagrangian

    def mass_matrix(self, q):
        return np.asarray(self._M(np.asarray(q, dtype=float)), dtype=float).reshape(self.nv, self.nv)

    def bias_forces(self, q, v):
        return np.asarray(self._h(np.asarray(q, dtype=float), np.asarray(v, dtype=float)), dtype=float).reshape(self.nv)

    def energy(self, q, v):
        return float(self._E(np.asarray(q, dtype=float), np.asarray(v, dtype=float)))

    def integrate(self, q, v, dt=1.0):
        return np.asarray(q, dtype=float) + np.asarray(v, dtype=float) * dt

    # The Lagrangian's own derivatives, which the variational integrator (multibody/variational.py)
    # needs: its discrete Euler–Lagrange equations are written in ∂L/∂q, not in the bias forces h.

    @cached_property
    def _derivatives(self):
        """Compiled ``∂L/∂q``, ``∂²L/∂q²``, ``∂(M v)/∂q`` and ``Q`` of the symbolic Lagrangian."""
        if self.symbolic_lagrangian is None:
            raise AttributeError("this NumericLagrangian was built without its Lagrangian "
                                 "(use LagrangianSystem.numeric())")
        q, v, L, Q = self.symbolic_lagrangian
        gradient = sp.Matrix([L]).jacobian(q)
        M = sp.Matrix([[L.diff(a).diff(b) for b in v] for a in v])
        return (sp.lambdify([q, v], gradient, "numpy"), sp.lambdify([q, v], gradient.T.jacobian(q), "numpy"),
                sp.lambdify([q, v], (M * sp.Matrix(v)).jacobian(q), "numpy"), sp.lambdify([q, v], Q, "numpy"))

    def _evaluate(self, k, q, v, shape):
        return np.asarray(self._derivatives[k](np.asarray(q, dtype=float), np.asarray(v, dtype=float)),
                          dtype=float).reshape(shape)

    def lagrangian_gradient(self, q, v):
        """``∂L/∂q (n,)`` at ``(q, v = q̇)``: ``½ vᵀ (∂M/∂q) v − ∂U/∂q``."""
        return self._evaluate(0, q, v, (self.nv,))

    def lagrangian_hessian(self, q, v):
        """``∂²L/∂q² (n, n)`` at ``(q, v)``."""
        return self._evaluate(1, q, v, (self.nv, self.nv))

    def momentum_jacobian(self, q, v):
        """``∂(M(q) v)/∂q (n, n)`` at fixed ``v``: row i, column k holds ``∂(M v)ᵢ/∂q_k``."""
        return self._evaluate(2, q, v, (self.nv, self.nv))

    def generalized_forces(self, q, v):
        """The generalized forces ``Q(q, v) (n,)`` of the forces without a potential (zero when none)."""
        return self._evaluate(3, q, v, (self.nv,))

    def configuration_rate(self, q, v):
        return np.asarray(v, dtype=float)

    def normalize(self, q):
        return np.asarray(q, dtype=float)

    def neutral(self):
        return np.zeros(self.nq)

    def __repr__(self):
        return f"NumericLagrangian(q = {self.coordinate_names})"
