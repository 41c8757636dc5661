"""A ball dropped on the ground with Newton's restitution e: its bounce apexes fall in the ratio e², then it rests.

The ball of ``examples/sliding_sphere.py`` (1 kg, radius 0.1 m) is dropped from a gap ``H₀ = 1`` m above the
ground with restitution ``e`` (``mb.Ground(restitution=e)``). Newton's law turns the normal velocity ``−u`` at
impact into ``e u``, so each apex is ``e²`` times the one before, ``H_k = e^{2k} H₀``, and the impulse of a bounce
is ``m (1 + e) u`` with ``u = √(2 g H)``. The flights last ``2 e^k √(2 H₀/g)`` in all, a finite time; the
Moreau–Jean step (``dt = 1e-3`` s) ends the bounces once the ball approaches slower than a step's change of
velocity, and the ball rests on the ground, which then carries its weight ``m g``. The contact force is the
step's impulse / dt (N).

Writes ``bouncing_ball.png``: the height of the ball's bottom with the apexes ``e^{2k} H₀`` dashed, and the
contact force (log scale) with ``m (1 + e) √(2 g H_k)/dt`` at each bounce and ``m g`` at rest.
Run: python examples/bouncing_ball.py [output_folder]
"""

from __future__ import annotations

import os
import runpy
import sys
from itertools import pairwise

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

G = 9.81
MASS, RADIUS = 1.0, 0.1
RESTITUTION, HEIGHT = 0.7, 1.0
DT, DURATION = 1e-3, 3.0


def sliding_sphere():
    """The functions of ``examples/sliding_sphere.py`` (its ball model)."""
    return runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "sliding_sphere.py"))


def drop(model, e=RESTITUTION, height=HEIGHT):
    """The ball dropped from rest with its bottom ``height`` (m) above the ground: ``(trajectory, gap (n,) (m),
    normal force (n,) (N), the first step of each bounce (b,))``."""
    system = mb.ConstrainedSystem(model, [mb.Ground(restitution=e)])
    trajectory = mb.simulate(system, [0, 0, height + RADIUS, 0, 0, 0, 1], np.zeros(6), DURATION, dt=DT)
    gap = trajectory.q[:, 2] - RADIUS
    force = np.array([entry.force[:, 2].sum() for entry in trajectory.contacts])
    # a bounce: a step whose contact reverses the falling velocity
    vz = trajectory.v[:, 2]
    bounces = np.flatnonzero((vz[:-1] < -1e-6) & (vz[1:] > 1e-6)) + 1
    return trajectory, gap, force, bounces


def apexes(gap, bounces):
    """The highest gap (m) of each flight: from the start to the first bounce, then between bounces."""
    edges = np.r_[0, bounces, len(gap)]
    return np.array([gap[a:b].max() for a, b in pairwise(edges)])


def main(out="output"):
    """Drop the ball, print the apexes against e^{2k} H₀ and the resting force, write the figure; return a
    summary."""
    model = sliding_sphere()["ball_model"](MASS, RADIUS)
    trajectory, gap, force, bounces = drop(model)
    t = trajectory.t
    heights = apexes(gap, bounces)
    expected = HEIGHT * RESTITUTION ** (2 * np.arange(len(heights)))
    # the ball rests from the output time after its last motion on
    rest = np.flatnonzero(np.abs(trajectory.v).max(axis=1) > 1e-9)[-1] + 1
    summary = {"apexes": heights, "closed-form apexes": expected, "bounces": len(bounces),
               "rests from": t[rest], "resting speed": np.abs(trajectory.v[rest:]).max(),
               "resting force": force[rest + 1:], "largest residual": trajectory.complementarity.max()}
    print(f"e = {RESTITUTION}: {len(bounces)} bounces, at rest from t = {t[rest]:.3f} s "
          f"(speed then at most {summary['resting speed']:.1e} m/s)")
    for k, (h, h_cf) in enumerate(zip(heights[:6], expected[:6])):
        ratio = "" if k == 0 else f", ratio {h / heights[k - 1]:.4f} (e² = {RESTITUTION ** 2:.4f})"
        print(f"apex {k}: {h:.5f} m (e^{2 * k} H₀ = {h_cf:.5f} m){ratio}")
    print(f"resting contact force {force[-1]:.9f} N (m g = {MASS * G:.9f} N); largest complementarity residual "
          f"{summary['largest residual']:.1e} m/s")

    figure = new_figure((10.0, 4.0))
    height_axes, force_axes = figure.subplots(1, 2)
    height_axes.plot(t, gap, color="C0", label="height of the ball's bottom")
    edges = np.r_[0, bounces]
    for k, (a, b) in enumerate(zip(edges, np.r_[bounces, rest])):
        height_axes.hlines(expected[k], t[a], t[b], colors="k", linestyles="--", lw=1,
                           label="closed-form apexes $e^{2k} H_0$" if k == 0 else None)
    height_axes.set(xlabel="time (s)", ylabel="height (m)", title=f"Dropped from {HEIGHT:g} m, e = {RESTITUTION}")
    force_axes.semilogy(t[1:], np.maximum(force[1:], 1e-3), color="C3", lw=1, label="normal force on the ball")
    impact = MASS * (1 + RESTITUTION) * np.sqrt(2 * G * expected[: len(bounces)]) / DT
    force_axes.plot(t[bounces], impact, "k_", ms=12, mew=1.5, label="closed form m (1 + e) √(2 g H_k) / dt")
    force_axes.axhline(MASS * G, color="k", ls="--", lw=1, label="weight m g")
    force_axes.set(xlabel="time (s)", ylabel="force (N)", ylim=(1.0, 3e4),
                   title=f"Contact force (the step's impulse / dt, dt = {DT:g} s)")
    height_axes.legend(fontsize=7)
    force_axes.legend(fontsize=7, loc="upper right")
    path = save_figure(figure, out, "bouncing_ball")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
