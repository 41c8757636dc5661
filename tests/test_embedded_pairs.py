"""The adaptive methods' embedded Runge–Kutta pairs (multibody.integrators.EMBEDDED) and their run
(multibody.kernels.stepping.adaptive): the orders of each pair's two solutions and of its dense output, the run's
order with its steps held fixed, agreement with SciPy's solve_ivp at the same tolerances, and the compiled run equal
to the same run with a Python controller."""

import numba
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import multibody as mb
from multibody.integrators import EMBEDDED
from multibody.kernels import stepping

#: The orders of each pair: its solution, its error estimates' embedded solutions, its dense output.
ORDERS = {"RK23": (3, (2,), 3), "RK45": (5, (4,), 4), "DOP853": (8, (5, 3), 7)}


def harmonic(t, y):
    """y'' = −y as a first-order system, y = [x, ẋ]: x = cos t from [1, 0]."""
    return np.array([y[1], -y[0]])


def exact(t):
    return np.array([np.cos(t), -np.sin(t)])


def one_step(pair, h):
    """The rates ``K (rows, 2)`` of one step of ``pair`` from ``exact(0)`` with step ``h``, its dense output's stages
    included, by the run's own sums (``stepping.weighted_sum``)."""
    block = pair.block()
    rows = pair.rows
    a = block[5 + rows : 5 + rows + rows * rows].reshape(rows, rows)
    y0 = exact(0.0)
    K = np.zeros((rows, 2))
    K[0] = harmonic(0.0, y0)
    y = np.zeros(2)
    for i in range(1, rows):
        stepping.weighted_sum(y0, h, a[i, :i], K, 0, 2, y)
        K[i] = harmonic(pair.c[i] * h, y)
    return y0, K


def slope(errors, steps):
    """The order ``p`` of ``errors ∝ steps^p`` from the first and last."""
    return np.log(errors[0] / errors[-1]) / np.log(steps[0] / steps[-1])


@pytest.mark.parametrize("name", EMBEDDED)
def test_each_pair_s_solutions_and_dense_output_have_their_orders(name):
    """One step of each pair from the harmonic oscillator's exact state: the local error of its solution scales as
    ``h^(p+1)``, of each embedded solution ``y₁ − h Σ e_j K_j`` (orders 2; 4; 5 and 3) as ``h^(p̂+1)``, and of the
    dense output in the middle of the step as ``h^(p_d+1)`` (3, 4, 7)."""
    pair = EMBEDDED[name]
    order, embedded, dense_order = ORDERS[name]
    steps = np.array([0.4, 0.2]) if name != "DOP853" else np.array([0.8, 0.4])
    solution, estimates, dense = [], [], []
    for h in steps:
        y0, K = one_step(pair, h)
        y1 = np.zeros(2)
        stepping.weighted_sum(y0, h, np.array(pair.a[pair.stages]), K, 0, 2, y1)
        solution.append(np.abs(y1 - exact(h)).max())
        weights = [pair.e] + ([] if pair.e3 is None else [pair.e3])
        estimates.append([np.abs(y1 - h * np.array(e) @ K[: pair.stages + 1] - exact(h)).max() for e in weights])
        F = np.zeros((len(pair.flips), 2))
        stepping.dense_coefficients(np.array(pair.dense), K, F)
        middle = np.zeros(2)
        stepping.dense_point(y0, h, 0.5, F, np.array(pair.flips, dtype=float), middle)
        dense.append(np.abs(middle - exact(h / 2)).max())
    assert slope(solution, steps) == pytest.approx(order + 1, abs=0.3)
    for k, p in enumerate(embedded):
        assert slope([e[k] for e in estimates], steps) == pytest.approx(p + 1, abs=0.3)
    assert slope(dense, steps) == pytest.approx(dense_order + 1, abs=0.3)


def oscillator():
    """A 1 kg cart on a horizontal prismatic joint held by ``mb.PD(kp=4)``: ``ẍ = −4 x``, ``x = cos 2t`` from
    ``x = 1`` at rest."""
    builder = mb.ModelBuilder("oscillator")
    builder.add_body("cart", mb.joints.Prismatic([1.0, 0.0, 0.0]),
                     inertia=mb.Inertia(1.0, [0.0, 0.0, 0.0], 0.1 * np.eye(3)))
    return builder.build(), mb.PD(4.0, 0.0, [0.0])


@pytest.mark.parametrize("name", EMBEDDED)
def test_the_run_with_fixed_steps_has_the_pair_s_order(name):
    """``simulate`` with tolerances so loose that every step is accepted at ``max_step``: the error at the end of the
    harmonic oscillator's run (compiled, with the PD as data) scales as ``h^p``, and the outputs between the steps
    (dense output, eleven per step) keep the run's order."""
    model, pd = oscillator()
    order = ORDERS[name][0]
    steps = {"RK23": [0.05, 0.025], "RK45": [0.1, 0.05], "DOP853": [0.25, 0.125]}[name]
    final, inside = [], []
    for h in steps:
        trajectory = mb.simulate(model, np.array([1.0]), np.array([0.0]), 2.0, dt=h / 11, method=name, tau=pd,
                                 rtol=1e3, atol=1e3, max_step=h)
        error = np.abs(trajectory.q[:, 0] - np.cos(2.0 * trajectory.t))
        final.append(error[-1])
        inside.append(error.max())
    assert slope(final, steps) == pytest.approx(order, abs=0.4)
    assert slope(inside, steps) == pytest.approx(order, abs=0.4)


@pytest.mark.parametrize("name", EMBEDDED)
def test_errors_are_those_of_scipy_s_solvers_at_the_same_tolerances(name):
    """The oscillator by ``simulate`` and the same ODE by ``scipy.integrate.solve_ivp`` at the same ``rtol``,
    ``atol``: the errors against ``cos 2t`` at the output times are of the same size (the step control, its factors
    and the first step are SciPy's; the error of ``q`` is measured against its size in the chart as SciPy measures
    ``q`` itself)."""
    model, pd = oscillator()
    options = dict(rtol=1e-7, atol=1e-9)
    trajectory = mb.simulate(model, np.array([1.0]), np.array([0.0]), 5.0, dt=0.05, method=name, tau=pd, **options)
    ours = np.abs(trajectory.q[:, 0] - np.cos(2.0 * trajectory.t)).max()
    scipy = solve_ivp(lambda t, y: np.array([y[1], -4.0 * y[0]]), (0.0, 5.0), [1.0, 0.0], method=name,
                      t_eval=trajectory.t, **options)
    theirs = np.abs(scipy.y[0] - np.cos(2.0 * trajectory.t)).max()
    assert 0.2 < ours / theirs < 5.0, (ours, theirs)


@pytest.mark.parametrize("name", ["DOP853", "RK23"])
def test_the_compiled_run_equals_the_run_with_a_python_controller(name, monkeypatch):
    """The rolling ball (a free body: a new chart at every step's end; a contact row and two rolling rows, projected
    at the steps' ends) under a PD as data, compiled in one call (no stage through Python), and under the same law
    as a Python callable, the run taken as Python with a call per stage: the same states to 1e-12."""
    from multibody.demos import rolling_ball_setup

    calls = []
    rates = mb.simulation._ChartStages.rates
    monkeypatch.setattr(mb.simulation._ChartStages, "rates", lambda *args: calls.append(1) or rates(*args))
    setup = rolling_ball_setup()
    pd = mb.PD(0.5, 0.2, setup.q0)
    bound = pd.bind(setup.system.system.model)
    options = dict(dt=0.01, method=name, rtol=1e-9, atol=1e-11)
    compiled = mb.simulate(setup.system, setup.q0, setup.v0, 1.0, tau=pd, **options)
    assert not calls
    python = mb.simulate(setup.system, setup.q0, setup.v0, 1.0, tau=lambda t, q, v: bound(t, q, v), **options)
    assert calls
    np.testing.assert_allclose(compiled.q, python.q, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(compiled.v, python.v, rtol=0.0, atol=1e-12)
    assert compiled.residual.max() < 1e-10


@numba.njit
def _damper(t, q, v, out):
    for c in range(v.shape[0]):
        out[c] = -0.2 * v[c]


def test_the_compiled_run_with_an_njit_controller_equals_the_run_with_a_python_one():
    """The rolling ball under a ``numba.njit`` controller ``f(t, q, v, out)`` (a damper), run compiled in one call,
    equals the same law as a Python callable to 1e-12."""
    from multibody.demos import rolling_ball_setup

    setup = rolling_ball_setup()
    options = dict(dt=0.01, method="RK45", rtol=1e-9, atol=1e-11)
    compiled = mb.simulate(setup.system, setup.q0, setup.v0, 1.0, tau=_damper, **options)
    python = mb.simulate(setup.system, setup.q0, setup.v0, 1.0, tau=lambda t, q, v: -0.2 * v, **options)
    np.testing.assert_allclose(compiled.q, python.q, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(compiled.v, python.v, rtol=0.0, atol=1e-12)
    assert compiled.energy[-1] < compiled.energy[0]


@numba.njit
def _cubic(t, q, v, out):
    out[0] = 100.0 * q[0] ** 3


def test_a_solution_that_blows_up_stops_where_the_step_falls_below_the_time_s_rounding():
    """``ẍ = 100 x³`` from ``x = 1`` at rest (the oscillator's cart pushed by a compiled controller, and by the same
    law from Python) goes to infinity at ``T = ∫₁^∞ dx / √(50 (x⁴ − 1)) = 0.18541`` s: the steps shrink with the distance to it until
    they fall below ten roundings of the time, and the run stops there, saying so, with the trajectory so far."""
    model, _ = oscillator()
    for tau in (_cubic, lambda t, q, v: 100.0 * q**3):
        with pytest.raises(mb.SimulationError) as info:
            mb.simulate(model, np.array([1.0]), np.array([0.0]), 1.0, dt=0.01, method="DOP853", tau=tau)
        cause = str(info.value.__cause__)
        assert "DOP853 failed at t = 0.18540" in cause and "fell below ten roundings of the time" in cause, cause
        partial = info.value.trajectory
        assert partial.t[-1] == pytest.approx(0.18, abs=1e-12) and np.isfinite(partial.q).all()
