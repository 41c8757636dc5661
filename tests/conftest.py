"""Shared fixtures and helpers for the multibody test suite.

* ``erd_urdf(relative_path)``: path of an example-robot-data URDF (skips the test when absent).
  The ``example-robot-data`` wheel ships no Python module; its files live under
  ``<site-packages>/cmeel.prefix/share/example-robot-data/robots``.
* ``pin``: the ``pinocchio`` module, or a skip when it is not installed.
* ``q_to_pinocchio`` / ``q_from_pinocchio``: configuration maps (continuous joints are one angle
  here, ``(cos θ, sin θ)`` in Pinocchio); velocities are identical (``nv`` equal).
* ``random_tree_model(seed)``: a random kinematic tree that uses every joint type.
"""

from __future__ import annotations

import importlib.util
import os
import site
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

import multibody as mb
from multibody.check import to_pinocchio_configuration
from multibody import joints as jt
from multibody.spatial import pose_from_xyz_rpy

# No "multibody: compiling ..." lines in the suite's output, nor in the processes its tests start
# (tests/test_compile_notices.py turns them on where it checks them).
os.environ.setdefault("MULTIBODY_QUIET", "1")

# ----------------------------------------------------------------------------- hypothesis profiles

# "ci": the default, small enough for .ci/run; "thorough" (pytest --hypothesis-profile=thorough):
# thousands of random robots and URDF mutants, before a release. Deadlines are off: a first example
# may compile kernels.
settings.register_profile("ci", max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=5000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci")

# ----------------------------------------------------------------------------- example-robot-data

_ERD_SUFFIX = os.path.join("cmeel.prefix", "share", "example-robot-data", "robots")


def _find_erd_dir():
    candidates = []
    spec = importlib.util.find_spec("example_robot_data")
    if spec is not None and spec.origin:
        # A Python loader module, if some version ships one, sits in site-packages.
        candidates.append(os.path.join(os.path.dirname(os.path.dirname(spec.origin)), _ERD_SUFFIX))
    try:
        candidates += [os.path.join(d, _ERD_SUFFIX) for d in site.getsitepackages()]
    except AttributeError:  # some virtualenvs lack getsitepackages
        pass
    if hasattr(site, "getusersitepackages"):
        candidates.append(os.path.join(site.getusersitepackages(), _ERD_SUFFIX))
    candidates += [os.path.join(d, _ERD_SUFFIX) for d in sys.path if d]
    for candidate in candidates:
        if os.path.isdir(candidate):
            return candidate
    return None


ERD_DIR = _find_erd_dir()


def erd_urdf(relative_path):
    """Absolute path of ``robots/<relative_path>`` in example-robot-data, or skip the test."""
    if ERD_DIR is None:
        pytest.skip("example-robot-data is not installed")
    path = os.path.join(ERD_DIR, relative_path)
    if not os.path.isfile(path):
        pytest.skip(f"example-robot-data has no {relative_path}")
    return path


@pytest.fixture(scope="session")
def erd_dir():
    if ERD_DIR is None:
        pytest.skip("example-robot-data is not installed")
    return ERD_DIR


# ----------------------------------------------------------------------------- Pinocchio

def import_pinocchio():
    """The ``pinocchio`` module, or skip the calling test."""
    return pytest.importorskip("pinocchio")


@pytest.fixture(scope="session")
def pin():
    return import_pinocchio()


def q_to_pinocchio(model, q):
    """Our ``q (..., nq)`` as Pinocchio's: each continuous angle θ becomes ``(cos θ, sin θ)``."""
    return to_pinocchio_configuration(model, np.asarray(q, dtype=float))


def q_from_pinocchio(model, q_pin):
    """Inverse of :func:`q_to_pinocchio`: ``(cos θ, sin θ)`` pairs back to angles."""
    q_pin = np.asarray(q_pin, dtype=float)
    blocks, s = [], 0
    for joint in model.joints:
        if isinstance(joint, jt.Continuous):
            blocks.append(np.arctan2(q_pin[..., s + 1 : s + 2], q_pin[..., s : s + 1]))
            s += 2
        else:
            blocks.append(q_pin[..., s : s + joint.nq])
            s += joint.nq
    assert s == q_pin.shape[-1]
    return np.concatenate(blocks, axis=-1) if blocks else q_pin.copy()


def v_to_pinocchio(model, v):
    """Velocities need no conversion (``nv`` is the same for every joint type)."""
    return np.asarray(v, dtype=float)


def pinocchio_nq(model):
    """Pinocchio's ``nq`` of our model: one more per continuous joint."""
    return model.nq + sum(isinstance(j, jt.Continuous) for j in model.joints)


# ----------------------------------------------------------------------------- random models

def random_inertia(rng, scale=1.0):
    """A valid random body: a box of random size and mass, shifted and rotated to a random pose."""
    mass = rng.uniform(0.5, 3.0)
    size = rng.uniform(0.05, 0.5, size=3) * scale
    box = mb.inertia.box(mass, size)
    X = pose_from_xyz_rpy(rng.uniform(-0.3, 0.3, size=3), rng.uniform(-np.pi, np.pi, size=3))
    return box.transformed(X)


def random_axis(rng):
    axis = rng.standard_normal(3)
    return axis / np.linalg.norm(axis)


def random_placement(rng, reach=0.5):
    return pose_from_xyz_rpy(rng.uniform(-reach, reach, size=3), rng.uniform(-np.pi, np.pi, size=3))


def random_tree_model(seed=0, n_extra=6):
    """A seeded random tree using every joint type, with branches and fixed attachments.

    Structure: a free-flyer base; then one body per joint type (Revolute with a random axis,
    Continuous, Prismatic, Planar, Spherical, Translation), each attached to a random earlier
    moving body; massive bodies fixed to moving ones; a massless tip fixed to a fixed body;
    ``n_extra`` more random revolute/prismatic/spherical bodies on random parents.
    """
    rng = np.random.default_rng(seed)
    b = mb.ModelBuilder(f"random_tree_{seed}")
    names = []

    def add(name, joint, parent, inertia=True, **kwargs):
        b.add_body(name, joint, parent=parent, placement=random_placement(rng),
                   inertia=random_inertia(rng) if inertia else None, **kwargs)
        names.append(name)

    # A massive body fixed to the world (mass that does not move), then the floating base.
    add("ground", jt.Fixed(), None)
    add("base", jt.FreeFlyer(), None)
    factories = [
        lambda: jt.Revolute(random_axis(rng)),
        lambda: jt.Continuous(random_axis(rng)),
        lambda: jt.Prismatic(random_axis(rng)),
        lambda: jt.Planar(),
        lambda: jt.Spherical(),
        lambda: jt.Translation(),
    ]
    for k, make in enumerate(factories):
        joint = make()
        kwargs = {}
        if isinstance(joint, jt.Revolute) and not isinstance(joint, jt.Continuous):
            kwargs = dict(lower=[-2.0], upper=[2.5])
        elif isinstance(joint, jt.Prismatic):
            kwargs = dict(lower=[-0.3], upper=[0.4])
        moving = [n for n in names if n != "ground"]
        add(f"{joint.kind}_{k}", joint, moving[rng.integers(len(moving))], **kwargs)
    # Fixed attachments: a massive one on a moving body, and a massless tip on the fixed body.
    moving = [n for n in names if n != "ground"]
    add("fixed_a", jt.Fixed(), moving[rng.integers(len(moving))])
    add("fixed_tip", jt.Fixed(), "fixed_a", inertia=False)
    kinds = [lambda: jt.Revolute(random_axis(rng)), lambda: jt.Prismatic(random_axis(rng)), lambda: jt.Spherical()]
    for k in range(n_extra):
        parent = names[1 + rng.integers(len(names) - 1)]  # anything but the world-fixed ground
        add(f"extra_{k}", kinds[rng.integers(len(kinds))](), parent)
    return b.build()


ALL_MOVING_KINDS = ("revolute", "continuous", "prismatic", "planar", "spherical", "free-flyer", "translation")


@pytest.fixture(scope="session", params=[0, 1, 2])
def random_tree(request):
    return random_tree_model(request.param)


def random_state(model, rng, velocity_scale=1.0):
    """``(q, v, a)`` with ``q`` random within limits and Gaussian ``v``, ``a``."""
    q = model.random_configuration(rng)
    v = velocity_scale * rng.standard_normal(model.nv)
    a = rng.standard_normal(model.nv)
    return q, v, a


# ----------------------------------------------------------------------------- Pinocchio twin

def _rotation_z_to(axis):
    """A rotation C with C e_z = axis (unit)."""
    z = np.array([0.0, 0.0, 1.0])
    w = np.cross(z, axis)
    s, c = np.linalg.norm(w), float(z @ axis)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return mb.spatial.axis_angle_rotation(w / s, np.arctan2(s, c))


def pinocchio_twin(pin, model):
    """The same kinematic tree as a ``pin.Model``, and the Pinocchio frame id of each of our bodies.

    Joint types map one to one, except that Pinocchio's unbounded revolute joint with an arbitrary
    axis cannot be given its axis from Python: a ``Continuous`` joint about ``a`` becomes ``RUBZ`` in
    a joint frame rotated by ``C`` (``C e_z = a``). Its children, bodies and inertia are expressed in
    that rotated frame, so world placements and world-aligned Jacobians of the bodies are unchanged.
    Masses fixed to the world are appended to Pinocchio's universe.
    """
    corrections = []
    pmodel = pin.Model()
    for i, joint in enumerate(model.joints):
        C = np.eye(3)
        if isinstance(joint, jt.Continuous):
            C = _rotation_z_to(joint.axis)
            jmodel = pin.JointModelRUBZ()
        elif isinstance(joint, jt.Revolute):
            jmodel = pin.JointModelRevoluteUnaligned(np.array(joint.axis))
        elif isinstance(joint, jt.Prismatic):
            jmodel = pin.JointModelPrismaticUnaligned(np.array(joint.axis))
        else:
            jmodel = {"planar": pin.JointModelPlanar, "spherical": pin.JointModelSpherical,
                      "free-flyer": pin.JointModelFreeFlyer, "translation": pin.JointModelTranslation}[joint.kind]()
        corrections.append(C)
        parent = model.parents[i]
        C_parent = corrections[parent] if parent >= 0 else np.eye(3)
        X = model.joint_placements[i]
        R = C_parent.T @ X[:3, :3] @ C
        p = C_parent.T @ X[:3, 3]
        jid = pmodel.addJoint(int(parent + 1), jmodel, pin.SE3(R, p), model.joint_names[i])
        inertia = model.joint_inertias[i].transformed(mb.spatial.pose_matrix(C.T, np.zeros(3)))
        pmodel.appendBodyToJoint(jid, pin.Inertia(inertia.mass, inertia.com, inertia.rotational), pin.SE3.Identity())
    frame_ids = []
    for b, name in enumerate(model.body_names):
        j = model.body_joints[b]
        C = corrections[j] if j >= 0 else np.eye(3)
        X = model.body_placements[b]
        placement = pin.SE3(C.T @ X[:3, :3], C.T @ X[:3, 3])
        if j < 0:
            I = model.body_inertias[b]
            pmodel.appendBodyToJoint(0, pin.Inertia(I.mass, I.com, I.rotational), placement)
        frame_ids.append(pmodel.addFrame(pin.Frame(name, int(j + 1), 0, placement, pin.FrameType.BODY)))
    pmodel.gravity = pin.Motion(np.concatenate([model.gravity, np.zeros(3)]))
    pmodel.armature = np.array(model.armature)  # per velocity coordinate, the same order in both
    return pmodel, frame_ids
