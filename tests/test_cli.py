"""The command line: help, --version, info, check, demo --list, view's trajectory errors, compile, one line
and status 2 for every failure, a closed pipe (running a demo is exercised in test_nonholonomic_simulation.py)."""

import os
import subprocess
import sys

import numpy as np
import pytest

import multibody as mb
from multibody.cli import main


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for command in ("demo", "info", "check"):
        assert command in out


def test_info_prints_tree_sizes_mass_and_warnings(capsys, tmp_path):
    assert main(["info", "double_pendulum"]) == 0
    out = capsys.readouterr().out
    assert "nq = 2, nv = 2" in out and "total mass = 2 kg" in out
    assert "shoulder [continuous axis [0.0, 1.0, 0.0]] -> link1 1 kg" in out
    # A suspicious inertia is reported: a placeholder link with impossible numbers fixed to a valid body.
    urdf = tmp_path / "placeholder.urdf"
    urdf.write_text(
        '<robot name="r"><link name="base"/>'
        '<link name="arm"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/>'
        '</inertial></link>'
        '<link name="tag"><inertial><mass value="0.000001"/><inertia ixx="0" iyy="0" izz="0.000003" ixy="0" ixz="0" iyz="0"/>'
        '</inertial></link>'
        '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>'
        '<joint name="f" type="fixed"><parent link="arm"/><child link="tag"/></joint></robot>')
    assert main(["info", str(urdf)]) == 0
    out = capsys.readouterr().out
    assert "warning: link 'tag': principal moments violate the triangle inequality" in out
    assert "warning: link 'tag': placeholder mass" in out


def test_info_on_bad_input_exits_with_a_message(capsys, tmp_path):
    urdf = tmp_path / "bad.urdf"
    urdf.write_text('<robot name="x"><link name="a"/><link name="b"/>'
                    '<joint name="j" type="bogus"><parent link="a"/><child link="b"/></joint></robot>')
    assert main(["info", str(urdf)]) == 2
    err = capsys.readouterr().err
    assert "bad.urdf" in err and "<joint name='j'>" in err and "unknown joint type 'bogus'" in err


@pytest.mark.parametrize("command", ["info", "check"])
def test_missing_file_directory_and_unknown_robot_give_one_message_and_status(capsys, tmp_path, command):
    """info and check answer the same wrong input with the same line on standard error and status 2,
    before check looks for Pinocchio."""
    cases = {
        str(tmp_path / "absent.urdf"): f"multibody {command}: no such file: {str(tmp_path / 'absent.urdf')!r}",
        str(tmp_path): f"multibody {command}: {str(tmp_path)!r} is a directory; give a URDF file or a robot name",
        "no_such_robot": f"multibody {command}: 'no_such_robot' is neither a URDF file nor a known robot: "
                         "no shipped robot named 'no_such_robot'",
    }
    for source, message in cases.items():
        assert main([command, source]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.startswith(message), captured.err
        assert captured.err.count("\n") == 1


def test_info_takes_a_robot_name_or_a_path(capsys):
    assert main(["info", "diff_drive"]) == 0
    by_name = capsys.readouterr().out
    assert main(["info", mb.robots.path("diff_drive")]) == 0
    assert capsys.readouterr().out == by_name
    assert main(["info", "diff_drive", "--floating-base"]) == 0
    assert "nq = 13, nv = 11" in capsys.readouterr().out


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"multibody {mb.__version__}"


def test_demo_list(capsys):
    from multibody.demos import DEMOS

    assert main(["demo", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == sorted(DEMOS)
    assert "rolling-ball" in DEMOS and any(line.startswith("rolling-ball") and "ball rolling" in line for line in lines)
    assert main(["demo"]) == 2
    assert "give a demo name, or --list" in capsys.readouterr().err
    assert main(["demo", "no-such-demo"]) == 2
    assert "multibody demo: unknown demo 'no-such-demo'; available: " in capsys.readouterr().err


def test_check_against_pinocchio(capsys):
    pytest.importorskip("pinocchio")
    assert main(["check", mb.robots.path("double_pendulum"), "--samples", "3"]) == 0
    out = capsys.readouterr().out
    assert "all quantities agree with Pinocchio" in out
    assert "coriolis (recursive)" in out and "forward dynamics, backward error" in out


def test_view_of_a_broken_or_foreign_trajectory_is_one_line(capsys, tmp_path):
    """``multibody view NAME --trajectory FILE``: a damaged file, or a trajectory of another model, gives
    one line on standard error and status 2 (the model loads, the viewer is not started)."""
    pytest.importorskip("viser")
    pendulum = mb.robots.load("pendulum")
    saved = mb.simulate(pendulum, np.array([0.3]), np.zeros(1), 0.05, dt=0.01, progress=False).save(tmp_path / "run")
    with open(saved, "rb") as f:
        data = f.read()
    (tmp_path / "broken.npz").write_bytes(data[: len(data) // 2])
    cases = {
        ("double_pendulum", "broken.npz"): "is not a trajectory saved by Trajectory.save: File is not a zip file",
        ("double_pendulum", "run.npz"): "is a trajectory of another model: nq = 1 in the file, 2 in the model",
    }
    for (robot, name), message in cases.items():
        assert main(["view", robot, "--trajectory", str(tmp_path / name)]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.startswith("multibody view: ") and message in captured.err
        assert captured.err.count("\n") == 1, captured.err


def test_any_failure_is_one_line_with_status_2(capsys, monkeypatch):
    """Errors the commands do not expect (an OSError, a failure of multibody itself) are one line too."""
    from multibody import cli

    for error in (IsADirectoryError(21, "Is a directory", "out"), KeyError("link9"), RuntimeError("stalled")):
        def failing(args, error=error):
            raise error

        monkeypatch.setattr(cli, "cmd_info", failing)
        assert main(["info", "double_pendulum"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("multibody info: "), err
    assert err == "multibody info: RuntimeError: stalled\n"


@pytest.mark.skipif(sys.platform == "win32", reason="a closed pipe is EPIPE on POSIX")
def test_a_closed_pipe_stops_quietly():
    """``multibody info NAME | head``: the reader goes away before the output is written; the command stops
    with status 141 (128 + SIGPIPE, as the shell reports it for a program SIGPIPE stops) and says nothing."""
    process = subprocess.Popen([sys.executable, "-m", "multibody.cli", "info", "double_pendulum"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()  # (the parent's end: the child's writes now meet a pipe without a reader)
    try:
        err = process.stderr.read().decode()
        assert process.wait(timeout=120) == 141
    finally:
        process.kill()
        process.stderr.close()
    assert err == ""
    # the same through a shell pipeline into head
    done = subprocess.run(f'"{sys.executable}" -m multibody.cli info double_pendulum | head -1; '
                          'exit "${PIPESTATUS[0]}"', shell=True, executable="/bin/bash", capture_output=True,
                          text=True, timeout=120)
    assert done.stderr == "" and done.stdout == "model 'double_pendulum'\n"
    assert done.returncode in (0, 141)  # (0 when the output fitted the pipe before head left)


def test_all_kernels_lists_every_kernel():
    """``driver.ALL_KERNELS``, what ``multibody compile --all`` compiles, holds every function of
    ``multibody.kernels`` with the kernel signature ``(joints, reals, frames, x0, x1, x2, x3, out, ws)``."""
    import importlib
    import inspect
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    from multibody import driver, kernels

    found = set()
    for info in pkgutil.iter_modules(kernels.__path__):
        module = importlib.import_module(f"multibody.kernels.{info.name}")
        for value in vars(module).values():
            function = getattr(value, "py_func", value)
            if callable(function) and getattr(function, "__module__", None) == module.__name__:
                parameters = list(inspect.signature(function).parameters)
                if len(parameters) == 9 and parameters[:3] == ["joints", "reals", "frames"]:
                    found.add(value)
    assert len(found) > 30 and found == set(driver.ALL_KERNELS)
    assert all(isinstance(kernel, Dispatcher) for kernel in found) or os.environ.get("NUMBA_DISABLE_JIT") == "1"


@pytest.fixture
def fake_cache(monkeypatch):
    """Numba's on-disk cache and compile_kernels, pretended: a set of kernels "on disk", and the calls made."""
    from multibody import driver

    cache, calls = set(), []

    def compile_kernels(kernels=None, processes=None):
        calls.append(list(kernels))
        cache.update(kernels)

    monkeypatch.setattr(driver, "compiled_before", lambda kernels=None: all(k in cache for k in kernels))
    monkeypatch.setattr(driver, "compile_kernels", compile_kernels)
    return cache, calls


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")
def test_compile_compiles_what_the_cache_lacks(capsys, fake_cache):
    from multibody import contact, driver, integrators, variational
    from multibody.cli import _compiled_by_default
    from multibody.demos import KERNELS
    from multibody.kernels import stepping

    cache, calls = fake_cache
    default = _compiled_by_default()
    loops = driver.ENTRY_POINTS + integrators.ENTRY_POINTS + variational.ENTRY_POINTS + contact.ENTRY_POINTS
    kernels = default[: len(default) - len(loops)]
    # the demos' kernels (first) and the common dynamics calls', a part of every kernel, then the loops of batches
    # and of the fixed-step, variational and contact runs (a first RK4 simulation compiles no_controller, run and _batch)
    assert kernels[: len(KERNELS)] == KERNELS and len(set(kernels)) == len(kernels) < len(driver.ALL_KERNELS)
    assert set(kernels) <= set(driver.ALL_KERNELS) and mb.kernels.aba.forward_dynamics in kernels
    assert default[len(kernels):] == loops and len(set(loops)) == len(loops) == 12
    assert {(stepping.run, integrators._RUN_TYPES), (driver._batch, driver._BATCH_TYPES),
            (stepping.no_controller, integrators.CONTROLLER_TYPES),
            (mb.kernels.variational.advance, variational.ADVANCE_TYPES),
            (mb.kernels.timestepping.run, contact._RUN_TYPES), (contact._trajectories, contact._TRAJECTORIES_TYPES),
            (mb.kernels.timestepping.deepest_gaps, contact._GAPS_TYPES)} <= set(loops)
    which = ("the kernels of the demos and the common dynamics calls, and the loops of batches, fixed-step, variational "
             "and contact runs")
    cache.add(KERNELS[0])
    assert main(["compile"]) == 0
    assert calls == [list(default[1:])]
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"{which}: compiling {len(default) - 1} of {len(default)} on every core (1 compiled already)"
    assert out[1].startswith(f"compiled {len(default) - 1} functions in ") and len(out) == 2
    assert main(["compile"]) == 0 and len(calls) == 1
    assert capsys.readouterr().out == f"{which}: all {len(default)} compiled already, in Numba's cache on disk\n"
    cache.difference_update(loops[:2])  # (with --all too: the loops the cache lacks)
    assert main(["compile", "--all"]) == 0
    assert set(calls[1]) == (set(driver.ALL_KERNELS) - set(default)) | set(loops[:2])
    assert len(calls[1]) == len(set(calls[1]))
    assert (f"every kernel and the loops of batches, fixed-step, variational and contact runs: compiling {len(calls[1])} of "
            f"{len(driver.ALL_KERNELS) + len(loops)}") in capsys.readouterr().out


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")
def test_compile_reports_kernels_that_did_not_compile(capsys, monkeypatch, fake_cache):
    from multibody import driver

    from multibody.cli import _compiled_by_default

    monkeypatch.setattr(driver, "compile_kernels", lambda kernels=None, processes=None: None)  # a worker failed
    assert main(["compile"]) == 2
    err = capsys.readouterr().err
    count = len(_compiled_by_default())
    assert err.startswith(f"multibody compile: {count} of {count} functions did not compile (each compiles on its "
                          "first use instead): multibody.kernels.kkt:project, ") and err.count("\n") == 1
    assert ", multibody.driver:_batch, multibody.kernels.stepping:run, " in err  # (the loops by their functions)


def test_compile_fills_the_cache():
    """``multibody compile`` for real: afterwards the kernels it names are in Numba's cache on disk."""
    done = subprocess.run([sys.executable, "-m", "multibody.cli", "compile"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    from multibody import driver
    from multibody.cli import _compiled_by_default

    if os.environ.get("NUMBA_DISABLE_JIT") == "1":
        assert done.stdout == "nothing to compile: NUMBA_DISABLE_JIT=1 runs the kernels as Python\n"
    else:
        assert driver.compiled_before(_compiled_by_default())
        assert ("the kernels of the demos and the common dynamics calls, and the loops of batches, fixed-step, "
                "variational and contact runs: ") in done.stdout
