"""The contact examples (examples/box_on_incline.py, sliding_sphere.py, bouncing_ball.py, box_stack.py,
quadruped.py, panda_limits.py): each main writes its figure and returns what it printed, which matches the closed
forms the example states. The step's exact discrete values of the same scenes are tests/test_contact.py's; here
the examples' own quantities: a sweep of slopes, the friction force of a rolling transition, the apexes of a
drop, a stack of four dropped boxes, a quadruped standing, the Panda's limits."""

import os
import runpy

import numpy as np
import pytest

from multibody import contact

EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")
G = 9.81


def run_example(name, tmp_path):
    """``examples/<name>.py``'s main run into ``tmp_path``: its summary, after checking that it wrote its figure
    ``<name>.png`` and nothing else."""
    summary = runpy.run_path(os.path.join(EXAMPLES, f"{name}.py"))["main"](str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{name}.png"]
    assert summary["paths"] == [str(tmp_path / f"{name}.png")] and (tmp_path / f"{name}.png").stat().st_size > 0
    return summary


def test_box_on_incline_sticks_below_atan_mu_and_slips_above(tmp_path):
    """Over the sweep of slopes, the friction force is m g sin α below atan μ and μ m g cos α above, the normal
    force m g cos α, the acceleration 0 then g (sin α − μ cos α) (the step's exact value: a constant acceleration
    changes the velocity by dt times it per step), each to the solver's tolerance times the forces' scale."""
    summary = run_example("box_on_incline", tmp_path)
    slopes = summary["slopes"]
    assert (slopes < summary["critical slope"]).any() and (slopes > summary["critical slope"]).any()
    assert summary["critical slope"] == pytest.approx(np.arctan(0.4), rel=1e-15)
    assert summary["friction error"] <= 1e-8 and summary["normal error"] <= 1e-8
    assert summary["acceleration error"] <= 1e-10
    assert (summary["acceleration"][slopes < summary["critical slope"]] == pytest.approx(0.0, abs=1e-10))
    assert summary["largest residual"] <= contact.TOLERANCE


def test_sliding_sphere_rolls_after_2v0_over_7_mu_g(tmp_path):
    """The sphere rolls from the first step at or after 2v₀/(7μg), then at 5v₀/7 with its spin times its radius
    equal; friction is −μ m g at every sliding step and zero once it rolls."""
    summary = run_example("sliding_sphere", tmp_path)
    rolls = summary["closed-form roll time"]
    assert rolls == pytest.approx(2 * 2.0 / (7 * 0.3 * G), rel=1e-15)
    assert rolls <= summary["rolls at"] < rolls + 1e-3
    assert summary["final speed"] == pytest.approx(5 * 2.0 / 7, abs=1e-11)
    assert summary["final spin times radius"] == pytest.approx(5 * 2.0 / 7, abs=1e-11)
    np.testing.assert_allclose(summary["sliding friction"], -0.3 * G, rtol=0, atol=1e-9)
    np.testing.assert_allclose(summary["rolling friction"], 0.0, atol=1e-9)
    assert summary["speed error"] <= 1e-11


def test_bouncing_ball_apexes_fall_by_e_squared_and_it_rests(tmp_path):
    """Each apex is e² times the one before, to the step's O(dt) (test_contact.py bounds the discrete apexes
    exactly); the ball comes to rest after finitely many bounces and the ground then carries its weight."""
    summary = run_example("bouncing_ball", tmp_path)
    heights = summary["apexes"]
    assert summary["bounces"] >= 5 and len(heights) == summary["bounces"] + 1
    ratios = heights[1:6] / heights[:5]
    np.testing.assert_allclose(ratios, 0.7**2, rtol=0.03)
    np.testing.assert_allclose(heights[:6], summary["closed-form apexes"][:6], rtol=0.1, atol=2e-3)
    assert summary["resting speed"] <= 1e-9
    np.testing.assert_allclose(summary["resting force"], G, rtol=0, atol=1e-8)
    assert summary["largest residual"] <= contact.TOLERANCE


def test_box_stack_interfaces_carry_the_weight_above(tmp_path):
    """Four boxes dropped onto each other come to rest, each interface then carrying g times the mass above it,
    to 1e-6 N."""
    summary = run_example("box_stack", tmp_path)
    np.testing.assert_allclose(summary["weights above"], G * np.array([3.75, 1.75, 0.75, 0.25]), rtol=1e-15)
    assert summary["rests from"] < 0.2 and summary["resting speed"] <= 1e-9
    assert len(summary["resting forces"]) > 100
    np.testing.assert_allclose(summary["resting forces"], np.broadcast_to(summary["weights above"],
                                                                          summary["resting forces"].shape), atol=1e-6)
    assert summary["largest residual"] <= contact.TOLERANCE


def test_quadruped_lands_and_stands_on_its_feet(tmp_path):
    """The Go1 lands on its four feet only and stands: over the last half second (its PD's slowest mode down to
    mm/s) the feet's normal forces sum to its weight within 0.2 % and the front pair carries the share of the
    moment balance about the rear feet within 1 %."""
    summary = run_example("quadruped", tmp_path)
    assert summary["status"] == "completed"
    assert summary["bodies touching"] == {"FL_foot", "FR_foot", "RL_foot", "RR_foot"}
    standing = summary["standing"]
    weight = summary["weight"]
    assert summary["standing speed"] <= 1e-2
    np.testing.assert_allclose(summary["total"][standing], weight, rtol=2e-3)
    np.testing.assert_allclose(summary["front"][standing], summary["front closed form"][standing], rtol=1e-2)
    assert summary["largest residual"] <= contact.TOLERANCE


def test_panda_limits_keep_the_fingers_in_the_hand(tmp_path):
    """With its limits enforced the falling Panda stays within them and its fingers within their 4 cm; without,
    the fingers leave the hand. (test_contact.py checks that each limit force points into the range.)"""
    summary = run_example("panda_limits", tmp_path)
    assert summary["largest excursion past a limit"] <= 1e-12
    held, free = summary["held fingers"], summary["free fingers"]
    assert (held >= -1e-12).all() and (held <= 0.04 + 1e-12).all()
    assert np.abs(free[-1]).max() > 1.0
    assert np.count_nonzero(summary["forces"][:, 7:]) > 0
    assert summary["largest residual"] <= contact.TOLERANCE
