"""``mb.robots``: shipped models and example-robot-data's robots by name.

Every name in ``names()`` loads without a warning (meshes resolved), into a model of Pinocchio's
size for the same URDF and base; example-robot-data's legged robots and humanoids get a floating
base, as ``example_robot_data.load`` gives them; a shipped model wins a name both have; without
example-robot-data (the prefix lookup patched to find nothing) its names give a clear error naming
the extra to install. The README's first example runs as written.
"""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody import robots

from conftest import ERD_DIR, pinocchio_nq

SHIPPED = ("ball", "diff_drive", "double_pendulum", "four_bar", "pendulum", "slider_crank")
NAMES = robots.names()
# example-robot-data's own defect, reported rather than hidden: mimic tags naming joints the file lacks.
# Four of example-robot-data's files give revolute joints a <limit> without lower and upper (centauro's wheels,
# the quadruped's knees) or with both 0 (the double pendulums): the URDF specification, urdfdom and Pinocchio
# read these as a range of zero, so loading them says the joint is held still.
HELD_STILL = "which hold the revolute joint still"
EXPECTED_WARNINGS = {"alex_psyonic_hands": "mimic relation is dropped", "centauro": HELD_STILL,
                     "quadruped": HELD_STILL, "double_pendulum_simple": HELD_STILL,
                     "example-robot-data:double_pendulum": HELD_STILL}

needs_erd = pytest.mark.skipif(ERD_DIR is None, reason="example-robot-data is not installed")


def load_quietly(name, **kwargs):
    """``robots.load(name)`` with every warning an error, but those :data:`EXPECTED_WARNINGS` names."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = robots.load(name, **kwargs)
    expected = EXPECTED_WARNINGS.get(name)
    unexpected = [str(w.message) for w in caught if expected is None or expected not in str(w.message)]
    assert not unexpected, unexpected
    return model


@pytest.mark.parametrize("name", NAMES)
def test_every_name_loads_without_warnings(name):
    model = load_quietly(name)
    assert isinstance(model, mb.Model)
    missing = [g.uri for g in model.geometries if g.shape == "mesh" and g.filename is None]
    assert not missing, missing


@needs_erd
@pytest.mark.parametrize("name", [n for n in NAMES if n not in SHIPPED])
def test_sizes_equal_pinocchio(pin, name):
    """``nv`` equal, ``nq`` equal once each continuous joint counts twice (Pinocchio's ``(cos θ, sin θ)``)."""
    model = load_quietly(name)
    relative, floating_base = robots.EXAMPLE_ROBOTS[name.removeprefix(robots.EXAMPLE_ROBOT_DATA_PREFIX)]
    urdf = robots.path(name)
    assert urdf == os.path.join(ERD_DIR, relative)
    pmodel = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer()) if floating_base else pin.buildModelFromUrdf(urdf)
    assert (pinocchio_nq(model), model.nv) == (pmodel.nq, pmodel.nv)
    assert list(model.joint_names) == [n for n in pmodel.names[1:]]


@needs_erd
def test_floating_base_as_example_robot_data():
    solo = robots.load("solo12")
    assert (solo.nq, solo.nv) == (19, 18) and solo.joint_names[0] == "root_joint"
    assert robots.load("talos").joints[0].kind == "free-flyer"
    assert robots.load("panda").joints[0].kind == "revolute"
    fixed = robots.load("solo12", floating_base=False)
    assert (fixed.nq, fixed.nv) == (12, 12)
    # legged robots and humanoids float; arms do not
    for name in ("anymal", "hyq", "icub", "romeo", "talos", "solo8", "go1"):
        assert robots.EXAMPLE_ROBOTS[name][1], name
    for name in ("panda", "ur5", "talos_arm", "kinova", "tiago", "double_pendulum"):
        assert not robots.EXAMPLE_ROBOTS[name][1], name


@needs_erd
def test_package_dirs_given_are_searched_first(tmp_path):
    """A mesh under a caller's folder wins; the rest still resolve from example-robot-data."""
    relative = os.path.join("example-robot-data", "robots", "panda_description", "meshes", "visual", "link0.dae")
    mine = tmp_path / relative
    mine.parent.mkdir(parents=True)
    mine.write_text("not really a mesh")
    model = load_quietly("panda", package_dirs=str(tmp_path))
    filenames = [g.filename for g in model.geometries if g.shape == "mesh"]
    assert str(mine) in filenames and all(filenames)
    load_quietly("panda", package_dirs=None)  # None: example-robot-data's own still resolve


@needs_erd
def test_shipped_model_wins_a_shared_name():
    assert "double_pendulum" in NAMES and "example-robot-data:double_pendulum" in NAMES
    shipped = robots.path("double_pendulum")
    assert os.path.dirname(shipped) == os.path.dirname(robots.path("ball"))
    assert robots.path("example-robot-data:double_pendulum").startswith(ERD_DIR)
    assert robots.load("double_pendulum").name != robots.load("example-robot-data:double_pendulum").name
    # any example-robot-data robot may be named with the prefix
    assert robots.path("example-robot-data:panda") == robots.path("panda")


def test_names_lists_shipped_models_sorted():
    assert set(SHIPPED) <= set(NAMES)
    assert NAMES == sorted(NAMES)
    assert robots.names(example_robot_data=False) == sorted(SHIPPED)
    if ERD_DIR is not None:
        assert {"panda", "ur5", "solo12", "talos", "anymal", "hyq", "romeo", "tiago", "icub", "talos_arm"} <= set(NAMES)


def test_unknown_name_lists_the_available_ones():
    with pytest.raises(ValueError, match=r"no shipped robot named 'nope'.*available: \[.*'double_pendulum'"):
        robots.load("nope")
    with pytest.raises(ValueError, match="no shipped robot named 'nope'"):
        robots.path("nope")
    with pytest.raises(TypeError, match="robot name must be a string"):
        robots.load(3)


def test_without_example_robot_data(monkeypatch):
    """The prefix lookup finding nothing: shipped models only, and a clear message for the rest."""
    monkeypatch.setattr(robots, "_example_robot_data_dir", lambda: None)
    assert robots.names() == sorted(SHIPPED)
    # multibody is not on PyPI: the hint names the package itself, or the extra of the checkout
    hint = 'pip install example-robot-data (or, in multibody\'s checkout, pip install -e ".[robots]")'
    with pytest.raises(ImportError, match=re.escape("robot 'panda' comes from example-robot-data, which is not "
                                                    f"installed: {hint}")):
        robots.load("panda")
    with pytest.raises(ImportError, match=re.escape(hint)):
        robots.path("example-robot-data:double_pendulum")
    with pytest.raises(ValueError, match=re.escape(hint)):
        robots.load("nope")
    assert robots.load("double_pendulum").nq == 2  # shipped models need nothing


def test_robot_missing_from_the_installed_version(monkeypatch, tmp_path):
    """An older example-robot-data without a robot of the table: not listed, and a clear error."""
    (tmp_path / "panda_description" / "urdf").mkdir(parents=True)
    monkeypatch.setattr(robots, "_example_robot_data_dir", lambda: str(tmp_path))
    assert "ur5" not in robots.names() and "panda" not in robots.names()
    with pytest.raises(ValueError, match=r"has no ur_description/urdf/ur5_robot.urdf for robot 'ur5'"):
        robots.load("ur5")


@needs_erd
def test_prefix_lookup_finds_the_installed_package():
    assert os.path.samefile(robots._example_robot_data_dir(), ERD_DIR)


@needs_erd
def test_readme_first_example_runs_as_written():
    readme = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")
    with open(readme, encoding="utf-8") as f:
        first = re.search(r"```python\n(.*?)```", f.read(), re.S).group(1)
    assert 'mb.robots.load("panda")' in first
    # the install it names exists (multibody itself is installed from its checkout, not from PyPI)
    assert "# pip install example-robot-data" in first and "multibody[" not in first
    namespace = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(compile(first, "README.md", "exec"), namespace)
    assert namespace["J"].shape == (1000, 6, namespace["model"].nv)
    assert np.all(np.isfinite(namespace["a"]))
