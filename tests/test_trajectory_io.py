"""Trajectory.save and Trajectory.load: an .npz round trip without pickle, and clear errors for other files."""

import dataclasses
import zipfile

import numpy as np
import pytest

import multibody as mb


def assert_same(a, b):
    for f in dataclasses.fields(mb.Trajectory):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert isinstance(y, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert type(x) is type(y) and x == y, f.name


@pytest.fixture(scope="module")
def pendulum_on_a_rod():
    """A simulated double pendulum whose tip is held at a distance from the origin: every field filled."""
    model = mb.robots.load("double_pendulum")
    tip = mb.Distance("link2", None, 1.5, point_a=(0.0, 0.0, -1.0))
    system = mb.ConstrainedSystem(model, [tip])
    q0 = np.array([0.5, 1.0])
    q0, v0 = system.project(q0, np.zeros(2))
    return mb.simulate(system, q0, v0, 0.2, dt=0.01, progress=False)


def test_round_trip_keeps_every_field(tmp_path, pendulum_on_a_rod):
    trajectory = pendulum_on_a_rod
    assert trajectory.lam.shape == (21, 1) and trajectory.row_names and trajectory.projection_tolerance == 1e-12
    path = trajectory.save(tmp_path / "run.npz")
    assert path == str(tmp_path / "run.npz")
    assert_same(mb.Trajectory.load(path), trajectory)
    # the suffix is added when missing; the file opens without pickle
    path = trajectory.save(tmp_path / "run2")
    assert path.endswith("run2.npz")
    with np.load(path, allow_pickle=False) as archive:
        assert archive["row_names"].dtype.kind == "U" and archive["status"].dtype.kind == "U"


def test_round_trip_of_a_stopped_run_without_constraints(tmp_path):
    n = 3
    trajectory = mb.Trajectory(t=np.arange(n, dtype=float), q=np.full((n, 7), np.nan), v=np.zeros((n, 6)),
                               lam=np.zeros((n, 0)), energy=np.array([1.0, np.nan, np.inf]), residual=np.zeros(n),
                               status="simulation stopped at t = 2 s: the state became non-finite")
    loaded = mb.Trajectory.load(trajectory.save(tmp_path / "stopped.npz"))
    assert loaded.row_names == [] and loaded.projection_tolerance is None and loaded.lam.shape == (n, 0)
    for f in dataclasses.fields(mb.Trajectory):
        x, y = getattr(trajectory, f.name), getattr(loaded, f.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y


def test_loading_other_files_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError):
        mb.Trajectory.load(tmp_path / "absent.npz")
    text = tmp_path / "notes.npz"
    text.write_text("not an archive")
    with pytest.raises(ValueError, match="is not a trajectory saved by Trajectory.save"):
        mb.Trajectory.load(text)
    one_array = tmp_path / "array.npy"
    np.save(one_array, np.zeros(3))
    with pytest.raises(ValueError, match="holds one array, not a .npz archive"):
        mb.Trajectory.load(one_array)
    other = tmp_path / "other.npz"
    np.savez(other, t=np.zeros(3), q=np.zeros((3, 1)))
    with pytest.raises(ValueError, match=r"without the entry '__multibody_format__' \(it has \['q', 't'\]\)"):
        mb.Trajectory.load(other)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, __multibody_format__=np.array(["multibody.Trajectory", "1"]),
             **{name: np.zeros(2) for name in ("t", "q", "v", "lam", "energy")},
             residual=np.array([object(), None], dtype=object))
    with pytest.raises(ValueError, match="is not a trajectory saved by Trajectory.save: .*pickle"):
        mb.Trajectory.load(pickled)
    incomplete = tmp_path / "incomplete.npz"
    np.savez(incomplete, __multibody_format__=np.array(["multibody.Trajectory", "1"]), t=np.zeros(2))
    with pytest.raises(ValueError, match=r"lacks the arrays \['q', 'v', 'lam', 'energy', 'residual'\]"):
        mb.Trajectory.load(incomplete)
    newer = tmp_path / "newer.npz"
    np.savez(newer, __multibody_format__=np.array(["multibody.Trajectory", "2"]))
    with pytest.raises(ValueError, match="version '2'; this version of multibody reads"):
        mb.Trajectory.load(newer)
    assert zipfile.is_zipfile(newer)


def test_progress_bar_on_request(capsys):
    model = mb.robots.load("pendulum")
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.1, dt=0.01, method="RK4", progress=True)
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.1, dt=0.01, progress=True)
    err = capsys.readouterr().err
    assert err.count("simulate: 100%") == 2 and "t = 0.1/0.1 s" in err
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.1, dt=0.01, progress=False)
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.1, dt=0.01)  # short: no bar by default
    assert capsys.readouterr().err == ""
    with pytest.raises(ValueError, match="progress must be None"):
        mb.simulate(model, np.array([0.3]), np.zeros(1), 0.1, progress="yes")


def test_progress_bar_for_a_long_run(capsys, monkeypatch):
    from multibody import simulation

    # A run "expected" to take long: the threshold lowered to nothing, and output seen as a terminal.
    monkeypatch.setattr(simulation, "PROGRESS_AFTER", 0.0)
    monkeypatch.setattr(simulation, "_visible", lambda: True)
    slow = lambda t, q, v: __import__("time").sleep(0.004) or np.zeros(1)  # noqa: E731
    model = mb.robots.load("pendulum")
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.3, dt=0.01, method="RK4", tau=slow)
    assert "simulate: 100%" in capsys.readouterr().err
    monkeypatch.setattr(simulation, "_visible", lambda: False)  # nobody would see it
    mb.simulate(model, np.array([0.3]), np.zeros(1), 0.3, dt=0.01, method="RK4", tau=slow)
    assert capsys.readouterr().err == ""
