"""``mb.distributed``: batches split into chunks on a Dask ``LocalCluster`` of two worker processes equal the
single-process results (bit for bit: every state takes the same compiled arithmetic). Skipped without
Dask's distributed scheduler (the ``[dask]`` extra)."""

from __future__ import annotations

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import multibody as mb  # noqa: E402

from test_simulation_batched import ball_system, random_states  # noqa: E402


@pytest.fixture(scope="module")
def client():
    # two worker processes of one thread each (each task's kernels then run on one of the two cores)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    with cluster, distributed.Client(cluster) as connected:
        yield connected


@pytest.fixture(scope="module")
def pendulum_states():
    rng = np.random.default_rng(0)
    return mb.robots.load("double_pendulum"), rng.uniform(-2.0, 2.0, (1001, 2)), rng.standard_normal((1001, 2)), \
        rng.standard_normal((1001, 2))


def test_map_states_equals_one_process(client, pendulum_states):
    model, q, v, tau = pendulum_states
    M = mb.distributed.map_states(mb.mass_matrix, model, q, chunks=300, client=client)  # 4 chunks, the last short
    np.testing.assert_array_equal(M, mb.mass_matrix(model, q))
    a = mb.distributed.map_states(mb.forward_dynamics, model, q, v, tau, chunks=250, client=client)
    np.testing.assert_array_equal(a, mb.forward_dynamics(model, q, v, tau))


def test_calls_one_after_another_ship_the_model_each_time(client, pendulum_states):
    """The cluster may still be releasing an earlier call's copy of the same model: each call has its own."""
    model, q, _, _ = pendulum_states
    expected = mb.mass_matrix(model, q[:40])
    for _ in range(5):
        M = mb.distributed.map_states(mb.mass_matrix, model, q[:40], chunks=10, client=client)
        np.testing.assert_array_equal(M, expected)


def test_map_states_on_the_current_client_with_default_chunks(client, pendulum_states):
    model, q, v, _ = pendulum_states
    # no client given: the current one (this module's), one chunk per Dask thread
    energy = mb.distributed.map_states(mb.kinetic_energy, model, q, v)
    np.testing.assert_array_equal(energy, mb.kinetic_energy(model, q, v))


def test_map_states_with_a_constrained_system_and_tuple_results(client):
    ball, system = ball_system()
    q, v = random_states(ball, system, 50, seed=1)

    def accelerations_and_multipliers(system, q, v):
        return system.forward_dynamics(q, v)

    a, lam = mb.distributed.map_states(accelerations_and_multipliers, system, q, v, chunks=20, client=client)
    a_one, lam_one = system.forward_dynamics(q, v)
    np.testing.assert_array_equal(a, a_one)
    np.testing.assert_array_equal(lam, lam_one)


def test_simulate_many_equals_one_batch(client):
    ball, system = ball_system()
    q0, v0 = system.project(*random_states(ball, system, 9, seed=2))
    tau = np.random.default_rng(3).standard_normal((9, ball.nv))
    options = dict(dt=0.02, method="RK4")
    many = mb.distributed.simulate_many(system, q0, v0, 0.2, tau=tau, chunks=4, client=client, **options)
    one = mb.simulate(system, q0, v0, 0.2, tau=tau, **options)
    assert many.q.shape == one.q.shape == (9, 11, ball.nq) and many.status == one.status
    for name in ("q", "v", "lam", "energy", "residual"):
        np.testing.assert_array_equal(getattr(many, name), getattr(one, name))


def test_simulate_many_splits_pd_rows_per_trajectory_with_the_states(client):
    """An ``mb.PD`` whose gains, feed-forward forces and reference tables are per trajectory, ``(N, …)``, goes to
    each chunk with the rows of its trajectories: the trajectories equal one batch's bit for bit."""
    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(4)
    n, t_ref = 9, np.array([0.0, 0.1, 0.2])
    pd = mb.PD(rng.uniform(5.0, 20.0, (n, 2)), 1.5, rng.uniform(-1.0, 1.0, (n, 3, 2)), tau_ff=rng.standard_normal(
        (n, 2)), t_ref=t_ref)
    q0, v0 = rng.uniform(-1.0, 1.0, (n, 2)), rng.standard_normal((n, 2))
    options = dict(dt=0.02, method="RK4")
    many = mb.distributed.simulate_many(model, q0, v0, 0.2, tau=pd, chunks=4, client=client, **options)
    one = mb.simulate(model, q0, v0, 0.2, tau=pd, **options)
    assert many.q.shape == one.q.shape == (n, 11, 2) and many.status == one.status
    np.testing.assert_array_equal(many.q, one.q)
    np.testing.assert_array_equal(many.v, one.v)
    # rows for another number of trajectories: refused here, before anything is sent
    with pytest.raises(ValueError, match=r"mb.PD: kp has shape \(9, 2\), for 9 trajectories, but the simulation has "
                                         r"8 initial states"):
        mb.distributed.simulate_many(model, q0[:8], v0[:8], 0.2, tau=pd, client=client, **options)


def test_simulate_many_reports_stopped_trajectories(client):
    model = mb.robots.load("double_pendulum")
    v0 = np.array([[0.5, 0.0], [1e150, -1e150], [0.0, 0.5]])
    with pytest.warns(RuntimeWarning, match="1 of 3 trajectories stopped early"):
        many = mb.distributed.simulate_many(model, np.zeros(2), v0, 0.1, dt=0.05, method="RK4", chunks=2,
                                            client=client)
    assert many.completed.tolist() == [True, False, True]


def test_arguments_that_cannot_be_split_are_refused(client, pendulum_states):
    model, q, v, _ = pendulum_states
    with pytest.raises(ValueError, match=r"share a leading batch axis N.*arrays\[0\] \(1001, 2\), arrays\[1\] \(2,\)"):
        mb.distributed.map_states(mb.bias_forces, model, q, v[0], client=client)
    with pytest.raises(ValueError, match="chunks must be a positive number of states"):
        mb.distributed.map_states(mb.mass_matrix, model, q, chunks=0, client=client)
    with pytest.raises(ValueError, match="simulate one with mb.simulate"):
        mb.distributed.simulate_many(model, q[0], v[0], 1.0, client=client)
    with pytest.raises(ValueError, match="fixed-step method"):  # refused before anything is sent
        mb.distributed.simulate_many(model, q, v, 1.0, method="DOP853", client=client)
