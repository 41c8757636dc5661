"""The 3-D viewer (multibody/viewer.py): the scene it computes, the server and its controls, the
offline page, ``multibody view``, and, in headless Chromium, the pixels a browser shows.

The browser test (marked ``browser``) drives Chromium through the DevTools protocol; it is skipped
when no ``chromium`` binary is on PATH (``apt-get install chromium``).
"""

import base64
import dataclasses
import importlib.util
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request

import numpy as np
import pytest

import multibody as mb
from multibody import viewer as viewer_module
from multibody.cli import main
from multibody.contact import Contacts
from multibody.viewer import equivalent_inertia_box, scene_of

needs_viser = pytest.mark.skipif(importlib.util.find_spec("viser") is None,
                                 reason="serving the viewer needs Viser: pip install multibody[viz]")


def synthetic_trajectory(q, t, lam=None):
    """A Trajectory of given configurations ``q (n, nq)`` at ``t (n,)``, at rest (no simulation needed;
    ``v`` as wide as ``q``, which is ``nv`` for the models without quaternions that it serves)."""
    n = len(t)
    q = np.asarray(q, float)
    return mb.Trajectory(t=np.asarray(t, float), q=q, v=np.zeros((n, q.shape[-1])),
                         lam=np.zeros((n, 0)) if lam is None else np.asarray(lam, float), energy=np.zeros(n),
                         residual=np.zeros(n))


@pytest.fixture(scope="module")
def pendulum():
    return mb.robots.load("double_pendulum")


@pytest.fixture(scope="module")
def swing():
    """The double pendulum swinging from hanging (t = 0) to both links horizontal (t = 1 s)."""
    t = np.linspace(0.0, 1.0, 51)
    return synthetic_trajectory(np.stack([np.pi / 2 * t, 0.0 * t], axis=1), t)


def port_is_free(port):
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


# ============================================================================= the scene (no server)

def test_equivalent_inertia_box_has_the_mass_and_principal_moments():
    m, edges = 2.0, np.array([0.3, 0.2, 0.1])
    R = mb.spatial.rpy_to_rotation([0.3, -0.2, 0.5])
    box = mb.inertia.box(m, edges)
    rotated = mb.Inertia(m, [0.1, 0.2, 0.3], R @ box.rotational @ R.T)
    found, pose = equivalent_inertia_box(rotated)
    np.testing.assert_allclose(np.sort(found), np.sort(edges), rtol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [0.1, 0.2, 0.3])
    # the box's axes are the principal axes: the box inertia turned by the pose is the body's
    I_box = np.diag(m / 12 * (np.sum(found**2) - found**2))
    np.testing.assert_allclose(pose[:3, :3] @ I_box @ pose[:3, :3].T, rotated.rotational, atol=1e-14)
    assert np.isclose(np.linalg.det(pose[:3, :3]), 1.0)
    assert equivalent_inertia_box(mb.Inertia.zero()) is None


def test_scene_one_pose_per_body_and_frame_from_forward_kinematics(pendulum, swing):
    scene = scene_of(pendulum, trajectory=swing, trace=["link2", ("link2", [0.0, 0.0, -1.0])])
    X = mb.forward_kinematics(pendulum, swing.q)
    assert scene.body_names == pendulum.body_names
    assert scene.positions.shape == (51, pendulum.nbodies, 3) and scene.wxyz.shape == (51, pendulum.nbodies, 4)
    np.testing.assert_allclose(scene.positions, X[..., :3, 3])
    w, xyz = scene.wxyz[..., 0], scene.wxyz[..., 1:]
    np.testing.assert_allclose(mb.spatial.quat_to_rotation(np.concatenate([xyz, w[..., None]], -1)), X[..., :3, :3],
                               atol=1e-12)
    tip = scene.traces["link2 [0.0, 0.0, -1.0]"]
    np.testing.assert_allclose(tip[-1], [-2.0, 0.0, 0.0], atol=1e-12)       # both links horizontal
    # visual cylinders for the links; the massless base and tip have none
    assert [len(scene.shapes[name]) for name in pendulum.body_names] == [0, 1, 1, 0]


def test_bodies_without_visuals_get_their_equivalent_inertia_box_or_a_point():
    builder = mb.ModelBuilder("bodies")
    builder.add_body("slab", joint=mb.joints.FreeFlyer(), inertia=mb.inertia.box(3.0, [0.4, 0.2, 0.05]))
    builder.add_body("bead", joint=mb.joints.Prismatic([1.0, 0.0, 0.0]), parent="slab",
                     inertia=mb.inertia.point_mass(0.1))
    model = builder.build()
    scene = scene_of(model, point_radius=0.01)
    (slab,), (bead,) = scene.shapes["slab"], scene.shapes["bead"]
    assert slab.kind == "inertia box" and bead.kind == "point mass"
    np.testing.assert_allclose(np.ptp(slab.vertices, axis=0), [0.4, 0.2, 0.05], atol=1e-12)
    np.testing.assert_allclose(np.ptp(bead.vertices, axis=0), 0.02, rtol=0.05)


def test_rolling_contact_force_is_an_arrow_from_the_contact_point_in_newtons():
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    tilt = 0.2
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    contact = mb.RollingSphere("ball", 0.1, plane_normal=normal)
    q = ball.neutral()
    q[:3] = 0.1 * normal
    weight = 9.81 * np.cos(tilt)
    lam = np.array([[0.0, 0.0, weight], [1.0, -2.0, weight]])                # (friction t₁, t₂, normal) N
    trajectory = synthetic_trajectory(np.stack([q, q]), [0.0, 0.1], lam)
    scene = scene_of(ball, trajectory=trajectory, constraints=mb.ConstrainedSystem(ball, [contact]),
                     force_scale=0.01)
    assert scene.arrows.shape == (2, 1, 2, 3) and scene.force_scale == 0.01
    np.testing.assert_allclose(scene.arrows[:, 0, 0], 0.0, atol=1e-12)       # the contact point, the origin
    np.testing.assert_allclose(scene.arrows[0, 0, 1], 0.01 * weight * normal, atol=1e-12)
    np.testing.assert_allclose(scene.arrows[1, 0, 1], 0.01 * contact.frame @ lam[1], atol=1e-12)
    assert scene.largest_force == pytest.approx(np.linalg.norm(lam[1]))
    assert len(scene.planes) == 1 and np.allclose(scene.planes[0][0], contact.frame)


@pytest.fixture(scope="module")
def gripper():
    """A 0.4 m palm turning about z and a finger on it sliding along x (inertia boxes, no visuals)."""
    builder = mb.ModelBuilder("gripper")
    builder.add_body("palm", joint=mb.joints.Revolute(axis=(0.0, 0.0, 1.0)),
                     inertia=mb.inertia.box(1.0, [0.4, 0.2, 0.1]))
    builder.add_body("finger", joint=mb.joints.Prismatic(axis=(1.0, 0.0, 0.0)), parent="palm",
                     inertia=mb.inertia.box(0.1, [0.02, 0.02, 0.1], center=[0.0, 0.0, 0.1]))
    return builder.build()


def test_the_view_frames_the_bodies_at_the_first_frame_not_a_part_flying_off(gripper):
    # the finger flies 15 m away in the second half, as in a simulation that blows up
    t = np.linspace(0.0, 1.0, 11)
    q = np.stack([0.3 * t, np.where(t > 0.5, 15.0 * t, 0.05)], axis=1)
    scene = scene_of(gripper, trajectory=synthetic_trajectory(q, t))
    first = scene_of(gripper, q=q[0])
    # whole-motion box for the ground, first-frame box for the camera and the scale
    assert scene.high[0] > 14.0
    np.testing.assert_allclose(scene.start_low, first.low, atol=1e-12)
    np.testing.assert_allclose(scene.start_high, first.high, atol=1e-12)
    assert scene.size == pytest.approx(first.size) and scene.size < 0.6
    np.testing.assert_allclose(scene.center, 0.5 * (first.low + first.high), atol=1e-12)
    # the first frame's box: the palm's inertia box and the finger standing 0.1 m on it
    np.testing.assert_allclose(first.low, [-0.2, -0.1, -0.05], atol=1e-12)
    np.testing.assert_allclose(first.high, [0.2, 0.1, 0.15], atol=1e-12)


@needs_viser
def test_the_camera_looks_at_the_bodies_where_they_start(gripper):
    t = np.linspace(0.0, 1.0, 11)
    q = np.stack([0.0 * t, np.where(t > 0.5, 15.0 * t, 0.05)], axis=1)
    with mb.view(gripper, trajectory=synthetic_trajectory(q, t), port=0) as viewer:
        scene = viewer.scene
        look_at = np.array(viewer.server.initial_camera.look_at)
        position = np.array(viewer.server.initial_camera.position)
        np.testing.assert_allclose(look_at, scene.center, atol=1e-6)
        assert np.all(scene.start_low - 1e-6 <= look_at) and np.all(look_at <= scene.start_high + 1e-6)
        assert np.linalg.norm(position - look_at) < 3 * scene.size < 2.0


def test_point_constraint_forces_act_at_their_point_and_coordinate_ones_are_named():
    builder = mb.ModelBuilder("bead", gravity=(0.0, 0.0, -9.81))
    builder.add_body("bead", joint=mb.joints.Translation(), inertia=mb.inertia.point_mass(0.2))
    bead = builder.build()
    ring = mb.PointOnSurface("bead", lambda x: x @ x - 1.0, gradient=lambda x: 2 * x)
    held = mb.Holonomic(lambda q, t: q[:1], name="x held")
    q = np.array([[0.0, 0.6, 0.8], [0.0, 0.8, 0.6]])
    scene = scene_of(bead, trajectory=synthetic_trajectory(q, [0.0, 1.0], [[1.0, 5.0], [2.0, 5.0]]),
                     constraints=[ring, held], force_scale=0.1)
    np.testing.assert_allclose(scene.arrows[:, 0, 0], q, atol=1e-12)         # at the bead
    np.testing.assert_allclose(scene.arrows[:, 0, 1] - q, 0.1 * 2 * q * [[1.0], [2.0]], atol=1e-12)
    assert scene.no_arrows == ("x held",)


def test_force_scales_are_round_numbers():
    assert viewer_module._nice(0.0737) == 0.05 and viewer_module._nice(1.0) == 1.0 and viewer_module._nice(3.0) == 2.0


def test_bad_input_is_refused_with_a_clear_error(pendulum, swing):
    cases = [
        (dict(q=np.zeros(3)), ValueError, "shape"),
        (dict(q=np.zeros(2), trajectory=swing), ValueError, "not both"),
        (dict(trajectory=synthetic_trajectory(np.zeros((3, 3)), [0, 1, 2])), ValueError, "nq = 3"),
        (dict(trajectory=synthetic_trajectory(np.full((2, 2), np.nan), [0, 1])), ValueError, "non-finite"),
        (dict(trajectory=synthetic_trajectory(np.zeros((2, 2)), [1, 0])), ValueError, "non-decreasing"),
        (dict(trajectory=synthetic_trajectory(np.zeros((0, 2)), [])), ValueError, "empty"),
        (dict(trajectory="swing.npz"), TypeError, "Trajectory"),
        (dict(trajectory=swing, trace=["hand"]), ValueError, "no body 'hand'"),
        (dict(trajectory=swing, trace=[("link2", [1.0, 2.0])]), ValueError, "(3,)"),
        (dict(trajectory=swing, constraints=[mb.Distance("link2", None, 1.0)]), ValueError, "1 rows"),
        (dict(trajectory=swing, constraints=["rod"]), TypeError, "constraints"),
        (dict(constraints=[mb.Distance("link2", None, 1.0)]), ValueError, "pass trajectory="),
    ]
    for kwargs, error, words in cases:
        with pytest.raises(error, match=words.replace("(", r"\(").replace(")", r"\)")):
            scene_of(pendulum, **kwargs)
    with pytest.raises(TypeError, match="multibody Model"):
        scene_of("double_pendulum")
    ball = mb.load_urdf(mb.robots.path("ball"))
    with pytest.raises(ValueError, match="floating_base=True"):
        scene_of(ball, trajectory=synthetic_trajectory(np.zeros((2, 7)) + [0, 0, 0, 0, 0, 0, 1], [0, 1]))
    with pytest.raises(ValueError, match="force_scale"):
        contact = mb.Distance("link2", None, 1.0)
        scene_of(pendulum, trajectory=synthetic_trajectory(swing.q, swing.t, np.ones((51, 1))), constraints=[contact],
                 force_scale=0.0)


@needs_viser
def test_bad_options_are_refused(pendulum):
    with pytest.raises(TypeError, match="unknown options"):
        mb.view(pendulum, colour="red")
    with pytest.raises(ValueError, match="port"):
        mb.view(pendulum, port=-1)


def test_missing_viser_names_the_viz_extra(monkeypatch, pendulum):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser now raises ImportError
    with pytest.raises(ImportError, match=r"pip install multibody\[viz\]"):
        mb.view(pendulum)


def test_importing_multibody_does_not_import_viser():
    code = "import sys, multibody as mb; assert 'viser' not in sys.modules; mb.view; assert 'viser' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


# ============================================================================= contacts

def entry(rows):
    """One entry of ``Trajectory.contacts`` from its rows ``[(body, other, point, normal, force), ...]``."""
    columns = list(zip(*rows)) if rows else [(), (), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))]
    return Contacts(np.array(columns[0], dtype=str), np.array(columns[1], dtype=str),
                    *(np.array(c, dtype=float).reshape(-1, 3) for c in columns[2:]))


def contact_trajectory(q, t, entries):
    """A trajectory of configurations ``q (n, nq)`` at ``t (n,)`` with ``contacts`` ``entries``."""
    return dataclasses.replace(synthetic_trajectory(q, t), contacts=entries)


@pytest.fixture(scope="module")
def slab():
    """A free 0.4 × 0.2 × 0.1 m box of 2 kg (drawn as its inertia box) on a slider, with a joint limit."""
    builder = mb.ModelBuilder("slab")
    builder.add_body("rail", joint=mb.joints.Prismatic(axis=(1.0, 0.0, 0.0)), inertia=mb.inertia.point_mass(0.5))
    builder.add_body("slab", joint=mb.joints.FreeFlyer(), parent="rail", inertia=mb.inertia.box(2.0, [0.4, 0.2, 0.1]))
    return builder.build()


@pytest.fixture(scope="module")
def sliding(slab):
    """The slab resting on the ground (t = 0.1 s), then slid 0.3 m along x (t = 0.2 s): its four lower corners
    pushed up by the ground, one corner not pushed at 0.2 s, the rail at its limit; entries 0 and 3 empty."""
    t = [0.0, 0.1, 0.2, 0.3]
    q = np.tile(slab.neutral(), (4, 1))
    q[:, 3] = 0.05                                      # the slab's centre 5 cm up: its lower face on z = 0
    q[2:, 1] = 0.3
    corners = np.array([[x, y, 0.0] for x in (-0.2, 0.2) for y in (-0.1, 0.1)])
    up, zero = np.array([0.0, 0.0, 1.0]), np.zeros(3)
    resting = [("slab", "ground", c, up, [0.0, 0.0, 2.5 * 9.81 / 4]) for c in corners]
    slid = [("slab", "ground", c + [0.3, 0.0, 0.0], up, [-1.0 - k, 0.5, 4.0 + k]) for k, c in enumerate(corners[:3])]
    slid.append(("slab", "ground", corners[3] + [0.3, 0.0, 0.0], up, zero))
    limit = ("rail", "limit", zero, zero, [-3.0, 0.0, 0.0])
    return contact_trajectory(q, t, [entry([]), entry(resting + [limit]), entry([limit] + slid), entry([])])


def test_contact_points_and_force_arrows_per_frame_joint_limits_left_out(slab, sliding):
    scene = scene_of(slab, trajectory=sliding, force_scale=0.01)
    assert len(scene.contact_points) == len(scene.contact_arrows) == 4
    assert scene.contact_points[0].shape == (0, 3) and scene.contact_arrows[0].shape == (0, 2, 3)
    assert scene.contact_points[3].shape == (0, 3) and scene.contact_arrows[3].shape == (0, 2, 3)
    for k in (1, 2):
        touching = sliding.contacts[k].other != "limit"
        points, forces = sliding.contacts[k].point[touching], sliding.contacts[k].force[touching]
        np.testing.assert_array_equal(scene.contact_points[k], points)
        pushing = np.linalg.norm(forces, axis=1) > 0.0
        arrows = scene.contact_arrows[k]
        assert arrows.shape == (pushing.sum(), 2, 3)
        np.testing.assert_array_equal(arrows[:, 0], points[pushing])
        np.testing.assert_allclose(arrows[:, 1] - arrows[:, 0], 0.01 * forces[pushing], rtol=1e-15, atol=1e-15)
    assert len(scene.contact_points[2]) == 4 and len(scene.contact_arrows[2]) == 3   # the unpushed corner: no arrow
    assert scene.largest_force == pytest.approx(np.linalg.norm([-3.0, 0.5, 6.0]))   # the limit's 3 N·m not counted


def test_contact_arrows_default_to_the_weight_as_long_as_the_bodies_size(slab, sliding):
    scene = scene_of(slab, trajectory=sliding)
    weight = 2.5 * 9.81
    assert scene.force_scale == viewer_module._nice(scene.size / weight)
    assert scene.force_scale * weight <= scene.size < 2.5 * scene.force_scale * weight


def test_joint_limits_alone_draw_no_contacts(slab, sliding):
    limit_only = [entry([]), entry([("rail", "limit", np.zeros(3), np.zeros(3), [-3.0, 0.0, 0.0])]), entry([]),
                  entry([])]
    scene = scene_of(slab, trajectory=contact_trajectory(sliding.q, sliding.t, limit_only))
    assert scene.contact_points == () and scene.contact_arrows == () and scene.force_scale == 0.0
    plain = scene_of(slab, trajectory=contact_trajectory(sliding.q, sliding.t, None))
    assert plain.contact_points == ()


def test_bad_contacts_are_refused_naming_the_entry(slab, sliding):
    good = list(sliding.contacts)
    wrong_shape = good[:1] + [dataclasses.replace(good[1], point=good[1].point[:, :2])] + good[2:]
    infinite = good[:2] + [dataclasses.replace(good[2], force=np.full((5, 3), np.inf))] + good[3:]
    cases = [(good[:3], ValueError, "3 entries but the trajectory 4 times"),
             (good[:1] + ["contact"] + good[2:], TypeError, r"trajectory.contacts\[1\] must have"),
             (wrong_shape, ValueError, r"trajectory.contacts\[1\]: other, point and force"),
             (infinite, ValueError, r"trajectory.contacts\[2\] \(t = 0.2 s\) has non-finite")]
    for entries, error, words in cases:
        with pytest.raises(error, match=words):
            scene_of(slab, trajectory=contact_trajectory(sliding.q, sliding.t, entries))


def test_a_simulated_box_slides_with_its_contacts_drawn():
    builder = mb.ModelBuilder("box")
    builder.add_body("box", joint=mb.joints.FreeFlyer(), inertia=mb.inertia.box(1.0, (0.2, 0.2, 0.1)))
    builder.add_collision("box", "box", (0.2, 0.2, 0.1))
    box = builder.build()
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])
    # dropped 1 cm, sliding along x
    slide = mb.simulate(system, [0, 0, 0.06, 0, 0, 0, 1], [1.0, 0, 0, 0, 0, 0], 0.1, dt=1e-3)
    scene = scene_of(box, trajectory=slide, force_scale=0.02)
    assert len(slide.contacts[0]) == 0 and scene.contact_points[0].shape == (0, 3)
    touching = [k for k, found in enumerate(slide.contacts) if len(found)]
    assert touching and len(slide.contacts[-1]) == 4            # the four lower corners, on the ground at the end
    for k in touching:
        np.testing.assert_array_equal(scene.contact_points[k], slide.contacts[k].point)
        pushing = np.linalg.norm(slide.contacts[k].force, axis=1) > 0.0
        np.testing.assert_allclose(scene.contact_arrows[k][:, 1] - scene.contact_arrows[k][:, 0],
                                   0.02 * slide.contacts[k].force[pushing], rtol=1e-15, atol=1e-15)
    # the corners move with the box: centred under it as it was at the start of the step (where the step
    # detects its contacts), one step before the entry's time
    flat = [k for k in touching if len(slide.contacts[k]) == 4]
    assert slide.q[flat[-1], 0] - slide.q[flat[0], 0] > 0.01
    np.testing.assert_allclose([scene.contact_points[k].mean(axis=0)[:2] for k in flat],
                               slide.q[np.array(flat) - 1, :2], atol=1e-9)


@needs_viser
def test_the_viewer_draws_contacts_moving_with_the_frame_scaled_and_hidden_by_a_checkbox(slab, sliding):
    with mb.view(slab, trajectory=sliding, port=0, force_scale=0.01) as viewer:
        scene = viewer.scene
        points, arrows = viewer._contacts
        assert (points.name, arrows.name) == ("/contacts/points", "/contacts/forces")
        assert "contacts" in viewer.layers and "forces" not in viewer.layers
        # entry 0 is empty: nothing drawn
        assert points.batched_positions.shape == (0, 3) and arrows.points.shape == (0, 2, 3)
        for k in (1, 2, 3, 1):
            viewer.time = sliding.t[k]
            assert points.batched_positions.shape == points.batched_wxyzs.shape[:1] + (3,)
            np.testing.assert_allclose(points.batched_positions, scene.contact_points[k], atol=1e-6)
            np.testing.assert_allclose(arrows.points, scene.contact_arrows[k], atol=1e-6)
        # an arrow is as long as its force times the scale
        viewer.time = sliding.t[2]
        forces = sliding.contacts[2].force[1:4]
        lengths = np.linalg.norm(arrows.points[:, 1] - arrows.points[:, 0], axis=1)
        np.testing.assert_allclose(lengths, 0.01 * np.linalg.norm(forces, axis=1), rtol=1e-6)
        # the panel's scale (as a browser sets it) and Viewer.force_scale redraw the arrows from the same tails
        viewer._scale_input.value = 0.03
        assert viewer.force_scale == 0.03
        np.testing.assert_allclose(arrows.points[:, 1] - arrows.points[:, 0], 0.03 * forces, rtol=1e-6, atol=1e-7)
        viewer.force_scale = 0.005
        assert viewer._scale_input.value == 0.005
        np.testing.assert_allclose(arrows.points[:, 0], scene.contact_arrows[2][:, 0], atol=1e-6)
        np.testing.assert_allclose(arrows.points[:, 1] - arrows.points[:, 0], 0.005 * forces, rtol=1e-6, atol=1e-7)
        viewer.time = sliding.t[1]                         # another frame keeps the chosen scale
        np.testing.assert_allclose(arrows.points[:, 1] - arrows.points[:, 0],
                                   0.005 * sliding.contacts[1].force[:4], rtol=1e-6, atol=1e-7)
        with pytest.raises(ValueError, match="force_scale"):
            viewer.force_scale = 0.0
        viewer.layers["contacts"].value = False
        assert not points.visible and not arrows.visible
        viewer.layers["contacts"].value = True
        assert points.visible and arrows.visible


# ============================================================================= the server and its controls

@needs_viser
def test_viewer_has_one_node_per_body_a_slider_over_the_time_span_and_close_frees_the_port(pendulum, swing):
    viewer = mb.view(pendulum, trajectory=swing, port=0, trace=["link2"])
    port = viewer.port
    try:
        assert not port_is_free(port) and viewer.url.endswith(f":{port}")
        assert list(viewer.nodes) == list(pendulum.body_names)
        names = {node.name for node in viewer.nodes.values()}
        assert len(names) == pendulum.nbodies and all(name.startswith("/bodies/") for name in names)
        assert (viewer.slider.min, viewer.slider.max) == (swing.t[0], swing.t[-1])
        assert set(viewer.layers) == {"bodies", "body frames", "ground", "paths"}
        viewer.layers["body frames"].value = False
        assert not any(node.show_axes for node in viewer.nodes.values())
        # the page's HTML is served
        with urllib.request.urlopen(viewer.url, timeout=10) as response:
            assert response.status == 200 and b"<html" in response.read(2000).lower()
        # setting the time shows the nearest frame and moves the slider
        viewer.time = 0.513                       # frames every 0.02 s: the nearest is t = 0.52 s
        k = 26
        assert viewer.frame == k and viewer.slider.value == pytest.approx(swing.t[k])
        b = pendulum.body_index("link2")
        np.testing.assert_allclose(viewer.nodes["link2"].position, viewer.scene.positions[k, b], atol=1e-6)
        # the slider (as a browser moves it) drives the frame too
        viewer.slider.value = float(swing.t[40])
        assert viewer.frame == 40
        viewer.play()
        assert viewer.playing
        time.sleep(0.3)
        viewer.pause()
        assert not viewer.playing
        with pytest.raises(ValueError, match="finite"):
            viewer.time = float("nan")
    finally:
        viewer.close()
    assert viewer.closed and port_is_free(port)
    viewer.close()  # twice is harmless


@needs_viser
def test_a_single_configuration_has_no_slider(pendulum):
    with mb.view(pendulum, q=[0.3, 0.4], port=0) as viewer:
        assert viewer.slider is None and viewer.scene.frames == 1 and viewer.time == 0.0
        np.testing.assert_allclose(viewer.scene.positions[0], mb.forward_kinematics(pendulum, [0.3, 0.4])[:, :3, 3])


@needs_viser
def test_save_html_writes_a_self_contained_page(pendulum, swing, tmp_path):
    with mb.view(pendulum, trajectory=swing, port=0) as viewer:
        viewer.time = 0.5
        path = viewer.save_html(tmp_path / "swing.html")
        assert viewer.time == pytest.approx(0.5)           # the time shown is restored
    text = open(path, encoding="utf-8").read()
    assert text.lstrip().lower().startswith("<!doctype html") and "__VISER_EMBED_DATA__" in text
    assert "http://" not in text.split("__VISER_EMBED_DATA__")[1][:200]  # the scene is inline


# ============================================================================= multibody view

@needs_viser
def test_cli_view_writes_the_offline_page_of_a_saved_trajectory(pendulum, swing, tmp_path, capsys):
    saved = swing.save(tmp_path / "swing.npz")
    page = tmp_path / "swing.html"
    assert main(["view", "double_pendulum", "--trajectory", saved, "--port", "0", "--trace", "link2",
                 "--html", str(page)]) == 0
    assert page.is_file() and page.stat().st_size > 100_000
    assert f"wrote {page}" in capsys.readouterr().out


@needs_viser
def test_cli_view_serves_until_interrupted(monkeypatch, capsys):
    opened = []
    real_view = viewer_module.view

    def spy(*args, **kwargs):
        opened.append(real_view(*args, **kwargs))
        return opened[-1]

    def interrupt(seconds):
        raise KeyboardInterrupt

    monkeypatch.setattr(viewer_module, "view", spy)
    monkeypatch.setattr(time, "sleep", interrupt)
    assert main(["view", "double_pendulum", "--port", "0"]) == 0
    assert "3-D viewer at http://localhost:" in capsys.readouterr().out
    assert opened and opened[0].closed


@needs_viser
def test_cli_view_reports_bad_input_in_one_line(tmp_path, swing, capsys):
    saved = swing.save(tmp_path / "swing.npz")
    for argv, words in [
        (["view", str(tmp_path / "missing.urdf")], "no such file"),
        (["view", "double_pendulum", "--trajectory", str(tmp_path / "missing.npz")], "no such file"),
        (["view", "double_pendulum", "--trajectory", str(tmp_path)], "is a directory"),
        (["view", "ball", "--trajectory", saved], "nq = 2"),
    ]:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("multibody view: ") and words in err and err.count("\n") == 1, err


# ============================================================================= in a real browser

def chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


class Chromium:
    """Headless Chromium driven through the DevTools protocol: ``navigate(url)``, ``screenshot()``."""

    def __init__(self, width=1000, height=700):
        from websockets.sync.client import connect

        self.profile = tempfile.mkdtemp(prefix="multibody-chromium-")
        # software WebGL (SwiftShader): no GPU is needed
        self.process = subprocess.Popen(
            [chromium(), "--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             f"--window-size={width},{height}", "--remote-debugging-port=0", f"--user-data-dir={self.profile}",
             "--no-first-run", "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        active = os.path.join(self.profile, "DevToolsActivePort")
        deadline = time.monotonic() + 60
        while not (os.path.exists(active) and len(open(active).read().split()) >= 2):
            if time.monotonic() > deadline or self.process.poll() is not None:
                self.close()
                raise RuntimeError("chromium did not open its DevTools port")
            time.sleep(0.1)
        port = int(open(active).read().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as response:
            page = next(p for p in json.load(response) if p["type"] == "page")
        self.socket = connect(page["webSocketDebuggerUrl"], max_size=None)
        self.calls = 0

    def call(self, method, **params):
        self.calls += 1
        self.socket.send(json.dumps({"id": self.calls, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv(timeout=60))
            if message.get("id") == self.calls:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def navigate(self, url, timeout=60.0):
        """Open ``url`` and wait for its load event."""
        self.call("Page.enable")
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if json.loads(self.socket.recv(timeout=timeout)).get("method") == "Page.loadEventFired":
                return
        raise TimeoutError(f"{url} did not load in {timeout} s")

    def screenshot(self):
        """The page as an ``(h, w, 3)`` int array."""
        from PIL import Image

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(int)

    def close(self):
        if getattr(self, "socket", None) is not None:
            self.socket.close()
        self.process.terminate()
        self.process.wait(timeout=30)
        shutil.rmtree(self.profile, ignore_errors=True)


def scene_pixels(image):
    """``(k, 3)`` the pixels where only the 3-D scene is drawn: all but the browser's software-rendering
    notice (top left), the control panel (top right) and the offline page's time bar (bottom)."""
    height, width = image.shape[:2]
    mask = np.ones((height, width), dtype=bool)
    mask[:170, :330] = False
    mask[:330, width - 350 :] = False
    mask[height - 60 :] = False
    return image[mask]


def changed_pixels(a, b, threshold=40):
    """How many scene pixels differ between screenshots ``a`` and ``b`` by more than ``threshold``."""
    return int(np.sum(np.abs(scene_pixels(a) - scene_pixels(b)).max(axis=-1) > threshold))


def drawn_pixels(image):
    """How many scene pixels are not near white: the grid, the frames, the robot."""
    return int(np.sum(scene_pixels(image).min(axis=-1) < 200))


def wait_for_page(browser, previous=None, moving=False, timeout=120.0, settle=0.0):
    """A screenshot once the scene shows (the page loads in ~10 s with software WebGL) and, unless the
    page is ``moving`` (the offline replay plays), has settled: the same in two consecutive shots, and
    for at least ``settle`` seconds (meshes appear one by one as the browser parses them). With
    ``previous``, once it differs from that in more than 300 pixels."""
    deadline = time.monotonic() + timeout
    last, since = browser.screenshot(), time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.3)
        shot = browser.screenshot()
        ready = drawn_pixels(shot) > 1000 and (previous is None or changed_pixels(shot, previous) > 300)
        if moving and ready:
            return shot
        if changed_pixels(shot, last, threshold=10) >= 20:
            last, since = shot, time.monotonic()
        elif ready and time.monotonic() - since >= settle:
            return shot
    return last


@pytest.fixture
def meshed_arm(tmp_path):
    """Three links hanging in a chain, each drawn from an STL file (the meshes Viser sends as GLB)."""
    import trimesh

    builder = mb.ModelBuilder("meshed_arm")
    parent, placement = None, np.eye(4)
    for k, width in enumerate((0.12, 0.08, 0.05)):
        name = f"link{k}"
        builder.add_body(name, joint=mb.joints.Revolute(axis=(0.0, 1.0, 0.0)), parent=parent, placement=placement,
                         inertia=mb.inertia.box(1.0, [width, width, 0.4], center=[0.0, 0.0, -0.2]))
        path = str(tmp_path / f"{name}.stl")
        trimesh.creation.box(extents=[width, width, 0.4]).apply_translation([0.0, 0.0, -0.2]).export(path)
        builder.add_geometry(mb.model.Geometry(name, "visual", "mesh", np.eye(4), uri=path, filename=path))
        parent, placement = name, mb.spatial.pose_from_xyz_rpy(xyz=(0.0, 0.0, -0.4))
    return builder.build()


@needs_viser
@pytest.mark.browser
@pytest.mark.skipif(chromium() is None, reason="no chromium binary on PATH (Debian: apt-get install chromium)")
def test_the_browser_shows_the_robot_and_its_motion(pendulum, swing, tmp_path):
    viewer = mb.view(pendulum, trajectory=swing, port=0, frames=False)
    browser = Chromium()
    try:
        browser.navigate(viewer.url)
        hanging = wait_for_page(browser)                  # t = 0: the links hang down
        viewer.layers["bodies"].value = False
        empty = wait_for_page(browser, hanging)           # the same scene without the robot
        robot = changed_pixels(hanging, empty)
        assert robot > 300, f"the robot covers {robot} pixels"
        viewer.layers["bodies"].value = True
        viewer.time = 1.0                                 # both links horizontal
        horizontal = wait_for_page(browser, empty)
        moved = changed_pixels(horizontal, hanging)
        assert moved > 300, f"only {moved} pixels changed between t = 0 and t = 1 s"

        # the offline page replays the motion: it shows the robot too, wherever the replay is
        page = viewer.save_html(tmp_path / "swing.html")
        viewer.layers["bodies"].value = False
        empty_page = viewer.save_html(tmp_path / "empty.html")
        shots = []
        for path in (page, empty_page):
            browser.navigate("file://" + os.path.abspath(path))
            shots.append(wait_for_page(browser, moving=True))
        assert changed_pixels(*shots) > 300
    finally:
        browser.close()
        viewer.close()


@needs_viser
@pytest.mark.browser
@pytest.mark.skipif(chromium() is None, reason="no chromium binary on PATH (Debian: apt-get install chromium)")
def test_a_fresh_browser_shows_every_mesh_on_its_first_load(meshed_arm):
    # the first page load of a fresh browser draws what a reload draws: every body's mesh, not only the first
    viewer = mb.view(meshed_arm, q=[0.6, -0.9, 0.7], port=0, frames=False)
    browser = Chromium()
    try:
        browser.navigate(viewer.url)
        first = wait_for_page(browser, settle=3.0)
        browser.navigate(viewer.url)
        reloaded = wait_for_page(browser, settle=3.0)
        viewer.layers["bodies"].value = False
        empty = wait_for_page(browser, reloaded)
        # each link alone covers some hundreds of pixels at this size
        robot = changed_pixels(reloaded, empty)
        assert robot > 1500, f"the arm covers {robot} pixels"
        missing = changed_pixels(first, reloaded)
        assert missing < 100, f"{missing} pixels of the first load differ from the reload's"
    finally:
        browser.close()
        viewer.close()
