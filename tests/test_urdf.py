"""URDF loader: agreement with Pinocchio's buildModelFromUrdf, and clear errors on bad files."""

import os
import pathlib
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody import joints as jt

from conftest import erd_urdf, import_pinocchio, pinocchio_nq, q_to_pinocchio

ROBOTS = [
    "ur_description/urdf/ur5_robot.urdf",
    "panda_description/urdf/panda.urdf",
    "solo_description/robots/solo12.urdf",
    "talos_data/robots/talos_reduced.urdf",
    "anymal_b_simple_description/robots/anymal.urdf",
    "double_pendulum_description/urdf/double_pendulum_continuous.urdf",
    "tiago_description/robots/tiago.urdf",
    "romeo_description/urdf/romeo.urdf",
    "a1_description/urdf/a1.urdf",
]


def load_both(relative, floating_base):
    pin = import_pinocchio()
    path = erd_urdf(relative)
    model = mb.load_urdf(path, floating_base=floating_base)
    pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating_base else pin.buildModelFromUrdf(path)
    return model, pmodel


# ----------------------------------------------------------------------------- against Pinocchio

@pytest.mark.parametrize("floating_base", [False, True], ids=["fixed", "floating"])
@pytest.mark.parametrize("relative", ROBOTS, ids=[os.path.basename(r) for r in ROBOTS])
def test_structure_matches_pinocchio(relative, floating_base):
    model, pmodel = load_both(relative, floating_base)
    # joint order, tree and sizes
    assert list(pmodel.names)[1:] == list(model.joint_names)
    assert model.nv == pmodel.nv
    n_continuous = sum(isinstance(j, jt.Continuous) for j in model.joints)
    assert model.nq + n_continuous == pmodel.nq == pinocchio_nq(model)
    assert (np.array(pmodel.parents[1:]) - 1).tolist() == model.parents.tolist()
    for i in range(model.njoints):
        assert_allclose(model.joint_placements[i], pmodel.jointPlacements[i + 1].homogeneous, atol=1e-15)
        assert model.idx_v[i] == pmodel.idx_vs[i + 1]
    if floating_base:
        assert model.joint_names[0] == "root_joint"
        assert isinstance(model.joints[0], jt.FreeFlyer)
    # limits of the bounded 1-DoF joints
    for i, joint in enumerate(model.joints):
        if joint.kind in ("revolute", "prismatic"):
            s, s_pin = model.idx_q[i], pmodel.idx_qs[i + 1]
            assert model.lower[s] == pytest.approx(pmodel.lowerPositionLimit[s_pin])
            assert model.upper[s] == pytest.approx(pmodel.upperPositionLimit[s_pin])
    # every link is a body, except a fixed-base root link called "world", which is the world itself
    link_frames = {f.name for f in pmodel.frames if f.type == import_pinocchio().FrameType.BODY}
    world = {"universe"} | ({"world"} if not floating_base else set())
    assert set(model.body_names) == link_frames - world


@pytest.mark.parametrize("floating_base", [False, True], ids=["fixed", "floating"])
@pytest.mark.parametrize("relative", ROBOTS, ids=[os.path.basename(r) for r in ROBOTS])
def test_mass_matches_pinocchio(relative, floating_base):
    model, pmodel = load_both(relative, floating_base)
    moving_mass = sum(inertia.mass for inertia in model.joint_inertias)
    world_fixed_mass = sum(inertia.mass for inertia, j in zip(model.body_inertias, model.body_joints) if j < 0)
    assert moving_mass == pytest.approx(sum(I.mass for I in pmodel.inertias[1:]), rel=1e-12)
    # Pinocchio lumps the links fixed to the world into the universe's inertia
    assert world_fixed_mass == pytest.approx(pmodel.inertias[0].mass, rel=1e-12, abs=1e-15)
    assert model.total_mass == pytest.approx(sum(I.mass for I in pmodel.inertias), rel=1e-12)
    if floating_base:
        assert world_fixed_mass == 0.0


@pytest.mark.parametrize("relative,floating_base", [
    ("talos_data/robots/talos_reduced.urdf", True),
    ("panda_description/urdf/panda.urdf", False),
    ("tiago_description/robots/tiago.urdf", False),
])
def test_lumped_inertias_match_pinocchio(relative, floating_base):
    model, pmodel = load_both(relative, floating_base)
    assert len(model.joint_inertias) == len(pmodel.inertias) - 1
    for i, ours in enumerate(model.joint_inertias):
        theirs = pmodel.inertias[i + 1]
        name = model.joint_names[i]
        assert ours.mass == pytest.approx(theirs.mass, rel=1e-12, abs=1e-15), name
        assert_allclose(ours.com, theirs.lever, atol=1e-12, err_msg=name)
        assert_allclose(ours.rotational, theirs.inertia, atol=1e-12, err_msg=name)


def test_tiago_has_continuous_and_prismatic_joints():
    model, pmodel = load_both("tiago_description/robots/tiago.urdf", False)
    kinds = {j.kind for j in model.joints}
    assert {"continuous", "prismatic", "revolute"} <= kinds
    assert model.mimic == ()


# ----------------------------------------------------------------------------- mimic joints

def test_panda_mimic_is_recorded():
    model, pmodel = load_both("panda_description/urdf/panda.urdf", False)
    assert model.njoints == 9 == pmodel.njoints - 1
    assert model.nq == 9 and model.nv == 9
    assert model.joint_names[-2:] == ("panda_finger_joint1", "panda_finger_joint2")
    assert model.mimic == (mb.Mimic("panda_finger_joint2", "panda_finger_joint1", 1.0, 0.0),)


def test_mimic_multiplier_and_offset_and_unknown_target(tmp_path):
    xml = robot(
        link("a") + link("b", INERTIAL) + link("c", INERTIAL) + link("d", INERTIAL),
        joint("j1", "a", "b")
        + joint("j2", "b", "c", extra='<axis xyz="0 0 1"/><mimic joint="j1" multiplier="-2" offset="0.5"/>')
        + joint("j3", "c", "d", extra='<axis xyz="0 0 1"/><mimic joint="nope"/>'),
    )
    with pytest.warns(UserWarning, match="nope"):
        model = mb.load_urdf(xml)
    assert model.mimic == (mb.Mimic("j2", "j1", -2.0, 0.5),)
    assert model.njoints == 3


# ----------------------------------------------------------------------------- bad input

INERTIAL = ('<inertial><mass value="1"/>'
            '<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>')


def inertial(mass=1.0, ixx=0.1, iyy=0.1, izz=0.1, ixy=0.0, ixz=0.0, iyz=0.0, origin=""):
    return (f'<inertial>{origin}<mass value="{mass}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" '
            f'ixy="{ixy}" ixz="{ixz}" iyz="{iyz}"/></inertial>')


def link(name, body=""):
    return f'<link name="{name}">{body}</link>'


def joint(name, parent, child, kind="revolute", extra='<axis xyz="0 0 1"/>', origin=""):
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>' if kind in ("revolute", "prismatic") else ""
    return (f'<joint name="{name}" type="{kind}">{origin}<parent link="{parent}"/><child link="{child}"/>'
            f'{extra}{limit}</joint>')


def robot(links, joints, name="r"):
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n{links}\n{joints}\n</robot>\n'


def expect_error(tmp_path, xml, *fragments, name="bad_robot.urdf"):
    """Load ``xml`` from a file and from a string; both must raise URDFError naming the fragments,
    and the file's message must name the file."""
    path = tmp_path / name
    path.write_text(xml)
    with pytest.raises(mb.URDFError) as info:
        mb.load_urdf(str(path))
    message = str(info.value)
    assert isinstance(info.value, ValueError)
    assert name in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    with pytest.raises(mb.URDFError) as info_string:
        mb.load_urdf(xml)
    for fragment in fragments:
        assert fragment in str(info_string.value), (fragment, str(info_string.value))
    return message


def test_error_xml_syntax(tmp_path):
    xml = '<robot name="r"><link name="a"></robot>'
    message = expect_error(tmp_path, xml, "XML syntax error")
    assert "line 1" in message


def test_error_missing_parent_link(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL), joint("j1", "ghost", "b"))
    expect_error(tmp_path, xml, "<joint name='j1'>", "parent link 'ghost' is not defined")


def test_error_missing_child_link(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL), joint("j1", "a", "b") + joint("j2", "b", "ghost"))
    expect_error(tmp_path, xml, "<joint name='j2'>", "child link 'ghost' is not defined")


def test_error_cycle_without_root(tmp_path):
    xml = robot(link("a", INERTIAL) + link("b", INERTIAL), joint("j1", "a", "b") + joint("j2", "b", "a"))
    expect_error(tmp_path, xml, "<robot>", "cycle")


def test_error_cycle_beside_root(tmp_path):
    # a is the root; b and c form a loop that no path from a reaches
    xml = robot(link("a") + link("b", INERTIAL) + link("c", INERTIAL),
                joint("j1", "b", "c") + joint("j2", "c", "b"))
    expect_error(tmp_path, xml, "cycle", "'b'", "'c'")


def test_error_link_with_two_parents(tmp_path):
    xml = robot(link("a") + link("b") + link("c", INERTIAL),
                joint("j1", "a", "c") + joint("j2", "b", "c") + joint("j3", "a", "b"))
    expect_error(tmp_path, xml, "<joint name='j2'>", "two parent joints")


def test_error_several_roots(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL) + link("c", INERTIAL), joint("j1", "a", "b"))
    expect_error(tmp_path, xml, "<robot>", "several root links", "'a'", "'c'")


def test_error_unknown_joint_type(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL), joint("j1", "a", "b", kind="screw"))
    expect_error(tmp_path, xml, "<joint name='j1'>", "unknown joint type 'screw'")


def test_error_negative_mass(tmp_path):
    xml = robot(link("a") + link("l1", inertial(mass=-1.0)), joint("j1", "a", "l1"))
    expect_error(tmp_path, xml, "<link name='l1'>", "negative mass")


def test_error_inertia_not_positive_semidefinite(tmp_path):
    xml = robot(link("a") + link("l1", inertial(ixx=-1.0, iyy=1.0, izz=1.0)), joint("j1", "a", "l1"))
    expect_error(tmp_path, xml, "<link name='l1'>", "not positive semi-definite")


def test_error_inertia_triangle_inequality(tmp_path):
    xml = robot(link("a") + link("l1", inertial(ixx=1.0, iyy=1.0, izz=5.0)), joint("j1", "a", "l1"))
    expect_error(tmp_path, xml, "<link name='l1'>", "triangle inequality")


def test_error_zero_axis(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL), joint("j1", "a", "b", extra='<axis xyz="0 0 0"/>'))
    expect_error(tmp_path, xml, "<joint name='j1'>", "axis must be non-zero")


def test_error_malformed_numbers(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL),
                joint("j1", "a", "b", origin='<origin xyz="0 zero 0"/>'))
    expect_error(tmp_path, xml, "<joint name='j1'>", "xyz")


def test_error_duplicate_link(tmp_path):
    xml = robot(link("a") + link("a"), "")
    expect_error(tmp_path, xml, "<link name='a'>", "duplicate")


def test_error_limits_reversed(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL),
                '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
                '<limit lower="1" upper="-1" effort="1" velocity="1"/></joint>')
    expect_error(tmp_path, xml, "<joint name='j1'>/<limit>", "exceeds upper limit")


def test_error_no_links(tmp_path):
    expect_error(tmp_path, '<robot name="empty"></robot>', "<robot>", "no <link>")


def test_error_root_element(tmp_path):
    expect_error(tmp_path, '<model name="x"><link name="a"/></model>', "<model>", "<robot>")


def test_missing_file_and_bad_option(tmp_path):
    with pytest.raises(FileNotFoundError):
        mb.load_urdf(str(tmp_path / "nowhere.urdf"))
    with pytest.raises(ValueError, match="invalid_inertia"):
        mb.load_urdf(robot(link("a"), ""), invalid_inertia="maybe")


# ----------------------------------------------------------------------------- accepted input

def test_joint_without_axis_uses_x(tmp_path):
    xml = robot(link("a") + link("b", INERTIAL) + link("c", INERTIAL),
                joint("j1", "a", "b", extra="") + joint("j2", "b", "c", kind="prismatic", extra=""))
    model = mb.load_urdf(xml)
    assert_allclose(model.joints[0].axis, [1.0, 0.0, 0.0])
    assert_allclose(model.joints[1].axis, [1.0, 0.0, 0.0])


def test_invalid_inertia_warn_and_ignore(tmp_path):
    xml = robot(link("a") + link("l1", inertial(ixx=1.0, iyy=1.0, izz=5.0)), joint("j1", "a", "l1"))
    path = tmp_path / "warn.urdf"
    path.write_text(xml)
    with pytest.warns(UserWarning, match=r"warn\.urdf.*<link name='l1'>.*triangle"):
        model = mb.load_urdf(str(path), invalid_inertia="warn")
    assert_allclose(model.joint_inertias[0].rotational, np.diag([1.0, 1.0, 5.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mb.load_urdf(str(path), invalid_inertia="ignore")
    # a negative mass is refused whatever the option
    bad = robot(link("a") + link("l1", inertial(mass=-2.0)), joint("j1", "a", "l1"))
    with pytest.raises(mb.URDFError, match="negative mass"):
        mb.load_urdf(bad, invalid_inertia="ignore")


def test_invalid_placeholder_fixed_to_valid_body_is_accepted():
    # The dynamics sees the lumped rigid body, which is valid: a tiny placeholder does not spoil it.
    xml = robot(link("a") + link("body", inertial(mass=2.0, ixx=1.0, iyy=1.0, izz=1.0))
                + link("placeholder", inertial(mass=1e-6, ixx=1e-9, iyy=1e-9, izz=5e-9)),
                joint("j1", "a", "body") + joint("fix", "body", "placeholder", kind="fixed", extra=""))
    model = mb.load_urdf(xml)
    assert model.joint_inertias[0].problems() == []
    assert model.body_inertias[model.body_index("placeholder")].problems() != []


def test_inertial_without_tensor_is_a_point_mass():
    xml = robot(link("a") + link("b", '<inertial><origin xyz="0 0 -1"/><mass value="2"/></inertial>'),
                joint("j1", "a", "b"))
    model = mb.load_urdf(xml)
    assert model.joint_inertias[0].mass == 2.0
    assert_allclose(model.joint_inertias[0].com, [0, 0, -1])
    assert_allclose(model.joint_inertias[0].rotational, np.zeros((3, 3)))


def test_massless_links_are_allowed():
    xml = robot(link("a") + link("massless") + link("tip", INERTIAL),
                joint("j1", "a", "massless") + joint("j2", "massless", "tip", kind="continuous"))
    model = mb.load_urdf(xml)
    assert model.joint_inertias[0].mass == 0.0
    assert_allclose(model.joint_inertias[0].rotational, np.zeros((3, 3)))
    assert model.total_mass == pytest.approx(1.0)


def test_inertial_origin_rotation_matches_pinocchio():
    pin = import_pinocchio()
    origin = '<origin xyz="0.1 -0.2 0.3" rpy="0.4 -0.7 1.9"/>'
    xml = robot(link("a") + link("b", inertial(2.0, 0.3, 0.2, 0.25, 0.01, -0.02, 0.03, origin=origin)),
                joint("j1", "a", "b"))
    model = mb.load_urdf(xml)
    theirs = pin.buildModelFromXML(xml).inertias[1]
    ours = model.joint_inertias[0]
    assert ours.mass == pytest.approx(theirs.mass)
    assert_allclose(ours.com, theirs.lever, atol=1e-15)
    assert_allclose(ours.rotational, theirs.inertia, atol=1e-15)
    # and by hand: c = p, I = R I_inertial Rᵀ
    R = mb.spatial.rpy_to_rotation([0.4, -0.7, 1.9])
    tensor = np.array([[0.3, 0.01, -0.02], [0.01, 0.2, 0.03], [-0.02, 0.03, 0.25]])
    assert_allclose(ours.com, [0.1, -0.2, 0.3])
    assert_allclose(ours.rotational, R @ tensor @ R.T, atol=1e-15)


def test_missing_mesh_does_not_fail(tmp_path):
    visual = ('<visual><geometry><mesh filename="package://nowhere/meshes/part.stl"/></geometry></visual>'
              '<collision><geometry><mesh filename="meshes/missing.dae" scale="2 2 2"/></geometry></collision>'
              '<visual><origin xyz="0 0 0.5"/><geometry><box size="0.1 0.2 0.3"/></geometry></visual>')
    xml = robot(link("a") + link("b", INERTIAL + visual), joint("j1", "a", "b"))
    path = tmp_path / "meshes.urdf"
    path.write_text(xml)
    with pytest.warns(UserWarning, match="2 mesh file\\(s\\) not found") as record:
        model = mb.load_urdf(str(path), package_dirs=[str(tmp_path)])
    assert len([w for w in record if "mesh" in str(w.message)]) == 1  # one warning per file, not per mesh
    assert mb.mass_matrix(model, np.zeros(model.nq)).shape == (1, 1)  # the dynamics are unaffected
    meshes = [g for g in model.geometries if g.shape == "mesh"]
    assert len(meshes) == 2
    assert all(g.filename is None for g in meshes)
    assert {g.uri for g in meshes} == {"package://nowhere/meshes/part.stl", "meshes/missing.dae"}
    assert meshes[1].kind == "collision" and tuple(meshes[1].scale) == (2.0, 2.0, 2.0)
    box = [g for g in model.geometries if g.shape == "box"][0]
    assert box.body == "b" and tuple(box.size) == (0.1, 0.2, 0.3)
    assert_allclose(box.placement[:3, 3], [0, 0, 0.5])
    # the dynamics does not need the meshes; asking for them warns instead of failing
    geometry = pytest.importorskip("multibody.geometry")
    with pytest.warns(UserWarning, match="not found"):
        loaded = geometry.load_meshes(model, "visual")
    assert [m is None for _, m in loaded] == [True, False]


def test_existing_mesh_is_resolved(tmp_path):
    (tmp_path / "pkg" / "meshes").mkdir(parents=True)
    (tmp_path / "pkg" / "meshes" / "part.stl").write_text("solid x\nendsolid x\n")
    visual = '<visual><geometry><mesh filename="package://pkg/meshes/part.stl"/></geometry></visual>'
    xml = robot(link("a", visual), "")
    model = mb.load_urdf(xml, package_dirs=str(tmp_path))
    assert model.geometries[0].filename == str(tmp_path / "pkg" / "meshes" / "part.stl")


def test_path_like_source(tmp_path):
    path = tmp_path / "p.urdf"
    path.write_text(robot(link("a") + link("b", INERTIAL), joint("j1", "a", "b")))
    model = mb.load_urdf(pathlib.Path(path))
    assert model.joint_names == ("j1",)


def test_world_root_link_is_the_world():
    # A root link named "world" is the world itself; with a floating base it is an ordinary body.
    xml = robot(link("world") + link("b", INERTIAL), joint("j1", "world", "b"))
    model = mb.load_urdf(xml)
    assert model.body_names == ("b",)
    floating = mb.load_urdf(xml, floating_base=True)
    assert floating.body_names[0] == "world" and floating.joint_names == ("root_joint", "j1")


def test_child_joints_ordered_by_name_depth_first():
    xml = robot(link("base") + "".join(link(n, INERTIAL) for n in ("l1", "l2", "l3", "l4")),
                joint("zeta", "base", "l1") + joint("alpha", "base", "l2") + joint("mid", "l2", "l3")
                + joint("beta", "base", "l4"))
    model = mb.load_urdf(xml)
    assert model.joint_names == ("alpha", "mid", "beta", "zeta")
    pin = import_pinocchio()
    assert list(pin.buildModelFromXML(xml).names)[1:] == list(model.joint_names)


# ----------------------------------------------------------------------------- every joint type

ALL_TYPES_XML = robot(
    link("base", inertial(5.0, 0.2, 0.3, 0.25))
    + "".join(link(n, inertial(1.0 + 0.1 * k, 0.02 + 0.01 * k, 0.03, 0.025 + 0.005 * k,
                                origin=f'<origin xyz="0.{k} 0.05 -0.1" rpy="0.{k} 0.2 -0.3"/>'))
              for k, n in enumerate(["rev", "cont", "pris", "fixed_link", "free", "plan", "rev2"]))
    + link("tip"),
    joint("j_rev", "base", "rev", origin='<origin xyz="0 0 0.5" rpy="0.1 0.2 0.3"/>', extra='<axis xyz="0 1 1"/>')
    + joint("j_cont", "rev", "cont", kind="continuous", origin='<origin xyz="0.3 0 0" rpy="0 0.5 0"/>',
            extra='<axis xyz="1 0 0"/>')
    + joint("j_pris", "cont", "pris", kind="prismatic", origin='<origin xyz="0 0.2 0"/>', extra='<axis xyz="0 0 1"/>')
    + joint("j_fixed", "pris", "fixed_link", kind="fixed", origin='<origin xyz="0 0 0.1" rpy="1 0 0"/>', extra="")
    + joint("j_free", "fixed_link", "free", kind="floating", origin='<origin xyz="0.1 0.1 0.1"/>', extra="")
    + joint("j_plan", "base", "plan", kind="planar", origin='<origin xyz="-0.5 0 0" rpy="0 0 0.7"/>',
            extra='<axis xyz="0 0 1"/>')
    + joint("j_rev2", "plan", "rev2", origin='<origin xyz="0 0 0.2"/>', extra='<axis xyz="0 0 1"/>')
    + joint("j_tip", "rev2", "tip", kind="fixed", origin='<origin xyz="0.3 0.1 0"/>', extra=""),
    name="all_types",
)


def test_every_joint_type_loads_with_right_sizes():
    model = mb.load_urdf(ALL_TYPES_XML)
    kinds = dict(zip(model.joint_names, (j.kind for j in model.joints)))
    assert kinds == {"j_rev": "revolute", "j_cont": "continuous", "j_pris": "prismatic",
                     "j_free": "free-flyer", "j_plan": "planar", "j_rev2": "revolute"}
    # revolute 1 + continuous 1 + prismatic 1 + floating 7 + planar 4 + revolute 1
    assert model.nq == 15 and model.nv == 13
    assert set(model.body_names) == {"base", "rev", "cont", "pris", "fixed_link", "free", "plan", "rev2", "tip"}
    floating = mb.load_urdf(ALL_TYPES_XML, floating_base=True)
    assert floating.nq == 22 and floating.nv == 19


@pytest.mark.parametrize("floating_base", [False, True], ids=["fixed", "floating"])
def test_every_joint_type_forward_kinematics_matches_pinocchio(floating_base):
    pin = import_pinocchio()
    model = mb.load_urdf(ALL_TYPES_XML, floating_base=floating_base)
    pmodel = pin.buildModelFromXML(ALL_TYPES_XML, pin.JointModelFreeFlyer()) if floating_base \
        else pin.buildModelFromXML(ALL_TYPES_XML)
    assert list(pmodel.names)[1:] == list(model.joint_names)
    assert pmodel.nq == pinocchio_nq(model) and pmodel.nv == model.nv
    data = pmodel.createData()
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = model.random_configuration(rng)
        pin.forwardKinematics(pmodel, data, q_to_pinocchio(model, q))
        pin.updateFramePlacements(pmodel, data)
        X = mb.forward_kinematics(model, q)
        for b, name in enumerate(model.body_names):
            fid = pmodel.getFrameId(name, pin.BODY)
            assert_allclose(X[b], data.oMf[fid].homogeneous, atol=1e-12, err_msg=name)
    for i, ours in enumerate(model.joint_inertias):
        assert_allclose(ours.spatial, pmodel.inertias[i + 1].matrix(), atol=1e-13)


def test_planar_axis_other_than_z_warns():
    xml = robot(link("a") + link("b", INERTIAL), joint("p", "a", "b", kind="planar", extra='<axis xyz="1 0 0"/>'))
    with pytest.warns(UserWarning, match="ignored"):
        model = mb.load_urdf(xml)
    assert model.joints[0].kind == "planar"
