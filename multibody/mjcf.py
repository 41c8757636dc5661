"""MJCF loader: ``load_mjcf(source, *, package_dirs=None)``, and MuJoCo's state conventions
(:func:`to_mujoco`, :func:`from_mujoco`).

The model is the one MuJoCo compiles from the same file (``mujoco.MjModel.from_xml_path``), in its order,
so that ``q``, ``v`` and every matrix line up with MuJoCo's ``qpos``, ``qvel``, ``mj_fullM`` and
``qfrc_bias`` (the quaternions and a free joint's velocity converted by :func:`to_mujoco`). What the
loader reads, after the MuJoCo XML reference (mujoco.readthedocs.io, "XML Reference" and "Modeling"):

* ``<compiler>``: ``angle`` (degrees unless ``radian``: Euler angles, axis-angles, a hinge's ``range``
  and ``ref``), ``eulerseq``, ``meshdir``/``assetdir``, ``autolimits``, ``inertiafromgeom``,
  ``inertiagrouprange``, ``boundmass``, ``boundinertia``, ``balanceinertia``, ``settotalmass``,
  ``strippath``. ``coordinate="global"`` is refused, as MuJoCo refuses it.
* ``<default>`` classes, nested (a class inherits its parent's values and overrides them), chosen by
  an element's ``class`` or the ``childclass`` of the bodies and frames around it; ``<include>`` of
  another ``<mujoco>`` file, looked up next to the including file, then next to the main file, then in
  ``package_dirs`` (an include cycle is refused); ``<frame>``, whose pose and ``childclass`` apply to
  what it holds.
* Bodies in every orientation form: ``quat`` (``w x y z``), ``euler`` (``eulerseq``), ``axisangle``,
  ``xyaxes``, ``zaxis``; ``mocap`` bodies are fixed to the world.
* Mass properties as MuJoCo compiles them: ``<inertial>`` (``diaginertia`` in its frame, or
  ``fullinertia``), or, with ``inertiafromgeom="true"`` or without ``<inertial>`` (``"auto"``), the
  body's geoms in ``inertiagrouprange``: spheres, capsules (a cylinder and two hemispheres), cylinders,
  boxes, ellipsoids and meshes (read with trimesh; MuJoCo's ``legacy``, ``exact``, ``convex`` and
  ``shell`` mesh inertia), from ``mass`` or ``density`` (default 1000 kg/m³), ``fromto`` included;
  then, in MuJoCo's order, ``boundmass``/``boundinertia``, ``balanceinertia`` and ``settotalmass``.
* Joints ``hinge``, ``slide``, ``ball`` and ``free`` (also ``<freejoint>``). The joints of one body
  form a chain in the file's order, each about its ``pos``; a hinge's or slide's ``q`` is MuJoCo's
  ``qpos``: at ``q = ref`` the body is where the file puts it (MuJoCo's ``qpos0``), so the model's
  zero configuration turns each joint by ``−ref``. ``range`` with ``limited`` (or ``autolimits``)
  gives ``model.lower``/``model.upper``; ``damping``, ``frictionloss`` and ``armature`` give
  ``model.damping``, ``model.friction`` and ``model.armature`` (per velocity coordinate).
* Named sites are frames (bodies without mass fixed to theirs, or to the world), usable by name in
  :func:`multibody.frame_placement`, :func:`multibody.jacobian` and the constraints; a site named as a
  body is not (a warning says so).
* Geoms are the viewer's shapes (``model.geometries``): those of groups 0–2, which MuJoCo's viewer
  shows, as ``"visual"``, the others as ``"collision"``; the world's geoms (a floor) and meshes given by
  their vertices (no file) are not kept.
* The bodies' geoms that collide (``contype`` or ``conaffinity`` not 0, MuJoCo's filter; any group) are
  ``model.collision_geometries``: spheres, boxes, capsules and cylinders, and meshes as their convex
  hulls (a file's read when :func:`multibody.geometry.collision_table` is built; one given by its vertices
  at once). Ellipsoids, planes, height fields and SDFs of bodies are left out with a warning; the world's
  geoms (a floor) belong to no body and are not kept (a floor is :class:`multibody.Ground`'s half-space).
* ``<option gravity>`` (and ``<flag gravity="disable"/>``).
* ``<equality>``: ``connect`` → :class:`~multibody.LoopClosure` ``kind="point"``, ``weld`` →
  ``kind="weld"``, ``joint`` → :class:`~multibody.JointCoupling` with MuJoCo's ``polycoef``, in
  ``model.equality_constraints``; a body that is the world, a missing ``body2`` or a mocap body is
  fixed, so the constraint holds against the world.

``model.body_names`` are MuJoCo's bodies without the world, in MuJoCo's order (``body_names[i]`` is
MuJoCo's body ``i + 1``), then the sites; ``model.joint_names`` MuJoCo's joints in order. An unnamed
body or joint is called ``body_<id>`` or ``joint_<id>`` after its MuJoCo id (with ``_`` appended while
the name is taken).

Left out, each with one warning naming the element and the line of its first occurrence: actuators
(joint forces are the ``τ`` given to the dynamics), tendons, passive springs (``stiffness``),
gravity compensation, fluid forces, ball-joint range cones, plugins and procedural elements
(``composite``, ``flexcomp``, ``replicate``, ``attach``), tendon and flex equalities and inactive
ones, and any attribute or element the loader does not know. What changes nothing in the
equations of motion is ignored without a word: rendering (``rgba``, materials, textures, cameras,
lights), contact and solver parameters, sensors, keyframes.

Malformed files raise :class:`MJCFError` naming the file, the line and the element.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
import xml.parsers.expat

import numpy as np

from . import joints as jt
from . import spatial
from .constraints import JointCoupling, LoopClosure
from .geometry import COLLISION_SHAPES, hull_vertices
from .inertia import Inertia
from .model import Geometry, ModelBuilder
from .modelfiles import (
    LARGEST_MAGNITUDE,
    is_xml_text,
    package_directories,
    parse_numbers,
    resolve_file,
    warn_missing_meshes,
)


class MJCFError(ValueError):
    """An MJCF file that cannot describe a valid model; the message names the file, line and element."""


#: MuJoCo's smallest meaningful value (``mjMINVAL``): shorter axes and quaternions are refused.
MINVAL = 1e-15

_IDENTITY = np.eye(4)
_IDENTITY.setflags(write=False)

# ----------------------------------------------------------------------------- the XML tree, with lines


class _Node:
    """An XML element with the file and line it starts on."""

    __slots__ = ("tag", "attrib", "children", "line", "file")

    def __init__(self, tag, attrib, line, file):
        self.tag, self.attrib, self.children, self.line, self.file = tag, attrib, [], line, file

    def where(self):
        """``file:line: <tag name='…'>`` for messages."""
        name = self.attrib.get("name")
        return f"{self.file}:{self.line}: <{self.tag}{'' if name is None else f' name={name!r}'}>"

    def error(self, problem):
        return MJCFError(f"{self.where()}: {problem}")


def _parse_xml(data, file):
    """The root :class:`_Node` of the XML ``data`` (bytes or text) read from ``file`` (a path or a
    display name); malformed XML raises :class:`MJCFError` naming the file and line."""
    parser = xml.parsers.expat.ParserCreate()
    roots, stack = [], []

    def start(tag, attrib):
        node = _Node(tag, attrib, parser.CurrentLineNumber, file)
        (stack[-1].children if stack else roots).append(node)
        stack.append(node)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        raise MJCFError(f"{file}:{exc.lineno}: XML syntax error: {xml.parsers.expat.ErrorString(exc.code)} "
                        f"(column {exc.offset + 1})") from None
    return roots[0]


def _read_file(path, where=None):
    """The root node of the MJCF file at ``path``; ``where``: the node that asked for it, for errors."""
    try:
        with open(path, "rb") as stream:
            data = stream.read()
    except OSError as error:
        if where is None:
            raise
        raise where.error(f"cannot read {path!r}: {error.strerror}") from None
    return _parse_xml(data, path)


class _FirstElement(Exception):
    pass


def is_mjcf_file(path) -> bool:
    """Whether the file at ``path`` is MJCF: its root element is ``<mujoco>`` (read up to that element only;
    ``False`` for a file that is not XML)."""
    parser = xml.parsers.expat.ParserCreate()

    def start(tag, attrib):
        raise _FirstElement(tag)

    parser.StartElementHandler = start
    try:
        with open(path, "rb") as stream:
            parser.ParseFile(stream)
    except _FirstElement as first:
        return first.args[0] == "mujoco"
    except xml.parsers.expat.ExpatError:
        return False
    return False


def _expand_includes(root, main_dir, package_dirs):
    """Replace every ``<include file>`` under ``root`` by the children of that file's ``<mujoco>``, looked up
    next to the including file, then next to the main file, then in ``package_dirs``; a file that
    includes itself, directly or through others, is refused."""
    # (node, chain of files that included it) — iterative, so that deep trees keep off the recursion limit
    stack = [(root, (root.file,))]
    while stack:
        node, chain = stack.pop()
        children = []
        for child in node.children:
            if child.tag != "include":
                children.append(child)
                stack.append((child, chain))
                continue
            name = child.attrib.get("file")
            if not name:
                raise child.error("missing attribute 'file'")
            here = os.path.dirname(child.file) if os.path.isfile(child.file) else None
            path = resolve_file(name, [d for d in (here, main_dir) if d] + package_dirs, package_dirs)
            if path is None:
                raise child.error(f"included file {name!r} not found (looked next to the including file, the main "
                                  "file and in package_dirs)")
            if path in chain:
                raise child.error("include cycle: " + " -> ".join([*chain[chain.index(path):], path]))
            included = _read_file(path, child)
            if included.tag != "mujoco":
                raise included.error(f"the root element of an included file must be <mujoco>, got <{included.tag}>")
            # its children go through the same loop, for their own includes
            wrapper = _Node("mujoco", {}, included.line, path)
            wrapper.children = included.children
            stack.append((wrapper, chain + (path,)))
            children.extend(included.children)
        node.children = children


# ----------------------------------------------------------------------------- what the loader reads

_ORIENTATIONS = ("quat", "axisangle", "xyaxes", "zaxis", "euler")
_FRAME = {"name", "pos", *_ORIENTATIONS}

#: per element: (attributes read, attributes that change nothing in the equations of motion)
_ATTRIBUTES = {
    "mujoco": ({"model"}, set()),
    "compiler": ({"angle", "eulerseq", "meshdir", "assetdir", "autolimits", "inertiafromgeom", "inertiagrouprange",
                  "boundmass", "boundinertia", "balanceinertia", "settotalmass", "coordinate", "strippath",
                  "fusestatic", "alignfree", "discardvisual"},
                 {"texturedir", "usethread", "fitaabb", "saveinertial"}),
    "option": ({"gravity", "wind", "density", "viscosity"},
               {"timestep", "apirate", "impratio", "tolerance", "ls_tolerance", "noslip_tolerance", "ccd_tolerance",
                "magnetic", "o_margin", "o_solref", "o_solimp", "o_friction", "integrator", "cone", "jacobian",
                "solver", "iterations", "ls_iterations", "noslip_iterations", "ccd_iterations", "sdf_iterations",
                "sdf_initpoints", "actuatorgroupdisable", "collision", "mpr_tolerance", "mpr_iterations",
                "sleep_tolerance"}),
    "flag": ({"gravity"}, None),  # every other flag: contact, limits, solver, rendering (None: all ignored)
    "body": ({*_FRAME, "childclass", "mocap", "gravcomp"}, {"user", "sleep"}),
    "frame": ({*_FRAME, "childclass"}, set()),
    "inertial": ({"pos", *_ORIENTATIONS, "mass", "diaginertia", "fullinertia"}, set()),
    "joint": ({"name", "class", "type", "pos", "axis", "limited", "range", "ref", "armature", "damping",
               "frictionloss", "stiffness", "springdamper"},
              {"group", "springref", "margin", "solreflimit", "solimplimit", "solreffriction", "solimpfriction",
               "user", "actuatorfrcrange", "actuatorfrclimited", "actuatorgravcomp"}),
    "freejoint": ({"name", "align"}, {"group"}),
    "geom": ({*_FRAME, "class", "type", "size", "group", "mass", "density", "shellinertia", "fromto", "mesh",
              "fitscale", "contype", "conaffinity"},
             {"condim", "priority", "material", "rgba", "friction", "solmix", "solref",
              "solimp", "margin", "gap", "user", "hfield", "fluidshape", "fluidcoef"}),
    "site": ({*_FRAME, "class", "fromto"}, {"type", "size", "group", "material", "rgba", "user"}),
    "mesh": ({"name", "class", "file", "vertex", "face", "refpos", "refquat", "scale", "inertia"},
             {"content_type", "normal", "texcoord", "smoothnormal", "maxhullvert", "material"}),
    "connect": ({"name", "class", "active", "body1", "body2", "site1", "site2", "anchor"}, {"solref", "solimp"}),
    "weld": ({"name", "class", "active", "body1", "body2", "site1", "site2", "anchor", "relpose"},
             {"solref", "solimp", "torquescale"}),
    "joint equality": ({"name", "class", "active", "joint1", "joint2", "polycoef"}, {"solref", "solimp"}),
}

#: what an element may hold: (read, ignored without a word); anything else warns
_CHILDREN = {
    "mujoco": ({"compiler", "option", "default", "asset", "worldbody", "equality"},
               {"size", "visual", "statistic", "custom", "keyframe", "contact", "sensor"}),
    "body": ({"inertial", "joint", "freejoint", "geom", "site", "body", "frame"}, {"camera", "light"}),
    "asset": ({"mesh"}, {"texture", "material", "hfield", "skin", "model"}),
    "option": ({"flag"}, set()),
    "equality": ({"connect", "weld", "joint"}, set()),
}

#: why an element is left out, when there is more to say than that it is unknown
_LEFT_OUT = {
    "actuator": "actuators are not modelled: give the joint forces as tau",
    "tendon": "tendons are not modelled",
    "extension": "plugins are not supported",
    "plugin": "plugins are not supported",
    "deformable": "flexes and skins are not supported",
    "composite": "composite bodies are not supported",
    "flexcomp": "flexes are not supported",
    "replicate": "replicated bodies are not supported",
    "attach": "attached models are not supported",
    "tendon equality": "tendon equalities are left out",
    "flex equality": "flex equalities are left out",
}


class _Report:
    """What the file holds that the model leaves out: one warning per kind, at its first line."""

    def __init__(self):
        self.items = {}

    def add(self, key, node, text):
        item = self.items.get(key)
        if item is None:
            self.items[key] = [node, 1, text]
        else:
            item[1] += 1

    def element(self, node, parent_tag):
        """An element that ``parent_tag`` may not hold, or that is left out."""
        text = _LEFT_OUT.get(node.tag, f"<{node.tag}> in <{parent_tag}> is not supported; it is ignored")
        self.add(("element", node.tag), node, text)

    def attributes(self, node, attrs, tag=None):
        """The attributes of ``attrs`` (``node``'s, with its defaults) that its element does not read."""
        tag = tag or node.tag
        read, ignored = _ATTRIBUTES[tag]
        if ignored is None:
            return
        for key in attrs.keys() - read - ignored:
            self.add(("attribute", tag, key), node, f"attribute {key!r} of <{node.tag}> is not supported; it is ignored")

    def warn(self, stacklevel):
        for node, count, text in self.items.values():
            more = f" ({count} elements)" if count > 1 else ""
            warnings.warn(f"{node.where()}: {text}{more}", UserWarning, stacklevel=stacklevel + 1)


# ----------------------------------------------------------------------------- numbers and frames


class _Compiler:
    """The ``<compiler>`` settings, MuJoCo's defaults where the file gives none."""

    def __init__(self):
        self.degree, self.eulerseq, self.meshdir, self.autolimits = True, "xyz", None, True
        self.inertiafromgeom, self.group_range = "auto", (0, 5)
        self.boundmass = self.boundinertia = 0.0
        self.settotalmass, self.balanceinertia, self.strippath = -1.0, False, False


class _Reader:
    """Reads attributes of elements (with their defaults) into numbers, frames and inertias, and says
    where a value is wrong."""

    def __init__(self, compiler, report):
        self.compiler, self.report = compiler, report
        self._numbers = {}

    def numbers(self, node, attrs, key, count=None, default=None, at_least=None):
        """``attrs[key]`` as ``(n,)`` floats: exactly ``count`` of them, or ``at_least`` and up to ``count``
        (``default`` when absent; ``None`` then raises)."""
        text = attrs.get(key)
        if text is None:
            if default is None:
                raise node.error(f"missing attribute {key!r}")
            return default
        values = self._numbers.get((text, count, at_least))
        if values is None:
            try:
                values = parse_numbers(text, key, count, at_least=at_least)
            except ValueError as problem:
                raise node.error(str(problem)) from None
            values.setflags(write=False)
            self._numbers[text, count, at_least] = values
        return values

    def number(self, node, attrs, key, default):
        """``attrs[key]``, one number (``default`` when absent)."""
        if key not in attrs:
            return default
        return float(self.numbers(node, attrs, key, 1)[0])

    def integers(self, node, attrs, key, count, default):
        """``attrs[key]`` as ``count`` integers (``default``, a tuple, when absent); MuJoCo reads them as C ints."""
        if key not in attrs:
            return default
        values = self.numbers(node, attrs, key, count)
        if not all(value == math.floor(value) and abs(value) < 2**31 for value in values):
            raise node.error(f"attribute {key}={attrs[key]!r} must be {count} integer(s)")
        return tuple(int(value) for value in values)

    def flag(self, node, attrs, key, default, choices=("true", "false")):
        value = attrs.get(key, default)
        if value not in choices:
            raise node.error(f"attribute {key}={value!r} must be one of {', '.join(choices)}")
        return value

    def angle(self, value):
        """An angle of the file in radians."""
        return value * (math.pi / 180.0) if self.compiler.degree else value

    def rotation(self, node, attrs):
        """The rotation ``(3, 3)`` of an element's orientation: MuJoCo's ``quat``, ``axisangle``, ``xyaxes``,
        ``zaxis`` or ``euler`` (MuJoCo XML reference, "Frame orientations"), the element's own over its
        defaults'; ``None`` for none."""
        own = [key for key in _ORIENTATIONS if key in node.attrib]
        keys = own or [key for key in _ORIENTATIONS if key in attrs]
        if not keys:
            return None
        if len(keys) > 1:
            raise node.error(f"several orientations ({', '.join(keys)}): give one")
        key = keys[0]
        if key == "quat":
            return _quat_rotation(self.numbers(node, attrs, key, 4), node)
        if key == "axisangle":
            values = self.numbers(node, attrs, key, 4)
            norm = math.sqrt(values[:3] @ values[:3])
            if norm < MINVAL:
                raise node.error("attribute axisangle: the axis is zero")
            return spatial.axis_angle_rotation(values[:3] / norm, self.angle(values[3]))
        if key == "zaxis":
            return _z_to_vector(self.numbers(node, attrs, key, 3), node)
        if key == "xyaxes":
            values = self.numbers(node, attrs, key, 6)
            x, y = values[:3], values[3:]
            norm = math.sqrt(x @ x)
            if norm < MINVAL:
                raise node.error("attribute xyaxes: the x axis is zero")
            x = x / norm
            # y made orthogonal to x (Gram–Schmidt), z = x × y
            y = y - x * (x @ y)
            norm = math.sqrt(y @ y)
            if norm < MINVAL:
                raise node.error("attribute xyaxes: the y axis is zero or along the x axis")
            y = y / norm
            return np.column_stack([x, y, np.cross(x, y)])
        # euler: one rotation per axis of eulerseq; lower case turns about the moving axes (post-multiply),
        # upper case about the fixed ones (pre-multiply)
        R = np.eye(3)
        for axis, angle in zip(self.compiler.eulerseq, self.numbers(node, attrs, key, 3)):
            turn = spatial.axis_angle_rotation(np.eye(3)["xyz".index(axis.lower())], self.angle(angle))
            R = R @ turn if axis.islower() else turn @ R
        return R

    def pose(self, node, attrs, required=False):
        """4×4 pose of an element's frame (``pos``, required or zero, and orientation) in its parent's frame."""
        R = self.rotation(node, attrs)
        p = self.numbers(node, attrs, "pos", 3, None if required else _ZERO3)
        if R is None and not p.any():
            return _IDENTITY
        return spatial.pose_matrix(np.eye(3) if R is None else R, p)


_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


def _quat_rotation(quat, node):
    """Rotation ``(3, 3)`` of the quaternion ``(w, x, y, z)`` (normalised here, as MuJoCo does)."""
    w, x, y, z = quat
    if math.sqrt(w * w + x * x + y * y + z * z) < MINVAL:
        raise node.error("the quaternion is zero")
    return spatial.quat_to_rotation((x, y, z, w))


def _z_to_vector(vector, node):
    """The rotation ``(3, 3)`` that takes the z axis to ``vector (3,)`` by the smallest turn (MuJoCo's ``zaxis``
    and ``fromto``): about ``z × vector``, or about x by π when ``vector`` points down the z axis."""
    norm = math.sqrt(vector @ vector)
    if norm < MINVAL:
        raise node.error("the z axis is zero")
    x, y, z = vector / norm
    s = math.sqrt(x * x + y * y)
    if s < 1e-10:
        return np.eye(3) if z > 0.0 else np.diag([1.0, -1.0, -1.0])
    return spatial.axis_angle_rotation(np.array([-y / s, x / s, 0.0]), math.atan2(s, z))


def _translation(p):
    """The pose ``(4, 4)`` that shifts by ``p (3,)`` (m) without turning."""
    return spatial.pose_matrix(np.eye(3), p)


# ----------------------------------------------------------------------------- defaults


class _Defaults:
    """The ``<default>`` classes: ``{class: {element tag: {attribute: text}}}``, each class holding its
    ancestors' values under its own."""

    def __init__(self, sections):
        self.classes = {"main": {}}
        for section in sections:
            name = section.attrib.get("class", "main")
            if name != "main":
                raise section.error(f"the top <default> is class 'main', got {name!r}")
            self._add(section, self.classes["main"])

    def _add(self, section, values):
        # (a <default> element, its class's values), iteratively, so that deep nesting keeps off the recursion
        # limit; a class takes all its own elements before its nested classes inherit them, wherever in it they
        # are written, as MuJoCo reads them
        stack = [(section, values)]
        while stack:
            section, values = stack.pop()
            for child in section.children:
                if child.tag != "default":
                    values.setdefault(child.tag, {}).update(child.attrib)
            nested = []
            for child in section.children:
                if child.tag == "default":
                    name = child.attrib.get("class")
                    if not name:
                        raise child.error("a nested <default> needs attribute 'class'")
                    if name in self.classes:
                        raise child.error(f"default class {name!r} is defined twice")
                    inherited = {tag: dict(attrs) for tag, attrs in values.items()}
                    self.classes[name] = inherited
                    nested.append((child, inherited))
            stack.extend(reversed(nested))

    def attributes(self, node, childclass, tag=None):
        """``node``'s attributes over those of its class (its ``class``, else ``childclass``, else main)."""
        name = node.attrib.get("class", childclass or "main")
        values = self.classes.get(name)
        if values is None:
            raise node.error(f"unknown default class {name!r}")
        defaults = values.get(tag or node.tag)
        return {**defaults, **node.attrib} if defaults else node.attrib


# ----------------------------------------------------------------------------- the body tree


class _Joint:
    __slots__ = ("node", "kind", "name", "model_name", "pos", "axis", "ref", "limits", "damping", "friction",
                 "armature")


class _Geom:
    __slots__ = ("node", "kind", "size", "pose", "group", "mass", "density", "mesh", "collides")


class _Body:
    __slots__ = ("node", "name", "parent", "pose", "world", "joints", "geoms", "sites", "inertial", "inertial_pose",
                 "raw_pos")

    def __init__(self, node, name, parent, pose, world):
        self.node, self.name, self.parent, self.pose, self.world = node, name, parent, pose, world
        self.joints, self.geoms, self.sites, self.inertial, self.inertial_pose = [], [], [], None, None


_JOINT_TYPES = ("hinge", "slide", "ball", "free")
_GEOM_TYPES = ("plane", "hfield", "sphere", "capsule", "ellipsoid", "cylinder", "box", "mesh", "sdf")
#: sizes a geom type reads (the rest of ``size`` is unused) and how many ``fromto`` replaces
_GEOM_SIZES = {"sphere": 1, "capsule": 2, "cylinder": 2, "ellipsoid": 3, "box": 3}


class _Tree:
    """The bodies of ``<worldbody>`` in MuJoCo's order (depth first, in the file's order), each with its
    joints, geoms, sites and inertial; frames folded into the poses of what they hold."""

    def __init__(self, worldbody, reader, defaults, report):
        self.reader, self.defaults, self.report = reader, defaults, report
        self.bodies, self.world_sites = [], []
        world = _Body(worldbody, "world", None, _IDENTITY, _IDENTITY)
        # (iterator over a container's children, body index (-1: world), frame pose in the body, childclass)
        stack = [(iter(worldbody.children), -1, _IDENTITY, worldbody.attrib.get("childclass"))]
        while stack:
            children, b, frame, childclass = stack[-1]
            child = next(children, None)
            if child is None:
                stack.pop()
                continue
            body = world if b < 0 else self.bodies[b]
            tag = child.tag
            if tag == "body":
                attrs = child.attrib
                report.attributes(child, attrs)
                pose = frame @ reader.pose(child, attrs) if frame is not _IDENTITY else reader.pose(child, attrs)
                new = _Body(child, attrs.get("name"), b, pose, body.world @ pose)
                new.raw_pos = reader.numbers(child, attrs, "pos", 3, _ZERO3)
                if reader.number(child, attrs, "gravcomp", 0.0) != 0.0:
                    report.add(("gravcomp",), child, "gravity compensation (gravcomp) is not modelled")
                reader.flag(child, attrs, "mocap", "false")
                if "childclass" in attrs and attrs["childclass"] not in defaults.classes:
                    raise child.error(f"unknown default class {attrs['childclass']!r}")
                self.bodies.append(new)
                stack.append((iter(child.children), len(self.bodies) - 1, _IDENTITY,
                              attrs.get("childclass", childclass)))
            elif tag == "frame":
                report.attributes(child, child.attrib)
                pose = frame @ reader.pose(child, child.attrib)
                stack.append((iter(child.children), b, pose, child.attrib.get("childclass", childclass)))
            elif tag in ("joint", "freejoint"):
                if b < 0:
                    raise child.error("the world body cannot have joints")
                body.joints.append(self._joint(child, frame, childclass))
            elif tag == "geom":
                attrs = defaults.attributes(child, childclass)
                report.attributes(child, attrs)
                body.geoms.append(self._geom(child, attrs, frame))
            elif tag == "site":
                attrs = defaults.attributes(child, childclass)
                report.attributes(child, attrs)
                pose = self._fromto_pose(child, attrs)[0] if "fromto" in attrs else reader.pose(child, attrs)
                (self.world_sites if b < 0 else body.sites).append((child, frame @ pose))
            elif tag == "inertial":
                if b < 0:
                    raise child.error("the world body has no <inertial>")
                if body.inertial is not None:
                    raise child.error("a body has one <inertial>")
                report.attributes(child, child.attrib)
                body.inertial, body.inertial_pose = child, frame
            else:
                if tag not in _CHILDREN["body"][1]:  # (the ignored children)
                    report.element(child, "body" if b >= 0 else "worldbody")

    def _joint(self, node, frame, childclass):
        reader, report = self.reader, self.report
        joint = _Joint()
        joint.node = node
        if node.tag == "freejoint":
            attrs = node.attrib
            if reader.flag(node, attrs, "align", "auto", ("true", "false", "auto")) == "true":
                report.add(("align",), node, "aligning a free body with its inertia (align) is not supported; the "
                                             "body frame stays as written")
            kind = "free"
        else:
            attrs = self.defaults.attributes(node, childclass)
            kind = attrs.get("type", "hinge")
            if kind not in _JOINT_TYPES:
                raise node.error(f"unknown joint type {kind!r} (expected {', '.join(_JOINT_TYPES)})")
        report.attributes(node, attrs)
        joint.kind, joint.name = kind, attrs.get("name")
        R = frame[:3, :3]
        joint.pos = R @ reader.numbers(node, attrs, "pos", 3, _ZERO3) + frame[:3, 3]
        axis = reader.numbers(node, attrs, "axis", 3, np.array([0.0, 0.0, 1.0]))
        if kind in ("hinge", "slide"):
            norm = math.sqrt(axis @ axis)
            if norm < MINVAL:
                raise node.error(f"attribute axis={attrs.get('axis')!r}: the axis is zero")
            joint.axis = R @ (axis / norm)
        ref = reader.number(node, attrs, "ref", 0.0)
        joint.ref = reader.angle(ref) if kind == "hinge" else ref
        joint.limits = None
        limited = reader.flag(node, attrs, "limited", "auto", ("true", "false", "auto"))
        if limited == "auto":
            if not reader.compiler.autolimits and "range" in attrs:
                raise node.error("attribute range is given without limited, and autolimits is false: say "
                                 "limited='true' or 'false'")
            limited = "true" if "range" in attrs else "false"
        if limited == "true" and kind in ("hinge", "slide"):
            low, high = reader.numbers(node, attrs, "range", 2, np.zeros(2))
            if low > high:
                raise node.error(f"attribute range={attrs.get('range')!r}: the lower limit exceeds the upper")
            joint.limits = (reader.angle(low), reader.angle(high)) if kind == "hinge" else (low, high)
        elif limited == "true" and kind == "ball":
            report.add(("ball range",), node, "a ball joint's range (a cone around its reference) is not modelled")
        for key, attribute in (("damping", "damping"), ("friction", "frictionloss"), ("armature", "armature")):
            value = reader.number(node, attrs, attribute, 0.0)
            if value < 0.0:
                raise node.error(f"attribute {attribute}={attrs.get(attribute)!r} must not be negative")
            setattr(joint, key, value)
        if reader.number(node, attrs, "stiffness", 0.0) != 0.0 or \
                np.any(reader.numbers(node, attrs, "springdamper", 2, _ZERO3[:2])):
            report.add(("stiffness",), node, "joint springs (stiffness, springdamper) are not modelled")
        return joint

    def _geom(self, node, attrs, frame):
        reader = self.reader
        geom = _Geom()
        geom.node = node
        kind = attrs.get("type", "mesh" if "mesh" in attrs else "sphere")
        if kind not in _GEOM_TYPES:
            raise node.error(f"unknown geom type {kind!r} (expected {', '.join(_GEOM_TYPES)})")
        geom.kind, geom.mesh = kind, attrs.get("mesh")
        if kind == "mesh" and not geom.mesh:
            raise node.error("a mesh geom needs attribute 'mesh'")
        if geom.mesh and kind != "mesh":
            self.report.add(("fit",), node, "fitting a primitive to a mesh is not supported: its size is used as "
                                            "written")
        size = np.zeros(3)
        given = reader.numbers(node, attrs, "size", 3, _ZERO3, at_least=1) if "size" in attrs else np.zeros(0)
        size[: len(given)] = given
        if "fromto" in attrs:
            if kind not in ("capsule", "cylinder", "box", "ellipsoid"):
                raise node.error(f"attribute fromto is for capsules, cylinders, boxes and ellipsoids, not a {kind}")
            if "pos" in attrs:
                raise node.error("give pos or fromto, not both")
            pose, length = self._fromto_pose(node, attrs)
            # the long axis is z; across it, the first size
            if kind in ("box", "ellipsoid"):
                size[1], size[2] = size[0], 0.5 * length
            else:
                size[1] = 0.5 * length
        else:
            pose = reader.pose(node, attrs)
        needed = _GEOM_SIZES.get(kind, 0)
        if needed and np.any(size[:needed] <= 0.0):
            raise node.error(f"a {kind} needs {needed} positive size(s), got size={attrs.get('size', '0 0 0')!r}")
        geom.size, geom.pose = size, frame @ pose if frame is not _IDENTITY else pose
        geom.group, = reader.integers(node, attrs, "group", 1, (0,))
        # MuJoCo's collision filter: a geom with contype and conaffinity both 0 collides with nothing
        contype, = reader.integers(node, attrs, "contype", 1, (1,))
        conaffinity, = reader.integers(node, attrs, "conaffinity", 1, (1,))
        geom.collides = contype != 0 or conaffinity != 0
        geom.mass = reader.number(node, attrs, "mass", None)
        geom.density = reader.number(node, attrs, "density", 1000.0)
        if (geom.mass is not None and geom.mass < 0.0) or geom.density < 0.0:
            raise node.error("mass and density must not be negative")
        if reader.flag(node, attrs, "shellinertia", "false") == "true":
            self.report.add(("shellinertia",), node, "shell inertia of a geom is not supported: its volume is used")
        return geom

    def _fromto_pose(self, node, attrs):
        """``(pose (4, 4), length)`` of a geom's or site's ``fromto``: at the middle, its z axis turned by the
        smallest rotation onto ``from − to`` (MuJoCo's ``mjCGeom::Compile``: z points back to the first end)."""
        ends = self.reader.numbers(node, attrs, "fromto", 6)
        axis = ends[:3] - ends[3:]
        length = math.sqrt(axis @ axis)
        if length < MINVAL:
            raise node.error(f"attribute fromto={attrs.get('fromto')!r}: the two ends coincide")
        pose = spatial.pose_matrix(_z_to_vector(axis, node), 0.5 * (ends[:3] + ends[3:]))
        return pose, length


# ----------------------------------------------------------------------------- mass properties


def _primitive_inertia(kind, size):
    """``(volume, principal moments per unit mass (3,))`` of a geom in its frame, as MuJoCo computes them
    (``mjCGeom``): size holds radii and half-lengths; a capsule is a cylinder of length 2 h and two
    hemispheres, each moment the cylinder's and the hemispheres' about the centre by the parallel-axis
    theorem, masses in proportion to the volumes."""
    a, b, c = size
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * a**3, np.full(3, 0.4 * a * a)
    if kind == "capsule":
        height = 2.0 * b
        volume = 4.0 / 3.0 * math.pi * a**3 + math.pi * a * a * height
        # the hemispheres' and the cylinder's shares of the volume, from the lengths: defined where the
        # volumes underflow
        s, k = 4.0 * a / (4.0 * a + 3.0 * height), 3.0 * height / (4.0 * a + 3.0 * height)
        # hemispheres of radius a centred ±h from the middle: I = 2/5 m a² + m h (2h + 3a)/8 (h: the length)
        across = k * (3.0 * a * a + height * height) / 12.0 + s * (0.4 * a * a + height * (2.0 * height + 3.0 * a) / 8.0)
        return volume, np.array([across, across, k * 0.5 * a * a + s * 0.4 * a * a])
    if kind == "cylinder":
        height = 2.0 * b
        across = (3.0 * a * a + height * height) / 12.0
        return math.pi * a * a * height, np.array([across, across, 0.5 * a * a])
    if kind == "ellipsoid":
        return 4.0 / 3.0 * math.pi * a * b * c, np.array([b * b + c * c, a * a + c * c, a * a + b * b]) / 5.0
    # box of half-sizes a, b, c
    return 8.0 * a * b * c, np.array([b * b + c * c, a * a + c * c, a * a + b * b]) / 3.0


def mesh_mass_properties(vertices, faces, mode="legacy"):
    """``(measure, centre (3,), inertia per unit density about the centre (3, 3))`` of a triangle mesh,
    by MuJoCo's mesh compiler (``mjCMesh::Process``, the mesh ``inertia`` attribute):

    * ``"exact"``: the volume integrals of the closed surface, each face the base of a pyramid with its
      apex at the centroid ``c_f`` of the faces (area-weighted): ``V = Σ (x̄ − c_f) · n A / 3`` and the centre
      ``Σ V_f (¾ x̄ + ¼ c_f) / V``; then the second moments of the pyramids from the centre,
      ``∫ xᵢ xⱼ dV = V_f/20 (2 Σ xᵢxⱼ + Σ cross terms)`` over their vertices (Tonon, J. Math. Stat. 1 (2004));
    * ``"legacy"`` (MuJoCo's default): the same with each pyramid's volume taken positive;
    * ``"convex"``: ``"exact"`` on the convex hull (``faces`` should be the hull's);
    * ``"shell"``: the surface instead of the volume (measure the area, moments with 12 for 20).

    ``vertices (n, 3)`` in m, ``faces (f, 3)`` vertex indices; the measure is in m³ (m² for a shell).
    """
    triangles = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    shell = mode == "shell"

    def pyramids(triangles, apex):
        # area, unit normal and centroid of each face, and the signed volume of its pyramid to apex
        normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        twice = np.linalg.norm(normal, axis=1)
        area = 0.5 * twice
        normal = normal / np.where(twice > 0.0, twice, 1.0)[:, None]
        center = triangles.mean(axis=1)
        volume = area if shell else np.einsum("ij,ij->i", center - apex, normal) * area / 3.0
        return area, center, np.abs(volume) if mode == "legacy" else volume

    area, center, _ = pyramids(triangles, np.zeros(3))
    if area.sum() < MINVAL:
        raise ValueError("the mesh's surface area is zero")
    face_center = area @ center / area.sum()
    _, center, volume = pyramids(triangles, face_center)
    measure = volume.sum()
    if measure < MINVAL:
        raise ValueError("the mesh's volume is not positive (faces turned inwards?)" if measure < 0.0 else
                         "the mesh's volume is zero; give it inertia='shell'")
    centre = volume @ (0.75 * center + 0.25 * face_center) / measure
    local = triangles - centre
    _, _, volume = pyramids(local, np.zeros(3))
    D, E, F = local[:, 0], local[:, 1], local[:, 2]
    # Σ_f V_f/C (2 (DDᵀ + EEᵀ + FFᵀ) + DEᵀ + EDᵀ + DFᵀ + FDᵀ + EFᵀ + FEᵀ), C = 20 (volume) or 12 (shell)
    products = 2.0 * (np.einsum("fi,fj->fij", D, D) + np.einsum("fi,fj->fij", E, E) + np.einsum("fi,fj->fij", F, F))
    cross = np.einsum("fi,fj->fij", D, E) + np.einsum("fi,fj->fij", D, F) + np.einsum("fi,fj->fij", E, F)
    moments = np.einsum("f,fij->ij", volume / (12.0 if shell else 20.0), products + cross + cross.transpose(0, 2, 1))
    # I = tr(P) 1 − P from the second moments P
    return volume.sum(), centre, np.trace(moments) * np.eye(3) - moments


class _Meshes:
    """The ``<asset><mesh>`` elements by name; each mesh's vertices and faces are read (with trimesh) only
    when a geom's mass needs them."""

    def __init__(self, assets, reader, defaults, report, mesh_dirs, package_dirs):
        self.reader, self.mesh_dirs, self.package_dirs = reader, mesh_dirs, package_dirs
        self.meshes, self._solids = {}, {}
        for asset in assets:
            for node in asset.children:
                if node.tag != "mesh":
                    if node.tag not in _CHILDREN["asset"][1]:
                        report.element(node, "asset")
                    continue
                attrs = defaults.attributes(node, None)
                report.attributes(node, attrs)
                file = attrs.get("file")
                if file is not None and reader.compiler.strippath:
                    file = os.path.basename(file)
                name = attrs.get("name") or (os.path.splitext(os.path.basename(file))[0] if file else None)
                if not name:
                    raise node.error("a mesh needs attribute 'name' or 'file'")
                if name in self.meshes:
                    raise node.error(f"mesh {name!r} is defined twice")
                if file is None and "vertex" not in attrs:
                    raise node.error("a mesh needs attribute 'file' or 'vertex'")
                mode = reader.flag(node, attrs, "inertia", "legacy", ("legacy", "exact", "convex", "shell"))
                scale = reader.numbers(node, attrs, "scale", 3, np.ones(3))
                refpos = reader.numbers(node, attrs, "refpos", 3, _ZERO3)
                refquat = tuple(reader.numbers(node, attrs, "refquat", 4, np.array([1.0, 0.0, 0.0, 0.0])))
                path = None if file is None else resolve_file(file, mesh_dirs, package_dirs)
                self.meshes[name] = (node, attrs, file, path, mode, scale, refpos, refquat)

    def drawn(self, name, node):
        """``(uri, filename, scale, placement (4, 4), exact)`` of a mesh drawn as its file scaled, then placed:
        ``exact`` unless it is scaled unevenly and turned by ``refquat`` (MuJoCo scales after turning)."""
        mesh = self._get(name, node)
        _, _, file, path, _, scale, refpos, refquat = mesh
        placement, exact = _IDENTITY, True
        if refpos.any() or refquat != (1.0, 0.0, 0.0, 0.0):
            # v ↦ S Rᵀ (v − refpos) = Rᵀ (S v) − S Rᵀ refpos where S and Rᵀ commute: S uniform or R = I
            R = _quat_rotation(refquat, mesh[0])
            placement = spatial.pose_matrix(R.T, -scale * (R.T @ refpos))
            exact = refquat == (1.0, 0.0, 0.0, 0.0) or np.allclose(scale, scale[0])
        return file, path, tuple(float(s) for s in scale), placement, exact

    def _get(self, name, node):
        mesh = self.meshes.get(name)
        if mesh is None:
            raise node.error(f"unknown mesh {name!r}")
        return mesh

    def solid(self, name, node):
        """``(measure, centre (3,), inertia per unit density (3, 3))`` of mesh ``name`` in the geom's frame
        (:func:`mesh_mass_properties` of its vertices as MuJoCo compiles them)."""
        if name in self._solids:
            return self._solids[name]
        mesh_node, _, _, _, mode, _, _, _ = self._get(name, node)
        vertices, faces = self._vertices(name, node)
        if faces is None or mode == "convex":
            # MuJoCo takes the convex hull of a mesh given by its vertices alone
            import trimesh

            try:
                # (trimesh divides by the zero volume of a flat hull; mesh_mass_properties says so below)
                with np.errstate(all="ignore"):
                    hull = trimesh.convex.convex_hull(vertices)
            except Exception as exc:  # qhull refuses fewer than four points and some degenerate sets
                first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise mesh_node.error(f"no convex hull of its {len(vertices)} vertices: {first}") from None
            vertices, faces = np.asarray(hull.vertices), np.asarray(hull.faces)
        try:
            self._solids[name] = mesh_mass_properties(vertices, faces, "exact" if mode == "convex" else mode)
        except ValueError as error:
            raise mesh_node.error(str(error)) from None
        return self._solids[name]

    def hull(self, name, node):
        """``(k, 3)`` vertices of the convex hull of mesh ``name`` in the geom's frame, m
        (:func:`multibody.geometry.hull_vertices` of its vertices as MuJoCo compiles them), or ``None`` with a
        warning when they have no hull with volume."""
        try:
            return hull_vertices(self._vertices(name, node)[0])
        except ValueError as problem:
            self.reader.report.add(("collision hull",), self._get(name, node)[0],
                                   f"a mesh without a convex hull is left out of the collision geometries: its "
                                   f"vertices {problem}")
            return None

    def _vertices(self, name, node):
        """``(vertices (k, 3), faces (f, 3) or None)`` of mesh ``name`` in the geom's frame, m, as MuJoCo
        compiles them: read in single precision, moved by ``refpos``, turned by ``refquat⁻¹``, scaled."""
        mesh_node, attrs, file, path, mode, scale, refpos, refquat = self._get(name, node)
        if "vertex" in attrs:
            vertices = self.reader.numbers(mesh_node, attrs, "vertex")
            if len(vertices) % 3:
                raise mesh_node.error(f"attribute vertex holds {len(vertices)} numbers, not a multiple of 3")
            vertices = vertices.reshape(-1, 3)
            faces = self._faces(mesh_node, attrs, len(vertices)) if "face" in attrs else None
        else:
            if path is None:
                raise node.error(f"the mass of this geom needs mesh {name!r}, whose file {file!r} is not found "
                                 f"(looked in {', '.join(self.mesh_dirs + self.package_dirs) or 'the working directory'})")
            import trimesh

            try:
                loaded = trimesh.load(path, force="mesh", process=False)
            except Exception as exc:  # trimesh raises many types for unreadable files
                raise mesh_node.error(f"cannot read mesh file {path!r}: {exc}") from None
            vertices, faces = np.asarray(loaded.vertices, dtype=float), np.asarray(loaded.faces)
        # MuJoCo keeps mesh vertices in single precision, a file's and those of attribute vertex alike
        with np.errstate(over="ignore", invalid="ignore"):
            single = vertices.astype(np.float32)
        if not np.all(np.isfinite(single)):
            raise mesh_node.error("vertices beyond single precision (3.4e38), in which MuJoCo keeps them")
        vertices = single.astype(float)
        # MuJoCo's order: move by refpos, turn by refquat⁻¹, then scale
        return (vertices - refpos) @ _quat_rotation(refquat, mesh_node) * scale, faces

    def _faces(self, node, attrs, count):
        """The ``face`` attribute as ``(f, 3)`` indices of the ``count`` vertices; any other number is refused,
        as MuJoCo refuses it."""
        values = self.reader.numbers(node, attrs, "face")
        if len(values) % 3:
            raise node.error(f"attribute face holds {len(values)} numbers, not a multiple of 3")
        wrong = (values != np.floor(values)) | (values < 0) | (values >= count)
        if wrong.any():
            raise node.error(f"attribute face: {values[wrong][0]:g} is not the index of one of the {count} vertices")
        return values.astype(int).reshape(-1, 3)


def _body_inertia(body, reader, meshes, from_geoms):
    """The body's :class:`Inertia` in its frame: from ``<inertial>``, or from its geoms (``from_geoms``)."""
    if not from_geoms:
        node = body.inertial
        if node is None:
            return Inertia.zero()
        attrs = node.attrib
        mass = float(reader.numbers(node, attrs, "mass", 1)[0])
        if mass < 0.0:
            raise node.error(f"negative mass {mass:g}")
        pose = reader.pose(node, attrs, required=True)
        if "fullinertia" in attrs:
            if reader.rotation(node, attrs) is not None:
                raise node.error("fullinertia gives the inertia's axes: give no orientation with it")
            xx, yy, zz, xy, xz, yz = reader.numbers(node, attrs, "fullinertia", 6)
            tensor = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
            moments = np.linalg.eigvalsh(tensor)
        elif "diaginertia" in attrs:
            moments = reader.numbers(node, attrs, "diaginertia", 3)
            tensor = np.diag(moments)
        else:
            raise node.error("give diaginertia or fullinertia")
        compiler = reader.compiler
        # (with bounds or balancing the moments are checked once those have acted: _adjust_inertias)
        _check_moments(node, sorted(moments), compiler.balanceinertia or compiler.boundinertia > 0.0)
        pose = body.inertial_pose @ pose if body.inertial_pose is not _IDENTITY else pose
        return Inertia(mass, pose[:3, 3], pose[:3, :3] @ tensor @ pose[:3, :3].T)
    low, high = reader.compiler.group_range
    parts = []
    for geom in body.geoms:
        if not _has_mass(geom, low, high):
            continue
        R, p = geom.pose[:3, :3], geom.pose[:3, 3]
        if geom.kind == "mesh":
            volume, centre, per_density = meshes.solid(geom.mesh, geom.node)
            mass = geom.density * volume if geom.mass is None else geom.mass
            parts.append((mass, R @ centre + p, R @ (per_density * (mass / volume)) @ R.T))
        else:
            volume, moments = _primitive_inertia(geom.kind, geom.size)
            mass = geom.density * volume if geom.mass is None else geom.mass
            parts.append((mass, p, (R * (mass * moments)) @ R.T))
    if not parts:
        return Inertia.zero()
    if len(parts) == 1:
        return Inertia(*parts[0])
    # as MuJoCo sums them: the centre of mass first, then each part's inertia moved there (parallel axes)
    total = sum(mass for mass, _, _ in parts)
    if total == 0.0:
        return Inertia(0.0, _ZERO3, sum(tensor for _, _, tensor in parts))
    com = sum(mass * centre for mass, centre, _ in parts) / total
    tensor = np.zeros((3, 3))
    for mass, centre, part in parts:
        d = centre - com
        tensor += part + mass * ((d @ d) * np.eye(3) - np.outer(d, d))
    return Inertia(total, com, tensor)


def _has_mass(geom, low, high):
    """Whether a geom counts in its body's mass: a solid of a group in ``[low, high]`` (inertiagrouprange)."""
    return geom.kind not in ("plane", "hfield", "sdf") and low <= geom.group <= high


def _check_moments(node, moments, deferred):
    """Refuse principal moments (ascending) that no body has: negative ones, or, unless ``deferred`` (the
    compiler's bounds and balancing act on them first), ``A + B < C`` beyond the rounding of the file's
    digits (MuJoCo's checks). Inertias from geoms are sums of real solids and need no check."""
    tolerance = 1e-9 * abs(moments[2])
    if moments[0] < -tolerance:
        raise node.error(f"the inertia is not positive semi-definite (principal moments {list(moments)})")
    if not deferred and moments[0] + moments[1] < moments[2] - tolerance:
        raise node.error(f"the principal moments break A + B >= C ({moments[0]:.6g} + {moments[1]:.6g} < "
                         f"{moments[2]:.6g}); give compiler balanceinertia='true' to even them out")


def _adjust_inertias(bodies, inertias, compiler):
    """MuJoCo's compiler options on every body's mass properties, in its order: ``boundmass`` and
    ``boundinertia`` (lower bounds on each body's mass and principal moments), ``balanceinertia`` (principal
    moments that still break ``A + B ≥ C`` replaced by their mean), then ``settotalmass`` (all masses and
    inertias scaled to that total). A body given mass by ``boundmass`` alone has its centre where MuJoCo
    puts it: at the body's ``pos`` as written, in the body's frame."""
    bound = compiler.boundmass > 0.0 or compiler.boundinertia > 0.0 or compiler.balanceinertia
    if bound:
        out = []
        for body, inertia in zip(bodies, inertias):
            moments, axes = np.linalg.eigh(inertia.rotational)
            moments = np.maximum(moments, compiler.boundinertia)
            if compiler.balanceinertia and moments[0] + moments[1] < moments[2]:
                moments = np.full(3, moments.mean())
            if body.inertial is not None:
                _check_moments(body.inertial, moments, False)
            com = body.raw_pos if inertia.mass == 0.0 and compiler.boundmass > 0.0 else inertia.com
            out.append(Inertia(max(inertia.mass, compiler.boundmass), com, (axes * moments) @ axes.T))
        inertias = out
    if compiler.settotalmass > 0.0:
        total = sum(inertia.mass for inertia in inertias)
        if total > 0.0:
            scale = compiler.settotalmass / total
            inertias = [Inertia(scale * i.mass, i.com, scale * i.rotational) for i in inertias]
    return inertias


# ----------------------------------------------------------------------------- equalities


def _equalities(sections, reader, defaults, report, tree, names, sites, joints):
    """The built-in constraints of the ``<equality>`` elements (module docstring). ``names``: each body's
    model name; ``sites``: ``{name: (body index or -1, pose in the body)}``; ``joints``: ``{name: _Joint}``."""
    out = []
    world = [body.world for body in tree.bodies]

    def named(node, attrs, key, table, what):
        name = attrs.get(key)
        if name is None:
            raise node.error(f"missing attribute {key!r}")
        if name not in table:
            raise node.error(f"attribute {key}={name!r}: no such {what}")
        return table[name]

    def body(node, attrs, key, required=True):
        # the world, which a missing body2 also is, is -1
        if attrs.get(key, None if required else "world") == "world":
            return -1
        return named(node, attrs, key, tree.index, "body")

    equality_id = -1
    for section in sections:
        for node in section.children:
            tag = node.tag
            equality_id += 1
            if tag not in ("connect", "weld", "joint"):
                if tag in ("tendon", "flex"):
                    report.add(("element", f"{tag} equality"), node, _LEFT_OUT[f"{tag} equality"])
                else:
                    report.element(node, "equality")
                continue
            attrs = defaults.attributes(node, None, "equality")
            report.attributes(node, attrs, "joint equality" if tag == "joint" else tag)
            label = attrs.get("name") or f"{tag} equality {equality_id}"
            if reader.flag(node, attrs, "active", "true") == "false":
                report.add(("inactive",), node, "inactive equalities (active='false') are left out")
                continue
            if tag == "joint":
                first = named(node, attrs, "joint1", joints, "joint")
                second = named(node, attrs, "joint2", joints, "joint") if "joint2" in attrs else None
                for joint in (first, second):
                    if joint is not None and joint.kind not in ("hinge", "slide"):
                        raise node.error(f"joint {joint.model_name!r} is a {joint.kind} joint: a joint equality "
                                         "couples hinges and slides")
                c = np.array(reader.numbers(node, attrs, "polycoef", 5, np.array([0.0, 1.0, 0.0, 0.0, 0.0])))
                # q₁ − q₁,ref = Σ cₖ (q₂ − q₂,ref)ᵏ, q_ref MuJoCo's qpos0 (the joints' ref)
                c[0] += first.ref
                out.append(JointCoupling(None if second is None else second.model_name, first.model_name,
                                         coefficients=c, reference=0.0 if second is None else second.ref, name=label))
                continue
            kind = "point" if tag == "connect" else "weld"
            if ("site1" in attrs or "site2" in attrs) and ("body1" in attrs or "body2" in attrs):
                raise node.error("give sites (site1, site2) or bodies (body1, body2), not both")
            if "site1" in attrs or "site2" in attrs:
                # the two site frames coincide (in position for connect, in pose for weld)
                (b1, frame_a), (b2, frame_b) = (named(node, attrs, key, sites, "site") for key in ("site1", "site2"))
                if attrs["site1"] == attrs["site2"]:
                    raise node.error(f"site {attrs['site1']!r} is on both sides of the equality")
            else:
                b1, b2 = body(node, attrs, "body1"), body(node, attrs, "body2", required=False)
                if b1 == b2:
                    # (a missing body2 is the world)
                    raise node.error(f"body {attrs['body1']!r} is on both sides of the equality")
                W1 = _IDENTITY if b1 < 0 else world[b1]
                W2 = _IDENTITY if b2 < 0 else world[b2]
                anchor = reader.numbers(node, attrs, "anchor", 3, _ZERO3)
                if tag == "connect":
                    # anchor in body1; body2's point is where the anchor is at qpos0
                    frame_a = _translation(anchor)
                    frame_b = _translation((np.linalg.inv(W2) @ W1 @ np.append(anchor, 1.0))[:3])
                else:
                    relpose = reader.numbers(node, attrs, "relpose", 7, np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
                    frame_b = _translation(anchor)
                    if np.any(relpose[3:]):
                        # body2's anchor at relpose's position in body1, body2 turned by its quaternion
                        frame_a = spatial.pose_matrix(_quat_rotation(tuple(relpose[3:]), node), relpose[:3])
                    else:
                        # the relative pose at qpos0
                        frame_a = np.linalg.inv(W1) @ W2 @ frame_b
            out.append(LoopClosure(None if b1 < 0 else names[b1], None if b2 < 0 else names[b2], frame_a=frame_a,
                                   frame_b=frame_b, kind=kind, name=label))
    return out


# ----------------------------------------------------------------------------- the loader


def _unique(base, taken):
    while base in taken:
        base += "_"
    return base


def load_mjcf(source, *, package_dirs=None):
    """Build a :class:`~multibody.model.Model` from an MJCF file path or XML string (module docstring:
    what is read, in which order, and what is left out with a warning).

    Args:
        source: path to an MJCF ``.xml`` file, or the XML text itself.
        package_dirs: directories (a path or a list) where relative ``<include>`` files, ``meshdir`` and
            mesh files are also looked for; an XML string has no directory of its own, so its relative
            paths resolve there only. Mesh files are read only when a body's mass comes from a mesh geom;
            the viewer reads the others on demand (:func:`multibody.geometry.load_meshes`), and meshes
            that cannot be found give one ``UserWarning``.

    Returns:
        the model, its ``equality_constraints`` the file's ``<equality>`` elements.

    Raises:
        MJCFError: malformed XML (with its line), unknown element types, classes, bodies, joints, sites or
            meshes, impossible numbers (non-decimal, infinite, a zero axis or quaternion, a negative mass, a
            fractional index or group), mass properties that no body can have or past ``1e50`` (a sphere of
            radius 1e20 m), a free joint beside others, and equalities of a body or site with itself.
        FileNotFoundError: ``source`` is neither an existing file nor XML text.
    """
    package_dirs = package_directories(package_dirs)
    if is_xml_text(source):
        root, main_dir = _parse_xml(source, "<MJCF string>"), None
    else:
        path = os.fspath(source)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"MJCF file not found: {path}")
        root, main_dir = _read_file(path), os.path.dirname(os.path.abspath(path))
    if root.tag != "mujoco":
        raise root.error(f"the root element must be <mujoco>, got <{root.tag}>")
    _expand_includes(root, main_dir, package_dirs)
    report = _Report()
    report.attributes(root, root.attrib)
    sections = {}
    read, ignored = _CHILDREN["mujoco"]
    for child in root.children:
        if child.tag in read:
            sections.setdefault(child.tag, []).append(child)
        elif child.tag not in ignored:
            report.element(child, "mujoco")

    compiler = _Compiler()
    reader = _Reader(compiler, report)
    for node in sections.get("compiler", ()):
        _read_compiler(node, reader, compiler, report)
    gravity = np.array([0.0, 0.0, -9.81])
    for node in sections.get("option", ()):
        report.attributes(node, node.attrib)
        gravity = reader.numbers(node, node.attrib, "gravity", 3, gravity)
        if any(np.any(reader.numbers(node, node.attrib, key, 3 if key == "wind" else 1, _ZERO3[: 3 if key == "wind" else 1]))
               for key in ("wind", "density", "viscosity")):
            report.add(("fluid",), node, "fluid forces (wind, density, viscosity) are not modelled")
        for flag in node.children:
            if flag.tag != "flag":
                report.element(flag, "option")
            elif reader.flag(flag, flag.attrib, "gravity", "enable", ("enable", "disable")) == "disable":
                gravity = np.zeros(3)

    defaults = _Defaults(sections.get("default", ()))
    worldbodies = sections.get("worldbody", ())
    worldbody = worldbodies[0] if worldbodies else _Node("worldbody", {}, root.line, root.file)
    for extra in worldbodies[1:]:
        worldbody.children.extend(extra.children)
    tree = _Tree(worldbody, reader, defaults, report)
    mesh_dirs = _mesh_directories(compiler, main_dir, package_dirs)
    meshes = _Meshes(sections.get("asset", ()), reader, defaults, report, mesh_dirs, package_dirs)

    model, tree.index, sites, joints = _build(root, tree, reader, meshes, gravity)
    names = model.body_names
    constraints = _equalities(sections.get("equality", ()), reader, defaults, report, tree, names, sites, joints)
    if constraints:
        model = dataclasses.replace(model, equality_constraints=tuple(constraints))
    report.warn(stacklevel=2)
    warn_missing_meshes(model, root.file, "give package_dirs, or the compiler's meshdir")
    return model


def _read_compiler(node, reader, compiler, report):
    """A ``<compiler>`` element's settings into ``compiler`` (a later element overrides an earlier one)."""
    attrs = node.attrib
    report.attributes(node, attrs)
    if reader.flag(node, attrs, "coordinate", "local", ("local", "global")) == "global":
        raise node.error("global coordinates are not supported (nor by MuJoCo since 2.3.3): convert the file to "
                         "local coordinates")
    compiler.degree = reader.flag(node, attrs, "angle", "degree" if compiler.degree else "radian",
                                  ("degree", "radian")) == "degree"
    sequence = attrs.get("eulerseq", compiler.eulerseq)
    if len(sequence) != 3 or any(axis not in "xyzXYZ" for axis in sequence):
        raise node.error(f"attribute eulerseq={sequence!r} must be three of x, y, z, X, Y, Z")
    compiler.eulerseq = sequence
    compiler.meshdir = attrs.get("meshdir", attrs.get("assetdir", compiler.meshdir))
    for key in ("autolimits", "balanceinertia", "strippath"):
        setattr(compiler, key, reader.flag(node, attrs, key, "true" if getattr(compiler, key) else "false") == "true")
    compiler.inertiafromgeom = reader.flag(node, attrs, "inertiafromgeom", compiler.inertiafromgeom,
                                           ("true", "false", "auto"))
    compiler.group_range = reader.integers(node, attrs, "inertiagrouprange", 2, compiler.group_range)
    for key in ("boundmass", "boundinertia", "settotalmass"):
        setattr(compiler, key, reader.number(node, attrs, key, getattr(compiler, key)))
    for key, text in (("fusestatic", "bodies without joints are kept, not fused into their parents (fusestatic)"),
                      ("alignfree", "free bodies keep their frames (alignfree is not supported)"),
                      ("discardvisual", "visual geoms are kept (discardvisual is not supported)")):
        if reader.flag(node, attrs, key, "false") == "true":
            report.add((key,), node, text)


def _mesh_directories(compiler, main_dir, package_dirs):
    """Where mesh files are looked for: ``meshdir`` (relative to the main file's folder and to each of
    ``package_dirs``; to the working directory for an XML string without them), else those folders."""
    bases = ([main_dir] if main_dir else []) + package_dirs or [os.getcwd()]
    if compiler.meshdir is None:
        return bases
    if os.path.isabs(compiler.meshdir):
        return [compiler.meshdir]
    return [os.path.join(base, compiler.meshdir) for base in bases]


def _build(root, tree, reader, meshes, gravity):
    """The :class:`Model` of the body tree: ``(model, {body name: index}, sites, joints)`` with ``sites``
    ``{name: (body index or -1, pose in the body)}`` and ``joints`` ``{model name: _Joint}``."""
    compiler = reader.compiler
    bodies = tree.bodies
    taken = {body.name for body in bodies if body.name} | {"world"}
    names, index = [], {}
    for k, body in enumerate(bodies):
        if body.name == "world":
            raise body.node.error("the name 'world' is the world body's")
        names.append(body.name if body.name else _unique(f"body_{k + 1}", taken))
        if names[-1] in index:
            raise body.node.error(f"body {names[-1]!r} is defined twice")
        index[names[-1]] = k
        taken.add(names[-1])
    joint_list = [joint for body in bodies for joint in body.joints]
    taken = {joint.name for joint in joint_list if joint.name}
    joints = {}
    for k, joint in enumerate(joint_list):
        joint.model_name = joint.name if joint.name else _unique(f"joint_{k}", taken)
        taken.add(joint.model_name)
        if joint.model_name in joints:
            raise joint.node.error(f"joint {joint.model_name!r} is defined twice")
        joints[joint.model_name] = joint

    setting, (low, high) = compiler.inertiafromgeom, compiler.group_range
    # "true" replaces an <inertial> by the body's geoms where it has some; "auto" uses them where it has none
    inertias = _adjust_inertias(bodies, [_body_inertia(body, reader, meshes, body.inertial is None or (
        setting == "true" and any(_has_mass(geom, low, high) for geom in body.geoms)))
        if setting != "false" else _body_inertia(body, reader, meshes, False) for body in bodies], compiler)
    for body, inertia in zip(bodies, inertias):
        # sizes and densities within the accepted magnitude can still make masses past it (a sphere of
        # radius 1e20 m), where the dynamics would overflow
        if not np.abs(np.append(inertia.rotational, inertia.mass)).max() <= LARGEST_MAGNITUDE:
            raise body.node.error(f"mass {inertia.mass:.3g} kg, largest inertia {np.abs(inertia.rotational).max():.3g} "
                                  f"kg m^2: magnitude above {LARGEST_MAGNITUDE:g}, the largest accepted (the dynamics "
                                  "would overflow)")

    builder = ModelBuilder(root.attrib.get("model", "MuJoCo Model"), gravity=gravity)
    # the bodies that carry a joint before the last of their body's: internal, dropped after the build
    hidden = []
    for k, (body, name, inertia) in enumerate(zip(bodies, names, inertias)):
        parent = None if body.parent < 0 else names[body.parent]
        if len(body.joints) > 1 and any(joint.kind == "free" for joint in body.joints):
            raise body.node.error("a body with a free joint has no other joints")
        if not body.joints:
            builder.add_body(name, jt.Fixed(), parent=parent, placement=body.pose, inertia=inertia,
                             joint_name=_FIXED + name)
        elif body.joints[0].kind == "free":
            joint = body.joints[0]
            if body.parent >= 0:
                raise joint.node.error("a free joint belongs to a body whose parent is the world")
            builder.add_body(name, jt.FreeFlyer(), parent=None, placement=_IDENTITY, inertia=inertia,
                             joint_name=joint.model_name, **_per_dof(joint))
        else:
            # B_k = B_{k−1} T(p_k) M_k(q_k − ref_k) T(−p_k): joint k's pre-joint frame is T(p_k − p_{k−1}) R_k(−ref_k)
            # in the frame of joint k − 1 (the body's frame for k = 1), and the body hangs T(−p_n) from the last
            previous, placement = _ZERO3, body.pose
            for i, joint in enumerate(body.joints):
                X = _translation(joint.pos - previous)
                kind = _joint_type(joint)
                if joint.ref != 0.0 and joint.kind in ("hinge", "slide"):
                    X = X @ _reference_turn(joint)
                placement = placement @ X if placement is not _IDENTITY else X
                last = i == len(body.joints) - 1
                carrier = name if last and not joint.pos.any() else f"{_FIXED}{k}:{i}"
                if carrier != name:
                    hidden.append(carrier)
                lower, upper = (None, None) if joint.limits is None else ([joint.limits[0]], [joint.limits[1]])
                builder.add_body(carrier, kind, parent=parent, placement=placement, joint_name=joint.model_name,
                                 lower=lower, upper=upper, inertia=inertia if carrier == name else None,
                                 **_per_dof(joint))
                parent, previous, placement = carrier, joint.pos, _IDENTITY
            if parent != name:
                builder.add_body(name, jt.Fixed(), parent=parent, placement=_translation(-previous), inertia=inertia,
                                 joint_name=_FIXED + name)
        for geom in body.geoms:
            geometry = _geometry(geom, name, meshes, "visual" if geom.group <= 2 else "collision")
            if geometry is not None:
                builder.add_geometry(geometry)
            collision = _collision_geometry(geom, name, meshes, tree.report) if geom.collides else None
            if collision is not None:
                builder.add_collision_geometry(collision)
    sites = {}
    site_names = []
    for b, site_list in [(-1, tree.world_sites)] + [(k, body.sites) for k, body in enumerate(bodies)]:
        for node, pose in site_list:
            name = node.attrib.get("name")
            if not name:
                continue
            if name in sites:
                raise node.error(f"site {name!r} is defined twice")
            sites[name] = (b, pose)
            if name in index:
                tree.report.add(("site name",), node, "a site named as a body is no frame of the model (the body keeps "
                                                      "the name)")
                continue
            builder.add_body(name, jt.Fixed(), parent=None if b < 0 else names[b], placement=pose,
                             joint_name=_FIXED + name)
            site_names.append(name)
    model = builder.build(check_inertia=False)
    if hidden:
        keep = [b for b, name in enumerate(model.body_names) if name not in set(hidden)]
        model = dataclasses.replace(model, body_names=tuple(model.body_names[b] for b in keep),
                                    body_joints=model.body_joints[keep], body_placements=model.body_placements[keep],
                                    body_inertias=tuple(model.body_inertias[b] for b in keep))
    return model, index, sites, joints


#: the start of the names of what the builder needs named and the model does not show: the fixed joints of
#: bodies and sites, and the bodies between the joints of one MuJoCo body (no MuJoCo name holds it)
_FIXED = "\x00"


def _joint_type(joint):
    if joint.kind == "hinge":
        return jt.Revolute(joint.axis)
    if joint.kind == "slide":
        return jt.Prismatic(joint.axis)
    return jt.Spherical()


def _reference_turn(joint):
    """The pose that makes ``q = ref`` the file's placement: a turn by ``−ref`` about a hinge's axis, a shift
    by ``−ref`` along a slide's."""
    if joint.kind == "slide":
        return _translation(-joint.ref * joint.axis)
    return spatial.pose_matrix(spatial.axis_angle_rotation(joint.axis, -joint.ref), _ZERO3)


def _per_dof(joint):
    return {"damping": joint.damping, "friction": joint.friction, "armature": joint.armature}


def _geometry(geom, body, meshes, kind):
    """The :class:`Geometry` of ``kind`` of a geom (``None`` for planes, height fields, SDFs and meshes given by
    their vertices, which have no file for the viewer to read)."""
    a, b, c = geom.size
    if geom.kind == "mesh":
        uri, filename, scale, placement, exact = meshes.drawn(geom.mesh, geom.node)
        if not exact:
            meshes.reader.report.add(("refquat scale",), meshes.meshes[geom.mesh][0], "a mesh scaled unevenly and "
                                                                                     "turned by refquat is drawn approximately")
        if uri is None:
            return None
        return Geometry(body, kind, "mesh", geom.pose @ placement, uri=uri, filename=filename, scale=scale)
    sizes = {"sphere": (a,), "capsule": (a, 2.0 * b), "cylinder": (a, 2.0 * b), "ellipsoid": (a, b, c),
             "box": (2.0 * a, 2.0 * b, 2.0 * c)}
    if geom.kind not in sizes:
        return None
    return Geometry(body, kind, geom.kind, geom.pose, size=sizes[geom.kind])


def _collision_geometry(geom, body, meshes, report):
    """The collision :class:`Geometry` of a colliding geom: a primitive, a mesh file (its convex hull, read
    when the collision table is built), or a mesh given by its vertices, or scaled unevenly and turned by
    ``refquat``, as the hull of its vertices as MuJoCo compiles them; ``None``, with a
    warning, for an ellipsoid, a plane, a height field or an SDF, which contact detection has no shape for, and
    for vertices in one plane; ``None`` for a mesh whose file is not found (:func:`warn_missing_meshes` says
    so)."""
    if geom.kind not in COLLISION_SHAPES:
        report.add(("collision", geom.kind), geom.node, f"{geom.kind} geoms of bodies are left out of the collision "
                                                        "geometries (contact detection has no such shape)")
        return None
    if geom.kind != "mesh":
        return _geometry(geom, body, meshes, "collision")
    uri, filename, scale, placement, exact = meshes.drawn(geom.mesh, geom.node)
    if uri is not None and filename is None:
        return None
    if uri is None or not exact:
        # vertices given in the file, or a file that its placement cannot draw exactly: the hull at once
        hull = meshes.hull(geom.mesh, geom.node)
        return None if hull is None else Geometry(body, "collision", "convex", geom.pose, vertices=hull)
    return Geometry(body, "collision", "mesh", geom.pose @ placement, uri=uri, filename=filename, scale=scale)


# ----------------------------------------------------------------------------- MuJoCo's state conventions


def _state(model, q, v, names):
    """``q``, ``v`` checked and broadcast to one batch shape, and the joints' layout: ``(q, v, [(kind, start in
    q, start in v)])`` for the joints whose conventions differ (free flyers and ball joints)."""
    q = model.check_configuration(q, names[0]) if names[0] == "q" else np.asarray(q, dtype=float)
    v = model.check_velocity(v, names[1])
    if q.shape[-1:] != (model.nq,):
        raise ValueError(f"{names[0]} must have shape (..., {model.nq}), got {q.shape}")
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    q = np.array(np.broadcast_to(q, batch + (model.nq,)), dtype=float)
    v = np.array(np.broadcast_to(v, batch + (model.nv,)), dtype=float)
    layout = []
    for joint, name, iq, iv in zip(model.joints, model.joint_names, model.idx_q, model.idx_v):
        if isinstance(joint, jt.FreeFlyer):
            layout.append(("free", iq, iv))
        elif isinstance(joint, jt.Spherical):
            layout.append(("ball", iq, iv))
        elif not isinstance(joint, (jt.Revolute, jt.Prismatic)):
            raise ValueError(f"joint {name!r} is {joint.kind}: MuJoCo has hinge, slide, ball and free joints only")
    return q, v, layout


def to_mujoco(model, q, v):
    """MuJoCo's ``(qpos, qvel)`` of the state ``(q (..., nq), v (..., nv))`` of ``model`` (both batched alike).

    Hinges and slides are the same numbers. A ball joint's quaternion ``[x, y, z, w]`` becomes MuJoCo's
    ``[w, x, y, z]`` (its angular velocity is in the child frame on both sides). A free joint's
    ``[p, x, y, z, w]`` becomes ``[p, w, x, y, z]``, and its linear velocity, in the body's axes here,
    ``R v_lin`` in the world's axes (the angular velocity stays in the body's axes). A planar joint has
    no MuJoCo counterpart (``ValueError``).
    """
    q, v, layout = _state(model, q, v, ("q", "v"))
    qpos, qvel = q.copy(), v.copy()
    for kind, iq, iv in layout:
        quat = slice(iq + 3, iq + 7) if kind == "free" else slice(iq, iq + 4)
        qpos[..., quat] = q[..., quat][..., [3, 0, 1, 2]]
        if kind == "free":
            R = spatial.quat_to_rotation(q[..., quat])
            qvel[..., iv : iv + 3] = spatial.matvec(R, v[..., iv : iv + 3])
    return qpos, qvel


def from_mujoco(model, qpos, qvel):
    """The state ``(q, v)`` of ``model`` from MuJoCo's ``(qpos (..., nq), qvel (..., nv))``: the inverse of
    :func:`to_mujoco`. Quaternions are normalised, as MuJoCo uses them."""
    qpos, qvel, layout = _state(model, qpos, qvel, ("qpos", "qvel"))
    q, v = qpos.copy(), qvel.copy()
    for kind, iq, iv in layout:
        quat = slice(iq + 3, iq + 7) if kind == "free" else slice(iq, iq + 4)
        wxyz = qpos[..., quat]
        norm = np.linalg.norm(wxyz, axis=-1, keepdims=True)
        if np.any(norm < MINVAL):
            raise ValueError(f"qpos[{quat.start}:{quat.stop}] holds a zero quaternion")
        q[..., quat] = (wxyz / norm)[..., [1, 2, 3, 0]]
        if kind == "free":
            R = spatial.quat_to_rotation(q[..., quat])
            v[..., iv : iv + 3] = spatial.matvec(spatial.transpose(R), qvel[..., iv : iv + 3])
    return q, v


def velocity_to_mujoco(model, q):
    """``T (..., nv, nv)`` with ``qvel = T v`` at configuration ``q``: the identity but for each free joint's
    linear block, its rotation ``R``. Orthogonal, so that generalized forces map by ``Tᵀ``
    (``τ = Tᵀ τ_MuJoCo``), the mass matrix by ``M = Tᵀ M_MuJoCo T``, and accelerations by
    ``qacc = T a + Ṫ v`` (:func:`acceleration_to_mujoco`)."""
    q = model.check_configuration(q)
    T = np.broadcast_to(np.eye(model.nv), q.shape[:-1] + (model.nv, model.nv)).copy()
    for joint, iq, iv in zip(model.joints, model.idx_q, model.idx_v):
        if isinstance(joint, jt.FreeFlyer):
            T[..., iv : iv + 3, iv : iv + 3] = spatial.quat_to_rotation(q[..., iq + 3 : iq + 7])
    return T


def acceleration_to_mujoco(model, q, v, a):
    """MuJoCo's ``qacc`` of the accelerations ``a`` at ``(q, v)``: ``a`` but for each free joint's linear part,
    ``R (a_lin + ω × v_lin)``, the rate of the world-axes velocity ``R v_lin``."""
    q, v = model.check_configuration(q), model.check_velocity(v)
    a = model.check_velocity(a, "a")
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], a.shape[:-1])
    out = np.array(np.broadcast_to(a, batch + (model.nv,)), dtype=float)
    for joint, iq, iv in zip(model.joints, model.idx_q, model.idx_v):
        if isinstance(joint, jt.FreeFlyer):
            R = spatial.quat_to_rotation(q[..., iq + 3 : iq + 7])
            linear = a[..., iv : iv + 3] + spatial.cross(v[..., iv + 3 : iv + 6], v[..., iv : iv + 3])
            out[..., iv : iv + 3] = spatial.matvec(R, linear)
    return out
