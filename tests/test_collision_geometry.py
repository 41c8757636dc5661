"""Collision geometry (issue 39, part 1): ``model.collision_geometries`` from URDF ``<collision>``, MJCF
colliding geoms and :meth:`ModelBuilder.add_collision`, and the arrays of
:func:`multibody.geometry.collision_table` in the kernels' conventions."""

from __future__ import annotations

import os
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import multibody as mb
from multibody import geometry as geo
from multibody.spatial import pose_from_xyz_rpy

from conftest import ERD_DIR, erd_urdf

trimesh = pytest.importorskip("trimesh")

LINK_INERTIA = '<inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>'


def urdf(links_body):
    """A two-link URDF: ``base`` and ``arm`` (a revolute joint about z), each link's extra elements given."""
    base, arm = links_body
    return (f'<robot name="r"><link name="base">{LINK_INERTIA}{base}</link>'
            f'<link name="arm">{LINK_INERTIA}{arm}</link>'
            '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>'
            '<origin xyz="0 0 1"/><limit lower="-1" upper="1"/></joint></robot>')


def collision(shape, xyz="0 0 0", rpy="0 0 0"):
    return f'<collision><origin xyz="{xyz}" rpy="{rpy}"/><geometry>{shape}</geometry></collision>'


@pytest.fixture
def box_stl(tmp_path):
    """A 1 × 2 × 4 box saved as STL in ``tmp_path``, its path."""
    path = tmp_path / "part.stl"
    trimesh.creation.box(extents=(1.0, 2.0, 4.0)).export(str(path))
    return path


def corners(half):
    """The 8 corners of the box of half-extents ``half``, sorted by rows."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    return sort_rows(signs * np.asarray(half, dtype=float))


def sort_rows(a):
    return a[np.lexsort(a.T[::-1])]


# ----------------------------------------------------------------------------- URDF


def test_urdf_collision_shapes_and_table(tmp_path, box_stl):
    """Each URDF ``<collision>`` shape (sphere, box, cylinder, a mesh scaled) is a collision geometry of its
    link with its origin; the visual ones are not; the table holds the shape codes, the body indices, the
    placements, half-extents and half-lengths, and the scaled mesh's hull vertices in its geometry frame."""
    text = urdf((collision('<sphere radius="0.1"/>', xyz="0 0 -0.5")
                 + collision('<box size="0.2 0.4 0.6"/>', rpy="0 0 0.3")
                 + '<visual><geometry><box size="1 1 1"/></geometry></visual>',
                 collision('<cylinder radius="0.05" length="0.8"/>', xyz="0.1 0 0")
                 + collision(f'<mesh filename="{box_stl.name}" scale="2 1 0.5"/>', xyz="0 0 0.2")))
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    model = mb.load_urdf(str(path))
    got = [(g.body, g.kind, g.shape, tuple(g.size)) for g in model.collision_geometries]
    assert got == [("base", "collision", "sphere", (0.1,)), ("base", "collision", "box", (0.2, 0.4, 0.6)),
                   ("arm", "collision", "cylinder", (0.05, 0.8)), ("arm", "collision", "mesh", ())]
    assert model.collision_geometries[3].filename == str(box_stl)
    # model.geometries keeps the file's visual and collision shapes for the viewer
    assert [(g.kind, g.shape) for g in model.geometries] == [
        ("visual", "box"), ("collision", "sphere"), ("collision", "box"), ("collision", "cylinder"),
        ("collision", "mesh")]
    table = geo.collision_table(model)
    assert table.shapes.tolist() == [geo.SPHERE, geo.BOX, geo.CYLINDER, geo.CONVEX]
    assert table.frames.tolist() == [model.body_index("base")] * 2 + [model.body_index("arm")] * 2
    assert table.names == ("base", "base", "arm", "arm")
    np.testing.assert_array_equal(table.placements[0], pose_from_xyz_rpy((0, 0, -0.5)))
    np.testing.assert_array_equal(table.placements[1], pose_from_xyz_rpy(rpy=(0, 0, 0.3)))
    np.testing.assert_array_equal(table.placements[3], pose_from_xyz_rpy((0, 0, 0.2)))
    np.testing.assert_array_equal(table.sizes, [[0.1, 0, 0], [0.1, 0.2, 0.3], [0.05, 0.4, 0], [0, 0, 0]])
    np.testing.assert_array_equal(table.vertex_ranges, [[0, 0], [0, 0], [0, 0], [0, 8]])
    # the 1 × 2 × 4 box scaled by (2, 1, 0.5): a 2 × 2 × 2 cube about the geometry frame's origin
    np.testing.assert_allclose(sort_rows(table.vertices), corners((1.0, 1.0, 1.0)), rtol=0, atol=1e-15)


def test_missing_collision_mesh_is_left_out_with_a_warning(tmp_path):
    """A collision mesh whose file is not found warns once at load and is left out of
    ``collision_geometries`` (the other shapes stay)."""
    text = urdf((collision('<mesh filename="missing.stl"/>'), collision('<sphere radius="0.1"/>')))
    with pytest.warns(UserWarning, match=r"1 mesh file\(s\) not found, e\.g\. 'missing\.stl'.*collision meshes "
                                         r"among them are left out of model\.collision_geometries"):
        model = mb.load_urdf(text)
    assert [(g.body, g.shape) for g in model.collision_geometries] == [("arm", "sphere")]


def test_unreadable_collision_mesh_is_named_when_the_table_is_built(tmp_path):
    """A collision mesh file that cannot be read makes :func:`collision_table` raise, naming its body and file."""
    bad = tmp_path / "bad.stl"
    bad.write_text("not a mesh")
    path = tmp_path / "robot.urdf"
    path.write_text(urdf(("", collision('<mesh filename="bad.stl"/>'))))
    model = mb.load_urdf(str(path))
    with pytest.raises(ValueError, match=rf"collision mesh '{bad}' of body 'arm': cannot be read"):
        geo.collision_table(model)


@pytest.mark.parametrize("shape, text", [("box", '<box size="0.1 0 0.2"/>'), ("sphere", '<sphere radius="0"/>'),
                                         ("cylinder", '<cylinder radius="0.1" length="0"/>')])
def test_geometry_without_positive_size_is_refused_by_the_table(shape, text):
    """A URDF shape of size 0 loads (the dynamics do not need it) and the collision table, which contact
    detection needs, refuses it naming its body and its shape."""
    model = mb.load_urdf(urdf(("", collision(text))))
    assert model.collision_geometries[0].shape == shape
    with pytest.raises(ValueError, match=rf"collision geometry of body 'arm': a {shape} needs \d positive size"):
        geo.collision_table(model)


# ----------------------------------------------------------------------------- example-robot-data


def test_solo12_collision_meshes_are_convex_hulls():
    """Solo12's 17 collision meshes (the base, then each leg's shoulder, upper and lower leg and foot) are its
    collision geometries, each the convex hull of its mesh file (the hull trimesh computes, same vertices)."""
    path = erd_urdf("solo_description/robots/solo12.urdf")
    model = mb.load_urdf(path, floating_base=True, package_dirs=[os.path.dirname(os.path.dirname(ERD_DIR))])
    legs = [f"{leg}_{part}" for leg in ("FL", "FR", "HL", "HR")
            for part in ("SHOULDER", "UPPER_LEG", "LOWER_LEG", "FOOT")]
    assert [g.body for g in model.collision_geometries] == ["base_link"] + legs
    assert all(g.shape == "mesh" for g in model.collision_geometries)
    table = geo.collision_table(model)
    assert table.shapes.tolist() == [geo.CONVEX] * 17
    assert table.frames.tolist() == [model.body_index(name) for name in table.names]
    np.testing.assert_array_equal(table.vertex_ranges[1:, 0], np.cumsum(table.vertex_ranges[:-1, 1]))
    assert table.vertices.shape == (table.vertex_ranges[:, 1].sum(), 3)
    for g, geometry in enumerate(model.collision_geometries):
        start, count = table.vertex_ranges[g]
        expected = trimesh.load(geometry.filename, force="mesh").convex_hull.vertices
        np.testing.assert_allclose(sort_rows(table.vertices[start : start + count]), sort_rows(np.asarray(expected)),
                                   rtol=0, atol=1e-12)


def test_go1_collision_primitives_match_the_file():
    """Go1's 38 ``<collision>`` primitives (boxes, cylinders, spheres) are its collision geometries, in the
    file's link order, each with the size written in the file (a cylinder's radius and length)."""
    path = erd_urdf("go1_description/urdf/go1.urdf")
    model = mb.load_urdf(path, floating_base=True)
    expected = {}
    for link in ET.parse(path).getroot().iter("link"):
        for element in link.findall("collision"):
            shape = element.find("geometry")[0]
            size = {"box": lambda s: tuple(map(float, s.get("size").split())),
                    "sphere": lambda s: (float(s.get("radius")),),
                    "cylinder": lambda s: (float(s.get("radius")), float(s.get("length")))}[shape.tag](shape)
            expected.setdefault(link.get("name"), []).append((shape.tag, size))
    got = {}
    for geometry in model.collision_geometries:
        got.setdefault(geometry.body, []).append((geometry.shape, tuple(geometry.size)))
    assert got == expected and len(model.collision_geometries) == 38
    table = geo.collision_table(model)
    for geometry, code, size in zip(model.collision_geometries, table.shapes, table.sizes):
        full = np.asarray(geometry.size)
        if geometry.shape == "box":
            assert code == geo.BOX and np.array_equal(size, full / 2)
        elif geometry.shape == "cylinder":
            assert code == geo.CYLINDER and np.array_equal(size, [full[0], full[1] / 2, 0.0])
        else:
            assert code == geo.SPHERE and np.array_equal(size, [full[0], 0.0, 0.0])


# ----------------------------------------------------------------------------- MJCF


def gymnasium_asset(name):
    gymnasium = pytest.importorskip("gymnasium")
    path = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", name)
    if not os.path.isfile(path):
        pytest.skip(f"gymnasium has no {name}")
    return path


@pytest.mark.parametrize("name", ["ant.xml", "half_cheetah.xml", "humanoid.xml"])
def test_mjcf_colliding_geoms_are_mujocos(name):
    """The collision geometries of a gymnasium MuJoCo model are MuJoCo's colliding geoms of bodies (the floor
    plane of the world left out): same shapes, the table's sizes MuJoCo's ``geom_size`` (radii, half-lengths,
    half-extents: the same convention), each placed in the world where MuJoCo places it."""
    mujoco = pytest.importorskip("mujoco")
    path = gymnasium_asset(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (actuators and the like are left out with warnings)
        model = mb.load_mjcf(path)
    reference = mujoco.MjModel.from_xml_path(path)
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(0)
    q = model.random_configuration(rng)
    data.qpos[:], data.qvel[:] = mb.mjcf.to_mujoco(model, q, np.zeros(model.nv))
    mujoco.mj_kinematics(reference, data)
    codes = {int(mujoco.mjtGeom.mjGEOM_SPHERE): geo.SPHERE, int(mujoco.mjtGeom.mjGEOM_CAPSULE): geo.CAPSULE,
             int(mujoco.mjtGeom.mjGEOM_BOX): geo.BOX, int(mujoco.mjtGeom.mjGEOM_CYLINDER): geo.CYLINDER}
    geoms = [k for k in range(reference.ngeom) if reference.geom_bodyid[k] > 0
             and (reference.geom_contype[k] or reference.geom_conaffinity[k])]
    table = geo.collision_table(model)
    assert len(geoms) == len(table.shapes) > 0
    assert table.shapes.tolist() == [codes[int(reference.geom_type[k])] for k in geoms]
    # (model.body_names[i] is MuJoCo's body i + 1)
    assert table.frames.tolist() == [reference.geom_bodyid[k] - 1 for k in geoms]
    assert table.names == tuple(model.body_names[b] for b in table.frames)
    np.testing.assert_allclose(table.sizes, reference.geom_size[geoms], rtol=1e-15, atol=0)
    placements = mb.forward_kinematics(model, q)
    for g, k in enumerate(geoms):
        world = placements[table.frames[g]] @ table.placements[g]
        np.testing.assert_allclose(world[:3, 3], data.geom_xpos[k], rtol=0, atol=1e-13)
        np.testing.assert_allclose(world[:3, :3], data.geom_xmat[k].reshape(3, 3), rtol=0, atol=1e-13)


MJCF_GEOMS = """<mujoco><asset><mesh name="tet" vertex="0 0 0  1 0 0  0 1 0  0 0 1  0.1 0.1 0.1" scale="2 2 2"/>
</asset><worldbody><geom type="plane" size="1 1 0.1"/>
<body name="b"><joint type="hinge" axis="0 0 1"/>
<geom name="shown" type="box" size="0.1 0.2 0.3" group="1"/>
<geom name="hidden" type="sphere" size="0.5" group="3" contype="0" conaffinity="0"/>
<geom name="collider" type="capsule" size="0.1 0.4" group="3" pos="0 0 1"/>
<geom name="drawn only" type="cylinder" size="0.2 0.3" contype="0" conaffinity="0"/>
<geom name="blob" type="ellipsoid" size="0.1 0.2 0.3"/>
<geom name="tet" type="mesh" mesh="tet" pos="1 0 0"/>
</body></worldbody></mujoco>"""


def test_mjcf_collision_filter_ellipsoid_and_vertex_mesh():
    """MuJoCo's filter decides: geoms with ``contype`` and ``conaffinity`` 0 are not collision geometries
    (whatever their group), the others are (any group); an ellipsoid is left out with a warning; a mesh given
    by its vertices is the convex hull of MuJoCo's compiled vertices (the interior vertex dropped); the world's plane is
    not a body's geometry. ``model.geometries`` (the viewer's) is unchanged."""
    with pytest.warns(UserWarning, match=r"ellipsoid geoms of bodies are left out of the collision geometries"):
        model = mb.load_mjcf(MJCF_GEOMS)
    assert [(g.shape, tuple(g.size)) for g in model.collision_geometries] == [
        ("box", (0.2, 0.4, 0.6)), ("capsule", (0.1, 0.8)), ("convex", ())]
    assert [(g.kind, g.shape) for g in model.geometries] == [
        ("visual", "box"), ("collision", "sphere"), ("collision", "capsule"), ("visual", "cylinder"),
        ("visual", "ellipsoid")]
    # MuJoCo's compiled vertices, centred on the mesh's inertial frame, at the geom's compiled pose: in the
    # body, the scaled tetrahedron at the geom's pos, to MuJoCo's single precision
    tetrahedron = model.collision_geometries[2]
    X = tetrahedron.placement
    np.testing.assert_allclose(sort_rows(np.round(tetrahedron.vertices @ X[:3, :3].T + X[:3, 3], 6)),
                               sort_rows(2.0 * np.vstack([np.zeros(3), np.eye(3)]) + [1.0, 0.0, 0.0]), rtol=0, atol=1e-6)
    table = geo.collision_table(model)
    assert table.shapes.tolist() == [geo.BOX, geo.CAPSULE, geo.CONVEX]
    np.testing.assert_array_equal(table.sizes, [[0.1, 0.2, 0.3], [0.1, 0.4, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(table.vertex_ranges, [[0, 0], [0, 0], [0, 4]])


# ----------------------------------------------------------------------------- the builder


def builder():
    b = mb.ModelBuilder("shapes")
    b.add_body("base", mb.joints.FreeFlyer(), inertia=mb.inertia.sphere(1.0, 0.1))
    b.add_body("tool", mb.joints.Revolute([0, 0, 1]), parent="base", placement=pose_from_xyz_rpy((0, 0, 0.5)),
               inertia=mb.inertia.sphere(1.0, 0.1))
    return b


def test_builder_shapes_and_table_conventions():
    """``add_collision`` of each shape gives a collision geometry with its size and placement; the table
    halves a box's edges and a cylinder's and capsule's lengths, and a convex shape keeps its hull's
    vertices (the interior point dropped) in its geometry frame."""
    b = builder()
    X = pose_from_xyz_rpy((0.1, 0.2, 0.3), (0.3, -0.2, 1.0))
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    returned = [b.add_collision("base", "sphere", 0.25),
                b.add_collision("base", "box", (0.2, 0.4, 0.8), X),
                b.add_collision("tool", "cylinder", (0.05, 0.3)),
                b.add_collision("tool", "capsule", [0.02, 0.1], placement=X),
                b.add_collision("tool", "convex", None, vertices=np.vstack([cube, np.zeros(3)]))]
    model = b.build()
    assert model.collision_geometries == tuple(returned)
    assert [(g.body, g.shape, g.size) for g in returned] == [
        ("base", "sphere", (0.25,)), ("base", "box", (0.2, 0.4, 0.8)), ("tool", "cylinder", (0.05, 0.3)),
        ("tool", "capsule", (0.02, 0.1)), ("tool", "convex", ())]
    assert model.geometries == ()  # (collision shapes are not the viewer's)
    table = geo.collision_table(model)
    assert table.shapes.tolist() == [geo.SPHERE, geo.BOX, geo.CYLINDER, geo.CAPSULE, geo.CONVEX]
    assert table.frames.tolist() == [0, 0, 1, 1, 1]
    np.testing.assert_array_equal(table.placements[[1, 3]], [X, X])
    np.testing.assert_array_equal(table.placements[[0, 2, 4]], np.broadcast_to(np.eye(4), (3, 4, 4)))
    np.testing.assert_array_equal(table.sizes, [[0.25, 0, 0], [0.1, 0.2, 0.4], [0.05, 0.15, 0], [0.02, 0.05, 0],
                                                [0, 0, 0]])
    np.testing.assert_array_equal(table.vertex_ranges, [[0, 0]] * 4 + [[0, 8]])
    np.testing.assert_array_equal(sort_rows(table.vertices), sort_rows(cube))


def test_table_arrays_are_cached_contiguous_and_never_empty():
    """The table is built once per model (the same object again), its arrays C-contiguous, read-only and of
    the documented dtypes and shapes; a model without collision geometry has no rows but one vertex row."""
    b = builder()
    b.add_collision("tool", "box", (1, 1, 1))
    model = b.build()
    table = geo.collision_table(model)
    assert geo.collision_table(model) is table
    for name, dtype, shape in (("shapes", np.int64, (1,)), ("frames", np.int64, (1,)),
                               ("placements", np.float64, (1, 4, 4)), ("sizes", np.float64, (1, 3)),
                               ("vertex_ranges", np.int64, (1, 2)), ("vertices", np.float64, (1, 3))):
        array = getattr(table, name)
        assert array.dtype == dtype and array.shape == shape and array.flags.c_contiguous
        assert not array.flags.writeable
    empty = geo.collision_table(builder().build())
    assert empty.shapes.shape == (0,) and empty.sizes.shape == (0, 3) and empty.vertices.shape == (1, 3)
    assert empty.names == ()


ROTATED_TWICE = np.diag([2.0, 1.0, 1.0, 1.0])


@pytest.mark.parametrize("args, kwargs, message", [
    (("hand", "sphere", 0.1), {}, r"add_collision: unknown body 'hand'; .*bodies are \['base', 'tool'\]"),
    (("tool", "cone", 0.1), {}, r"collision geometry of body 'tool': shape must be one of sphere, box, cylinder, "
                                r"capsule, convex, got 'cone'"),
    (("tool", "box", (0.1, 0.2)), {}, r"body 'tool': size of a box must be 3 number\(s\) .*got 2"),
    (("tool", "sphere", None), {}, r"body 'tool': size of a sphere must be 1 number\(s\) \(radius\), got 0"),
    (("tool", "capsule", (0.1, 0.0)), {}, r"body 'tool': size of a capsule \(radius, length\) must be positive and "
                                          r"finite, got \[0.1, 0.0\]"),
    (("tool", "sphere", -1.0), {}, r"body 'tool': size of a sphere \(radius\) must be positive"),
    (("tool", "cylinder", (0.1, np.inf)), {}, r"body 'tool': size of a cylinder .* must be positive and finite"),
    (("tool", "box", "big"), {}, r"body 'tool': size of a box must be numbers, got 'big'"),
    (("tool", "sphere", 0.1, np.full((4, 4), np.nan)), {}, r"body 'tool': placement must be finite"),
    (("tool", "sphere", 0.1, np.eye(3)), {}, r"body 'tool': placement must have shape \(4, 4\), got \(3, 3\)"),
    (("tool", "sphere", 0.1, ROTATED_TWICE), {}, r"body 'tool': placement must hold a rotation"),
    (("tool", "convex", None), {}, r"body 'tool': vertices are given for a convex shape, and only for one"),
    (("tool", "box", (1, 1, 1)), {"vertices": np.eye(3)}, r"body 'tool': vertices .*\(not a box\)"),
    (("tool", "convex", None), {"vertices": np.eye(3)}, r"body 'tool': vertices must be at least 4 points .*got 3"),
    (("tool", "convex", None), {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]},
     r"body 'tool': vertices lie in one plane"),
    (("tool", "convex", None), {"vertices": np.full((5, 3), np.nan)}, r"body 'tool': vertices must be finite"),
    (("tool", "convex", None), {"vertices": np.zeros((5, 2))}, r"body 'tool': vertices must have shape \(k, 3\)"),
    (("tool", "convex", 1.0), {"vertices": np.eye(4)[:, :3]}, r"body 'tool': size of a convex must be 0 number\(s\)"),
])
def test_builder_refuses_bad_input(args, kwargs, message):
    """Each bad argument of ``add_collision`` raises ``ValueError`` naming the argument and the body, and
    nothing is added."""
    b = builder()
    with pytest.raises(ValueError, match=message):
        b.add_collision(*args, **kwargs)
    assert b.build().collision_geometries == ()


def test_mjcf_flat_vertex_mesh_is_left_out_with_a_warning():
    """A colliding mesh given by vertices within 1e-12 of one plane, which MuJoCo compiles, has no convex hull
    with volume: it is left out of the collision geometries with a warning naming it, and the model loads."""
    xml = ('<mujoco><asset><mesh name="flat" vertex="0 0 0  1 0 0  0 1 0  1 1 0  0.5 0.5 1e-12"/></asset><worldbody>'
           '<body name="b"><joint type="hinge"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
           '<geom type="mesh" mesh="flat" mass="0"/><geom type="sphere" size="0.1"/></body></worldbody></mujoco>')
    with pytest.warns(UserWarning, match=r"^<MJCF string>: mesh 'flat': a mesh without a convex hull is left out of the "
                                         r"collision geometries: its vertices lie in one plane"):
        model = mb.load_mjcf(xml)
    assert [g.shape for g in model.collision_geometries] == ["sphere"]


def test_table_rows_feed_the_detection_kernel():
    """The table's rows are what :func:`multibody.kernels.collision.halfspace_contacts` reads: each shape of
    the builder, placed in the world so that it rests on the ground ``z ≥ 0`` by its size (a box on a face of
    edge 0.6 at 0.3, a capsule lying flat at its radius, a cylinder standing at half its length, a sphere at
    its radius, a cube given by its vertices at 1), touches it with zero gap at the kernel's count of points."""
    from multibody.kernels import collision as kernels

    b = builder()
    lying = pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))  # (the capsule's z axis along y)
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    shapes = [("box", (0.2, 0.4, 0.6), np.eye(4), None, 0.3, 4), ("capsule", (0.1, 0.8), lying, None, 0.1, 2),
              ("cylinder", (0.05, 0.3), np.eye(4), None, 0.15, 4), ("sphere", (0.25,), np.eye(4), None, 0.25, 1),
              ("convex", None, np.eye(4), cube, 1.0, 4)]
    for shape, size, placement, vertices, _, _ in shapes:
        b.add_collision("base", shape, size, placement, vertices=vertices)
    table = geo.collision_table(b.build())
    out, ws = np.zeros((kernels.MAX_PAIR_CONTACTS, kernels.CONTACT_COLUMNS)), np.zeros(kernels.PAIR_WORKSPACE)
    for g, (shape, _, _, _, height, expected) in enumerate(shapes):
        start, count = table.vertex_ranges[g]
        pose = pose_from_xyz_rpy((0.5, -0.2, height)) @ table.placements[g]
        found = kernels.halfspace_contacts(table.shapes[g], table.sizes[g], table.vertices[start : start + count],
                                           np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]),
                                           np.array([0.0, 0.0, 1.0]), 0.0, 1e-9, out, ws)
        assert found == expected, shape
        np.testing.assert_allclose(out[:found, 6], 0.0, rtol=0, atol=1e-15, err_msg=shape)


def test_add_collision_geometry_takes_a_model_files_shapes_as_given():
    """``add_collision_geometry`` (the loaders' way in) takes a collision shape as a file gives it, a size of 0
    included (the table refuses that later), and refuses an unknown body, a visual geometry or a shape contact
    detection has no code for."""
    b = builder()
    flat = mb.model.Geometry("tool", "collision", "box", np.eye(4), size=(0.1, 0.0, 0.1))
    b.add_collision_geometry(flat)
    with pytest.raises(ValueError, match=r"unknown body 'hand'"):
        b.add_collision_geometry(mb.model.Geometry("hand", "collision", "sphere", np.eye(4), size=(0.1,)))
    for kind, shape in (("visual", "sphere"), ("collision", "ellipsoid")):
        with pytest.raises(ValueError, match=rf"collision geometry of body 'tool' must be of kind 'collision' and "
                                             rf"shape sphere, box, capsule, cylinder, mesh, convex; got kind "
                                             rf"'{kind}', shape '{shape}'"):
            b.add_collision_geometry(mb.model.Geometry("tool", kind, shape, np.eye(4), size=(0.1, 0.1, 0.1)))
    model = b.build()
    assert model.collision_geometries == (flat,)
    with pytest.raises(ValueError, match=r"collision geometry of body 'tool': a box needs 3 positive size\(s\), got "
                                         r"\(0.1, 0.0, 0.1\)"):
        geo.collision_table(model)


@pytest.mark.parametrize("reference_pose, exact", [('refpos="0.05 0 0"', True),
                                                   ('refpos="0.05 0 0" refquat="0.9 0.1 0.3 0.2"', False)])
def test_mjcf_mesh_file_hull_is_mujocos(tmp_path, reference_pose, exact):
    """A colliding mesh geom read from a file (scaled unevenly, moved by ``refpos``, placed by ``pos`` and
    ``euler``) is the convex hull MuJoCo collides: its support function ``max_v d·v`` in the world equals
    that of MuJoCo's mesh vertices placed at the geom's pose, in every direction, to MuJoCo's single
    precision, and so does the viewer's mesh, drawn without a warning. Turned by ``refquat`` as well, the
    file's placement cannot draw it (MuJoCo scales after turning, and the viewer warns); the collision hull,
    from MuJoCo's compiled vertices, is exact either way."""
    mujoco = pytest.importorskip("mujoco")
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    mesh.vertices[:, 0] += 0.2 * mesh.vertices[:, 1] ** 2  # (not symmetric: the re-centring shows)
    mesh.export(str(tmp_path / "blob.stl"))
    xml = (f'<mujoco><asset><mesh name="blob" file="blob.stl" scale="1 2 0.5" {reference_pose}/></asset>'
           '<worldbody><body name="b" pos="0 0 1"><joint type="ball"/>'
           '<geom type="mesh" mesh="blob" pos="0.1 0.2 0.3" euler="10 20 30"/></body></worldbody></mujoco>')
    (tmp_path / "blob.xml").write_text(xml)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = mb.load_mjcf(str(tmp_path / "blob.xml"))
    assert [str(w.message).split(": ", 1)[1] for w in caught] == \
        ([] if exact else ["mesh 'blob': a mesh scaled unevenly and turned by refquat is drawn approximately"])
    reference = mujoco.MjModel.from_xml_path(str(tmp_path / "blob.xml"))
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(3)
    q = model.random_configuration(rng)
    data.qpos[:] = mb.mjcf.to_mujoco(model, q, np.zeros(model.nv))[0]
    mujoco.mj_kinematics(reference, data)
    assert [g.shape for g in model.collision_geometries] == ["convex"]
    table = geo.collision_table(model)
    assert table.shapes.tolist() == [geo.CONVEX]
    X = mb.forward_kinematics(model, q)[table.frames[0]] @ table.placements[0]
    ours = table.vertices @ X[:3, :3].T + X[:3, 3]
    start, count = reference.mesh_vertadr[0], reference.mesh_vertnum[0]
    theirs = reference.mesh_vert[start : start + count] @ data.geom_xmat[0].reshape(3, 3).T + data.geom_xpos[0]
    directions = rng.normal(size=(200, 3))
    support = (directions @ theirs.T).max(axis=1)
    np.testing.assert_allclose((directions @ ours.T).max(axis=1), support, rtol=0, atol=1e-6)
    if exact:
        (geometry, drawn), = geo.load_meshes(model)
        body = mb.forward_kinematics(model, q)[model.body_index(geometry.body)]
        world = np.asarray(drawn.vertices) @ body[:3, :3].T + body[:3, 3]
        np.testing.assert_allclose((directions @ world.T).max(axis=1), support, rtol=0, atol=1e-6)
