"""Batched constrained dynamics and the dense-output path of ``mb.simulate`` (rolling ball on a tilted plane)."""

import numpy as np
import pytest

import multibody as mb
from multibody.constrained import ModelSystem

TILT = 0.1
RADIUS = 0.1


def ball_system(disc=False):
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    normal = (np.sin(TILT), 0.0, np.cos(TILT))
    constraint = mb.RollingDisc("ball", RADIUS, plane_normal=normal) if disc else \
        mb.RollingSphere("ball", RADIUS, plane_normal=normal)
    return ball, mb.ConstrainedSystem(ball, [constraint])


def random_states(ball, cs, n, seed=0):
    rng = np.random.default_rng(seed)
    q = ball.random_configuration(rng, (n,))
    q[:, :3] = RADIUS * np.array([np.sin(TILT), 0.0, np.cos(TILT)]) + 0.01 * rng.standard_normal((n, 3))
    v = rng.standard_normal((n, ball.nv))
    return q, v


def test_mass_matrix_and_bias_equals_crba_and_rnea():
    ball, _ = ball_system()
    q, v = random_states(ball, _, 4)
    M, h = ModelSystem(ball).mass_matrix_and_bias(q, v)
    assert np.abs(M - mb.mass_matrix(ball, q)).max() <= 1e-12
    assert np.abs(h - mb.bias_forces(ball, q, v)).max() <= 1e-12


@pytest.mark.parametrize("disc", [False, True])
def test_batched_solve_residual_and_project_equal_single_calls(disc):
    ball, cs = ball_system(disc)
    assert cs.batched
    q, v = random_states(ball, cs, 5)
    tau = np.random.default_rng(1).standard_normal((5, ball.nv))
    batch = cs.solve(q, v, tau)
    residual = cs.residual(q, v)
    q_p, v_p = cs.project(q, v)
    for k in range(5):
        single = cs.solve(q[k], v[k], tau[k])
        assert np.abs(batch.a[k] - single.a).max() <= 1e-10 * max(1.0, np.abs(single.a).max())
        assert np.abs(batch.lam[k] - single.lam).max() <= 1e-10 * max(1.0, np.abs(single.lam).max())
        assert batch.rank[k] == single.rank == 3
        assert residual[k] == pytest.approx(cs.residual(q[k], v[k]), rel=1e-12, abs=1e-15)
        # Each state of the batch stops at its own tolerance, taking the Gauss–Newton steps it takes alone:
        # the two differ by rounding only (the batch's linear algebra runs through numpy.linalg).
        q_k, v_k = cs.project(q[k], v[k])
        assert np.abs(q_p[k] - q_k).max() <= 1e-14
        assert np.abs(v_p[k] - v_k).max() <= 1e-14 * max(1.0, np.abs(v_k).max())
    assert cs.residual(q_p, v_p).max() <= 1e-12


def test_user_constraints_take_one_state_at_a_time():
    ball, _ = ball_system()
    cs = mb.ConstrainedSystem(ball, [mb.Holonomic(lambda q, t: q[2:3] - RADIUS)])
    assert not cs.batched
    q, v = random_states(ball, cs, 2)
    with pytest.raises(ValueError, match="one state at a time"):
        cs.solve(q, v)


def test_residual_matches_its_definition():
    ball, cs = ball_system()
    q, v = random_states(ball, cs, 1)
    phi = cs.position_error(q[0])
    assert cs.residual(q[0], v[0]) == pytest.approx(max(np.abs(phi).max(), np.abs(cs.velocity_error(q[0], v[0])).max()))


def test_dense_output_at_a_high_rate_agrees_with_landing_on_coarse_output_times():
    """Output every 1 ms (much shorter than DOP853's steps: dense output) against output every 0.1 s
    (each interval landed on exactly): the same motion to the integration tolerance; the residual
    reported is that of the returned states, which are on the constraints."""
    ball, cs = ball_system()
    q0 = ball.neutral()
    q0[:3] = RADIUS * np.array([np.sin(TILT), 0.0, np.cos(TILT)])
    q0, v0 = cs.project(q0, np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]))
    fine = mb.simulate(cs, q0, v0, 0.5, dt=1e-3, method="DOP853", rtol=1e-10, atol=1e-12)
    coarse = mb.simulate(cs, q0, v0, 0.5, dt=0.1, method="DOP853", rtol=1e-10, atol=1e-12)
    assert len(fine) == 501
    assert np.abs(fine.q[::100] - coarse.q).max() <= 1e-8
    assert np.abs(fine.v[::100] - coarse.v).max() <= 1e-8
    assert fine.residual.max() <= 1e-12
    recomputed = np.array([cs.residual(q, v) for q, v in zip(fine.q[::50], fine.v[::50])])
    assert np.abs(recomputed - fine.residual[::50]).max() <= 1e-15
    lam = np.array([cs.forward_dynamics(q, v)[1] for q, v in zip(fine.q[::50], fine.v[::50])])
    assert np.abs(lam - fine.lam[::50]).max() <= 1e-10 * np.abs(lam).max()
    # rolling down the slope at 5/7 g sin α, energy conserved
    assert np.abs(fine.energy - fine.energy[0]).max() <= 1e-8
