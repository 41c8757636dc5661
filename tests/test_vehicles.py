"""The vehicle examples (examples/ackermann_car.py, examples/unicycle.py, examples/cartpole_lqr.py), on
short runs: the car's circle and the balance of its wheel forces, the unicycle's equations of motion
along its simulated motion, and LQR through ``linearize``."""

import os
import runpy

import numpy as np
import pytest
import scipy.linalg

import multibody as mb

EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")
EPS = np.finfo(float).eps


def example(name):
    """The functions of ``examples/<name>.py`` (run without its ``__main__`` part)."""
    return runpy.run_path(os.path.join(EXAMPLES, f"{name}.py"))


@pytest.fixture(scope="module")
def car():
    return example("ackermann_car")


# ============================================================================= the Ackermann car

def test_ackermann_angles_meet_at_the_centre_of_the_turn(car):
    dimensions = car["Car"]()
    inner, outer = dimensions.ackermann_angles(10.0)
    # cot δ_outer − cot δ_inner = w / L, and the inner wheel's axle passes through (0, R)
    assert 1 / np.tan(outer) - 1 / np.tan(inner) == pytest.approx(dimensions.track / dimensions.wheelbase, rel=1e-14)
    assert dimensions.wheelbase * np.tan(np.pi / 2 - inner) == pytest.approx(10.0 - dimensions.track / 2, rel=1e-14)
    with pytest.raises(ValueError, match="radius must exceed half the track"):
        dimensions.ackermann_angles(0.5)


def test_fit_circle_recovers_centre_and_radius(car):
    angle = np.linspace(0.3, 2.0, 40)
    centre, radius = car["fit_circle"](np.column_stack([1.5 + 4.0 * np.cos(angle), -2.0 + 4.0 * np.sin(angle)]))
    np.testing.assert_allclose(centre, [1.5, -2.0], atol=1e-12)
    assert radius == pytest.approx(4.0, rel=1e-13)


def test_car_drives_its_ackermann_circle_and_the_wheel_forces_give_the_centripetal_force(car):
    """At constant speed v on the circle of radius R about c = (0, R), the middle of the rear axle stays at
    R from c and turns at ω = v/R; the ground's forces on the four wheels (their RollingDisc multipliers)
    sum to the weight, m g, upwards and to m ω² (c − x_G) horizontally, the centripetal force of the
    centre of mass, whose magnitude is m v_G² / R_G."""
    radius, speed = 10.0, 5.0
    system, q0, v0 = car["circle_setup"](car["Car"](), radius, speed)
    assert system.num_rows == 14 and system.rank(q0) == 11          # the redundant rows are there
    run = dict(dt=0.1, method="DOP853")
    trajectory = mb.simulate(system, q0, v0, 3.0, rtol=1e-10, atol=1e-12, **run)
    reference = mb.simulate(system, q0, v0, 3.0, rtol=1e-12, atol=1e-14, **run)
    # the integrator's error: the distance to the run at 100 times tighter tolerances, and the rounding of x, y
    error = np.abs(trajectory.q[:, :2] - reference.q[:, :2]).max() + 100 * EPS * radius
    xy = trajectory.q[:, :2]
    centre = np.array([0.0, radius])
    assert np.abs(np.linalg.norm(xy - centre, axis=1) - radius).max() <= 10 * error
    turned = np.unwrap(np.arctan2(xy[:, 1] - radius, xy[:, 0])) + np.pi / 2
    assert np.abs(turned - speed / radius * trajectory.t).max() <= 10 * error / radius
    fitted_centre, fitted_radius = car["fit_circle"](xy)
    assert np.abs(fitted_centre - centre).max() <= 10 * error and abs(fitted_radius - radius) <= 10 * error
    assert np.ptp(turned) > 1.4                                                   # over 1.4 rad of arc

    model = system.model
    mass, g = model.total_mass, np.linalg.norm(model.gravity)
    forces = car["wheel_forces"](system, trajectory)
    total = forces["world"].sum(axis=1)
    x_G = mb.center_of_mass(model, trajectory.q)
    centripetal = mass * (speed / radius) ** 2 * (centre - x_G[:, :2])
    # forces are smooth in the state: their relative error is that of the positions over the car's size
    relative = 10 * error / car["Car"]().wheelbase
    np.testing.assert_allclose(total[:, :2], centripetal, rtol=0, atol=relative * np.abs(centripetal).max())
    np.testing.assert_allclose(total[:, 2], mass * g, rtol=relative)
    v_G = np.linalg.norm(mb.center_of_mass_velocity(model, trajectory.q, trajectory.v)[:, :2], axis=1)
    radius_G = np.linalg.norm(x_G[:, :2] - centre, axis=1)
    np.testing.assert_allclose(np.linalg.norm(total[:, :2], axis=1), mass * v_G**2 / radius_G, rtol=relative)
    # every wheel carries load and pushes towards the centre; none drives
    assert (forces["normal"] > 0).all() and (forces["lateral"] > 0).all()
    assert np.abs(forces["longitudinal"]).max() <= relative * np.abs(centripetal).max()


def test_a_driven_car_stays_on_its_circle_and_its_turn_rate_grows_as_the_power_balance_says(car):
    """From rest, torque τ on each rear wheel: the wheels roll at ω (R ∓ w/2) / r, so the power is
    2 τ ω R / r, and with the kinetic energy ½ J ω² (J constant along the circle) the turn rate grows
    as ω̇ = 2 τ R / (r J). Newton's law for the car: Σ F + m g = m (ω̇ ẑ × ρ − ω² ρ), ρ = x_G − c."""
    dimensions, radius, torque = car["Car"](), 10.0, 250.0
    system, q0, v0 = car["circle_setup"](dimensions, radius, speed=0.0)
    _, q1, v1 = car["circle_setup"](dimensions, radius, speed=radius)            # turning at 1 rad/s
    model = system.model
    J = 2.0 * mb.kinetic_energy(model, q1, v1)
    turn_acceleration = 2.0 * torque * radius / (dimensions.wheel_radius * J)
    run = dict(drive_time=2.0, coast_time=0.5, dt=0.1)
    trajectory, tau = car["drive"](system, q0, v0, torque, rtol=1e-10, **run)
    reference, _ = car["drive"](system, q0, v0, torque, rtol=1e-12, **run)
    driving = trajectory.t <= 2.0
    omega = trajectory.v[:, 5]                            # the chassis stays level: its yaw rate
    # the integrator's error relative to the motion: the distance to the run at 100 times tighter tolerances
    scale = turn_acceleration * 2.0
    estimate = (np.abs(omega - reference.v[:, 5]).max() / scale
                + np.abs(trajectory.q[:, :2] - reference.q[:, :2]).max() / radius + 100 * EPS)
    assert np.abs(omega[driving] - turn_acceleration * trajectory.t[driving]).max() <= 10 * estimate * scale
    assert np.ptp(omega[~driving]) <= 10 * estimate * scale                        # coasting: constant
    centre = np.array([0.0, radius])
    assert np.abs(np.linalg.norm(trajectory.q[:, :2] - centre, axis=1) - radius).max() <= 10 * estimate * radius

    forces = car["wheel_forces"](system, trajectory)
    rho = mb.center_of_mass(model, trajectory.q)[:, :2] - centre
    rate = np.where(driving, turn_acceleration, 0.0)[:, None]
    expected = model.total_mass * (rate * np.column_stack([-rho[:, 1], rho[:, 0]]) - omega[:, None] ** 2 * rho)
    total = forces["world"].sum(axis=1)
    np.testing.assert_allclose(total[:, :2], expected, rtol=0, atol=10 * estimate * np.abs(expected).max())
    # the drive shows on the rear wheels only while it lasts
    rear = forces["longitudinal"][:, :2]
    assert (rear[driving] > 0.5 * torque / dimensions.wheel_radius).all()
    assert np.abs(rear[~driving]).max() <= 10 * estimate * np.abs(expected).max()
    np.testing.assert_array_equal(car["drive_torque"](trajectory, 2.0, tau)[~driving], 0.0)


# ============================================================================= the unicycle

@pytest.fixture(scope="module")
def unicycle():
    return example("unicycle")


@pytest.fixture(scope="module")
def pedalled(unicycle):
    """One second at 6 m/s under the pitch feedback, outputs every 2 ms, and the pedals' torques."""
    h = 0.002
    system, feedback, trajectory = unicycle["ride"](unicycle["Unicycle"](), 6.0, 1.0, dt=h, rtol=1e-11)
    tau = np.array([feedback(t, q, v) for t, q, v in zip(trajectory.t, trajectory.q, trajectory.v)])
    return system, trajectory, tau, h


def simpson(f, h):
    """∫ f dt from the first sample to every other one, ``f (n,)`` sampled ``h`` apart, by the composite
    Simpson rule: ``W₂ₖ₊₂ = W₂ₖ + h/3 (f₂ₖ + 4 f₂ₖ₊₁ + f₂ₖ₊₂)``; ``(n // 2 + 1,)`` for odd ``n``, the last
    sample dropped for even ``n``."""
    pairs = (len(f) - 1) // 2
    steps = h / 3 * (f[0 : 2 * pairs : 2] + 4 * f[1 : 2 * pairs : 2] + f[2 : 2 * pairs + 1 : 2])
    return np.concatenate([[0.0], np.cumsum(steps)])


def test_yaw_lean_pitch_reads_the_angles_of_rz_rx_ry(unicycle):
    yaw, lean, pitch = 0.7, -0.3, 0.2
    R = (mb.spatial.axis_angle_rotation([0, 0, 1], yaw) @ mb.spatial.axis_angle_rotation([1, 0, 0], lean)
         @ mb.spatial.axis_angle_rotation([0, 1, 0], pitch))
    np.testing.assert_allclose(unicycle["yaw_lean_pitch"](mb.spatial.rotation_to_quat(R)), [yaw, lean, pitch],
                               atol=1e-14)


def test_unicycle_motion_satisfies_its_equations_with_the_recorded_contact_forces(pedalled):
    """Along the pedalled ride, M v̇ + h = τ + Aᵀ λ with v̇ from central differences of the recorded
    velocities and λ the recorded multipliers: the residual stays within ten times the differences'
    error, estimated per state by Richardson's comparison with the differences over twice the step
    (error ≈ |D_h − D_2h| / 3). The KKT solution at each recorded state gives the recorded λ, and
    satisfies the equations to the rounding of their terms."""
    system, trajectory, tau, h = pedalled
    model = system.model
    M, bias = mb.mass_matrix(model, trajectory.q), mb.bias_forces(model, trajectory.q, trajectory.v)
    A = system.jacobian(trajectory.q)
    a_h = (trajectory.v[2:] - trajectory.v[:-2]) / (2 * h)
    a_2h = (trajectory.v[4:] - trajectory.v[:-4]) / (4 * h)
    inner = slice(2, -2)                                   # the states with both differences
    residual = (np.einsum("nij,nj->ni", M[inner], a_h[1:-1]) + bias[inner] - tau[inner]
                - np.einsum("nji,nj->ni", A[inner], trajectory.lam[inner]))
    error = np.abs(M[inner]).sum(axis=2).max(axis=1) * np.abs(a_h[1:-1] - a_2h).max(axis=1) / 3
    assert (np.abs(residual).max(axis=1) <= 10 * error).all()
    assert np.median(10 * error) < 1e-2                   # a bound well below the forces (~700 N) over most of the ride

    a, lam = system.forward_dynamics(trajectory.q, trajectory.v, tau)
    np.testing.assert_array_equal(lam, trajectory.lam)
    kkt = np.einsum("nij,nj->ni", M, a) + bias - tau - np.einsum("nji,nj->ni", A, lam)
    terms = (np.abs(M).max() * np.abs(a).max() + np.abs(bias).max() + np.abs(tau).max()
             + np.abs(A).max() * np.abs(lam).max())
    assert np.abs(kkt).max() <= 10 * EPS * terms


def test_unicycle_stays_on_the_ground_and_its_energy_changes_by_the_pedals_work(pedalled, unicycle):
    """The rolling rows hold to what the step ends' projection leaves (its tolerance, 1e-12 m or m/s per
    coordinate, times the rows' largest absolute row sum); the contact point stays on the ground with a
    positive normal force; the rolling forces do no work, so E(t) − E(0) = ∫ τ_axle v_axle dt (Simpson's
    rule, its error estimated by Richardson's comparison with the rule over twice the step)."""
    system, trajectory, tau, h = pedalled
    A = system.jacobian(trajectory.q)
    assert trajectory.residual.max() <= 10 * trajectory.projection_tolerance * np.abs(A).sum(axis=2).max()
    (contact,) = system.constraints
    heights = np.array([contact.contact_point(system.model, q)[2] for q in trajectory.q])
    assert np.abs(heights).max() <= 10 * trajectory.projection_tolerance * np.abs(A).sum(axis=2).max()
    assert (trajectory.lam[:, 2] > 0).all()
    axle = system.model.idx_v[system.model.joint_index("axle")]
    power = tau[:, axle] * trajectory.v[:, axle]
    work = simpson(power, h)
    coarse = simpson(power[::2], 2 * h)
    error = np.abs(work[::2][: len(coarse)] - coarse).max() / 15 + 100 * EPS * np.abs(trajectory.energy).max()
    gained = (trajectory.energy - trajectory.energy[0])[::2][: len(work)]
    assert np.abs(gained - work).max() <= 10 * error
    assert abs(work[-1]) > 100 * 10 * error                     # the pedals do work worth checking


def test_unicycle_falls_to_the_side_slowly_and_weaves_fast(unicycle):
    """The pedals hold the pitch only: at 2 m/s the lean grows until the ride stops at 0.6 rad; at 6 m/s the
    lean stays below 0.15 rad while the pitch settles."""
    slow = unicycle["ride"](unicycle["Unicycle"](), 2.0, 2.0, dt=0.02)[2]
    fast = unicycle["ride"](unicycle["Unicycle"](), 6.0, 4.0, dt=0.02)[2]
    slow_angles, fast_angles = (unicycle["yaw_lean_pitch"](t.q[:, 3:7]) for t in (slow, fast))
    assert slow.t[-1] < 2.0 and 0.5 < np.abs(slow_angles[:, 1]).max() <= 0.6
    assert fast.t[-1] == pytest.approx(4.0) and np.abs(fast_angles[:, 1]).max() < 0.15
    assert np.abs(fast_angles[len(fast.t) // 2:, 2]).max() < 0.2 * abs(fast_angles[0, 2])


# ============================================================================= LQR through linearize

@pytest.fixture(scope="module")
def lqr():
    return example("cartpole_lqr")


def test_lqr_gain_of_the_double_integrator(lqr):
    """``ẍ = u`` with ``Q = I``, ``R = 1``: the Riccati solution is ``X = [[√3, 1], [1, √3]]`` (``Aᵀ X + X A − X B Bᵀ X
    + Q = 0`` entry by entry), so ``K = Bᵀ X = [1, √3]`` and the closed loop ``s² + √3 s + 1`` is damped."""
    A, B = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])
    K, closed_loop = lqr["lqr"](A, B, np.eye(2), np.eye(1))
    np.testing.assert_allclose(K, [[1.0, np.sqrt(3.0)]], rtol=1e-14)
    np.testing.assert_array_equal(closed_loop, A - B @ K)


def test_cart_pole_lqr_takes_the_linearization_as_given(lqr):
    """The cart-pole of the URDF string is linearized by ``mb.linearize`` at its upright equilibrium; the
    gain is the Riccati gain of exactly that ``A`` and the cart's column of ``B``, and it makes every
    closed-loop eigenvalue's real part negative."""
    model = lqr["cart_pole"]()
    assert model.joint_names == ("slide", "hinge")
    rest = np.zeros(model.nv)
    np.testing.assert_array_equal(mb.forward_dynamics(model, model.neutral(), rest, rest), 0.0)   # upright: at rest
    Q, R = np.diag([10.0, 100.0, 1.0, 10.0]), np.array([[0.1]])
    linearization, cart, K, closed_loop = lqr["cart_pole_regulator"](model, Q, R)
    given = mb.linearize(model, model.neutral(), rest, rest)
    np.testing.assert_array_equal(linearization.A, given.A)
    np.testing.assert_array_equal(linearization.B, given.B)
    assert cart == model.idx_v[model.joint_index("slide")]
    B = given.B[:, [cart]]
    X = scipy.linalg.solve_continuous_are(given.A, B, Q, R)
    np.testing.assert_allclose(K, B.T @ X / R[0, 0], rtol=1e-12)
    np.testing.assert_array_equal(closed_loop, given.A - B @ K)
    assert np.linalg.eigvals(closed_loop).real.max() < 0
    assert np.linalg.eigvals(given.A).real.max() > 1.0                 # the upright pole alone falls


@pytest.mark.parametrize("tilt", [0.05, 0.3])
def test_cart_pole_closed_loop_decays_within_its_eigenvalue_bound(lqr, tilt):
    """The nonlinear closed loop from the pole tipped by ``tilt``: the minimal coordinates' norm stays below
    the linear closed loop's bound ``κ e^{α t} |x(0)|`` (``α`` the largest real part of its eigenvalues, ``κ``
    the condition number of its eigenvectors) over 4 s, and the pole ends upright, the cart back, at rest."""
    model, controller, closed_loop, trajectory, states, forces = lqr["balance_cart_pole"](tilt=tilt, duration=4.0,
                                                                                          dt=0.02)
    alpha, kappa = lqr["decay_bound"](closed_loop)
    assert alpha < 0
    norms = np.linalg.norm(states, axis=1)
    assert norms[0] == pytest.approx(tilt, rel=1e-12)
    assert (norms <= kappa * np.exp(alpha * trajectory.t) * norms[0]).all()
    assert norms[-1] < 0.1 * norms[0]
    # the regulator's state is the deviation from the upright at rest in these coordinates
    np.testing.assert_allclose(states, np.concatenate([trajectory.q, trajectory.v], axis=1), rtol=0, atol=1e-15)


def test_regulated_subspace_drops_uncontrollable_modes_and_symmetry_shifts(lqr):
    """A pendulum (x₁, ẋ₁ = x₂, ẋ₂ = 2 x₁ − u) on a cart (ẋ₄ = x₅, ẋ₅ = u) beside an uncontrollable x₃:
    the controllable subspace is span(x₁, x₂, x₄, x₅); the cart's place x₄, which A ignores, is dropped
    from the regulated coordinates, which span x₁, x₂, x₅."""
    A = np.zeros((5, 5))
    A[0, 1], A[1, 0], A[2, 2], A[3, 4] = 1.0, 2.0, -1.0, 1.0
    B = np.array([[0.0], [-1.0], [0.0], [0.0], [1.0]])
    T_c = lqr["controllable_subspace"](A, B)
    assert T_c.shape == (5, 4)
    np.testing.assert_allclose(T_c[2], 0.0, atol=1e-15)
    T = lqr["regulated_subspace"](A, B)
    assert T.shape == (5, 3)
    np.testing.assert_allclose(T.T @ T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(T[[2, 3]], 0.0, atol=1e-14)


def test_unicycle_modes_and_lqr_pedals(lqr):
    """``ConstrainedSystem.linearize`` of the unicycle rolling upright: the pitch falls at either speed
    (a real pair ±7.45 1/s), the lean falls at 2 m/s (a real pair) and weaves at 6 m/s (an imaginary pair):
    what examples/unicycle.py shows. The LQR pedals regulate three coordinates (pitch, its rate, speed) and
    make them decay."""
    rates = {}
    for speed in (2.0, 6.0):
        _, system, linearization, T, K, closed_loop, _ = lqr["unicycle_regulator"](speed)
        assert (linearization.p, linearization.k) == (6, 4)
        eigenvalues = np.linalg.eigvals(linearization.A)
        scale = np.abs(eigenvalues).max()
        rates[speed] = eigenvalues[np.abs(eigenvalues) > 1e-6 * scale]
        assert T.shape == (10, 3) and np.linalg.eigvals(closed_loop).real.max() < 0
    assert np.sum(rates[2.0].real > 1e-6) == 2 and np.abs(rates[2.0].imag).max() < 1e-6
    assert np.sum(rates[6.0].real > 1e-6) == 1 and np.sum(np.abs(rates[6.0].imag) > 1.0) == 2


def test_unicycle_lqr_closed_loop_decays_within_its_eigenvalue_bound_without_lean(lqr):
    """From a pitch of 0.05 rad without lean the motion stays in the plane of the wheel and the regulated
    coordinates follow the closed loop's bound ``κ e^{α t} |y(0)|``; with a lean of 0.02 rad the lean weaves,
    its second-order terms stir the pitch, and the pedals hold it within a fifth of its start after 1 s."""
    controller, closed_loop, trajectory, angles, _ = lqr["ride_with_lqr"](lean=0.0, duration=3.0, dt=0.02)
    alpha, kappa = lqr["decay_bound"](closed_loop)
    regulated = np.array([controller.gain_basis.T @ controller.state(t, q, v)
                          for t, q, v in zip(trajectory.t, trajectory.q, trajectory.v)])
    norms = np.linalg.norm(regulated, axis=1)
    assert np.abs(angles[:, 1]).max() == 0.0
    assert (norms <= kappa * np.exp(alpha * trajectory.t) * norms[0]).all()
    _, _, trajectory, angles, _ = lqr["ride_with_lqr"](lean=0.02, duration=3.0, dt=0.02)
    assert np.abs(angles[:, 1]).max() > 0.05                              # the lean is not held
    assert np.abs(angles[trajectory.t >= 1.0, 2]).max() < 0.2 * abs(angles[0, 2])   # held near upright


# ============================================================================= the examples' figures

@pytest.mark.parametrize("name, figures", [("ackermann_car", ["ackermann_car_forces", "ackermann_car_path"]),
                                           ("unicycle", ["unicycle"]),
                                           ("cartpole_lqr", ["cartpole_lqr", "unicycle_lqr"])])
def test_example_writes_its_figures(name, figures, tmp_path):
    # The gallery's figures, written by each example's main as its command line runs it (a few seconds each).
    example(name)["main"](str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{figure}.png" for figure in figures]
    assert all(p.stat().st_size > 0 for p in tmp_path.iterdir())
