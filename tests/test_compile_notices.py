"""A first call that compiles says so: one line on standard error per function and process, none when
Numba's on-disk cache has the machine code, none under ``MULTIBODY_QUIET=1`` (which the test suite sets,
``conftest.py``), none for the kernels ``driver.compile_kernels`` compiles (its caller says so).

Each case runs in a fresh interpreter on a cache directory of its own (``NUMBA_CACHE_DIR``): a cold cache.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NOTICE = "multibody: compiling {} for this machine (first use; cached afterwards) ..."

_CALLS = textwrap.dedent("""
    import numpy as np
    import multibody as mb

    model = mb.robots.load("double_pendulum")
    q, v = np.zeros((600, 2)), np.ones((600, 2))
    for _ in range(2):
        mb.kinetic_energy(model, q[0], v[0])  # one state: the kernel
        mb.kinetic_energy(model, q, v)  # a batch: the parallel loop too
    print("done")
""")

_COMPILE_KERNELS = textwrap.dedent("""
    import numpy as np
    import multibody as mb
    from multibody.kernels import energy

    mb.driver.compile_kernels((energy.potential_energy,), processes=1)
    mb.potential_energy(mb.robots.load("double_pendulum"), np.zeros(2))
    print("done")
""")


def _run(code, cache, quiet=None):
    env = {name: value for name, value in os.environ.items() if name != "MULTIBODY_QUIET"}
    env["NUMBA_CACHE_DIR"] = str(cache)
    if quiet is not None:
        env["MULTIBODY_QUIET"] = quiet
    done = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["done"]
    return done.stderr.splitlines()


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing compiles")
def test_a_first_call_says_it_compiles_once_and_a_cached_one_says_nothing(tmp_path):
    assert _run(_CALLS, tmp_path) == [NOTICE.format("kernels.energy.kinetic_energy"), NOTICE.format("driver._batch")]
    # the same calls in a new process: Numba's on-disk cache has them
    assert _run(_CALLS, tmp_path) == []


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing compiles")
@pytest.mark.parametrize("quiet, lines", [("1", 0), ("0", 2), ("", 2)])
def test_multibody_quiet_silences_the_lines(tmp_path, quiet, lines):
    assert len(_run(_CALLS, tmp_path, quiet)) == lines


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing compiles")
def test_compile_kernels_leaves_the_saying_to_its_caller(tmp_path):
    assert _run(_COMPILE_KERNELS, tmp_path) == []
