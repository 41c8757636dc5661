"""``mb.simulate`` from a batch of initial states: ``N`` trajectories in lockstep with RK4.

A batched simulation equals the ``N`` single simulations (to 1e-12; in practice bit for bit, since every
state takes the same compiled arithmetic), for an open chain, a free-flying tree with every joint kind, a
rolling ball (nonholonomic) and a four-bar linkage (a loop closure, projected onto its constraint); one
trajectory that fails is marked and leaves the others as they would be alone; shapes, methods and systems
that cannot batch are refused by name.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import multibody as mb

from conftest import random_tree_model
from constraint_helpers import CurveCoordinateSystem, Helix, crank_state, parallelogram_chain, planar_closures
from test_simulation_batched import ball_system, random_states

RK4 = dict(method="RK4")


def assert_equals_single_runs(system, q0, v0, t_final, dt, tau=None, single_tau=None, **options):
    """The batch from ``q0 (N, nq)``, ``v0 (N, nv)`` against each trajectory simulated alone (``single_tau(k)``:
    the joint forces of trajectory ``k`` alone): every array to 1e-12 of its size."""
    batch = mb.simulate(system, q0, v0, t_final, dt=dt, tau=tau, **RK4, **options)
    n = len(batch)
    assert batch.batch_size == len(q0) and batch.t.shape == (n,)
    assert batch.q.shape == (len(q0), n, q0.shape[-1]) and batch.v.shape == (len(q0), n, v0.shape[-1])
    assert batch.energy.shape == batch.residual.shape == (len(q0), n)
    assert batch.completed.all() and batch.status == ["completed"] * len(q0)
    for k in range(len(q0)):
        alone = mb.simulate(system, q0[k], v0[k], t_final, dt=dt, tau=None if single_tau is None else single_tau(k),
                            **RK4, **options)
        one = batch.select(k)
        np.testing.assert_array_equal(one.t, alone.t)
        for name in ("q", "v", "lam", "energy", "residual"):
            expected, actual = getattr(alone, name), getattr(one, name)
            assert actual.shape == expected.shape, name
            scale = max(1.0, np.abs(expected).max(initial=0.0))
            assert np.abs(actual - expected).max(initial=0.0) <= 1e-12 * scale, (name, k)
    return batch


def test_double_pendulum_with_joint_forces_that_take_batches():
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(0)
    q0, v0 = rng.uniform(-2.0, 2.0, (5, model.nq)), rng.uniform(-1.0, 1.0, (5, model.nv))
    gains = rng.uniform(0.1, 1.0, (5, model.nv))  # one row per trajectory

    def tau(t, q, v):  # q (N, nq), v (N, nv) -> (N, nv)
        return -gains * v + np.sin(t)

    batch = assert_equals_single_runs(model, q0, v0, 1.0, 0.01, tau=tau,
                                      single_tau=lambda k: lambda t, q, v: -gains[k] * v + np.sin(t))
    assert batch.lam.shape == (5, len(batch), 0)


def test_constant_joint_forces_per_trajectory_and_shared():
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(1)
    q0, v0 = rng.uniform(-2.0, 2.0, (3, model.nq)), rng.uniform(-1.0, 1.0, (3, model.nv))
    tau = rng.standard_normal((3, model.nv))
    assert_equals_single_runs(model, q0, v0, 0.5, 0.01, tau=tau, single_tau=lambda k: tau[k])
    assert_equals_single_runs(model, q0, v0, 0.5, 0.01, tau=tau[0], single_tau=lambda k: tau[0])


def test_joint_damping_with_joint_forces_per_trajectory():
    model = mb.robots.load("double_pendulum_simple")
    assert np.all(model.damping > 0)
    rng = np.random.default_rng(10)
    q0, v0 = rng.uniform(-2.0, 2.0, (3, model.nq)), rng.uniform(-1.0, 1.0, (3, model.nv))
    tau = rng.standard_normal((3, model.nv))
    assert_equals_single_runs(model, q0, v0, 0.5, 0.01, tau=tau, single_tau=lambda k: tau[k], joint_damping=True,
                              progress=False, limits="ignore")  # (its URDF gives the limits [0, 0])


def test_free_flying_tree_with_every_joint_kind():
    model = random_tree_model(3)
    rng = np.random.default_rng(2)
    q0 = model.random_configuration(rng, (4,))
    v0 = rng.standard_normal((4, model.nv))
    assert_equals_single_runs(model, q0, v0, 0.3, 0.01, limits="ignore")


def test_rolling_ball():
    ball, cs = ball_system()
    q0, v0 = cs.project(*random_states(ball, cs, 4, seed=3))
    batch = assert_equals_single_runs(cs, q0, v0, 0.5, 0.01)
    assert batch.residual.max() <= 1e-12 and batch.lam.shape == (4, len(batch), 3)


def four_bar():
    model = mb.robots.load("four_bar")
    in_plane = mb.spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))
    return mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", frame_a=in_plane, kind="planar")])


def test_four_bar_projected_onto_its_loop():
    system = four_bar()
    rng = np.random.default_rng(4)
    guess = np.array([-np.pi / 3, 0.9, -1.4]) + 0.05 * rng.standard_normal((4, 3))
    q0, v0 = system.project(guess, rng.standard_normal((4, 3)))
    batch = assert_equals_single_runs(system, q0, v0, 1.0, 0.01, projection_tolerance=1e-12)
    # A step's end is left unprojected when the projection moves no coordinate by more than 1e-12, so its
    # residual may reach the rows' largest absolute row sum times that (3.5e-12 here; measured 8.7e-13); margin 10.
    rows = max(np.abs(system.solve(q, v).A).sum(axis=-1).max() for q, v in zip(batch.q.reshape(-1, 3),
                                                                                 batch.v.reshape(-1, 3)))
    assert batch.residual.max() <= 10.0 * rows * 1e-12


def test_parallelogram_chains_through_flat_evaluate_their_stages_as_alone():
    """Two-cell parallelogram chains swinging through their flat configuration: the steps that start near it
    (conditioning below ``NEAR_SINGULAR``) evaluate their stages on the constraints, trajectory by trajectory,
    as one trajectory alone does; one chain starts far from flat and one at its edge."""
    cells = 2
    system = mb.ConstrainedSystem(parallelogram_chain(cells), planar_closures(cells))
    states = [crank_state(cells, angle, rate) for angle, rate in ((0.5, 0.0), (0.05, -1.0), (0.01, 2.0))]
    q0, v0 = (np.array(x) for x in zip(*states))
    conditioning = system.projection(q0, v0)[2]
    assert conditioning[0] > mb.simulation.NEAR_SINGULAR > conditioning[2]
    batch = assert_equals_single_runs(system, q0, v0, 2.0, 0.01)
    assert np.count_nonzero(np.diff(np.sign(batch.q[:, :, 0]), axis=1)) >= 3  # flat passages


def test_one_state_shared_by_a_batch_of_the_other():
    model = mb.robots.load("double_pendulum")
    v0 = np.random.default_rng(5).standard_normal((3, model.nv))
    batch = mb.simulate(model, np.array([0.3, -0.2]), v0, 0.2, dt=0.02, **RK4)
    for k in range(3):
        alone = mb.simulate(model, np.array([0.3, -0.2]), v0[k], 0.2, dt=0.02, **RK4)
        np.testing.assert_array_equal(batch.q[k], alone.q)


def test_inconsistent_initial_states_are_projected_with_one_warning():
    ball, cs = ball_system()
    q0, v0 = random_states(ball, cs, 3, seed=6)
    with pytest.warns(UserWarning, match="initial states of 3 of 3 trajectories violated the constraints"):
        batch = mb.simulate(cs, q0, v0, 0.1, dt=0.05, **RK4)
    assert batch.residual.max() <= 1e-12


# ============================================================================= failures

def test_a_trajectory_that_blows_up_is_marked_and_the_others_go_on():
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(7)
    q0, v0 = rng.uniform(-1.0, 1.0, (4, model.nq)), rng.uniform(-1.0, 1.0, (4, model.nv))
    v0[2] = [1e150, -1e150]  # its accelerations overflow in the first step
    with pytest.warns(RuntimeWarning, match="1 of 4 trajectories stopped early"):
        batch = mb.simulate(model, q0, v0, 0.3, dt=0.01, **RK4)
    assert batch.completed.tolist() == [True, True, False, True]
    with pytest.raises(mb.SimulationError) as alone:
        mb.simulate(model, q0[2], v0[2], 0.3, dt=0.01, **RK4)
    assert batch.status[2] == str(alone.value)
    kept = len(alone.value.trajectory)
    np.testing.assert_array_equal(batch.q[2, :kept], alone.value.trajectory.q)
    assert np.isnan(batch.q[2, kept:]).all() and np.isnan(batch.energy[2, kept:]).all()
    for k in (0, 1, 3):
        np.testing.assert_array_equal(batch.q[k], mb.simulate(model, q0[k], v0[k], 0.3, dt=0.01, **RK4).q)


def test_one_trajectory_is_a_batch_of_one():
    """One initial state runs as a batch of one: its trajectory, and where it stops its error and the part so far,
    are those of the batch of one from the same state, bit for bit; the part so far has the energies of its states
    (a PD law so stiff that RK4 with a step of 0.05 s diverges in two steps)."""
    model = mb.robots.load("double_pendulum")
    q0, v0 = np.array([0.3, 0.2]), np.array([0.1, 0.0])
    names = ("q", "v", "lam", "energy", "residual")
    pd = mb.PD(5.0, 1.0, np.zeros(model.nq))
    alone = mb.simulate(model, q0, v0, 1.0, dt=0.01, tau=pd, **RK4)
    batch = mb.simulate(model, q0[None], v0[None], 1.0, dt=0.01, tau=pd, **RK4)
    assert alone.status == batch.status[0] == "completed"
    for name in names:
        np.testing.assert_array_equal(getattr(alone, name), getattr(batch, name)[0])

    stiff, rest = mb.PD(1e6, 0.0, np.ones(model.nq)), np.zeros((1, model.nq))
    with pytest.raises(mb.SimulationError) as error:
        mb.simulate(model, rest[0], rest[0], 5.0, dt=0.05, tau=stiff, **RK4)
    with pytest.warns(RuntimeWarning, match="1 of 1 trajectories stopped early"):
        batch = mb.simulate(model, rest, rest, 5.0, dt=0.05, tau=stiff, **RK4)
    assert str(error.value) == batch.status[0] == error.value.trajectory.status
    assert "the state grew beyond bounds" in str(error.value)
    part = error.value.trajectory
    kept = len(part)
    assert 1 < kept < len(batch) and part.q.shape == (kept, model.nq)
    np.testing.assert_array_equal(part.t, batch.t[:kept])
    for name in names:
        np.testing.assert_array_equal(getattr(part, name), getattr(batch, name)[0, :kept])
    assert np.isfinite(part.energy[:2]).all()


def test_non_finite_joint_forces_of_one_trajectory_stop_it_alone():
    """A callable that returns NaN for trajectory 1 from t = 0.2 s: it stops there, with the state of its last
    good step kept and a status naming the stage time and the joint, as the same run alone says; the callable
    keeps receiving every trajectory (the stopped one at its last state)."""
    ball, cs = ball_system()
    q0, v0 = cs.project(*random_states(ball, cs, 3, seed=8))
    seen = []

    def tau(t, q, v):
        seen.append(q.shape)
        forces = np.zeros((3, 6))
        if t > 0.2:
            forces[1] = np.nan
        return forces

    with pytest.warns(RuntimeWarning, match="1 of 3 trajectories stopped early"):
        batch = mb.simulate(cs, q0, v0, 0.5, dt=0.05, tau=tau, **RK4)
    assert batch.completed.tolist() == [True, False, True]
    assert set(seen) == {(3, 7)}
    # (the first RK4 stage after t = 0.2 s is the midpoint one, at 0.225 s)
    assert batch.status[1].startswith("simulation stopped at t = 0.2 s: the joint forces tau(t, q, v) are not finite "
                                      "at t = 0.225 s: tau[0] (joint 'root_joint', N) = nan")
    with pytest.raises(mb.SimulationError) as alone:
        mb.simulate(cs, q0[1], v0[1], 0.5, dt=0.05, tau=lambda t, q, v: tau(t, q[None], v[None])[1], **RK4)
    assert batch.status[1] == str(alone.value)
    stopped = np.flatnonzero(np.isnan(batch.q[1]).any(axis=1))
    assert stopped[0] == 5 and np.isfinite(batch.q[1, :5]).all() and np.isfinite(batch.lam[1, :5]).all()
    for k in (0, 2):
        alone = mb.simulate(cs, q0[k], v0[k], 0.5, dt=0.05, **RK4)
        np.testing.assert_array_equal(batch.q[k], alone.q)
        np.testing.assert_array_equal(batch.lam[k], alone.lam)


def test_non_finite_initial_states_or_joint_forces_of_a_batch_are_refused():
    """Non-finite entries of q0 (N, nq), v0 (N, nv) or constant joint forces (N, nv) are a ValueError naming the
    argument, the trajectory and the joint, before anything runs."""
    ball, cs = ball_system()
    q0, v0 = cs.project(*random_states(ball, cs, 3, seed=11))
    bad_q, bad_v, tau = q0.copy(), v0.copy(), np.zeros((3, ball.nv))
    bad_q[1, 0] = np.nan
    bad_v[2, 4], bad_v[0, 1] = np.inf, np.nan
    tau[2, 5] = np.nan
    with pytest.raises(ValueError, match=re.escape("q0 must be finite: in trajectory 1, q0[1] has q[0] (joint "
                                                   "'root_joint', m) = nan")):
        mb.simulate(cs, bad_q, v0, 0.1, dt=0.05, **RK4)
    with pytest.raises(ValueError, match=re.escape("v0 must be finite: in trajectory 0, v0[0] has v[1] (joint "
                                                   "'root_joint', m/s) = nan (2 trajectories have non-finite "
                                                   "entries: [0, 2])")):
        mb.simulate(cs, q0, bad_v, 0.1, dt=0.05, **RK4)
    with pytest.raises(ValueError, match=re.escape("tau must be finite: in trajectory 2, tau[2] has tau[5] (joint "
                                                   "'root_joint', N·m) = nan")):
        mb.simulate(cs, q0, v0, 0.1, dt=0.05, tau=tau, **RK4)


def test_joint_limits_of_a_batch():
    model = random_tree_model(3)
    rng = np.random.default_rng(9)
    q0, v0 = model.random_configuration(rng, (3,)), 5.0 * rng.standard_normal((3, model.nv))
    with pytest.warns(mb.JointLimitWarning, match="of 3 trajectories left them"):
        mb.simulate(model, q0, v0, 0.3, dt=0.01, **RK4)
    with pytest.warns(RuntimeWarning, match="stopped early"):
        marked = mb.simulate(model, q0, v0, 0.3, dt=0.01, limits="error", **RK4)
    stopped = np.flatnonzero(~marked.completed)
    assert stopped.size
    for k in stopped:
        assert "left its limits" in marked.status[k] and marked.status[k].endswith("(limits='error')")
        with pytest.raises(mb.SimulationError) as alone:
            mb.simulate(model, q0[k], v0[k], 0.3, dt=0.01, limits="error", **RK4)
        kept = len(alone.value.trajectory)
        np.testing.assert_array_equal(marked.q[k, :kept], alone.value.trajectory.q)
        assert np.isnan(marked.q[k, kept:]).all()


# ============================================================================= refusals

def test_shapes_that_do_not_match_are_refused():
    model = mb.robots.load("double_pendulum")
    with pytest.raises(ValueError, match=r"\(N, 2\) and \(N, 2\) with the same N.*got \(3, 2\) and \(4, 2\)"):
        mb.simulate(model, np.zeros((3, 2)), np.zeros((4, 2)), 1.0, **RK4)
    with pytest.raises(ValueError, match="got \\(3, 3\\) and \\(3, 2\\)"):
        mb.simulate(model, np.zeros((3, 3)), np.zeros((3, 2)), 1.0, **RK4)
    with pytest.raises(ValueError, match="got \\(2, 3, 2\\)"):
        mb.simulate(model, np.zeros((2, 3, 2)), np.zeros(2), 1.0, **RK4)
    with pytest.raises(ValueError, match=r"tau must be None, an array of shape \(2,\) or \(3, 2\)"):
        mb.simulate(model, np.zeros((3, 2)), np.zeros((3, 2)), 1.0, tau=np.zeros((4, 2)), **RK4)
    with pytest.raises(ValueError, match=r"tau\(t, q, v\) must return joint forces of shape \(3, 2\)"):
        mb.simulate(model, np.zeros((3, 2)), np.zeros((3, 2)), 1.0, tau=lambda t, q, v: np.zeros((2, 2)), **RK4)


def test_adaptive_methods_are_refused_for_a_batch():
    model = mb.robots.load("double_pendulum")
    with pytest.raises(ValueError, match="lockstep.*fixed-step method.*'DOP853' chooses its own steps"):
        mb.simulate(model, np.zeros((3, 2)), np.zeros((3, 2)), 1.0, method="DOP853")


def test_systems_evaluated_in_python_are_refused_for_a_batch():
    ball, _ = ball_system()
    user = mb.ConstrainedSystem(ball, [mb.Holonomic(lambda q, t: q[2:3] - 0.1, name="height")])
    q0 = np.broadcast_to(ball.neutral(), (2, ball.nq))
    with pytest.raises(ValueError, match=r"constraints \['height'\] are evaluated in Python"):
        mb.simulate(user, q0, np.zeros((2, ball.nv)), 1.0, **RK4)
    curve = CurveCoordinateSystem(Helix(1.0, 0.2), 1.0)
    with pytest.raises(ValueError, match="CurveCoordinateSystem, is evaluated in Python one state at a time"):
        mb.simulate(curve, np.zeros((2, 1)), np.zeros((2, 1)), 1.0, **RK4)


def test_an_empty_batch_gives_empty_arrays():
    model = mb.robots.load("double_pendulum")
    batch = mb.simulate(model, np.zeros((0, 2)), np.zeros((0, 2)), 0.1, dt=0.05, **RK4)
    assert batch.q.shape == (0, 3, 2) and batch.energy.shape == (0, 3) and batch.status == []


# ============================================================================= the Trajectory of a batch

def test_a_batch_saves_and_loads_with_its_statuses(tmp_path):
    model = mb.robots.load("double_pendulum")
    v0 = np.array([[0.5, 0.0], [1e150, -1e150]])
    with pytest.warns(RuntimeWarning, match="stopped early"):
        batch = mb.simulate(model, np.zeros(2), v0, 0.1, dt=0.05, **RK4)
    loaded = mb.Trajectory.load(batch.save(tmp_path / "batch"))
    assert loaded.status == batch.status and loaded.completed.tolist() == [True, False]
    np.testing.assert_array_equal(loaded.q, batch.q)
    one = loaded.select(0)
    assert one.batch_size is None and one.completed is True and one.q.shape == (3, 2)
    with pytest.raises(ValueError, match="this is one trajectory"):
        one.select(0)
