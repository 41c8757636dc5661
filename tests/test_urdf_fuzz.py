"""URDF mutation fuzzing: a damaged URDF either fails to load with a clear error or loads a sound model.

Seeds are the URDFs shipped in ``robots/`` and a few example-robot-data robots. A Hypothesis
strategy applies one to three mutations to a seed's XML tree: delete, duplicate or reorder
elements; give a link or joint the name of another; write non-numeric text, NaN, ±inf, negative,
zero, huge (1e308) or tiny (1e-308) numbers or the wrong count of numbers into attributes; scale
a link's mass and inertia by huge, tiny, zero or negative factors; set joint limits; make a
joint's child an ancestor of its parent (a cycle); point a joint at a parent link that does not
exist; write unknown joint types; add mimic relations to a missing joint, to the joint itself or to
a fixed joint; give links and joints non-ASCII names.

The property, for every mutant written to a file: :func:`multibody.load_urdf` (fixed or floating
base) either raises :class:`~multibody.urdf.URDFError` whose message names the file and an element
of the document, or returns a model on which ``random_configuration`` works and, at that finite
state with finite ``v`` and ``tau``, the mass matrix, the bias forces and the forward dynamics are
finite. The forward dynamics may instead raise ``LinAlgError`` for a mass matrix that is singular
(a joint that moves no inertia, which the message names) or numerically singular. Whenever
Pinocchio loads the same file into the same joints, the two mass matrices agree. No other
exception, no warning other than a few of the loader's user warnings (meshes not found, ignored
planar axis, dropped mimic), and no example slower than the deadline. A loaded model also keeps
the loader's promises (:func:`check_model`).

The number of examples comes from the Hypothesis profile (``conftest.py``).
"""

from __future__ import annotations

import copy
import os
import pathlib
import re
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

import multibody as mb
from multibody import joints as jt
from multibody.check import to_pinocchio_configuration
from multibody.urdf import LARGEST_MAGNITUDE, UNBOUNDED_LIMIT, URDFError

from conftest import ERD_DIR
from fuzz_helpers import check_forward_dynamics, check_refused

try:
    import pinocchio as pin
except ImportError:  # the comparison is skipped; the rest of the property still runs
    pin = None

# ----------------------------------------------------------------------------- seeds

ERD_SEEDS = (
    "ur_description/urdf/ur5_robot.urdf",
    "panda_description/urdf/panda.urdf",
    "solo_description/robots/solo12.urdf",
)


def _seed_paths():
    paths = {name: mb.robots.path(name) for name in mb.robots.names(example_robot_data=False)}
    for relative in ERD_SEEDS:
        path = os.path.join(ERD_DIR, relative) if ERD_DIR else None
        if path and os.path.isfile(path):
            paths[os.path.basename(relative)[: -len(".urdf")]] = path
    return paths


SEED_PATHS = _seed_paths()
SEED_TEXT = {name: pathlib.Path(path).read_text(encoding="utf-8") for name, path in SEED_PATHS.items()}
SEEDS = sorted(SEED_TEXT)

# ----------------------------------------------------------------------------- mutations
#
# A mutation is a tuple of plain values, so that a failing example can be written down in
# @example(...). Integers pick among the matching elements modulo their number; a mutation that
# finds nothing to act on leaves the document unchanged.

STRUCTURAL_TAGS = ("link", "joint", "inertial", "mass", "inertia", "origin", "axis", "limit", "parent",
                   "child", "mimic", "visual", "geometry")
REORDERED_TAGS = ("robot", "link", "joint", "inertial", "visual")
NUMERIC_ATTRIBUTES = (
    ("origin", "xyz"), ("origin", "rpy"), ("mass", "value"),
    ("inertia", "ixx"), ("inertia", "iyy"), ("inertia", "izz"),
    ("inertia", "ixy"), ("inertia", "ixz"), ("inertia", "iyz"),
    ("axis", "xyz"), ("limit", "lower"), ("limit", "upper"), ("limit", "effort"),
    ("mimic", "multiplier"), ("mimic", "offset"),
    ("box", "size"), ("sphere", "radius"), ("cylinder", "radius"), ("cylinder", "length"), ("mesh", "scale"),
)
TEXT_ATTRIBUTES = NUMERIC_ATTRIBUTES + (
    ("link", "name"), ("joint", "name"), ("joint", "type"), ("parent", "link"), ("child", "link"),
    ("mimic", "joint"), ("robot", "name"),
)
# Replacements for one number of an attribute.
NUMBER_TOKENS = ("nan", "NaN", "inf", "-inf", "-1", "-0.5", "0", "-0", "1e308", "-1e308", "1e300", "1e-308",
                 "5e-324", "1e16", "-1e16", "1e50", "1e51", "1e20", "1e-20", "1e999")
# Replacements for a whole attribute: not numbers, wrong counts, and syntax only Python accepts.
ATTRIBUTE_TEXTS = ("abc", "", " ", "1 2", "1 2 3 4", "0 0 0", "1,5", "1_0", "\u0663", "0x1p3", "infinity",
                   "1e308 1e308 1e308", "nan nan nan", "1e-308 0 0")
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar", "screw", "", "REVOLUTE",
               "spherical")
LIMIT_TOKENS = ("-1e308", "1e308", "-inf", "inf", "-1e16", "1e16", "-1e15", "1e15", "0", "-1", "1", "nan", "1e-308")
MIMIC_TARGETS = ("missing", "self", "fixed", "other", "no attribute")
# Factors for a link's mass and inertia tensor together (a positive one keeps a valid body valid).
INERTIAL_SCALES = ("1e300", "1e51", "1e50", "1e20", "1e-20", "1e-300", "5e-324", "0", "-1")
NON_ASCII = ("_\u00fc\u00df", "_\u03bb\u03af\u03bd\u03ba", "_\u65e5\u672c", "_\U0001f916", " \u00e9")

indices = st.integers(0, 1000)
numbers = st.one_of(st.sampled_from(NUMBER_TOKENS), st.floats().map(repr))

mutations = st.one_of(
    st.tuples(st.just("delete"), st.sampled_from(STRUCTURAL_TAGS), indices),
    st.tuples(st.just("duplicate"), st.sampled_from(STRUCTURAL_TAGS), indices),
    st.tuples(st.just("reorder"), st.sampled_from(REORDERED_TAGS), indices, st.integers(1, 5)),
    st.tuples(st.just("rename"), st.sampled_from(("link", "joint")), indices, indices),
    st.tuples(st.just("non_ascii"), st.sampled_from(("link", "joint")), indices, st.sampled_from(NON_ASCII)),
    st.tuples(st.just("set_number"), st.sampled_from(NUMERIC_ATTRIBUTES), indices, st.integers(0, 2), numbers),
    st.tuples(st.just("set_text"), st.sampled_from(TEXT_ATTRIBUTES), indices, st.sampled_from(ATTRIBUTE_TEXTS)),
    st.tuples(st.just("scale_inertial"), indices, st.sampled_from(("mass", "inertia", "both")),
              st.sampled_from(INERTIAL_SCALES)),
    st.tuples(st.just("cycle"), indices, indices),
    st.tuples(st.just("missing_parent"), indices, st.booleans()),
    st.tuples(st.just("joint_type"), indices, st.sampled_from(JOINT_TYPES)),
    st.tuples(st.just("limits"), indices, st.sampled_from(LIMIT_TOKENS), st.sampled_from(LIMIT_TOKENS)),
    st.tuples(st.just("mimic"), indices, st.sampled_from(MIMIC_TARGETS), indices),
)


def _parents(root):
    return {child: parent for parent in root.iter() for child in parent}


def _pick(elements, k):
    return elements[k % len(elements)] if elements else None


def _with_tag(root, tag):
    return [element for element in root.iter(tag) if element is not root] if tag != "robot" else [root]


def _rename_references(root, tag, old, new):
    """Rename link or joint ``old`` to ``new`` everywhere it is referred to."""
    if tag == "link":
        for end in list(root.iter("parent")) + list(root.iter("child")):
            if end.get("link") == old:
                end.set("link", new)
    else:
        for mimic in root.iter("mimic"):
            if mimic.get("joint") == old:
                mimic.set("joint", new)


def _link_parents(root):
    """``{child link: parent link}`` of the joints as they stand."""
    out = {}
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is not None and child is not None:
            out[child.get("link")] = parent.get("link")
    return out


def _owner_name(root, element):
    """Name of the link or joint that holds ``element`` (its own name for a link or joint)."""
    parents = _parents(root)
    while element is not None and element.tag not in ("link", "joint"):
        element = parents.get(element)
    return element.get("name", "") if element is not None else ""


def _joint_links(joint):
    return [end.get("link", "") for end in (joint.find("parent"), joint.find("child")) if end is not None]


def mutate(root, mutation):
    """Apply one mutation to the XML tree ``root`` in place.

    Returns the names and attributes involved: a load error caused by this mutation alone must
    mention one of them (empty when the mutation did nothing or cannot be traced to a name).
    """
    kind, *args = mutation
    joints = root.findall("joint")
    if kind in ("delete", "duplicate"):
        tag, k = args
        element = _pick(_with_tag(root, tag), k)
        if element is None or element is root:
            return ()
        involved = (_owner_name(root, element), element.get("name", ""))
        if element.tag == "joint":
            involved += tuple(_joint_links(element))
        if element.tag == "link":
            involved += ("no <link> elements",)  # when it was the only one
        parent = _parents(root)[element]
        if kind == "delete":
            parent.remove(element)
        else:
            parent.insert(list(parent).index(element) + 1, copy.deepcopy(element))
        return involved
    if kind == "reorder":
        tag, k, shift = args
        element = _pick(_with_tag(root, tag), k)
        if element is None or len(element) < 2:
            return ()
        children = list(element)
        shift %= len(children)
        for child in children:
            element.remove(child)
        element.extend(children[shift:][::-1] + children[:shift])
        return ()
    if kind == "rename":
        tag, k, j = args
        elements = root.findall(tag)
        if not elements:
            return ()
        element, new = _pick(elements, k), _pick(elements, j).get("name", "")
        involved = (element.get("name", ""), new)
        element.set("name", new)
        return involved
    if kind == "non_ascii":
        tag, k, suffix = args
        element = _pick(root.findall(tag), k)
        if element is None:
            return ()
        old = element.get("name", "")
        element.set("name", old + suffix)
        _rename_references(root, tag, old, old + suffix)
        return (old + suffix,)
    if kind in ("set_number", "set_text"):
        (tag, attribute), k, *rest = args
        element = _pick([e for e in root.iter(tag) if attribute in e.attrib], k)
        if element is None:
            return ()
        old = element.get(attribute)
        if kind == "set_number":
            component, token = rest
            numbers = old.split() or ["0"]
            numbers[component % len(numbers)] = token
            new = " ".join(numbers)
        else:
            new, = rest
        element.set(attribute, new)
        return (_owner_name(root, element), attribute, old, new)
    if kind == "scale_inertial":
        k, what, factor = args
        inertial = _pick([i for i in root.iter("inertial") if i.find("mass") is not None], k)
        if inertial is None:
            return ()
        targets = [] if what == "inertia" else [(inertial.find("mass"), "value")]
        if what != "mass" and inertial.find("inertia") is not None:
            targets += [(inertial.find("inertia"), key) for key in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
        for element, attribute in targets:
            try:
                element.set(attribute, repr(float(element.get(attribute)) * float(factor)))
            except (TypeError, ValueError):  # absent, or already made non-numeric by another mutation
                pass
        return (_owner_name(root, inertial),)
    if kind == "cycle":
        # The child of a joint becomes its parent link or one of that link's ancestors.
        k, depth = args
        joint = _pick([j for j in joints if j.find("parent") is not None and j.find("child") is not None], k)
        if joint is None:
            return ()
        parent_of = _link_parents(root)
        ancestors = [joint.find("parent").get("link")]
        while ancestors[-1] in parent_of and parent_of[ancestors[-1]] not in ancestors:
            ancestors.append(parent_of[ancestors[-1]])
        involved = (joint.get("name", ""), *_joint_links(joint))
        joint.find("child").set("link", ancestors[depth % len(ancestors)])
        return involved
    if kind == "missing_parent":
        # The joint's parent link is renamed away, or its element deleted.
        k, delete_link = args
        joint = _pick([j for j in joints if j.find("parent") is not None], k)
        if joint is None:
            return ()
        name = joint.find("parent").get("link")
        if delete_link:
            for link in root.findall("link"):
                if link.get("name") == name:
                    root.remove(link)
        else:
            joint.find("parent").set("link", "ghost_link")
        return (joint.get("name", ""), name)
    if kind == "joint_type":
        k, kind_text = args
        joint = _pick(joints, k)
        if joint is None:
            return ()
        joint.set("type", kind_text)
        return (joint.get("name", ""),)
    if kind == "limits":
        k, lower, upper = args
        joint = _pick(joints, k)
        if joint is None:
            return ()
        limit = joint.find("limit")
        if limit is None:
            limit = ET.SubElement(joint, "limit", effort="1", velocity="1")
        limit.set("lower", lower)
        limit.set("upper", upper)
        return (joint.get("name", ""),)
    if kind == "mimic":
        k, target, j = args
        joint = _pick(joints, k)
        if joint is None:
            return ()
        for old in joint.findall("mimic"):
            joint.remove(old)
        fixed = [other.get("name", "") for other in joints if other.get("type") == "fixed"]
        name = {"missing": "no_such_joint", "self": joint.get("name", ""),
                "fixed": _pick(fixed, j) or "no_fixed_joint",
                "other": _pick(joints, j).get("name", "")}.get(target)
        mimic = ET.SubElement(joint, "mimic", multiplier="-2", offset="0.1")
        if name is not None:
            mimic.set("joint", name)
        return (joint.get("name", ""),)
    raise AssertionError(f"unknown mutation {mutation!r}")


def mutant(seed, mutation_list):
    """``(XML text, names involved)`` of a seed after the mutations; the names only for a single mutation."""
    root = ET.fromstring(SEED_TEXT[seed])
    involved = [mutate(root, mutation) for mutation in mutation_list]
    return ET.tostring(root, encoding="unicode"), involved[0] if len(involved) == 1 else ()


# ----------------------------------------------------------------------------- the property

# UserWarnings the loader may give for a document that loads: meshes not found (the files are
# written away from their meshes), a planar joint's axis ignored, a mimic of a missing joint dropped.
EXPECTED_WARNINGS = re.compile(r"mesh file\(s\) not found|planar joints move in the x-y plane|"
                               r"the mimic relation is dropped")
MAX_WARNINGS = 3
# Relative error of our mass matrix against Pinocchio's: max|ours − theirs| / max(1, max|theirs|),
# as in test_dynamics_pinocchio.py.
PINOCCHIO_TOLERANCE = 1e-10


def _element_names(root):
    """The element references an error message may start with."""
    names = {"<robot>", "<link>", "<joint>", "rigid body of links"}
    names |= {f"<link name='{link.get('name')}'>" for link in root.iter("link")}
    names |= {f"<joint name='{joint.get('name')}'>" for joint in root.iter("joint")}
    return names


def check_error(error, path, root, involved=()):
    """The message names the file, then an element of the document, and one of the names or
    attributes ``involved`` in the mutation that caused it (when known)."""
    message = str(error)
    prefix = f"{path}: "
    assert message.startswith(prefix), message
    where = message[len(prefix):]
    assert any(where.startswith(name) for name in _element_names(root)), message
    assert ": " in where, message
    assert not involved or any(name and name in message for name in involved), (involved, message)
    event("URDFError: " + re.sub(r"'[^']*'|\"[^\"]*\"|\[[^]]*\]|[-+0-9.e]{2,}", "…", where.split(": ", 1)[1])[:60])


def check_warnings(caught):
    unexpected = [w for w in caught if not (issubclass(w.category, UserWarning)
                                            and EXPECTED_WARNINGS.search(str(w.message)))]
    assert not unexpected, [f"{w.category.__name__}: {w.message}" for w in unexpected]
    assert len(caught) <= MAX_WARNINGS, [str(w.message) for w in caught]


def check_model(model):
    """What a loaded model promises, whatever the document: unit joint axes, limits that are ordered
    and either unbounded or below ``UNBOUNDED_LIMIT``, link masses and inertias within
    ``LARGEST_MAGNITUDE``, and mimic relations between two distinct one-coordinate joints."""
    for name, joint in zip(model.joint_names, model.joints):
        if hasattr(joint, "axis"):
            assert np.all(np.isfinite(joint.axis)) and abs(np.linalg.norm(joint.axis) - 1.0) < 1e-12, (name, joint.axis)
    assert np.all(model.lower <= model.upper), (model.lower, model.upper)
    for bound in (model.lower, model.upper):
        finite = bound[np.isfinite(bound)]
        assert np.all(np.abs(finite) < UNBOUNDED_LIMIT), bound
    for name, inertia in zip(model.body_names, model.body_inertias):
        assert 0.0 <= inertia.mass <= LARGEST_MAGNITUDE, (name, inertia)
        assert np.all(np.abs(inertia.com) <= LARGEST_MAGNITUDE), (name, inertia)
        # the tensor rotated into the link frame: each entry at most three times the largest written
        assert np.all(np.abs(inertia.rotational) <= 3.0 * LARGEST_MAGNITUDE), (name, inertia)
    for mimic in model.mimic:
        assert mimic.joint != mimic.mimicked, mimic
        for name in (mimic.joint, mimic.mimicked):
            joint = model.joints[model.joint_index(name)]
            assert joint.nq == joint.nv == 1, (mimic, joint)


def check_dynamics(model, rng):
    """Finite dynamics at a random state; returns ``(q, M)``."""
    q = model.random_configuration(rng)
    assert q.shape == (model.nq,) and np.all(np.isfinite(q)), q
    assert np.all(q >= model.lower) and np.all(q <= model.upper), (q, model.lower, model.upper)
    v, tau = rng.standard_normal((2, model.nv))
    M = mb.mass_matrix(model, q)
    assert np.all(np.isfinite(M)), M
    h = mb.bias_forces(model, q, v)
    assert np.all(np.isfinite(h)), h
    check_forward_dynamics(model, q, v, tau, M, event)
    return q, M


def rounding_scale(model, q):
    """Magnitude of the terms the mass matrix is summed from: ``m (2 R)² + max|I|`` over the links,
    ``R`` the largest distance of a link frame or centre of mass from the world origin at ``q``. Any
    algorithm that is stable in norm may be off by about ``eps`` times this, e.g. when a centre of
    mass lies 1e16 m along a joint axis and the mass matrix entry is ``m (x² + z²) ≈ 0.25``."""
    poses = mb.forward_kinematics(model, q)
    coms = np.einsum("bij,bj->bi", poses[:, :3, :3], np.array([I.com for I in model.body_inertias])) + poses[:, :3, 3]
    reach = max(np.abs(poses[:, :3, 3]).max(initial=0.0), np.abs(coms).max(initial=0.0))
    return max(I.mass * (2.0 * reach) ** 2 + np.abs(I.rotational).max() for I in model.body_inertias)


def compare_with_pinocchio(model, path, floating_base, q, M):
    """Our mass matrix against Pinocchio's at ``q``, when Pinocchio builds the same joints and the
    tolerance lies above the rounding that the sizes in the document allow."""
    if pin is None:
        return
    try:
        pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating_base \
            else pin.buildModelFromUrdf(path)
    except Exception:  # Pinocchio refuses some files we accept (e.g. an <inertial> without <inertia>)
        return
    n_continuous = sum(isinstance(joint, jt.Continuous) for joint in model.joints)
    if (list(pmodel.names)[1:] != list(model.joint_names) or pmodel.nv != model.nv
            or pmodel.nq != model.nq + n_continuous):
        return
    data = pmodel.createData()
    M_pin = pin.crba(pmodel, data, to_pinocchio_configuration(model, q))
    M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
    scale = max(1.0, np.abs(M_pin).max(initial=0.0))
    if np.finfo(float).eps * rounding_scale(model, q) > PINOCCHIO_TOLERANCE * scale:
        event("loaded; not compared with Pinocchio: rounding at the links' scale exceeds the tolerance")
        return
    error = np.abs(M - M_pin).max(initial=0.0) / scale
    assert error <= PINOCCHIO_TOLERANCE, (error, M, M_pin)
    event("loaded; mass matrix compared with Pinocchio")


def check_mutant(text, path, floating_base, involved=(), state_seed=0):
    """The property of the module docstring, for one document."""
    with open(path, "w", encoding="utf-8") as file:
        file.write(text)
    root = ET.fromstring(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = mb.load_urdf(path, floating_base=floating_base)
        except URDFError as error:
            check_error(error, path, root, involved)
            model = None
        if model is not None:
            event("loaded")
            check_model(model)
        if model is not None and model.nv > 0:
            q, M = check_dynamics(model, np.random.default_rng(state_seed))
            compare_with_pinocchio(model, path, floating_base, q, M)
    check_warnings(caught)
    return model


@pytest.fixture(scope="module")
def mutant_path(tmp_path_factory):
    """One file, rewritten by every example. A shipped robot, fixed and floating, goes through the
    dynamics first, so that the compiled kernels are loaded before the first timed example."""
    for floating_base in (False, True):
        model = mb.robots.load("four_bar", floating_base=floating_base)
        q, v = model.random_configuration(0), np.ones(model.nv)
        mb.mass_matrix(model, q), mb.bias_forces(model, q, v), mb.forward_dynamics(model, q, v, v)
        rounding_scale(model, q)
    return str(tmp_path_factory.mktemp("urdf_fuzz") / "mutant.urdf")


@settings(deadline=5000, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.sampled_from(SEEDS), floating_base=st.booleans(),
       mutation_list=st.lists(mutations, min_size=1, max_size=3))
# Mutants that exposed defects of the loader (each broke the property before its fix).
@example(seed="pendulum", floating_base=False,  # limits of ±1e308: OverflowError in random_configuration
         mutation_list=[("joint_type", 0, "revolute"), ("limits", 0, "-1e308", "1e308")])
@example(seed="double_pendulum", floating_base=False,  # inertia of 1e300: loaded as it stood
         mutation_list=[("scale_inertial", 0, "inertia", "1e300")])
@example(seed="pendulum", floating_base=True,  # mass of 1e308: infinite bias forces
         mutation_list=[("set_number", ("mass", "value"), 0, 0, "1e308")])
@example(seed="pendulum", floating_base=False,  # axis of 1e200: its norm overflowed, a zero axis
         mutation_list=[("set_text", ("axis", "xyz"), 0, "1e200 1e200 0")])
@example(seed="double_pendulum", floating_base=False,  # a joint that mimics itself
         mutation_list=[("mimic", 0, "self", 0)])
@example(seed="double_pendulum", floating_base=False,  # a joint that mimics a fixed joint
         mutation_list=[("mimic", 0, "fixed", 0)])
@example(seed="double_pendulum", floating_base=False,  # a fixed joint that mimics another
         mutation_list=[("mimic", 2, "other", 0)])
# A centre of mass 1e16 m along the joint axis: rounding at that scale is beyond the tolerance of the
# comparison with Pinocchio, which must be skipped (see rounding_scale).
@example(seed="double_pendulum", floating_base=False,
         mutation_list=[("set_number", ("origin", "xyz"), 0, 1, "1e16")])
def test_mutated_urdf_loads_soundly_or_fails_clearly(mutant_path, seed, floating_base, mutation_list):
    """Any mutant of a seed URDF: a clear URDFError, or a model with finite dynamics that agrees with Pinocchio."""
    text, involved = mutant(seed, mutation_list)
    check_mutant(text, mutant_path, floating_base, involved)


def test_random_configuration_with_one_sided_limit_beyond_default_range():
    """A joint limited only from above, at -4 rad: ``random_configuration`` must draw angles ≤ -4.

    Found by the fuzz test (``<limit lower="-1e308" upper="-1e15">``)."""
    xml = ('<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
           '<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>'
           '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
           '<limit lower="-inf" upper="-4" effort="1" velocity="1"/></joint></robot>')
    model = mb.load_urdf(xml)
    assert model.lower[0] == -np.inf and model.upper[0] == -4.0
    q = model.random_configuration(np.random.default_rng(0), shape=100)
    assert np.all(q <= -4.0)


# ----------------------------------------------------------------------------- regression cases

INERTIAL = ('<inertial><mass value="{mass}"/><inertia ixx="{moment}" iyy="{moment}" izz="{moment}" ixy="0" ixz="0" '
            'iyz="0"/></inertial>')


def one_joint_robot(joint_body='<axis xyz="0 0 1"/>', kind="revolute", mass="1", moment="0.1", links="", joints=""):
    """A root link ``a`` and a link ``b`` on joint ``j``, plus any further links and joints."""
    return (f'<robot name="r"><link name="a"/><link name="b">{INERTIAL.format(mass=mass, moment=moment)}</link>{links}'
            f'<joint name="j" type="{kind}"><parent link="a"/><child link="b"/>{joint_body}</joint>{joints}</robot>')


FIXED_TIP = ('<link name="c"/>', '<joint name="f" type="fixed"><parent link="b"/><child link="c"/></joint>')

REFUSED = {
    "inertia 1e300": (one_joint_robot(moment="1e300"), ["<link name='b'>/<inertial>/<inertia>", "ixx", "magnitude"]),
    "mass 1e308": (one_joint_robot(mass="1e308"), ["<link name='b'>/<inertial>/<mass>", "value", "magnitude"]),
    "origin 1e308": (one_joint_robot('<origin xyz="1e308 0 0"/><axis xyz="0 0 1"/>'),
                     ["<joint name='j'>/<origin>", "xyz", "magnitude"]),
    "axis 1e200": (one_joint_robot('<axis xyz="1e200 1e200 0"/>'), ["<joint name='j'>/<axis>", "xyz"]),
    "axis 1e-308": (one_joint_robot('<axis xyz="1e-308 0 0"/>'), ["<joint name='j'>/<axis>", "xyz", "non-zero"]),
    "digit separator": (one_joint_robot('<origin xyz="1_0 0 0"/>'), ["<origin>", "xyz", "'1_0' is not a decimal"]),
    "non-ASCII digit": (one_joint_robot('<origin xyz="\u0663 0 0"/>'), ["<origin>", "xyz", "not a decimal"]),
    "hexadecimal": (one_joint_robot(mass="0x1p3"), ["<mass>", "value", "not a decimal"]),
    "infinite origin": (one_joint_robot('<origin xyz="inf 0 0"/>'), ["<origin>", "xyz", "'inf' is not a decimal"]),
    "NaN limit": (one_joint_robot('<limit lower="nan" upper="1"/>'), ["<joint name='j'>/<limit>", "lower", "'nan'"]),
    "lower limit 1e308": (one_joint_robot('<limit lower="1e308" upper="1e308"/>'),
                          ["<joint name='j'>/<limit>", "lower", "no finite position"]),
    "negative box size": (one_joint_robot(links='<link name="c"><visual><geometry><box size="1 -1 1"/></geometry>'
                                                '</visual></link>', joints=FIXED_TIP[1]),
                          ["<link name='c'>/<visual>/<box>", "size", "negative"]),
    "mimic of itself": (one_joint_robot('<mimic joint="j"/>'), ["<joint name='j'>/<mimic>", "'j'", "itself"]),
    "mimic of a fixed joint": (one_joint_robot('<mimic joint="f"/>', links=FIXED_TIP[0], joints=FIXED_TIP[1]),
                               ["<joint name='j'>/<mimic>", "'f'", "fixed joint"]),
    "mimic without target": (one_joint_robot('<mimic multiplier="2"/>'), ["<joint name='j'>/<mimic>", "'joint'"]),
    "floating joint that mimics": (
        one_joint_robot(kind="floating", links='<link name="c">' + INERTIAL.format(mass=1, moment=0.1) + '</link>',
                        joints='<joint name="k" type="revolute"><parent link="b"/><child link="c"/></joint>')
        .replace('<child link="b"/>', '<child link="b"/><mimic joint="k"/>'),
        ["<joint name='j'>/<mimic>", "floating joint cannot mimic"]),
}


@pytest.mark.parametrize("name", REFUSED)
def test_refused_at_load_with_the_element_and_attribute(name, tmp_path):
    """Documents the fuzz test found loading, or failing later, must fail at load time with a
    URDFError naming the file, the element and the attribute."""
    xml, fragments = REFUSED[name]
    path = tmp_path / "case.urdf"
    check_refused(mb.load_urdf, URDFError, path, xml, f"{path}: ", fragments)


@pytest.mark.parametrize("lower,upper,expected", [
    ("-1e308", "1e308", (-np.inf, np.inf)),
    ("-1e16", "1e16", (-np.inf, np.inf)),
    ("-inf", "inf", (-np.inf, np.inf)),
    ("-1e999", "0.5", (-np.inf, 0.5)),
    ("-1e15", "1e15", (-1e15, 1e15)),
])
@pytest.mark.parametrize("kind", ["revolute", "prismatic"])
def test_huge_limits_mean_unbounded(kind, lower, upper, expected):
    """Limits at or beyond ±1e16 (the SDFormat convention for none) load as ±inf, so that
    ``random_configuration`` draws from its default range instead of overflowing; finite limits
    below that are kept."""
    model = mb.load_urdf(one_joint_robot(f'<axis xyz="0 0 1"/><limit lower="{lower}" upper="{upper}"/>', kind=kind))
    assert (model.lower[0], model.upper[0]) == expected
    q = model.random_configuration(np.random.default_rng(0), shape=50)
    assert np.all(np.isfinite(q)) and np.all(q >= model.lower) and np.all(q <= model.upper)
    assert np.all(np.isfinite(mb.bias_forces(model, q, np.ones((50, 1)))))


def test_mimic_on_a_fixed_joint_is_ignored():
    """Reduced models freeze mimicking joints into fixed ones and keep their <mimic>: a relation for a
    joint without a coordinate is not recorded (mb.mimic_constraints would refuse it)."""
    links, joints = FIXED_TIP
    model = mb.load_urdf(one_joint_robot(links=links, joints=joints.replace("</joint>", '<mimic joint="j"/></joint>')))
    assert model.mimic == ()
