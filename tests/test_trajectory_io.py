"""Trajectory.save and Trajectory.load: an .npz round trip without pickle, and clear errors for other files."""

import dataclasses
import errno
import os
import subprocess
import sys
import textwrap
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
    # (NumPy reads such a file as a pickle and suggests loading it unsafely: the message says what it is)
    with pytest.raises(ValueError, match=r"is not a trajectory saved by Trajectory.save: it is not a \.npz archive "
                                         r"\(it starts with b'not an'\)$"):
        mb.Trajectory.load(text)
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=r"it is not a \.npz archive \(empty\)$"):
        mb.Trajectory.load(empty)
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
    from multibody import runs

    # A run "expected" to take long: the threshold lowered to nothing, and output seen as a terminal. The bar
    # follows the compiled calls, so the run is longer than the first one's steps.
    monkeypatch.setattr(runs, "PROGRESS_AFTER", 0.0)
    monkeypatch.setattr(runs, "_visible", lambda: True)
    slow = lambda t, q, v: __import__("time").sleep(0.001) or np.zeros(1)  # noqa: E731
    model = mb.robots.load("pendulum")
    steps = 2 * runs.FIRST_CHUNK
    mb.simulate(model, np.array([0.3]), np.zeros(1), steps * 0.01, dt=0.01, method="RK4", tau=slow)
    assert "simulate: 100%" in capsys.readouterr().err
    monkeypatch.setattr(runs, "_visible", lambda: False)  # nobody would see it
    mb.simulate(model, np.array([0.3]), np.zeros(1), steps * 0.01, dt=0.01, method="RK4", tau=slow)
    assert capsys.readouterr().err == ""


def plain_trajectory(n, nq=2, nv=2, m=0, **fields):
    """A trajectory of ``n`` output times built by hand (no simulation): ramps, so that rows differ."""
    rows = np.arange(n, dtype=float)[:, None]
    values = dict(t=0.01 * np.arange(n, dtype=float), q=rows + np.arange(nq), v=rows - np.arange(nv),
                  lam=np.ones((n, m)), energy=np.full(n, 2.0), residual=np.zeros(n),
                  row_names=[f"row[{k}]" for k in range(m)])
    return mb.Trajectory(**{**values, **fields})


def failing_writer(monkeypatch, after):
    """NumPy's writer of one array in an archive, failing as a full disk does once ``after`` arrays are written."""
    write_array = np.lib.format.write_array
    written = []

    def write(fid, array, *args, **kwargs):
        if len(written) == after:
            raise OSError(errno.ENOSPC, "No space left on device")
        written.append(array.shape)
        return write_array(fid, array, *args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", write)


def test_a_full_disk_leaves_the_earlier_file(tmp_path, monkeypatch):
    """ENOSPC in the middle of a save: the error reaches the caller, the file saved before is untouched
    and loads, and no temporary file is left in the folder."""
    earlier = plain_trajectory(5)
    path = earlier.save(tmp_path / "run.npz")
    before = (tmp_path / "run.npz").read_bytes()
    failing_writer(monkeypatch, after=3)
    with pytest.raises(OSError) as error:
        plain_trajectory(1000, nq=7, nv=6).save(path)
    assert error.value.errno == errno.ENOSPC
    assert (tmp_path / "run.npz").read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["run.npz"]
    monkeypatch.undo()
    assert_same(mb.Trajectory.load(path), earlier)
    # a file that did not exist is not created by a failed save
    failing_writer(monkeypatch, after=1)
    with pytest.raises(OSError):
        earlier.save(tmp_path / "new.npz")
    assert sorted(os.listdir(tmp_path)) == ["run.npz"]


def test_a_killed_save_leaves_the_earlier_file(tmp_path):
    """``kill -9`` of a process writing a large trajectory, after it has written part of the archive: the
    file saved before is as it was and loads."""
    earlier = plain_trajectory(5)
    path = earlier.save(tmp_path / "run.npz")
    # The child writes q (11 MB), says so, and waits in the writer of the next array to be killed.
    child = textwrap.dedent(f"""
        import sys, time
        import numpy as np
        import multibody as mb

        write_array = np.lib.format.write_array
        def write(fid, array, *args, **kwargs):
            if array.shape == (200_000, 7):
                write_array(fid, array, *args, **kwargs)
                print("writing", flush=True)
                time.sleep(120)
            return write_array(fid, array, *args, **kwargs)
        np.lib.format.write_array = write
        n = 200_000
        rows = np.arange(n, dtype=float)[:, None]
        mb.Trajectory(t=np.arange(n, dtype=float), q=rows + np.arange(7), v=rows + np.arange(6),
                      lam=np.zeros((n, 0)), energy=np.zeros(n), residual=np.zeros(n)).save({path!r})
        print("saved", flush=True)
    """)
    process = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == "writing\n"  # (EOF, "", if the child failed or never waited)
        assert sum(f.stat().st_size for f in tmp_path.iterdir()) > 10e6  # q is on disk, in some file
    finally:
        process.kill()
        process.wait(timeout=60)
        process.stdout.close()
    assert_same(mb.Trajectory.load(path), earlier)
    # the killed write's temporary file is all that is left of it
    assert [f.name for f in tmp_path.iterdir() if f.name != "run.npz"] == [
        f.name for f in tmp_path.iterdir() if f.name.startswith(".run.npz.") and f.name.endswith(".tmp")]


def test_truncated_and_corrupted_files_raise_value_error(tmp_path):
    with open(plain_trajectory(50).save(tmp_path / "good"), "rb") as f:
        data = f.read()
    damaged = {f"cut at {cut}": data[:cut] for cut in (0, 4, 30, len(data) // 2, len(data) - 30)}
    for position in (len(data) // 3, len(data) // 2):
        flipped = bytearray(data)
        flipped[position] ^= 0xFF
        damaged[f"byte {position} flipped"] = bytes(flipped)
    for case, content in damaged.items():
        path = tmp_path / "damaged.npz"
        path.write_bytes(content)
        with pytest.raises(ValueError, match="is not a trajectory saved by Trajectory.save"):
            mb.Trajectory.load(path)
            pytest.fail(f"{case}: loaded")


def test_arrays_that_disagree_are_refused(tmp_path):
    """A file whose arrays disagree in length or are not floating point fails to load, naming the arrays;
    such a trajectory is not saved either (nothing written)."""
    format_entry = {"__multibody_format__": np.array(["multibody.Trajectory", "1"])}
    good = {name: getattr(plain_trajectory(4, m=1), name) for name in ("t", "q", "v", "lam", "energy", "residual")}
    cases = {
        "short q": ({"q": np.zeros((3, 2))}, r"disagree in length: q \(3, 2\) has \(n\) = \(3,\), but t \(4,\), "
                                             r"v \(4, 2\), lam \(4, 1\), energy \(4,\), residual \(4,\)"),
        "long residual": ({"residual": np.zeros(5)}, r"disagree in length: .*but residual \(5,\) \("),
        "energy as a table": ({"energy": np.zeros((4, 2))}, r"but energy \(4, 2\)"),
        "integer q and energy": ({"q": np.zeros((4, 2), dtype=np.int64), "energy": np.zeros(4, dtype=np.int32)},
                                 r"the arrays q \(int64\), energy \(int32\) are not floating point"),
        "t a number, lam text": ({"t": np.array(0.0), "lam": np.full((4, 1), "x")},
                                 "the fields t, lam must be arrays of floating point, got float, list"),
        "row names": ({"row_names": np.array(["a", "b"])}, r"row_names must be the names of the 1 constraint rows"),
    }
    for case, (changes, message) in cases.items():
        path = tmp_path / f"{case}.npz"
        np.savez(path, **format_entry, **{**good, "row_names": np.array(["row[0]"]), **changes})
        with pytest.raises(ValueError, match="is not a trajectory saved by Trajectory.save: .*" + message):
            mb.Trajectory.load(path)
    with pytest.raises(ValueError, match=r"Trajectory.save: the trajectory: the arrays disagree in length: .*"
                                         r"energy \(3,\)"):
        plain_trajectory(4, energy=np.zeros(3)).save(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match=r"status must be a list of 2 strings"):
        plain_trajectory(3, q=np.zeros((2, 3, 2)), v=np.zeros((2, 3, 2)), lam=np.zeros((2, 3, 0)),
                         energy=np.zeros((2, 3)), residual=np.zeros((2, 3)), status="completed").save(tmp_path / "b")
    assert not (tmp_path / "bad.npz").exists() and not (tmp_path / "b.npz").exists()


def test_the_file_records_its_model_and_load_checks_it(tmp_path, pendulum_on_a_rod):
    model = mb.robots.load("double_pendulum")
    trajectory = pendulum_on_a_rod
    assert trajectory.joint_names == list(model.joint_names) == ["shoulder", "elbow"]
    assert (trajectory.nq, trajectory.nv) == (model.nq, model.nv)
    path = trajectory.save(tmp_path / "run.npz")
    for fits in (model, mb.ConstrainedSystem(model, [])):
        assert mb.Trajectory.load(path, model=fits).joint_names == ["shoulder", "elbow"]
    with pytest.raises(ValueError, match=r"'.*run.npz' is a trajectory of another model: nq = 2 in the file, 1 in "
                                         r"the model 'pendulum'; nv = 2 in the file, 1 in the model 'pendulum'"):
        mb.Trajectory.load(path, model=mb.robots.load("pendulum"))
    with open(mb.robots.path("double_pendulum"), encoding="utf-8") as f:
        renamed = mb.load_urdf(f.read().replace('"elbow"', '"knee"'))
    assert renamed.nq == 2 and list(renamed.joint_names) == ["shoulder", "knee"]
    with pytest.raises(ValueError, match="another model: joint 1 is 'elbow' in the file, 'knee' in the model"):
        mb.Trajectory.load(path, model=renamed)
    # A file without the record (a trajectory built without it) loads, and is checked on nq and nv only.
    unnamed = plain_trajectory(3).save(tmp_path / "unnamed.npz")
    assert mb.Trajectory.load(unnamed, model=renamed).joint_names is None
    with pytest.raises(ValueError, match="nq = 2 in the file, 1 in the model 'pendulum'"):
        mb.Trajectory.load(unnamed, model=mb.robots.load("pendulum"))


def test_every_kind_of_run_records_its_model():
    """Batched, variational and failed runs record the joint names; a symbolic system its coordinates."""
    model = mb.robots.load("double_pendulum")
    q0, v0 = np.array([0.3, 0.2]), np.zeros(2)
    batch = mb.simulate(model, np.tile(q0, (3, 1)), np.zeros((3, 2)), 0.05, dt=0.01, method="RK4", progress=False)
    assert batch.joint_names == ["shoulder", "elbow"] and batch.select(1).joint_names == ["shoulder", "elbow"]
    assert mb.simulate(model, q0, v0, 0.05, dt=0.01, method="variational").joint_names == ["shoulder", "elbow"]
    with pytest.raises(mb.SimulationError) as failure:
        mb.simulate(model, q0, v0, 0.05, dt=0.01, method="RK4", tau=lambda t, q, v: np.full(2, np.nan if t > 0.02
                                                                                            else 0.0))
    assert failure.value.trajectory.joint_names == ["shoulder", "elbow"]
    sympy = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    r, theta = dynamicsymbols("r theta")
    m, k = sympy.symbols("m k", positive=True)
    kepler = mb.LagrangianSystem([r, theta], m / 2 * (r.diff() ** 2 + r**2 * theta.diff() ** 2), -k / r)
    orbit = mb.simulate(kepler.numeric(m=1.0, k=1.0), np.array([1.0, 0.0]), np.array([0.0, 1.0]), 0.05, dt=0.01)
    assert orbit.joint_names == ["r", "theta"]


def test_repr_is_a_few_lines():
    trajectory = plain_trajectory(10_000, m=3, status="simulation stopped at t = 99.99 s: the state became "
                                                     "non-finite", joint_names=["shoulder", "elbow"])
    text = repr(trajectory)
    assert text.splitlines() == [
        "Trajectory: 10000 output times, t = 0 to 99.99 s",
        "  q (10000, 2), v (10000, 2), lam (10000, 3), energy (10000,), residual (10000,)",
        "  constraint rows: 3: row[0], row[1], row[2]",
        "  model: nq = 2, nv = 2, joints 2: shoulder, elbow",
        "  status: simulation stopped at t = 99.99 s: the state became non-finite"]
    batch = plain_trajectory(4, q=np.zeros((3, 4, 2)), v=np.zeros((3, 4, 2)), lam=np.zeros((3, 4, 0)),
                             energy=np.zeros((3, 4)), residual=np.zeros((3, 4)), projection_tolerance=1e-12,
                             status=["completed", "stopped at t = 0.02 s", "completed"])
    assert repr(batch).splitlines() == [
        "Trajectory: 3 trajectories, 4 output times, t = 0 to 0.03 s",
        "  q (3, 4, 2), v (3, 4, 2), lam (3, 4, 0), energy (3, 4), residual (3, 4)",
        "  constraint rows: 0",
        "  outputs projected onto the constraints above a residual of 1e-12",
        "  status: 2 completed, 1 stopped early; trajectory 1: stopped at t = 0.02 s"]
    many = plain_trajectory(2, m=40)
    assert "constraint rows: 40: row[0], row[1], row[2], row[3], ... (36 more)" in repr(many)
    assert repr(plain_trajectory(0)).splitlines()[0] == "Trajectory: 0 output times, no output times"
