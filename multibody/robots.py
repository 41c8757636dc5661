"""Robots by name: the models shipped with multibody and, when installed, those of example-robot-data.

``names()`` lists them, ``path(name)`` gives a URDF file and ``load(name, **kw)`` builds the model
(keyword arguments go to :func:`multibody.load_urdf`)::

    panda = mb.robots.load("panda")        # example-robot-data's Franka Emika Panda
    solo = mb.robots.load("solo12")        # free-flyer base, as example_robot_data loads it

Shipped models live in the project's ``robots/`` folder, installed as the package data of
``multibody.robot_files``.

example-robot-data (``pip install example-robot-data``, or ``pip install -e ".[robots]"`` in multibody's
checkout) ships URDF files and no Python module: they lie under
``<site-packages>/cmeel.prefix/share/example-robot-data/robots`` (or, from conda or ROS,
``<prefix>/share/example-robot-data/robots``). :data:`EXAMPLE_ROBOTS` names them as
``example_robot_data.load`` does, with the same files and bases:

* robots with a floating base there (legged robots, humanoids, drones, ...) get one here too
  (``floating_base=True``, a free-flyer ``"root_joint"``); pass ``floating_base=False`` to fix them
  to the world;
* ``package_dirs`` is set so that every mesh resolves (directories given by the caller come first);
* a name that is both shipped and in example-robot-data (``"double_pendulum"``) is the shipped
  model; example-robot-data's is ``"example-robot-data:double_pendulum"``. Any of its robots may be
  named so.

What ``example_robot_data.load`` adds beyond its URDF is not reproduced: SRDF reference postures
and rotor parameters, ``talos_legs`` (Talos cut down to its legs in code) and ``human``'s re-oriented
root joint; ``cassie`` is an SDF file. Robots of the table that the installed version lacks are
not listed.
"""

from __future__ import annotations

import importlib.metadata
import os
import site
import sys
from importlib import resources

_PACKAGE = "multibody.robot_files"

#: Prefix that names an example-robot-data robot explicitly, e.g. ``"example-robot-data:double_pendulum"``.
EXAMPLE_ROBOT_DATA_PREFIX = "example-robot-data:"

# (multibody is installed from its checkout, not from PyPI: "pip install multibody[robots]" finds nothing)
_INSTALL_HINT = "pip install example-robot-data (or, in multibody's checkout, pip install -e \".[robots]\")"

#: example-robot-data's robots: name -> (URDF path under its ``robots`` folder, floating base).
EXAMPLE_ROBOTS = {
    "a1": ("a1_description/urdf/a1.urdf", True),
    "alex_nub_hands": ("alex_description/urdf/alex_nub_hands.urdf", False),
    "alex_psyonic_hands": ("alex_description/urdf/alex_psyonic_hands.urdf", False),
    "alex_sake_hands": ("alex_description/urdf/alex_sake_hands.urdf", False),
    "alexander": ("alexander_description/urdf/alexander_v1.lowerBodyOnly.urdf", True),
    "allegro_left_hand": ("allegro_hand_description/urdf/allegro_left_hand.urdf", False),
    "allegro_right_hand": ("allegro_hand_description/urdf/allegro_right_hand.urdf", False),
    "anymal": ("anymal_b_simple_description/robots/anymal.urdf", True),
    "anymal_c": ("anymal_c_simple_description/urdf/anymal.urdf", True),
    "anymal_kinova": ("anymal_b_simple_description/robots/anymal-kinova.urdf", True),
    "asr_twodof": ("asr_twodof_description/urdf/TwoDofs.urdf", False),
    "b1": ("b1_description/urdf/b1.urdf", True),
    "b1_z1": ("b1_description/urdf/b1-z1.urdf", True),
    "baxter": ("baxter_description/urdf/baxter.urdf", False),
    "bolt": ("bolt_description/robots/bolt.urdf", True),
    "borinot": ("borinot_description/urdf/borinot_flying_arm_2.urdf", True),
    "centauro": ("centauro_description/urdf/centauro.urdf", True),
    "double_pendulum": ("double_pendulum_description/urdf/double_pendulum.urdf", False),
    "double_pendulum_continuous": ("double_pendulum_description/urdf/double_pendulum_continuous.urdf", False),
    "double_pendulum_simple": ("double_pendulum_description/urdf/double_pendulum_simple.urdf", False),
    "finger_edu": ("finger_edu_description/robots/finger_edu.urdf", False),
    "g1": ("g1_description/urdf/g1_29dof_rev_1_0.urdf", True),
    "g1_with_hands": ("g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf", True),
    "go1": ("go1_description/urdf/go1.urdf", True),
    "go2": ("go2_description/urdf/go2.urdf", True),
    "hector": ("hector_description/robots/quadrotor_base.urdf", True),
    "hextilt": ("hextilt_description/urdf/hextilt_flying_arm_5.urdf", True),
    "human": ("human_description/robots/human.urdf", True),
    "hyq": ("hyq_description/robots/hyq_no_sensors.urdf", True),
    "icub": ("icub_description/robots/icub.urdf", True),
    "icub_reduced": ("icub_description/robots/icub_reduced.urdf", True),
    "iris": ("iris_description/robots/iris_simple.urdf", True),
    "kinova": ("kinova_description/robots/kinova.urdf", False),
    "laikago": ("laikago_description/urdf/laikago.urdf", True),
    "panda": ("panda_description/urdf/panda.urdf", False),
    "panda_collision": ("panda_description/urdf/panda_collision.urdf", False),
    "pr2": ("pr2_description/urdf/pr2.urdf", True),
    "quadruped": ("quadruped_description/urdf/quadruped.urdf", True),
    "romeo": ("romeo_description/urdf/romeo.urdf", True),
    "simple_humanoid": ("simple_humanoid_description/urdf/simple_humanoid.urdf", True),
    "simple_humanoid_classical": ("simple_humanoid_description/urdf/simple_humanoid_classical.urdf", True),
    "so100": ("so_arm_description/urdf/so100.urdf", True),
    "so101": ("so_arm_description/urdf/so101.urdf", True),
    "solo8": ("solo_description/robots/solo.urdf", True),
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos": ("talos_data/robots/talos_reduced.urdf", True),
    "talos_arm": ("talos_data/robots/talos_left_arm.urdf", False),
    "talos_box": ("talos_data/robots/talos_reduced_box.urdf", True),
    "talos_full": ("talos_data/robots/talos_full_v2.urdf", True),
    "talos_full_box": ("talos_data/robots/talos_full_v2_box.urdf", True),
    "tiago": ("tiago_description/robots/tiago.urdf", False),
    "tiago_dual": ("tiago_description/robots/tiago_dual.urdf", False),
    "tiago_no_hand": ("tiago_description/robots/tiago_no_hand.urdf", False),
    "tiago_pro": ("tiago_pro_description/robots/tiago_pro.urdf", False),
    "ur3": ("ur_description/urdf/ur3_robot.urdf", False),
    "ur3_gripper": ("ur_description/urdf/ur3_gripper.urdf", False),
    "ur3_limited": ("ur_description/urdf/ur3_joint_limited_robot.urdf", False),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "ur5_gripper": ("ur_description/urdf/ur5_gripper.urdf", False),
    "ur5_limited": ("ur_description/urdf/ur5_joint_limited_robot.urdf", False),
    "ur10": ("ur_description/urdf/ur10_robot.urdf", False),
    "ur10_limited": ("ur_description/urdf/ur10_joint_limited_robot.urdf", False),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", False),
    "z1": ("z1_description/urdf/z1.urdf", False),
}

_ROBOTS_SUBDIR = os.path.join("share", "example-robot-data", "robots")


def _example_robot_data_dir():
    """example-robot-data's ``robots`` folder, or ``None`` when the package is not installed.

    Looked up through the installed distribution's files (``cmeel.prefix/...`` of the wheel), then in
    the ``cmeel.prefix`` of every ``site-packages`` and ``sys.path`` entry, then under ``sys.prefix``
    (conda and ROS install it in ``<prefix>/share``).
    """
    candidates = []
    try:
        distribution = importlib.metadata.distribution("example-robot-data")
        candidates.append(str(distribution.locate_file(os.path.join("cmeel.prefix", _ROBOTS_SUBDIR))))
    except importlib.metadata.PackageNotFoundError:
        pass
    roots = list(getattr(site, "getsitepackages", list)())
    if hasattr(site, "getusersitepackages"):
        roots.append(site.getusersitepackages())
    roots += [d for d in sys.path if d]
    candidates += [os.path.join(root, "cmeel.prefix", _ROBOTS_SUBDIR) for root in roots]
    candidates.append(os.path.join(sys.prefix, _ROBOTS_SUBDIR))
    for candidate in candidates:
        if os.path.isdir(candidate):
            return candidate
    return None


def _shipped_names() -> list[str]:
    return sorted(entry.name[: -len(".urdf")] for entry in resources.files(_PACKAGE).iterdir()
                  if entry.name.endswith(".urdf"))


def names(*, example_robot_data: bool = True) -> list[str]:
    """Names that :func:`load` accepts, sorted: the shipped models, and example-robot-data's robots when it
    is installed (those whose name a shipped model takes also as ``"example-robot-data:<name>"``).
    ``example_robot_data=False`` lists the shipped models only."""
    shipped = _shipped_names()
    robots_dir = _example_robot_data_dir() if example_robot_data else None
    # the robots of the table whose file the installed example-robot-data has
    found = [] if robots_dir is None else [name for name, (relative, _) in EXAMPLE_ROBOTS.items()
                                           if os.path.isfile(os.path.join(robots_dir, relative))]
    clashing = [EXAMPLE_ROBOT_DATA_PREFIX + name for name in found if name in shipped]
    return sorted(set(shipped) | set(found) | set(clashing))


def _example_robot(name):
    """``(URDF path, floating base, share folder for package_dirs)`` of example-robot-data's robot ``name``."""
    robots_dir = _example_robot_data_dir()
    if name not in EXAMPLE_ROBOTS:
        where = "none in example-robot-data" if robots_dir is not None else \
            f"example-robot-data, which has many more, is not installed: {_INSTALL_HINT}"
        raise ValueError(f"no shipped robot named {name!r} and {where}; available: {names()}")
    if robots_dir is None:
        raise ImportError(f"robot {name!r} comes from example-robot-data, which is not installed: {_INSTALL_HINT}")
    relative, floating_base = EXAMPLE_ROBOTS[name]
    urdf = os.path.join(robots_dir, relative)
    if not os.path.isfile(urdf):
        raise ValueError(f"the installed example-robot-data ({robots_dir}) has no {relative} for robot {name!r} "
                         f"(a different version); available: {names()}")
    # Meshes are written package://example-robot-data/robots/..., relative to <prefix>/share.
    return urdf, floating_base, os.path.dirname(os.path.dirname(robots_dir))


def _resolve(name):
    """``(URDF path, load_urdf defaults)`` of a robot name (see :func:`names`)."""
    if not isinstance(name, str):
        raise TypeError(f"robot name must be a string, got {type(name).__name__}")
    stem = name[: -len(".urdf")] if name.endswith(".urdf") else name
    if not stem.startswith(EXAMPLE_ROBOT_DATA_PREFIX):
        entry = resources.files(_PACKAGE).joinpath(stem + ".urdf")
        if entry.is_file():
            return str(entry), {}
    urdf, floating_base, share = _example_robot(stem.removeprefix(EXAMPLE_ROBOT_DATA_PREFIX))
    return urdf, {"floating_base": floating_base, "package_dirs": [share]}


def path(name: str) -> str:
    """Filesystem path of the URDF of robot ``name`` (one of :func:`names`; a shipped model's name may
    carry the ``.urdf`` suffix).

    Raises:
        ValueError: unknown name (the message lists the available ones).
        ImportError: an example-robot-data robot while that package is not installed.
    """
    return _resolve(name)[0]


def load(name: str, **kwargs):
    """The :class:`~multibody.model.Model` of robot ``name`` (one of :func:`names`).

    Keyword arguments go to :func:`multibody.load_urdf`. example-robot-data's robots default to the
    base example_robot_data gives them (``floating_base=True`` for legged robots, humanoids and
    drones; see :data:`EXAMPLE_ROBOTS`), and their meshes resolve: ``package_dirs`` given here are
    searched first, then example-robot-data's own.

    Raises:
        ValueError: unknown name (the message lists the available ones).
        ImportError: an example-robot-data robot while that package is not installed (the message
            says what to install).
    """
    from .urdf import load_urdf

    urdf, defaults = _resolve(name)
    if "package_dirs" in defaults:
        given = kwargs.pop("package_dirs", None)
        if given is not None:
            given = [given] if isinstance(given, (str, os.PathLike)) else list(given)
            defaults["package_dirs"] = given + defaults["package_dirs"]
    return load_urdf(urdf, **{**defaults, **kwargs})
