"""The textbook front-end: SymPy Lagrangians, their equations, Hamiltonians and numbers."""

import numpy as np
import pytest

sp = pytest.importorskip("sympy")
from scipy.integrate import solve_ivp  # noqa: E402
from sympy.physics.mechanics import dynamicsymbols  # noqa: E402

import multibody as mb  # noqa: E402

t = dynamicsymbols._t
m, g, l, k = sp.symbols("m g l k", positive=True)


def kepler():
    r, theta = dynamicsymbols("r theta")
    return mb.LagrangianSystem([r, theta], m / 2 * (r.diff() ** 2 + r**2 * theta.diff() ** 2), -k / r), r, theta


def double_pendulum():
    """The shipped URDF double pendulum in its joint angles: uniform rods (1 kg, 1 m) about +y."""
    q1, q2 = dynamicsymbols("q1 q2")

    def down(angle, length):  # R_y(angle) (0, 0, −length)
        return sp.Matrix([-length * sp.sin(angle), 0, -length * sp.cos(angle)])

    com1 = down(q1, sp.Rational(1, 2))
    com2 = down(q1, 1) + down(q1 + q2, sp.Rational(1, 2))
    inertia = sp.Rational(1, 12)  # m L² / 12 about the centre, unit rods
    velocity = lambda x: x.diff(t)  # noqa: E731
    T = (sp.Rational(1, 2) * (velocity(com1).dot(velocity(com1)) + velocity(com2).dot(velocity(com2)))
         + sp.Rational(1, 2) * inertia * (q1.diff() ** 2 + (q1.diff() + q2.diff()) ** 2))
    U = g * (com1[2] + com2[2])
    return mb.LagrangianSystem([q1, q2], T, U)


def test_particle_under_gravity():
    x, y, z = dynamicsymbols("x y z")
    particle = mb.LagrangianSystem([x, y, z], m / 2 * (x.diff() ** 2 + y.diff() ** 2 + z.diff() ** 2), m * g * z)
    equations = particle.equations()
    assert sp.simplify(equations[0].lhs - m * x.diff(t, 2)) == 0
    assert sp.simplify(equations[2].lhs - m * (z.diff(t, 2) + g)) == 0
    assert particle.cyclic_coordinates() == [x, y]
    assert particle.conserved_momenta() == {x: m * x.diff(), y: m * y.diff()}


def test_pendulum_equation_and_small_oscillation_frequency():
    theta = dynamicsymbols("theta")
    pendulum = mb.LagrangianSystem([theta], m * l**2 * theta.diff() ** 2 / 2, m * g * l * (1 - sp.cos(theta)))
    equation = pendulum.equations()[0]
    assert sp.simplify(equation.lhs / (m * l**2) - (theta.diff(t, 2) + g / l * sp.sin(theta))) == 0
    M0, K, omega2 = pendulum.linearize({theta: 0})
    assert omega2 == [g / l]
    with pytest.raises(ValueError, match="not an equilibrium"):
        pendulum.linearize({theta: 1})


def test_kepler_symbolic_structure():
    system, r, theta = kepler()
    assert system.cyclic_coordinates() == [theta]
    assert sp.simplify(system.conserved_momenta()[theta] - m * r**2 * theta.diff()) == 0
    radial = system.equations()[0]
    assert sp.simplify(radial.lhs - (m * r.diff(t, 2) - m * r * theta.diff() ** 2 + k / r**2)) == 0
    H = system.hamiltonian()
    p_r, p_theta = sp.symbols("p_r p_theta")
    assert sp.simplify(H - (p_r**2 / (2 * m) + p_theta**2 / (2 * m * r**2) - k / r)) == 0


def test_kepler_orbit_closes_and_conserves_angular_momentum():
    system, _, _ = kepler()
    values = {"m": 1.0, "k": 1.0}
    r0, speed = 1.0, 1.2
    a = -values["k"] / (2 * (0.5 * speed**2 - values["k"] / r0))
    period = 2 * np.pi * np.sqrt(a**3 * values["m"] / values["k"])
    orbit = mb.simulate(system.numeric(**values), np.array([r0, 0.0]), np.array([0.0, speed / r0]), period,
                        dt=period / 200, method="DOP853", rtol=1e-12, atol=1e-14)
    assert abs(orbit.q[-1, 0] - r0) < 1e-8
    assert abs(orbit.q[-1, 1] - 2 * np.pi) < 1e-8
    p_theta = values["m"] * orbit.q[:, 0] ** 2 * orbit.v[:, 1]
    assert np.ptp(p_theta) < 1e-10


def test_hamiltonian_is_constant_and_hamilton_matches_lagrange():
    system, _, _ = kepler()
    values = {"m": 1.0, "k": 1.0}
    flow, momentum = system.hamiltonian_flow(**values)
    q0, v0 = np.array([1.0, 0.0]), np.array([0.1, 1.1])
    duration = 6.0
    lagrange = mb.simulate(system.numeric(**values), q0, v0, duration, dt=0.1, method="DOP853", rtol=1e-12, atol=1e-14)
    hamilton = solve_ivp(flow, (0.0, duration), np.concatenate([q0, momentum(q0, v0)]), method="DOP853",
                         rtol=1e-12, atol=1e-14, dense_output=True)
    assert np.abs(hamilton.sol(lagrange.t)[:2].T - lagrange.q).max() < 1e-9
    # H(q, p) along the Lagrangian trajectory
    r_, th_, p_r, p_th = sp.symbols("r_ th_ p_r p_theta")
    r, theta = system.q
    H = sp.lambdify([r_, p_r, p_th], system.hamiltonian().subs({m: 1.0, k: 1.0}).subs(r, r_))
    p = np.array([momentum(q, v) for q, v in zip(lagrange.q, lagrange.v)])
    energies = H(lagrange.q[:, 0], p[:, 0], p[:, 1])
    assert np.ptp(energies) / abs(energies[0]) < 1e-9
    np.testing.assert_allclose(energies, lagrange.energy, rtol=1e-12)


def test_symbolic_double_pendulum_equals_the_urdf_engine():
    numeric = double_pendulum().numeric(g=9.81)
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(0)
    for _ in range(10):
        q, v = rng.uniform(-np.pi, np.pi, 2), rng.standard_normal(2)
        np.testing.assert_allclose(numeric.mass_matrix(q), mb.mass_matrix(model, q), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(numeric.bias_forces(q, v), mb.bias_forces(model, q, v), rtol=1e-12, atol=1e-12)


def test_symbolic_pendulum_equals_the_urdf_engine():
    theta = dynamicsymbols("theta")
    # The shipped pendulum: a 1 kg point mass 1 m below a pivot about +y: U = −m g l cos θ.
    numeric = mb.LagrangianSystem([theta], m * l**2 * theta.diff() ** 2 / 2, -m * g * l * sp.cos(theta)).numeric(
        m=1.0, l=1.0, g=9.81)
    model = mb.robots.load("pendulum")
    for angle, rate in [(0.3, 1.0), (-2.0, 0.5), (3.0, -4.0)]:
        q, v = np.array([angle]), np.array([rate])
        np.testing.assert_allclose(numeric.mass_matrix(q), mb.mass_matrix(model, q), rtol=1e-12)
        np.testing.assert_allclose(numeric.bias_forces(q, v), mb.bias_forces(model, q, v), rtol=1e-12, atol=1e-12)


def test_generalized_forces_from_cartesian_ones():
    """Q_k = Σ F·∂x/∂q_k: gravity on the pendulum bob gives −∂U/∂θ; linear drag gives −c l² θ̇."""
    theta = dynamicsymbols("theta")
    c = sp.symbols("c", positive=True)
    bob = sp.Matrix([l * sp.sin(theta), 0, -l * sp.cos(theta)])
    gravity = sp.Matrix([0, 0, -m * g])
    drag = -c * bob.diff(t)
    Q_gravity, = mb.generalized_forces([theta], [bob], [gravity])
    assert sp.simplify(Q_gravity + m * g * l * sp.sin(theta)) == 0
    Q_drag, = mb.generalized_forces([theta], [bob], [drag])
    assert sp.simplify(Q_drag + c * l**2 * theta.diff()) == 0
    damped = mb.LagrangianSystem([theta], m * l**2 * theta.diff() ** 2 / 2, -m * g * l * sp.cos(theta), forces=[Q_drag])
    trajectory = mb.simulate(damped.numeric(m=1.0, l=1.0, g=9.81, c=0.3), np.array([1.0]), np.array([0.0]), 5.0,
                             method="DOP853", rtol=1e-10, atol=1e-12)
    assert np.all(np.diff(trajectory.energy) <= 1e-12)  # drag only ever takes energy out
    assert trajectory.energy[-1] < 0.5 * trajectory.energy[0] + 0.5 * (-9.81)


def test_symbolic_constraints_feed_the_same_solver():
    """A particle on a circle written as a symbolic holonomic constraint: tension m g cos θ + m l θ̇²."""
    x, z = dynamicsymbols("x z")
    particle = mb.LagrangianSystem([x, z], m / 2 * (x.diff() ** 2 + z.diff() ** 2), m * g * z)
    circle = particle.holonomic(x**2 + z**2 - l**2, l=0.8)
    system = mb.ConstrainedSystem(particle.numeric(m=1.0, g=9.81), [circle])
    theta, rate = 0.6, 1.5
    q = 0.8 * np.array([np.sin(theta), -np.cos(theta)])
    v = 0.8 * rate * np.array([np.cos(theta), np.sin(theta)])
    a, lam = system.forward_dynamics(q, v)
    # ∇φ = 2x: the force is 2 λ x, pointing inwards with magnitude tension = −2 λ l
    tension = -2 * lam[0] * 0.8
    assert tension == pytest.approx(9.81 * np.cos(theta) + 0.8 * rate**2, rel=1e-12)
    # the same rows as a Pfaffian: x ẋ + z ż = 0
    rows = particle.pfaffian([[x, z]])
    system2 = mb.ConstrainedSystem(particle.numeric(m=1.0, g=9.81), [rows])
    np.testing.assert_allclose(system2.forward_dynamics(q, v)[0], a, rtol=1e-12, atol=1e-12)


def test_bad_input_is_refused_clearly():
    with pytest.raises(ValueError, match="not a function of time"):
        mb.LagrangianSystem([sp.Symbol("x")], 0)
    x = dynamicsymbols("x")
    with pytest.raises(ValueError, match="not quadratic"):
        mb.LagrangianSystem([x], x.diff() ** 4).hamiltonian()
    with pytest.raises(ValueError, match="not positive definite"):
        mb.LagrangianSystem([x], -x.diff() ** 2).hamiltonian()
    y = dynamicsymbols("y")
    with pytest.raises(ValueError, match="singular"):
        mb.LagrangianSystem([x, y], (x.diff() + y.diff()) ** 2).hamiltonian()
    system, _, _ = kepler()
    with pytest.raises(ValueError, match=r"missing value for parameter\(s\) \['k'\]"):
        system.numeric(m=1.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        system.numeric(m=1.0, k=1.0, mass=2.0)
    with pytest.raises(ValueError, match="one generalized force per coordinate"):
        mb.LagrangianSystem([x], x.diff() ** 2, forces=[0, 0])
