"""Helpers shared by ``test_rolling.py`` and ``test_nonholonomic_simulation.py``.

Models (all with the standard gravity ``[0, 0, −9.81]`` unless stated):

* ``free_ball()``: the shipped ``ball`` URDF (1 kg, r = 0.1 m, I = 2/5 m r²) on a free-flyer;
  ``q = [x, y, z, quat]``, ``v = [R_WBᵀ ẋ, ω_B]`` (both in the body frame).
* ``five_coordinate_ball(inertia)``: the seed's model: prismatic x, prismatic y (massless carts),
  then a spherical joint at height r carrying the ball; ``q = [x, y, quat]``,
  ``v = [ẋ, ẏ (world), ω_B (body)]``. ``free_to_five`` / ``five_to_free`` map states between them.
* ``chaplygin_ball()``: a free-flyer sphere with unequal principal moments, centre of mass at the
  geometric centre.
* ``coin(m, r)``: a free-flyer thin disc, axis along body z (joint ``root_joint``).
* ``sleigh()``: a planar body (no gravity) carrying a knife edge at ``b`` ahead of its centre of mass.

Others: ``tilted_normal``, ``contact_angular_momentum`` (of a ball about its contact point),
``fd_gamma`` (central differences of ``A v + b`` along ``q ⊕ v s``, ``t + s``), ``relative_error``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

import multibody as mb
from multibody.spatial import axis_angle_rotation, pose_from_xyz_rpy, quat_to_rotation

G = 9.81
BALL_MASS, BALL_RADIUS = 1.0, 0.1
E_Z = np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------- comparisons

def relative_error(actual, expected, scale=None):
    """``max|actual − expected| / scale`` (``scale`` defaults to ``max|expected|``)."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"shape {actual.shape} != {expected.shape}"
    assert np.all(np.isfinite(actual)), f"non-finite values in {actual}"
    if scale is None:
        scale = float(np.abs(expected).max())
    return float(np.abs(actual - expected).max()) / scale


# ----------------------------------------------------------------------------- geometry

def tilted_normal(alpha, azimuth=0.0):
    """Unit normal of a plane tilted by ``alpha`` (rad) from the horizontal; its steepest-descent
    direction points along the azimuth ``azimuth`` in the x–y plane."""
    return np.array([np.sin(alpha) * np.cos(azimuth), np.sin(alpha) * np.sin(azimuth), np.cos(alpha)])


def downhill(normal, gravity=(0.0, 0.0, -G)):
    """Unit vector of the plane along which gravity pulls (tangential part of ``g``)."""
    g = np.asarray(gravity, dtype=float)
    tangential = g - (g @ normal) * normal
    return tangential / np.linalg.norm(tangential)


def rotation(rpy):
    return mb.spatial.rpy_to_rotation(np.asarray(rpy, dtype=float))


def quat(R):
    return mb.spatial.rotation_to_quat(R)


# ----------------------------------------------------------------------------- models

def free_ball():
    return mb.load_urdf(mb.robots.path("ball"), floating_base=True)


def five_coordinate_ball(inertia=None, radius=BALL_RADIUS):
    """Prismatic x → prismatic y (massless carts) → spherical joint at height ``radius`` (the ball)."""
    inertia = mb.Inertia(BALL_MASS, [0, 0, 0], 0.4 * BALL_MASS * radius**2 * np.eye(3)) if inertia is None else inertia
    builder = mb.ModelBuilder("five_coordinate_ball")
    builder.add_body("cart_x", mb.joints.Prismatic([1.0, 0.0, 0.0]), placement=pose_from_xyz_rpy([0.0, 0.0, radius]))
    builder.add_body("cart_y", mb.joints.Prismatic([0.0, 1.0, 0.0]), parent="cart_x")
    builder.add_body("ball", mb.joints.Spherical(), parent="cart_y", inertia=inertia)
    return builder.build()


CHAPLYGIN_MOMENTS = (0.0030, 0.0040, 0.0055)  # kg m²: unequal, and a valid rigid body (I₁ + I₂ > I₃)


def chaplygin_inertia(mass=BALL_MASS, moments=CHAPLYGIN_MOMENTS):
    return mb.Inertia(mass, [0.0, 0.0, 0.0], np.diag(moments))


def chaplygin_ball(mass=BALL_MASS, moments=CHAPLYGIN_MOMENTS):
    builder = mb.ModelBuilder("chaplygin_ball")
    builder.add_body("ball", joint=mb.joints.FreeFlyer(), joint_name="root_joint",
                     inertia=chaplygin_inertia(mass, moments))
    return builder.build()


def coin(mass=1.0, radius=0.5):
    """A thin uniform disc: I = m r²/2 about its axis (body z), m r²/4 about any diameter."""
    builder = mb.ModelBuilder("coin")
    builder.add_body("coin", joint=mb.joints.FreeFlyer(), joint_name="root_joint",
                     inertia=mb.Inertia(mass, [0, 0, 0], np.diag([mass * radius**2 / 4, mass * radius**2 / 4,
                                                                   mass * radius**2 / 2])))
    return builder.build()


SLEIGH_MASS, SLEIGH_INERTIA, SLEIGH_B = 2.0, 0.05, 0.2  # kg, kg m² about the centre of mass, m


def sleigh():
    """Planar body, centre of mass at the body origin, blade ``SLEIGH_B`` ahead along body x."""
    builder = mb.ModelBuilder("sleigh", gravity=(0.0, 0.0, 0.0))
    builder.add_body("sleigh", joint=mb.joints.Planar(), joint_name="plane",
                     inertia=mb.Inertia(SLEIGH_MASS, [0, 0, 0], SLEIGH_INERTIA * np.eye(3)))
    model = builder.build()
    return model, mb.KnifeEdge("sleigh", point=[SLEIGH_B, 0.0, 0.0], direction=[1.0, 0.0, 0.0])


def diff_drive_numbers():
    """``(total mass, wheel spin inertia I_w, wheel radius r)`` read from robots/diff_drive.urdf."""
    root = ET.parse(mb.robots.path("diff_drive")).getroot()
    masses = {link.get("name"): float(link.find("inertial/mass").get("value"))
              for link in root.findall("link") if link.find("inertial") is not None}
    wheels = [root.find(f"link[@name='{w}']") for w in ("left_wheel", "right_wheel")]
    spin_inertia = {float(w.find("inertial/inertia").get("iyy")) for w in wheels}  # the wheel joints turn about y
    radius = {float(w.find("visual/geometry/cylinder").get("radius")) for w in wheels}
    assert len(spin_inertia) == 1 and len(radius) == 1
    return sum(masses.values()), spin_inertia.pop(), radius.pop()


# ----------------------------------------------------------------------------- state maps

def free_to_five(q, v):
    """Free-flyer ball state → five-coordinate state (centre on the horizontal plane z = r).

    ``v_lin`` of the free-flyer is in the body frame: the carts' rates are its world x, y
    components ``(R_WB v_lin)[:2]``; the spherical joint's ω is in the ball frame, as the
    free-flyer's.
    """
    R = quat_to_rotation(q[3:])
    return np.concatenate([q[:2], q[3:]]), np.concatenate([(R @ v[:3])[:2], v[3:]])


def five_to_free(q5, v5, radius=BALL_RADIUS):
    R = quat_to_rotation(q5[2:])
    q = np.concatenate([q5[:2], [radius], q5[2:]])
    return q, np.concatenate([R.T @ np.array([v5[0], v5[1], 0.0]), v5[2:]])


# ----------------------------------------------------------------------------- physics

def contact_angular_momentum(inertia_body, mass, radius, normal, q, v):
    """Angular momentum of a ball (centre of mass at its centre) about its contact point ``P = x − r n``.

    ``K_P = I_W ω + (x − P) × m ẋ = I_W ω + m r n × ẋ``; with rolling (``ẋ = r ω × n``) this is the
    literature's ``I_W ω + m r² (ω − (ω·n) n)``. Evaluated here from ``ẋ`` itself (free-flyer q, v).
    """
    R = quat_to_rotation(q[3:])
    omega = R @ v[3:]
    x_dot = R @ v[:3]
    return R @ inertia_body @ R.T @ omega + mass * radius * np.cross(normal, x_dot)


def fd_gamma(cs, q, v, t=0.0, eps=1e-5):
    """``−d/ds [A(q ⊕ v s, t + s) v + b(q ⊕ v s, t + s)]`` at ``s = 0`` by central differences.

    Error estimate: truncation ``ε²/6 |f'''|`` ≈ 2e-11 |f'''| and rounding ``~1e-16 |f| / ε`` ≈ 1e-11 |f|
    for O(1) states: both far below the 1e-7 relative tolerance the tests use.
    """
    def f(s):
        qs = cs.system.integrate(q, v, s)
        return cs.jacobian(qs, t + s) @ v + cs.velocity_bias(qs, t + s)

    return -(f(eps) - f(-eps)) / (2.0 * eps)


def turntable(omega, centre=(0.0, 0.0, 0.0), axis=E_Z):
    """Surface velocity of a plane turning at ``omega`` rad/s about ``axis`` through ``centre``."""
    centre, axis = np.asarray(centre, dtype=float), np.asarray(axis, dtype=float)
    return lambda p, t: omega * np.cross(axis, np.asarray(p, dtype=float) - centre)


def lean_rotation(yaw, lean, spin):
    """Orientation of a disc whose axis is its body z: heading ``yaw``, leaned by ``lean`` from upright
    (the axis horizontal when ``lean = 0``), turned by ``spin`` about its axis."""
    return (axis_angle_rotation([0.0, 0.0, 1.0], yaw) @ axis_angle_rotation([1.0, 0.0, 0.0], np.pi / 2 + lean)
            @ axis_angle_rotation([0.0, 0.0, 1.0], spin))
