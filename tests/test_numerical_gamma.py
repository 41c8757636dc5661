"""Numerical ``γ`` of user constraints at high speed: the stencil steps along ``q ⊕ v s`` in
configuration units, so ``γ`` stays accurate whatever the joint rates (1, 1e2 and 1e4 rad/s here),
against ``γ = −vᵀ (∂²φ/∂q²) v`` (holonomic) and ``γ = −(∂(A v)/∂q) v`` (Pfaffian) from SymPy."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import multibody as mb

q0, q1 = sp.symbols("q0 q1")
PHI = sp.sin(q0) + 0.5 * sp.cos(q0 + q1) - 0.3 * q1**2
HESSIAN = sp.lambdify((q0, q1), sp.hessian(PHI, (q0, q1)))
GRADIENT = sp.lambdify((q0, q1), [sp.diff(PHI, x) for x in (q0, q1)])
PHI_VALUE = sp.lambdify((q0, q1), PHI)
# a Pfaffian row A(q) v = 0 with A = [cos q1, 1 + q0²]
A_ROW = sp.Matrix([[sp.cos(q1), 1 + q0**2]])
A_JACOBIAN = sp.lambdify((q0, q1), A_ROW.jacobian(sp.Matrix([q0, q1])))  # ∂A/∂q, shape (2,) per entry of A


@pytest.mark.parametrize("rate", [1.0, 1e2, 1e4])
@pytest.mark.parametrize("with_jacobian", [False, True], ids=["phi only", "phi and jacobian"])
def test_holonomic_gamma_at_high_joint_rates(rate, with_jacobian):
    model = mb.robots.load("double_pendulum")
    jacobian = (lambda q, t: np.array([GRADIENT(*q)])) if with_jacobian else None
    constraint = mb.Holonomic(lambda q, t: np.array([PHI_VALUE(*q)]), jacobian)
    q, v = np.array([0.4, -0.7]), rate * np.array([0.8, -0.6])
    gamma = constraint.acceleration_rhs(model, q, v)
    exact = -v @ np.array(HESSIAN(*q), dtype=float) @ v
    assert abs(gamma[0] - exact) <= 1e-8 * abs(exact)


@pytest.mark.parametrize("rate", [1.0, 1e2, 1e4])
def test_pfaffian_gamma_at_high_joint_rates(rate):
    model = mb.robots.load("double_pendulum")
    constraint = mb.Pfaffian(lambda q, t: np.array([[np.cos(q[1]), 1.0 + q[0] ** 2]]))
    q, v = np.array([0.4, -0.7]), rate * np.array([0.8, -0.6])
    gamma = constraint.acceleration_rhs(model, q, v)
    # d/dt (A v) at a = 0: Σ_k (∂A/∂q_k v) v_k
    dA = np.array(A_JACOBIAN(*q), dtype=float)  # (1 · 2 entries of A, 2 coordinates) flattened by rows
    exact = -(dA @ v) @ v
    assert abs(gamma[0] - exact) <= 1e-8 * abs(exact)
