"""The demos (multibody/demos.py): the list, the frames of the rolling ball's animation, each demo's
figures (short runs), and ``--view``. The full rolling-ball demo is run through the command line in
test_nonholonomic_simulation.py."""

import numpy as np
import pytest

import multibody as mb
from multibody import demos
from multibody.cli import main


def test_demo_list_names_the_ball_the_bead_the_four_bar_and_the_coin(capsys):
    assert main(["demo", "--list"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert {"rolling-ball", "bead-on-wire", "four-bar", "rolling-coin"} <= set(listed)


def test_animation_frames_keep_the_turn_per_frame_below_half_a_radian():
    # a body spinning ever faster about z: ω = 10 t rad/s, 4 s at 0.005 s
    t = np.arange(0.0, 4.0 + 1e-9, 0.005)
    angle = 5.0 * t**2
    quat = np.stack([0 * t, 0 * t, np.sin(angle / 2), np.cos(angle / 2)], axis=1)
    frames, delay, turn = demos.animation_frames(t, quat)
    steps = np.diff(angle[frames])
    assert turn < 0.5 and steps.max() < 0.5 and turn == pytest.approx(steps.max(), rel=1e-6)
    assert np.all(np.diff(frames) == frames[1] - frames[0])                   # uniform in time
    assert delay >= 0.02 and delay == pytest.approx(round(delay, 2))
    # states too far apart for any choice of frames
    with pytest.raises(ValueError, match="smaller output interval"):
        demos.animation_frames(t, np.stack([0 * t, 0 * t, np.sin(10 * angle), np.cos(10 * angle)], axis=1))
    # a slow body gets the largest interval, 0.04 s
    frames, delay, turn = demos.animation_frames(t, np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
    assert frames[1] - frames[0] == 8 and delay == 0.04 and turn == 0.0


def test_setups_start_on_their_constraints():
    for setup in (demos.rolling_ball_setup(), demos.bead_on_wire_setup(), demos.four_bar_setup(),
                  demos.rolling_coin_setup()):
        assert setup.system.residual(setup.q0, setup.v0) < 1e-10
        assert isinstance(setup.model, mb.Model)
    ball = demos.rolling_ball_setup(velocity=(-1.0, 1.0))
    R = mb.spatial.quat_to_rotation(ball.q0[3:])
    (contact,) = ball.constraints
    np.testing.assert_allclose(contact.frame[:, :2].T @ R @ ball.v0[:3], [-1.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("name, duration, files", [
    ("bead-on-wire", 0.3, ["bead_on_wire_state.png", "bead_on_wire_energy.png", "bead_on_wire_residual.png",
                           "bead_on_wire_multipliers.png"]),
    ("four-bar", 0.3, ["four_bar_state.png", "four_bar_energy.png", "four_bar_residual.png",
                       "four_bar_multipliers.png"]),
    ("rolling-coin", 0.1, ["rolling_coin_state.png", "rolling_coin_energy.png", "rolling_coin_residual.png",
                           "rolling_coin_multipliers.png", "rolling_coin_path.png"]),
])
def test_each_demo_writes_its_figures_and_gives_the_viewer_its_motion(tmp_path, name, duration, files):
    result = demos.DEMOS[name](str(tmp_path), duration=duration)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)
    assert sorted(result.paths) == sorted(str(tmp_path / f) for f in files)
    assert result.summary["largest constraint residual"] < 1e-9
    assert result.trajectory.t[-1] == pytest.approx(duration)
    assert all(body in result.model.body_names for body in result.trace)
    scene = mb.viewer.scene_of(result.model, trajectory=result.trajectory, constraints=result.constraints,
                               trace=result.trace)
    assert scene.arrows.shape[1] >= 1 and scene.largest_force > 0.0


def test_demo_view_opens_the_viewer_on_the_demo(monkeypatch, tmp_path, capsys):
    pytest.importorskip("viser")
    from multibody import cli

    shown = {}

    def fake_demo(out_dir, duration=0.2):
        """The four-bar, briefly."""
        return demos.four_bar(out_dir, duration=duration)

    def serve(handle, html=None):
        shown["viewer"] = handle
        handle.close()
        return 0

    monkeypatch.setitem(demos.DEMOS, "four-bar", fake_demo)
    monkeypatch.setattr(cli, "_serve", serve)
    assert main(["demo", "four-bar", "--out", str(tmp_path), "--view", "--port", "0"]) == 0
    handle = shown["viewer"]
    assert handle.closed and handle.scene.frames == 21 and "coupler_tip" in handle.scene.traces
    assert handle.scene.arrows.shape[1] == 2                                  # the pin force on both bodies
