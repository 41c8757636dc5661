"""A slider–crank driven by a motor, with the loads every joint carries.

The URDF is the open tree ground–crank–rod plus ground–slider (prismatic along x); a planar point
constraint pins the rod's tip to the slider. Its frame A is fixed in the rod, so its two multipliers
are the pin force on the slider along the rod's x and z axes (N). A speed-controlled motor drives the
crank. At each output time the constraint forces go back onto the bodies (``system.body_forces``) and a
Newton–Euler pass (``mb.joint_reaction_forces``) gives the force each joint's bearing carries.
Run: python examples/slider_crank.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, plot_trajectory, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
model = mb.robots.load("slider_crank")
in_plane = mb.spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))  # frame A's x–y plane = the x–z plane
system = mb.ConstrainedSystem(model, [mb.LoopClosure("rod_tip", "slider", frame_a=in_plane, kind="planar")])

target_speed, gain = 2 * np.pi * 2.0, 0.5  # rad/s (2 rev/s), N m s/rad
crank = model.joint_index("crank_joint")


def motor(t, q, v):
    """Torque on the crank only: a proportional speed controller."""
    tau = np.zeros(model.nv)
    tau[crank] = gain * (target_speed - v[crank])
    return tau


q0, v0 = system.project(np.array([0.0, 0.0, 0.5]), np.zeros(model.nv))  # crank along +x, slider at 0.5 m
trajectory = mb.simulate(system, q0, v0, 3.0, dt=0.01, method="RK45", tau=motor, rtol=1e-9, atol=1e-11)

# Bearing loads: the force each joint transmits, in its own frame (N).
bearing = []
for t, q, v, lam in zip(trajectory.t, trajectory.q, trajectory.v, trajectory.lam):
    a, _ = system.forward_dynamics(q, v, motor(t, q, v), t)
    f_constraint = system.body_forces(q, lam, t)
    bearing.append(mb.joint_reaction_forces(model, q, v, a, f_constraint))
bearing = np.array(bearing)  # (n, njoints, 6)
crank_speed = trajectory.v[:, crank]
print(f"mean crank speed over the last second: {crank_speed[trajectory.t >= 2].mean():.3f} rad/s (target {target_speed:.3f})")
print(f"peak crank bearing force {np.linalg.norm(bearing[:, crank, :3], axis=-1).max():.2f} N, "
      f"max residual {trajectory.residual.max():.2e}")

# the system names each curve after its joint with its unit (rad for the crank and rod, m for the slider)
for path in plot_trajectory(trajectory, out, "slider_crank", system,
                            multiplier_labels=["pin force on the slider along the rod's x",
                                               "pin force on the slider along the rod's z"]):
    print("wrote", path)
figure = new_figure()
ax = figure.subplots()
for j, name in enumerate(model.joint_names):
    ax.plot(trajectory.t, np.linalg.norm(bearing[:, j, :3], axis=-1), label=name)
ax.set_xlabel("t (s)")
ax.set_ylabel("bearing force |f| (N)")
ax.set_title("Force each joint's bearing carries")
ax.legend()
ax.grid(True, alpha=0.3)
print("wrote", save_figure(figure, out, "slider_crank_joint_forces"))
