"""``mb.load_mjcf``: MuJoCo's model format, checked against MuJoCo itself (and Pinocchio as a third opinion).

Every comparison goes through :func:`multibody.check.compare_with_mujoco`: MuJoCo's model with contacts,
limits, equalities, friction loss, springs, dampers and actuators off, at random states, its free joints'
coordinates mapped to ours; ``M``, ``h``, inverse and forward dynamics, placements of bodies and sites and
the bodies' Jacobians must agree to ``MUJOCO_TOLERANCE`` (1e-10 relative; forward dynamics
``max(1e-10, 10 κ(M) ε)``).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody.check import MUJOCO_TOLERANCE, compare_with_mujoco
from multibody.mjcf import MJCFError, load_mjcf

mujoco = pytest.importorskip("mujoco")

GYMNASIUM_MODELS = ("ant", "half_cheetah", "hopper", "humanoid", "humanoidstandup", "inverted_pendulum",
                    "inverted_double_pendulum", "pusher", "reacher", "swimmer", "walker2d")


def gymnasium_model(name):
    spec = importlib.util.find_spec("gymnasium")
    if spec is None:
        pytest.skip("gymnasium is not installed")
    return os.path.join(os.path.dirname(spec.origin), "envs", "mujoco", "assets", f"{name}.xml")


def gym_hil_panda():
    """gym-hil's Panda with the Robotiq 2F-85 gripper (found without importing gym_hil, whose dependencies
    are heavy and not installed with it)."""
    spec = importlib.util.find_spec("gym_hil")
    if spec is None:
        pytest.skip("gym-hil is not installed (pip install --no-deps gym-hil)")
    path = os.path.join(spec.submodule_search_locations[0], "assets", "panda.xml")
    if not os.path.isfile(path):
        pytest.skip(f"gym-hil has no {path}")
    return path


@pytest.fixture(autouse=True)
def _in_tmp_path(tmp_path, monkeypatch):
    # MuJoCo writes its warnings (settotalmass is deprecated) to MUJOCO_LOG.TXT in the working directory
    monkeypatch.chdir(tmp_path)


def quietly(function, *args, **kwargs):
    """``function(*args, **kwargs)`` without the warnings about what the model leaves out (actuators, springs)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return function(*args, **kwargs)


def assert_agrees_with_mujoco(source, samples=10, seed=0):
    model, rows, _ = quietly(compare_with_mujoco, source, samples=samples, seed=seed)
    failed = [f"{row.quantity}: {row.error:.2e} > {row.tolerance:.1e}" for row in rows if not row.ok]
    assert not failed, "; ".join(failed)
    names = {row.quantity for row in rows}
    assert {"body placements", "jacobian", "mass matrix (crba)", "bias h(q, v)", "inverse dynamics",
            "forward dynamics"} <= names
    return model, rows


def mujoco_names(reference, kind, count, first=0):
    return [mujoco.mj_id2name(reference, kind, k) for k in range(first, count)]


# ============================================================================= the gymnasium models


@pytest.mark.parametrize("name", GYMNASIUM_MODELS)
def test_gymnasium_model_agrees_with_mujoco(name):
    """Each of gymnasium's MuJoCo models: the dynamics (armature included) at random states, the joints'
    and bodies' names in MuJoCo's order, and the joint parameters (limits in radians, damping, friction
    loss, armature) as MuJoCo compiles them."""
    path = gymnasium_model(name)
    model, _ = assert_agrees_with_mujoco(path)
    reference = mujoco.MjModel.from_xml_path(path)
    assert list(model.joint_names) == mujoco_names(reference, mujoco.mjtObj.mjOBJ_JOINT, reference.njnt)
    bodies = [n or f"body_{k + 1}" for k, n in enumerate(mujoco_names(reference, mujoco.mjtObj.mjOBJ_BODY,
                                                                        reference.nbody, 1))]
    assert list(model.body_names[: reference.nbody - 1]) == bodies
    assert np.allclose(model.armature, reference.dof_armature, rtol=0, atol=0)
    assert np.array_equal(model.damping, reference.dof_damping)
    assert np.array_equal(model.friction, reference.dof_frictionloss)
    assert np.allclose(model.gravity, reference.opt.gravity, rtol=0, atol=0)
    for j in range(reference.njnt):
        if reference.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            iq = reference.jnt_qposadr[j]
            expected = reference.jnt_range[j] if reference.jnt_limited[j] else (-np.inf, np.inf)
            np.testing.assert_allclose((model.lower[iq], model.upper[iq]), expected, rtol=1e-15, atol=0)


@pytest.mark.parametrize("name", GYMNASIUM_MODELS)
def test_gymnasium_actuators_do_nothing_at_zero_control(name):
    """The comparison turns MuJoCo's actuators off; with their flag on and zero control they add no force
    either (all of gymnasium's are motors), so nothing is hidden by turning them off."""
    reference = mujoco.MjModel.from_xml_path(gymnasium_model(name))
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(1)
    data.qpos[:] = reference.qpos0 + 0.1 * rng.standard_normal(reference.nq)
    data.qvel[:] = rng.standard_normal(reference.nv)
    data.ctrl[:] = 0.0
    mujoco.mj_forward(reference, data)
    assert reference.nu > 0
    assert np.all(data.qfrc_actuator == 0.0)


PINOCCHIO_DIFFERS = {
    "half_cheetah": "Pinocchio does not apply the compiler's settotalmass",
    "swimmer": "Pinocchio gives the geoms of swimmer.xml no mass (density on the geoms)",
    "pusher": "Pinocchio keeps only the first of the file's kinematic trees",
    "reacher": "Pinocchio keeps only the first of the file's kinematic trees",
}


@pytest.mark.parametrize("name", GYMNASIUM_MODELS)
def test_mass_matrix_agrees_with_pinocchio(name, pin):
    """Pinocchio's ``buildModelFromMJCF`` as a third opinion where it reads the file as MuJoCo does: the mass
    matrix at random states (Pinocchio's armature set to ours: its parser does not read every file's)."""
    if name in PINOCCHIO_DIFFERS:
        pytest.skip(PINOCCHIO_DIFFERS[name])
    path = gymnasium_model(name)
    try:
        reference = pin.buildModelFromMJCF(path)
    except Exception as error:  # noqa: BLE001 (whatever Pinocchio's parser raises)
        pytest.skip(f"Pinocchio cannot load {name}: {error}")
    model = quietly(load_mjcf, path)
    assert (reference.nq, reference.nv) == (model.nq, model.nv)
    reference.armature[:] = model.armature
    data = reference.createData()
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = model.random_configuration(rng)
        M_pin = pin.crba(reference, data, q)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        M = mb.mass_matrix(model, q)
        assert np.abs(M - M_pin).max() <= MUJOCO_TOLERANCE * np.abs(M_pin).max()


# ============================================================================= the format, feature by feature


def write_model(tmp_path, text, name="model.xml"):
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))
    return str(path)


def write_meshes(tmp_path):
    """``meshes/block.stl`` (a box, binary STL) and ``meshes/ell.obj`` (an L-shaped prism: not convex, and
    not star-shaped about its faces' centroid, so that MuJoCo's four mesh inertias differ)."""
    import trimesh

    folder = tmp_path / "meshes"
    folder.mkdir(exist_ok=True)
    trimesh.creation.box(extents=(0.1, 0.06, 0.04)).export(folder / "block.stl")
    # the L (counter-clockwise) at z = 0 and z = 0.08; caps split into four triangles inside the L, sides
    # wound so that every normal points out
    profile = [(0.0, 0.0), (0.3, 0.0), (0.3, 0.05), (0.05, 0.05), (0.05, 0.2), (0.0, 0.2)]
    vertices = [(x, y, 0.0) for x, y in profile] + [(x, y, 0.08) for x, y in profile]
    fan = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)]
    faces = [(a + 6, b + 6, c + 6) for a, b, c in fan] + [(a, c, b) for a, b, c in fan]
    for i in range(6):
        j = (i + 1) % 6
        faces += [(i, j, j + 6), (i, j + 6, i + 6)]
    ell = trimesh.Trimesh(vertices, faces, process=False)
    assert ell.is_watertight and ell.volume > 0.0
    ell.export(folder / "ell.obj")
    return folder


FEATURES = """\
    <mujoco model="features">
      <compiler angle="degree" eulerseq="zyx" meshdir="meshes"/>
      <option gravity="0.5 -0.3 -9.7"/>
      <default>
        <joint damping="0.3" armature="0.02"/>
        <geom density="800"/>
        <default class="light">
          <geom density="300" rgba="1 0 0 1"/>
          <joint frictionloss="0.1" armature="0.05"/>
          <default class="lighter">
            <geom density="100"/>
          </default>
        </default>
      </default>
      <asset>
        <mesh name="block" file="block.stl" scale="1 2 0.5"/>
        <mesh name="ell" file="ell.obj"/>
        <mesh name="ell_exact" file="ell.obj" inertia="exact"/>
        <mesh name="ell_convex" file="ell.obj" inertia="convex"/>
        <mesh name="ell_shell" file="ell.obj" inertia="shell"/>
      </asset>
      <worldbody>
        <geom type="plane" size="5 5 0.1"/>
        <site name="world_site" pos="0.1 0.2 0.3" euler="10 20 30"/>
        <frame pos="0.1 0 0.2" euler="0 0 30" childclass="light">
          <body name="base" pos="0 0 1" quat="0.9 0.1 -0.2 0.3">
            <freejoint name="root"/>
            <geom type="box" size="0.2 0.1 0.05"/>
            <geom type="ellipsoid" size="0.1 0.05 0.08" pos="0.1 0 0" axisangle="1 1 0 30"/>
            <site name="base_site" pos="0.1 0.1 0" xyaxes="0 1 0 -1 0 0.2"/>
            <body name="arm" pos="0.2 0 0" zaxis="1 1 1">
              <joint name="shoulder_x" axis="1 0 0" pos="0 0 0.05" range="-60 60" ref="10"/>
              <joint name="shoulder_y" axis="0 1 0.2" pos="0.02 0 0" ref="-5"/>
              <joint type="slide" axis="0 0 1" pos="0 0.01 0" ref="0.03" range="-0.1 0.2"/>
              <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" class="lighter"/>
              <geom type="cylinder" size="0.02 0.1" pos="0.15 0 0.05" euler="10 20 30"/>
              <frame pos="0.3 0 0" quat="0 0 0 1">
                <body name="hand">
                  <joint name="wrist" type="ball" pos="0.01 0 0"/>
                  <geom type="sphere" size="0.04"/>
                  <geom type="box" fromto="0 0 0 0 0 0.1" size="0.02"/>
                  <geom type="ellipsoid" fromto="0 0 0 0.1 0.05 0" size="0.02"/>
                  <geom type="mesh" mesh="block" pos="0 0 0.2" euler="5 10 15"/>
                  <site name="tool" pos="0 0 0.25" zaxis="0 -1 0"/>
                </body>
              </frame>
            </body>
            <body name="plate" pos="-0.2 0 0">
              <joint name="plate_hinge" axis="0 0 1"/>
              <inertial pos="0.01 0.02 0.03" mass="0.7" fullinertia="0.02 0.03 0.04 0.001 -0.002 0.003"/>
              <geom type="mesh" mesh="ell"/>
            </body>
            <body>
              <joint axis="0 1 0" pos="0 0 -0.1"/>
              <inertial pos="0 0 -0.2" mass="1.5" diaginertia="0.01 0.02 0.025" euler="10 0 40"/>
            </body>
          </body>
        </frame>
        <body name="ells" pos="1 0 0">
          <joint name="ells_x" type="slide" axis="1 0 0"/>
          <geom type="mesh" mesh="ell"/>
          <body name="ell_exact" pos="0 0.5 0">
            <joint name="exact_z" axis="0 0 1"/>
            <geom type="mesh" mesh="ell_exact" euler="30 0 0"/>
          </body>
          <body name="ell_convex" pos="0 1 0">
            <joint name="convex_y" axis="0 1 0"/>
            <geom type="mesh" mesh="ell_convex" pos="0.1 0 0"/>
          </body>
          <body name="ell_shell" pos="0 1.5 0">
            <joint name="shell_x" axis="1 0 0"/>
            <geom type="mesh" mesh="ell_shell" mass="0.3"/>
          </body>
        </body>
        <include file="parts/pendulum.xml"/>
      </worldbody>
    </mujoco>
"""

PENDULUM = """\
    <mujoco>
      <body name="pendulum" pos="1 1 1">
        <joint name="swing" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05" mass="2"/>
        <site name="bob" pos="0 0 -0.5"/>
      </body>
    </mujoco>
"""


@pytest.fixture
def features(tmp_path):
    write_meshes(tmp_path)
    write_model(tmp_path, PENDULUM, "parts/pendulum.xml")
    return write_model(tmp_path, FEATURES)


def test_every_feature_agrees_with_mujoco(features):
    """Defaults (nested, ``childclass``), ``<frame>``, ``<include>``, every orientation form with
    ``eulerseq``, ``fromto`` capsules, boxes and ellipsoids, each primitive's and mesh's mass from a
    density (MuJoCo's legacy, exact, convex and shell mesh inertias; a mesh's scale), ``<inertial>`` with
    ``diaginertia`` (turned) and ``fullinertia``, several joints in one body about their own points with
    ``ref``, ball and free joints, sites, an unnamed body and joint, and gravity: the model is MuJoCo's."""
    model, rows = assert_agrees_with_mujoco(features)
    assert "site placements" in {row.quantity for row in rows}
    reference = mujoco.MjModel.from_xml_path(features)
    for k in range(1, reference.nbody):
        assert model.body_inertias[k - 1].mass == pytest.approx(reference.body_mass[k], rel=1e-12)
    assert [type(joint).__name__ for joint in model.joints] == [
        "FreeFlyer", "Revolute", "Revolute", "Prismatic", "Spherical", "Revolute", "Revolute", "Prismatic",
        "Revolute", "Revolute", "Revolute", "Revolute"]
    assert model.joint_names[3] == "joint_3" and model.body_names[4] == "body_5"
    assert list(model.body_names[reference.nbody - 1:]) == ["world_site", "base_site", "tool", "bob"]


def test_mesh_inertias_follow_mujocos_four_rules(features):
    """The L-shaped mesh's mass and inertia under MuJoCo's legacy, exact, convex and shell rules, against MuJoCo
    (single-precision vertices on both sides), and the four rules give four different bodies."""
    model = quietly(load_mjcf, features)
    reference = mujoco.MjModel.from_xml_path(features)
    masses = []
    for name in ("ells", "ell_exact", "ell_convex", "ell_shell"):
        k = reference.body(name).id
        inertia = model.body_inertias[model.body_index(name)]
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, reference.body_iquat[k])
        R = R.reshape(3, 3)
        expected = R @ np.diag(reference.body_inertia[k]) @ R.T
        assert inertia.mass == pytest.approx(reference.body_mass[k], rel=1e-12)
        np.testing.assert_allclose(inertia.com, reference.body_ipos[k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(inertia.rotational, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        masses.append(inertia.mass)
    assert len(set(np.round(masses[:3], 9))) == 3


COMPILER_OPTIONS = """\
    <mujoco>
      <compiler angle="radian" eulerseq="XYZ" settotalmass="7.5" boundmass="0.2" boundinertia="0.003"
                balanceinertia="true" inertiagrouprange="0 2" autolimits="false"/>
      <worldbody>
        <body name="a" euler="0.1 0.2 0.3">
          <joint name="a" axis="1 0 0" limited="true" range="-1 1.5" ref="0.2"/>
          <geom type="box" size="0.1 0.2 0.3"/>
          <geom type="sphere" size="0.5" group="3"/>
          <body name="b" pos="0 0 -0.5">
            <joint name="b" axis="0 1 0" limited="false" range="-3 3"/>
            <inertial pos="0 0 -0.1" mass="0.05" diaginertia="0.001 0.001 0.004"/>
            <body name="c" pos="0 0 -0.3">
              <joint name="c" type="slide" axis="0 0 1"/>
            </body>
          </body>
        </body>
      </worldbody>
    </mujoco>
"""


def test_compiler_mass_options_agree_with_mujoco():
    """``settotalmass``, ``boundmass``, ``boundinertia``, ``balanceinertia`` (an inertia that breaks A + B ≥ C),
    ``inertiagrouprange`` (a geom of group 3 left out), ``angle="radian"``, extrinsic ``eulerseq`` and
    ``autolimits="false"``: MuJoCo's masses and dynamics."""
    model, _ = assert_agrees_with_mujoco(COMPILER_OPTIONS)
    reference = mujoco.MjModel.from_xml_string(COMPILER_OPTIONS)
    np.testing.assert_allclose([inertia.mass for inertia in model.body_inertias], reference.body_mass[1:], rtol=1e-13)
    assert model.total_mass == pytest.approx(7.5, rel=1e-14)
    assert (model.lower[0], model.upper[0]) == (-1.0, 1.5)
    assert np.isinf(model.upper[1])


@pytest.mark.parametrize("setting", ["true", "false", "auto"])
def test_inertia_from_geoms_setting(setting):
    """``inertiafromgeom``: ``"true"`` replaces an ``<inertial>`` by the body's geoms (a body without geoms
    keeps its own), ``"false"`` ignores the geoms (a body with geoms alone is massless), ``"auto"`` uses them
    where there is no ``<inertial>``; each as MuJoCo compiles it."""
    text = f"""
    <mujoco>
      <compiler inertiafromgeom="{setting}"/>
      <worldbody>
        <body name="a">
          <joint axis="0 1 0"/>
          <inertial pos="0 0 -0.2" mass="1" diaginertia="0.01 0.01 0.01"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.05"/>
          <body name="b" pos="0 0 -0.4">
            <geom type="sphere" size="0.1"/>
            <body name="c" pos="0 0 -0.1">
              <joint axis="1 0 0"/>
              <inertial pos="0 0 -0.1" mass="0.5" diaginertia="0.002 0.002 0.001"/>
            </body>
          </body>
        </body>
      </worldbody>
    </mujoco>"""
    model, _ = assert_agrees_with_mujoco(text)
    reference = mujoco.MjModel.from_xml_string(text)
    masses = [inertia.mass for inertia in model.body_inertias]
    np.testing.assert_allclose(masses, reference.body_mass[1:], rtol=1e-13)
    capsule = 1000.0 * np.pi * 0.05**2 * (0.4 + 4.0 / 3.0 * 0.05)
    assert masses[0] == pytest.approx(capsule if setting == "true" else 1.0, rel=1e-14)
    assert (masses[1] == 0.0) == (setting == "false")
    assert masses[2] == 0.5


def test_gravity_flag_and_geometries(features, tmp_path):
    """``<flag gravity="disable"/>`` zeroes gravity; the geoms are the viewer's shapes, each placed where
    MuJoCo places it (primitives; a mesh's frame is MuJoCo's after it re-centres the mesh) with its
    dimensions (full lengths, radii), groups 0–2 visual, the world's plane left out."""
    text = open(features).read().replace('<option gravity="0.5 -0.3 -9.7"/>',
                                         '<option gravity="0.5 -0.3 -9.7"><flag gravity="disable"/></option>')
    path = write_model(tmp_path, text, "no_gravity.xml")
    assert np.array_equal(quietly(load_mjcf, path).gravity, np.zeros(3))
    model = quietly(load_mjcf, features)
    reference = mujoco.MjModel.from_xml_path(features)
    data = mujoco.MjData(reference)
    mujoco.mj_kinematics(reference, data)
    placements = mb.forward_kinematics(model, quietly(mb.mjcf.from_mujoco, model, reference.qpos0,
                                                      np.zeros(reference.nv))[0])
    primitives = [g for g in model.geometries if g.shape != "mesh"]
    geoms = [k for k in range(reference.ngeom) if reference.geom_bodyid[k] > 0
             and reference.geom_type[k] != mujoco.mjtGeom.mjGEOM_MESH]
    assert len(primitives) == len(geoms)
    assert all(g.kind == "visual" for g in model.geometries)
    full = {"sphere": lambda s: s[:1], "capsule": lambda s: (s[0], 2 * s[1]), "cylinder": lambda s: (s[0], 2 * s[1]),
            "ellipsoid": lambda s: s, "box": lambda s: 2 * s}
    for geometry, k in zip(primitives, geoms):
        world = placements[model.body_index(geometry.body)] @ geometry.placement
        np.testing.assert_allclose(world[:3, 3], data.geom_xpos[k], rtol=0, atol=1e-14)
        np.testing.assert_allclose(world[:3, :3], data.geom_xmat[k].reshape(3, 3), rtol=0, atol=1e-14)
        np.testing.assert_allclose(geometry.size, full[geometry.shape](reference.geom_size[k]), rtol=1e-15)
    meshes = [g for g in model.geometries if g.shape == "mesh"]
    assert [os.path.basename(g.filename) for g in meshes] == ["block.stl"] + ["ell.obj"] * 5
    assert meshes[0].scale == (1.0, 2.0, 0.5)


@pytest.mark.parametrize("scale", ["2 2 2", "1 2 0.5"])
def test_a_mesh_is_drawn_where_mujoco_compiles_its_vertices(tmp_path, scale):
    """A mesh's drawing, its file scaled at its placement, lies on MuJoCo's compiled vertices (re-centred at
    the mesh's inertial frame, then placed by the geom), with the file's ``refpos`` and ``refquat`` (an even
    scale) or an uneven scale without them (measured: 3e-10 and 1e-17 m)."""
    import trimesh

    write_meshes(tmp_path)
    turned = ' refpos="0.01 -0.02 0.03" refquat="0.9 0.1 -0.3 0.2"' if scale == "2 2 2" else ""
    path = write_model(tmp_path, f"""<mujoco><compiler meshdir="meshes"/>
        <asset><mesh name="block" file="block.stl" scale="{scale}"{turned}/></asset>
        <worldbody><body name="b"><joint/><geom type="mesh" mesh="block" pos="0.1 0 0" euler="10 20 30"/></body>
        </worldbody></mujoco>""")
    (geometry,) = load_mjcf(path).geometries
    reference = mujoco.MjModel.from_xml_path(path)
    drawn = trimesh.load(geometry.filename, force="mesh").vertices * geometry.scale
    drawn = drawn @ geometry.placement[:3, :3].T + geometry.placement[:3, 3]
    R = mb.spatial.quat_to_rotation(reference.geom_quat[0][[1, 2, 3, 0]])
    compiled = reference.mesh_vert @ R.T + reference.geom_pos[0]
    distances = np.linalg.norm(drawn[:, None] - compiled[None], axis=-1)
    tolerance = 4 * np.finfo(np.float32).eps * np.abs(compiled).max()  # (MuJoCo keeps its vertices in float32)
    assert distances.min(axis=0).max() < tolerance and distances.min(axis=1).max() < tolerance


def test_a_mesh_file_mujoco_read_that_the_viewer_does_not_find_warns(tmp_path):
    """MuJoCo reads an attached model's mesh from that model's folder and ``meshdir``; the viewer looks for it
    in the main file's folder, finds none, and leaves it undrawn (``filename`` ``None``), warning with the
    mesh's name and the path it tried."""
    (tmp_path / "arm").mkdir()
    write_meshes(tmp_path / "arm")
    write_model(tmp_path, """<mujoco><compiler meshdir="meshes"/><asset><mesh name="block" file="block.stl"/></asset>
        <worldbody><body name="link"><joint/><geom type="mesh" mesh="block"/></body></worldbody></mujoco>""",
                "arm/arm.xml")
    path = write_model(tmp_path, """<mujoco><asset><model name="arm" file="arm/arm.xml"/></asset>
        <worldbody><body name="base"><attach model="arm" prefix="a_"/></body></worldbody></mujoco>""")
    tried = os.path.join(mujoco.MjSpec.from_file(path).modelfiledir, "block.stl")
    with pytest.warns(UserWarning, match=f"^{re.escape(path)}: mesh 'a_block', looked for at {re.escape(tried)}: a "
                                         "mesh whose file MuJoCo read but the viewer does not find there is not drawn$"):
        model = load_mjcf(path)
    assert [(g.uri, g.filename) for g in model.geometries] == [("block.stl", None)]


def test_sites_are_frames(features):
    """A site is a named frame of the model: its placement and Jacobian by name, as MuJoCo's site."""
    model = quietly(load_mjcf, features)
    reference = mujoco.MjModel.from_xml_path(features)
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(4)
    q = model.random_configuration(rng)
    data.qpos[:], data.qvel[:] = mb.mjcf.to_mujoco(model, q, np.zeros(model.nv))
    mujoco.mj_kinematics(reference, data)
    mujoco.mj_comPos(reference, data)
    k = reference.site("tool").id
    X = mb.frame_placement(model, q, "tool")
    np.testing.assert_allclose(X[:3, 3], data.site_xpos[k], rtol=0, atol=1e-14)
    np.testing.assert_allclose(X[:3, :3], data.site_xmat[k].reshape(3, 3), rtol=0, atol=1e-14)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(reference, data, jacp, jacr, k)
    T = mb.mjcf.velocity_to_mujoco(model, q)
    np.testing.assert_allclose(mb.jacobian(model, q, "tool"), np.vstack([jacp, jacr]) @ T, rtol=0, atol=1e-14)


def test_string_source_resolves_meshes_and_includes_in_package_dirs(features, tmp_path, monkeypatch):
    """An XML string has no folder: its ``<include>``, ``meshdir`` and meshes resolve in ``package_dirs`` (or,
    without them, in the working directory)."""
    text = open(features).read()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    model = quietly(load_mjcf, text, package_dirs=[str(tmp_path)])
    assert model.nv == quietly(load_mjcf, features).nv
    assert all(g.filename is not None for g in model.geometries if g.shape == "mesh")
    with pytest.raises(MJCFError, match=r"^<MJCF string>: XML Error: Error opening file 'parts/pendulum.xml'\nElement "
                                        r"'include', line \d+"):
        quietly(load_mjcf, text)
    monkeypatch.chdir(tmp_path)
    assert quietly(load_mjcf, text).nv == model.nv


# ============================================================================= equalities

EQUALITIES = """\
    <mujoco model="equalities">
      <worldbody>
        <body name="crank" pos="0 0 1">
          <joint name="crank" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
          <body name="coupler" pos="0.3 0 0" euler="0 -30 0">
            <joint name="coupler" axis="0 1 0"/>
            <geom type="capsule" fromto="0 0 0 0.8 0 0" size="0.03"/>
            <site name="coupler_tip" pos="0.8 0 0" euler="10 20 30"/>
          </body>
        </body>
        <body name="rocker" pos="0.9 0 1">
          <joint name="rocker" axis="0 1 0" ref="20"/>
          <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.03"/>
        </body>
        <body name="box" pos="0.2 0.8 1.2" quat="0.9 0.1 0.3 0.2">
          <freejoint/>
          <geom type="box" size="0.1 0.2 0.3"/>
          <site name="box_corner" pos="0.1 0.2 0.3" quat="0 1 0 0"/>
        </body>
        <body name="arm" pos="0 -0.8 1">
          <joint name="arm" axis="1 0 0" ref="15"/>
          <geom type="capsule" fromto="0 0 0 0 0.4 0" size="0.03"/>
          <body name="slider" pos="0 0.4 0">
            <joint name="slide" type="slide" axis="0 1 0" ref="0.05"/>
            <geom type="box" size="0.05 0.05 0.05"/>
          </body>
        </body>
        <body name="hand" pos="0.3 -0.5 1.5">
          <joint name="hx" axis="1 0 0"/>
          <joint name="hy" axis="0 1 0" pos="0.1 0 0"/>
          <joint name="hz" axis="0 0 1" pos="0 0.1 0"/>
          <geom type="sphere" size="0.05"/>
        </body>
        <body name="target" mocap="true" pos="0.3 -0.3 1.5"/>
      </worldbody>
      <equality>
        <connect name="four-bar" body1="coupler" body2="rocker" anchor="0.8 0 0"/>
        <weld name="box to world" body1="box" torquescale="2"/>
        <joint name="gear" joint1="slide" joint2="arm" polycoef="0.01 0.05 -0.02 0.003 0.001"/>
        <weld name="sites" site1="box_corner" site2="coupler_tip"/>
        <connect name="hand" body1="hand" body2="target" anchor="0 0.2 0"/>
        <weld name="relpose" body1="crank" body2="box" relpose="0.1 0.2 0.3 0.8 0.1 0.2 0.3" anchor="0.01 0.02 0.03"/>
        <joint name="lock" joint1="hx"/>
        <connect body1="arm" anchor="0 0.4 0" active="false"/>
      </equality>
    </mujoco>
"""


def mujoco_equality_residuals(reference, model, q):
    """MuJoCo's position error ``efc_pos`` of each equality at our ``q`` (all its constraints on but contacts)."""
    data = mujoco.MjData(reference)
    data.qpos[:], data.qvel[:] = mb.to_mujoco(model, q, np.zeros(model.nv))
    mujoco.mj_forward(reference, data)
    rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    return {k: data.efc_pos[rows][data.efc_id[rows] == k] for k in range(reference.neq)}


def reference_configuration(model, reference):
    """Our ``q`` at MuJoCo's ``qpos0``, where the file places every body."""
    return mb.from_mujoco(model, reference.qpos0, np.zeros(reference.nv))[0]


def with_frames_together(model, q, closure, free_body):
    """``q`` with ``free_body`` (on a free joint) moved so that the two frames of ``closure`` coincide."""
    def world(body, frame):
        return frame if body is None else mb.frame_placement(model, q, body) @ frame

    if closure.body_b == free_body:
        X = world(closure.body_a, closure.frame_a) @ np.linalg.inv(closure.frame_b)
    else:
        X = world(closure.body_b, closure.frame_b) @ np.linalg.inv(closure.frame_a)
    joint = model.body_joints[model.body_index(free_body)]
    start = model.idx_q[joint]
    q = q.copy()
    q[start : start + 3] = X[:3, 3]
    q[start + 3 : start + 7] = mb.spatial.rotation_to_quat(X[:3, :3])
    return q


def test_equalities_become_built_in_constraints():
    """connect → a point loop closure, weld → a weld closure, joint → a coupling by MuJoCo's polynomial; a
    missing body2 or a mocap body is the world's side (a body fixed to it); inactive ones are left out
    with a warning."""
    with pytest.warns(UserWarning, match=r"<MJCF string>: equality 'connect equality 7': inactive equalities"):
        model = quietly_except_inactive(EQUALITIES)
    kinds = [(type(c).__name__, getattr(c, "kind", None), c.name) for c in model.equality_constraints]
    assert kinds == [("LoopClosure", "point", "four-bar"), ("LoopClosure", "weld", "box to world"),
                     ("JointCoupling", None, "gear"), ("LoopClosure", "weld", "sites"),
                     ("LoopClosure", "point", "hand"), ("LoopClosure", "weld", "relpose"),
                     ("JointCoupling", None, "lock")]
    box, hand, gear, lock = (model.equality_constraints[k] for k in (1, 4, 2, 6))
    assert (box.body_a, box.body_b) == ("box", None)
    assert hand.body_b == "target" and model.body_joints[model.body_index("target")] == -1
    # q_slide − 0.05 = 0.01 + 0.05 x − 0.02 x² + 0.003 x³ + 0.001 x⁴ with x = q_arm − 15°
    assert (gear.joint_a, gear.joint_b) == ("arm", "slide")
    np.testing.assert_allclose(gear.coefficients, [0.06, 0.05, -0.02, 0.003, 0.001], rtol=1e-15)
    assert gear.reference == pytest.approx(np.radians(15.0), rel=1e-15)
    assert (lock.joint_a, lock.joint_b, lock.offset) == (None, "hx", 0.0)
    assert mb.load_urdf(mb.robots.path("double_pendulum")).equality_constraints == ()


def quietly_except_inactive(text):
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(actuator|spring|tendon)")
        return load_mjcf(text)


def held(model, q, constraint):
    """``q`` changed so that ``constraint`` holds: the free box moved to make a weld's frames meet, or the
    coupled joint set to its polynomial of the other (the rest hold where the file places the bodies)."""
    if constraint.name in ("sites", "relpose"):
        return with_frames_together(model, q, constraint, "box")
    if isinstance(constraint, mb.JointCoupling):
        q = q.copy()
        q[model.idx_q[model.joint_index(constraint.joint_b)]] -= constraint.position(model, q)[0]
    return q


# a planar loop closed by a point constraint: three rows of rank two, by design
@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")
@pytest.mark.parametrize("index", range(7))
def test_each_equality_holds_where_mujocos_does(index):
    """Each equality's rows vanish exactly where MuJoCo's do: at a state where it holds (the file's own
    placement, adjusted by :func:`held`), and after a disturbance and our projection onto it, MuJoCo's
    residual of that equality is at rounding, where it was large before the projection."""
    model = quietly(load_mjcf, EQUALITIES)
    reference = mujoco.MjModel.from_xml_string(EQUALITIES)
    reference.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    constraint = model.equality_constraints[index]
    rng = np.random.default_rng(index)
    q = held(model, reference_configuration(model, reference), constraint)
    assert np.abs(constraint.position(model, q)).max() < 1e-12
    assert np.abs(mujoco_equality_residuals(reference, model, q)[index]).max() < 1e-12
    q = model.integrate(q, 0.2 * rng.standard_normal(model.nv))
    assert np.abs(mujoco_equality_residuals(reference, model, q)[index]).max() > 1e-3
    q, _ = mb.ConstrainedSystem(model, [constraint]).project(q, np.zeros(model.nv))
    assert np.abs(constraint.position(model, q)).max() < 1e-10
    assert np.abs(mujoco_equality_residuals(reference, model, q)[index]).max() < 1e-10


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")
def test_robotiq_gripper_closes_like_mujoco():
    """gym-hil's Panda with the Robotiq 2F-85: two connect equalities close the four-bars of the fingers and a
    joint equality couples the drivers. At MuJoCo's qpos0 every constraint holds on both sides, and the
    constrained degrees of freedom (nv minus the rank of the rows) are MuJoCo's: 15 − 5 = 10; after a
    disturbance our projection leaves MuJoCo's residuals at rounding."""
    path = gym_hil_panda()
    model = quietly(load_mjcf, path)
    reference = mujoco.MjModel.from_xml_path(path)
    reference.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    reference.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    assert [type(c).__name__ for c in model.equality_constraints] == ["LoopClosure", "LoopClosure", "JointCoupling"]
    q = reference_configuration(model, reference)
    A = np.vstack([c.jacobian(model, q) for c in model.equality_constraints])
    assert max(np.abs(c.position(model, q)).max() for c in model.equality_constraints) < 1e-15
    data = mujoco.MjData(reference)
    data.qpos[:] = reference.qpos0
    mujoco.mj_forward(reference, data)
    rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    J = data.efc_J.reshape(data.nefc, reference.nv)[rows]
    assert rows.sum() == A.shape[0] == 7
    assert np.abs(data.efc_pos[rows]).max() < 1e-15
    assert model.nv - np.linalg.matrix_rank(A) == reference.nv - np.linalg.matrix_rank(J) == 10
    system = mb.ConstrainedSystem(model, model.equality_constraints)
    q = model.integrate(q, 0.05 * np.random.default_rng(5).standard_normal(model.nv))
    q, _ = system.project(q, np.zeros(model.nv))
    residuals = mujoco_equality_residuals(reference, model, q)
    assert max(np.abs(r).max() for r in residuals.values()) < 1e-10


# ============================================================================= MuJoCo's state conventions


FREE_BODY = """\
    <mujoco>
      <worldbody>
        <body name="brick" pos="0.3 -0.2 1.1" euler="20 -30 45">
          <freejoint/>
          <geom type="box" size="0.1 0.2 0.05"/>
          <body name="lid" pos="0 0 0.05">
            <joint type="ball"/>
            <geom type="box" size="0.1 0.2 0.01" pos="0 0 0.01"/>
          </body>
        </body>
      </worldbody>
    </mujoco>
"""


def test_conversions_round_trip_batched(features):
    """``from_mujoco(to_mujoco(q, v)) = (q, v)`` for a batch of states (one ``q`` broadcast against many
    ``v`` too), the free joint's and ball joint's quaternions reordered to MuJoCo's ``[w, x, y, z]``."""
    model = quietly(load_mjcf, features)
    rng = np.random.default_rng(6)
    q = model.random_configuration(rng, (4, 3))
    v = rng.standard_normal((4, 3, model.nv))
    qpos, qvel = mb.to_mujoco(model, q, v)
    assert qpos.shape == q.shape and qvel.shape == v.shape
    np.testing.assert_array_equal(qpos[..., 3:7], q[..., [6, 3, 4, 5]])
    back_q, back_v = mb.from_mujoco(model, qpos, qvel)
    np.testing.assert_allclose(back_q, q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back_v, v, rtol=0, atol=1e-15)
    single_q, many_v = mb.to_mujoco(model, q[0, 0], v[0])
    assert single_q.shape == (3, model.nq) and np.array_equal(single_q[1], qpos[0, 0])
    assert np.array_equal(many_v, mb.to_mujoco(model, np.broadcast_to(q[0, 0], (3, model.nq)), v[0])[1])


def test_free_body_state_agrees_with_mujocos_kinematics():
    """A free body and a ball joint: MuJoCo's ``mj_kinematics`` at ``to_mujoco(q, v)`` puts the bodies where our
    forward kinematics does, and its body velocities (``mj_objectVelocity`` of the body frame, world axes)
    are ours, the free joint's linear velocity turned from the body's axes to the world's."""
    model = load_mjcf(FREE_BODY)
    reference = mujoco.MjModel.from_xml_string(FREE_BODY)
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(7)
    for _ in range(5):
        q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
        data.qpos[:], data.qvel[:] = mb.to_mujoco(model, q, v)
        mujoco.mj_forward(reference, data)
        placements = mb.forward_kinematics(model, q)
        for b, name in enumerate(model.body_names):
            k = reference.body(name).id
            np.testing.assert_allclose(placements[b, :3, 3], data.xpos[k], rtol=0, atol=1e-14)
            np.testing.assert_allclose(placements[b, :3, :3], data.xmat[k].reshape(3, 3), rtol=0, atol=1e-14)
            velocity = np.zeros(6)
            mujoco.mj_objectVelocity(reference, data, mujoco.mjtObj.mjOBJ_XBODY, k, velocity, 0)
            ours = mb.frame_velocity(model, q, v, name)
            np.testing.assert_allclose(ours, np.concatenate([velocity[3:], velocity[:3]]), rtol=0, atol=1e-13)
        np.testing.assert_allclose(data.qvel[:3], placements[0, :3, :3] @ v[:3], rtol=0, atol=1e-15)


def test_conversions_refuse_what_mujoco_lacks():
    """A planar joint has no MuJoCo counterpart; a zero quaternion in ``qpos`` has no rotation."""
    builder = mb.ModelBuilder("planar")
    builder.add_body("puck", mb.joints.Planar(), inertia=mb.inertia.sphere(1.0, 0.1))
    planar = builder.build()
    with pytest.raises(ValueError, match="joint 'puck_joint' is planar: MuJoCo has hinge, slide, ball and free"):
        mb.to_mujoco(planar, planar.neutral(), np.zeros(3))
    model = load_mjcf(FREE_BODY)
    with pytest.raises(ValueError, match=r"qpos\[3:7\] holds a zero quaternion"):
        mb.from_mujoco(model, np.zeros(model.nq), np.zeros(model.nv))
    qpos, _ = mb.to_mujoco(model, model.neutral(), np.zeros(model.nv))
    q, _ = mb.from_mujoco(model, 2.0 * qpos, np.zeros(model.nv))
    np.testing.assert_allclose(q[3:7], [0.0, 0.0, 0.0, 1.0], rtol=0, atol=0)


# ============================================================================= what is left out, and what MuJoCo refuses


def test_left_out_elements_warn_once_each_kind(tmp_path):
    """One warning per kind of thing the dynamics leaves out, naming the file, an element and how many there
    are; what changes nothing in the equations of motion (colours, contact parameters) stays silent."""
    path = write_model(tmp_path, """\
        <mujoco>
          <option density="1.2"/>
          <worldbody>
            <body name="a" gravcomp="1">
              <joint name="j" axis="0 1 0" stiffness="3"/>
              <joint name="k" axis="1 0 0" stiffness="2"/>
              <geom size="0.1" rgba="1 0 0 1" friction="1 0.1 0.1"/>
              <body name="b">
                <joint name="ball" type="ball" range="0 30"/>
                <geom size="0.1" pos="0 0 -0.1"/>
              </body>
            </body>
          </worldbody>
          <tendon><fixed name="t"><joint joint="j" coef="1"/></fixed></tendon>
          <actuator><motor name="m" joint="j"/><motor joint="k"/></actuator>
        </mujoco>""")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_mjcf(path)
    assert sorted(str(w.message) for w in caught) == sorted([
        f"{path}: actuator 'm': actuators are not modelled: give the joint forces as tau (2 elements)",
        f"{path}: tendon 't': tendons are not modelled",
        f"{path}: joint 'j': joint springs (stiffness, springdamper) are not modelled (2 elements)",
        f"{path}: body 'a': gravity compensation (gravcomp) is not modelled",
        f"{path}: joint 'ball': a ball joint's range (a cone around its reference) is not modelled",
        f"{path}: <option>: fluid forces (wind, density, viscosity) are not modelled",
    ])


ARM = """\
    <mujoco>
      <worldbody>
        <body name="upper" pos="0 0 0.5">
          <joint name="shoulder" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
          <site name="tip" pos="0.3 0 0"/>
        </body>
      </worldbody>
    </mujoco>
"""

PROCEDURAL = """\
    <mujoco model="procedural">
      <asset><model name="arm" file="arm.xml"/></asset>
      <worldbody>
        <frame pos="0 0.5 0" euler="0 0 10">
          <replicate count="3" offset="0.4 0 0" euler="0 0 20">
            <body name="link" pos="0 0 1">
              <joint name="hinge" axis="0 1 0" ref="10"/>
              <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02"/>
            </body>
          </replicate>
        </frame>
        <body name="mount" pos="0 -1 0.5">
          <joint name="mount_slide" type="slide" axis="1 0 0"/>
          <geom type="box" size="0.1 0.1 0.1"/>
          <attach model="arm" body="upper" prefix="arm-"/>
        </body>
      </worldbody>
    </mujoco>
"""


def test_procedural_elements_load_as_mujoco_expands_them(tmp_path):
    """``<replicate>`` in a ``<frame>`` and ``<attach>`` of another file's model: MuJoCo expands them, and the
    model is MuJoCo's (names, order, dynamics), the attached site a frame of the model by its prefixed name."""
    write_model(tmp_path, ARM, "arm.xml")
    path = write_model(tmp_path, PROCEDURAL)
    model, _ = assert_agrees_with_mujoco(path)
    assert model.joint_names == ("hinge0", "hinge1", "hinge2", "mount_slide", "arm-shoulder")
    assert model.body_names == ("link0", "link1", "link2", "mount", "arm-upper", "arm-tip")


def test_malformed_xml_is_mujocos_message_after_the_file(tmp_path):
    path = write_model(tmp_path, """\
        <mujoco>
          <worldbody>
            <body name="a">
              <geom size="0.1">
            </body>
          </worldbody>
        </mujoco>""")
    with pytest.raises(MJCFError, match=rf"(?s)^{path}: XML parse error .*MISMATCHED_ELEMENT.*Line number=4: XMLElement name=geom"):
        load_mjcf(path)
    with pytest.raises(MJCFError, match=r"^<MJCF string>: XML parse error"):
        load_mjcf("<mujoco><worldbody></mujoco>")


def test_include_cycle_is_refused(tmp_path):
    write_model(tmp_path, "<mujoco><include file='b.xml'/></mujoco>", "a.xml")
    write_model(tmp_path, "<mujoco><include file='a.xml'/></mujoco>", "b.xml")
    a = str(tmp_path / "a.xml")
    with pytest.raises(MJCFError, match=rf"^{a}: XML Error: File 'a.xml' already included\nElement 'include'"):
        load_mjcf(a)


@pytest.mark.parametrize("body, message", [
    ('<body><joint type="screw"/></body>', r"XML Error: invalid keyword: 'screw'\nElement 'joint', line 1"),
    ('<body><joint axis="0 0 0"/><geom size="1"/></body>', r"Error: axis too small in joint\nElement name '', id 0"),
    ('<body><geom size="1" class="nope"/></body>', r"XML Error: unknown default class name 'nope'\nElement 'geom'"),
    ('<body><geom type="mesh" mesh="nope"/></body>', r"Error: mesh 'nope' not found in geom 0"),
    ('<body euler="0 0 1" quat="1 0 0 0"/>', r"XML Error: multiple orientation specifiers are not allowed"),
    ('<body quat="0 0 0 0"/>', r"XML Error: zero quaternion is not allowed\nElement 'body', line 1"),
    ('<body><joint/><inertial pos="0 0 0" mass="-1" diaginertia="1 1 1"/></body>',
     r"Error: mass and inertia of moving bodies must be larger than mjMINVAL"),
    ('<body><joint/><inertial pos="0 0 0" mass="1" diaginertia="1 1 3"/></body>',
     r"Error: inertia must satisfy A \+ B >= C; use 'balanceinertia' to fix"),
    ('<body><geom size="abc"/></body>', r"XML Error: bad format in attribute 'size'\nElement 'geom', line 1"),
    ('<body><body><freejoint/><geom size="1"/></body></body>', r"Error: free joint can only be used on top level"),
    ('<body><joint/><freejoint/><geom size="1"/></body>', r"Error: more than 6 dofs in body"),
    ('<body><geom type="capsule" size="0.1"/></body>', r"Error: size 1 must be positive in geom"),
    ('<body><geom size="0.1" sparkle="1"/></body>', r"XML Error: Schema violation: unrecognized attribute: 'sparkle'"),
])
def test_invalid_models_carry_mujocos_message(body, message):
    with pytest.raises(MJCFError, match=r"^<MJCF string>: " + message):
        load_mjcf(f"<mujoco><worldbody>{body}</worldbody></mujoco>")


def test_refusals_of_whole_files(tmp_path):
    with pytest.raises(MJCFError, match=r"^<MJCF string>: the root element must be <mujoco>, got <robot>$"):
        load_mjcf("<robot name='r'/>")
    with pytest.raises(MJCFError, match=r"XML Error: global coordinates no longer supported"):
        load_mjcf("<mujoco><compiler coordinate='global'/></mujoco>")
    with pytest.raises(MJCFError, match=r"Error: unknown element 'nope' in equality constraint\nElement name 'c'"):
        load_mjcf("<mujoco><worldbody/><equality><connect name='c' body1='nope' anchor='0 0 0'/></equality></mujoco>")
    with pytest.raises(FileNotFoundError, match="MJCF file not found"):
        load_mjcf(str(tmp_path / "missing.xml"))


def test_a_mesh_file_not_found_is_refused_even_for_the_viewer_alone(tmp_path, monkeypatch):
    """MuJoCo's compiler reads every mesh file, so one that is not found is MuJoCo's error after the file, also
    for a geom only the viewer draws (the body's mass from its ``<inertial>``)."""
    monkeypatch.chdir(tmp_path)
    body = ('<body><joint/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
            '<geom type="mesh" mesh="missing" contype="0" conaffinity="0" group="1"/></body>')
    with pytest.raises(MJCFError, match=r"^<MJCF string>: Error: Error opening file 'missing.stl'"):
        load_mjcf(f'<mujoco><asset><mesh file="missing.stl"/></asset><worldbody>{body}</worldbody></mujoco>')


def test_without_mujoco_the_loader_says_how_to_install_it(monkeypatch):
    """MuJoCo is an extra: ``import multibody`` works without it, and ``load_mjcf`` names the extra."""
    done = subprocess.run([sys.executable, "-c", "import sys; sys.modules['mujoco'] = None; import multibody; "
                           "print(multibody.load_mjcf.__name__)"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stdout.split() == ["load_mjcf"], done.stderr
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(ImportError, match=r'pip install "multibody\[mjcf\]"'):
        load_mjcf("<mujoco/>")


# ============================================================================= the command line and the viewer


def test_command_line_accepts_mjcf(features, capsys):
    """``multibody info``, ``check`` (against MuJoCo) on an MJCF file; ``--floating-base`` is for URDF."""
    from multibody.cli import main

    assert main(["info", features]) == 0
    out = capsys.readouterr().out
    assert "model 'features'" in out and "nq = 21, nv = 19, 12 moving joints" in out
    assert "shoulder_x [revolute axis" in out
    assert main(["check", features, "--samples", "3"]) == 0
    out = capsys.readouterr().out
    assert "all quantities agree with MuJoCo" in out and "site placements" in out
    assert main(["info", features, "--floating-base"]) == 2
    assert "--floating-base is for URDF files" in capsys.readouterr().err


def test_command_line_lists_equalities(capsys):
    from multibody.cli import main

    path = os.path.join(os.getcwd(), "equalities.xml")
    with open(path, "w") as stream:
        stream.write(textwrap.dedent(EQUALITIES))
    assert main(["info", path]) == 0
    out = capsys.readouterr().out
    assert "  four-bar: point loop closure of coupler and rocker" in out
    assert "  box to world: weld loop closure of box and the world" in out
    assert "  gear: slide = 0.06 + 0.05 x + -0.02 x^2 + 0.003 x^3 + 0.001 x^4 with x = arm - 0.261799" in out
    assert "  lock: hx held at 0" in out
    assert f"warning: {path}: equality 'connect equality 7': inactive equalities (active='false') are left out" in out


def test_viewer_shapes_of_every_geom(features):
    """The viewer's meshes of the geoms: each primitive's extent is MuJoCo's size (capsules with their caps,
    ellipsoids by their semi-axes), each mesh the file's, scaled."""
    from multibody.geometry import load_meshes

    model = quietly(load_mjcf, features)
    shapes = load_meshes(model, "visual")
    assert len(shapes) == len(model.geometries) and all(mesh is not None for _, mesh in shapes)
    for geometry, mesh in shapes:
        local = mesh.copy()
        local.apply_transform(np.linalg.inv(geometry.placement))
        extent = local.bounds[1] - local.bounds[0]
        if geometry.shape == "capsule":
            radius, length = geometry.size
            np.testing.assert_allclose(extent, [2 * radius, 2 * radius, length + 2 * radius], rtol=1e-3)
        elif geometry.shape == "ellipsoid":
            np.testing.assert_allclose(extent, 2 * np.asarray(geometry.size), rtol=1e-3)
        elif geometry.shape == "mesh" and geometry.filename.endswith("block.stl"):
            np.testing.assert_allclose(extent, [0.1, 0.12, 0.02], rtol=1e-6)
