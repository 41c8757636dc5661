"""A car with Ackermann steering driving a circle on four rolling wheels, and the force on each wheel.

The car is a chassis on a free-flyer joint with four wheels on revolute axles; each front wheel turns
on a revolute steering joint (a knuckle). Each wheel rolls without slipping on the ground
(``mb.RollingDisc`` with its normal row). The steering joints are held at the Ackermann angles of a
turning radius ``R`` (measured to the middle of the rear axle, wheelbase ``L``, track ``w``):

    cot δ_outer − cot δ_inner = w / L,   cot δ_inner = (R − w/2) / L,   cot δ_outer = (R + w/2) / L

(J. Y. Wong, *Theory of Ground Vehicles*, 4th ed., Wiley 2008, §5.1, eq. 5.1), so that the four
wheel axles meet at the centre of the turn. Each is held by an ``mb.JointCoupling`` with ratio 0
(``q_b = 0 · q_a + δ``), whose multiplier is the torque the steering holds.

Four rolling wheels say more than the car's motion needs: three of the four normal rows fix the
chassis' height, roll and pitch, and with the axles meeting in one point two of the four lateral
rows fix its sideways slip and yaw rate (rank 11 of 14 rows). The redundancy is by design; the
multipliers are the minimum-norm ones, which share the load among the wheels (a rigid car on four
wheels is statically indeterminate: the minimum norm is one of its many load sharings). Their sums
are determined: the normal forces carry the weight and the lateral ones give the centripetal force
``m v_G² / R_G`` of the centre of mass.

The car starts on the circle at the speed the constraints allow (``system.project``) and, with no
torque and no losses (rolling forces do no work), drives round it at constant speed. Writes the path
with the fitted circle (``ackermann_car_path.png``) and each wheel's normal and lateral force against
time (``ackermann_car_forces.png``).
Run: python examples/ackermann_car.py [output_folder]
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass, replace

import numpy as np

import multibody as mb
from multibody import inertia
from multibody.plotting import new_figure, save_figure

#: The wheels, in the order of their RollingDisc constraints.
WHEELS = ("rear_left_wheel", "rear_right_wheel", "front_left_wheel", "front_right_wheel")


@dataclass(frozen=True)
class Car:
    """The car's dimensions (m) and masses (kg). The chassis frame has its origin at the middle of the
    rear axle, x forward, y to the left, z up."""

    wheelbase: float = 2.5
    track: float = 1.5
    wheel_radius: float = 0.3
    chassis_mass: float = 1200.0
    wheel_mass: float = 15.0
    knuckle_mass: float = 5.0

    def model(self):
        """The :class:`~multibody.model.Model`: the chassis (free flyer, a 3.8 × 1.6 × 0.5 m box with its
        centre of mass 1.2 m ahead of the rear axle and 0.25 m above the wheel centres), the rear wheels
        on revolute joints about y, and the front wheels on revolute joints about y of knuckles that
        steer about z (``front_left_steering``, ``front_right_steering``)."""
        builder = mb.ModelBuilder("ackermann_car")
        builder.add_body("chassis", joint=mb.joints.FreeFlyer(), joint_name="root_joint",
                         inertia=inertia.box(self.chassis_mass, (3.8, 1.6, 0.5), center=(1.2, 0.0, 0.25)))
        wheel = inertia.cylinder(self.wheel_mass, self.wheel_radius, 0.2, axis="y")
        for side, y in (("left", self.track / 2), ("right", -self.track / 2)):
            builder.add_body(f"rear_{side}_wheel", parent="chassis", joint=mb.joints.Revolute((0.0, 1.0, 0.0)),
                             placement=mb.spatial.pose_from_xyz_rpy((0.0, y, 0.0)), inertia=wheel)
        for side, y in (("left", self.track / 2), ("right", -self.track / 2)):
            builder.add_body(f"front_{side}_knuckle", parent="chassis", joint=mb.joints.Revolute((0.0, 0.0, 1.0)),
                             joint_name=f"front_{side}_steering",
                             placement=mb.spatial.pose_from_xyz_rpy((self.wheelbase, y, 0.0)),
                             inertia=inertia.sphere(self.knuckle_mass, 0.05))
            builder.add_body(f"front_{side}_wheel", parent=f"front_{side}_knuckle",
                             joint=mb.joints.Revolute((0.0, 1.0, 0.0)), inertia=wheel)
        return builder.build()

    def ackermann_angles(self, radius):
        """Steering angles ``(δ_inner, δ_outer)`` (rad) of a turn of ``radius`` (m, to the middle of the
        rear axle), from ``cot δ = (R ∓ w/2) / L``."""
        if not radius > self.track / 2:
            raise ValueError(f"radius must exceed half the track ({self.track / 2} m), got {radius!r}")
        return (float(np.arctan2(self.wheelbase, radius - self.track / 2)),
                float(np.arctan2(self.wheelbase, radius + self.track / 2)))


def circle_setup(car=Car(), radius=10.0, speed=5.0):
    """The car turning left on a circle of ``radius`` (m, centre at ``(0, radius)``), the middle of its
    rear axle at the origin heading along x at ``speed`` (m/s).

    Returns ``(system, q0 (13,), v0 (12,))``; the system's constraints are the four
    ``RollingDisc`` (in the order of :data:`WHEELS`; multipliers: the ground's force on the wheel
    along the world's −y, x and z, N) and the two steering holds (steering torques, N·m). The projection's
    ``mb.RankDeficientWarning`` about the wheels' repeated rows, which are intended, is silenced.
    """
    model = car.model()
    r = car.wheel_radius
    wheels = [mb.RollingDisc(name, r, axis=(0.0, 1.0, 0.0)) for name in WHEELS]
    inner, outer = car.ackermann_angles(radius)
    # ratio 0: each steering joint is held at its angle, whatever the other does
    holds = [mb.JointCoupling("front_right_steering", "front_left_steering", ratio=0.0, offset=inner),
             mb.JointCoupling("front_left_steering", "front_right_steering", ratio=0.0, offset=outer)]
    system = mb.ConstrainedSystem(model, wheels + holds)
    q_index = {name: model.idx_q[model.joint_index(name)] for name in model.joint_names}
    v_index = {name: model.idx_v[model.joint_index(name)] for name in model.joint_names}
    q = model.neutral()
    q[2] = r
    q[q_index["front_left_steering"]], q[q_index["front_right_steering"]] = inner, outer
    # A rigid turn at ω = v / R about the centre: each wheel rolls at its distance from it (spin = speed / r).
    omega = speed / radius
    v = np.zeros(model.nv)
    v[0], v[5] = speed, omega
    half = car.track / 2
    distances = {"rear_left_wheel": radius - half, "rear_right_wheel": radius + half,
                 "front_left_wheel": np.hypot(car.wheelbase, radius - half),
                 "front_right_wheel": np.hypot(car.wheelbase, radius + half)}
    for name, distance in distances.items():
        v[v_index[f"{name}_joint"]] = omega * distance / r
    with warnings.catch_warnings():
        # the four wheels' repeated rows are intended (see the module docstring); the first projection says so
        warnings.simplefilter("ignore", mb.RankDeficientWarning)
        q0, v0 = system.project(q, v)
    return system, q0, v0


def fit_circle(xy):
    """Centre ``(2,)`` and radius (m) of the circle nearest to the points ``xy (n, 2)`` (m) in the algebraic
    least-squares sense (I. Kåsa, "A circle fitting procedure and its error analysis", IEEE Trans.
    Instrum. Meas. IM-25, 1976): the circle ``x² + y² = 2 a x + 2 b y + c`` has centre ``(a, b)`` and
    radius ``√(c + a² + b²)``."""
    xy = np.asarray(xy, dtype=float)
    # x² + y² = 2 a x + 2 b y + c, solved for (a, b, c) by least squares
    design = np.column_stack([2.0 * xy, np.ones(len(xy))])
    (a, b, c), *_ = np.linalg.lstsq(design, np.sum(xy**2, axis=1), rcond=None)
    return np.array([a, b]), float(np.sqrt(c + a * a + b * b))


def wheel_forces(system, trajectory):
    """The ground's force on each wheel, from the multipliers of its ``RollingDisc``: a dict of
    ``(n, 4)`` arrays (N), one column per wheel of :data:`WHEELS`: ``"world"`` ``(n, 4, 3)`` in world
    axes; ``"normal"`` along the ground's normal; ``"lateral"`` along the wheel's axle (positive to the
    car's left); ``"longitudinal"`` along the wheel's rolling direction (positive forward)."""
    model = system.model
    offsets = np.cumsum([0] + [c.rows(model) for c in system.constraints])
    world, lateral, longitudinal = [], [], []
    for k, contact in enumerate(system.constraints[: len(WHEELS)]):
        # E λ: the multipliers are the force's components along the plane frame E = [t₁ t₂ n]
        force = trajectory.lam[:, offsets[k] : offsets[k + 1]] @ contact.frame.T
        axle = mb.frame_placement(model, trajectory.q, contact.body)[:, :3, 1]
        forward = np.cross(axle, contact.normal)
        world.append(force)
        lateral.append(np.sum(force * axle, axis=1))
        longitudinal.append(np.sum(force * forward, axis=1))
    world = np.stack(world, axis=1)
    return {"world": world, "normal": world @ system.constraints[0].normal,
            "lateral": np.stack(lateral, axis=1), "longitudinal": np.stack(longitudinal, axis=1)}


def drive(system, q0, v0, torque, drive_time, coast_time, dt=0.02, rtol=1e-10):
    """Drive ``system`` (from :func:`circle_setup`) from ``(q0, v0)`` with ``torque`` (N·m) on each rear wheel
    for ``drive_time`` (s), then let it coast for ``coast_time`` (s), by DOP853 at ``rtol`` (``atol`` a
    hundredth of it); returns one :class:`~multibody.Trajectory` of both (outputs every ``dt`` s in each)
    and the joint forces ``(nv,)`` of the drive."""
    model = system.model
    tau = np.zeros(model.nv)
    for name in ("rear_left_wheel_joint", "rear_right_wheel_joint"):
        tau[model.idx_v[model.joint_index(name)]] = torque
    options = dict(dt=dt, method="DOP853", rtol=rtol, atol=1e-2 * rtol)
    driven = mb.simulate(system, q0, v0, drive_time, tau=tau, **options)
    # the torque stops at drive_time: a second run from there, so that no step straddles the switch
    coasting = mb.simulate(system, driven.q[-1], driven.v[-1], drive_time + coast_time, t0=drive_time, **options)
    joined = {name: np.concatenate([getattr(driven, name), getattr(coasting, name)[1:]])
              for name in ("t", "q", "v", "lam", "energy", "residual")}
    return replace(driven, **joined), tau


def drive_torque(trajectory, drive_time, tau):
    """The joint forces ``(n, nv)`` at each output time of :func:`drive`'s trajectory (the drive's up to
    ``drive_time``, zero after; the output at ``drive_time`` ends the drive)."""
    return np.where(trajectory.t[:, None] <= drive_time, tau, 0.0)


def main(out):
    car, radius, torque, drive_time, coast_time = Car(), 10.0, 250.0, 4.0, 12.5
    system, q0, v0 = circle_setup(car, radius, speed=0.0)
    trajectory, tau = drive(system, q0, v0, torque, drive_time, coast_time)
    model = system.model
    print(f"constraint rows {system.num_rows}, rank {system.rank(trajectory.q[0])}")
    centre, fitted = fit_circle(trajectory.q[:, :2])
    distance = np.linalg.norm(trajectory.q[:, :2] - centre, axis=1)
    turned = np.unwrap(np.arctan2(*(trajectory.q[:, :2] - centre).T[::-1]))
    print(f"rear axle's path: circle of radius {fitted:.9f} m (R = {radius} m) about ({centre[0]:.2e}, "
          f"{centre[1]:.9f}) m, {np.ptp(turned) / (2 * np.pi):.2f} turns; distances to that centre within "
          f"{np.ptp(distance):.2e} m")
    coasting = trajectory.t >= drive_time
    speed = np.hypot(*trajectory.v[:, :2].T)
    print(f"speed after the drive {speed[coasting].min():.9f} to {speed[coasting].max():.9f} m/s; energy drift "
          f"while coasting {np.ptp(trajectory.energy[coasting]) / trajectory.energy[-1]:.2e} (relative), "
          f"max residual {trajectory.residual.max():.2e}")

    forces = wheel_forces(system, trajectory)
    mass, g = model.total_mass, float(np.linalg.norm(model.gravity))
    # Newton's law for the whole car: the ground's forces and the weight give the centre of mass its acceleration
    joint_forces = drive_torque(trajectory, drive_time, tau)
    a = np.array([system.forward_dynamics(q, v, f)[0] for q, v, f in zip(trajectory.q, trajectory.v, joint_forces)])
    a_G = mb.center_of_mass_acceleration(model, trajectory.q, trajectory.v, a)
    total = forces["world"].sum(axis=1)
    newton = np.abs(total + mass * model.gravity - mass * a_G).max()
    print(f"normal forces sum to {total[:, 2].min():.3f} to {total[:, 2].max():.3f} N (m g = {mass * g:.3f} N); "
          f"|Σ F + m g − m a_G| ≤ {newton:.2e} N")
    end = len(trajectory.t) - 1
    for name, normal, lateral, longitudinal in zip(WHEELS, *(forces[k][end] for k in ("normal", "lateral",
                                                                                      "longitudinal"))):
        print(f"  {name:18s} coasting: normal {normal:9.2f} N  lateral {lateral:8.2f} N  "
              f"longitudinal {longitudinal:8.2f} N")

    figure = new_figure((6.5, 5.5))
    axes = figure.subplots()
    turn = np.linspace(0.0, 2.0 * np.pi, 361)
    axes.plot(centre[0] + fitted * np.cos(turn), centre[1] + fitted * np.sin(turn), color="0.6", lw=4,
              label=f"fitted circle, radius {fitted:.4f} m")
    axes.plot(*trajectory.q[:, :2].T, color="k", label="middle of the rear axle")
    for contact, name in zip(system.constraints, WHEELS):
        points = np.array([contact.contact_point(model, q) for q in trajectory.q])
        axes.plot(points[:, 0], points[:, 1], lw=1, label=f"{name.replace('_', ' ')} contact")
    axes.plot(*centre, "k+", ms=10)
    axes.set_aspect("equal", adjustable="datalim")
    axes.set(xlabel="x (m)", ylabel="y (m)", title=f"Ackermann car steered for R = {radius} m")
    axes.legend(fontsize=8, loc="center")
    path_figure = save_figure(figure, out, "ackermann_car_path")

    figure = new_figure((10.0, 7.0))
    figure.suptitle(f"The ground's force on each wheel: {torque:g} N·m on each rear wheel for {drive_time:g} s, "
                    "then coasting")
    panels = figure.subplots(2, 2, sharex=True)
    for k, (key, title) in enumerate((("normal", "normal force (N)"), ("lateral", "lateral force, to the left (N)"),
                                      ("longitudinal", "longitudinal force, forward (N)"))):
        axes = panels.flat[k]
        for name, values in zip(WHEELS, forces[key].T):
            axes.plot(trajectory.t, values, label=name.replace("_", " "))
        axes.set(ylabel=title)
    panels[0, 0].plot(trajectory.t, forces["normal"].sum(axis=1), "k", label="sum")
    panels[0, 0].axhline(mass * g, color="0.5", ls="--", label="m g")
    axes = panels[1, 1]
    axes.plot(trajectory.t, np.linalg.norm(total[:, :2], axis=1), "k", lw=3, label="|Σ horizontal forces|")
    axes.plot(trajectory.t, mass * np.linalg.norm(a_G[:, :2], axis=1), color="0.8", ls="--", label="m |a_G|")
    axes.set(ylabel="force (N)", title="Newton's law for the whole car")
    for axes in panels.flat:
        axes.axvline(drive_time, color="0.7", lw=0.8)
        axes.legend(fontsize=7)
    for axes in panels[1]:
        axes.set_xlabel("time (s)")
    force_figure = save_figure(figure, out, "ackermann_car_forces")
    for path in (path_figure, force_figure):
        print("wrote", path)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
