"""One RK4 step and its derivatives (``mb.rk4_step``, ``mb.rk4_step_derivatives``): the step equals the
step ``simulate(method="RK4")`` takes, and its derivatives equal central differences of the step in the
tangent space, for models (the double pendulum, a branched tree of revolute, prismatic and translation
joints, a tree of every joint kind with a free-flyer base) and constrained systems (a four-bar, a ball
rolling on a tilted plane); batched equals single."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import pose_from_xyz_rpy

from constraint_helpers import four_bar
from dyn_helpers import assert_rel, central_differences, central_differences_vector, coordinate_tree_model, random_tree_model
from rolling_helpers import BALL_RADIUS, free_ball, quat, tilted_normal

DT = 0.01
FD_TOL = 1e-7  # the central differences of the step are good to about 1e-9 here


def _systems():
    pendulum = mb.robots.load("double_pendulum")
    tree = coordinate_tree_model(0)
    model, tip, pivot = four_bar()
    in_plane = pose_from_xyz_rpy(pivot, [np.pi / 2, 0.0, 0.0])  # frame A's x–y plane: the mechanism's x–z
    closed = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=in_plane, frame_b=tip, kind="planar")])
    rng = np.random.default_rng(0)
    q4, v4 = closed.project(np.array([-1.2, 1.0, 1.5]), rng.standard_normal(3))
    every_kind = random_tree_model(1)
    ball = free_ball()
    rolling = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", BALL_RADIUS, plane_normal=tilted_normal(0.4, 0.2))])
    q_ball, v_ball = rolling.project(np.concatenate([[0.1, 0.2, 0.3], quat(mb.spatial.rpy_to_rotation([0.3, -0.2, 1.0]))]),
                                    rng.standard_normal(6))
    return {
        "every_joint_kind": (every_kind, every_kind.random_configuration(rng), rng.standard_normal(every_kind.nv)),
        "rolling_ball": (rolling, q_ball, v_ball),
        "double_pendulum": (pendulum, pendulum.random_configuration(rng), rng.standard_normal(pendulum.nv)),
        "coordinate_tree": (tree, tree.random_configuration(rng), rng.standard_normal(tree.nv)),
        "four_bar": (closed, q4, v4),
    }


SYSTEMS = _systems()


@pytest.mark.parametrize("name", list(SYSTEMS))
def test_step_is_simulates_rk4_step(name):
    system, q, v = SYSTEMS[name]
    tau = np.linspace(-0.5, 0.5, v.shape[-1])
    q_next, v_next = mb.rk4_step(system, q, v, tau, DT)
    trajectory = mb.simulate(system, q, v, DT, dt=DT, method="RK4", tau=tau, project=False, limits="ignore")
    np.testing.assert_allclose(q_next, trajectory.q[-1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(v_next, trajectory.v[-1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", list(SYSTEMS))
def test_step_derivatives_match_central_differences(name):
    system, q, v = SYSTEMS[name]
    nv = v.shape[-1]
    tau = np.linspace(-0.5, 0.5, nv)
    (q_next, v_next), d = mb.rk4_step_derivatives(system, q, v, tau, DT)
    np.testing.assert_array_equal(q_next, mb.rk4_step(system, q, v, tau, DT)[0])

    model = system if isinstance(system, mb.Model) else system.model

    def step(q_, v_, tau_):
        # q⁺ in the tangent space at the unperturbed q⁺
        q_plus, v_plus = mb.rk4_step(system, q_, v_, tau_, DT)
        return np.concatenate([model.difference(q_next, q_plus), v_plus])

    references = {"q": central_differences(lambda x: step(x, v, tau), model, q),
                  "v": central_differences_vector(lambda x: step(q, x, tau), v),
                  "tau": central_differences_vector(lambda x: step(q, v, x), tau)}
    for x, reference in references.items():
        ours = np.concatenate([getattr(d, f"dq_d{x}"), getattr(d, f"dv_d{x}")])
        assert ours.shape == (2 * nv, nv)
        assert_rel(ours, reference, FD_TOL, f"d(q⁺, v⁺)/d{x}", batch_ndim=0)


def test_batched_equals_single():
    system, q, v = SYSTEMS["double_pendulum"]
    rng = np.random.default_rng(1)
    qs, vs, taus = np.stack([q, -q]), np.stack([v, 2 * v]), rng.standard_normal((2, system.nv))
    (q_next, v_next), d = mb.rk4_step_derivatives(system, qs, vs, taus, DT)
    for k in range(2):
        (q1, v1), d1 = mb.rk4_step_derivatives(system, qs[k], vs[k], taus[k], DT)
        np.testing.assert_allclose(q_next[k], q1, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(v_next[k], v1, rtol=1e-14, atol=1e-14)
        for name in ("dq_dq", "dq_dv", "dq_dtau", "dv_dq", "dv_dv", "dv_dtau"):
            np.testing.assert_allclose(getattr(d, name)[k], getattr(d1, name), rtol=1e-13, atol=1e-13, err_msg=name)


def test_bad_input_is_refused():
    system, q, v = SYSTEMS["double_pendulum"]
    with pytest.raises(ValueError, match="shapes"):
        mb.rk4_step(system, q, v, np.zeros(3), DT)
    with pytest.raises(ValueError, match="dt"):
        mb.rk4_step(system, q, v, np.zeros(2), -DT)
    with pytest.raises(TypeError, match="Model or a ConstrainedSystem"):
        mb.rk4_step("pendulum", q, v, np.zeros(2), DT)
