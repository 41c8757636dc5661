"""The vehicle examples (examples/ackermann_car.py, examples/unicycle.py, examples/cartpole_lqr.py), on
short runs: the car's circle and the balance of its wheel forces, the unicycle's equations of motion
along its simulated motion, and LQR through ``linearize``."""

import os
import runpy
import warnings

import numpy as np
import pytest

import multibody as mb

EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")
EPS = np.finfo(float).eps


def example(name):
    """The functions of ``examples/<name>.py`` (run without its ``__main__`` part)."""
    return runpy.run_path(os.path.join(EXAMPLES, f"{name}.py"))


@pytest.fixture(scope="module")
def car():
    return example("ackermann_car")


def simulate_quietly(*args, **kw):
    # the car's four wheels repeat rows by design (examples/ackermann_car.py)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mb.RankDeficientWarning)
        return mb.simulate(*args, **kw)


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
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mb.RankDeficientWarning)
        system, q0, v0 = car["circle_setup"](car["Car"](), radius, speed)
    assert system.num_rows == 14 and system.rank(q0) == 11          # the redundant rows are there
    run = dict(dt=0.1, method="DOP853")
    trajectory = simulate_quietly(system, q0, v0, 3.0, rtol=1e-10, atol=1e-12, **run)
    reference = simulate_quietly(system, q0, v0, 3.0, rtol=1e-12, atol=1e-14, **run)
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
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mb.RankDeficientWarning)
        system, q0, v0 = car["circle_setup"](dimensions, radius, speed=0.0)
        _, q1, v1 = car["circle_setup"](dimensions, radius, speed=radius)        # turning at 1 rad/s
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
