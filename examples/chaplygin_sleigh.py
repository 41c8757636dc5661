"""The Chaplygin sleigh: a rigid body on ice with one knife edge that cannot slide sideways.

A planar body (x, y, heading) carries a blade at a distance b ahead of its centre of mass. The blade
forbids sideways motion at its contact point (a nonholonomic, Pfaffian constraint). Whatever it
starts with, the sleigh ends up gliding straight along the blade with no rotation: the classical
result (Chaplygin 1911; Bloch, *Nonholonomic Mechanics and Control*, §1.7). Energy is conserved.
Run: python examples/chaplygin_sleigh.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import plot_path, plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
m, inertia, b = 2.0, 0.05, 0.2  # kg, kg m² about the centre of mass, m from the centre of mass to the blade

builder = mb.ModelBuilder("sleigh", gravity=(0.0, 0.0, 0.0))
builder.add_body("sleigh", joint=mb.joints.Planar(), joint_name="plane",
                 inertia=mb.Inertia(m, [0, 0, 0], np.diag([inertia, inertia, inertia])))
sleigh = builder.build()
blade = mb.KnifeEdge("sleigh", point=[b, 0.0, 0.0], direction=[1.0, 0.0, 0.0])
system = mb.ConstrainedSystem(sleigh, [blade])

q0 = sleigh.neutral()
# Forward at 0.5 m/s and spinning at 3 rad/s; the blade point's sideways velocity vy + b ω must vanish.
q0, v0 = system.project(q0, np.array([0.5, -b * 3.0, 3.0]))
trajectory = mb.simulate(system, q0, v0, 20.0, dt=0.02, method="DOP853", rtol=1e-11, atol=1e-13)
print(f"angular velocity: {trajectory.v[0, 2]:.3f} rad/s at the start, {trajectory.v[-1, 2]:.2e} rad/s at the end")
print(f"energy drift {np.ptp(trajectory.energy) / abs(trajectory.energy).max():.2e} (relative), "
      f"max residual {trajectory.residual.max():.2e}")
paths = plot_trajectory(trajectory, out, "sleigh", coordinate_labels=["x", "y", "cos θ", "sin θ"],
                        multiplier_labels=["sideways blade force (N)"])
paths.append(plot_path(trajectory.q[:, :2], out, "sleigh", "path of the sleigh's centre of mass"))
for path in paths:
    print("wrote", path)
