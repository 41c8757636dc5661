"""URDF loader: ``load_urdf(source, floating_base=False, package_dirs=None)``.

The model follows Pinocchio's ``buildModelFromUrdf`` exactly where both are defined:

* Joint order: depth-first from the root link; the child joints of a link are visited in
  ascending order of joint name (urdfdom keeps them in a name-sorted map).
* Links attached by fixed joints are lumped into the moving body they hang from; they keep their
  names and placements in ``model.body_names`` / ``model.body_placements``.
* ``continuous`` joints are plain angles here (``nq = 1``); Pinocchio stores ``(cos θ, sin θ)``.
* ``planar`` joints move in the x–y plane of the joint frame (Pinocchio ignores the axis too).
* ``floating`` joints, and ``floating_base=True``, give free-flyer joints (``q = [p, quat]``).
* Mimic joints stay independent coordinates; the relation is recorded in ``model.mimic``.
* A link without ``<inertial>`` is massless.
* Numbers are decimal (``-1.5``, ``2e-3``; no ``inf``, ``nan``, hexadecimal or digit separators)
  and at most :data:`LARGEST_MAGNITUDE` in absolute value: larger values describe no physical
  robot, and products of a few of them in the dynamics (``m · L² · ω²``) would overflow.
* Joint limits are the exception: a limit at or beyond ``±UNBOUNDED_LIMIT`` (``±1e16``, the
  SDFormat convention for "no limit"), ``±inf`` included, leaves that side unbounded.
* ``<limit lower upper effort velocity>`` and ``<dynamics damping friction>`` of revolute,
  continuous and prismatic joints go into ``model.lower``/``model.upper`` (``(nq,)``) and
  ``model.effort_limit``, ``model.velocity_limit``, ``model.damping``, ``model.friction``
  (``(nv,)``), Pinocchio's ``lowerPositionLimit``, ``upperPositionLimit``, ``effortLimit``,
  ``velocityLimit``, ``damping`` and ``friction``. A joint without ``<limit>`` has unbounded positions
  (``±inf``), and an absent ``effort`` or ``velocity`` means no limit (``inf``); a ``<limit>`` without
  ``lower`` or ``upper`` gives that side 0, as the URDF specification, urdfdom and Pinocchio do, and a
  revolute or prismatic joint whose limits are then both 0 (held still) warns. Without ``<dynamics>``
  there is no damping or friction. Where Pinocchio differs: a continuous joint's angle is unbounded
  here (Pinocchio bounds its ``(cos θ, sin θ)`` by ±1.01); a free flyer's position is unbounded and its
  quaternion bounded by ±1, where Pinocchio writes ±``DBL_MAX`` for the ``root_joint`` of
  ``floating_base`` (and ±1.01 for the quaternion of a URDF ``floating`` joint). As in Pinocchio, the
  ``<limit>`` and ``<dynamics>`` of ``floating`` and ``planar`` joints are ignored. Effort and speed limits must not be negative, nor
  damping and friction; limits at or beyond ``UNBOUNDED_LIMIT`` mean none.
* A ``<mimic>`` must name another joint with one coordinate (revolute, continuous or prismatic),
  and the joint that carries it must have one coordinate too. A mimicked joint that does not
  exist only warns, and the relation is dropped; a ``<mimic>`` on a fixed joint is ignored
  (reduced models such as Talos's freeze the mimicking joints and keep the tag).
* ``<visual>`` and ``<collision>`` shapes (sphere, box, cylinder, mesh) are ``model.geometries``, the
  viewer's; the ``<collision>`` ones are also ``model.collision_geometries`` (a mesh as its convex hull,
  read when :func:`multibody.geometry.collision_table` is first built). A size of 0 loads (the dynamics need
  no shape); the collision table refuses it.

Malformed files raise :class:`URDFError` naming the file, the element and the problem.
"""

from __future__ import annotations

import os
import warnings
import xml.etree.ElementTree as ET

import numpy as np

from . import joints as jt
from . import spatial
from .inertia import Inertia
from .model import Geometry, Mimic, ModelBuilder, inertia_problems
# LARGEST_MAGNITUDE is the bound this module's docstrings name, and scripts read it here
from .modelfiles import (LARGEST_MAGNITUDE, is_xml_text, package_directories, parse_numbers,  # noqa: F401
                         resolve_file, warn_missing_meshes)


class URDFError(ValueError):
    """A URDF that cannot describe a valid model."""


#: Joint limits at or beyond this absolute value (``inf`` included) mean "no limit on that side".
UNBOUNDED_LIMIT = 1e16

# Joint types whose configuration is one number, the only ones a <mimic> can relate, and their joints.
_ONE_COORDINATE_TYPES = {"revolute": jt.Revolute, "continuous": jt.Continuous, "prismatic": jt.Prismatic}


class _Context:
    """Where we are in the document, for error messages."""

    def __init__(self, source_name):
        self.source_name = source_name

    def error(self, element_path, problem):
        return URDFError(f"{self.source_name}: {element_path}: {problem}")


def _floats(ctx, element, attribute, path, count, default=None, allow_infinite=False):
    """``count`` numbers from ``element``'s ``attribute`` (``default`` when it is absent), finite and at
    most :data:`LARGEST_MAGNITUDE` in absolute value unless ``allow_infinite`` (joint limits: any size,
    and ``inf``)."""
    text = element.get(attribute) if element is not None else None
    if text is None:
        if default is None:
            raise ctx.error(path, f"missing attribute {attribute!r}")
        return np.array(default, dtype=float)
    try:
        return parse_numbers(text, attribute, count, allow_infinite=allow_infinite)
    except ValueError as problem:
        raise ctx.error(path, str(problem)) from None


def _origin(ctx, element, path):
    """4×4 pose from an ``<origin xyz rpy>`` child (identity when absent)."""
    origin = element.find("origin")
    if origin is None:
        return np.eye(4)
    xyz = _floats(ctx, origin, "xyz", path + "/<origin>", 3, (0.0, 0.0, 0.0))
    rpy = _floats(ctx, origin, "rpy", path + "/<origin>", 3, (0.0, 0.0, 0.0))
    return spatial.pose_from_xyz_rpy(xyz, rpy)


def _inertial(ctx, link, path):
    """The link's :class:`Inertia` in the link frame, from ``<inertial>`` (massless when absent)."""
    inertial = link.find("inertial")
    if inertial is None:
        return Inertia.zero()
    path = path + "/<inertial>"
    mass_element = inertial.find("mass")
    if mass_element is None:
        raise ctx.error(path, "missing <mass>")
    mass = _floats(ctx, mass_element, "value", path + "/<mass>", 1)[0]
    if mass < 0.0:
        raise ctx.error(path + "/<mass>", f"negative mass {mass:g}")
    tensor_element = inertial.find("inertia")
    if tensor_element is None:
        tensor = np.zeros((3, 3))
    else:
        get = lambda key: _floats(ctx, tensor_element, key, path + "/<inertia>", 1, (0.0,))[0]  # noqa: E731
        ixx, ixy, ixz, iyy, iyz, izz = (get(k) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    # The inertial frame may be offset and rotated from the link frame.
    return Inertia(mass, np.zeros(3), tensor).transformed(_origin(ctx, inertial, path))


def _check_bodies(ctx, model, invalid_inertia):
    """Refuse (or report) moving rigid bodies whose lumped mass properties are impossible."""
    for _, links, problems in inertia_problems(model):
        where = f"<link name='{links[0]}'>/<inertial>" if len(links) == 1 else \
            "rigid body of links " + ", ".join(f"<link name='{name}'>" for name in links)
        message = "; ".join(problems)
        if invalid_inertia == "error":
            raise ctx.error(where, message + " (pass invalid_inertia='warn' to load it anyway)")
        if invalid_inertia == "warn":
            warnings.warn(f"{ctx.source_name}: {where}: {message}", UserWarning, stacklevel=3)


def _joint_type(ctx, joint, path):
    kind = joint.get("type")
    axis_element = joint.find("axis")
    axis = _floats(ctx, axis_element, "xyz", path + "/<axis>", 3, (1.0, 0.0, 0.0))
    if kind in _ONE_COORDINATE_TYPES:
        if np.linalg.norm(axis) < 1e-12:
            raise ctx.error(path + "/<axis>", f"attribute xyz={axis_element.get('xyz')!r}: axis must be non-zero "
                                              "(length at least 1e-12)")
        return _ONE_COORDINATE_TYPES[kind](axis)
    if kind == "fixed":
        return jt.Fixed()
    if kind == "floating":
        return jt.FreeFlyer()
    if kind == "planar":
        if axis_element is not None and np.linalg.norm(np.cross(axis, [0.0, 0.0, 1.0])) > 1e-9 * np.linalg.norm(axis):
            warnings.warn(
                f"{ctx.source_name}: {path}/<axis>: planar joints move in the x-y plane of the joint frame; "
                f"the axis {axis.tolist()} is ignored (as in Pinocchio)",
                UserWarning,
                stacklevel=4,
            )
        return jt.Planar()
    if kind is None:
        raise ctx.error(path, "missing attribute 'type'")
    raise ctx.error(
        path, f"unknown joint type {kind!r} (expected revolute, continuous, prismatic, fixed, floating or planar)"
    )


def _limits(ctx, joint_element, joint, path):
    """``(lower, upper)`` of a one-coordinate joint; a side at or beyond ``±UNBOUNDED_LIMIT`` is unbounded.
    A ``<limit>`` without ``lower`` or ``upper`` gives that side 0 (the URDF specification's default, as in
    urdfdom and Pinocchio); a revolute or prismatic joint held at 0 by both warns."""
    lower, upper = joint.default_limits
    limit = joint_element.find("limit")
    if limit is None or joint.nq != 1 or isinstance(joint, jt.Continuous):
        return lower, upper
    path = path + "/<limit>"
    lower = _floats(ctx, limit, "lower", path, 1, (0.0,), allow_infinite=True)
    upper = _floats(ctx, limit, "upper", path, 1, (0.0,), allow_infinite=True)
    absent = [side for side in ("lower", "upper") if limit.get(side) is None]
    reason = f" ({' and '.join(absent)} absent: the URDF specification reads 0)" if absent else ""
    if lower[0] == upper[0] == 0.0:
        remedy = "give its range, or make it continuous for an unbounded angle" if isinstance(joint, jt.Revolute) \
            else "give its range"
        warnings.warn(f"{ctx.source_name}: {path}: the limits are lower = upper = 0{reason}, which hold the "
                      f"{joint.kind} joint still; {remedy}", UserWarning, stacklevel=3)
    for side, unbounded in (("lower", lower[0] >= UNBOUNDED_LIMIT), ("upper", upper[0] <= -UNBOUNDED_LIMIT)):
        if unbounded:
            raise ctx.error(path, f"attribute {side}={limit.get(side)!r} leaves no finite position "
                                  f"(limits at or beyond ±{UNBOUNDED_LIMIT:g} mean unbounded)")
    if lower[0] > upper[0]:
        raise ctx.error(path, f"lower limit {lower[0]:g} exceeds upper limit {upper[0]:g}{reason}")
    lower = np.where(lower <= -UNBOUNDED_LIMIT, -np.inf, lower)
    upper = np.where(upper >= UNBOUNDED_LIMIT, np.inf, upper)
    return lower, upper


def _joint_dynamics(ctx, joint_element, joint, path):
    """``damping``, ``friction``, ``effort_limit`` and ``velocity_limit`` of a joint, ``(joint.nv,)`` each,
    for :meth:`ModelBuilder.add_body`: from ``<dynamics>`` and ``<limit>`` of a one-coordinate joint
    (absent: no damping or friction, no limits), the defaults for the others (as in Pinocchio)."""
    if joint.nq != 1:
        return {}
    out = {}
    dynamics = joint_element.find("dynamics")
    for key in ("damping", "friction"):
        value = _floats(ctx, dynamics, key, path + "/<dynamics>", 1, (0.0,))
        if value[0] < 0.0:
            raise ctx.error(path + "/<dynamics>", f"attribute {key}={dynamics.get(key)!r} must not be negative")
        out[key] = value
    limit = joint_element.find("limit")
    for key in ("effort", "velocity"):
        value = _floats(ctx, limit, key, path + "/<limit>", 1, (np.inf,), allow_infinite=True)
        if value[0] < 0.0:
            raise ctx.error(path + "/<limit>", f"attribute {key}={limit.get(key)!r} must not be negative "
                                               f"(give {UNBOUNDED_LIMIT:g} or more, or leave it out, for no limit)")
        out[f"{key}_limit"] = np.where(value >= UNBOUNDED_LIMIT, np.inf, value)
    return out


def _mimic(ctx, mimic, joint_name, joint_type, path):
    """The :class:`Mimic` of a ``<mimic>`` element carried by ``joint_name`` (its target checked later)."""
    mimicked = mimic.get("joint")
    if not mimicked:
        raise ctx.error(path, "missing attribute 'joint'")
    if mimicked == joint_name:
        raise ctx.error(path, f"attribute joint={mimicked!r}: a joint cannot mimic itself")
    if joint_type not in _ONE_COORDINATE_TYPES:
        raise ctx.error(path, f"a {joint_type} joint cannot mimic another: only revolute, continuous and "
                              "prismatic joints can (a fixed joint's <mimic> is ignored)")
    return Mimic(
        joint_name,
        mimicked,
        float(_floats(ctx, mimic, "multiplier", path, 1, (1.0,))[0]),
        float(_floats(ctx, mimic, "offset", path, 1, (0.0,))[0]),
    )


def _sizes(ctx, element, attribute, path, count):
    """Dimensions of a primitive shape: ``count`` non-negative numbers."""
    values = _floats(ctx, element, attribute, path, count)
    if np.any(values < 0.0):
        raise ctx.error(path, f"attribute {attribute}={element.get(attribute)!r} must not be negative")
    return tuple(float(x) for x in values)


#: The attributes, and how many numbers each holds, of the size of each primitive shape (:class:`Geometry`'s order).
_SHAPE_SIZES = {"box": (("size", 3),), "sphere": (("radius", 1),), "cylinder": (("radius", 1), ("length", 1))}


def _geometries(ctx, link, path, base_dir, package_dirs):
    out = []
    for kind in ("visual", "collision"):
        for element in link.findall(kind):
            element_path = f"{path}/<{kind}>"
            geometry = element.find("geometry")
            if geometry is None or len(geometry) == 0:
                continue
            shape_element = geometry[0]
            placement = _origin(ctx, element, element_path)
            shape = shape_element.tag
            if shape == "mesh":
                uri = shape_element.get("filename", "")
                filename = resolve_file(uri, base_dir, package_dirs)
                scale = tuple(_floats(ctx, shape_element, "scale", element_path + "/<mesh>", 3, (1.0, 1.0, 1.0)))
                out.append(Geometry(link.get("name"), kind, "mesh", placement, uri=uri, filename=filename, scale=scale))
            elif shape in _SHAPE_SIZES:
                size = sum((_sizes(ctx, shape_element, attribute, f"{element_path}/<{shape}>", count)
                            for attribute, count in _SHAPE_SIZES[shape]), ())
                out.append(Geometry(link.get("name"), kind, shape, placement, size=size))
    return out


def _parse_source(source):
    """``(root element, display name, base directory)`` from a path or an XML string."""
    is_xml = is_xml_text(source)
    name = "<URDF string>" if is_xml else os.fspath(source)
    try:
        if is_xml:
            root = ET.fromstring(source)
            base_dir = None
        else:
            if not os.path.isfile(name):
                raise FileNotFoundError(f"URDF file not found: {name}")
            root = ET.parse(name).getroot()
            base_dir = os.path.dirname(os.path.abspath(name))
    except ET.ParseError as exc:
        raise URDFError(f"{name}: XML syntax error: {exc}") from None
    if root.tag != "robot":
        raise URDFError(f"{name}: <{root.tag}>: the root element must be <robot>")
    return root, name, base_dir


def load_urdf(source, *, floating_base=False, package_dirs=None, invalid_inertia="error"):
    """Build a :class:`~multibody.model.Model` from a URDF file path or XML string.

    Args:
        source: path to a ``.urdf`` file, or the XML text itself.
        floating_base: put a free-flyer joint named ``"root_joint"`` between the world and the root
            link (``q`` gains ``[x, y, z, qx, qy, qz, qw]`` in front, ``v`` gains ``[v_lin, ω]``).
        package_dirs: directories searched for ``package://name/...`` meshes (a path or a list);
            ``package://name/rest`` is looked up as ``d/name/rest`` and ``d/rest`` for each ``d``,
            then in the directories of ``ROS_PACKAGE_PATH``. Nothing is read until
            :func:`multibody.geometry.load_meshes` (the viewer) or
            :func:`multibody.geometry.collision_table` (contact: each ``<collision>`` mesh's convex hull)
            is called; meshes that cannot be found give one ``UserWarning`` (the dynamics need only
            ``<inertial>``), and collision meshes among them are left out of ``model.collision_geometries``.
        invalid_inertia: what to do when a moving rigid body (a moving link lumped with the links
            fixed to it, as the dynamics sees it) has mass properties no real body can have: an
            inertia tensor that is not positive semi-definite or breaks the triangle inequality
            ``I₁ + I₂ ≥ I₃``. ``"error"`` (default) raises :class:`URDFError`; ``"warn"`` loads it
            with a warning; ``"ignore"`` loads it silently (as Pinocchio does). A placeholder link
            with impossible numbers that is fixed to a valid body does not make that body invalid;
            ``multibody info`` lists such links as suspicious. Negative masses are always refused.

    Raises:
        URDFError: malformed XML, missing links, cycles, several roots, unknown joint types,
            negative masses, invalid inertias, zero axes, duplicate names, numbers that are not
            decimal, not finite or above :data:`LARGEST_MAGNITUDE`, negative shape sizes, negative
            damping, friction, effort or velocity limits, and mimic relations that cannot hold (a
            joint that mimics itself, or a joint without exactly one coordinate on either side).
        FileNotFoundError: ``source`` is neither an existing file nor XML text.
    """
    if invalid_inertia not in ("error", "warn", "ignore"):
        raise ValueError(f"invalid_inertia must be 'error', 'warn' or 'ignore', got {invalid_inertia!r}")
    root, source_name, base_dir = _parse_source(source)
    ctx = _Context(source_name)
    package_dirs = package_directories(package_dirs)

    links = {}
    for link in root.findall("link"):
        name = link.get("name")
        if not name:
            raise ctx.error("<link>", "missing attribute 'name'")
        if name in links:
            raise ctx.error(f"<link name='{name}'>", "duplicate link name")
        links[name] = link

    children, parent_joint, joint_types = {}, {}, {}
    for joint in root.findall("joint"):
        name = joint.get("name")
        path = f"<joint name='{name}'>"
        if not name:
            raise ctx.error("<joint>", "missing attribute 'name'")
        if name in joint_types:
            raise ctx.error(path, "duplicate joint name")
        joint_types[name] = joint.get("type")
        ends = {}
        for end in ("parent", "child"):
            element = joint.find(end)
            link_name = element.get("link") if element is not None else None
            if not link_name:
                raise ctx.error(path, f"missing <{end} link=...>")
            if link_name not in links:
                raise ctx.error(f"{path}/<{end}>", f"{end} link {link_name!r} is not defined")
            ends[end] = link_name
        if ends["child"] in parent_joint:
            raise ctx.error(path, f"link {ends['child']!r} has two parent joints "
                                  f"({parent_joint[ends['child']].get('name')!r} and {name!r})")
        parent_joint[ends["child"]] = joint
        children.setdefault(ends["parent"], []).append(joint)

    if not links:
        raise ctx.error("<robot>", "no <link> elements")
    roots = [name for name in links if name not in parent_joint]
    if len(roots) != 1:
        if not roots:
            raise ctx.error("<robot>", f"the joints {sorted(joint_types)} form a cycle: no link is without a parent")
        raise ctx.error("<robot>", f"several root links {roots}: a URDF must describe a single tree")
    root_link = roots[0]

    builder = ModelBuilder(root.get("name") or "robot")
    mimics = []

    def add_link(name, parent, joint, joint_name, placement, lower=None, upper=None, dynamics=None):
        path = f"<link name='{name}'>"
        inertia = _inertial(ctx, links[name], path)
        builder.add_body(name, joint, parent=parent, placement=placement, inertia=inertia,
                         joint_name=joint_name, lower=lower, upper=upper, **(dynamics or {}))
        for geometry in _geometries(ctx, links[name], path, base_dir, package_dirs):
            builder.add_geometry(geometry)
            # (a mesh that is not found is left out: warn_missing_meshes says so)
            if geometry.kind == "collision" and (geometry.shape != "mesh" or geometry.filename is not None):
                builder.add_collision_geometry(geometry)

    # The root link is the world itself when it is called "world" and the base is fixed.
    world_root = root_link if (root_link == "world" and not floating_base) else None
    if floating_base:
        add_link(root_link, None, jt.FreeFlyer(), "root_joint", np.eye(4))
    elif world_root is None:
        add_link(root_link, None, jt.Fixed(), f"{root_link}_to_world", np.eye(4))

    # Depth-first, child joints by name; an explicit stack keeps deep chains off Python's recursion limit.
    visited = {root_link}
    stack = [(root_link, joint) for joint in sorted(children.get(root_link, []), key=lambda j: j.get("name"), reverse=True)]
    while stack:
        parent_link, joint = stack.pop()
        name = joint.get("name")
        path = f"<joint name='{name}'>"
        child = joint.find("child").get("link")
        visited.add(child)
        joint_type = _joint_type(ctx, joint, path)
        lower, upper = _limits(ctx, joint, joint_type, path)
        add_link(child, None if parent_link == world_root else parent_link, joint_type, name, _origin(ctx, joint, path),
                 lower, upper, _joint_dynamics(ctx, joint, joint_type, path))
        mimic = joint.find("mimic")
        # A fixed joint has no coordinate to couple: reduced models freeze mimicking joints and keep the tag.
        if mimic is not None and not isinstance(joint_type, jt.Fixed):
            mimics.append(_mimic(ctx, mimic, name, joint.get("type"), path + "/<mimic>"))
        stack.extend((child, j) for j in sorted(children.get(child, []), key=lambda j: j.get("name"), reverse=True))

    unreached = [name for name in links if name not in visited]
    if unreached:
        cycle = [parent_joint[name].get("name") for name in unreached if name in parent_joint]
        raise ctx.error("<robot>", f"the joints {cycle} form a cycle: links {unreached} are not reachable "
                                   f"from root {root_link!r}")
    for mimic in mimics:
        if mimic.mimicked in joint_types:
            if joint_types[mimic.mimicked] not in _ONE_COORDINATE_TYPES:
                raise ctx.error(f"<joint name='{mimic.joint}'>/<mimic>",
                                f"attribute joint={mimic.mimicked!r} names a {joint_types[mimic.mimicked]} joint; "
                                "a mimic must follow a revolute, continuous or prismatic joint")
            builder.add_mimic(mimic)
        else:
            warnings.warn(f"{source_name}: <joint name='{mimic.joint}'>/<mimic>: mimicked joint {mimic.mimicked!r} "
                          "is not defined; the mimic relation is dropped", UserWarning, stacklevel=2)
    model = builder.build(check_inertia=False)
    _check_bodies(ctx, model, invalid_inertia)
    warn_missing_meshes(model, source_name, "give package_dirs to resolve package:// paths")
    return model
