"""MJCF loader: ``load_mjcf(source, *, package_dirs=None)``, and MuJoCo's state conventions
(:func:`to_mujoco`, :func:`from_mujoco`).

MuJoCo's own compiler reads the file (``mujoco.MjSpec``, then ``MjSpec.compile``), so that the model is
the one MuJoCo compiles: includes, default classes, frames, every orientation form, ``<compiler>``
options, mass properties from geoms and meshes, and the procedural elements (``replicate``, ``attach``,
and ``composite`` where the installed MuJoCo still reads it) are MuJoCo's. The loader then reads the compiled arrays
(``mujoco.MjModel``), in MuJoCo's order, so that ``q``, ``v`` and every matrix line up with MuJoCo's
``qpos``, ``qvel``, ``mj_fullM`` and ``qfrc_bias`` (the quaternions and a free joint's velocity
converted by :func:`to_mujoco`):

* bodies (``body_parentid``, ``body_pos``, ``body_quat``; a ``mocap`` body is fixed to the world) with
  their mass properties (``body_mass``, ``body_ipos``, and ``body_inertia``, the principal moments in
  the frame ``body_iquat``: ``I = R diag(moments) Rᵀ``);
* joints ``hinge``, ``slide``, ``ball`` and ``free`` (``jnt_pos``, ``jnt_axis`` in the body frame). The
  joints of one body form a chain in MuJoCo's order, each about its ``pos``; a hinge's or slide's ``q``
  is MuJoCo's ``qpos``: at ``q = ref`` (MuJoCo's ``qpos0``) the body is where the file puts it, so the
  model's zero configuration turns each joint by ``−ref``. ``jnt_range`` where ``jnt_limited`` gives
  ``model.lower``/``model.upper``; ``dof_damping``, ``dof_frictionloss`` and ``dof_armature`` give
  ``model.damping``, ``model.friction`` and ``model.armature``;
* named sites are frames (bodies without mass fixed to theirs, or to the world), usable by name in
  :func:`multibody.frame_placement`, :func:`multibody.jacobian` and the constraints; a site named as a
  body is not (a warning says so);
* geoms of bodies are the viewer's shapes (``model.geometries``): those of groups 0–2, which MuJoCo's
  viewer shows, as ``"visual"``, the others as ``"collision"``; a mesh is its file, scaled, placed where
  MuJoCo's compiled vertices are (MuJoCo moves a mesh's vertices to its inertial frame, ``mesh_pos`` and
  ``mesh_quat``, and the geom's pose with them); a mesh given by its vertices (no file), a plane, a
  height field and an SDF are not drawn, nor, with a warning, a mesh whose file the loader does not find
  where MuJoCo read it (an attached model's, read from that model's folder);
* the bodies' geoms that collide (``contype`` or ``conaffinity`` not 0, MuJoCo's filter; any group) are
  ``model.collision_geometries``: spheres, boxes, capsules and cylinders, and a mesh as the convex hull
  of its compiled vertices (``mesh_vert``, MuJoCo's own, in the geom frame). Ellipsoids, planes, height
  fields and SDFs of bodies are left out with a warning; the world's geoms (a floor) belong to no body
  and are not kept (a floor is :class:`multibody.Ground`'s half-space);
* gravity (``opt.gravity``; zero with ``<flag gravity="disable"/>``);
* equalities: ``connect`` → :class:`~multibody.LoopClosure` ``kind="point"``, ``weld`` → ``kind="weld"``
  (body2's ``anchor``, and the relative pose ``relpose`` or, without it, the one at ``qpos0``, as MuJoCo
  compiles them into ``eq_data``; site-based ones use the site frames), ``joint`` →
  :class:`~multibody.JointCoupling` with MuJoCo's ``polycoef``, in ``model.equality_constraints``; the
  world, a missing ``body2`` or a mocap body is fixed, so the constraint holds against the world.

``model.body_names`` are MuJoCo's bodies without the world, in MuJoCo's order (``body_names[i]`` is
MuJoCo's body ``i + 1``), then the sites; ``model.joint_names`` MuJoCo's joints in order. An unnamed
body or joint is called ``body_<id>`` or ``joint_<id>`` after its MuJoCo id (with ``_`` appended while
the name is taken).

Left out, with one warning per kind naming the file, an element and how many there are: actuators
(joint forces are the ``τ`` given to the dynamics), tendons, passive springs (``stiffness``), gravity
compensation, fluid forces, ball-joint range cones, plugins, flexes, tendon and flex equalities and
inactive ones. Rendering, contact and solver parameters, sensors and keyframes change nothing in the
equations of motion and are ignored without a word.

What MuJoCo refuses raises :class:`MJCFError` with MuJoCo's message (it names the element and the
line) after the file; so does what MuJoCo compiles and the model cannot hold (a number that is not finite
or past ``1e50``, a negative damping), naming the element. MuJoCo is an extra
(``pip install "multibody[mjcf]"``), imported when a file is loaded.
"""

from __future__ import annotations

import functools
import os
import pathlib
import re
import warnings
import xml.parsers.expat

import numpy as np

from . import joints as jt
from . import spatial
from .constraints import JointCoupling, LoopClosure
from .geometry import hull_vertices
from .inertia import Inertia
from .model import Geometry, ModelBuilder
from .modelfiles import LARGEST_MAGNITUDE, is_xml_text, package_directories, resolve_file

#: MuJoCo's smallest meaningful value (``mjMINVAL``): shorter quaternions are refused.
MINVAL = 1e-15

_IDENTITY = np.eye(4)
_IDENTITY.setflags(write=False)


class MJCFError(ValueError):
    """An MJCF file that MuJoCo refuses: its message is the file's name, then MuJoCo's (element and line)."""


class _FirstElement(Exception):
    pass


def _root_tag(read):
    """The tag of the root element of the XML that ``read(parser)`` feeds to an expat ``parser`` (parsed up to
    that element only), or ``None`` when it is not XML."""
    parser = xml.parsers.expat.ParserCreate()

    def start(tag, attrib):
        raise _FirstElement(tag)

    parser.StartElementHandler = start
    try:
        read(parser)
    except _FirstElement as first:
        return first.args[0]
    except xml.parsers.expat.ExpatError:
        return None
    return None


def is_mjcf_file(path) -> bool:
    """Whether the file at ``path`` is MJCF: its root element is ``<mujoco>`` (read up to that element only;
    ``False`` for a file that is not XML)."""
    with open(path, "rb") as stream:
        return _root_tag(lambda parser: parser.ParseFile(stream)) == "mujoco"


# A file an MJCF document names (include, mesh, texture, height field, skin) or a folder it puts them in.
_FILE_ATTRIBUTE = re.compile(r"""\b(file\w*|meshdir|assetdir|texturedir)\s*=\s*(?:"([^"]*)"|'([^']*)')""")


def _package_files(text, package_dirs):
    """``{name: path}`` of the files that ``text`` (and the files it includes) names, found in ``package_dirs``:
    each relative ``file`` attribute, alone and under each ``meshdir``/``assetdir``/``texturedir``, under
    the name MuJoCo looks up in its virtual file system."""
    names, folders, found, texts = set(), {""}, {}, [text]
    while texts:
        for key, double, single in _FILE_ATTRIBUTE.findall(texts.pop()):
            (folders if key.endswith("dir") else names).add(double or single)
        for name in names - {""}:
            for folder in folders:
                key = os.path.join(folder, name)
                if key in found or os.path.isabs(key):
                    continue
                path = resolve_file(key, package_dirs, package_dirs)
                if path is not None:
                    found[key] = path
                    if key.endswith(".xml"):
                        with open(path, encoding="utf-8", errors="replace") as stream:
                            texts.append(stream.read())
    return found


def _compile(mujoco, source, package_dirs):
    """``(spec, compiled model, the source's name for messages, {name: path} of package files)`` of MuJoCo's
    compiler (the module ``mujoco``) on ``source`` (a path or XML text)."""
    if is_xml_text(source):
        name, text = "<MJCF string>", source
    else:
        name = os.fspath(source)
        if not os.path.isfile(name):
            raise FileNotFoundError(f"MJCF file not found: {name}")
        text = pathlib.Path(name).read_text(encoding="utf-8", errors="replace")
    root = _root_tag(lambda parser: parser.Parse(text, True))
    # (MuJoCo would compile a URDF too)
    if root is not None and root != "mujoco":
        raise MJCFError(f"{name}: the root element must be <mujoco>, got <{root}>")
    found = _package_files(text, package_dirs) if package_dirs else {}
    files = {key: pathlib.Path(path).read_bytes() for key, path in found.items()}
    try:
        if name == "<MJCF string>":
            spec = mujoco.MjSpec.from_string(text, include=files, assets=files)
        else:
            spec = mujoco.MjSpec.from_file(name, include=files, assets=files)
        return spec, spec.compile(), name, found
    except ValueError as error:
        raise MJCFError(f"{name}: {str(error).strip()}") from None


class _Report:
    """What the file holds that the model leaves out: one warning per kind, naming an element and the count."""

    def __init__(self, name):
        self.name, self.items = name, {}

    def add(self, text, element, count=1):
        item = self.items.setdefault(text, [element, 0])
        item[1] += count

    def warn(self, stacklevel):
        for text, (element, count) in self.items.items():
            more = f" ({count} elements)" if count > 1 else ""
            warnings.warn(f"{self.name}: {element}: {text}{more}", UserWarning, stacklevel=stacklevel + 1)


def load_mjcf(source, *, package_dirs=None):
    """Build a :class:`~multibody.model.Model` from an MJCF file path or XML string, as MuJoCo compiles it
    (module docstring: what is read, in which order, and what is left out with a warning).

    Args:
        source: path to an MJCF ``.xml`` file, or the XML text itself.
        package_dirs: directories (a path or a list) where relative ``<include>`` files, ``meshdir`` and
            mesh files are also looked for (handed to MuJoCo as its assets); an XML string has no
            directory of its own, so its relative paths resolve there, or in the working directory.

    Returns:
        the model, its ``equality_constraints`` the file's ``<equality>`` elements.

    Raises:
        MJCFError: what MuJoCo's compiler refuses (malformed XML, unknown elements, attributes, classes,
            names and files, impossible numbers and inertias), with MuJoCo's message; a root element other
            than ``<mujoco>``; a compiled number that is not finite or past ``1e50`` (the dynamics would
            overflow) or that the model refuses (a negative damping), naming the element.
        FileNotFoundError: ``source`` is neither an existing file nor XML text.
        ImportError: MuJoCo is not installed (``pip install "multibody[mjcf]"``).
    """
    try:
        import mujoco
    except ImportError as error:
        raise ImportError('load_mjcf needs MuJoCo\'s compiler: pip install "multibody[mjcf]"') from error
    spec, m, name, found = _compile(mujoco, source, package_directories(package_dirs))
    report = _Report(name)
    _report_left_out(mujoco, m, report)
    try:
        model = _build(mujoco, spec, m, found, report)
    except ValueError as error:
        # what MuJoCo compiles and the model refuses (a NaN, a negative damping), after the file
        raise MJCFError(f"{name}: {error}") from None
    report.warn(stacklevel=2)
    return model


def _build(mujoco, spec, m, found, report):
    """The :class:`Model` of MuJoCo's compiled model ``m`` (of ``spec``, with the package files ``found``), what
    it leaves out told to ``report``; ``ValueError`` naming the element for what the model cannot hold."""
    def object_name(kind, k):
        return mujoco.mj_id2name(m, kind, k) or ""

    body_names = _unique_names([object_name(mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, m.nbody)], "body_", 1)
    joint_names = _unique_names([object_name(mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)], "joint_", 0)
    gravity = np.zeros(3) if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY) else np.array(m.opt.gravity)
    builder = ModelBuilder(spec.modelname, gravity=gravity)
    _check_magnitudes(mujoco, m, object_name)
    # the poses of the bodies, of their principal axes, of the geoms and of the sites, in one call
    poses = _pose(np.concatenate((m.body_quat, m.body_iquat, m.geom_quat, m.site_quat)),
                  np.concatenate((m.body_pos, m.body_ipos, m.geom_pos, m.site_pos)))
    geoms = 2 * m.nbody + m.ngeom
    hidden = _add_bodies(mujoco, builder, m, body_names, joint_names, poses[: m.nbody], poses[m.nbody : 2 * m.nbody, :3, :3])
    _add_geoms(mujoco, builder, m, poses[2 * m.nbody : geoms], body_names, _MeshFiles(spec, m, found), report)
    for s, body in enumerate(m.site_bodyid.tolist()):
        site = object_name(mujoco.mjtObj.mjOBJ_SITE, s)
        if site in body_names:
            report.add("a site named as a body is no frame of the model (the body keeps the name)", f"site {site!r}")
        elif site:
            builder.add_body(site, jt.Fixed(), parent=_body_name(body, body_names), placement=poses[geoms + s],
                             joint_name=_FIXED + site)
    builder.equality_constraints += _equalities(mujoco, m, body_names, joint_names, object_name, report)
    return builder.build(check_inertia=False, hidden=hidden)


#: The compiled arrays the model is made of, by the element their rows belong to.
_READ = {"body": ("body_pos", "body_quat", "body_mass", "body_ipos", "body_iquat", "body_inertia"),
         "joint": ("jnt_pos", "jnt_axis", "jnt_range"), "dof": ("dof_damping", "dof_frictionloss", "dof_armature"),
         "site": ("site_pos", "site_quat"), "geom": ("geom_pos", "geom_quat", "geom_size"), "equality": ("eq_data",)}


def _check_magnitudes(mujoco, m, object_name):
    """Refuse compiled numbers that are not finite or past ``LARGEST_MAGNITUDE`` (MuJoCo compiles a NaN it reads,
    and sizes and densities within its bounds can make masses past ours, such as a sphere of radius 1e20 m),
    where the dynamics would overflow: a ``ValueError`` naming the element and the array."""
    arrays = [(kind, field, getattr(m, field)) for kind, fields in _READ.items() for field in fields]
    arrays += [("option", "gravity", m.opt.gravity[None]), ("joint", "qpos0", m.qpos0[:, None])]
    # (one pass over all the numbers; the element is looked for only when one fails)
    if np.abs(np.concatenate([values for _, _, values in arrays], axis=None)).max() <= LARGEST_MAGNITUDE:
        return
    for kind, field, values in arrays:
        bad = np.flatnonzero(~np.all(np.abs(values) <= LARGEST_MAGNITUDE, axis=tuple(range(1, values.ndim))))
        if len(bad):
            k = bad[0]
            if kind == "dof":
                kind, k = "joint", m.dof_jntid[k]
            elif field == "qpos0":
                k = np.flatnonzero(m.jnt_qposadr <= k)[-1]
            label = object_name(getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}"), int(k)) if kind != "option" else ""
            element = "<option>" if kind == "option" else f"{kind} {label!r}" if label else f"{kind} {int(k)}"
            raise ValueError(f"{element}: {field} {np.array2string(values[bad[0]], precision=3)}: not finite or of "
                             f"magnitude above {LARGEST_MAGNITUDE:g}, the largest accepted (the dynamics would overflow)")


def _unique_names(names, prefix, first):
    """``names`` with each empty one replaced by ``prefix`` and its MuJoCo id (``first`` the id of the first),
    ``_`` appended while the name is taken."""
    taken = set(names) | {"world"}
    out = []
    for k, name in enumerate(names):
        if not name:
            name = f"{prefix}{k + first}"
            while name in taken:
                name += "_"
            taken.add(name)
        out.append(name)
    return out


def _report_left_out(mujoco, m, report):
    """Each kind of thing MuJoCo compiled that the dynamics leaves out, to ``report``."""
    def named(kind, k, what):
        name = mujoco.mj_id2name(m, kind, k)
        return f"{what} {name!r}" if name else f"{what} {k}"

    obj = mujoco.mjtObj
    for count, kind, what, text in (
            (m.nu, obj.mjOBJ_ACTUATOR, "actuator", "actuators are not modelled: give the joint forces as tau"),
            (m.ntendon, obj.mjOBJ_TENDON, "tendon", "tendons are not modelled"),
            (m.nplugin, obj.mjOBJ_PLUGIN, "plugin", "plugins are not supported"),
            (m.nflex, obj.mjOBJ_FLEX, "flex", "flexes are not supported")):
        if count:
            report.add(text, named(kind, 0, what), count)
    ball, opt = int(mujoco.mjtJoint.mjJNT_BALL), m.opt
    for values, kind, what, text in (
            (m.jnt_stiffness, obj.mjOBJ_JOINT, "joint", "joint springs (stiffness, springdamper) are not modelled"),
            (m.body_gravcomp, obj.mjOBJ_BODY, "body", "gravity compensation (gravcomp) is not modelled"),
            (m.jnt_limited & (m.jnt_type == ball), obj.mjOBJ_JOINT, "joint",
             "a ball joint's range (a cone around its reference) is not modelled")):
        ids = [k for k, x in enumerate(values.tolist()) if x]
        if ids:
            report.add(text, named(kind, ids[0], what), len(ids))
    if opt.density or opt.viscosity or any(opt.wind.tolist()):
        report.add("fluid forces (wind, density, viscosity) are not modelled", "<option>")


#: the start of the names of what the builder needs named and the model does not show: the fixed joints of
#: bodies and sites, and the bodies between the joints of one MuJoCo body (no MuJoCo name holds it)
_FIXED = "\x00"


@functools.cache
def _kinds(enum):
    """``{code: name}`` of a MuJoCo enum's members, each name in lower case after its prefix (``mjJNT_HINGE``: hinge)."""
    return {int(code): name.partition("_")[2].lower() for name, code in enum.__members__.items()}


def _pose(quat, pos):
    """The poses ``(..., 4, 4)`` of MuJoCo's quaternions ``(..., 4)`` ``(w, x, y, z)`` and positions ``(..., 3)``."""
    return spatial.pose_matrix(spatial.quat_to_rotation(np.asarray(quat)[..., [1, 2, 3, 0]]), pos)


def _translation(p):
    """The pose ``(4, 4)`` that shifts by ``p (3,)`` (m) without turning."""
    return spatial.pose_matrix(np.eye(3), p)


def _add_bodies(mujoco, builder, m, body_names, joint_names, poses, principal):
    """MuJoCo's bodies and joints into ``builder``, given the bodies' ``poses (nbody, 4, 4)`` in their parents and
    ``principal (nbody, 3, 3)`` axes of inertia; returns the names of the bodies it adds between the joints of
    one MuJoCo body (to drop from the model)."""
    types, jnt_pos, refs = [_kinds(mujoco.mjtJoint)[t] for t in m.jnt_type.tolist()], m.jnt_pos, m.qpos0[m.jnt_qposadr]
    # B_k = B_{k−1} T(p_k) M_k(q_k − ref_k) T(−p_k): joint k's pre-joint frame is T(p_k − p_{k−1}) R_k(−ref_k)
    # in the frame of joint k − 1 (the body's frame B for k = 1), and the body hangs T(−p_n) from the last;
    # all joints' at once (a stacked matrix product gives each the numbers of its own)
    first = m.body_jntadr[m.jnt_bodyid] == np.arange(m.njnt)
    X = _translation(np.concatenate((jnt_pos - np.where(first[:, None], 0.0, jnt_pos[np.arange(-1, m.njnt - 1)]),
                                     -jnt_pos)))
    X, ends = X[: m.njnt], X[m.njnt :]
    hinge = (m.jnt_type == int(mujoco.mjtJoint.mjJNT_HINGE)) & (refs != 0.0)
    if hinge.any():
        X[hinge] = X[hinge] @ spatial.pose_matrix(spatial.axis_angle_rotation(m.jnt_axis[hinge], -refs[hinge]), np.zeros(3))
    if "slide" in types:
        slide = m.jnt_type == int(mujoco.mjtJoint.mjJNT_SLIDE)
        X[slide] = X[slide] @ _translation(-refs[slide, None] * m.jnt_axis[slide])
    placements = np.where(first[:, None, None], poses[m.jnt_bodyid], _IDENTITY) @ X
    # I = R diag(moments) Rᵀ, R the principal axes (body_iquat), of all bodies at once
    rotational = (principal * m.body_inertia[:, None, :]) @ np.swapaxes(principal, 1, 2)
    moved, limited, ranges = jnt_pos.any(axis=1).tolist(), m.jnt_limited.tolist(), m.jnt_range.tolist()
    # each joint's damping, friction and armature: numbers for one coordinate, lists for more
    nv, per_dof = {"free": 6, "ball": 3, "slide": 1, "hinge": 1}, {
        "damping": m.dof_damping.tolist(), "friction": m.dof_frictionloss.tolist(), "armature": m.dof_armature.tolist()}
    dynamics = [{key: v[d] if nv[t] == 1 else v[d : d + nv[t]] for key, v in per_dof.items()}
                for t, d in zip(types, m.jnt_dofadr.tolist())]
    hidden = set()
    for b, mass, com, mocap, parent_id, j0, count in zip(
            range(1, m.nbody), m.body_mass[1:], m.body_ipos[1:], m.body_mocapid[1:].tolist(),
            m.body_parentid[1:].tolist(), m.body_jntadr[1:].tolist(), m.body_jntnum[1:].tolist()):
        body, inertia = body_names[b - 1], Inertia(mass, com, rotational[b])
        parent = None if mocap >= 0 else _body_name(parent_id, body_names)
        if count and types[j0] == "free":
            # (MuJoCo allows a free joint alone, in a body whose parent is the world)
            builder.add_body(body, jt.FreeFlyer(), parent=None, placement=_IDENTITY, inertia=inertia,
                             joint_name=joint_names[j0], **dynamics[j0])
            continue
        for j in range(j0, j0 + count):
            try:
                # (MuJoCo compiles an axis whose square overflows to zero)
                joint = jt.Spherical() if types[j] == "ball" else {"hinge": jt.Revolute, "slide": jt.Prismatic}[types[j]](m.jnt_axis[j])
            except ValueError as error:
                raise ValueError(f"joint {joint_names[j]!r}: {error}") from None
            carrier = body if j == j0 + count - 1 and not moved[j] else f"{_FIXED}{b}:{j}"
            if carrier != body:
                hidden.add(carrier)
            lower, upper = (ranges[j][:1], ranges[j][1:]) if types[j] != "ball" and limited[j] else (None, None)
            builder.add_body(carrier, joint, parent=parent, placement=placements[j], joint_name=joint_names[j],
                             lower=lower, upper=upper, inertia=inertia if carrier == body else None, **dynamics[j])
            parent = carrier
        if parent != body:  # (a body without joints, or one that hangs from its last joint)
            builder.add_body(body, jt.Fixed(), parent=parent, placement=ends[j] if count else poses[b], inertia=inertia,
                             joint_name=_FIXED + body)
    return hidden


class _MeshFiles:
    """Where the viewer finds each compiled mesh's file, and how it is placed in the compiled geom frame."""

    def __init__(self, spec, m, found):
        self.spec, self.m, self.found = spec, m, found
        self.base = spec.modelfiledir or os.getcwd()

    def drawn(self, k, report):
        """``(uri, filename, scale, placement (4, 4))`` of mesh ``k`` drawn as its file scaled, then placed in the
        geom frame (``None`` for a mesh without a file; ``filename`` ``None``, told to ``report``, where the file
        MuJoCo read is not found again).

        MuJoCo compiles a file's vertices ``v`` into ``Rₘᵀ (S R_refᵀ (v − p_ref) − pₘ)`` (``S`` the scale, ``pₘ``,
        ``Rₘ`` its ``mesh_pos``, ``mesh_quat``); where ``S`` and ``R_ref`` commute (``S`` uniform or
        ``refquat`` the identity) that is the placement ``T(pₘ, Rₘ)⁻¹ (R_refᵀ, −S R_refᵀ p_ref)`` of ``S v``;
        otherwise the drawing is approximate (a warning says so)."""
        mesh = self.spec.meshes[k]
        if not mesh.file:
            return None
        uri = mesh.file if os.path.isabs(mesh.file) else os.path.join(self.spec.meshdir, mesh.file)
        filename = self.found.get(uri) or resolve_file(uri, self.base, [])
        if filename is None:
            report.add("a mesh whose file MuJoCo read but the viewer does not find there is not drawn",
                       f"mesh {mesh.name!r}, looked for at {os.path.join(self.base, uri)}")
        scale = np.asarray(self.m.mesh_scale[k], dtype=float)
        refquat = np.asarray(mesh.refquat, dtype=float)
        if not np.allclose(scale, scale[0]) and np.any(refquat[1:]):
            report.add("a mesh scaled unevenly and turned by refquat is drawn approximately", f"mesh {mesh.name!r}")
        turn = spatial.quat_to_rotation(refquat[[1, 2, 3, 0]]).T  # (MuJoCo's (w, x, y, z), of any norm)
        placement = np.linalg.inv(_pose(self.m.mesh_quat[k], self.m.mesh_pos[k])) @ spatial.pose_matrix(
            turn, -scale * (turn @ np.asarray(mesh.refpos, dtype=float)))
        return mesh.file, filename, tuple(float(s) for s in scale), placement

    def hull(self, k):
        """The convex hull's vertices ``(h, 3)`` of compiled mesh ``k`` in the geom frame, m."""
        start = self.m.mesh_vertadr[k]
        return hull_vertices(self.m.mesh_vert[start : start + self.m.mesh_vertnum[k]])


#: the viewer's dimensions of MuJoCo's geom sizes (radii, half-lengths and half-extents)
_SIZES = {"sphere": lambda s: (s[0],), "capsule": lambda s: (s[0], 2.0 * s[1]),
          "cylinder": lambda s: (s[0], 2.0 * s[1]), "ellipsoid": lambda s: tuple(s), "box": lambda s: tuple(2.0 * s)}


def _add_geoms(mujoco, builder, m, poses, body_names, meshes, report):
    """The geoms of bodies (at ``poses (ngeom, 4, 4)`` in them) as the viewer's shapes and, those that collide, as
    collision shapes."""
    for g, (b, shape, group, k, collides, size, pose) in enumerate(zip(
            m.geom_bodyid.tolist(), m.geom_type.tolist(), m.geom_group.tolist(), m.geom_dataid.tolist(),
            ((m.geom_contype != 0) | (m.geom_conaffinity != 0)).tolist(), m.geom_size, poses)):
        if b == 0:
            continue
        body, shape, kind = body_names[b - 1], _kinds(mujoco.mjtGeom)[shape], "visual" if group <= 2 else "collision"
        if shape == "mesh":
            drawn = meshes.drawn(k, report)
            if drawn is not None:
                uri, filename, scale, placement = drawn
                builder.add_geometry(Geometry(body, kind, "mesh", pose @ placement, uri=uri, filename=filename,
                                              scale=scale))
        elif shape in _SIZES:
            dimensions = _SIZES[shape](size)
            builder.add_geometry(Geometry(body, kind, shape, pose, size=dimensions))
        if not collides:
            continue
        if shape in ("sphere", "box", "capsule", "cylinder"):
            builder.add_collision_geometry(Geometry(body, "collision", shape, pose, size=dimensions))
        elif shape == "mesh":
            try:
                vertices = meshes.hull(k)
            except ValueError as problem:
                report.add(f"a mesh without a convex hull is left out of the collision geometries: its vertices "
                           f"{problem}", f"mesh {meshes.spec.meshes[k].name!r}")
                continue
            builder.add_collision_geometry(Geometry(body, "collision", "convex", pose, vertices=vertices))
        else:
            report.add(f"{shape} geoms of bodies are left out of the collision geometries (contact detection has no "
                       "such shape)", f"geom {g} of body {body!r}")


def _equalities(mujoco, m, body_names, joint_names, object_name, report):
    """The built-in constraints of MuJoCo's compiled equalities (module docstring)."""
    out = []
    for e in range(m.neq):
        kind = _kinds(mujoco.mjtEq)[m.eq_type[e]]
        label = object_name(mujoco.mjtObj.mjOBJ_EQUALITY, e) or f"{kind} equality {e}"
        if kind not in ("connect", "weld", "joint"):
            report.add(f"{kind} equalities are left out", f"equality {label!r}")
            continue
        if not m.eq_active0[e]:
            report.add("inactive equalities (active='false') are left out", f"equality {label!r}")
            continue
        first, second, data = m.eq_obj1id[e], m.eq_obj2id[e], m.eq_data[e]
        if kind == "joint":
            # q₁ − q₁,ref = Σ cₖ (q₂ − q₂,ref)ᵏ, q_ref MuJoCo's qpos0 (the joints' ref)
            c = data[:5].copy()
            c[0] += m.qpos0[m.jnt_qposadr[first]]
            reference = 0.0 if second < 0 else m.qpos0[m.jnt_qposadr[second]]
            out.append(JointCoupling(None if second < 0 else joint_names[second], joint_names[first], coefficients=c,
                                     reference=reference, name=label))
            continue
        if m.eq_objtype[e] == int(mujoco.mjtObj.mjOBJ_SITE):
            # the two site frames coincide (in position for connect, in pose for weld)
            (body_a, frame_a), (body_b, frame_b) = ((_body_name(m.site_bodyid[k], body_names),
                                                     _pose(m.site_quat[k], m.site_pos[k])) for k in (first, second))
        else:
            body_a, body_b = (_body_name(b, body_names) for b in (first, second))
            if kind == "connect":
                # the anchor in body1, and body2's point where the anchor is at qpos0
                frame_a, frame_b = _translation(data[:3]), _translation(data[3:6])
            else:
                # body2's anchor at relpose in body1 (MuJoCo's compiler sets it from qpos0 where the file has none)
                frame_a, frame_b = _pose(data[6:10], data[3:6]), _translation(data[:3])
        out.append(LoopClosure(body_a, body_b, frame_a=frame_a, frame_b=frame_b,
                               kind="point" if kind == "connect" else "weld", name=label))
    return out


def _body_name(b, body_names):
    """The model's name of MuJoCo's body ``b`` (``None`` for the world, which ``-1``, a missing body, also is)."""
    return None if b <= 0 else body_names[b - 1]


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
