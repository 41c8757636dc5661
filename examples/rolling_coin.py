"""A coin rolling on a table: a thin disc, rolling without slipping, leaning into a circle.

The coin is a free body (a free-flyer joint) with a rolling-disc constraint. Started upright
enough and rolling fast, it leans and runs around a circle while the contact force keeps it on its
path; energy stays constant because rolling forces do no work.
Run: python examples/rolling_coin.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.demos import rolling_coin_setup
from multibody.plotting import plot_path, plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
# The coin is built in multibody/demos.py (also `multibody demo rolling-coin`): 10 g, radius 2 cm, a
# free body whose axis is its body z axis (I = m r²/2 about it, m r²/4 about any diameter), with a
# RollingDisc on z = 0; it starts leaned 0.15 rad from the vertical, spinning at 40 rad/s about its
# axis, and the projection adds the matching forward speed.
setup = rolling_coin_setup(mass=0.01, radius=0.02, lean=0.15, spin=40.0)
coin, system, q0, v0 = setup.model, setup.system, setup.q0, setup.v0
(contact,) = setup.constraints

trajectory = mb.simulate(system, q0, v0, 2.0, dt=0.002, method="DOP853", rtol=1e-11, atol=1e-13)
print(f"energy drift {np.ptp(trajectory.energy) / abs(trajectory.energy).max():.2e} (relative), "
      f"max residual {trajectory.residual.max():.2e}")
paths = plot_trajectory(trajectory, out, "coin", multiplier_labels=["friction t₁ (N)", "friction t₂ (N)", "normal (N)"])
contact_points = np.array([contact.contact_point(coin, q) for q in trajectory.q])
paths.append(plot_path(contact_points[:, :2], out, "coin", "contact path of the rolling coin"))
for path in paths:
    print("wrote", path)
