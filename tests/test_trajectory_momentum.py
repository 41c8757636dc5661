"""``Trajectory.momentum``: generalized momenta ``p = M(q) v`` (conserved for cyclic coordinates, the
lecture note's ``p_θ``) and the total spatial momentum of the moving bodies (conserved for a free
system), checked against closed forms and for conservation along simulated motions."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import pose_from_xyz_rpy


def free_chain():
    """A floating box carrying an arm and a wrist, without gravity: a free system."""
    b = mb.ModelBuilder("free_chain", gravity=(0.0, 0.0, 0.0))
    b.add_body("base", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1]))
    b.add_body("arm", mb.joints.Revolute([0.0, 1.0, 0.0]), parent="base", placement=pose_from_xyz_rpy([0.2, 0, 0]),
               inertia=mb.inertia.box(1.0, [0.4, 0.05, 0.05], center=[0.2, 0, 0]))
    b.add_body("wrist", mb.joints.Spherical(), parent="arm", placement=pose_from_xyz_rpy([0.4, 0, 0]),
               inertia=mb.inertia.box(0.5, [0.1, 0.1, 0.2]))
    return b.build()


def test_spatial_momentum_of_one_body_is_its_closed_form():
    """One free box: ``[m ċ; R I_c Rᵀ ω + c × m ċ]`` with the body-frame velocity ``v = [v_lin; ω_body]``."""
    b = mb.ModelBuilder("box", gravity=(0.0, 0.0, 0.0))
    inertia = mb.inertia.box(1.5, [0.3, 0.2, 0.1], center=[0.05, -0.02, 0.01])
    b.add_body("box", mb.joints.FreeFlyer(), inertia=inertia)
    model = b.build()
    rng = np.random.default_rng(1)
    q, v = model.random_configuration(rng, shape=(3,)), rng.standard_normal((3, 6))
    trajectory = mb.Trajectory(t=np.arange(3.0), q=q, v=v, lam=np.zeros((3, 0)), energy=np.zeros(3),
                               residual=np.zeros(3))
    h = trajectory.momentum(model, "spatial")
    X = mb.forward_kinematics(model, q)[:, 0]
    for k in range(3):
        R, p = X[k, :3, :3], X[k, :3, 3]
        omega = R @ v[k, 3:]
        com_body = inertia.com
        c = p + R @ com_body
        c_dot = R @ (v[k, :3] + np.cross(v[k, 3:], com_body))
        linear = inertia.mass * c_dot
        angular = R @ inertia.rotational @ R.T @ omega + np.cross(c, linear)
        np.testing.assert_allclose(h[k], np.concatenate([linear, angular]), rtol=1e-12, atol=1e-12)


def test_spatial_momentum_of_a_free_system_is_conserved():
    model = free_chain()
    rng = np.random.default_rng(0)
    trajectory = mb.simulate(model, model.random_configuration(rng), rng.standard_normal(model.nv), 2.0, dt=0.01,
                             method="DOP853", rtol=1e-12, atol=1e-14)
    h = trajectory.momentum(model, "spatial")
    assert h.shape == (len(trajectory), 6)
    assert np.abs(h - h[0]).max() <= 1e-10 * np.abs(h[0]).max()


def test_cyclic_momentum_of_a_central_force():
    """The lecture note's central force in polar coordinates ``(r, θ)``: θ is cyclic, ``p_θ = m r² θ̇``."""
    sympy = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    r, theta = dynamicsymbols("r theta")
    m, k = sympy.symbols("m k", positive=True)
    kepler = mb.LagrangianSystem([r, theta], m / 2 * (r.diff() ** 2 + r**2 * theta.diff() ** 2), -k / r)
    system = kepler.numeric(m=1.3, k=2.0)
    trajectory = mb.simulate(system, [1.0, 0.0], [0.1, 1.1], 5.0, dt=0.05, method="DOP853", rtol=1e-12, atol=1e-14)
    p = trajectory.momentum(system)
    np.testing.assert_allclose(p[:, 1], 1.3 * trajectory.q[:, 0] ** 2 * trajectory.v[:, 1], rtol=1e-13)
    np.testing.assert_allclose(p[:, 0], 1.3 * trajectory.v[:, 0], rtol=1e-13)
    assert np.abs(p[:, 1] - p[0, 1]).max() <= 1e-10 * abs(p[0, 1])


def test_batched_trajectories_and_stopped_rows():
    model = free_chain()
    rng = np.random.default_rng(2)
    q0, v0 = model.random_configuration(rng, shape=(2,)), rng.standard_normal((2, model.nv))
    trajectory = mb.simulate(model, q0, v0, 0.05, dt=0.01, method="RK4")
    p = trajectory.momentum(model)
    assert p.shape == (2, len(trajectory), model.nv)
    single = mb.simulate(model, q0[1], v0[1], 0.05, dt=0.01, method="RK4")
    np.testing.assert_allclose(p[1], single.momentum(model), rtol=1e-12, atol=1e-12)
    stopped = trajectory.select(0)
    stopped.q[3:], stopped.v[3:] = np.nan, np.nan
    assert np.isnan(stopped.momentum(model, "spatial")[3:]).all()
    assert np.isfinite(stopped.momentum(model, "spatial")[:3]).all()


def test_bad_kind_and_spatial_without_a_model_are_refused():
    model = free_chain()
    trajectory = mb.simulate(model, model.neutral(), np.zeros(model.nv), 0.02, dt=0.01, method="RK4")
    with pytest.raises(ValueError, match="kind"):
        trajectory.momentum(model, "angular")
    sympy = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    x = dynamicsymbols("x")
    oscillator = mb.LagrangianSystem([x], sympy.Rational(1, 2) * x.diff() ** 2, sympy.Rational(1, 2) * x**2).numeric()
    line = mb.simulate(oscillator, [1.0], [0.0], 0.1, dt=0.05, method="RK4")
    with pytest.raises(ValueError, match="needs a Model"):
        line.momentum(oscillator, "spatial")
