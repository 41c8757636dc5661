"""The benchmark script runs end to end (tiny sizes), so that it never rots. Speed itself is
measured by benchmarks/run.py, never asserted here."""

import json
import os
import re
import runpy

import pytest


def test_benchmark_script_smoke(tmp_path):
    pytest.importorskip("pinocchio")
    script = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "run.py")
    main = runpy.run_path(script)["main"]
    assert main(["--quick", "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    algorithms = {row["algorithm"] for row in results["rows"]}
    assert algorithms == {"rnea", "crba", "aba", "coriolis", "bias", "jacobian", "rnea_derivatives", "aba_derivatives"}
    assert all(row["single_us"] > 0 and row["pinocchio_us"] > 0 for row in results["rows"])
    assert results["rolling_ball"]["max_residual"] < 1e-9
    assert results["rolling_ball"]["variational_step_us"] > 0 and results["rolling_ball"]["rk4_step_us"] > 0
    # the Panda under a PD: mb.PD, the njit controller and the Python callable give the same run, and the Pinocchio
    # loop (and MuJoCo's, where installed) the same final state
    pd = results["panda_pd"]
    assert pd["controllers_final_difference"] <= 1e-12 and pd["final_state_difference"] <= 1e-10
    assert pd["pd_s"] > 0 and pd["njit_s"] > 0 and pd["python_s"] > 0
    if "mujoco_s" in pd:
        assert pd["mujoco_final_difference"] <= 1e-10 and pd["mujoco_acceleration_difference"] <= 1e-9
    report = (tmp_path / "results.md").read_text()
    assert report.startswith("| robot |")
    assert "closed chain of 4 parallelograms (9 bars, 8 rows)" in report


def test_benchmark_prints_the_mjcf_load_time_against_mujocos():
    """The benchmark's line of ``mb.load_mjcf`` on gymnasium's humanoid against ``MjModel.from_xml_path`` (its
    numbers are measured, not asserted)."""
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    script = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "run.py")
    line = runpy.run_path(script)["mjcf_load_line"](0.01)
    number = r"\d+\.\d+"
    assert re.fullmatch(rf"loading gymnasium's humanoid\.xml: mb\.load_mjcf {number} ms, MuJoCo's "
                        rf"MjModel\.from_xml_path {number} ms \(ratio {number}; target ≤ 2\)", line), line


def test_contact_benchmark_smoke(tmp_path):
    """benchmarks/contact.py end to end at tiny sizes: the box on the incline holds still (|v| ≤ 1e-9 m/s at every
    step, the issue's no-creep target), Go1 is the same model in MuJoCo (free joint accelerations agree), every
    trajectory completes, and the table has its four rows with MuJoCo's column filled where MuJoCo is installed."""
    script = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "contact.py")
    namespace = runpy.run_path(script)
    if namespace["example_robot_data"]() is None:
        pytest.skip("example-robot-data is not installed (Go1 is its model)")
    main = namespace["main"]
    assert main(["--quick", "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "contact.json").read_text())
    incline, go1, batch = results["incline"], results["go1"], results["go1_batch"]
    assert incline["ours_max_speed"] <= 1e-9 and incline["ours_status"] == "completed"
    assert go1["ours_step_us"] > 0 and go1["ours_status"] == "completed" and go1["ours_contacts"] == 4
    assert batch["ours_us"] > 0 and batch["ours_completed"] == batch["n"] == 4
    table = (tmp_path / "contact.md").read_text().split("\n\n")[0].splitlines()
    assert table[0] == "| contact | multibody | MuJoCo | ratio |" and len(table) == 6
    try:
        import mujoco  # noqa: F401
    except ImportError:
        assert all("not measured" in row for row in table[2:])
        return
    assert incline["mujoco_max_speed"] > 0 and go1["mujoco_step_us"] > 0 and batch["mujoco_us"] > 0
    assert go1["joint_acceleration_difference"] <= 1e-9 and go1["mujoco_contacts"] == 4
    assert "not measured" not in "\n".join(table)
