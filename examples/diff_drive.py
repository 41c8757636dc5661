"""A differential-drive robot from URDF, driven by wheel torques under rolling constraints.

The shipped `diff_drive` robot: a chassis on a planar joint, two wheels on continuous joints, and a
ball caster. Each wheel rolls without slipping (a rolling-disc constraint without its normal row,
since the planar joint already holds the height). The two wheels' sideways rows say the same thing
(rank 3 of 4 rows): the solver reports it and shares the sideways force between them (minimum norm).
Run: python examples/diff_drive.py [output_folder]
"""

import sys
import warnings

import numpy as np

import multibody as mb
from multibody.plotting import plot_path, plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
# The repeated sideways row is intended: the simulation's rank check need not say so.
warnings.filterwarnings("ignore", category=mb.RankDeficientWarning)
robot = mb.robots.load("diff_drive")
wheels = [mb.RollingDisc(name, 0.08, axis=(0.0, 1.0, 0.0), normal=False) for name in ("left_wheel", "right_wheel")]
system = mb.ConstrainedSystem(robot, wheels)
left, right = robot.idx_v[robot.joint_index("left_wheel_joint")], robot.idx_v[robot.joint_index("right_wheel_joint")]


def torques(t, q, v):
    """Drive forward, then turn: more torque on the right wheel for t in [1, 2) s, damped wheels."""
    tau = -0.05 * v  # viscous losses in the wheel bearings (none on the planar joint's coordinates)
    tau[:3] = 0.0
    tau[left] += 0.2
    tau[right] += 0.2 + (0.15 if 1.0 <= t < 2.0 else 0.0)
    return tau


q0 = robot.neutral()
print(f"constraint rows {system.num_rows}, rank {system.rank(q0)}")
trajectory = mb.simulate(system, q0, np.zeros(robot.nv), 4.0, dt=0.01, tau=torques, method="RK45", rtol=1e-9, atol=1e-11)
heading = np.degrees(np.arctan2(trajectory.q[-1, 3], trajectory.q[-1, 2]))
print(f"after 4 s: at ({trajectory.q[-1, 0]:.3f}, {trajectory.q[-1, 1]:.3f}) m, heading {heading:.1f}°, "
      f"max residual {trajectory.residual.max():.2e}")
paths = plot_trajectory(trajectory, out, "diff_drive", coordinate_labels=["x", "y", "cos θ", "sin θ", "left", "right"])
paths.append(plot_path(trajectory.q[:, :2], out, "diff_drive", "path of the chassis"))
for path in paths:
    print("wrote", path)
