"""A box on an incline, over a sweep of slopes: it sticks below atan μ and slides above.

A 1 kg box (0.2 × 0.2 × 0.1 m) rests on the plane through the origin with normal ``(sin α, 0, cos α)``
(``mb.Ground(normal=..., friction=μ)``), released from rest, and is simulated for 0.5 s by the Moreau–Jean
step at ``dt = 1e-3`` s. Coulomb's law on an incline gives, with ``m`` the mass and ``g`` gravity:

    sticking (tan α ≤ μ):  friction  F_T = m g sin α,     normal F_N = m g cos α,   a = 0
    slipping (tan α > μ):  friction  F_T = μ m g cos α,   normal F_N = m g cos α,   a = g (sin α − μ cos α)

The friction and normal forces are the contact rows' forces (``Trajectory.contacts``: the step's impulse / dt,
N) summed over the box's corners and projected on the slope and its normal; the acceleration is the change of
the box's velocity down the slope over the run.

Writes ``box_on_incline.png``: the forces and the acceleration against the slope, the closed forms dashed.
Run: python examples/box_on_incline.py [output_folder]
"""

from __future__ import annotations

import sys

import numpy as np

import multibody as mb
from multibody import inertia
from multibody.joints import FreeFlyer
from multibody.plotting import new_figure, save_figure

G = 9.81
MASS, SIZE = 1.0, (0.2, 0.2, 0.1)
FRICTION = 0.4
DT, DURATION = 1e-3, 0.5


def box_model():
    """A free box of mass ``MASS`` (kg) and size ``SIZE`` (m) with its box collision geometry."""
    builder = mb.ModelBuilder("box")
    builder.add_body("box", joint=FreeFlyer(), inertia=inertia.box(MASS, SIZE))
    builder.add_collision("box", "box", SIZE)
    return builder.build()


def closed_form(alpha, mu=FRICTION):
    """Friction and normal force (N, on the box) and the acceleration down the slope (m/s²) at slope ``alpha``
    (rad) from rest: ``(m g sin α, m g cos α, 0)`` while ``tan α ≤ μ``, else ``(μ m g cos α, m g cos α,
    g (sin α − μ cos α))``."""
    normal = MASS * G * np.cos(alpha)
    slipping = np.tan(alpha) > mu
    friction = np.where(slipping, mu * normal, MASS * G * np.sin(alpha))
    acceleration = np.where(slipping, G * (np.sin(alpha) - mu * np.cos(alpha)), 0.0)
    return friction, normal, acceleration


def on_incline(model, alpha, mu=FRICTION):
    """The box released from rest on the slope ``alpha`` (rad): ``(friction force (n,), normal force (n,), speed
    down the slope (n,), trajectory)``, the forces (N) summed over the contact rows of each step (entry 0, before
    the first step, is zero)."""
    normal = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    downhill = np.array([np.cos(alpha), 0.0, -np.sin(alpha)])
    system = mb.ConstrainedSystem(model, [mb.Ground(normal=normal, friction=mu)])
    # the box's bottom face on the plane: its centre half a height along the normal, turned by α about y
    q0 = np.r_[SIZE[2] / 2 * normal, 0.0, np.sin(alpha / 2), 0.0, np.cos(alpha / 2)]
    trajectory = mb.simulate(system, q0, np.zeros(6), DURATION, dt=DT)
    force = np.array([entry.force.sum(axis=0) for entry in trajectory.contacts])
    # friction acts up the slope, against the motion or the pull of gravity
    friction, normal_force = -force @ downhill, force @ normal
    speed = mb.frame_velocity(model, trajectory.q, trajectory.v, "box")[:, :3] @ downhill
    return friction, normal_force, speed, trajectory


def sweep(model, slopes):
    """For each slope (rad): the friction and normal force (N) at the last step, the mean acceleration down the
    slope over the run (m/s²) and the largest complementarity residual (m/s), as arrays ``(len(slopes),)``."""
    rows = []
    for alpha in slopes:
        friction, normal, speed, trajectory = on_incline(model, alpha)
        rows.append((friction[-1], normal[-1], (speed[-1] - speed[0]) / (trajectory.t[-1] - trajectory.t[0]),
                     trajectory.complementarity.max()))
    return tuple(np.array(column) for column in zip(*rows))


def main(out="output"):
    """Run the sweep, print the largest deviations from the closed forms, write the figure; return a summary."""
    model = box_model()
    critical = np.arctan(FRICTION)
    slopes = np.linspace(0.05, 0.75, 15)
    friction, normal, acceleration, residual = sweep(model, slopes)
    expected = closed_form(slopes)
    summary = {"slopes": slopes, "friction": friction, "normal": normal, "acceleration": acceleration,
               "critical slope": critical, "largest residual": residual.max(),
               "friction error": np.abs(friction - expected[0]).max(),
               "normal error": np.abs(normal - expected[1]).max(),
               "acceleration error": np.abs(acceleration - expected[2]).max()}
    print(f"μ = {FRICTION}: sticks below atan μ = {critical:.4f} rad, slips above")
    print(f"friction force within {summary['friction error']:.1e} N of the closed form, normal force within "
          f"{summary['normal error']:.1e} N, acceleration within {summary['acceleration error']:.1e} m/s²; "
          f"largest complementarity residual {summary['largest residual']:.1e} m/s")

    fine = np.linspace(slopes[0], slopes[-1], 400)
    friction_cf, normal_cf, acceleration_cf = closed_form(fine)
    # two runs in time: one below the critical slope, one above
    below, above = 0.30, 0.55
    figure = new_figure((11.0, 4.0))
    forces, accel, speeds = figure.subplots(1, 3)
    forces.plot(fine, friction_cf, "k--", lw=1, label="closed form")
    forces.plot(fine, normal_cf, "k--", lw=1)
    forces.plot(slopes, friction, "o", color="C0", label="friction force $F_T$")
    forces.plot(slopes, normal, "s", color="C1", label="normal force $F_N$")
    forces.set(xlabel="slope α (rad)", ylabel="force on the box (N)",
               title=f"Contact forces, μ = {FRICTION}, m = {MASS:g} kg")
    accel.plot(fine, acceleration_cf, "k--", lw=1, label="g (sin α − μ cos α) above atan μ, 0 below")
    accel.plot(slopes, acceleration, "o", color="C2", label="simulated")
    accel.set(xlabel="slope α (rad)", ylabel="acceleration down the slope (m/s²)", title="Stick, then slip")
    for axes in (forces, accel):
        axes.axvline(critical, color="0.6", lw=0.8, ls=":")
        axes.text(critical, 0.5, " atan μ", transform=axes.get_xaxis_transform(), va="center", fontsize=8,
                  color="0.4")
    for alpha, color in ((below, "C0"), (above, "C3")):
        _, _, speed, trajectory = on_incline(model, alpha)
        speeds.plot(trajectory.t, speed, color=color, lw=3, alpha=0.6, label=f"α = {alpha} rad")
        speeds.plot(trajectory.t, closed_form(alpha)[2] * trajectory.t, "k--", lw=1)
    speeds.plot([], [], "k--", lw=1, label="closed form a t")
    speeds.set(xlabel="time (s)", ylabel="speed down the slope (m/s)", title="Released from rest")
    forces.legend(fontsize=7, loc="lower right")
    accel.legend(fontsize=7, loc="upper left")
    speeds.legend(fontsize=7)
    path = save_figure(figure, out, "box_on_incline")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
