"""A coin rolling on a table: a thin disc, rolling without slipping, leaning into a circle.

The coin is a free body (a free-flyer joint) with a rolling-disc constraint. Started upright
enough and rolling fast, it leans and runs around a circle while the contact force keeps it on its
path; energy stays constant because rolling forces do no work.
Run: python examples/rolling_coin.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import plot_path, plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
m, r = 0.01, 0.02  # kg, m: a large coin
builder = mb.ModelBuilder("coin")
# The coin's axis is its body z axis: I = m r²/2 about it, m r²/4 about any diameter.
builder.add_body("coin", joint=mb.joints.FreeFlyer(), joint_name="root_joint",
                 inertia=mb.Inertia(m, [0, 0, 0], np.diag([m * r**2 / 4, m * r**2 / 4, m * r**2 / 2])))
coin = builder.build()
contact = mb.RollingDisc("coin", r, axis=(0.0, 0.0, 1.0))
system = mb.ConstrainedSystem(coin, [contact])

lean = 0.15  # rad from the vertical
# Axis along the world y axis, leaned by `lean` about the rolling direction x.
R0 = mb.spatial.axis_angle_rotation([1.0, 0.0, 0.0], np.pi / 2 + lean)
q0 = np.concatenate([[0.0, 0.0, r * np.cos(lean)], mb.spatial.rotation_to_quat(R0)])
spin = 40.0  # rad/s about the coin's axis; the projection adds the matching forward speed
q0, v0 = system.project(q0, np.array([0.0, 0.0, 0.0, 0.0, 0.0, spin]))

trajectory = mb.simulate(system, q0, v0, 2.0, dt=0.002, method="DOP853", rtol=1e-11, atol=1e-13)
print(f"energy drift {np.ptp(trajectory.energy) / abs(trajectory.energy).max():.2e} (relative), "
      f"max residual {trajectory.residual.max():.2e}")
paths = plot_trajectory(trajectory, out, "coin", multiplier_labels=["friction t₁ (N)", "friction t₂ (N)", "normal (N)"])
contact_points = np.array([contact.contact_point(coin, q) for q in trajectory.q])
paths.append(plot_path(contact_points[:, :2], out, "coin", "contact path of the rolling coin"))
for path in paths:
    print("wrote", path)
