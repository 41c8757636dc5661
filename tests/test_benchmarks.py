"""The benchmark script runs end to end (tiny sizes), so that it never rots. Speed itself is
measured by benchmarks/run.py, never asserted here."""

import json
import os
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
    report = (tmp_path / "results.md").read_text()
    assert report.startswith("| robot |")
    assert "closed chain of 4 parallelograms (9 bars, 8 rows)" in report
