"""Unitree's Go1 dropped onto the ground, landing and standing under a PD controller.

The Go1 of example-robot-data (``go1_description``: a free-flyer trunk, twelve revolute joints, 38 primitive
collision shapes: boxes, cylinders and the four feet's spheres) is released from rest 0.25 m above its standing
height, its legs in the standing posture (hip 0, thigh 0.9 rad, calf −1.8 rad). ``mb.Ground(friction=0.8)``
takes every collision shape against the ground; an ``mb.PD`` on the twelve joints (none on the trunk) holds the
posture, run inside the compiled Moreau–Jean step (``dt = 1e-3`` s). The robot falls, lands on its feet and comes
to rest standing. At rest the ground's forces balance gravity: with the front feet at ``x_f`` and the rear feet
at ``x_r`` (world x of their contact points) and the centre of mass at ``x_G``,

    Σ F_z = m g,      F_front (x_f − x_r) = m g (x_G − x_r),      F_rear = m g − F_front

(the forces and moments about the rear feet's line; the friction forces act in the ground's plane, through that
line's height). The forces are the contact rows' forces (the step's impulse / dt, N) summed per foot.

Writes ``quadruped.png``: the height of the trunk, each foot's normal force, and their sum and the front and rear
pairs' sums against the closed forms, dashed.
Run: python examples/quadruped.py [output_folder]
"""

from __future__ import annotations

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

G = 9.81
LEGS = ("FL", "FR", "RL", "RR")
POSTURE = (0.0, 0.9, -1.8)
# the PD acts on the step's start state (explicitly): with the legs' light links, kd = 10 N·m·s/rad at dt = 1e-3 s
# diverges
KP, KD = 150.0, 4.0
FRICTION, DROP = 0.8, 0.25
DT, DURATION = 1e-3, 2.0


def standing(model):
    """The standing configuration ``q (nq,)``: the legs in ``POSTURE``, the trunk level with the feet's spheres
    touching the ground (z = 0)."""
    q = model.neutral()
    q[7:] = np.tile(POSTURE, len(LEGS))
    radius = next(g.size[0] for g in model.collision_geometries if g.body == "FL_foot")
    q[2] = radius - mb.frame_placement(model, q, "FL_foot")[2, 3]
    return q


def drop(model, height=DROP):
    """The robot released from rest ``height`` (m) above ``standing(model)`` with the PD holding the posture:
    ``(trajectory, feet (n, 4) normal force per foot (N), points (n, 4) world x of each foot's contact (m; nan
    without contact))``."""
    q_ref = standing(model)
    kp = np.r_[np.zeros(6), np.full(model.nv - 6, KP)]
    kd = np.r_[np.zeros(6), np.full(model.nv - 6, KD)]
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=FRICTION)])
    q0 = q_ref.copy()
    q0[2] += height
    trajectory = mb.simulate(system, q0, np.zeros(model.nv), DURATION, dt=DT, tau=mb.PD(kp, kd, q_ref))
    feet = np.zeros((len(trajectory.t), len(LEGS)))
    points = np.full((len(trajectory.t), len(LEGS)), np.nan)
    for k, entry in enumerate(trajectory.contacts):
        for i, leg in enumerate(LEGS):
            rows = entry.body == f"{leg}_foot"
            feet[k, i] = entry.force[rows, 2].sum()
            if rows.any():
                points[k, i] = entry.point[rows, 0].mean()
    return trajectory, feet, points


def main(out="output"):
    """Drop the robot, print the standing forces against the closed forms, write the figure; return a summary."""
    model = mb.robots.load("go1")
    mass = model.total_mass
    trajectory, feet, points = drop(model)
    t = trajectory.t
    total, front, rear = feet.sum(axis=1), feet[:, :2].sum(axis=1), feet[:, 2:].sum(axis=1)
    # the moment balance about the rear feet's line, with the centre of mass at the step's start
    x_g = mb.center_of_mass(model, trajectory.q)[:, 0]
    x_f, x_r = points[:, :2].mean(axis=1), points[:, 2:].mean(axis=1)
    front_cf = np.r_[np.nan, (mass * G * (x_g[:-1] - x_r[1:]) / (x_f[1:] - x_r[1:]))]
    others = {str(body) for entry in trajectory.contacts for body in entry.body[entry.force[:, 2] > 0]}
    # the last half second: the PD's slowest mode has decayed to mm/s
    standing_from = t >= t[-1] - 0.5
    summary = {"mass": mass, "weight": mass * G, "total": total, "front": front, "front closed form": front_cf,
               "standing": standing_from, "bodies touching": others,
               "standing speed": np.abs(trajectory.v[standing_from]).max(),
               "largest residual": trajectory.complementarity.max(), "status": trajectory.status}
    print(f"Go1: {mass:.3f} kg, {len(model.collision_geometries)} collision shapes; {trajectory.status}; "
          f"touching the ground: {', '.join(sorted(others))}")
    print(f"landed at t = {t[np.flatnonzero(total > 0)[0]]:.3f} s; standing, from t = {t[standing_from][0]:g} s: "
          f"speed at most "
          f"{summary['standing speed']:.1e} m/s, Σ F_z − m g within "
          f"{np.abs(total[standing_from] - mass * G).max():.1e} N (m g = {mass * G:.4f} N), front pair within "
          f"{np.abs(front - front_cf)[standing_from].max():.1e} N of m g (x_G − x_r)/(x_f − x_r) = "
          f"{front_cf[-1]:.4f} N")
    print(f"largest complementarity residual {summary['largest residual']:.1e} m/s")

    figure = new_figure((11.0, 4.0))
    height_axes, feet_axes, sums_axes = figure.subplots(1, 3)
    height_axes.plot(t, trajectory.q[:, 2], color="C0", label="trunk origin")
    height_axes.axhline(standing(model)[2], color="k", ls="--", lw=1, label="standing height (PD reference)")
    height_axes.set(xlabel="time (s)", ylabel="height (m)", title=f"Trunk, dropped from {DROP:g} m higher")
    for i, leg in enumerate(LEGS):
        feet_axes.plot(t[1:], feet[1:, i], color=f"C{i}", lw=1, label=f"{leg} foot")
    feet_axes.axhline(mass * G / 4, color="k", ls=":", lw=1, label="m g / 4")
    feet_axes.set(xlabel="time (s)", ylabel="normal force (N)", ylim=(0, 3 * mass * G),
                  title="Each foot (landing peak clipped)")
    sums_axes.plot(t[1:], total[1:], color="C0", lw=2, alpha=0.8, label="Σ F_z, four feet")
    sums_axes.plot(t[1:], front[1:], color="C1", lw=2, alpha=0.8, label="front pair")
    sums_axes.plot(t[1:], rear[1:], color="C2", lw=2, alpha=0.8, label="rear pair")
    sums_axes.axhline(mass * G, color="k", ls="--", lw=1, label="closed forms: m g, and by moments")
    sums_axes.plot(t[1:], front_cf[1:], "k--", lw=1)
    sums_axes.plot(t[1:], mass * G - front_cf[1:], "k--", lw=1)
    sums_axes.set(xlabel="time (s)", ylabel="normal force (N)", ylim=(0, 2 * mass * G), xlim=(0.5, t[-1]),
                  title="Sums: the ground carries the weight")
    for axes in (height_axes, feet_axes, sums_axes):
        axes.legend(fontsize=7, loc="upper right")
    path = save_figure(figure, out, "quadruped")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
