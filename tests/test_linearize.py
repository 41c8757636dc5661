"""Linearization on the constraint manifold (``mb.linearize``, ``ConstrainedSystem.linearize``).

Closed forms where they exist (a cart-pole at its upright equilibrium, a free body spinning about an
axis of inertia, the Chaplygin sleigh gliding straight), and otherwise differences of the nonlinear
dynamics along admissible perturbations: a perturbed state ``q ⊕ P s``, ``v + V u + D s`` projected onto
the constraints, whose coordinates in the linearization's bases, ``lin.coordinates(q(t) ⊖ q_ε(t), v_ε(t) −
v(t))``, are differentiated in time at ``t = 0`` and then in the perturbation ``ε``, each by the
five-point stencil (``constraint_helpers.fd_derivative``). The configurations move as ``q ⊕ v t``, exact
to first order in ``t``, and the velocities as ``v + a t`` with the nonlinear constrained accelerations.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

import multibody as mb
from multibody.demos import four_bar_setup

from constraint_helpers import fd_derivative
from dyn_helpers import central_differences, central_differences_vector
from rolling_helpers import SLEIGH_B, SLEIGH_INERTIA, SLEIGH_MASS, coin, lean_rotation, quat, sleigh

EPS = np.finfo(float).eps

# ----------------------------------------------------------------------------- systems


def cart_pole(cart_mass=1.5, pole_mass=0.4, com=0.6, pole_inertia=0.05):
    """A cart on a prismatic joint along x carrying a pole on a revolute joint about y; the pole's centre of
    mass at ``com`` (m) along its z axis, its inertia about y through the centre of mass ``pole_inertia``.
    ``q = [x, θ]``, θ = 0 upright, positive tipping the pole towards +x."""
    builder = mb.ModelBuilder("cart_pole")
    builder.add_body("cart", mb.joints.Prismatic([1.0, 0.0, 0.0]), joint_name="slide",
                     inertia=mb.Inertia(cart_mass, [0, 0, 0], 0.01 * np.eye(3)))
    builder.add_body("pole", mb.joints.Revolute([0.0, 1.0, 0.0]), parent="cart", joint_name="hinge",
                     inertia=mb.Inertia(pole_mass, [0, 0, com], np.diag([pole_inertia, pole_inertia, 1e-4])))
    return builder.build()


def four_bar():
    """The four-bar of the demos (robots/four_bar.urdf closed by a planar LoopClosure), at rest."""
    setup = four_bar_setup()
    return setup.system, setup.q0, setup.v0


def rolling_coin(speed=0.0, lean=0.0, yaw=0.0, turn=0.0):
    """The tests' coin (1 kg, radius 0.5 m, axis body z) on z = 0: leaned by ``lean`` from upright,
    heading ``yaw``, rolling at ``speed`` (m/s) along its heading and turning at ``turn`` rad/s about the
    vertical; projected onto the rolling constraint."""
    model, radius = coin(), 0.5
    system = mb.ConstrainedSystem(model, [mb.RollingDisc("coin", radius, axis=[0.0, 0.0, 1.0])])
    R = lean_rotation(yaw, lean, 0.0)
    q = np.concatenate([[0.1, -0.2, radius * np.cos(lean)], quat(R)])
    # body-frame velocity: spin about the axis (body z) for the speed, plus the turn about the world vertical
    omega = np.array([0.0, 0.0, -speed / radius]) + R.T @ np.array([0.0, 0.0, turn])
    contact_offset = R.T @ np.array([0.0, 0.0, -radius * np.cos(lean)])  # centre to contact, body axes
    v_lin = -np.cross(omega, contact_offset)  # the contact point at rest
    return system, *system.project(q, np.concatenate([v_lin, omega]), tolerance=1e-15)


# ----------------------------------------------------------------------------- differences

def _constrained(system):
    return isinstance(system, mb.ConstrainedSystem)


def _model(system):
    return system.model if _constrained(system) else system


def _accelerations(system, q, v, tau, t):
    if _constrained(system):
        return system.forward_dynamics(q, v, tau, t)[0]
    return mb.forward_dynamics(system, q, v, tau)


def nonlinear_rates(system, lin, x, dtau=None, h=1e-3):
    """``d[s; u]/dt`` at ``t = 0`` of the perturbed state of coordinates ``x`` (and joint forces ``τ + dtau``),
    from the nonlinear dynamics (module docstring)."""
    model, q, v, t = _model(system), lin.q, lin.v, lin.t
    dq, dv = lin.perturbation(x)
    q_e, v_e = model.integrate(q, dq), v + dv
    if _constrained(system) and system.num_rows:
        q_e, v_e = system.project(q_e, v_e, t, tolerance=1e-15)
    a = _accelerations(system, q, v, lin.tau, t)
    a_e = _accelerations(system, q_e, v_e, lin.tau + (0.0 if dtau is None else dtau), t)

    def coordinates(time):
        return lin.coordinates(model.difference(model.integrate(q, v * time), model.integrate(q_e, v_e * time)),
                               v_e - v + (a_e - a) * time)

    return fd_derivative(coordinates, h)


def rates_by_differences(system, lin, h=1e-3):
    """``(A, B)`` by five-point differences in each coordinate of ``[s; u]`` and ``δτ`` of
    :func:`nonlinear_rates`."""
    n, nv = lin.p + lin.k, lin.B.shape[-1]
    A = np.stack([fd_derivative(lambda e, j=j: nonlinear_rates(system, lin, e * np.eye(n)[j]), h) for j in range(n)],
                 axis=-1)
    B = np.stack([fd_derivative(lambda e, j=j: nonlinear_rates(system, lin, np.zeros(n), e * np.eye(nv)[j]), h)
                  for j in range(nv)], axis=-1)
    return A, B


#: Nested five-point differences (steps h = 1e-3 in time and in ε): the rounding of the coordinates,
#: about ε max(1, |q|, |v|), is divided by both steps, ≈ 3e-10 per unit of state (the stencil's weights
#: sum to 1.5/h); the truncation, h⁴ times fifth derivatives of rates of order one, stays below 1e-11; the
#: analytic side differentiates the rows by five-point steps too (about 1e-11). Ten times that rounding:
DIFFERENCE_TOL = 3e-9


def assert_matches_differences(system, lin, what):
    A, B = rates_by_differences(system, lin)
    scale = max(1.0, float(np.abs(lin.q).max()), float(np.abs(lin.v).max()))
    for name, ours, reference in (("A", lin.A, A), ("B", lin.B, B)):
        error = np.abs(ours - reference).max() / (scale * max(1.0, np.abs(reference).max()))
        assert error <= DIFFERENCE_TOL, f"{what}: {name} differs from the differences by {error:.2e} (relative)"


# ----------------------------------------------------------------------------- unconstrained models

def test_cart_pole_upright_matches_closed_form():
    """``[[M + m, m l], [m l, J]] [ẍ; θ̈] = [F; τ + m g l θ]`` at θ = 0 (``J = I_c + m l²``), so with
    ``Δ = (M + m) J − m² l²``: ``ẍ = (J F − m l (τ + m g l θ)) / Δ``, ``θ̈ = ((M + m)(τ + m g l θ) − m l F) / Δ``."""
    M, m, l, I_c = 1.5, 0.4, 0.6, 0.05
    model = cart_pole(M, m, l, I_c)
    g = -model.gravity[2]
    J = I_c + m * l**2
    delta = (M + m) * J - m**2 * l**2
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 1] = -m * l * m * g * l / delta
    A[3, 1] = (M + m) * m * g * l / delta
    B = np.array([[0.0, 0.0], [0.0, 0.0], [J / delta, -m * l / delta], [-m * l / delta, (M + m) / delta]])

    lin = mb.linearize(model, np.zeros(2), np.zeros(2), np.zeros(2))
    assert (lin.p, lin.k) == (2, 2) and lin.dt is None
    np.testing.assert_array_equal(lin.position_basis, np.eye(2))
    np.testing.assert_array_equal(lin.velocity_basis, np.eye(2))
    np.testing.assert_array_equal(lin.dependent_rates, np.zeros((2, 2)))
    np.testing.assert_allclose(lin.A, A, rtol=0, atol=1e-10 * np.abs(A).max())
    np.testing.assert_allclose(lin.B, B, rtol=0, atol=1e-10 * np.abs(B).max())
    # the upright pole is unstable: eigenvalues ±sqrt((M + m) m g l / Δ) and a double zero
    rate = np.sqrt((M + m) * m * g * l / delta)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(lin.A).real), [-rate, 0.0, 0.0, rate], atol=1e-7)


def test_double_pendulum_matches_forward_dynamics_differences():
    """``A = [[0, I], [∂a/∂q, ∂a/∂v]]`` and ``B = [[0], [∂a/∂τ]]`` against central differences of
    ``mb.forward_dynamics`` (steps 1e-6: rounding about 1e-9 of the entries; 1e-7 leaves a margin of 10
    over it and over the step's truncation)."""
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(3)
    q, v, tau = model.random_configuration(rng), rng.standard_normal(2), rng.standard_normal(2)
    lin = mb.linearize(model, q, v, tau)
    da_dq = central_differences(lambda x: mb.forward_dynamics(model, x, v, tau), model, q)
    da_dv = central_differences_vector(lambda x: mb.forward_dynamics(model, q, x, tau), v)
    da_dtau = central_differences_vector(lambda x: mb.forward_dynamics(model, q, v, x), tau)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [da_dq, da_dv]])
    B = np.concatenate([np.zeros((2, 2)), da_dtau])
    np.testing.assert_allclose(lin.A, A, rtol=0, atol=1e-7 * np.abs(A).max())
    np.testing.assert_allclose(lin.B, B, rtol=0, atol=1e-7 * np.abs(B).max())
    assert_matches_differences(model, lin, "double pendulum")


def free_body(gravity=(0.0, 0.0, 0.0), moments=(0.2, 0.3, 0.5)):
    """A rigid body on a free-flyer joint (its orientation a quaternion), 2 kg, principal moments ``moments``
    (kg m²) about its body axes through its centre of mass at the body origin."""
    builder = mb.ModelBuilder("free_body", gravity=gravity)
    builder.add_body("body", mb.joints.FreeFlyer(), joint_name="root_joint",
                     inertia=mb.Inertia(2.0, [0, 0, 0], np.diag(moments)))
    return builder.build()


def test_free_body_spinning_about_its_middle_axis_has_eulers_exponents():
    """A free body spinning at ω₀ about its middle axis, without gravity: ``∂a/∂q = 0`` and ``A`` is block
    triangular, so its eigenvalues are those of ``−ad_v`` (0 and ±iω₀ for the position and for the orientation
    perturbations, which the body axes carry round) and of ``∂a/∂v``: ``δv̇_lin = −ω × δv_lin`` (0, ±iω₀) and
    Euler's equations linearized, ``λ² = ω₀² (I₂ − I₁)(I₃ − I₂) / (I₁ I₃)`` and 0 (Landau and Lifshitz,
    *Mechanics*, §37): four zeros, ±iω₀ three times and ±λ."""
    I1, I2, I3 = 0.2, 0.3, 0.5
    model, omega = free_body(moments=(I1, I2, I3)), 4.0
    q, v = model.neutral(), np.array([0.0, 0.0, 0.0, 0.0, omega, 0.0])
    lin = mb.linearize(model, q, v)
    np.testing.assert_array_equal(lin.position_basis, np.eye(6))
    rate = omega * np.sqrt((I2 - I1) * (I3 - I2) / (I1 * I3))
    expected = [-rate, rate] + [0.0] * 4 + [omega * 1j, -omega * 1j] * 3
    key = lambda z: (round(z.real, 6), round(z.imag, 6))  # noqa: E731
    np.testing.assert_allclose(sorted(np.linalg.eigvals(lin.A), key=key), sorted(np.array(expected), key=key),
                               atol=1e-6 * omega)


def test_free_body_tumbling_matches_differences():
    """A free body under gravity, spinning about a skew axis and moving: the Lie-group terms ``−ad_v`` (SE(3):
    the body-frame translation turns with ω, and rotation perturbations turn about ω) agree with the
    nonlinear motion; leaving them out misses by their own size."""
    model = free_body(gravity=(0.0, 0.0, -9.81))
    q = np.concatenate([[0.3, -0.2, 1.0], quat(mb.spatial.rpy_to_rotation([0.4, -0.3, 1.2]))])
    v = np.array([0.5, -0.4, 0.3, 1.5, -2.0, 3.0])
    lin = mb.linearize(model, q, v, np.array([0.1, 0.2, -0.3, 0.05, 0.0, 0.02]))
    assert_matches_differences(model, lin, "free body")
    ad = mb.linearization.lie_bracket(model, v)
    assert np.abs(ad).max() > 1.0  # (the term the differences check is not small here)
    np.testing.assert_allclose(lin.A[:6, :6], -ad, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------- holonomic: the four-bar

def test_four_bar_position_basis_spans_the_loops_null_space_and_rates_match_differences():
    system, q0, v0 = four_bar()
    rng = np.random.default_rng(4)
    q1, v1 = system.project(q0, rng.standard_normal(3), tolerance=1e-15)
    holonomic = system.position_rows
    assert holonomic.all() and system.rank(q0, rows=holonomic) == 2
    for q, v, what in ((q0, v0, "at rest"), (q1, v1, "moving")):
        lin = system.linearize(q, v, rng.standard_normal(3))
        A_h = system.jacobian(q)[holonomic]
        P = lin.position_basis
        assert (lin.p, lin.k) == (1, 1) and P.shape == (3, 1)
        assert np.abs(A_h @ P).max() <= 1e-12 * np.abs(A_h).max(), what
        np.testing.assert_allclose(P.T @ P, np.eye(1), rtol=0, atol=1e-15)
        # every row has a position level: the velocity basis is the position basis
        np.testing.assert_array_equal(lin.velocity_basis, P)
        # the loop's velocity rows hold to first order: A δv + ∂(A v)/∂q δq = 0 for δv = D s, δq = P s
        C = system.velocity_error_derivative(q, v)
        assert np.abs(A_h @ lin.dependent_rates + C @ P).max() <= 1e-12 * max(1.0, np.abs(C).max()), what
        assert_matches_differences(system, lin, f"four-bar {what}")
    # at rest the rows allow no dependent rates; moving, the loop's rates change with the configuration
    assert np.abs(system.linearize(q0, v0).dependent_rates).max() == 0.0
    assert np.abs(lin.dependent_rates).max() > 1e-2


# ----------------------------------------------------------------------------- nonholonomic: coin and sleigh

def _check_nonholonomic_bases(system, lin, p, k, what):
    A = system.jacobian(lin.q, lin.t)
    holonomic = system.position_rows
    assert (lin.p, lin.k) == (p, k) and k < p, what
    P, V = lin.position_basis, lin.velocity_basis
    assert np.abs(A @ V).max() <= 1e-12 * np.abs(A).max(), f"{what}: A V"
    assert np.abs(A[holonomic] @ P).max(initial=0.0) <= 1e-12 * np.abs(A).max(), f"{what}: A_h P"
    np.testing.assert_allclose(V.T @ V, np.eye(k), rtol=0, atol=1e-14)
    np.testing.assert_allclose(P.T @ P, np.eye(p), rtol=0, atol=1e-14)
    # V lies in the span of P, and D is orthogonal to V
    assert np.abs(V - P @ (P.T @ V)).max() <= 1e-14, f"{what}: V outside span P"
    assert np.abs(V.T @ lin.dependent_rates).max() <= 1e-13 * max(1.0, np.abs(lin.dependent_rates).max())


@pytest.mark.parametrize("motion", ["straight", "leaned and turning"])
def test_rolling_coin_bases_and_rates(motion):
    """The coin has 6 velocity coordinates, one holonomic row (the contact height) and two rolling rows:
    p = 5 position and k = 3 velocity coordinates. Rolling straight and upright at 1 m/s is a steady motion;
    the leaned, turning state is not, and A is the instantaneous rate there."""
    system, q, v = rolling_coin(speed=1.0) if motion == "straight" else rolling_coin(1.0, 0.3, 0.4, 0.7)
    lin = system.linearize(q, v)
    _check_nonholonomic_bases(system, lin, 5, 3, f"coin {motion}")
    # rolling, moving the configuration changes the rates the rows allow
    assert np.abs(lin.dependent_rates).max() > 0.1
    assert_matches_differences(system, lin, f"coin {motion}")


def test_chaplygin_sleigh_glide_has_the_reduced_equations_exponent():
    """The sleigh (body-frame velocities ``[v_x, v_y, ω]``, the blade at ``b`` ahead of the centre of mass
    along body x) keeps ``v_y + b ω = 0``. With it, ``m (v̇_y + ω v_x) = λ`` and ``I ω̇ = b λ`` give
    ``(I + m b²) ω̇ = m b v_x ω`` and ``v̇_x = −b ω²`` (Bloch, *Nonholonomic Mechanics and Control*, §1.7, with
    the centre of mass behind the blade): gliding straight at ``v_x = c`` the turn grows at ``m b c / (I + m b²)``
    (unstable forward, stable backward), every other exponent zero. The rows are constant in the body frame,
    so the glide is steady in the linearization's bases."""
    model, blade = sleigh()
    system = mb.ConstrainedSystem(model, [blade])
    for speed in (0.5, -0.5):
        q, v = system.project(model.neutral(), np.array([speed, 0.0, 0.0]))
        lin = system.linearize(q, v)
        _check_nonholonomic_bases(system, lin, 3, 2, "sleigh")
        rate = SLEIGH_MASS * SLEIGH_B * speed / (SLEIGH_INERTIA + SLEIGH_MASS * SLEIGH_B**2)
        eigenvalues = np.linalg.eigvals(lin.A)
        np.testing.assert_allclose(sorted(eigenvalues.real), sorted([rate, 0.0, 0.0, 0.0, 0.0]), atol=1e-9)
        np.testing.assert_allclose(eigenvalues.imag, 0.0, atol=1e-9)
        assert_matches_differences(system, lin, f"sleigh at {speed} m/s")
    # turning, with joint forces: the instantaneous rates
    q, v = system.project(model.neutral(), np.array([0.5, 0.3, 1.0]))
    assert_matches_differences(system, system.linearize(q, v, np.array([0.1, 0.2, 0.3])), "sleigh turning")


# ----------------------------------------------------------------------------- one step of RK4

def test_rk4_step_map_is_the_exponential_to_fifth_order():
    """At an equilibrium every stage of the step sits at the same state, so the step's map is RK4 applied to
    ``ẋ = A x``: ``T₄(hA) = Σ_{j≤4} (hA)ʲ/j!``, which differs from ``expm(hA)`` by ``(hA)⁵/5! + O(h⁶)``: halving
    ``h`` divides the difference by 32."""
    model = cart_pole()
    zero = np.zeros(2)
    continuous = mb.linearize(model, zero, zero, zero)
    A, B = continuous.A, continuous.B
    errors = []
    for h in (0.1, 0.05, 0.025):
        step = mb.linearize(model, zero, zero, zero, dt=h)
        assert step.dt == h and step.method == "RK4" and (step.p, step.k) == (2, 2)
        taylor = sum(np.linalg.matrix_power(h * A, j) / np.prod(np.arange(1, j + 1)) for j in range(5))
        np.testing.assert_allclose(step.A, taylor, rtol=0, atol=1e-12)
        exact = scipy.linalg.expm(h * A)
        errors.append(np.abs(step.A - exact).max())
        # the leading term of the difference, (hA)⁵/5!, within the next term's share (h λ/6 ≤ 0.07: the
        # fastest rate λ is 3.8/s)
        leading = np.abs(np.linalg.matrix_power(h * A, 5)).max() / 120
        assert abs(errors[-1] - leading) <= 0.1 * leading, (h, errors[-1], leading)
        # B: joint forces held over the step, RK4's Σ_{j≤3} hʲ⁺¹ Aʲ B / (j + 1)!, against the exact response
        # ∫₀ʰ expm(A s) ds B, which differs by h⁵ A⁴ B / 5! + O(h⁶)
        taylor = sum(np.linalg.matrix_power(h * A, j) * h / np.prod(np.arange(1, j + 2)) for j in range(4)) @ B
        np.testing.assert_allclose(step.B, taylor, rtol=0, atol=1e-12)
        integral = scipy.linalg.expm(np.block([[h * A, h * B], [np.zeros((2, 6))]]))[:4, 4:]
        leading = np.abs(h * np.linalg.matrix_power(h * A, 4) @ B).max() / 120
        assert abs(np.abs(step.B - integral).max() - leading) <= 0.1 * leading, (h, leading)
    np.testing.assert_allclose(np.array(errors[:-1]) / errors[1:], 32.0, rtol=0.05)


def step_by_differences(system, lin, h=1e-3):
    """``(A, B)`` of one step by five-point differences of ``mb.rk4_step`` from perturbed (projected) states,
    the end measured in the linearization's coordinates against the unperturbed end."""
    model, n, nv = _model(system), lin.p + lin.k, lin.B.shape[-1]
    q_end, v_end = mb.rk4_step(system, lin.q, lin.v, lin.tau, lin.dt, lin.t)

    def end(x, dtau):
        dq, dv = lin.perturbation(x)
        q_e, v_e = model.integrate(lin.q, dq), lin.v + dv
        if _constrained(system) and system.num_rows:
            q_e, v_e = system.project(q_e, v_e, lin.t, tolerance=1e-15)
        q_next, v_next = mb.rk4_step(system, q_e, v_e, lin.tau + dtau, lin.dt, lin.t)
        return lin.coordinates(model.difference(q_end, q_next), v_next - v_end)

    A = np.stack([fd_derivative(lambda e, j=j: end(e * np.eye(n)[j], 0.0), h) for j in range(n)], axis=-1)
    B = np.stack([fd_derivative(lambda e, j=j: end(np.zeros(n), e * np.eye(nv)[j]), h) for j in range(nv)], axis=-1)
    return A, B


def _moving_states():
    rng = np.random.default_rng(6)
    system, q0, _ = four_bar()
    q1, v1 = system.project(q0, rng.standard_normal(3), tolerance=1e-15)
    body = free_body(gravity=(0.0, 0.0, -9.81))
    q_body = np.concatenate([[0.3, -0.2, 1.0], quat(mb.spatial.rpy_to_rotation([0.4, -0.3, 1.2]))])
    return {"four-bar": (system, q1, v1, rng.standard_normal(3)),
            "coin": (*rolling_coin(1.0, 0.3, 0.4, 0.7), 0.1 * rng.standard_normal(6)),
            "free body": (body, q_body, np.array([0.5, -0.4, 0.3, 1.5, -2.0, 3.0]), rng.standard_normal(6))}


MOVING = _moving_states()


@pytest.mark.parametrize("name", list(MOVING))
def test_rk4_step_map_equals_differences_of_one_step(name):
    """Single five-point differences (h = 1e-3, rounding about 1.5 ε / h ≈ 3e-13 of the states) against the
    step's derivatives, whose glue and constraint rows are differentiated by five-point steps too (about 1e-11):
    1e-9 relative leaves a margin of ten over both."""
    system, q, v, tau = MOVING[name]
    lin = mb.linearize(system, q, v, tau, dt=0.01)
    A, B = step_by_differences(system, lin)
    for what, ours, reference in (("A", lin.A, A), ("B", lin.B, B)):
        error = np.abs(ours - reference).max() / np.abs(reference).max()
        assert error <= 1e-9, f"{name}: the step's {what} differs from the differences by {error:.2e}"


# ----------------------------------------------------------------------------- batches, coordinates, errors

#: Batch against single: the constrained derivatives difference the rows with a step scaled by the largest
#: |q| of the whole batch (ConstrainedSystem.DERIVATIVE_STEP), and the single state runs the compiled KKT step,
#: so A and D agree to the five-point differences' error (about 1e-11 relative), with a margin of ten.
BATCH_TOL = 1e-10


@pytest.mark.parametrize("name", ["four-bar", "coin", "free body"])
def test_batch_equals_single(name):
    system, q, v, tau = MOVING[name]
    model = _model(system)
    rng = np.random.default_rng(7)
    qs = np.stack([model.integrate(q, 0.05 * rng.standard_normal(model.nv)) for _ in range(3)])
    vs = v + 0.1 * rng.standard_normal((3, model.nv))
    if _constrained(system):
        qs, vs = system.project(qs, vs, tolerance=1e-15)
    for dt in (None, 0.01):
        batch = mb.linearize(system, qs.reshape(3, 1, -1), vs.reshape(3, 1, -1), tau, dt=dt)
        assert batch.A.shape == (3, 1, batch.p + batch.k, batch.p + batch.k)
        assert batch.q.shape == (3, 1, model.nq) and batch.tau.shape == (3, 1, model.nv)
        for i in range(3):
            single = mb.linearize(system, qs[i], vs[i], tau, dt=dt)
            assert (single.p, single.k) == (batch.p, batch.k)
            np.testing.assert_array_equal(batch.position_basis[i, 0], single.position_basis)
            np.testing.assert_array_equal(batch.velocity_basis[i, 0], single.velocity_basis)
            for field in ("A", "B", "dependent_rates"):
                ours, reference = getattr(batch, field)[i, 0], getattr(single, field)
                error = np.abs(ours - reference).max() / max(1.0, np.abs(reference).max())
                assert error <= (BATCH_TOL if _constrained(system) else 1e-14), (name, dt, field, error)


def _sleigh_by_a_user_row():
    """The sleigh with its blade written as a user Pfaffian row ``v_y + b ω = 0`` (a system that takes one state
    at a time), and a particle whose row ``x v_x = 0`` vanishes at ``x = 0`` (its rank changes there)."""
    model, _ = sleigh()
    blade = mb.Pfaffian(lambda q, t: np.array([[0.0, 1.0, SLEIGH_B]]), name="blade")
    builder = mb.ModelBuilder("particle")
    builder.add_body("particle", mb.joints.Translation(), inertia=mb.inertia.point_mass(1.0))
    particle = builder.build()
    row = mb.Pfaffian(lambda q, t: np.array([[q[0], 0.0, 0.0]]), name="row")
    return mb.ConstrainedSystem(model, [blade]), mb.ConstrainedSystem(particle, [row])


def test_batch_of_a_system_that_takes_one_state_at_a_time():
    system, particle = _sleigh_by_a_user_row()
    assert not system.batched
    qs = np.stack([system.model.integrate(system.model.neutral(), [0.1 * i, 0.0, 0.3 * i]) for i in range(3)])
    vs = np.array([[0.5, -SLEIGH_B * w, w] for w in (0.0, 1.0, -2.0)])
    batch = system.linearize(qs, vs)
    for i in range(3):
        single = system.linearize(qs[i], vs[i])
        for field in ("A", "B", "position_basis", "velocity_basis", "dependent_rates"):
            np.testing.assert_array_equal(getattr(batch, field)[i], getattr(single, field))
    # the particle's row has rank 1 at x = 1 and rank 0 at x = 0: k differs, and the batch says where
    with pytest.raises(ValueError, match=r"rank changes across the batch \(p = 3, k = 2 at state 0; p = 3, k = 3 "
                                         r"at state 1\)"):
        particle.linearize(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), np.zeros((2, 3)))


def test_perturbation_and_coordinates_invert_each_other():
    system, q, v, tau = MOVING["coin"]
    lin = system.linearize(q, v, tau)
    x = np.random.default_rng(8).standard_normal((4, lin.p + lin.k))
    dq, dv = lin.perturbation(x)
    assert dq.shape == dv.shape == (4, 6)
    np.testing.assert_allclose(lin.coordinates(dq, dv), x, rtol=0, atol=1e-14)
    with pytest.raises(ValueError, match=r"x must have shape \(\.\.\., 8\)"):
        lin.perturbation(np.zeros(6))
    with pytest.raises(ValueError, match=r"dv must have shape \(\.\.\., 6\)"):
        lin.coordinates(np.zeros(6), np.zeros(5))


def test_bad_input_is_refused_naming_it():
    system, q, v = four_bar()
    with pytest.raises(ValueError, match=r"off the constraints by 0\.1.*system\.project"):
        system.linearize(q, v + np.array([0.1, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"off the constraints at state 1 "):
        system.linearize(np.stack([q, q]), np.stack([v, v + 0.1]))
    with pytest.raises(ValueError, match=r"q must have shape \(\.\.\., 3\), got \(2,\)"):
        system.linearize(q[:2], v)
    with pytest.raises(ValueError, match=r"tau must have shape \(\.\.\., 3\), got \(4,\)"):
        system.linearize(q, v, np.zeros(4))
    with pytest.raises(ValueError, match=r"tau must be finite: tau\[1\] = nan"):
        system.linearize(q, v, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"q must be finite: q\[1, 2\] = inf"):
        system.linearize(np.stack([q, q + [0.0, 0.0, np.inf]]), np.stack([v, v]))
    with pytest.raises(ValueError, match=r"method must be one of \('RK4',\)"):
        system.linearize(q, v, dt=0.01, method="Euler")
    with pytest.raises(ValueError, match=r"dt must be a positive number of seconds, got 0"):
        system.linearize(q, v, dt=0)
    with pytest.raises(ValueError, match=r"rows must be a boolean mask of shape \(2,\), got int64 of shape \(1,\)"):
        system.rank(q, rows=np.array([0]))
    with pytest.raises(TypeError, match=r"system must be a Model or a ConstrainedSystem, got str"):
        mb.linearize("four_bar", q, v)
