"""A sphere launched sliding without spin on the ground starts to roll at t = 2v₀/(7μg), then rolls at 5v₀/7.

A uniform sphere (mass ``m``, radius ``r``, moment of inertia ``(2/5) m r²``) is launched along x at ``v₀`` with
no spin on a ground of friction ``μ`` (``mb.Ground(friction=μ)``). While its contact point slips, kinetic
friction ``−μ m g`` slows the centre and spins the sphere up:

    v(t) = v₀ − μ g t,      ω(t) r = (5/2) μ g t,

until the contact point stops slipping, ``v = ω r``, at ``t* = 2 v₀/(7 μ g)``; from then on the sphere rolls at
``v = ω r = 5 v₀/7`` and friction vanishes (the angular momentum about the contact point, ``m r v + (2/5) m r² ω``,
is kept by every force there). The simulation is the Moreau–Jean step at ``dt = 1e-3`` s; the friction force is
the contact row's force (the step's impulse / dt, N).

Writes ``sliding_sphere.png``: the speed, the spin times the radius and the friction force against time, the
closed forms dashed.
Run: python examples/sliding_sphere.py [output_folder]
"""

from __future__ import annotations

import sys

import numpy as np

import multibody as mb
from multibody import inertia
from multibody.joints import FreeFlyer
from multibody.plotting import new_figure, save_figure

G = 9.81
MASS, RADIUS = 1.0, 0.1
FRICTION, SPEED = 0.3, 2.0
DT, DURATION = 1e-3, 0.6


def ball_model(mass=MASS, radius=RADIUS):
    """A free uniform sphere ``"ball"`` of ``mass`` (kg) and ``radius`` (m) with its sphere collision geometry."""
    builder = mb.ModelBuilder("ball")
    builder.add_body("ball", joint=FreeFlyer(), inertia=inertia.sphere(mass, radius))
    builder.add_collision("ball", "sphere", radius)
    return builder.build()


def closed_form(t, v0=SPEED, mu=FRICTION):
    """Speed (m/s), spin times radius (m/s) and friction force along x (N) at times ``t (n,)`` (s), and the time
    the sphere starts to roll, ``2 v₀/(7 μ g)`` (s)."""
    rolls = 2 * v0 / (7 * mu * G)
    sliding = t < rolls
    speed = np.where(sliding, v0 - mu * G * t, 5 * v0 / 7)
    spin = np.where(sliding, 2.5 * mu * G * t, 5 * v0 / 7)
    friction = np.where(sliding, -mu * MASS * G, 0.0)
    return speed, spin, friction, rolls


def launch(model, v0=SPEED, mu=FRICTION):
    """The sphere launched at ``v0`` (m/s) along x without spin: ``(trajectory, speed (n,), spin times radius (n,),
    friction force along x (n,))``, velocities in world axes (m/s), the force summed over the step's contact rows
    (N; entry 0, before the first step, is zero)."""
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=mu)])
    trajectory = mb.simulate(system, [0, 0, RADIUS, 0, 0, 0, 1], [v0, 0, 0, 0, 0, 0], DURATION, dt=DT)
    velocity = mb.frame_velocity(model, trajectory.q, trajectory.v, "ball")
    friction = np.array([entry.force[:, 0].sum() for entry in trajectory.contacts])
    return trajectory, velocity[:, 0], velocity[:, 4] * RADIUS, friction


def main(out="output"):
    """Simulate, print the transition and the deviations from the closed forms, write the figure; return a
    summary."""
    model = ball_model()
    trajectory, speed, spin, friction = launch(model)
    t = trajectory.t
    speed_cf, spin_cf, _, rolls = closed_form(t)
    # the first output time at which the contact point no longer slips
    rolling = t[np.flatnonzero(np.abs(speed - spin) <= 1e-9)[0]]
    # the friction force of step k acts over (t[k-1], t[k]]: compare it with the closed form at the step's start
    friction_start = closed_form(t - DT)[2]
    summary = {"rolls at": rolling, "closed-form roll time": rolls, "final speed": speed[-1],
               "final spin times radius": spin[-1],
               "speed error": np.abs(speed - speed_cf).max(),
               "sliding friction": friction[1:int(rolls / DT)],
               "rolling friction": friction[int(np.ceil(rolls / DT)) + 1:],
               "largest residual": trajectory.complementarity.max()}
    print(f"rolls from t = {rolling:.3f} s (closed form 2v₀/(7μg) = {rolls:.4f} s) at {speed[-1]:.12f} m/s "
          f"(5v₀/7 = {5 * SPEED / 7:.12f} m/s), spin·r {spin[-1]:.12f} m/s")
    print(f"friction while sliding {friction[1]:.9f} N (−μ m g = {-FRICTION * MASS * G:.9f} N), while rolling at "
          f"most {np.abs(summary['rolling friction']).max():.1e} N; speed within {summary['speed error']:.1e} m/s of "
          "the closed form")

    figure = new_figure((10.0, 4.0))
    velocities, forces = figure.subplots(1, 2)
    velocities.plot(t, speed, color="C0", lw=2.5, alpha=0.7, label="speed of the centre v")
    velocities.plot(t, spin, color="C1", lw=2.5, alpha=0.7, label="spin times radius ω r")
    velocities.plot(t, speed_cf, "k--", lw=1, label="closed form: v₀ − μ g t, (5/2) μ g t, then 5v₀/7")
    velocities.plot(t, spin_cf, "k--", lw=1)
    velocities.axvline(rolls, color="0.6", lw=0.8, ls=":")
    velocities.text(rolls, 0.05, " 2v₀/(7μg)", transform=velocities.get_xaxis_transform(), fontsize=8, color="0.4")
    velocities.set(xlabel="time (s)", ylabel="velocity (m/s)",
                   title=f"Launched at {SPEED:g} m/s without spin, μ = {FRICTION}")
    forces.plot(t[1:], friction[1:], color="C2", lw=2.5, alpha=0.7, label="friction force on the sphere (x)")
    forces.plot(t[1:], friction_start[1:], "k--", lw=1, label="closed form: −μ m g, then 0")
    forces.axvline(rolls, color="0.6", lw=0.8, ls=":")
    forces.set(xlabel="time (s)", ylabel="force (N)", title=f"Friction, m = {MASS:g} kg, r = {RADIUS:g} m",
               ylim=(-1.3 * FRICTION * MASS * G, 0.3 * FRICTION * MASS * G))
    for axes in (velocities, forces):
        axes.legend(fontsize=7, loc="center right")
    path = save_figure(figure, out, "sliding_sphere")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
