"""Named demonstrations for ``multibody demo NAME``: each simulates, prints a summary and writes figures."""

from __future__ import annotations

import os

import numpy as np

from . import robots, spatial
from .constrained import ConstrainedSystem
from .plotting import pyplot
from .rolling import RollingSphere
from .simulation import simulate
from .urdf import load_urdf


def rolling_ball(out_dir, duration=6.0):
    """The lecture note's nonholonomic example: a ball rolling without slipping on a tilted plane.

    A uniform ball (1 kg, radius 0.1 m) is launched across a plane tilted by 0.15 rad. Rolling
    makes its centre accelerate downhill at 5/7 g sin α (not g sin α as when sliding), so the
    contact path is a parabola. Writes the contact path, energy and constraint residual, the
    contact force, and an animation (GIF) seen from above the plane with three body-fixed
    markers that show the ball turning.
    """
    radius, tilt, g = 0.1, 0.15, 9.81
    ball = load_urdf(robots.path("ball"), floating_base=True)
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])  # the plane z' = 0 through the origin, downhill along +x'
    contact = RollingSphere("ball", radius, plane_normal=normal)
    system = ConstrainedSystem(ball, [contact])

    q0 = ball.neutral()
    q0[:3] = radius * normal
    # Launched across and slightly up the slope; the projection gives the rolling spin that goes with it.
    across = np.array([-0.4 * np.cos(tilt), 1.0, 0.4 * np.sin(tilt)])
    v0 = np.concatenate([across, np.zeros(3)])
    q0, v0 = system.project(q0, v0)
    trajectory = simulate(system, q0, v0, duration, dt=0.02, method="DOP853", rtol=1e-12, atol=1e-14)

    # Coordinates on the plane: x' downhill, y' across.
    E = contact.frame
    points = np.array([contact.contact_point(system.system, q) for q in trajectory.q])
    plane_xy = points @ E[:, :2]
    downhill = plane_xy[:, 0] - plane_xy[0, 0]
    expected = 0.5 * (5.0 / 7.0) * g * np.sin(tilt) * trajectory.t**2 + (v0[:3] @ E[:, 0]) * trajectory.t
    summary = {
        "downhill motion vs 5/7 g sin α (m)": float(np.abs(downhill - expected).max()),
        "energy drift (relative)": float(np.ptp(trajectory.energy) / abs(trajectory.energy).max()),
        "largest constraint residual": float(trajectory.residual.max()),
        "friction / normal force (max)": float(np.abs(np.linalg.norm(trajectory.lam[:, :2], axis=1)
                                                      / trajectory.lam[:, 2]).max()),
    }
    os.makedirs(out_dir, exist_ok=True)
    plt = pyplot()
    paths = []

    def save(figure, name):
        path = os.path.join(out_dir, name)
        figure.tight_layout()
        figure.savefig(path, dpi=110)
        plt.close(figure)
        paths.append(path)

    figure, ax = plt.subplots(figsize=(6, 5))
    ax.plot(plane_xy[:, 1], plane_xy[:, 0])
    ax.set_xlabel("across the slope y' (m)")
    ax.set_ylabel("downhill x' (m)")
    ax.invert_yaxis()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("contact path on the plane")
    save(figure, "rolling_ball_path.png")

    figure, (ax_e, ax_r) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    ax_e.plot(trajectory.t, trajectory.energy - trajectory.energy[0])
    ax_e.set_ylabel("E − E₀ (J)")
    ax_r.semilogy(trajectory.t, np.maximum(trajectory.residual, 1e-17))
    ax_r.set_ylabel("constraint residual")
    ax_r.set_xlabel("t (s)")
    save(figure, "rolling_ball_energy_residual.png")

    figure, ax = plt.subplots(figsize=(7, 4))
    for k, label in enumerate(["friction along t₁", "friction along t₂", "normal force"]):
        ax.plot(trajectory.t, trajectory.lam[:, k], label=label)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("contact force on the ball (N)")
    ax.legend()
    save(figure, "rolling_ball_contact_force.png")

    paths.append(_animate(plt, trajectory, E, radius, plane_xy, os.path.join(out_dir, "rolling_ball.gif")))
    return summary, paths


def _animate(plt, trajectory, E, radius, plane_xy, path, frames=120):
    """Top view of the ball on the plane; three body-fixed markers show its orientation."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    markers = radius * np.eye(3)  # ends of the body axes, on the surface
    colors = ["tab:red", "tab:green", "tab:blue"]
    indices = np.linspace(0, len(trajectory.t) - 1, frames).astype(int)
    figure, ax = plt.subplots(figsize=(5, 5))
    ax.plot(plane_xy[:, 1], plane_xy[:, 0], color="0.8")
    ax.set_aspect("equal")
    window = 4 * radius  # the view follows the ball, so that its turning stays visible
    ax.set_xlabel("y' (m)")
    ax.set_ylabel("x' downhill (m)")
    circle = plt.Circle((0, 0), radius, fill=False, lw=2)
    ax.add_patch(circle)
    dots = [ax.plot([], [], "o", color=c, ms=12)[0] for c in colors]
    title = ax.set_title("")

    def draw(frame):
        k = indices[frame]
        q = trajectory.q[k]
        R = spatial.quat_to_rotation(q[3:])
        centre = E.T @ q[:3]
        circle.center = (centre[1], centre[0])
        ax.set_xlim(centre[1] - window, centre[1] + window)
        ax.set_ylim(centre[0] + window, centre[0] - window)
        for dot, marker in zip(dots, markers):
            p = E.T @ (q[:3] + R @ marker)
            dot.set_data([p[1]], [p[0]])
            dot.set_alpha(1.0 if p[2] >= centre[2] else 0.3)  # faded when on the far side
        title.set_text(f"t = {trajectory.t[k]:.2f} s")
        return [circle, *dots, title]

    animation = FuncAnimation(figure, draw, frames=frames, blit=False)
    animation.save(path, writer=PillowWriter(fps=20))
    plt.close(figure)
    return path


DEMOS = {"rolling-ball": rolling_ball}
