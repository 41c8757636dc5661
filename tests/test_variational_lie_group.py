"""The variational integrator on Lie-group joints (free-flyer, spherical, planar): the group terms of the
discrete equations against the configuration maps they come from, the left-trivialised ``∂L/∂q``
against differences of ``L``, the observed order against DOP853, the exact spatial momentum of a free
system, and the nonholonomic contacts of the lecture note (the rolling ball, the rolling disc, the
Chaplygin sleigh on a planar joint) held without projection.

The long runs take ``LONG_STEPS`` steps (10⁴; ``MULTIBODY_LONG_RUNS=1``: the issue's 10⁵), as in
``test_variational.py``.
"""

from __future__ import annotations

import functools
import os

import numba
import numpy as np
import pytest

import multibody as mb
from multibody import demos, spatial, variational
from multibody.integrators import as_controller
from multibody.kernels import configuration
from multibody.kernels import variational as kernels
from multibody.spatial import pose_from_xyz_rpy

LONG_STEPS = 100_000 if os.environ.get("MULTIBODY_LONG_RUNS") == "1" else 10_000


# ============================================================================= systems

def free_chain(gravity=(0.0, 0.0, 0.0)):
    """A floating box carrying an arm (revolute) and a wrist (spherical): every kind of joint the
    integrator's group terms distinguish, on a free system when ``gravity`` is zero."""
    b = mb.ModelBuilder("free_chain", gravity=gravity)
    b.add_body("base", mb.joints.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1]))
    b.add_body("arm", mb.joints.Revolute([0.0, 1.0, 0.0]), parent="base", placement=pose_from_xyz_rpy([0.2, 0, 0]),
               inertia=mb.inertia.box(1.0, [0.4, 0.05, 0.05], center=[0.2, 0, 0]))
    b.add_body("wrist", mb.joints.Spherical(), parent="arm", placement=pose_from_xyz_rpy([0.4, 0, 0]),
               inertia=mb.inertia.box(0.5, [0.1, 0.1, 0.2], center=[0.0, 0.05, 0.1]))
    return b.build()


def planar_chain():
    """A planar base carrying a pendulum: SE(2) and a revolute joint, with gravity in the plane."""
    b = mb.ModelBuilder("planar_chain", gravity=(0.0, -9.81, 0.0))
    b.add_body("base", mb.joints.Planar(), inertia=mb.inertia.box(1.5, [0.3, 0.2, 0.1], center=[0.05, 0.02, 0.0]))
    b.add_body("bob", mb.joints.Revolute([0.0, 0.0, 1.0]), parent="base", placement=pose_from_xyz_rpy([0.1, 0, 0]),
               inertia=mb.inertia.box(0.7, [0.05, 0.5, 0.05], center=[0.0, -0.25, 0.0]))
    return b.build()


def heavy_top():
    """A box on a spherical joint, its centre of mass 0.3 m up its body z axis, under gravity."""
    b = mb.ModelBuilder("top")
    b.add_body("top", mb.joints.Spherical(), inertia=mb.inertia.box(1.0, [0.2, 0.3, 0.05], center=[0.0, 0.0, 0.3]))
    return b.build()


def chaplygin_sleigh():
    """The Chaplygin sleigh as a body on a planar joint (SE(2)): centre of mass ``a = 0.5`` m ahead of
    the blade along the body x axis, the blade at the body origin (:class:`~multibody.rolling.KnifeEdge`)."""
    b = mb.ModelBuilder("sleigh")
    b.add_body("sleigh", mb.joints.Planar(), inertia=mb.Inertia(1.0, [0.5, 0.0, 0.0], np.diag([0.1, 0.1, 0.2])))
    model = b.build()
    system = mb.ConstrainedSystem(model, [mb.KnifeEdge("sleigh", direction=(1.0, 0.0, 0.0))])
    heading = 0.3
    q0 = np.array([0.0, 0.0, np.cos(heading), np.sin(heading)])
    return system, q0, np.array([1.0, 0.0, 2.0])


def _random_state(model, seed):
    rng = np.random.default_rng(seed)
    return model.random_configuration(rng), rng.standard_normal(model.nv)


# ============================================================================= the group terms

def _group_difference(model, chart, q0, q1):
    """``x`` with ``chart.advance(q0, x) = q1``: ``Model.difference``, but a free flyer's translation
    is the difference of its positions (SO(3) × R³)."""
    x = model.difference(q0, q1)
    for iq, iv in chart.free_flyers:
        x[iv:iv + 3] = q1[iq:iq + 3] - q0[iq:iq + 3]
    return x


def _check_exponential_terms(model, advance, difference, terms):
    """``q ⊕ (x + ε δ) = (q ⊕ x) ⊕ (ε J_l(−x) δ)`` and ``q ⊕ (ε η) ⊕ x = (q ⊕ x) ⊕ (ε Ad_exp(−x) η)`` to
    first order, by central differences of ``advance`` and ``difference`` (to 1e-8) at steps of up to
    1.5 rad; the inverses to rounding."""
    rng = np.random.default_rng(3)
    q = model.random_configuration(rng)
    eps = 1e-6
    for scale in (0.05, 1.5):
        x = scale * rng.standard_normal(model.nv)
        base = advance(q, x)
        Ad_minus, J_minus = terms(-x)
        Ad_plus, J_plus = terms(x)
        for k in range(model.nv):
            e = np.eye(model.nv)[k]
            moved = (difference(base, advance(q, x + eps * e)) - difference(base, advance(q, x - eps * e))) / (2 * eps)
            np.testing.assert_allclose(moved, J_minus[:, k], atol=1e-8)
            turned = (difference(base, advance(advance(q, eps * e), x))
                      - difference(base, advance(advance(q, -eps * e), x))) / (2 * eps)
            np.testing.assert_allclose(turned, Ad_minus[:, k], atol=1e-8)
        np.testing.assert_allclose(Ad_plus @ Ad_minus, np.eye(model.nv), atol=1e-13)
        # J_l(x) = Ad_exp(x) J_l(−x): the left and right Jacobians
        np.testing.assert_allclose(J_plus, Ad_plus @ J_minus, atol=1e-13)


@pytest.mark.parametrize("make", [free_chain, planar_chain])
def test_integrator_group_terms_match_its_steps(make):
    """The integrator's group (a free flyer on SO(3) × R³): its ``Ad_exp`` and ``J_l`` against its own
    step ``advance`` and the matching difference."""
    model = make()
    chart = variational._LieGroupChart(model)
    _check_exponential_terms(model, chart.advance, lambda q0, q1: _group_difference(model, chart, q0, q1),
                             chart.exponential_terms)


def _coadjoint(model, x, p):
    """``ad_xᵀ p (nv,)`` by its kernel (:func:`multibody.kernels.configuration.coadjoint`)."""
    out, unused = np.empty((1, model.nv)), np.zeros(0)
    tree = model.tree
    configuration.coadjoint(tree.joints, tree.reals, tree.bodies, x, p, unused, unused, out, unused)
    return out[0]


def test_coadjoint_of_the_joint_velocities():
    """``ad_xᵀ p`` from its kernel, for the joints' own velocities, against the adjoint matrices written
    out: the spatial motion cross product ``[x×]`` on a free flyer's ``[v, ω]`` (SE(3)), ``[ω]×`` on a
    spherical joint, and SE(2)'s on a planar one."""
    rng = np.random.default_rng(5)
    chain = free_chain()
    x, p = rng.standard_normal(chain.nv), rng.standard_normal(chain.nv)
    ad = np.zeros((chain.nv, chain.nv))
    ad[:6, :6] = spatial.motion_cross_matrix(x[:6])
    ad[7:10, 7:10] = spatial.skew(x[7:10])  # the wrist, after the arm's revolute joint
    np.testing.assert_allclose(_coadjoint(chain, x, p), ad.T @ p, rtol=1e-14, atol=1e-15)
    planar = planar_chain()
    x, p = rng.standard_normal(planar.nv), rng.standard_normal(planar.nv)
    ux, uy, w = x[:3]
    ad = np.zeros((planar.nv, planar.nv))
    ad[:3, :3] = [[0.0, -w, uy], [w, 0.0, -ux], [0.0, 0.0, 0.0]]
    np.testing.assert_allclose(_coadjoint(planar, x, p), ad.T @ p, rtol=1e-14, atol=1e-15)


def test_the_commutative_joints_have_identity_terms():
    model = mb.robots.load("double_pendulum")
    chart = variational._LieGroupChart(model)
    Ad, J_l = chart.exponential_terms(np.array([0.4, -2.0]))
    np.testing.assert_array_equal(Ad, np.eye(2))
    np.testing.assert_array_equal(J_l, np.eye(2))
    np.testing.assert_array_equal(_coadjoint(model, np.array([0.4, -2.0]), np.array([1.0, 3.0])), np.zeros(2))


@pytest.mark.parametrize("make", [lambda: free_chain((0.0, 0.0, -9.81)), planar_chain, heavy_top])
def test_left_trivialised_lagrangian_gradient(make):
    """``d/dε L(q ⊕ ε η, v) = (Cᵀ v − g − ad_vᵀ M v)·η`` at fixed joint velocity ``v``, against central
    differences of ``L = ½ vᵀ M(q) v − U(q)`` (to 1e-7 of the terms' size)."""
    model = make()
    q, v = _random_state(model, 7)
    lagrangian = variational._ModelLagrangian(model)

    def L(configuration_):
        return 0.5 * v @ mb.mass_matrix(model, configuration_) @ v - mb.potential_energy(model, configuration_)

    eps = 1e-6
    differences = np.array([(L(model.integrate(q, eps * e)) - L(model.integrate(q, -eps * e))) / (2 * eps)
                            for e in np.eye(model.nv)])
    gradient = lagrangian.gradient(q, v)
    np.testing.assert_allclose(gradient, differences, atol=1e-7 * max(1.0, np.abs(differences).max()))
    # the one compiled call against the public functions it stands for
    M, from_terms = lagrangian.terms(q, v)
    np.testing.assert_array_equal(M, mb.mass_matrix(model, q))
    np.testing.assert_array_equal(from_terms, gradient)
    composed = mb.coriolis_matrix(model, q, v).T @ v - mb.generalized_gravity(model, q) - _coadjoint(model, v, M @ v)
    np.testing.assert_allclose(gradient, composed, rtol=1e-13, atol=1e-13 * np.abs(composed).max())


def test_group_lagrangian_gradient_of_a_free_flyer():
    """In the integrator's group velocities ``w`` (``v = T(q) w``, a free flyer's linear velocity in the
    parent frame): ``d/dε L(q ⊕ ε η, T w)`` at fixed ``w``, with ``⊕`` the SO(3) × R³ step, against the
    adapter's gradient (to 1e-7 of the terms' size), and ``M_G = Tᵀ M T``."""
    model = free_chain((0.0, 0.0, -9.81))
    q, w = _random_state(model, 9)
    inner = variational._ModelLagrangian(model)
    group = variational._GroupLagrangian(inner)
    chart = inner.chart

    def L(configuration_):
        v = chart.alignment(configuration_) @ w
        return 0.5 * v @ mb.mass_matrix(model, configuration_) @ v - mb.potential_energy(model, configuration_)

    eps = 1e-6
    differences = np.array([(L(chart.advance(q, eps * e)) - L(chart.advance(q, -eps * e))) / (2 * eps)
                            for e in np.eye(model.nv)])
    np.testing.assert_allclose(group.gradient(q, w), differences, atol=1e-7 * max(1.0, np.abs(differences).max()))
    T = chart.alignment(q)
    np.testing.assert_allclose(group.mass_matrix(q), T.T @ mb.mass_matrix(model, q) @ T, rtol=1e-14, atol=1e-14)
    # the compiled M_G and ∂L_G/∂q against T and the joint-velocity terms (the free flyer's p_lin × v_lin added)
    M_G, gradient = group.terms(q, w)
    np.testing.assert_allclose(M_G, T.T @ mb.mass_matrix(model, q) @ T, rtol=1e-14, atol=1e-14)
    v = T @ w
    M = mb.mass_matrix(model, q)
    turning = np.zeros(model.nv)
    turning[3:6] = np.cross((M @ v)[:3], v[:3])
    np.testing.assert_allclose(gradient, T.T @ inner.gradient(q, v) + turning, rtol=1e-13,
                               atol=1e-13 * np.abs(gradient).max())
    assert variational._LieGroupChart(planar_chain()).alignment(planar_chain().neutral()) is None


# ============================================================================= order, momentum, energy

ORDER_CASES = {
    # name: (rule, order, step counts over 1 s)
    "midpoint": ("midpoint", 2, (100, 200, 400)),
    "trapezoidal": ("trapezoidal", 2, (100, 200, 400)),
    "yoshida-midpoint": ("midpoint", 4, (200, 400, 800)),
}


@functools.lru_cache(maxsize=None)
def _reference(name, t_final):
    model = {"free_chain": lambda: free_chain((0.0, 0.0, -9.81)), "planar_chain": planar_chain,
             "heavy_top": heavy_top}[name]()
    q0, v0 = _random_state(model, 11)
    end = mb.simulate(model, q0, v0, t_final, dt=t_final, method="DOP853", rtol=1e-13, atol=1e-14)
    return model, q0, v0, end.q[-1], end.v[-1]


@pytest.mark.parametrize("name", ["free_chain", "planar_chain", "heavy_top"])
@pytest.mark.parametrize("case", list(ORDER_CASES))
def test_observed_order_on_lie_groups(name, case):
    """The final-state error ``max(|q ⊖ q_ref|, |v − v_ref|)`` after 1 s, for steps halved twice, falls as
    ``h^order``: observed orders within 0.25 of 2 (midpoint, trapezoidal) and 4 (Yoshida)."""
    rule, order, steps = ORDER_CASES[case]
    model, q0, v0, q_ref, v_ref = _reference(name, 1.0)
    errors = []
    for n in steps:
        run = mb.simulate(model, q0, v0, 1.0, method="variational", dt=1.0 / n, rule=rule, order=order)
        assert run.status == "completed" and run.q.shape == (n + 1, model.nq)
        errors.append(max(np.abs(model.difference(q_ref, run.q[-1])).max(), np.abs(run.v[-1] - v_ref).max()))
    assert min(errors) > 1e-10
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - order) < 0.25), f"{name} {case}: errors {errors}, observed orders {orders}"


def _with_still_centre_of_mass(model, q, v):
    """``v`` less the base velocity that moves the centre of mass: the free system then tumbles about a
    fixed point, and its positions stay bounded (a drifting body's coordinates grow, and with them the
    rounding of each step's position, which the angular momentum about the origin inherits)."""
    one = mb.Trajectory(t=np.zeros(1), q=q[None], v=v[None], lam=np.zeros((1, 0)), energy=np.zeros(1),
                        residual=np.zeros(1))
    linear = one.momentum(model, "spatial")[0, :3]
    R = mb.forward_kinematics(model, q)[0, :3, :3]
    v = v.copy()
    v[:3] -= R.T @ linear / model.total_mass  # a uniform translation of the whole system
    return v


def free_box():
    """One free-floating box, its centre of mass off the body origin, without gravity."""
    builder = mb.ModelBuilder("box", gravity=(0.0, 0.0, 0.0))
    builder.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(1.5, [0.3, 0.2, 0.1], center=[0.05, -0.02, 0.01]))
    return builder.build()


#: Newton's tolerance of the momentum runs: the discrete momentum is conserved by the solution of the
#: discrete equations, so to the tolerance of their solve per step (1e-12, the default, leaves 1e-16 of
#: the momentum per step: 1e-11 over 10⁵ steps)
MOMENTUM_TOLERANCE = 1e-14


@functools.lru_cache(maxsize=None)
def _free_run(name, rule):
    model = {"free_chain": free_chain, "free_box": free_box}[name]()
    q0, v0 = _random_state(model, 0)
    v0 = _with_still_centre_of_mass(model, q0, v0)
    return model, variational.simulate(model, q0, v0, LONG_STEPS * 0.01, dt=0.01, rule=rule, tolerance=MOMENTUM_TOLERANCE)


@pytest.mark.parametrize("name", ["free_box", "free_chain"])
@pytest.mark.parametrize("rule", ["midpoint", "trapezoidal"])
def test_spatial_momentum_of_a_free_system_is_conserved_exactly(name, rule):
    """Without gravity the discrete Lagrangian of a free body, or of the free chain, is invariant under
    moving the whole system, so its spatial momentum (``Trajectory.momentum(model, "spatial")``) is
    conserved by the discrete equations (the discrete Noether theorem): ≤ 1e-12 relative over the long
    run with the equations solved to ``MOMENTUM_TOLERANCE``, while the bodies tumble."""
    model, run = _free_run(name, rule)
    assert run.status == "completed"
    momentum = run.momentum(model, "spatial")
    assert np.abs(momentum[0, :3]).max() < 1e-14 and np.abs(momentum[0, 3:]).max() > 0.01
    drift = np.abs(momentum - momentum[0]).max() / np.abs(momentum[0]).max()
    assert drift <= 1e-12, f"{name} {rule}: spatial momentum drift {drift:.3g}"
    if name == "free_chain":
        assert np.ptp(run.q[:, 7]) > 3.0  # the arm swings through large angles


def test_energy_of_a_free_system_is_bounded_without_drift():
    """The free chain tumbles chaotically, and its energy error wanders within a band instead of following
    a line: the mean error over each eighth of the long run stays below 0.2 of its amplitude (a drift
    would move the means across the whole band; measured: 0.06)."""
    _, run = _free_run("free_chain", "midpoint")
    error = run.energy - run.energy[0]
    amplitude = 0.5 * np.ptp(error)
    means = [part.mean() for part in np.array_split(error, 8)]
    assert 0.0 < amplitude and np.abs(means).max() < 0.2 * amplitude, (means, amplitude)


# ============================================================================= contacts without projection

def test_rolling_ball_follows_the_closed_form_to_rounding():
    """The lecture note's ball on the tilted plane (``demos.rolling_ball_setup``: a free body, two
    rolling rows and the holonomic height row): every step keeps ``|φ|`` and ``|A v|`` below 1e-11 with
    no projection. Its exact motion — the centre at constant acceleration ``(5/7) g sin α`` downhill,
    turning about itself at the rolling rate — is a straight path of SO(3) × R³, the free flyer's group
    in the integrator, so the steps follow it to rounding (1e-11 m over 1 s at 10 ms steps), and the
    contact force is ``(2/7) m g sin α`` uphill and ``m g cos α`` normal to the plane to 1e-9 N (the
    multipliers are impulses divided by the step, 1e-11 of the force; measured 1.1e-10 N)."""
    tilt = 0.15
    setup = demos.rolling_ball_setup(tilt=tilt)
    system, q0, v0 = setup.system, setup.q0, setup.v0
    frame = system.constraints[0].frame
    g = np.linalg.norm(system.system.model.gravity)
    run = mb.simulate(system, q0, v0, 1.0, method="variational", dt=0.01)
    assert run.status == "completed"
    phi = np.array([system.constraints[0].position(system.system, q) for q in run.q])
    assert np.abs(phi).max() <= 1e-11
    assert np.abs(run.residual).max() <= 1e-11
    R0 = mb.forward_kinematics(system.system.model, q0)[0, :3, :3]
    v_start = (frame.T @ R0 @ v0[:3])[:2]  # the centre's initial velocity in the plane (the body frame is at it)
    exact = q0[:3] + (np.outer(run.t, v_start) + 0.5 * np.outer(run.t**2, [5 / 7 * g * np.sin(tilt), 0.0])) @ frame[:, :2].T
    assert np.abs(run.q[:, :3] - exact).max() < 1e-11
    # friction along the plane (downhill, across) and the normal force, m = 1 kg
    assert np.abs(run.lam - [-2 / 7 * g * np.sin(tilt), 0.0, g * np.cos(tilt)]).max() < 1e-9


def test_thrown_spinning_body_follows_its_parabola():
    """A box thrown upwards and spinning fast about two axes: its centre (the body origin) flies on the
    parabola of free fall to rounding, however fast it turns, and its energy error stays ``O(h²)``."""
    builder = mb.ModelBuilder("box")
    builder.add_body("box", mb.joints.FreeFlyer(), inertia=mb.inertia.box(1.0, [0.3, 0.2, 0.1]))
    model = builder.build()
    q0, v0 = model.neutral(), np.array([1.0, 0.0, 5.0, 0.3, 8.0, 20.0])
    run = mb.simulate(model, q0, v0, 1.0, method="variational", dt=0.01)
    R = mb.forward_kinematics(model, run.q)[:, 0, :3, :3]
    velocity = (R @ run.v[:, :3, None])[..., 0]
    exact = np.outer(run.t, v0[:3]) + 0.5 * np.outer(run.t**2, model.gravity)
    assert np.abs(run.q[:, :3] - exact).max() < 1e-12
    assert np.abs(velocity - (v0[:3] + np.outer(run.t, model.gravity))).max() < 1e-12
    assert np.ptp(run.energy) < 1e-4 * run.energy[0]


def test_rolling_disc_energy_is_bounded():
    """The coin of ``demos.rolling_coin_setup`` (a free body, rolling without slipping, spinning at
    40 rad/s): over a run of ``LONG_STEPS / 2`` steps its rows hold to 1e-11 at every step and its
    energy error has no trend (the fitted change over the second half is below 0.1 of its amplitude);
    the amplitude is ``O(h²)``: a quarter when the step is halved (two 0.5 s runs)."""
    setup = demos.rolling_coin_setup()
    h = 0.002
    run = mb.simulate(setup.system, setup.q0, setup.v0, LONG_STEPS // 2 * h, method="variational", dt=h)
    assert run.status == "completed"
    assert np.abs(run.residual).max() <= 1e-11
    error = run.energy - run.energy[0]
    amplitude = 0.5 * np.ptp(error)
    half = len(run.t) // 2
    slope = np.polyfit(run.t[half:] - run.t[half], error[half:], 1)[0]
    assert abs(slope) * (run.t[-1] - run.t[half]) < 0.1 * amplitude, (slope, amplitude)
    amplitudes = [np.ptp(mb.simulate(setup.system, setup.q0, setup.v0, 0.5, method="variational", dt=step).energy)
                  for step in (0.004, 0.002)]
    assert abs(np.log2(amplitudes[0] / amplitudes[1]) - 2.0) < 0.2, amplitudes


def test_chaplygin_sleigh_on_a_planar_joint():
    """The sleigh on SE(2) with a knife edge: the blade's row holds to 1e-11 at every step, the energy is
    conserved to ``O(h²)`` (the blade does no work), and the heading rate decays while the sleigh settles
    into straight motion along its body axis (the known qualitative behaviour)."""
    system, q0, v0 = chaplygin_sleigh()
    q0, v0 = system.project(q0, v0)
    run = mb.simulate(system, q0, v0, 30.0, method="variational", dt=0.01)
    assert run.status == "completed"
    assert np.abs(run.residual).max() <= 1e-11
    assert np.ptp(run.energy) < 0.01**2 * run.energy[0]  # O(h²) at h = 0.01 s (measured 3.3e-5 of it)
    assert abs(run.v[-1, 2]) < 1e-3 * abs(v0[2])  # the turning has stopped
    assert abs(run.v[-1, 1]) < 1e-9 and run.v[-1, 0] > 0.5 * np.sqrt(2 * run.energy[0] / 1.0) * 0.9


def test_group_newton_terms_against_differences():
    """``K_G = ∂(M_G w)/∂q``, ``S_G = ∂(∂L_G/∂q)/∂w`` and, at rest, ``H_G = ∂(∂L_G/∂q)/∂q`` of the integrator's
    group velocities, against central differences along its own steps (a free flyer carrying a revolute and a
    spherical joint, with gravity): the derivatives of ``T(q)`` included."""
    model = free_chain((0.0, 0.0, -9.81))
    q, w = _random_state(model, 11)
    group = variational._GroupLagrangian(variational._ModelLagrangian(model))
    chart = group.chart
    K, H, S = group.jacobian_terms(q, w)
    eps = 1e-6

    def along_q(f):
        return np.stack([(f(chart.advance(q, eps * e)) - f(chart.advance(q, -eps * e))) / (2 * eps)
                         for e in np.eye(model.nv)], axis=-1)

    K_differences = along_q(lambda x: group.terms(x, w)[0] @ w)
    np.testing.assert_allclose(K, K_differences, atol=1e-7 * np.abs(K_differences).max())
    S_differences = np.stack([(group.terms(q, w + eps * e)[1] - group.terms(q, w - eps * e)[1]) / (2 * eps)
                              for e in np.eye(model.nv)], axis=-1)
    np.testing.assert_allclose(S, S_differences, atol=1e-7 * np.abs(S_differences).max())
    H_differences = along_q(lambda x: group.terms(x, np.zeros(model.nv))[1])
    _, H_at_rest, _ = group.jacobian_terms(q, np.zeros(model.nv))
    np.testing.assert_allclose(H_at_rest, H_differences, atol=1e-7 * np.abs(H_differences).max())
    np.testing.assert_array_equal(H, H_at_rest)  # (H leaves out the velocity terms)


def _rolling_ball():
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    normal = np.array([np.sin(0.1), 0.0, np.cos(0.1)])
    system = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", 0.1, plane_normal=tuple(normal))])
    q0 = ball.neutral()
    q0[:3] = 0.1 * normal
    return (system, *system.project(q0, np.array([0.0, 1.0, 0.0, 0.5, 0.0, 3.0])))


def _parallelograms():
    from constraint_helpers import crank_state, parallelogram_chain, planar_closures

    system = mb.ConstrainedSystem(parallelogram_chain(2), planar_closures(2))
    return (system, *crank_state(2, 0.4, 2.0))


def _free_chain():
    model = free_chain((0.0, 0.0, -9.81))
    return (model, *_random_state(model, 3))


def _heavy_top():
    model = heavy_top()
    return model, model.neutral(), np.array([0.3, -0.2, 8.0])


def _pd(system):
    """A PD controller toward the neutral configuration, bound to the system as simulate binds it."""
    mechanical = system.system if isinstance(system, mb.ConstrainedSystem) else system
    model = getattr(mechanical, "model", mechanical)
    return as_controller(mb.PD(2.0, 0.3, model.neutral()), mechanical)


@pytest.mark.parametrize("rule", variational.RULES)
@pytest.mark.parametrize("forced", [False, True], ids=["free", "PD"])
@pytest.mark.parametrize("make", [_rolling_ball, chaplygin_sleigh, _parallelograms, _free_chain, _heavy_top],
                         ids=["rolling ball", "sleigh", "parallelograms", "free chain", "heavy top"])
def test_the_compiled_run_gives_the_python_steps(make, forced, rule, monkeypatch):
    """Every step by one compiled run (:func:`multibody.kernels.variational.advance`) gives the trajectory of the
    Python steps, with either rule and with or without a PD controller: on a free flyer with holonomic and
    rolling rows, a planar joint with a knife edge, redundant loop closures on a vector space, and free and
    spherical joints without rows."""
    system, q0, v0 = make()
    tau = _pd(system) if forced else None
    runs = []
    run = variational._CompiledSteps.run
    monkeypatch.setattr(variational._CompiledSteps, "run", lambda self, *args: runs.append(self) or run(self, *args))
    compiled = variational.simulate(system, q0, v0, 0.2, dt=1e-3, rule=rule, tau=tau)
    assert len(runs) == 1 and runs[0].io[kernels.IO_STATUS] == kernels.COMPLETED
    monkeypatch.setattr(variational._CompiledSteps, "applies", staticmethod(lambda *args: False))
    python = variational.simulate(system, q0, v0, 0.2, dt=1e-3, rule=rule, tau=tau)
    assert len(runs) == 1
    np.testing.assert_allclose(compiled.q, python.q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(compiled.v, python.v, rtol=0, atol=1e-9 * max(1.0, np.abs(python.v).max()))
    if python.lam.size:
        np.testing.assert_allclose(compiled.lam, python.lam, rtol=0, atol=1e-8 * max(1.0, np.abs(python.lam).max()))
    np.testing.assert_allclose(compiled.energy, python.energy, rtol=0, atol=1e-9 * max(1.0, np.abs(python.energy).max()))
    assert compiled.residual.max() <= 1e-11


def test_the_compiled_run_applies_to_models_with_data_or_compiled_forces():
    """The compiled run takes a model's steps with joint forces none, constant, PD or a ``numba.njit`` function;
    a Python callable, user constraints and systems that give their own Lagrangian keep the Python steps."""
    system, q0, v0 = _rolling_ball()
    lagrangian = variational._lagrangian_of(system.system)
    applies = variational._CompiledSteps.applies
    assert applies(lagrangian, system, None)
    assert applies(lagrangian, system, np.zeros(6))
    assert applies(lagrangian, system, _pd(system))
    assert applies(lagrangian, system, as_controller(_zero_forces, system.system))
    assert not applies(lagrangian, system, lambda t, q, v: np.zeros(6))
    # a user's row, z = 0.1 for the ball's centre (the rolling ball's contact height)
    user = mb.ConstrainedSystem(system.system, [mb.Holonomic(lambda q, t: np.array([q[2] - 0.1]))])
    assert not applies(variational._lagrangian_of(user.system), user, None)
    from sympy.physics.mechanics import dynamicsymbols

    x = dynamicsymbols("x")
    oscillator = mb.ConstrainedSystem(mb.LagrangianSystem([x], x.diff() ** 2 / 2, x**2 / 2).numeric())
    assert not applies(variational._lagrangian_of(oscillator.system), oscillator, None)


@numba.njit
def _zero_forces(t, q, v, out):
    pass
