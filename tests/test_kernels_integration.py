"""The compiled chart derivative (multibody.kernels.integration) against the same composition in NumPy,
and simulate's compiled path (constant joint forces) against its NumPy path (callable joint forces)."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb

from conftest import erd_urdf
from constraint_helpers import assert_close


def numpy_chart_derivative(system, q_chart, y, tau):
    """``[δ̇; ẇ]`` composed from the public maps: ``q = chart(q_c, δ)``, ``v = Tᵀ w``,
    ``ẇ = T (a + κ(v))``, ``δ̇ = chart_rate(δ, w)``."""
    model, nv = system.model, system.nv
    delta, w = y[:nv], y[nv:]
    q = model.chart(q_chart, delta)
    T = model.velocity_alignment(q)
    v = T.T @ w
    a = system.forward_dynamics(q, v, tau)[0]
    return np.concatenate([model.chart_rate(delta, w), T @ (a + model.velocity_coupling(v))])


def systems():
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    solo = mb.load_urdf(erd_urdf("solo_description/robots/solo12.urdf"), floating_base=True)
    return {
        "rolling ball": mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", 0.1, plane_normal=(0.1, 0.0, 1.0))],
                                             baumgarte=2.0),
        "free ball": mb.ConstrainedSystem(ball),
        "solo12": mb.ConstrainedSystem(solo),
        "double pendulum": mb.ConstrainedSystem(mb.robots.load("double_pendulum")),
    }


@pytest.mark.parametrize("name", ["rolling ball", "free ball", "solo12", "double pendulum"])
def test_chart_derivative_matches_the_numpy_composition(name):
    system = systems()[name]
    model, nv = system.model, system.nv
    rng = np.random.default_rng(4)
    for torque in (None, rng.standard_normal(nv)):
        q_chart = model.random_configuration(rng)
        y = np.concatenate([0.2 * rng.standard_normal(nv), rng.standard_normal(nv)])
        compiled = system.chart_derivative(q_chart, y, torque)
        expected = numpy_chart_derivative(system, q_chart, y, torque)
        assert_close(compiled, expected, 1e-12, scale=max(1.0, np.abs(expected).max()), what=name)


def test_singular_mass_matrix_falls_back_to_the_numpy_error():
    builder = mb.ModelBuilder("ghost")
    builder.add_body("p", mb.joints.Translation())
    system = mb.ConstrainedSystem(builder.build(check_inertia=False))
    assert system.chart_derivative(np.zeros(3), np.zeros(6), None) is None
    with pytest.raises(mb.SimulationError, match="singular"):
        mb.simulate(system, np.zeros(3), np.zeros(3), 0.1, method="RK4", dt=0.01)


@pytest.mark.parametrize("forces", ["constant", "callable"])
@pytest.mark.parametrize("method", ["RK4", "DOP853"])
def test_simulate_compiled_and_numpy_paths_give_the_same_motion(method, forces):
    """The compiled derivative against the NumPy composition (the compiled step withheld): both
    integrate the same equations, so the states agree to rounding (RK4) or to far below the
    tolerance (DOP853, whose step sizes may differ by a rounding)."""
    model = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    q0 = model.neutral()
    q0[2] = 0.1
    v0 = np.array([0.3, 0.1, 0.0, 0.0, 0.0, 2.0])
    constant = np.array([0.1, 0.0, 0.0, 0.0, 0.02, 0.0])
    tau = constant if forces == "constant" else (lambda t, q, v: constant - 0.1 * v)
    q0, v0 = mb.ConstrainedSystem(model, [mb.RollingSphere("ball", 0.1)]).project(q0, v0)
    runs = []
    for compiled in (True, False):
        system = mb.ConstrainedSystem(model, [mb.RollingSphere("ball", 0.1)])
        if not compiled:
            system.__dict__["compiled_step"] = None  # the cached property, withheld
        runs.append(mb.simulate(system, q0, v0, 0.5, dt=0.01, method=method, tau=tau))
    tol = 1e-12 if method == "RK4" else 1e-8
    assert_close(runs[0].q, runs[1].q, tol, scale=1.0, what="q")
    assert_close(runs[0].v, runs[1].v, tol, scale=1.0, what="v")
