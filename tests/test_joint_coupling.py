"""``JointCoupling`` by a polynomial: ``q_b = Σₖ cₖ (q_a − reference)ᵏ`` (MuJoCo's joint equality), and a joint
held alone (``joint_a=None``). The rows are checked against finite differences of ``φ`` along the motion, the
constrained dynamics against the row's acceleration level, and the linear form against ``ratio``/``offset``."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb

from constraint_helpers import assert_close

COEFFICIENTS = (0.1, -0.7, 0.4, 0.25, -0.3)
REFERENCE = 0.2


@pytest.fixture(scope="module")
def pendulum():
    return mb.robots.load("double_pendulum")


def polynomial(x, c=COEFFICIENTS):
    return sum(ck * x**k for k, ck in enumerate(c))


def test_polynomial_position_level_is_the_polynomial(pendulum):
    coupling = mb.JointCoupling("shoulder", "elbow", coefficients=COEFFICIENTS, reference=REFERENCE)
    q = np.array([0.7, -0.4])
    expected = q[1] - polynomial(q[0] - REFERENCE)
    assert_close(coupling.position(pendulum, q), [expected], 1e-15, scale=1.0, what="phi")


def test_polynomial_rows_match_finite_differences(pendulum):
    """``A`` is ``dφ/dq`` and ``γ = −d²φ/dt²`` at ``a = 0``: both against central differences of ``φ`` along
    ``q + v t`` (the joints are angles, so ``q̇ = v``), with the fourth-order stencil's error ~ h⁴."""
    coupling = mb.JointCoupling("shoulder", "elbow", coefficients=COEFFICIENTS, reference=REFERENCE)
    rng = np.random.default_rng(3)
    h = 1e-3
    for _ in range(5):
        q, v = rng.uniform(-1.0, 1.0, 2), rng.standard_normal(2)
        A, b, gamma = coupling.evaluate(pendulum, q, v)

        def phi(t):
            return coupling.position(pendulum, q + v * t)[0]

        rate = (8.0 * (phi(h) - phi(-h)) - (phi(2 * h) - phi(-2 * h))) / (12.0 * h)
        curvature = (-phi(2 * h) + 16.0 * phi(h) - 30.0 * phi(0.0) + 16.0 * phi(-h) - phi(-2 * h)) / (12.0 * h * h)
        assert_close(A @ v, [rate], 1e-9, scale=1.0, what="A v")
        assert_close(gamma, [-curvature], 1e-5, scale=1.0, what="gamma")
        assert np.all(b == 0.0)


def test_polynomial_coupling_constrains_the_dynamics(pendulum):
    """The constrained accelerations satisfy ``A a = γ``, with ``γ = p″(x) v_a²`` non-zero."""
    coupling = mb.JointCoupling("shoulder", "elbow", coefficients=COEFFICIENTS, reference=REFERENCE)
    system = mb.ConstrainedSystem(pendulum, [coupling])
    q, v = system.project(np.array([0.5, 0.0]), np.array([1.2, 0.0]))
    assert_close(coupling.position(pendulum, q), [0.0], 1e-12, scale=1.0, what="projected phi")
    a, _ = system.forward_dynamics(q, v)
    A, _, gamma = coupling.evaluate(pendulum, q, v)
    assert abs(gamma[0]) > 0.1
    assert_close(A @ a, gamma, 1e-12, what="A a = gamma")


def test_linear_coefficients_equal_ratio_and_offset(pendulum):
    ratio_form = mb.JointCoupling("shoulder", "elbow", 1.7, -0.3)
    coefficient_form = mb.JointCoupling("shoulder", "elbow", coefficients=(-0.3, 1.7))
    assert (ratio_form.ratio, ratio_form.offset) == (coefficient_form.ratio, coefficient_form.offset) == (1.7, -0.3)
    q, v = np.array([0.3, 0.9]), np.array([-0.4, 2.0])
    for ours, theirs in zip(ratio_form.evaluate(pendulum, q, v), coefficient_form.evaluate(pendulum, q, v)):
        assert np.array_equal(ours, theirs)
    assert np.array_equal(ratio_form.position(pendulum, q), coefficient_form.position(pendulum, q))


def test_ratio_and_offset_are_the_coefficients_rows_use():
    """``ratio`` and ``offset`` read ``c₁`` and ``c₀`` of the coefficients the compiled row is built from, and
    cannot be set apart from them (a second copy would leave the row on the old polynomial)."""
    coupling = mb.JointCoupling("shoulder", "elbow", coefficients=(0.2, -1.5, 0.7), reference=0.1)
    assert (coupling.ratio, coupling.offset) == (-1.5, 0.2)
    with pytest.raises(AttributeError):
        coupling.ratio = 2.0
    with pytest.raises(AttributeError):
        coupling.offset = 1.0


def test_joint_held_alone(pendulum):
    """Without joint a the row holds joint b at ``offset``: ``φ = q_b − c₀``, ``A = e_b``, ``γ = 0``."""
    hold = mb.JointCoupling(None, "elbow", offset=0.25)
    q, v = np.array([0.3, 0.9]), np.array([-0.4, 2.0])
    A, _, gamma = hold.evaluate(pendulum, q, v)
    assert np.array_equal(A, [[0.0, 1.0]]) and np.array_equal(gamma, [0.0])
    assert_close(hold.position(pendulum, q), [0.9 - 0.25], 1e-15, scale=1.0, what="phi")
    system = mb.ConstrainedSystem(pendulum, [hold])
    q, _ = system.project(q, v)
    assert_close(q[1], 0.25, 1e-12, scale=1.0, what="held joint")


def test_refuses_bad_coefficients():
    with pytest.raises(ValueError, match="give ratio and offset, or coefficients, not both"):
        mb.JointCoupling("a", "b", 2.0, coefficients=(0.0, 1.0))
    with pytest.raises(ValueError, match="at most 5 finite numbers"):
        mb.JointCoupling("a", "b", coefficients=(0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="at most 5 finite numbers"):
        mb.JointCoupling("a", "b", coefficients=(0.0, np.nan))
    with pytest.raises(ValueError, match="coefficients must be numbers"):
        mb.JointCoupling("a", "b", coefficients="one")
