"""The Panda falling under gravity with its joint limits enforced: every joint stops at its limit, the fingers stay
in the hand.

example-robot-data's Franka Emika Panda (seven arm joints, two prismatic fingers) is released from rest in its
neutral posture (clipped into its limits) and falls for 1.5 s. ``mb.JointLimits()`` makes each joint's
``model.lower ≤ q ≤ model.upper`` a unilateral constraint of the Moreau–Jean step (``dt = 1e-3`` s, no
restitution): where a joint reaches a limit, its generalized force (N·m for a revolute joint, N for a finger;
the step's impulse / dt, negative at an upper limit) stops it there and then holds it against gravity. The same
fall without limits (``mb.simulate(..., method="RK4", limits="ignore")``) slides the fingers out of the hand,
the lecture note's unconstrained arm.

Writes ``panda_limits.png``: each joint's position within its range (0 at ``lower``, 1 at ``upper``, dashed), the
finger positions with and without the limits (m), and the limits' generalized forces against time.
Run: python examples/panda_limits.py [output_folder]
"""

from __future__ import annotations

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

DT, DURATION = 1e-3, 1.5


def fall(model, limits=True):
    """The arm released from rest at its neutral posture (clipped into its limits): the trajectory, with the limits
    enforced (``mb.JointLimits()``) or, for ``limits=False``, unconstrained by RK4 with the limits ignored."""
    q0 = np.clip(model.neutral(), model.lower, model.upper)
    if limits:
        return mb.simulate(mb.ConstrainedSystem(model, [mb.JointLimits()]), q0, np.zeros(model.nv), DURATION, dt=DT)
    return mb.simulate(model, q0, np.zeros(model.nv), DURATION, dt=DT, method="RK4", limits="ignore")


def limit_forces(model, trajectory):
    """The limits' generalized force on each joint ``(n, nv)`` (N·m or N; row 0, before the first step, is zero)."""
    forces = np.zeros((len(trajectory.t), model.nv))
    for k, entry in enumerate(trajectory.contacts):
        for joint, force in zip(entry.body, entry.force[:, 0]):
            forces[k, model.idx_v[model.joint_index(str(joint))]] += force
    return forces


def main(out="output"):
    """Let the arm fall with and without its limits, print how far each goes, write the figure; return a summary."""
    model = mb.robots.load("panda")
    held, free = fall(model), fall(model, limits=False)
    t = held.t
    span = model.upper - model.lower
    fraction = (held.q - model.lower) / span
    forces = limit_forces(model, held)
    fingers = [i for i, name in enumerate(model.joint_names) if "finger" in name]
    outside = np.maximum(held.q - model.upper, model.lower - held.q).max()
    summary = {"largest excursion past a limit": outside, "forces": forces,
               "free fingers": free.q[:, [model.idx_q[i] for i in fingers]],
               "held fingers": held.q[:, [model.idx_q[i] for i in fingers]],
               "largest residual": held.complementarity.max(), "trajectory": held}
    print(f"with mb.JointLimits: every joint within its limits to {max(outside, 0.0):.1e} (m or rad); "
          f"largest complementarity residual {summary['largest residual']:.1e} m/s")
    for i in range(model.njoints):
        iq, iv = model.idx_q[i], model.idx_v[i]
        hit = np.flatnonzero(forces[:, iv] != 0.0)
        at = f"meets a limit at t = {t[hit[0]]:.3f} s, force up to {np.abs(forces[:, iv]).max():.3f}" if len(hit) \
            else "stays inside"
        print(f"  {model.joint_names[i]}: q from {held.q[0, iq]:+.4f} to {held.q[-1, iq]:+.4f} in "
              f"[{model.lower[iq]:+.4f}, {model.upper[iq]:+.4f}]; {at}")
    for i in fingers:
        iq = model.idx_q[i]
        print(f"  without limits {model.joint_names[i]} ends at {free.q[-1, iq]:+.3f} m (range "
              f"[{model.lower[iq]:g}, {model.upper[iq]:g}] m)")

    figure = new_figure((11.0, 4.0))
    range_axes, finger_axes, force_axes = figure.subplots(1, 3)
    for i in range(model.njoints):
        iq = model.idx_q[i]
        range_axes.plot(t, fraction[:, iq], color=f"C{i}", label=model.joint_names[i].removeprefix("panda_"))
    for level in (0.0, 1.0):
        range_axes.axhline(level, color="k", ls="--", lw=1)
    range_axes.set(xlabel="time (s)", ylabel="(q − lower) / (upper − lower)", ylim=(-0.05, 1.05),
                   title="Joints within their limits (dashed)")
    for i, style in zip(fingers, ("-", ":")):
        iq, name = model.idx_q[i], model.joint_names[i].removeprefix("panda_")
        finger_axes.plot(t, 1e3 * held.q[:, iq], "C0" + style, lw=2, label=f"{name}, mb.JointLimits")
        finger_axes.plot(t, 1e3 * free.q[:, iq], "C3" + style, lw=1, label=f"{name}, no limits (RK4)")
    finger_axes.axhline(1e3 * model.upper[model.idx_q[fingers[0]]], color="k", ls="--", lw=1, label="upper limit")
    finger_axes.axhline(1e3 * model.lower[model.idx_q[fingers[0]]], color="k", ls="--", lw=1)
    finger_axes.set(xlabel="time (s)", ylabel="finger opening (mm)", ylim=(-20, 100),
                    title="Fingers stay in the hand")
    for i in range(model.njoints):
        iv = model.idx_v[i]
        if np.any(forces[:, iv]):
            force_axes.plot(t[1:], forces[1:, iv], color=f"C{i}", lw=1,
                            label=model.joint_names[i].removeprefix("panda_"))
    # impacts (an impulse over one step) and holding forces differ by orders of magnitude
    force_axes.set_yscale("symlog", linthresh=1.0)
    force_axes.set(xlabel="time (s)", ylabel="limit force (N·m; N for a finger)",
                   title="Limit forces (< 0 at an upper limit)")
    range_axes.legend(fontsize=6, loc="center right")
    finger_axes.legend(fontsize=6, loc="upper left")
    force_axes.legend(fontsize=7)
    path = save_figure(figure, out, "panda_limits")
    print("wrote", path)
    summary["paths"] = [path]
    return summary


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
