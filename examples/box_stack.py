"""A stack of four boxes dropped onto each other: each interface comes to carry the weight of the boxes above it.

Four free boxes (0.2 × 0.2 × 0.1 m, masses 2, 1, 0.5 and 0.25 kg from the bottom) start 5 mm apart above the
ground and fall; ``mb.Ground`` holds the bottom box and an ``mb.ContactPair`` each box on the one below (friction
0.5, no restitution). Each interface is a face on a face: four corner contacts, which the three rows of one rigid
body cannot tell apart (a singular Delassus matrix); the step's solver shares the load by its proximal rule.
Once the stack rests, the force the lower body (or the ground) exerts on box ``i`` is, by the equilibrium of the
boxes above,

    F_i = g Σ_{j ≥ i} m_j      (upwards, N).

The forces are the contact rows' forces (the step's impulse / dt) on box ``i`` summed over its four corners.

Writes ``box_stack.png``: each interface's force against time with its closed form dashed, and its deviation
from the closed form once the stack rests (log scale).
Run: python examples/box_stack.py [output_folder]
"""

from __future__ import annotations

import sys

import numpy as np

import multibody as mb
from multibody import inertia
from multibody.joints import FreeFlyer
from multibody.plotting import new_figure, save_figure

G = 9.81
MASSES = (2.0, 1.0, 0.5, 0.25)
SIZE = (0.2, 0.2, 0.1)
GAP, FRICTION = 0.005, 0.5
DT, DURATION = 1e-3, 0.3


def stack_model(masses=MASSES):
    """Free boxes ``box0``, ``box1``, … of ``masses`` (kg) and size ``SIZE`` (m), each with its box collision
    geometry."""
    builder = mb.ModelBuilder("stack")
    for i, mass in enumerate(masses):
        builder.add_body(f"box{i}", joint=FreeFlyer(), inertia=inertia.box(mass, SIZE))
        builder.add_collision(f"box{i}", "box", SIZE)
    return builder.build()


def interfaces(count):
    """``(body, other)`` of each interface from the bottom: ``box0`` on the ground, then each box on the one
    below."""
    return [("box0", "ground")] + [(f"box{i}", f"box{i - 1}") for i in range(1, count)]


def drop(model):
    """The stack of ``model``'s boxes released from rest, ``GAP`` (m) apart: ``(trajectory, forces (n, count))``, the upward
    force (N) on each box from the body below it, summed over the interface's contact rows (row 0 is zero)."""
    count = len(model.body_names)
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=FRICTION)]
                                  + [mb.ContactPair(body, other, friction=FRICTION)
                                     for body, other in interfaces(count)[1:]])
    height = SIZE[2]
    q0 = np.concatenate([[0, 0, height / 2 + i * (height + GAP) + GAP, 0, 0, 0, 1] for i in range(count)])
    trajectory = mb.simulate(system, q0, np.zeros(6 * count), DURATION, dt=DT)
    forces = np.array([[entry.force[(entry.body == body) & (entry.other == other), 2].sum()
                        for body, other in interfaces(count)] for entry in trajectory.contacts])
    return trajectory, forces


def main(out="output"):
    """Drop the stack, print each interface's resting force against the weight above, write the figure; return a
    summary."""
    model = stack_model()
    trajectory, forces = drop(model)
    t = trajectory.t
    above = G * np.cumsum(MASSES[::-1])[::-1]
    # the stack rests from the output time after its last motion on
    rest = np.flatnonzero(np.abs(trajectory.v).max(axis=1) > 1e-9)[-1] + 1
    deviation = np.abs(forces - above)
    summary = {"rests from": t[rest], "weights above": above, "resting forces": forces[rest + 1:],
               "largest resting deviation": deviation[rest + 1:].max(),
               "resting speed": np.abs(trajectory.v[rest:]).max(),
               "largest residual": trajectory.complementarity.max()}
    print(f"at rest from t = {t[rest]:.3f} s (speed then at most {summary['resting speed']:.1e} m/s)")
    for (body, other), force, weight in zip(interfaces(len(MASSES)), forces[-1], above):
        print(f"{other} on {body}: {force:.9f} N, weight above {weight:.9f} N")
    print(f"largest deviation at rest {summary['largest resting deviation']:.1e} N; largest complementarity residual "
          f"{summary['largest residual']:.1e} m/s")

    figure = new_figure((10.0, 4.0))
    force_axes, error_axes = figure.subplots(1, 2)
    for i, ((body, other), weight) in enumerate(zip(interfaces(len(MASSES)), above)):
        label = f"{other} on {body}"
        force_axes.plot(t[1:], forces[1:, i], color=f"C{i}", lw=2, alpha=0.8, label=label)
        force_axes.axhline(weight, color=f"C{i}", ls="--", lw=1)
        error_axes.semilogy(t[rest + 1:], np.maximum(deviation[rest + 1:, i], 1e-13), color=f"C{i}", label=label)
    force_axes.plot([], [], "k--", lw=1, label="closed form g Σ (masses above)")
    force_axes.set(xlabel="time (s)", ylabel="upward force on the box (N)", ylim=(0.0, 1.5 * above[0]),
                   title="Interface forces (impacts run off the top)")
    error_axes.axhline(1e-6, color="k", ls="--", lw=1, label="1e-6 N")
    error_axes.set(xlabel="time (s)", ylabel="|force − weight above| (N)", ylim=(1e-13, 1e-4),
                   title=f"At rest, from t = {t[rest]:.3f} s")
    force_axes.legend(fontsize=7, loc="upper right")
    error_axes.legend(fontsize=7, loc="upper right")
    path = save_figure(figure, out, "box_stack")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
