"""MJCF mutation fuzzing: a damaged or hostile MJCF document either fails to load with a clear error or
loads a sound model.

Seeds are a document that uses most of what :func:`multibody.load_mjcf` reads (default classes and
``childclass``, ``<frame>``, ``<include>``, every orientation form, ``<inertial>`` and masses from geoms,
an inline mesh, hinge, slide, ball and free joints, sites, and ``connect``, ``weld`` and ``joint``
equalities) and a few gymnasium models. A Hypothesis strategy applies one to three mutations to a seed's
XML tree: delete or duplicate elements; write non-numeric text, NaN, ±inf, negative, zero, huge or tiny
numbers, or the wrong count of numbers, into attributes; scale a body's mass and inertia by huge, tiny,
zero or negative factors; write unknown joint and geom types; name default classes that do not exist;
point equalities at bodies, joints and sites that do not exist; give two bodies or joints one name; nest
a body deep inside empty bodies; include a missing file, the document itself, a file that includes the
document back, a file without ``<mujoco>`` or one that is not XML; or cut the document short.

The property, for every mutant written to a file: :func:`multibody.load_mjcf` either raises
:class:`~multibody.mjcf.MJCFError` (a ``ValueError``) whose message starts with the file, then MuJoCo's
message naming the element and line (or its XML parser's error), or the loader's own naming the element,
or returns a model that keeps the loader's promises (:func:`check_model`: masses and inertias physical
and within ``LARGEST_MAGNITUDE``, unit axes,
ordered limits, non-negative damping, friction and armature, equalities that bind to the model) with
finite mass matrix, bias forces and constraint rows at a random finite state; the forward dynamics may
instead raise ``LinAlgError`` for a mass matrix that is singular (a joint that moves no mass, which the
message names) or numerically singular. Whenever MuJoCo compiles the same file, the two mass matrices
agree. No other exception, no warning other than the loader's ``UserWarning`` about what it leaves out,
and no example slower than the deadline; :func:`time_limit` stops one that hangs.

The number of examples comes from the Hypothesis profile (``conftest.py``).
"""

from __future__ import annotations

import contextlib
import copy
import importlib.util
import math
import os
import re
import signal
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import event as hypothesis_event
from hypothesis import strategies as st
from hypothesis.errors import InvalidArgument

import multibody as mb
from multibody.check import _full_mass_matrix
from multibody.mjcf import MJCFError

from fuzz_helpers import NUMERICALLY_SINGULAR, check_forward_dynamics, check_refused
from multibody.modelfiles import LARGEST_MAGNITUDE

try:
    import mujoco
except ImportError:  # the comparison is skipped; the rest of the property still runs
    mujoco = None

# ----------------------------------------------------------------------------- seeds

SEED = """\
<mujoco model="seed">
  <compiler angle="degree" eulerseq="zyx" autolimits="true"/>
  <option gravity="0.3 0 -9.81"/>
  <default>
    <joint damping="0.2" armature="0.01"/>
    <geom density="700"/>
    <default class="arm">
      <joint axis="0 1 0" range="-90 90" frictionloss="0.05"/>
      <geom type="capsule" size="0.03"/>
      <default class="tip">
        <geom type="sphere" size="0.05" density="300"/>
      </default>
    </default>
  </default>
  <asset>
    <mesh name="wedge" vertex="0 0 0  0.2 0 0  0 0.1 0  0 0 0.1  0.2 0.1 0.1" scale="1 1 2"/>
    <mesh name="tetra" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1" face="0 2 1  0 1 3  0 3 2  1 2 3"/>
  </asset>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <site name="anchor" pos="0 0.5 1"/>
    <body name="cart" pos="0 0 1">
      <joint name="rail" type="slide" axis="1 0 0" range="-1 1"/>
      <geom type="box" size="0.2 0.1 0.05"/>
      <site name="cart_site" pos="0.1 0 0" quat="0.9 0 0.1 0"/>
      <frame pos="0.1 0 -0.05" euler="0 0 20" childclass="arm">
        <body name="upper" euler="10 20 30">
          <joint name="shoulder" ref="15"/>
          <geom fromto="0 0 0 0 0 -0.4"/>
          <body name="lower" pos="0 0 -0.4" axisangle="0 0 1 30">
            <joint name="elbow" pos="0 0 0.01" springref="5"/>
            <joint name="twist" axis="0 0 1" ref="-10"/>
            <geom fromto="0 0 0 0 0 -0.4"/>
            <geom class="tip" pos="0 0 -0.4"/>
            <site name="hand" pos="0 0 -0.45"/>
          </body>
        </body>
      </frame>
    </body>
    <body name="bob" pos="0.5 0 1" xyaxes="0 1 0 -1 0 0">
      <joint name="swivel" type="ball"/>
      <inertial pos="0 0 -0.3" mass="1.2" diaginertia="0.01 0.02 0.025" quat="1 0 0 0.2"/>
      <body name="plate" pos="0 0 -0.3" zaxis="0 1 1">
        <joint name="flap" axis="1 0 0"/>
        <inertial pos="0.01 0 0" mass="0.4" fullinertia="0.003 0.004 0.005 0.0001 0 0.0002"/>
        <geom type="mesh" mesh="wedge" mass="0"/>
      </body>
    </body>
    <body name="brick" pos="-0.5 0 1">
      <freejoint name="loose"/>
      <geom type="ellipsoid" size="0.1 0.05 0.08" contype="0" conaffinity="0"/>
      <geom type="mesh" mesh="tetra" pos="0.1 0 0"/>
      <geom type="cylinder" size="0.02 0.1" pos="0 0.1 0" euler="0 90 0"/>
      <site name="brick_site" pos="0 0 0.1"/>
    </body>
    <include file="part.xml"/>
  </worldbody>
  <equality>
    <connect name="pin" body1="lower" body2="bob" anchor="0 0 -0.45"/>
    <weld name="glue" site1="brick_site" site2="anchor"/>
    <joint name="gear" joint1="twist" joint2="shoulder" polycoef="0 0.5 0.1 0 0"/>
    <weld name="lock" body1="plate" relpose="0 0 0 1 0 0 0"/>
  </equality>
</mujoco>
"""

#: the file the seed includes, written next to every mutant
PART = """\
<mujoco>
  <body name="swing" pos="0 -0.5 1">
    <joint name="swing_hinge" axis="0 1 0"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5"/>
  </body>
</mujoco>
"""

GYMNASIUM_SEEDS = ("hopper", "ant", "humanoid", "reacher")


def _seed_text():
    seeds = {"seed": SEED}
    spec = importlib.util.find_spec("gymnasium")
    if spec is not None:
        folder = os.path.join(os.path.dirname(spec.origin), "envs", "mujoco", "assets")
        for name in GYMNASIUM_SEEDS:
            path = os.path.join(folder, f"{name}.xml")
            if os.path.isfile(path):
                with open(path, encoding="utf-8") as stream:
                    seeds[name] = stream.read()
    return seeds


SEED_TEXT = _seed_text()
SEEDS = sorted(SEED_TEXT)

# ----------------------------------------------------------------------------- mutations
#
# A mutation is a tuple of plain values, so that a failing example can be written down in @example(...).
# Integers pick among the matching elements modulo their number; a mutation that finds nothing to act on
# leaves the document unchanged.

STRUCTURAL_TAGS = ("body", "joint", "freejoint", "geom", "inertial", "site", "frame", "default", "mesh", "asset",
                   "worldbody", "equality", "connect", "weld", "compiler", "include")
NUMERIC_ATTRIBUTES = (
    ("body", "pos"), ("body", "quat"), ("body", "euler"), ("body", "axisangle"), ("body", "xyaxes"),
    ("body", "zaxis"), ("frame", "pos"), ("frame", "euler"),
    ("joint", "pos"), ("joint", "axis"), ("joint", "range"), ("joint", "ref"), ("joint", "damping"),
    ("joint", "armature"), ("joint", "frictionloss"), ("joint", "polycoef"),
    ("geom", "size"), ("geom", "pos"), ("geom", "fromto"), ("geom", "mass"), ("geom", "density"),
    ("geom", "euler"), ("geom", "group"),
    ("inertial", "pos"), ("inertial", "mass"), ("inertial", "diaginertia"), ("inertial", "fullinertia"),
    ("inertial", "quat"), ("site", "pos"), ("site", "quat"),
    ("mesh", "vertex"), ("mesh", "face"), ("mesh", "scale"),
    ("connect", "anchor"), ("weld", "relpose"), ("option", "gravity"),
    ("compiler", "settotalmass"), ("compiler", "boundmass"), ("compiler", "boundinertia"),
    ("compiler", "inertiagrouprange"),
)
TEXT_ATTRIBUTES = NUMERIC_ATTRIBUTES + (
    ("body", "name"), ("joint", "name"), ("joint", "type"), ("joint", "limited"), ("geom", "type"),
    ("geom", "mesh"), ("joint", "class"), ("geom", "class"), ("body", "childclass"), ("connect", "body1"),
    ("connect", "body2"), ("weld", "site1"), ("joint", "joint1"), ("joint", "joint2"), ("compiler", "angle"),
    ("compiler", "eulerseq"), ("compiler", "inertiafromgeom"), ("mesh", "inertia"), ("body", "mocap"),
)
# Replacements for one number of an attribute.
NUMBER_TOKENS = ("nan", "NaN", "inf", "-inf", "-1", "-0.5", "0", "-0", "1e308", "-1e308", "1e300", "1e-308",
                 "5e-324", "1e16", "1e50", "-1e50", "1e51", "1e20", "1e-20", "1e999", "2.5", "7")
# Replacements for a whole attribute: not numbers, wrong counts, and syntax only Python accepts.
ATTRIBUTE_TEXTS = ("abc", "", " ", "1 2", "1 2 3 4", "0 0 0", "0 0 0 0", "1,5", "1_0", "\u0663", "0x1p3",
                   "infinity", "1e50 1e50 1e50", "nan nan nan", "1e-308 0 0", "true", "ghost", "world", "-1 -1 -1",
                   "1 2 3 4 5 6 7 8", "0 1 2 3 4 5 6")
JOINT_TYPES = ("hinge", "slide", "ball", "free", "", "Hinge", "revolute", "planar", "screw")
GEOM_TYPES = ("sphere", "capsule", "cylinder", "box", "ellipsoid", "mesh", "plane", "hfield", "sdf", "blob", "")
# Factors for a body's mass and inertia together (a positive one keeps a valid body valid).
INERTIAL_SCALES = ("1e300", "1e51", "1e50", "1e20", "1e-20", "1e-300", "5e-324", "0", "-1")
EQUALITY_TARGETS = (("connect", "body1"), ("connect", "body2"), ("weld", "site1"), ("weld", "site2"),
                    ("weld", "body1"), ("joint", "joint1"), ("joint", "joint2"))
INCLUDES = ("self", "cycle", "missing", "no file", "not mujoco", "not xml", "empty", "directory")
NEST_DEPTHS = (1, 2, 50, 300)

indices = st.integers(0, 1000)
numbers = st.one_of(st.sampled_from(NUMBER_TOKENS), st.floats().map(repr))

mutations = st.one_of(
    st.tuples(st.just("delete"), st.sampled_from(STRUCTURAL_TAGS), indices),
    st.tuples(st.just("duplicate"), st.sampled_from(STRUCTURAL_TAGS), indices),
    st.tuples(st.just("set_number"), st.sampled_from(NUMERIC_ATTRIBUTES), indices, st.integers(0, 7), numbers),
    st.tuples(st.just("set_text"), st.sampled_from(TEXT_ATTRIBUTES), indices, st.sampled_from(ATTRIBUTE_TEXTS)),
    st.tuples(st.just("scale_inertial"), indices, st.sampled_from(INERTIAL_SCALES)),
    st.tuples(st.just("joint_type"), indices, st.sampled_from(JOINT_TYPES)),
    st.tuples(st.just("geom_type"), indices, st.sampled_from(GEOM_TYPES)),
    st.tuples(st.just("unknown_class"), st.sampled_from(("joint", "geom", "site", "body", "frame", "connect")),
              indices),
    st.tuples(st.just("equality_target"), st.sampled_from(EQUALITY_TARGETS), indices),
    st.tuples(st.just("rename"), st.sampled_from(("body", "joint", "site", "mesh")), indices, indices),
    st.tuples(st.just("nest"), indices, st.sampled_from(NEST_DEPTHS)),
    st.tuples(st.just("include"), st.sampled_from(INCLUDES), indices),
    st.tuples(st.just("truncate"), st.integers(1, 99)),
)


def _parents(root):
    return {child: parent for parent in root.iter() for child in parent}


def _pick(elements, k):
    return elements[k % len(elements)] if elements else None


def _elements(root, tag):
    return [element for element in root.iter(tag) if element is not root]


def mutate(root, mutation, folder, name):
    """Apply one mutation to the XML tree ``root`` in place; ``folder`` and ``name``: where the mutant will
    be written (files it includes are written there). Returns the text to append to the document cut short
    (``("truncate", percent)``) or ``None``."""
    kind, *args = mutation
    if kind in ("delete", "duplicate"):
        tag, k = args
        element = _pick(_elements(root, tag), k)
        if element is None:
            return None
        parent = _parents(root)[element]
        if kind == "delete":
            parent.remove(element)
        else:
            parent.insert(list(parent).index(element) + 1, copy.deepcopy(element))
    elif kind in ("set_number", "set_text"):
        (tag, attribute), k, *rest = args
        if kind == "set_number":
            element = _pick([e for e in root.iter(tag) if attribute in e.attrib], k)
            if element is None:
                return None
            component, token = rest
            values = element.get(attribute).split() or ["0"]
            values[component % len(values)] = token
            element.set(attribute, " ".join(values))
        else:
            element = _pick(list(root.iter(tag)), k)
            if element is None:
                return None
            element.set(attribute, rest[0])
    elif kind == "scale_inertial":
        k, factor = args
        element = _pick(list(root.iter("inertial")), k)
        if element is None:
            return None
        for attribute in ("mass", "diaginertia", "fullinertia"):
            if attribute in element.attrib:
                try:
                    values = [float(x) * float(factor) for x in element.get(attribute).split()]
                except ValueError:  # already made non-numeric by another mutation
                    continue
                element.set(attribute, " ".join(repr(x) for x in values))
    elif kind == "joint_type":
        k, text = args
        element = _pick([e for e in root.iter("joint") if "joint1" not in e.attrib and e.get("joint") is None], k)
        if element is not None:
            element.set("type", text)
    elif kind == "geom_type":
        k, text = args
        element = _pick(list(root.iter("geom")), k)
        if element is not None:
            element.set("type", text)
    elif kind == "unknown_class":
        tag, k = args
        element = _pick(list(root.iter(tag)), k)
        if element is not None:
            element.set("childclass" if tag in ("body", "frame") else "class", "no_such_class")
    elif kind == "equality_target":
        (tag, attribute), k = args
        equality = root.find("equality")
        element = _pick(list(equality.iter(tag)) if equality is not None else [], k)
        if element is not None:
            element.set(attribute, "ghost")
    elif kind == "rename":
        tag, k, j = args
        elements = [e for e in root.iter(tag) if "name" in e.attrib]
        if elements:
            _pick(elements, k).set("name", _pick(elements, j).get("name"))
    elif kind == "nest":
        # body k wrapped in `depth` bodies without joints or mass
        k, depth = args
        element = _pick(_elements(root, "body"), k)
        if element is None:
            return None
        parent = _parents(root)[element]
        position = list(parent).index(element)
        parent.remove(element)
        outer = inner = ET.Element("body")
        for _ in range(depth - 1):
            inner = ET.SubElement(inner, "body")
        inner.append(element)
        parent.insert(position, outer)
    elif kind == "include":
        what, k = args
        target = _pick([root] + _elements(root, "body"), k)
        attributes = {"file": {"self": name, "cycle": "cycle.xml", "missing": "missing.xml", "not mujoco": "robot.xml",
                               "not xml": "notes.xml", "empty": "empty.xml", "directory": "."}.get(what, "")}
        if what == "no file":
            attributes = {}
        contents = {"cycle": f'<mujoco><include file="{name}"/></mujoco>', "not mujoco": "<robot name='r'/>",
                    "not xml": "not XML at all", "empty": ""}
        if what in contents:
            with open(os.path.join(folder, attributes["file"]), "w", encoding="utf-8") as stream:
                stream.write(contents[what])
        target.insert(0, ET.Element("include", attributes))
    elif kind == "truncate":
        return args[0]
    return None


def mutant(seed, mutation_list, folder, name):
    """The seed's text after the mutations (written as a file named ``name`` in ``folder``)."""
    root = ET.fromstring(SEED_TEXT[seed])
    cut = None
    for mutation in mutation_list:
        cut = mutate(root, mutation, folder, name) or cut
    text = ET.tostring(root, encoding="unicode")
    if cut is not None:
        text = text[: len(text) * cut // 100]
    return text


# ----------------------------------------------------------------------------- the property

#: The deadline of one example (ms), and the time after which time_limit stops a hanging one (s).
DEADLINE_MS, HANG_S = 5000, 30
MAX_WARNINGS = 8
# Relative error of our mass matrix against MuJoCo's, max|ours − theirs| / max(1, max|theirs|), above the
# rounding that the sizes in the document allow (rounding_scale).
MUJOCO_TOLERANCE = 1e-9


def event(text):
    """Hypothesis's statistics of what happened, in a Hypothesis test (nothing elsewhere)."""
    with contextlib.suppress(InvalidArgument):
        hypothesis_event(text)


@contextlib.contextmanager
def time_limit(seconds):
    """Raise ``TimeoutError`` in the main thread if the block runs longer than ``seconds``."""
    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


#: What MuJoCo's messages name (an element and its line, the XML parser's line), or the loader's own (the root,
#: or the element of a compiled value the model refuses).
CONTEXT = re.compile(r"Element |Line number=|ParseXML: |the root element must be <mujoco>|"
                     r"\b(?:body|joint|site|geom|equality) (?:'|\d)|<option>: ")


def check_error(error, folder):
    """The message starts with the file (of ``folder``), then MuJoCo's message, which names the element and
    the line (or the XML parser's error), or the loader's own, which names the element."""
    assert type(error) is MJCFError and isinstance(error, ValueError)
    path, _, message = str(error).partition(": ")
    assert os.path.isabs(path) and os.path.dirname(path) == folder and os.path.exists(path), str(error)
    assert CONTEXT.search(message), str(error)
    summary = re.sub(r"'[^']*'|\"[^\"]*\"|\([^)]*\)|\[[^]]*\]|[-+0-9.e]{2,}", "…", message.splitlines()[0])
    event("MJCFError: " + summary[:60])


def check_warnings(caught):
    unexpected = [w for w in caught if not issubclass(w.category, UserWarning)
                  or issubclass(w.category, mb.RankDeficientWarning)]
    assert not unexpected, [f"{w.category.__name__}: {w.message}" for w in unexpected]
    assert len(caught) <= MAX_WARNINGS, [str(w.message) for w in caught]


def check_model(model):
    """What a loaded model promises, whatever the document: unit joint axes, ordered limits, physical
    masses and inertias within ``LARGEST_MAGNITUDE``, non-negative finite damping, friction and armature,
    and equalities that bind to the model."""
    for name, joint in zip(model.joint_names, model.joints):
        if hasattr(joint, "axis"):
            assert np.all(np.isfinite(joint.axis)) and abs(np.linalg.norm(joint.axis) - 1.0) < 1e-12, (name, joint.axis)
    assert np.all(model.lower <= model.upper), (model.lower, model.upper)
    for name, inertia in zip(model.body_names, model.body_inertias):
        assert 0.0 <= inertia.mass <= LARGEST_MAGNITUDE, (name, inertia)
        assert np.all(np.abs(inertia.com) <= LARGEST_MAGNITUDE), (name, inertia)
        assert np.all(np.abs(inertia.rotational) <= 3.0 * LARGEST_MAGNITUDE), (name, inertia)
        moments = np.linalg.eigvalsh(inertia.rotational)
        assert moments[0] >= -1e-9 * max(moments[2], 0.0), (name, moments)
    for values in (model.damping, model.friction, model.armature):
        assert np.all(np.isfinite(values)) and np.all(values >= 0.0), values
    for placement in model.body_placements:
        assert np.all(np.isfinite(placement)), placement
    return mb.ConstrainedSystem(model, model.equality_constraints) if model.equality_constraints else None


def check_dynamics(model, system, rng):
    """Finite dynamics at a random state; returns ``q``."""
    q = model.random_configuration(rng)
    assert q.shape == (model.nq,) and np.all(np.isfinite(q)), q
    v, tau = rng.standard_normal((2, model.nv))
    M = mb.mass_matrix(model, q)
    assert np.all(np.isfinite(M)), M
    assert np.all(np.isfinite(mb.bias_forces(model, q, v)))
    if system is not None:
        for constraint in system.constraints:
            assert np.all(np.isfinite(constraint.position(model, q))), constraint
            assert np.all(np.isfinite(constraint.jacobian(model, q))), constraint
    check_forward_dynamics(model, q, v, tau, M, event)
    return q


def reach(model, q):
    """A bound on the distance from the world origin of every joint frame, body frame and centre of mass at
    ``q`` (m): the lengths of the placements and displacements along each path from the root added up."""
    joints = np.zeros(len(model.joints))
    for j, (joint, parent, start) in enumerate(zip(model.joints, model.parents, model.idx_q)):
        joints[j] = (joints[parent] if parent >= 0 else 0.0) + np.linalg.norm(model.joint_placements[j][:3, 3]) \
            + np.abs(q[start : start + joint.nq]).sum()
    bodies = [(joints[j] if j >= 0 else 0.0) + np.linalg.norm(X[:3, 3]) + np.linalg.norm(I.com)
              for j, X, I in zip(model.body_joints, model.body_placements, model.body_inertias)]
    return max([0.0, *joints, *bodies])


def rounding_scale(model, q):
    """Magnitude of the terms the mass matrix is summed from, ``m (2 R)² + max|I|`` over the bodies with
    ``R`` the :func:`reach`, armature included (``tests/test_urdf_fuzz.py``). MuJoCo sums them about the
    centres of mass of subtrees, so its rounding grows with a joint's distance even along its own axis,
    where the mass matrix does not see it."""
    R = reach(model, q)
    bodies = max((I.mass * (2.0 * R) ** 2 + np.abs(I.rotational).max() for I in model.body_inertias), default=0.0)
    return bodies + model.armature.max(initial=0.0)


#: What the loader leaves out with a warning that cannot change the mass matrix.
MASS_MATRIX_UNAFFECTED = re.compile(
    r"actuators are not modelled|tendons are not modelled|joint springs|gravity compensation|fluid forces|"
    r"inactive equalities|tendon equalities|flex equalities|a ball joint's range|is no frame of the model|"
    r"mesh file\(s\) not found")


def compare_with_mujoco(model, path, q, caught):
    """Our mass matrix against MuJoCo's at ``q``, when MuJoCo compiles the file into the same joints: they
    agree, unless the loader warned (``caught``) that it leaves out something that may change it."""
    if mujoco is None:
        return
    try:
        reference = mujoco.MjModel.from_xml_path(path)
    except Exception as error:  # MuJoCo refuses some files we accept (see the statistics)
        reason = re.sub(r"'[^']*'|[-+0-9.e]{2,}", "…", str(error).replace("\n", " "))
        event("loaded; MuJoCo refuses the file: " + reason[:70])
        return
    if (reference.nv != model.nv or reference.nq != model.nq
            or [mujoco.mj_id2name(reference, mujoco.mjtObj.mjOBJ_JOINT, k) or "" for k in range(reference.njnt)]
            != [name if not name.startswith("joint_") else "" for name in model.joint_names]):
        event("loaded; MuJoCo's joints differ")
        return
    data = mujoco.MjData(reference)
    data.qpos[:], _ = mb.to_mujoco(model, q, np.zeros(model.nv))
    mujoco.mj_forward(reference, data)
    M_mujoco = np.zeros((model.nv, model.nv))
    _full_mass_matrix(mujoco, reference, data, M_mujoco)
    T = mb.mjcf.velocity_to_mujoco(model, q)
    M_mujoco = T.T @ M_mujoco @ T
    scale = max(1.0, np.abs(M_mujoco).max(initial=0.0))
    if not np.isfinite(scale) or np.finfo(float).eps * rounding_scale(model, q) > MUJOCO_TOLERANCE * scale:
        event("loaded; not compared with MuJoCo: rounding at the bodies' scale exceeds the tolerance")
        return
    M = mb.mass_matrix(model, q)
    singular_values = np.linalg.svd(M, compute_uv=False)
    if singular_values.min() <= singular_values.max() / NUMERICALLY_SINGULAR:
        # MuJoCo's shortcuts for "simple" bodies take their joints to be independent (two slides along one
        # axis get a diagonal mass matrix)
        event("loaded; not compared with MuJoCo: the mass matrix is singular")
        return
    error = np.abs(M - M_mujoco).max(initial=0.0) / scale
    if error > MUJOCO_TOLERANCE:
        said = [str(w.message) for w in caught if not MASS_MATRIX_UNAFFECTED.search(str(w.message))]
        assert said, (error, [str(w.message) for w in caught])
        event("loaded; mass matrix differs from MuJoCo's after a warning")
    else:
        event("loaded; mass matrix agrees with MuJoCo's")


def check_mutant(text, path, state_seed=0):
    """The property of the module docstring, for one document."""
    folder = os.path.dirname(path)
    with open(path, "w", encoding="utf-8") as stream:
        stream.write(text)
    with warnings.catch_warnings(record=True) as caught, time_limit(HANG_S):
        warnings.simplefilter("always")
        try:
            model = mb.load_mjcf(path)
        except MJCFError as error:
            check_error(error, folder)
            model = None
        if model is not None:
            event("loaded")
            system = check_model(model)
            if model.nv > 0:
                q = check_dynamics(model, system, np.random.default_rng(state_seed))
                compare_with_mujoco(model, path, q, caught)
    check_warnings(caught)
    return model


@pytest.fixture(scope="module", autouse=True)
def _in_tmp_folder(tmp_path_factory):
    # MuJoCo writes its warnings about singular mass matrices to MUJOCO_LOG.TXT in the working directory
    here = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("mujoco_log"))
    yield
    os.chdir(here)


@pytest.fixture(scope="module")
def mutant_folder(tmp_path_factory):
    """The folder every example writes its mutant to (with the file the seed includes). The seed goes
    through the dynamics first, so that the compiled kernels are loaded before the first timed example."""
    folder = tmp_path_factory.mktemp("mjcf_fuzz")
    (folder / "part.xml").write_text(PART, encoding="utf-8")
    (folder / "seed.xml").write_text(SEED, encoding="utf-8")
    model = mb.load_mjcf(str(folder / "seed.xml"))
    q, v = model.random_configuration(0), np.ones(model.nv)
    mb.mass_matrix(model, q), mb.bias_forces(model, q, v), mb.forward_dynamics(model, q, v, v)
    rounding_scale(model, q)
    return str(folder)


def test_seed_loads_as_mujoco_compiles_it(mutant_folder):
    """The seed itself loads, without warnings, into MuJoCo's model (so that mutants start from a sound one)."""
    path = os.path.join(mutant_folder, "mutant.xml")
    check_mutant(SEED, path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = mb.load_mjcf(path)
    assert model.nv == 1 + 1 + 2 + 3 + 1 + 6 + 1 and len(model.equality_constraints) == 4


@settings(deadline=DEADLINE_MS, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(seed=st.sampled_from(SEEDS), mutation_list=st.lists(mutations, min_size=1, max_size=3))
# Mutants that exposed defects of the loader (each broke the property before its fix).
@example(seed="seed", mutation_list=[("set_number", ("mesh", "face"), 0, 0, "1e16")])  # IndexError
@example(seed="seed", mutation_list=[("set_text", ("mesh", "vertex"), 1, "1 2 3 4")])  # ValueError of a reshape
@example(seed="seed", mutation_list=[("delete", "inertial", 1),  # QhullError: a hull of three points
                                     ("set_text", ("mesh", "vertex"), 0, "0 0 0 1 0 0 0 1 0")])
@example(seed="seed", mutation_list=[("set_text", ("geom", "size"), 1, "1e-308")])  # a capsule's NaN inertia
@example(seed="seed", mutation_list=[("set_text", ("geom", "size"), 1, "1e50")])  # a body of 1e153 kg
@example(seed="seed", mutation_list=[("joint_type", 2, "hinge")])  # vertex= in double precision: M off by 3.6e-9
# A joint 8192 m along its own axis: MuJoCo's rounding grows with that distance (rounding_scale).
@example(seed="seed", mutation_list=[("set_number", ("joint", "pos"), 0, 1, "8192.0")])
def test_mutated_mjcf_loads_soundly_or_fails_clearly(mutant_folder, seed, mutation_list):
    """Any mutant of a seed: a clear MJCFError, or a model with finite dynamics that agrees with MuJoCo."""
    path = os.path.join(mutant_folder, "mutant.xml")
    check_mutant(mutant(seed, mutation_list, mutant_folder, "mutant.xml"), path)


# ----------------------------------------------------------------------------- regression cases


def one_body(inside="", before="", joint='<joint name="j" axis="0 1 0"/>', equality=""):
    """A document with body ``a`` on joint ``j`` holding ``inside`` (a unit sphere by default), after ``before``
    (compiler, defaults, assets), with ``equality`` in an ``<equality>``."""
    inside = inside or '<geom size="0.1"/>'
    equality = f"<equality>{equality}</equality>" if equality else ""
    return (f'<mujoco>{before}<worldbody><body name="a" pos="0 0 1">{joint}{inside}<site name="s"/></body>'
            f'<body name="b"><joint name="k"/><geom size="0.1"/></body></worldbody>{equality}</mujoco>')


TETRA = "0 0 0  1 0 0  0 1 0  0 0 1"


def mesh(vertex=TETRA, face=None, scale=None):
    face = f' face="{face}"' if face is not None else ""
    scale = f' scale="{scale}"' if scale is not None else ""
    return f'<asset><mesh name="m" vertex="{vertex}"{face}{scale}/></asset>'


MESH_GEOM = '<geom type="mesh" mesh="m"/>'

REFUSED = {
    "vertex count": (one_body(MESH_GEOM, mesh("0 0 0 1 0 0 0 1")), ["vertex data must be a multiple of 3", "'m'"]),
    "face count": (one_body(MESH_GEOM, mesh(face="0 1 2 3")), ["face data must be a multiple of 3", "'m'"]),
    "face index past the vertices": (one_body(MESH_GEOM, mesh(face="0 1 7")), ["vertex index 7 does not exist"]),
    "negative face index": (one_body(MESH_GEOM, mesh(face="0 2 1  0 1 -1  0 3 2  1 2 3")),
                            ["vertex index -1 does not exist"]),
    "fractional face index": (one_body(MESH_GEOM, mesh(face="0 2 1  0 1 2.5  0 3 2  1 2 3")),
                              ["bad format in attribute 'face'", "Element 'mesh', line 1"]),
    "hull of three points": (one_body(MESH_GEOM, mesh("0 0 0 1 0 0 0 1 0")), ["at least 4 vertices required", "'m'"]),
    "vertex past single precision": (one_body(MESH_GEOM, mesh("0 0 0 1e39 0 0 0 1 0 0 0 1")),
                                     ["number is too large in attribute 'vertex'", "Element 'mesh', line 1"]),
    "sphere of radius 1e20": (one_body('<geom size="1e20"/>'), ["body 'a': body_mass 4.189e+63", "magnitude above 1e+50"]),
    "dense cylinder": (one_body('<geom type="cylinder" size="1e-30 1e40"/>'),
                       ["mass and inertia of moving bodies must be larger than mjMINVAL", "'a'"]),
    "capsule thinner than the smallest volume": (one_body('<geom type="capsule" size="1e-200 0.5"/>'),
                                                 ["mass and inertia of moving bodies must be larger than mjMINVAL"]),
    "NaN position, which MuJoCo compiles": (one_body().replace('pos="0 0 1"', 'pos="nan 0 1"'),
                                            ["body 'a': body_pos [nan", "not finite"]),
    "axis whose square overflows, which MuJoCo compiles as zero": (
        one_body(joint='<joint name="j" axis="1e160 0 0"/>'), ["joint 'j': revolute joint axis must be non-zero"]),
    "negative damping, which MuJoCo compiles": (one_body(joint='<joint name="j" damping="-1"/>'),
                                                ["damping of joint 'j' must not be negative"]),
    "free joint after a hinge": (one_body(joint='<joint name="j"/><freejoint name="f"/>'),
                                 ["more than 6 dofs in body 'a'"]),
    "free joint after a slide, as a joint type": (one_body(joint='<joint type="slide"/><joint type="free"/>'),
                                                  ["more than 6 dofs in body 'a'"]),
    "a body named world": (one_body().replace('name="b"', 'name="world"'), ["repeated name 'world' in body"]),
    "fractional group": (one_body('<geom size="0.1" group="1.5"/>'), ["bad format in attribute 'group'"]),
    "huge group": (one_body('<geom size="0.1" group="1e40"/>'), ["bad format in attribute 'group'"]),
    "fractional inertiagrouprange": (one_body(before='<compiler inertiagrouprange="0 2.5"/>'),
                                     ["bad format in attribute 'inertiagrouprange'"]),
    "connect of a body to itself": (one_body(equality='<connect body1="a" body2="a" anchor="0 0 0"/>'),
                                    ["element 'a' is repeated in equality constraint 0"]),
    "weld of the world to itself": (one_body(equality='<weld body1="world"/>'),
                                    ["element 'world' is repeated in equality constraint 0"]),
    "weld of a site to itself": (one_body(equality='<weld site1="s" site2="s"/>'),
                                 ["element 's' is repeated in equality constraint 0"]),
    "sites and bodies": (one_body(equality='<connect site1="s" site2="s" body1="a" anchor="0 0 0"/>'),
                         ["at most one of ('site1', 'site2'), ('body1', 'body2', 'anchor') can be specified"]),
    "joint equality without joint1": (one_body(equality='<joint joint2="j"/>'), ["required attribute missing: 'joint1'"]),
}


@pytest.mark.parametrize("name", REFUSED)
def test_refused_at_load_with_mujocos_message(name, tmp_path):
    """Documents the fuzz test found crashing the loader, loading with NaN or past ``LARGEST_MAGNITUDE``, or
    loading wrongly (a free joint as a ball joint, fractional indices truncated, a constraint of a body with
    itself) fail at load time with an MJCFError: the file, then what MuJoCo's compiler says (or, for masses
    past ``LARGEST_MAGNITUDE``, which MuJoCo compiles, the loader's own message)."""
    xml, fragments = REFUSED[name]
    path = tmp_path / "case.xml"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # (MuJoCo's compiler warns of the zero axis it makes of an overflowing one)
        warnings.filterwarnings("ignore", message="Inertia matrix is too close to singular")
        check_refused(mb.load_mjcf, MJCFError, path, xml, f"{path}: ", fragments)


@pytest.mark.skipif(mujoco is None, reason="MuJoCo is not installed")
def test_mesh_given_by_its_vertices_is_mujocos_in_single_precision():
    """``vertex=`` is read in single precision, as MuJoCo keeps it: the tetrahedron's mass is MuJoCo's to
    rounding (it differed by 4.5e-8 relative), and the mesh, which has no file for the viewer, gives no
    warning about missing mesh files."""
    xml = one_body(MESH_GEOM, mesh(TETRA, scale="0.1 0.1 0.1"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = mb.load_mjcf(xml)
    reference = mujoco.MjModel.from_xml_string(xml)
    assert model.body_inertias[0].mass == pytest.approx(reference.body_mass[1], rel=1e-15, abs=0)
    assert not any(geometry.shape == "mesh" for geometry in model.geometries)


@pytest.mark.parametrize("order", ["nested class first", "nested class last"])
def test_nested_default_class_inherits_what_its_parent_holds_wherever_written(order):
    """A nested class inherits all of its parent's elements, also those written after it, as MuJoCo reads
    them (the sphere's size of class ``a`` reaches class ``b``)."""
    nested, own = '<default class="b"/>', '<geom size="0.2"/>'
    inside = nested + own if order == "nested class first" else own + nested
    xml = one_body('<geom class="b"/>', f'<default><default class="a">{inside}</default></default>')
    model = mb.load_mjcf(xml)
    volume = 4.0 / 3.0 * math.pi * 0.2**3
    assert model.body_inertias[0].mass == pytest.approx(1000.0 * volume, rel=1e-15)
    if mujoco is not None:
        assert model.body_inertias[0].mass == pytest.approx(mujoco.MjModel.from_xml_string(xml).body_mass[1], rel=1e-15)


@pytest.mark.parametrize("depth", [450, 5000])
def test_deep_nesting_loads_or_is_refused_quickly(depth):
    """450 nested default classes and 450 bodies nested without joints load, each within a few seconds;
    5000 are past the nesting MuJoCo's XML parser reads, a clear MJCFError at once."""
    classes = "".join(f'<default class="c{i}">' for i in range(depth)) + '<geom size="0.2"/>' + "</default>" * depth
    bodies = "<body>" * depth + '<geom size="0.1"/>' + "</body>" * depth
    for xml, check in ((one_body(f'<geom class="c{depth - 1}"/>', f"<default>{classes}</default>"),
                        lambda model: model.body_inertias[0].mass > 0.0),
                       (one_body('<geom size="0.1"/>' + bodies),
                        lambda model: len(model.body_names) == depth + 3 and model.nv == 2)):
        with time_limit(HANG_S):
            if depth > 500:
                with pytest.raises(MJCFError, match=r"(?s)^<MJCF string>: .*XML_ELEMENT_DEPTH_EXCEEDED"):
                    mb.load_mjcf(xml)
            else:
                assert check(mb.load_mjcf(xml))


HOSTILE_FILES = {
    "empty": ("", r"ParseXML: empty file"),
    "blank": ("  \n ", r"XML parse error 13:\nError=XML_ERROR_EMPTY_DOCUMENT"),
    "not XML": ("joint hinge 0 0 1", r"XML parse error 8:\nError=XML_ERROR_PARSING_TEXT"),
    "binary": ("\x00\x01\x02", r"XML parse error 13:\nError=XML_ERROR_EMPTY_DOCUMENT"),
    "cut short": ('<mujoco><worldbody><body name="a"', r"XML parse error 6:\nError=XML_ERROR_PARSING_ELEMENT"),
    "not MJCF": ("<robot name='r'/>", r"the root element must be <mujoco>, got <robot>"),
}


@pytest.mark.parametrize("name", HOSTILE_FILES)
def test_hostile_files_fail_with_the_file_and_mujocos_message(name, tmp_path):
    """Empty files, non-XML, files cut short and another format's root (which MuJoCo would compile as URDF):
    an MJCFError naming the file, quickly and without reading anything else."""
    text, message = HOSTILE_FILES[name]
    path = tmp_path / "hostile.xml"
    path.write_text(text, encoding="utf-8")
    with time_limit(HANG_S), pytest.raises(MJCFError, match=rf"^{re.escape(str(path))}: {message}"):
        mb.load_mjcf(str(path))


ENTITIES = {
    "entity expansion": "<!DOCTYPE m [<!ENTITY a 'aaaaaaaaaa'>" + "".join(
        f"<!ENTITY {b} '{('&' + a + ';') * 10}'>" for a, b in zip("abcdefg", "bcdefgh")) + "]><mujoco model='&h;'/>",
    "external entity": "<!DOCTYPE m [<!ENTITY x SYSTEM 'file:///etc/hostname'>]><mujoco model='&x;'/>",
}


@pytest.mark.parametrize("name", ENTITIES)
def test_entities_are_neither_expanded_nor_read(name, tmp_path):
    """A billion laughs and an external entity: MuJoCo's parser expands no entity of a document type, so the
    file loads quickly, its model named by the entity reference as written."""
    path = tmp_path / "hostile.xml"
    path.write_text(ENTITIES[name], encoding="utf-8")
    with time_limit(HANG_S):
        model = mb.load_mjcf(str(path))
    assert model.nv == 0 and model.name in ("&h;", "&x;")


@pytest.mark.parametrize("kind", ["self", "cycle", "missing", "no file", "not mujoco", "not xml", "empty"])
def test_hostile_includes_fail_with_the_including_element(kind, tmp_path):
    """An ``<include>`` of the file itself, of a file that includes it back, of a missing file, without
    ``file``, of a file whose root is not ``<mujoco>``, of non-XML or of an empty file: an MJCFError that
    names the file and line of the ``<include>`` (or of the included file's error)."""
    root = ET.fromstring(one_body())
    mutate(root, ("include", kind, 0), str(tmp_path), "main.xml")
    path = tmp_path / "main.xml"
    path.write_text(ET.tostring(root, encoding="unicode"), encoding="utf-8")
    with time_limit(HANG_S), pytest.raises(MJCFError) as info:
        mb.load_mjcf(str(path))
    check_error(info.value, str(tmp_path))
