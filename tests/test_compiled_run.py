"""The compiled fixed-step run of ``mb.simulate`` (``multibody.kernels.stepping``, ``multibody.integrators``).

Each fixed-step method has its order on problems with a closed form; the compiled run gives the numbers of the
Python loop (``simulate`` with the compiled run switched off) on an open chain, a rolling ball and a projected
four-bar, for every controller (none, constant, ``mb.PD``, a ``numba.njit`` function, a Python callable) and with
joint damping; ``mb.PD`` and compiled controllers equal the same law as a Python callable; reference tables are
interpolated as documented; bad controllers are refused by name; batches equal their trajectories alone; and every
way a run stops reaches the message the Python loop gives.
"""

from __future__ import annotations

import dataclasses
import re

import numba
import numpy as np
import pytest
from scipy.special import ellipj, ellipk

import multibody as mb
from multibody import integrators, runs, simulation
from multibody.kernels import stepping

from constraint_helpers import crank_state, parallelogram_chain, particle_model, planar_closures
from test_simulation_batched import ball_system, random_states

FIXED = ("Euler", "semi-implicit Euler", "RK4")


@pytest.fixture
def python_loop(monkeypatch):
    """``simulate`` without the compiled run: every step by the Python loop (the path before the run existed)."""
    def switch_off():
        monkeypatch.setattr(simulation, "_compiled_run", lambda *arguments, **options: None)
    return switch_off


@pytest.fixture
def statuses(monkeypatch):
    """The statuses that compiled runs return, recorded (a check that the compiled run took the steps)."""
    seen = []
    advance, advance_batch = integrators.CompiledRun.advance, integrators.CompiledRun.advance_batch

    def recorded(self, *arguments, **options):
        k, status = advance(self, *arguments, **options)
        seen.append(status)
        return k, status

    def recorded_batch(self, states, io, rows, threads=None):
        advance_batch(self, states, io, rows, threads)
        seen.extend(int(io[r, stepping.IO_STATUS]) for r in rows)

    monkeypatch.setattr(integrators.CompiledRun, "advance", recorded)
    monkeypatch.setattr(integrators.CompiledRun, "advance_batch", recorded_batch)
    return seen


def both(python_loop, *arguments, **options):
    """``mb.simulate(*arguments, **options)`` by the compiled run, and by the Python loop."""
    compiled = mb.simulate(*arguments, **options)
    python_loop()
    return compiled, mb.simulate(*arguments, **options)


def assert_same(a, b, tol=1e-12, names=("q", "v", "lam", "energy", "residual")):
    """Every array of two trajectories to ``tol`` of its size (absolute below 1)."""
    np.testing.assert_array_equal(a.t, b.t)
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        scale = max(1.0, float(np.abs(y).max(initial=0.0)))
        assert np.abs(x - y).max(initial=0.0) <= tol * scale, (name, np.abs(x - y).max())


def panda():
    model = mb.robots.load("panda")
    return model, model.neutral() + 0.1, np.linspace(-0.5, 0.5, model.nv)


# ============================================================================= orders of the methods


def oscillator(mass=1.0):
    """A mass on a horizontal slider (x, m): with the spring ``τ = −k x`` of ``mb.PD(k, 0, 0)`` a harmonic
    oscillator of ``ω² = k / m``."""
    builder = mb.ModelBuilder("oscillator")
    builder.add_body("mass", mb.joints.Prismatic((1.0, 0.0, 0.0)), inertia=mb.inertia.point_mass(mass))
    return builder.build()


def observed_orders(errors):
    return [float(np.log2(a / b)) for a, b in zip(errors, errors[1:])]


@pytest.mark.parametrize("method", FIXED)
def test_each_method_has_its_order_on_the_harmonic_oscillator(method):
    """x(t) = x₀ cos ωt: the largest error over one period halves (order 1) or falls 16-fold (order 4) as the
    step halves; Euler and semi-implicit Euler are order 1, RK4 order 4."""
    model, k, x0 = oscillator(), 4.0, 0.3
    omega = np.sqrt(k)
    period = 2 * np.pi / omega
    errors = []
    for steps in (64, 128, 256):
        trajectory = mb.simulate(model, [x0], [0.0], period, dt=period / steps, method=method,
                                 tau=mb.PD(k, 0.0, [0.0]), limits="ignore")
        exact = np.stack([x0 * np.cos(omega * trajectory.t), -x0 * omega * np.sin(omega * trajectory.t)], axis=1)
        errors.append(np.abs(np.concatenate([trajectory.q, trajectory.v], axis=1) - exact).max())
    order = integrators.TABLEAUS[method].order
    assert np.allclose(observed_orders(errors), order, atol=0.1), observed_orders(errors)


def test_rk4_has_order_four_on_the_pendulum_through_the_chart():
    """The pendulum released from rest at 2 rad, θ(t) = 2 arcsin(k sn(K − ω₀t | k²)), k = sin(θ₀/2): the largest
    error of RK4 over 2 s falls 16-fold as the step halves."""
    model = mb.robots.load("pendulum")
    theta0 = 2.0
    # ω₀² = g(π/2) / M: the pendulum's M is constant, its gravity torque c sin θ
    omega0 = np.sqrt(mb.generalized_gravity(model, [np.pi / 2])[0] / mb.mass_matrix(model, [0.0])[0, 0])
    m = np.sin(theta0 / 2) ** 2
    errors = []
    for dt in (0.01, 0.005, 0.0025):
        trajectory = mb.simulate(model, [theta0], [0.0], 2.0, dt=dt, method="RK4", limits="ignore")
        sn = ellipj(ellipk(m) - omega0 * trajectory.t, m)[0]
        errors.append(np.abs(trajectory.q[:, 0] - 2 * np.arcsin(np.sqrt(m) * sn)).max())
    assert np.allclose(observed_orders(errors), 4.0, atol=0.1), observed_orders(errors)


def test_semi_implicit_euler_keeps_the_oscillators_energy_where_euler_gains_it():
    """Over 200 periods at hω ≈ 0.1: the symplectic semi-implicit Euler's energy oscillates within hω of its
    start, as much in the last 20 periods as in the first 20 (no drift; its modified energy is conserved);
    explicit Euler's grows by (1 + (hω)²) each step, e^(2π·200·0.1) over the run."""
    model, k, x0 = oscillator(), 4.0, 0.3
    omega = np.sqrt(k)
    per_period = 63  # steps: hω = 2π / 63 ≈ 0.1
    h = 2 * np.pi / omega / per_period
    energy = {}
    for method in ("semi-implicit Euler", "Euler"):
        trajectory = mb.simulate(model, [x0], [0.0], 200 * per_period * h, dt=h, method=method,
                                 tau=mb.PD(k, 0.0, [0.0]), limits="ignore")
        energy[method] = (0.5 * trajectory.v[:, 0] ** 2 + 0.5 * k * trajectory.q[:, 0] ** 2) / (0.5 * k * x0 ** 2)
    symplectic = np.abs(energy["semi-implicit Euler"] - 1.0)
    first, last = symplectic[: 20 * per_period].max(), symplectic[-20 * per_period :].max()
    assert first <= h * omega and abs(last - first) <= 1e-3 * first, (first, last)
    steps = len(energy["Euler"]) - 1
    assert np.isclose(energy["Euler"][-1], (1 + (h * omega) ** 2) ** steps, rtol=1e-9)


# ============================================================================= the compiled run is the Python loop


@pytest.mark.parametrize("method", FIXED)
def test_panda_under_pd_equals_the_python_loop(python_loop, statuses, method):
    model, q0, v0 = panda()
    options = dict(dt=1e-3, method=method, tau=mb.PD(50.0, 2.0, model.neutral() + 0.3), limits="ignore")
    compiled, python = both(python_loop, model, q0, v0, 0.3, **options)
    assert statuses and set(statuses) == {stepping.COMPLETED}
    assert_same(compiled, python)


@pytest.mark.parametrize("method", FIXED)
def test_rolling_ball_equals_the_python_loop(python_loop, statuses, method):
    """A free-flyer on a tilted plane, rolling without slipping (a curved configuration space, nonholonomic rows):
    the chart maps, the constrained step and the projection at each step's end."""
    ball, system = ball_system()
    q0, v0 = system.project(*(x[0] for x in random_states(ball, system, 1, seed=3)))
    compiled, python = both(python_loop, system, q0, v0, 0.5, dt=0.01, method=method, tau=np.full(6, 0.2))
    assert statuses and set(statuses) == {stepping.COMPLETED}
    assert_same(compiled, python)


def four_bar():
    model = mb.robots.load("four_bar")
    in_plane = mb.spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))
    system = mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", frame_a=in_plane, kind="planar")])
    q0, v0 = system.project(np.array([-np.pi / 3, 0.9, -1.4]), np.array([2.0, -1.0, 0.5]))
    return model, system, q0, v0


@pytest.mark.parametrize("method", FIXED)
def test_projected_four_bar_equals_the_python_loop(python_loop, statuses, method):
    """A loop closure under a PD on the crank: the steps' ends are projected back onto the loop (the run without
    the projection drifts off it by far more than the tolerance), as the Python loop projects them."""
    model, system, q0, v0 = four_bar()
    options = dict(dt=0.01, method=method, tau=mb.PD([5.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]))
    compiled, python = both(python_loop, system, q0, v0, 1.0, **options)
    assert statuses and set(statuses) == {stepping.COMPLETED}
    assert_same(compiled, python)
    drifted = mb.simulate(system, q0, v0, 1.0, project=False, **options)
    assert drifted.residual.max() > 1e3 * compiled.residual.max()


def test_every_controller_equals_the_python_loop(python_loop, statuses):
    """No joint forces, constant ones, a PD, a compiled function and a Python callable, each with the URDF's joint
    damping (``joint_damping=True``, Panda's 0.003 N·m·s/rad) and without."""
    model, q0, v0 = panda()
    q_ref = model.neutral() + 0.3

    @numba.njit
    def compiled_pd(t, q, v, out):
        for c in range(q.shape[0]):
            out[c] = 50.0 * (q_ref[c] - q[c]) - 2.0 * v[c]

    controllers = {"none": None, "constant": np.linspace(1.0, 2.0, model.nv), "PD": mb.PD(50.0, 2.0, q_ref),
                   "njit": compiled_pd, "python": lambda t, q, v: 50.0 * (q_ref - q) - 2.0 * v}
    results = {}
    for damping in (False, True):
        for name, tau in controllers.items():
            options = dict(dt=2e-3, method="RK4", tau=tau, joint_damping=damping, limits="ignore")
            results[name, damping] = mb.simulate(model, q0, v0, 0.2, **options)
    assert set(statuses) == {stepping.COMPLETED} and len(statuses) >= len(results)
    python_loop()
    for (name, damping), compiled in results.items():
        python = mb.simulate(model, q0, v0, 0.2, dt=2e-3, method="RK4", tau=controllers[name], joint_damping=damping,
                             limits="ignore")
        assert_same(compiled, python)
    # the damping acts (Panda's URDF gives every joint 0.003 N·m·s/rad)
    assert np.abs(results["PD", True].v - results["PD", False].v).max() > 1e-6


def test_pd_and_compiled_controllers_equal_the_same_law_in_python():
    """mb.PD, and the same law as a numba.njit function, against it as a Python callable: the trajectories agree to
    1e-12 (the law's arithmetic is the same, only where it runs differs)."""
    model, q0, v0 = panda()
    kp, kd = np.linspace(40.0, 60.0, model.nv), np.linspace(1.0, 3.0, model.nv)
    q_ref, v_ref, tau_ff = model.neutral() + 0.3, np.full(model.nv, 0.1), np.linspace(-1.0, 1.0, model.nv)

    @numba.njit
    def law(t, q, v, out):
        for c in range(q.shape[0]):
            out[c] = kp[c] * (q_ref[c] - q[c]) + kd[c] * (v_ref[c] - v[c]) + tau_ff[c]

    options = dict(dt=1e-3, method="RK4", limits="ignore")
    python = mb.simulate(model, q0, v0, 0.3, tau=lambda t, q, v: kp * (q_ref - q) + kd * (v_ref - v) + tau_ff,
                         **options)
    for tau in (mb.PD(kp, kd, q_ref, v_ref, tau_ff), law):
        assert_same(mb.simulate(model, q0, v0, 0.3, tau=tau, **options), python)


def test_pd_takes_the_difference_on_the_configuration_manifold():
    """On a free-flyer, q_ref ⊖ q is model.difference(q, q_ref) (rotation vectors, body-frame translation): the
    bound controller gives kp ⊙ difference + kd ⊙ (v_ref − v) + τ_ff for one state and for a batch."""
    model = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    rng = np.random.default_rng(0)
    q, q_ref = model.random_configuration(rng, (5,)), model.random_configuration(rng)
    v, v_ref = rng.standard_normal((5, 6)), rng.standard_normal(6)
    kp, kd, tau_ff = rng.uniform(1, 2, 6), rng.uniform(0, 1, 6), rng.standard_normal(6)
    controller = mb.PD(kp, kd, q_ref, v_ref, tau_ff).bind(model)
    expected = kp * model.difference(q, q_ref) + kd * (v_ref - v) + tau_ff
    np.testing.assert_allclose(controller(0.0, q, v), expected, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(controller(0.0, q[2], v[2]), expected[2], rtol=1e-13, atol=1e-13)


# ============================================================================= reference tables


def test_reference_tables_are_interpolated_on_the_manifold_and_held_at_the_ends():
    """A free-flyer's q_ref at three times: between two rows the reference is q_i ⊕ s (q_{i+1} ⊖ q_i), v_ref the
    linear interpolation; before the first time and after the last the end rows hold. The PD law's error then
    equals model.difference(q, that reference) (kp = 1, kd = 0)."""
    model = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    rng = np.random.default_rng(1)
    t_ref = np.array([0.0, 0.5, 2.0])
    table, velocities = model.random_configuration(rng, (3,)), rng.standard_normal((3, 6))
    position = mb.PD(1.0, 0.0, table, t_ref=t_ref).bind(model)
    velocity = mb.PD(0.0, 1.0, table, velocities, t_ref=t_ref).bind(model)
    q, zero = model.random_configuration(rng), np.zeros(6)
    for t in (-1.0, 0.0, 0.2, 0.5, 1.1, 2.0, 3.0):
        i = min(max(int(np.searchsorted(t_ref, t, side="right")) - 1, 0), 1)
        s = np.clip((t - t_ref[i]) / (t_ref[i + 1] - t_ref[i]), 0.0, 1.0)
        reference = model.integrate(table[i], s * model.difference(table[i], table[i + 1]))
        np.testing.assert_allclose(position(t, q, zero), model.difference(q, reference), atol=1e-12)
        v_ref = velocities[i] + s * (velocities[i + 1] - velocities[i])
        np.testing.assert_allclose(velocity(t, q, zero), v_ref, atol=1e-14)


def test_the_law_on_a_vector_space_is_the_joint_formula_to_the_last_bit():
    """On the Panda (angles and displacements only, nq = nv) q_ref ⊖ q is q_ref − q and q_i ⊕ s (q_{i+1} ⊖ q_i) is
    q_i + (q_{i+1} − q_i) s: the law equals k_p (q_ref − q) + k_d (v_ref − v) + τ_ff in that order of operations
    bit for bit, between the rows of a table, on them and beyond its ends, and equals model.difference's error."""
    model, _, _ = panda()
    rng = np.random.default_rng(3)
    t_ref = np.array([0.0, 0.3, 1.0])
    table, velocities = model.random_configuration(rng, (3,)), rng.standard_normal((3, model.nv))
    kp, kd, tau_ff = (rng.uniform(1.0, 50.0, model.nv), rng.uniform(0.5, 5.0, model.nv),
                      rng.standard_normal(model.nv))
    law = mb.PD(kp, kd, table, velocities, tau_ff, t_ref=t_ref).bind(model)
    q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
    for t in (-0.5, 0.0, 0.1, 0.3, 0.77, 1.0, 2.0):
        i = min(max(int(np.searchsorted(t_ref, t, side="right")) - 1, 0), 1)
        s = float(np.clip((t - t_ref[i]) / (t_ref[i + 1] - t_ref[i]), 0.0, 1.0))
        q_ref = table[i] + (table[i + 1] - table[i]) * s if 0.0 < s < 1.0 else table[i if s == 0.0 else i + 1]
        v_ref = velocities[i] + s * (velocities[i + 1] - velocities[i]) if 0.0 < s < 1.0 else \
            velocities[i if s == 0.0 else i + 1]
        expected = kp * (q_ref - q) + kd * (v_ref - v) + tau_ff
        np.testing.assert_array_equal(law(t, q, v), expected)
        np.testing.assert_allclose(mb.PD(1.0, 0.0, q_ref).bind(model)(t, q, v), model.difference(q, q_ref),
                                   rtol=0.0, atol=1e-15)


def test_tracking_a_reference_table_equals_the_same_law_in_python():
    """Panda tracking a trajectory of joint angles given at 11 times (linear between them: np.interp), inside the
    compiled step, against the law as a Python callable."""
    model, q0, v0 = panda()
    t_ref = np.linspace(0.0, 0.5, 11)
    table = model.neutral() + 0.4 * np.sin(2 * np.pi * t_ref)[:, None] * np.linspace(0.2, 1.0, model.nv)
    rates = np.gradient(table, t_ref, axis=0)

    def reference(t):
        return (np.array([np.interp(t, t_ref, column) for column in table.T]),
                np.array([np.interp(t, t_ref, column) for column in rates.T]))

    def law(t, q, v):
        q_ref, v_ref = reference(t)
        return 80.0 * (q_ref - q) + 4.0 * (v_ref - v)

    options = dict(dt=1e-3, method="RK4", limits="ignore")
    tracked = mb.simulate(model, q0, v0, 0.6, tau=mb.PD(80.0, 4.0, table, rates, t_ref=t_ref), **options)
    assert_same(tracked, mb.simulate(model, q0, v0, 0.6, tau=law, **options), tol=1e-11)


# ============================================================================= bad controllers


@pytest.mark.parametrize("arguments, options, error, message", [
    ((np.nan, 1.0, np.zeros(2)), {}, ValueError, r"mb.PD: kp must be finite: kp = nan"),
    ((1.0, [1.0, np.inf], np.zeros(2)), {}, ValueError, r"mb.PD: kd must be finite: kd\[1\] = inf"),
    ((1.0, 1.0, np.zeros(2)), dict(tau_ff=[0.0, np.nan]), ValueError, r"tau_ff must be finite"),
    (("stiff", 1.0, np.zeros(2)), {}, TypeError, r"mb.PD: kp must be real numbers, got <U5"),
    ((np.ones((2, 2, 2)), 1.0, np.zeros(2)), {}, ValueError, r"kp must be a number, \(nv,\) or \(N, nv\)"),
    ((1.0, 1.0, np.zeros((3, 2))), dict(t_ref=[0.0, 1.0]), ValueError,
     r"q_ref has 3 rows but t_ref has 2 times"),
    ((1.0, 1.0, np.zeros((2, 2))), dict(t_ref=[0.0, 0.0]), ValueError,
     r"t_ref must be strictly increasing: t_ref\[0\] = 0.0 is followed by t_ref\[1\] = 0.0"),
    ((1.0, 1.0, np.zeros(2)), dict(t_ref=[0.0]), ValueError, r"with t_ref, q_ref must be a table \(n, nq\)"),
    ((1.0, 1.0, np.zeros((2, 3, 2))), {}, ValueError, r"q_ref must be \(nq,\) .*a table of references needs t_ref"),
])
def test_bad_pd_arguments_are_refused_by_name(arguments, options, error, message):
    with pytest.raises(error, match=message):
        mb.PD(*arguments, **options)


def test_pd_shapes_are_checked_against_the_system_and_the_batch():
    model = mb.robots.load("double_pendulum")
    q0, v0 = np.zeros(2), np.zeros(2)
    with pytest.raises(ValueError, match=r"mb.PD: q_ref must have shape \(2,\) .* \(nq = 2, nv = 2\), got \(3,\)"):
        mb.simulate(model, q0, v0, 0.1, method="RK4", tau=mb.PD(1.0, 1.0, np.zeros(3)))
    with pytest.raises(ValueError, match=r"mb.PD: kp must have shape \(2,\)"):
        mb.simulate(model, q0, v0, 0.1, method="RK4", tau=mb.PD([1.0, 1.0, 1.0], 1.0, np.zeros(2)))
    with pytest.raises(ValueError, match=r"kp has shape \(4, 2\), for 4 trajectories, but the simulation has one "
                                         r"initial state"):
        mb.simulate(model, q0, v0, 0.1, method="RK4", tau=mb.PD(np.ones((4, 2)), 1.0, np.zeros(2)))
    with pytest.raises(ValueError, match=r"q_ref has shape \(4, 2\), for 4 trajectories, but the simulation has 3 "
                                         r"initial states"):
        mb.simulate(model, np.zeros((3, 2)), v0, 0.1, method="RK4", tau=mb.PD(1.0, 1.0, np.zeros((4, 2))))
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    q_ref = ball.neutral()
    q_ref[3:] = [0.0, 0.0, 0.0, 2.0]
    with pytest.raises(ValueError, match="q_ref"):
        mb.simulate(ball, ball.neutral(), np.zeros(6), 0.1, method="RK4", tau=mb.PD(1.0, 1.0, q_ref))


def test_a_compiled_controller_of_the_wrong_form_is_refused_naming_tau():
    model = mb.robots.load("double_pendulum")

    @numba.njit
    def returns(t, q, v, out):
        return q

    @numba.njit
    def untyped(t, q, v, out):
        out[0] = q.undefined

    with pytest.raises(TypeError, match=r"tau: the numba.njit controller returns\(t, q, v, out\) must write the "
                                        r"joint forces into out and return nothing; it returns array"):
        mb.simulate(model, np.zeros(2), np.zeros(2), 0.1, method="RK4", tau=returns)
    with pytest.raises(TypeError, match=r"tau: the numba.njit controller untyped\(t, q, v, out\) does not compile"):
        mb.simulate(model, np.zeros(2), np.zeros(2), 0.1, method="RK4", tau=untyped)


# ============================================================================= batches


def test_a_batch_with_pd_rows_per_trajectory_equals_its_trajectories_alone(statuses):
    """Four Panda trajectories, each with its own gains and reference ((N, nv) and (N, nq) arrays), on all cores:
    each equals its own run (same arithmetic, so to the last bit)."""
    model, q0, v0 = panda()
    rng = np.random.default_rng(2)
    n = 4
    kp, q_ref = rng.uniform(20.0, 60.0, (n, model.nv)), model.neutral() + rng.uniform(-0.3, 0.3, (n, model.nv))
    starts = q0 + 0.1 * rng.standard_normal((n, model.nv))
    options = dict(dt=1e-3, method="RK4", limits="ignore")
    batch = mb.simulate(model, starts, v0, 0.2, tau=mb.PD(kp, 2.0, q_ref), **options)
    assert set(statuses) == {stepping.COMPLETED}
    for r in range(n):
        alone = mb.simulate(model, starts[r], v0, 0.2, tau=mb.PD(kp[r], 2.0, q_ref[r]), **options)
        assert_same(batch.select(r), alone, tol=0.0)


def test_pd_trajectories_keep_the_rows_of_a_part_of_the_batch():
    """``PD.trajectories(start, stop)``: the arguments given per trajectory keep their rows ``[start:stop]``, the
    shared ones stay; the part drives the trajectories ``start:stop`` of a batch as the whole PD drives them."""
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(5)
    n, t_ref = 5, np.array([0.0, 0.05, 0.1])
    kp, tau_ff = rng.uniform(5.0, 20.0, (n, 2)), rng.standard_normal((n, 2))
    q_ref, v_ref = rng.uniform(-1.0, 1.0, (n, 3, 2)), rng.standard_normal((3, 2))
    pd = mb.PD(kp, 1.5, q_ref, v_ref, tau_ff, t_ref=t_ref)
    part = pd.trajectories(1, 4)
    np.testing.assert_array_equal(part.kp, kp[1:4])
    np.testing.assert_array_equal(part.tau_ff, tau_ff[1:4])
    np.testing.assert_array_equal(part.q_ref, q_ref[1:4])
    assert part.kd is pd.kd and part.v_ref is pd.v_ref and part.t_ref is pd.t_ref
    assert pd.kp.shape == (n, 2)  # (the whole PD unchanged)
    starts, options = rng.uniform(-1.0, 1.0, (n, 2)), dict(dt=0.01, method="RK4")
    whole = mb.simulate(model, starts, np.zeros(2), 0.1, tau=pd, **options)
    some = mb.simulate(model, starts[1:4], np.zeros(2), 0.1, tau=part, **options)
    np.testing.assert_array_equal(some.q, whole.q[1:4])
    np.testing.assert_array_equal(some.v, whole.v[1:4])
    shared = mb.PD(1.0, 1.0, np.zeros(2))
    assert shared.trajectories(3, 7) is shared  # nothing per trajectory: shared by every part
    for start, stop in ((2, 6), (-1, 2), (3, 2), (0.0, 2)):
        with pytest.raises(ValueError, match=r"mb.PD.trajectories: start and stop must be integers with 0 <= start "
                                             r"<= stop <= 5 \(the trajectories of kp \(5, 2\)\)"):
            pd.trajectories(start, stop)


def test_a_batch_with_a_compiled_controller_equals_its_trajectories_alone():
    ball, system = ball_system()
    q0, v0 = system.project(*random_states(ball, system, 3, seed=4))

    @numba.njit
    def push(t, q, v, out):
        out[0] = np.sin(3.0 * t)
        out[4] = -0.2 * v[4]

    batch = mb.simulate(system, q0, v0, 0.3, dt=0.01, method="RK4", tau=push)
    for r in range(3):
        assert_same(batch.select(r), mb.simulate(system, q0[r], v0[r], 0.3, dt=0.01, method="RK4", tau=push), tol=0.0)


@pytest.fixture
def made(monkeypatch):
    """The functions :func:`multibody.numba_hooks.first_class` is asked to make first-class during a test, in
    order (it still makes them)."""
    from multibody import numba_hooks

    made = []
    first_class = numba_hooks.first_class

    def recorded(function, types):
        made.append(function)
        return first_class(function, types)

    monkeypatch.setattr(numba_hooks, "first_class", recorded)
    return made


def test_the_run_s_first_class_functions_are_made_once_and_a_controller_is_not_kept(made):
    """The driver makes the first-class value of each of multibody's functions once (about 30 µs each) however
    many runs and chunks ask for it; a user's compiled controller has its own, made once per function (a function
    defined again makes its own, and runs its own law), and the driver holds none."""
    from multibody import driver

    ball, system = ball_system()
    q0, v0 = system.project(*random_states(ball, system, 2, seed=5))

    def defined(gain):
        @numba.njit
        def push(t, q, v, out):
            out[0] = gain * np.sin(3.0 * t)
        return push

    push = defined(1.0)
    runs = [mb.simulate(system, q0, v0, 0.1, dt=0.01, method="RK4", tau=push) for _ in range(2)]
    assert_same(runs[0], runs[1], tol=0.0)
    assert made.count(push) == 1, "the controller's first-class value is made once per function"
    again = defined(-1.0)
    other = mb.simulate(system, q0, v0, 0.1, dt=0.01, method="RK4", tau=again)
    assert made.count(again) == 1, "a function defined again makes its own"
    assert not np.array_equal(other.q[:, -1], runs[0].q[:, -1]), "the function defined again runs its own law"
    assert_same(other, mb.simulate(system, q0, v0, 0.1, dt=0.01, method="RK4",
                                   tau=lambda t, q, v: np.array([-np.sin(3.0 * t), 0, 0, 0, 0, 0])), tol=1e-12)
    ours = [function for function in made if function not in (push, again, steered)]
    assert len(ours) == len(set(ours)), f"made again: {ours}"
    assert push not in driver._FIRST_CLASS and again not in driver._FIRST_CLASS

    # a function compiled again (Numba freezes the global it reads at each compilation) runs its new code
    global STEERING_GAIN
    STEERING_GAIN = 1.0
    first = mb.simulate(system, q0, v0, 0.1, dt=0.01, method="RK4", tau=steered)
    STEERING_GAIN = -1.0
    steered.recompile()
    assert_same(mb.simulate(system, q0, v0, 0.1, dt=0.01, method="RK4", tau=steered), other, tol=0.0)
    assert_same(first, runs[0], tol=0.0)
    assert made.count(steered) == 2, "a function compiled again makes its first-class value again"


STEERING_GAIN = 1.0


@numba.njit
def steered(t, q, v, out):
    out[0] = STEERING_GAIN * np.sin(3.0 * t)


def test_a_controller_whose_code_numba_does_not_record_is_made_again_and_computes_the_same(made, monkeypatch):
    """The cache of compiled controllers asks :func:`multibody.numba_hooks.compiled_code` whether a pointer is
    current; where that has no answer (``None``, a Numba without the internal record) each controller is checked
    and made again, and every one computes the same forces."""
    from multibody import numba_hooks

    @numba.njit
    def spring(t, q, v, out):
        out[0] = -2.0 * q[0] - 0.5 * v[0] + t

    kept = [integrators.CompiledController(spring, 1) for _ in range(2)]
    assert made.count(spring) == 1 and kept[0].pointer is kept[1].pointer
    monkeypatch.setattr(numba_hooks, "compiled_code", lambda dispatcher, types: None)
    remade = [integrators.CompiledController(spring, 1) for _ in range(2)]
    assert made.count(spring) == 3
    q, v = np.array([[1.0], [2.0]]), np.array([[0.0], [4.0]])
    for controller in kept + remade:
        np.testing.assert_array_equal(controller(0.5, q, v), [[-1.5], [-5.5]])


def test_a_compiled_controller_made_once_serves_each_model_at_its_size():
    """The same numba.njit controller bound to models of different sizes: one first-class value (the same machine
    code), each bound controller with its own model's nv, and each run equal to the same law as a Python callable."""
    @numba.njit
    def damp(t, q, v, out):
        for c in range(v.shape[0]):
            out[c] = -0.5 * v[c] - q[c]

    bound = []
    for model in (oscillator(), mb.robots.load("panda")):
        controller = integrators.as_controller(damp, model)
        bound.append(controller)
        q0, v0 = model.neutral() + 0.1, np.full(model.nv, 0.2)
        assert controller(0.0, q0, v0).shape == (model.nv,)
        compiled = mb.simulate(model, q0, v0, 0.05, dt=0.01, method="RK4", tau=damp, limits="ignore")
        python = mb.simulate(model, q0, v0, 0.05, dt=0.01, method="RK4", tau=lambda t, q, v: -0.5 * v - q,
                             limits="ignore")
        assert_same(compiled, python, tol=1e-12)
    assert bound[0].pointer is bound[1].pointer
    assert (bound[0].nv, bound[1].nv) == (1, 9)


def test_one_trajectory_with_a_compiled_controller_runs_on_the_calling_thread(monkeypatch):
    """One trajectory's compiled controller runs in the run itself (stepping.advance on this thread), not through
    the batch's parallel loop, and equals the same law as a Python callable."""
    def parallel(*arguments, **options):
        raise AssertionError("one trajectory ran through the batch's parallel loop")

    model, q0, v0 = panda()
    q_ref = model.neutral()

    @numba.njit
    def pd(t, q, v, out):
        for c in range(v.shape[0]):
            out[c] = 50.0 * (q_ref[c] - q[c]) - 2.0 * v[c]

    python = mb.simulate(model, q0, v0, 0.05, dt=0.001, method="RK4", tau=lambda t, q, v: 50.0 * (q_ref - q) - 2.0 * v,
                         limits="ignore")
    monkeypatch.setattr(integrators.CompiledRun, "advance_batch", parallel)
    compiled = mb.simulate(model, q0, v0, 0.05, dt=0.001, method="RK4", tau=pd, limits="ignore")
    assert_same(compiled, python, tol=1e-12)


def test_a_batch_through_singular_configurations_hands_those_steps_to_python(statuses):
    """Parallelogram chains swinging through their flat configuration with a PD on the first bar: the runs stop
    before each step that starts near it, the lockstep loop takes it on the constraints, and the runs go on; each
    trajectory equals its run alone, whose compiled run hands the same steps to the Python loop."""
    cells = 2
    system = mb.ConstrainedSystem(parallelogram_chain(cells), planar_closures(cells))
    q0, v0 = (np.array(x) for x in zip(*[crank_state(cells, angle, rate) for angle, rate in ((0.5, 0.0),
                                                                                           (0.05, -1.0))]))
    tau = mb.PD(np.r_[0.5, np.zeros(system.nv - 1)], 0.0, np.zeros(system.nq))
    batch = mb.simulate(system, q0, v0, 1.0, dt=0.01, method="RK4", tau=tau)
    assert stepping.NEAR_SINGULAR in statuses and batch.completed.all()
    for r in range(2):
        alone = mb.simulate(system, q0[r], v0[r], 1.0, dt=0.01, method="RK4", tau=tau)
        assert_same(batch.select(r), alone, tol=0.0)


def test_a_trajectory_of_a_batch_whose_controller_fails_stops_alone_with_its_message():
    """A compiled controller that turns NaN once the shoulder passes 0.4 rad: of three double pendulums, the one
    that swings past it stops there (NaN after its last good state, its status the message of its run alone), the
    others complete as alone."""
    model = mb.robots.load("double_pendulum")

    @numba.njit
    def guarded(t, q, v, out):
        out[0] = np.nan if q[0] > 0.4 else 0.0

    q0 = np.array([[0.1, 0.0], [0.3, 0.0], [-0.2, 0.1]])
    v0 = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 0.0]])
    with pytest.warns(RuntimeWarning, match="1 of 3 trajectories stopped early"):
        batch = mb.simulate(model, q0, v0, 0.5, dt=0.01, method="RK4", tau=guarded, limits="ignore")
    assert batch.completed.tolist() == [True, False, True]
    with pytest.raises(mb.SimulationError) as alone:
        mb.simulate(model, q0[1], v0[1], 0.5, dt=0.01, method="RK4", tau=guarded, limits="ignore")
    assert batch.status[1] == str(alone.value)
    good = len(alone.value.trajectory)
    np.testing.assert_array_equal(batch.q[1, :good], alone.value.trajectory.q)
    assert np.isnan(batch.q[1, good:]).all()
    for r in (0, 2):
        assert_same(batch.select(r), mb.simulate(model, q0[r], v0[r], 0.5, dt=0.01, method="RK4", tau=guarded,
                                                 limits="ignore"), tol=0.0)


# ============================================================================= where a run stops


def test_near_singular_steps_are_taken_by_the_python_loop(python_loop, statuses):
    cells = 2
    system = mb.ConstrainedSystem(parallelogram_chain(cells), planar_closures(cells))
    q0, v0 = crank_state(cells, 0.05, -1.0)
    compiled, python = both(python_loop, system, q0, v0, 1.0, dt=0.01, method="RK4")
    assert stepping.NEAR_SINGULAR in statuses
    assert np.count_nonzero(np.diff(np.sign(compiled.q[:, 0]))) >= 1  # (it passes its flat configuration)
    assert_same(compiled, python, tol=0.0)


def test_a_stage_the_compiled_step_cannot_take_is_taken_by_the_python_loop(python_loop, statuses):
    """Joint forces of 1e300 on the pendulum: the second stage's state overflows, the run hands the step to the
    Python loop, which fails as it would alone, with its own message."""
    model = mb.robots.load("pendulum")
    with pytest.raises(mb.SimulationError) as compiled:
        mb.simulate(model, [0.1], [0.0], 1.0, dt=0.1, method="RK4", tau=[1e300])
    assert statuses[-1] == stepping.STAGE_UNSOLVED
    python_loop()
    with pytest.raises(mb.SimulationError) as python:
        mb.simulate(model, [0.1], [0.0], 1.0, dt=0.1, method="RK4", tau=[1e300])
    assert str(compiled.value) == str(python.value)
    assert_same(compiled.value.trajectory, python.value.trajectory, tol=0.0)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # (the Python loop's NumPy sum)
def test_a_state_that_overflows_at_a_steps_end_stops_with_its_time(python_loop, statuses):
    """Explicit Euler on the slider pushed by 1e308 N at steps of 10 s: each stage is finite, the step's end is not
    (w⁺ = h a = 1e309): SimulationError naming the time, as the Python loop says."""
    model = oscillator()
    with pytest.raises(mb.SimulationError) as compiled:
        mb.simulate(model, [0.0], [0.0], 30.0, dt=10.0, method="Euler", tau=[1e308], limits="ignore")
    assert statuses[-1] == stepping.NON_FINITE_STATE
    assert str(compiled.value).endswith("the state became non-finite at t = 10 s")
    python_loop()
    with pytest.raises(mb.SimulationError) as python:
        mb.simulate(model, [0.0], [0.0], 30.0, dt=10.0, method="Euler", tau=[1e308], limits="ignore")
    assert str(compiled.value) == str(python.value)


def test_non_finite_joint_forces_of_a_compiled_controller_name_the_time_and_joint(python_loop, statuses):
    model = mb.robots.load("double_pendulum")

    @numba.njit
    def broken(t, q, v, out):
        out[1] = np.nan if t > 0.5 else 0.0

    with pytest.raises(mb.SimulationError) as compiled:
        mb.simulate(model, [0.3, 0.2], [0.0, 0.0], 1.0, dt=0.05, method="RK4", tau=broken)
    assert statuses[-1] == stepping.NON_FINITE_TORQUE
    assert re.search(r"the joint forces tau\(t, q, v\) are not finite at t = 0.525 s: tau\[1\] \(joint 'elbow', "
                     r"N·m\) = nan$", str(compiled.value))
    python_loop()
    with pytest.raises(mb.SimulationError) as python:
        mb.simulate(model, [0.3, 0.2], [0.0, 0.0], 1.0, dt=0.05, method="RK4", tau=broken)
    assert str(compiled.value) == str(python.value)
    assert_same(compiled.value.trajectory, python.value.trajectory, tol=0.0)


def test_a_projection_that_does_not_converge_stops_with_the_python_loops_message():
    """The run's projection with one Gauss–Newton iteration allowed (the plan's setting) on a four-bar whose step
    ends off its loop: NOT_CONVERGED with the largest |φ| left, which the table turns into the ConstraintError the
    Python loop raises for it."""
    model, system, q0, v0 = four_bar()
    times = runs.output_times(0.0, 0.1, 0.05)
    run = simulation._compiled_run(system, simulation.Charts(system.system), integrators.TABLEAUS["RK4"], None, None,
                                   True, 1e-12, times)
    run.plan[int(run.plan[stepping.PLAN_SETTINGS]) + 1] = 1  # (max_iterations)
    states = np.zeros((len(times), system.nq + system.nv))
    states[0] = np.concatenate([q0, v0])
    k, status = run.advance(states, 1, len(times))
    assert (k, status) == (1, stepping.NOT_CONVERGED)
    error = simulation._RUN_FAILURES[status](system.system, run.io, run.plan)
    assert isinstance(error, mb.ConstraintError)
    assert re.fullmatch(r"projection onto the position constraints did not converge: \|φ\| = \S+ after 1 iterations",
                        str(error))
    assert float(str(error).split("= ")[1].split()[0]) == float(f"{run.io[stepping.IO_VALUE]:.3g}") > 0.0


def test_a_projection_the_compiled_step_cannot_make_hands_the_step_to_python():
    """A particle held by a rod of 0.5 m to the origin, one explicit Euler step from off the rod straight into the
    origin, where the rod has no direction: the run stops before that step with PROJECTION_UNSOLVED, which is no
    failure of its own (the table has none for it): simulate's Python loop takes such a step, as it takes a stage
    the run cannot (test above)."""
    model = particle_model(1.0)
    system = mb.ConstrainedSystem(model, [mb.Distance("p1", None, 0.5)])
    times = np.array([0.0, 0.1, 0.2])
    run = simulation._compiled_run(system, simulation.Charts(system.system), integrators.TABLEAUS["Euler"], None,
                                   None, True, 1e-12, times)
    states = np.zeros((3, 6))
    states[0] = [0.1, 0.0, 0.0, -1.0, 0.0, 0.0]  # (q⁺ = q + h v = 0)
    assert run.advance(states, 1, 3) == (1, stepping.PROJECTION_UNSOLVED)
    assert stepping.PROJECTION_UNSOLVED not in simulation._RUN_FAILURES


def test_a_python_controller_that_raises_keeps_the_steps_before_its_stage(python_loop):
    model = mb.robots.load("double_pendulum")

    def tau(t, q, v):
        if t > 0.31:
            raise ValueError("no torque after 0.31 s")
        return np.zeros(2)

    outcomes = []
    for switch in (lambda: None, python_loop):
        switch()
        with pytest.raises(mb.SimulationError) as info:
            mb.simulate(model, [0.3, 0.2], [0.0, 0.0], 1.0, dt=0.01, method="RK4", tau=tau)
        outcomes.append(info.value)
    assert str(outcomes[0]) == str(outcomes[1]) == "simulation stopped at t = 0.31 s: no torque after 0.31 s"
    assert_same(outcomes[0].trajectory, outcomes[1].trajectory, tol=0.0)


def test_a_tableau_s_block_is_made_once_and_read_only():
    """Each run reads its method's coefficients from the one block the tableau made (read-only, as runs share it):
    c, a_position, a_velocity, b_position, b_velocity and which stages need the accelerations."""
    for name, tableau in integrators.TABLEAUS.items():
        block = tableau.block()
        assert block is tableau.block(), name
        assert not block.flags.writeable, name
        s = tableau.stages
        expected = np.concatenate([tableau.c, np.ravel(tableau.a_position), np.ravel(tableau.a_velocity),
                                   tableau.b_position, tableau.b_velocity, tableau.needs_acceleration])
        np.testing.assert_array_equal(block, expected)
        assert block.size == 4 * s + 2 * s * s, name


def test_fixed_step_and_adaptive_runs_take_the_systems_one_compiled_step():
    """``ConstrainedSystem.compiled_step`` is what both runs are built from: a four-bar's step and projection sizes,
    settings ``[project's tolerance, iterations, position rows]`` and chart flag land in the same places of a
    fixed-step and an adaptive run's plans; a system whose rows are evaluated in Python has none, and its adaptive
    run runs as Python only."""
    _, system, _, _ = four_bar()
    step, nq, nv = system.compiled_step, system.nq, system.nv
    assert step is system.compiled_step and step.charts and step.program.size and step.projection_columns
    np.testing.assert_array_equal(step.settings, np.concatenate(([1e-12, 50], system.position_rows)))
    with pytest.raises(ValueError, match="read-only"):
        step.settings[0] = 1.0  # (project's own settings, which the step's were, stay as they are)
    # a step holds arrays: it is one object, hashed and compared by identity (field-wise == would be ambiguous)
    other = mb.ConstrainedSystem(system.system, system.constraints).compiled_step
    assert step == step and step != other and len({step, other}) == 2
    times = np.linspace(0.0, 0.1, 3)
    fixed = integrators.CompiledRun(step, integrators.TABLEAUS["RK4"], None, None, 1e-12, 1e-2, times, nq, nv)
    adaptive = integrators.AdaptiveRun(step, False, integrators.EMBEDDED["RK45"], None, None, 1e-12, 1e-2, times, nq,
                                       nv, 1e-8, 1e-10, np.inf, 1.0, np.zeros(0))
    fields = [stepping.PLAN_NQ, stepping.PLAN_NV, stepping.PLAN_CHARTS, stepping.PLAN_PROJECT, stepping.PLAN_PROJECTION_TOLERANCE,
              stepping.PLAN_NEAR_SINGULAR, stepping.PLAN_STEP_COLUMNS, stepping.PLAN_STEP_WORKSPACE,
              stepping.PLAN_PROJECTION_COLUMNS, stepping.PLAN_PROJECTION_WORKSPACE]
    np.testing.assert_array_equal(fixed.plan[fields], adaptive.plan[fields])
    np.testing.assert_array_equal(fixed.plan[fields], [nq, nv, 1.0, 1.0, 1e-12, 1e-2, step.step_columns,
                                                       step.step_workspace, step.projection_columns,
                                                       step.projection_workspace])
    for run in (fixed, adaptive):
        start = int(run.plan[stepping.PLAN_SETTINGS])
        np.testing.assert_array_equal(run.plan[start : start + step.settings.size], step.settings)
        assert run.tree is step.tree and run.frames is step.frames
    pendulum = mb.ConstrainedSystem(particle_model(1.0), [mb.Holonomic(lambda q, t: np.array([q @ q - 1.0]))])
    assert pendulum.compiled_step is None
    python = integrators.AdaptiveRun(None, False, integrators.EMBEDDED["RK45"], None, None, 1e-12, -np.inf, times, 3,
                                     3, 1e-8, 1e-10, np.inf, 1.0, np.zeros(0))
    assert python.tree is None and python.plan[stepping.PLAN_STEP_COLUMNS] == 0


def test_a_python_controller_that_gives_none_gives_zero_joint_forces():
    """``None`` from a Python controller at a stage is zero joint forces: the compiled run's states equal those of
    the run without a controller."""
    model = mb.robots.load("double_pendulum")
    step, times = mb.ConstrainedSystem(model).compiled_step, np.linspace(0.0, 0.2, 21)
    results = []
    for controller in (None, lambda t, q, v: None):
        run = integrators.CompiledRun(step, integrators.TABLEAUS["RK4"], controller, None, None, -np.inf, times,
                                      model.nq, model.nv)
        states = np.zeros((len(times), model.nq + model.nv))
        states[0, :2] = [0.3, 0.2]
        assert run.advance(states, 1, len(times), controller) == (len(times), stepping.COMPLETED)
        results.append(states)
    np.testing.assert_array_equal(results[0], results[1])


def test_control_rows_of_each_controller_kind():
    """:func:`multibody.integrators.control_rows`: the kind each controller runs as and its rows, one row of ``nv``
    zeros where the kind reads none."""
    model = mb.robots.load("double_pendulum")
    nv = model.nv

    @numba.njit
    def compiled(t, q, v, out):
        out[0] = -q[0]

    constant = np.array([[1.0, 2.0], [3.0, 4.0]])
    pd = integrators.as_controller(mb.PD(5.0, 1.0, np.zeros(model.nq)), model)
    cases = [(None, stepping.NO_CONTROL), (constant, stepping.CONSTANT), (pd, stepping.PD),
             (integrators.as_controller(compiled, model), stepping.FUNCTION), (lambda t, q, v: -q, stepping.PYTHON)]
    for controller, expected in cases:
        kind, rows = integrators.control_rows(controller, nv)
        assert kind == expected
        assert rows.dtype == np.float64 and rows.flags.c_contiguous
        if expected == stepping.CONSTANT:
            np.testing.assert_array_equal(rows, constant)
        elif expected == stepping.PD:
            np.testing.assert_array_equal(rows, np.concatenate([np.zeros((1, nv)), pd.rows], axis=1))
        else:
            np.testing.assert_array_equal(rows, np.zeros((1, nv)))


@pytest.mark.parametrize("controller", ["pd", "python", "batch"])
def test_the_run_records_the_energy_of_each_step_start(monkeypatch, controller):
    """A fixed-step run by ABA records the energy of every output state it takes a step from (ABA's first stage
    evaluates the state itself), and the vector-space steps that of the last state too: the trajectory's energy equals
    the system's at every state to 1e-12 (relative), and none is evaluated after the run, but the last state's of a
    Python controller's run (whose steps are not the vector-space steps); for each trajectory of a batch alike."""
    model = mb.robots.load("panda")
    pd = mb.PD(100.0, 10.0, model.neutral() + 0.3)
    q0 = model.neutral()
    if controller == "batch":
        q0 = np.stack([q0, q0 + 0.1, q0 - 0.2])
    v0 = np.zeros(q0.shape[:-1] + (model.nv,))
    evaluated = []
    from multibody.mechanical import ModelSystem

    energy = ModelSystem.energy

    def counted(self, q, v):
        evaluated.append(np.asarray(q).reshape(-1, model.nq).shape[0])
        return energy(self, q, v)

    monkeypatch.setattr(ModelSystem, "energy", counted)
    tau = (lambda t, q, v: pd.kp * (pd.q_ref - q) - pd.kd * v) if controller == "python" else pd
    trajectory = mb.simulate(model, q0, v0, 0.2, dt=1e-3, method="RK4", tau=tau, limits="ignore")
    assert sum(evaluated) == (1 if controller == "python" else 0)
    reference = mb.kinetic_energy(model, trajectory.q, trajectory.v) + mb.potential_energy(model, trajectory.q)
    assert np.isfinite(trajectory.energy).all()
    np.testing.assert_allclose(trajectory.energy, reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())



def vector_space_chain():
    """A tree of every joint kind of a vector space (revolute about a principal and a skew axis, prismatic,
    translation), its bodies' centres off the joint frames, with armature and damping."""
    builder = mb.ModelBuilder("vector chain")
    rng = np.random.default_rng(3)
    joints = [mb.joints.Revolute((0.0, 0.0, 1.0)), mb.joints.Revolute((0.6, 0.0, 0.8)),
              mb.joints.Prismatic((0.0, 1.0, 0.0)), mb.joints.Translation(), mb.joints.Revolute((-1.0, 0.0, 0.0))]
    parent = None
    for k, joint in enumerate(joints):
        placement = np.eye(4)
        rotation = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        placement[:3, :3] = rotation * np.sign(np.linalg.det(rotation))
        placement[:3, 3] = rng.uniform(-0.3, 0.3, 3)
        inertia = mb.inertia.box(float(rng.uniform(0.5, 2.0)), rng.uniform(0.1, 0.4, 3), rng.uniform(-0.2, 0.2, 3))
        parent = builder.add_body(f"b{k}", joint, parent=parent, placement=placement, inertia=inertia,
                                  damping=float(rng.uniform(0.0, 0.5)), armature=float(rng.uniform(0.0, 0.1)))
    return builder.build()


@pytest.mark.parametrize("method", FIXED)
def test_the_vector_space_steps_equal_the_charted_steps(method):
    """A run on a vector space without constraints takes its stages straight in ``[q, v]``
    (:func:`multibody.kernels.stepping.vector_space_steps`): from random states of a chain of every vector-space joint
    kind, with each controller that is not Python and with joint damping, its states equal the general run's through
    the chart maps (the identity there) to 1e-13, and the energies it records those of all its states to 1e-12."""
    model = vector_space_chain()
    nq, nv = model.nq, model.nv
    assert model.is_vector_space and nq == nv
    rng = np.random.default_rng(7)
    times = np.linspace(0.0, 0.05, 51)

    @numba.njit
    def compiled(t, q, v, out):
        for c in range(q.shape[0]):
            out[c] = -3.0 * q[c] - 0.5 * v[c] + np.sin(t)

    controllers = [None, rng.standard_normal(nv), integrators.as_controller(mb.PD(20.0, 1.0, rng.standard_normal(nq)),
                                                                           model),
                   integrators.as_controller(compiled, model)]
    tableau = integrators.TABLEAUS[method]
    for controller in controllers:
        for damping in (None, model.damping):
            q0, v0 = rng.uniform(-1.0, 1.0, nq), rng.uniform(-2.0, 2.0, nv)
            results = []
            for charts in (False, True):
                step = dataclasses.replace(mb.ConstrainedSystem(model).compiled_step, charts=charts)
                run = integrators.CompiledRun(step, tableau, controller, damping, None, -np.inf, times, nq, nv)
                states = np.full((len(times), nq + nv), np.nan)
                states[0] = np.concatenate([q0, v0])
                assert run.advance(states, 1, len(times)) == (len(times), stepping.COMPLETED)
                results.append((states, run.energies.copy()))
            (fast, energy), (general, _) = results
            assert np.isfinite(fast).all()
            np.testing.assert_allclose(fast, general, rtol=0, atol=1e-13 * np.abs(general).max())
            q, v = fast[:, :nq], fast[:, nq:]
            if method != "semi-implicit Euler":  # (whose first stage evaluates no accelerations)
                # every state's, the last one's included
                reference = mb.kinetic_energy(model, q, v) + mb.potential_energy(model, q)
                np.testing.assert_allclose(energy, reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())
