"""The array contract and the random-robot properties once more with Numba's bounds checking on.

The kernels read arrays without bounds checks: an input of an inconsistent shape that slipped past
validation would read past a buffer and return a plausible wrong number, or crash. With
``NUMBA_BOUNDSCHECK=1`` such a read raises ``IndexError`` instead, so this pass turns a missed check
into a failing test. It runs in a subprocess, with its own Numba cache (bounds-checked machine code
must not replace the fast one), and compiles every kernel it reaches: it is the slowest test here.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))


def test_array_contract_and_properties_with_bounds_checking(tmp_path_factory):
    pytest.importorskip("hypothesis")
    cache = os.environ.get("MULTIBODY_BOUNDSCHECK_CACHE") or str(tmp_path_factory.mktemp("numba_boundscheck_cache"))
    environment = {**os.environ, "NUMBA_BOUNDSCHECK": "1", "NUMBA_CACHE_DIR": cache}
    command = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
               os.path.join(HERE, "test_array_contract.py"), os.path.join(HERE, "test_properties.py"),
               os.path.join(HERE, "test_kernels_kkt.py")]
    result = subprocess.run(command, env=environment, capture_output=True, text=True, cwd=HERE, timeout=1800)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
