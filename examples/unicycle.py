"""A unicycle: a rider balanced in pitch over a wheel rolling without slipping, falling or weaving in lean.

The rider (with the seat and the fork) is a free body whose frame has its origin at the wheel's centre,
x forward, y along the axle (to the left), z up; the wheel turns on a revolute joint about y (the axle)
and rolls without slipping on the ground (``mb.RollingDisc``, three rows: the ground's force on the
wheel along the world's −y, x and z). In pitch the unicycle is an inverted pendulum on the wheel
(D. W. Vos and A. H. von Flotow, "Dynamics and nonlinear adaptive control of an autonomous unicycle",
Proc. 29th IEEE Conference on Decision and Control, 1990), balanced here by the pedals: the torque
``τ = k_p θ + k_d θ̇`` on the wheel (its reaction on the rider), with ``θ`` the rider's pitch and ``θ̇``
the rate of the rider about its own y axis. The pedals act about the axle only, so nothing holds the
lean: at 2 m/s the unicycle falls to the side (the run stops at a lean of 0.6 rad, where a rider puts a
foot down); at 6 m/s it steers into its lean as a rolling coin does and weaves along a curving path.

Writes ``unicycle.png``: lean, pitch, the path of the contact point, and the ground's normal and
sideways force against time, for both speeds.
Run: python examples/unicycle.py [output_folder]
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace

import numpy as np

import multibody as mb
from multibody import inertia
from multibody.plotting import new_figure, save_figure


@dataclass(frozen=True)
class Unicycle:
    """The unicycle's dimensions (m) and masses (kg): the wheel, and the rider, a 0.3 × 0.4 × 1.0 m box
    whose centre of mass is ``rider_height`` above the axle."""

    wheel_radius: float = 0.3
    wheel_mass: float = 4.0
    rider_mass: float = 70.0
    rider_height: float = 0.8

    def model(self):
        """The :class:`~multibody.model.Model`: ``rider`` on a free-flyer joint (``root_joint``), ``wheel`` on
        the revolute joint ``axle`` about the rider's y axis."""
        builder = mb.ModelBuilder("unicycle")
        builder.add_body("rider", joint=mb.joints.FreeFlyer(), joint_name="root_joint",
                         inertia=inertia.box(self.rider_mass, (0.3, 0.4, 1.0), center=(0.0, 0.0, self.rider_height)))
        builder.add_body("wheel", parent="rider", joint=mb.joints.Revolute((0.0, 1.0, 0.0)), joint_name="axle",
                         inertia=inertia.cylinder(self.wheel_mass, self.wheel_radius, 0.06, axis="y"))
        return builder.build()

    def system(self):
        """The model with the wheel's ``RollingDisc`` on the ground ``z = 0``."""
        return mb.ConstrainedSystem(self.model(), [mb.RollingDisc("wheel", self.wheel_radius, axis=(0.0, 1.0, 0.0))])


def yaw_lean_pitch(quat):
    """Yaw ``ψ``, lean ``φ`` and pitch ``θ`` (rad) of the rider's orientations ``quat (..., 4)``: ``(..., 3)``.

    The rider's rotation is ``R = Rz(ψ) Rx(φ) Ry(θ)``: heading ψ about the vertical, lean φ about the
    heading (positive to the right), pitch θ about the axle (positive forward). Its entries give
    ``sin φ = R₃₂``, ``tan θ = −R₃₁ / R₃₃``, ``tan ψ = −R₁₂ / R₂₂``.
    """
    R = mb.spatial.quat_to_rotation(quat)
    lean = np.arcsin(np.clip(R[..., 2, 1], -1.0, 1.0))
    pitch = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    yaw = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    return np.stack([yaw, lean, pitch], axis=-1)


def start(unicycle, system, speed, lean=0.0, pitch=0.0):
    """A state ``(q0 (8,), v0 (7,))`` on the rolling constraint: the unicycle at the origin heading along x,
    leaned by ``lean`` and pitched by ``pitch`` (rad), the wheel rolling at ``speed`` (m/s)."""
    q = system.model.neutral()
    q[2] = unicycle.wheel_radius * np.cos(lean)
    q[3:7] = mb.spatial.rotation_to_quat(mb.spatial.axis_angle_rotation([1.0, 0.0, 0.0], lean)
                                         @ mb.spatial.axis_angle_rotation([0.0, 1.0, 0.0], pitch))
    v = np.zeros(system.nv)
    v[0], v[6] = speed, speed / unicycle.wheel_radius
    return system.project(q, v)


class PitchFeedback:
    """The pedals' torque on the wheel, ``τ = k_p θ + k_d θ̇`` (N·m), with ``θ`` the rider's pitch
    (:func:`yaw_lean_pitch`) and ``θ̇`` its angular velocity about its own y axis; ``k_p`` in N·m/rad,
    ``k_d`` in N·m·s/rad. A pitch forward drives the wheel forward, under the rider, while the reaction
    on the rider pitches it back. Called as ``tau(t, q, v) -> (nv,)``."""

    def __init__(self, model, kp=1500.0, kd=300.0):
        self.kp, self.kd, self.nv = float(kp), float(kd), model.nv
        self.axle = model.idx_v[model.joint_index("axle")]

    def __call__(self, t, q, v):
        tau = np.zeros(self.nv)
        tau[self.axle] = self.kp * yaw_lean_pitch(q[3:7])[2] + self.kd * v[4]
        return tau


def ride(unicycle=Unicycle(), speed=6.0, duration=8.0, lean=0.02, pitch=0.05, dt=0.01, rtol=1e-9, fall=0.6):
    """Simulate the unicycle under :class:`PitchFeedback` from ``lean``, ``pitch`` (rad) at ``speed`` (m/s) for
    ``duration`` (s), by RK45 at ``rtol`` (``atol`` a hundredth of it), the outputs ``dt`` apart; returns
    ``(system, feedback, trajectory)``, the trajectory cut before the first lean beyond ``fall`` (rad)."""
    system = unicycle.system()
    q0, v0 = start(unicycle, system, speed, lean, pitch)
    feedback = PitchFeedback(system.model)
    trajectory = mb.simulate(system, q0, v0, duration, dt=dt, method="RK45", tau=feedback, rtol=rtol,
                             atol=1e-2 * rtol)
    fallen = np.flatnonzero(np.abs(yaw_lean_pitch(trajectory.q[:, 3:7])[:, 1]) > fall)
    if fallen.size:
        trajectory = replace(trajectory, **{name: getattr(trajectory, name)[: fallen[0]]
                                            for name in ("t", "q", "v", "lam", "energy", "residual")})
    return system, feedback, trajectory


def main(out):
    unicycle = Unicycle()
    figure = new_figure((10.0, 7.0))
    lean_axes, pitch_axes, path_axes, force_axes = figure.subplots(2, 2).flat
    for speed, duration, color in ((2.0, 2.0, "C0"), (6.0, 8.0, "C1")):
        system, _, trajectory = ride(unicycle, speed, duration)
        (contact,) = system.constraints
        angles = yaw_lean_pitch(trajectory.q[:, 3:7])
        points = np.array([contact.contact_point(system.model, q) for q in trajectory.q])
        # the ground's force E λ on the wheel, and its part along the ground across the heading
        force = trajectory.lam @ contact.frame.T
        heading = np.column_stack([np.cos(angles[:, 0]), np.sin(angles[:, 0])])
        sideways = force[:, 0] * -heading[:, 1] + force[:, 1] * heading[:, 0]
        print(f"{speed} m/s: {trajectory.t[-1]:.2f} s, largest lean {np.abs(angles[:, 1]).max():.3f} rad, pitch "
              f"{np.abs(angles[:, 2]).max():.3f} rad at most and {np.abs(angles[-1, 2]):.1e} rad at the end, heading "
              f"turned by {angles[-1, 0]:.2f} rad; max residual {trajectory.residual.max():.2e}")
        label = f"{speed:g} m/s"
        lean_axes.plot(trajectory.t, angles[:, 1], color=color, label=label)
        pitch_axes.plot(trajectory.t, angles[:, 2], color=color, label=label)
        path_axes.plot(points[:, 0], points[:, 1], color=color, label=label)
        force_axes.plot(trajectory.t, force[:, 2], color=color, label=f"normal, {label}")
        force_axes.plot(trajectory.t, sideways, ":", color=color, label=f"sideways (to the left), {label}")
    lean_axes.set(xlabel="time (s)", ylabel="lean φ (rad, to the right)", title="Lean: held by nothing")
    pitch_axes.set(xlabel="time (s)", ylabel="pitch θ (rad, forward)", title="Pitch: balanced by the pedals")
    path_axes.set(xlabel="x (m)", ylabel="y (m)", title="Path of the contact point")
    path_axes.set_aspect("equal", adjustable="datalim")
    force_axes.set(xlabel="time (s)", ylabel="force (N)", title="The ground's force on the wheel")
    for axes in (lean_axes, pitch_axes, path_axes, force_axes):
        axes.legend(fontsize=7)
    print("wrote", save_figure(figure, out, "unicycle"))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
