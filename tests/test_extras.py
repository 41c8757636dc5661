"""Optional dependencies: without SymPy, the symbolic front-end says how to install it (the ``[symbolic]``
extra), and the extra is declared in ``pyproject.toml``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# ``sys.modules["sympy"] = None`` makes ``import sympy`` raise ImportError, as where SymPy is not installed.
_WITHOUT_SYMPY = textwrap.dedent("""
    import sys
    sys.modules["sympy"] = None
    import multibody as mb
    mb.inverse_dynamics  # the rest of the package imports without SymPy
    try:
        {access}
    except ImportError as error:
        print(error)
    else:
        print("no ImportError")
""")


@pytest.mark.parametrize("access", ["mb.LagrangianSystem", "mb.generalized_forces", "import multibody.symbolic"])
def test_without_sympy_the_symbolic_front_end_names_the_extra(access):
    done = subprocess.run([sys.executable, "-c", _WITHOUT_SYMPY.format(access=access)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    message = done.stdout.strip()
    assert "SymPy" in message and 'pip install -e ".[symbolic]"' in message and "pip install sympy" in message, message


def test_the_symbolic_extra_installs_sympy_and_the_test_extra_keeps_it():
    tomllib = pytest.importorskip("tomllib")  # (Python 3.11 and later)
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as file:
        extras = tomllib.load(file)["project"]["optional-dependencies"]
    for extra in ("symbolic", "test"):
        assert any(requirement.startswith("sympy") for requirement in extras[extra]), extra
