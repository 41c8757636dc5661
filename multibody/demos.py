"""Named demonstrations for ``multibody demo NAME``: each simulates, prints a summary and writes figures.

``multibody demo --list`` lists them; ``multibody demo NAME --view`` also opens the 3-D viewer
(:func:`multibody.view`) on the motion. Each demo is a function ``demo(out_dir, duration=...)``
returning a :class:`DemoResult`, registered in :data:`DEMOS`.

The mechanisms are built here, once, by the ``*_setup`` functions, which the examples
(``examples/bead_on_wire.py``, ``four_bar.py``, ``rolling_coin.py``) import as well: each returns a
:class:`Setup`, the system with a consistent initial state.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from . import robots, spatial
from .constrained import ConstrainedSystem
from .constraints import LoopClosure, PointOnCurve
from .inertia import Inertia, point_mass
from .joints import FreeFlyer, Translation
from .kernels import configuration, constraints, energy, integration, kkt
from .model import Geometry, ModelBuilder
from .rolling import RollingDisc, RollingSphere
from .simulation import simulate
from .urdf import load_urdf


#: The kernels a demo runs: the projection onto the constraints, the constrained step and its charts,
#: and the energies of the summary. Heaviest first, so that :func:`multibody.driver.compile_kernels`
#: deals them out evenly among the cores.
KERNELS = (kkt.project, integration.constrained_chart_derivative, constraints.constraint_levels,
           configuration.velocity_alignment, kkt.constrained_accelerations, configuration.chart_magnitude,
           configuration.normalize, energy.kinetic_energy, energy.potential_energy)


@dataclass(frozen=True)
class Setup:
    """A mechanism ready to simulate: ``system`` (a ``ConstrainedSystem``), its ``model``, its
    ``constraints``, and a state ``(q0 (nq,), v0 (nv,))`` on the constraints."""

    system: ConstrainedSystem
    q0: np.ndarray
    v0: np.ndarray

    @property
    def model(self):
        """The :class:`~multibody.model.Model` under the constraints."""
        return self.system.system.model

    @property
    def constraints(self):
        return tuple(self.system.constraints)


@dataclass(frozen=True)
class DemoResult:
    """What a demo computed: ``summary`` (name -> number, printed), the files it wrote (``paths``), and
    what the viewer shows: ``model``, ``trajectory``, ``constraints`` (for the force arrows) and the
    bodies whose paths it draws (``trace``)."""

    summary: dict
    paths: list
    model: object
    trajectory: object
    constraints: tuple = ()
    trace: tuple = ()


def _conservation(trajectory):
    """The summary lines every demo reports: relative energy drift and largest constraint residual."""
    return {"energy drift (relative)": float(np.ptp(trajectory.energy) / abs(trajectory.energy).max()),
            "largest constraint residual": float(trajectory.residual.max())}


# ----------------------------------------------------------------------------- the mechanisms


def rolling_ball_setup(tilt=0.15, radius=0.1, velocity=(-1.0, 1.0)):
    """The ball (``robots/ball.urdf``: 1 kg, ``radius`` m, free body) rolling without slipping on the plane
    through the origin tilted by ``tilt`` rad about the world y axis, downhill along the plane's ``t₁``.

    ``velocity``: the centre's initial velocity in the plane, ``(downhill, across)`` m/s, with the spin
    that rolls it, ``ω = n × ẋ / r``. The ball starts in a generic orientation (a uniform ball's motion
    does not depend on it), so that both bands painted on it in the animation show from the start.
    """
    ball = load_urdf(robots.path("ball"), floating_base=True)
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    contact = RollingSphere("ball", radius, plane_normal=normal)
    system = ConstrainedSystem(ball, [contact])
    E = contact.frame
    q0 = ball.neutral()
    q0[:3] = radius * normal
    q0[3:] = spatial.rotation_to_quat(spatial.rpy_to_rotation([0.7, 0.5, 0.3]))
    velocity_W = E[:, :2] @ np.asarray(velocity, dtype=float)
    omega_W = np.cross(normal, velocity_W) / radius          # rolling: ẋ + ω × (−r n) = 0
    # the free flyer's velocities are in the body frame (docs/conventions.md)
    R_WB = spatial.quat_to_rotation(q0[3:])
    q0, v0 = system.project(q0, np.concatenate([R_WB.T @ velocity_W, R_WB.T @ omega_W]))
    return Setup(system, q0, v0)


def helix(s, radius=0.5, rise=0.15):
    """A helix about the z axis: ``r(s) = (R cos s, R sin s, rise · s)`` (m), ``s (...)`` -> ``(..., 3)``."""
    return np.stack([radius * np.cos(s), radius * np.sin(s), rise * s], axis=-1)


def wavy_loop(s):
    """A closed, tilted, wavy loop (m), ``s (...)`` -> ``(..., 3)``, period 2π."""
    return np.stack([np.cos(s), 0.6 * np.sin(s), 0.3 * np.sin(s) + 0.1 * np.cos(3 * s)], axis=-1)


def bead_on_wire_setup(curve=helix, s_range=(-40.0, 15.0), mass=0.2, gravity=9.81, s0=1.0, s_dot0=2.0):
    """A bead (point mass ``mass`` kg, Cartesian coordinates: a translation joint) held on the wire
    ``curve(s)`` by :class:`~multibody.constraints.PointOnCurve`, the multipliers being the wire's normal
    force (N, world axes). Starts at ``curve(s0)`` moving along the wire at ``ṡ = s_dot0``."""
    builder = ModelBuilder("bead", gravity=(0.0, 0.0, -gravity))
    builder.add_body("bead", joint=Translation(), inertia=point_mass(mass))
    bead = builder.build()
    wire = PointOnCurve("bead", curve, s_range=s_range, samples=4001)
    h = 1e-3  # the curve's tangent r'(s0), by the five-point central difference (error ~h⁴)
    tangent = (8 * (curve(s0 + h) - curve(s0 - h)) - (curve(s0 + 2 * h) - curve(s0 - 2 * h))) / (12 * h)
    system = ConstrainedSystem(bead, [wire])
    q0, v0 = system.project(curve(s0), tangent * s_dot0)
    return Setup(system, q0, v0)


def four_bar_setup(crank=-np.pi / 3):
    """The four-bar linkage (``robots/four_bar.urdf``: the open tree ground–crank–coupler and
    ground–rocker) closed by a planar loop closure between the coupler's and the rocker's tips, at rest.
    The multipliers are the pin force on the rocker's tip (N) along the coupler's x and z axes, which
    turn with the coupler. ``crank``: its angle
    (rad, about +y; negative lifts it), from which the projection finds the others."""
    model = robots.load("four_bar")
    # The closure infers its plane (x–z) from the joint axes; frame A, fixed in the coupler's tip and turned
    # by +90° about x, has its x and y axes in that plane along the coupler's x and z, which makes the
    # multipliers the pin force on the rocker along those two axes of the coupler.
    in_plane = spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))
    closure = LoopClosure("coupler_tip", "rocker_tip", frame_a=in_plane, kind="planar")
    system = ConstrainedSystem(model, [closure])
    guess = np.array([crank, 0.9, -1.4])  # coupler and rocker roughly placed
    q0, v0 = system.project(guess, np.zeros(model.nv))
    return Setup(system, q0, v0)


def rolling_coin_setup(mass=0.01, radius=0.02, lean=0.15, spin=40.0):
    """A coin (thin disc, ``mass`` kg, ``radius`` m, a free body) rolling without slipping on the table
    ``z = 0`` (:class:`~multibody.rolling.RollingDisc`), its axis leaned by ``lean`` rad from the
    horizontal and spinning at ``spin`` rad/s about it; the projection adds the matching forward speed.
    Multipliers: friction along t₁, t₂ and the normal force (N)."""
    builder = ModelBuilder("coin")
    # The coin's axis is its body z axis: I = m r²/2 about it, m r²/4 about any diameter.
    builder.add_body("coin", joint=FreeFlyer(), joint_name="root_joint",
                     inertia=Inertia(mass, [0, 0, 0], np.diag([mass * radius**2 / 4, mass * radius**2 / 4,
                                                               mass * radius**2 / 2])))
    # a cylinder's axis is its z axis, as the coin's: the viewer draws it as a coin
    builder.add_geometry(Geometry("coin", "visual", "cylinder", np.eye(4), size=(radius, 0.1 * radius)))
    coin = builder.build()
    contact = RollingDisc("coin", radius, axis=(0.0, 0.0, 1.0))
    system = ConstrainedSystem(coin, [contact])
    # axis along the world y axis, leaned by `lean` about the rolling direction x
    R0 = spatial.axis_angle_rotation([1.0, 0.0, 0.0], np.pi / 2 + lean)
    q0 = np.concatenate([[0.0, 0.0, radius * np.cos(lean)], spatial.rotation_to_quat(R0)])
    q0, v0 = system.project(q0, np.array([0.0, 0.0, 0.0, 0.0, 0.0, spin]))
    return Setup(system, q0, v0)


# ----------------------------------------------------------------------------- the demos

def rolling_ball(out_dir, duration=2.6):
    """The lecture note's nonholonomic example: a ball rolling without slipping on a tilted plane.

    A uniform ball (1 kg, radius 0.1 m) is launched up and across a plane tilted by 0.15 rad. Rolling
    makes its centre accelerate downhill at 5/7 g sin α (not g sin α as when sliding), so the contact
    path is a parabola. Writes the contact path, the energy, the constraint residual (log scale, with
    the projection tolerance), the contact force, and an animation (GIF) of the plane seen from above,
    fixed in the world, with the ball painted with two bands so that its turning shows and its contact
    path traced. The frames are chosen so that the ball turns less than 0.5 rad from one to the next.
    """
    from .plotting import energy_figure, multiplier_figure, plot_path, residual_figure, save_figure

    setup = rolling_ball_setup()
    system, (contact,) = setup.system, setup.constraints
    g, tilt = float(np.linalg.norm(setup.model.gravity)), float(np.arcsin(contact.normal[0]))
    # a fine output grid: the animation picks its frames among these states
    trajectory = simulate(system, setup.q0, setup.v0, duration, dt=0.005, method="DOP853", rtol=1e-12, atol=1e-14)

    E = contact.frame
    points = np.array([contact.contact_point(setup.model, q) for q in trajectory.q])
    plane_xy = (points - contact.plane_point) @ E[:, :2]       # (n, 2): downhill x', across y' (m)
    v0_plane = spatial.quat_to_rotation(setup.q0[3:]) @ setup.v0[:3] @ E[:, 0]
    expected = plane_xy[0, 0] + 0.5 * (5.0 / 7.0) * g * np.sin(tilt) * trajectory.t**2 + v0_plane * trajectory.t
    frames, delay, turn = animation_frames(trajectory.t, trajectory.q[:, 3:7])
    summary = {
        "downhill motion vs 5/7 g sin α (m)": float(np.abs(plane_xy[:, 0] - expected).max()),
        **_conservation(trajectory),
        "friction / normal force (max)": _friction_ratio(trajectory),
        "largest turn of the ball between animation frames (rad)": turn,
    }
    paths = [plot_path(np.stack([plane_xy[:, 1], -plane_xy[:, 0]], axis=1), out_dir, "rolling_ball",
                       f"contact path on the plane tilted by {tilt:g} rad (seen from above it)",
                       ("across the slope, y' (m)", "up the slope, −x' (m)"), dpi=100),
             save_figure(energy_figure(trajectory), out_dir, "rolling_ball_energy", dpi=100)]
    paths.append(save_figure(residual_figure(trajectory, system), out_dir, "rolling_ball_residual", dpi=100))
    figure = multiplier_figure(trajectory, system,
                               multiplier_labels=["friction along t₁ (downhill)", "friction along t₂ (across)",
                                                  "normal force"])
    figure.suptitle("contact force of the plane on the ball", fontsize="medium")
    paths.append(save_figure(figure, out_dir, "rolling_ball_contact_force", dpi=100))

    paths.append(_animate_ball(trajectory, contact, plane_xy, frames, delay,
                               os.path.join(out_dir, "rolling_ball.gif")))
    return DemoResult(summary, paths, setup.model, trajectory, setup.constraints, trace=("ball",))


def animation_frames(t, quat, max_turn=0.45, max_interval=0.04, min_delay=0.02):
    """Frames of a turning body's animation: ``(indices (k,), delay (s), largest turn between frames (rad))``.

    Frames are every ``s``-th state of ``t (n,)`` (uniform times, so that accelerations show), ``s`` the
    largest stride with ``s Δt ≤ max_interval`` and a rotation between frames, bounded by the sum of the
    rotations between the states it spans, of at most ``max_turn``: a turning pattern cannot alias.
    ``quat (n, 4)`` are the body's orientations ``[x, y, z, w]``. The delay is the frames' time step, at
    least ``min_delay`` (browsers show shorter GIF delays slower, not faster), in hundredths of a second.
    Raises ``ValueError`` when consecutive states are already more than ``max_turn`` apart.
    """
    dots = np.abs(np.sum(quat[1:] * quat[:-1], axis=1)) / (np.linalg.norm(quat[1:], axis=1)
                                                           * np.linalg.norm(quat[:-1], axis=1))
    turned = np.concatenate([[0.0], np.cumsum(2.0 * np.arccos(np.clip(dots, -1.0, 1.0)))])  # (n,) rad
    dt = float(np.min(np.diff(t)))
    stride = max(1, int(max_interval / dt + 1e-9))
    while stride > 1 and np.max(turned[stride:] - turned[:-stride], initial=0.0) > max_turn:
        stride -= 1
    if np.max(np.diff(turned), initial=0.0) > max_turn:
        raise ValueError(f"the body turns up to {np.max(np.diff(turned)):.3g} rad between consecutive states, more "
                         f"than {max_turn} rad: simulate with a smaller output interval dt")
    indices = np.arange(0, len(t), stride)
    delay = max(min_delay, round(stride * dt, 2))
    R = spatial.quat_to_rotation(quat[indices])
    relative = np.einsum("kji,kjl->kil", R[:-1], R[1:])        # R_kᵀ R_{k+1}
    angles = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return indices, delay, float(angles.max(initial=0.0))


def _animate_ball(trajectory, contact, plane_xy, frames, delay, path, size=(6.4, 4.4)):
    """The GIF: the plane seen from above it, fixed in the world, the ball drawn to scale with two
    body-fixed great circles (their half facing the viewer), the contact path traced as it goes.

    The still parts are drawn once; each frame restores them and draws the moving ones (blitting), and
    Pillow writes the frames with one shared palette.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_rgb
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle
    from PIL import Image

    from .plotting import new_figure

    E, radius = contact.frame, contact.radius
    tilt = float(np.arcsin(contact.normal[0]))
    figure = new_figure(size)
    figure.set_layout_engine("none")
    canvas = FigureCanvasAgg(figure)
    ax = figure.add_axes([0.11, 0.3, 0.86, 0.6])
    across, up = plane_xy[:, 1], -plane_xy[:, 0]               # page right, page up (m)
    margin = 3 * radius
    ax.set_xlim(across.min() - margin, across.max() + margin)
    ax.set_ylim(up.min() - margin, up.max() + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.set_facecolor("#eef1f5")
    ax.grid(True, color="white", linewidth=1.0)
    ax.set_xlabel("across the slope, y' (m)")
    ax.set_ylabel("up the slope, −x' (m)")
    ax.set_title(f"the plane tilted by {tilt:g} rad, seen from above it (downhill: down the page)",
                 fontsize="small")
    ax.plot(across, up, color="0.8", linewidth=1.0, zorder=1)

    colors = {"path": "tab:purple", "equator": "tab:red", "meridian": "tab:blue"}
    traced, = ax.plot([], [], color=colors["path"], linewidth=1.5, zorder=2)
    ball = Circle((0.0, 0.0), radius, facecolor="#fafafa", edgecolor="0.25", linewidth=1.0, zorder=3)
    ax.add_patch(ball)
    bands = {name: ax.plot([], [], color=colors[name], linewidth=2.0, zorder=4)[0] for name in ("equator", "meridian")}
    clock = ax.text(0.02, 0.95, "", transform=ax.transAxes, va="top", fontsize="small")
    figure.legend(handles=[Line2D([], [], color="0.8", label="contact path, whole run"),
                           Line2D([], [], color=colors["path"], label="contact path so far"),
                           Line2D([], [], color=colors["equator"], lw=2, label="ball's equator (body z = 0)"),
                           Line2D([], [], color=colors["meridian"], lw=2, label="ball's meridian (body x = 0)")],
                  loc="lower center", ncol=2, fontsize="small", frameon=False,
                  title="bands painted on the ball: the half facing you is drawn", title_fontsize="small")
    moving = [traced, ball, *bands.values(), clock]
    for artist in moving:
        artist.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(figure.bbox)

    s = np.linspace(0.0, 2 * np.pi, 73)
    circles = {"equator": radius * np.stack([np.cos(s), np.sin(s), 0 * s], axis=1),
               "meridian": radius * np.stack([0 * s, np.cos(s), np.sin(s)], axis=1)}   # body frame (m)
    # the frames' spacing in simulated time over their delay: below 1 when the delay had to be raised
    speed = (trajectory.t[frames[1]] - trajectory.t[frames[0]]) / delay if len(frames) > 1 else 1.0
    slower = f" (played at {speed:.2g}× speed)" if speed < 0.99 else ""
    images = []
    for k in frames:
        q = trajectory.q[k]
        R_WB = spatial.quat_to_rotation(q[3:7])
        centre = (q[:3] - contact.plane_point) @ E            # plane coordinates (x', y', n')
        canvas.restore_region(background)
        traced.set_data(across[: k + 1], up[: k + 1])
        ball.center = (centre[1], -centre[0])
        for name, points in circles.items():
            local = points @ R_WB.T @ E                        # (73, 3): offsets from the centre, plane axes
            front = local[:, 2] >= 0.0                         # the half facing a viewer above the plane
            bands[name].set_data(np.where(front, centre[1] + local[:, 1], np.nan),
                                 np.where(front, -(centre[0] + local[:, 0]), np.nan))
        clock.set_text(f"t = {trajectory.t[k]:.2f} s{slower}")
        for artist in moving:
            ax.draw_artist(artist)
        # a copy of the canvas (the next frame draws over it), without a round trip through NumPy
        images.append(Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
                      .convert("RGB"))
    # One palette for every frame (no flicker), from the first frame and swatches of the drawn colours,
    # which cover too few of its pixels to win palette entries by themselves.
    swatches = np.repeat(np.array([[np.uint8(255 * c) for c in to_rgb(color)] for color in colors.values()],
                                  dtype=np.uint8)[:, None, None, :], 32, axis=1).repeat(images[0].width // len(colors), axis=2)
    swatch = Image.fromarray(np.concatenate(list(swatches), axis=1)[:, : images[0].width])
    sample = Image.new("RGB", (images[0].width, images[0].height + swatch.height))
    sample.paste(images[0], (0, 0))
    sample.paste(swatch, (0, images[0].height))
    palette = sample.quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    frames_p = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    frames_p[0].save(path, save_all=True, append_images=frames_p[1:], duration=int(round(1000 * delay)), loop=0)
    return path


def _constrained_demo(setup, out_dir, name, trace, summary, duration, dt, rtol, atol, **labels):
    """Simulate ``setup`` for ``duration`` s (DOP853, a state every ``dt`` s) and write its figures
    (:func:`multibody.plotting.plot_trajectory` with ``labels``): the :class:`DemoResult`, its summary
    :func:`_conservation`'s lines and ``summary``'s (name -> function of the trajectory), the viewer
    tracing the bodies ``trace``."""
    from .plotting import plot_trajectory

    trajectory = simulate(setup.system, setup.q0, setup.v0, duration, dt=dt, method="DOP853", rtol=rtol, atol=atol)
    lines = {**_conservation(trajectory), **{key: line(trajectory) for key, line in summary.items()}}
    paths = plot_trajectory(trajectory, out_dir, name, setup.system, **labels)
    return DemoResult(lines, paths, setup.model, trajectory, setup.constraints, trace=trace)


def _largest_force(trajectory):
    """The largest norm of the multipliers over the run (N): the force of a constraint whose rows are one."""
    return float(np.linalg.norm(trajectory.lam, axis=1).max())


def _friction_ratio(trajectory):
    """The largest ratio of friction to normal force of a rolling contact's multipliers (t₁, t₂, normal)."""
    return float(np.abs(np.linalg.norm(trajectory.lam[:, :2], axis=1) / trajectory.lam[:, 2]).max())


def bead_on_wire(out_dir, duration=3.0):
    """A bead on a helical wire: Cartesian coordinates held on the curve, the multipliers its normal force.

    Writes the state, energy, residual and wire-force figures; the viewer traces the bead's path and
    draws the wire's force on it.
    """
    return _constrained_demo(bead_on_wire_setup(), out_dir, "bead_on_wire", ("bead",),
                             {"largest wire force (N)": _largest_force}, duration, 0.01, 1e-11, 1e-12,
                             coordinate_labels=["x", "y", "z"],
                             multiplier_labels=["wire force, x", "wire force, y", "wire force, z"])


def four_bar(out_dir, duration=4.0):
    """A four-bar linkage falling under gravity: a URDF tree closed by a loop-closure constraint.

    Writes the state, energy, residual and pin-force figures; the viewer traces the coupler's tip and
    draws the pin force.
    """
    return _constrained_demo(four_bar_setup(), out_dir, "four_bar", ("coupler_tip",),
                             {"largest pin force (N)": _largest_force}, duration, 0.01, 1e-10, 1e-12,
                             multiplier_labels=["pin force on the rocker along the coupler's x",
                                                "pin force on the rocker along the coupler's z"])


def rolling_coin(out_dir, duration=2.0):
    """A coin rolling without slipping on a table, leaning into a circle.

    Writes the state, energy, residual, contact-force and contact-path figures; the viewer traces the
    coin's centre and draws the table's force on it.
    """
    from .plotting import plot_path

    result = _constrained_demo(rolling_coin_setup(), out_dir, "rolling_coin", ("coin",),
                               {"friction / normal force (max)": _friction_ratio}, duration, 0.002, 1e-11, 1e-13,
                               multiplier_labels=["friction along t₁", "friction along t₂", "normal force"])
    (contact,) = result.constraints
    contact_points = np.array([contact.contact_point(result.model, q) for q in result.trajectory.q])
    result.paths.append(plot_path(contact_points[:, :2], out_dir, "rolling_coin", "contact path of the rolling coin"))
    return result


DEMOS = {"rolling-ball": rolling_ball, "bead-on-wire": bead_on_wire, "four-bar": four_bar,
         "rolling-coin": rolling_coin}
