"""A four-bar linkage: a URDF kinematic tree closed by a loop-closure constraint.

The URDF describes the open tree ground–crank–coupler and ground–rocker; the constraint makes the
coupler's tip and the rocker's tip coincide in the mechanism's plane (x–z). The linkage falls under
gravity from a consistent configuration. The constraint's two rows are the tips' offset along the
coupler's x and z axes (its frame A is fixed in the coupler and turns with it), so their multipliers
are the pin force on the rocker's tip along those two axes, in newtons; the coupler's tip carries the
opposite force.
Run: python examples/four_bar.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.demos import four_bar_setup
from multibody.plotting import plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
# The linkage is built in multibody/demos.py (also `multibody demo four-bar`): the URDF tree, a planar
# LoopClosure whose frame A is turned by +90° about x so that its x–y plane is the mechanism's x–z
# plane, and a start projected onto the loop from a guess (crank at 60°, the others roughly placed).
setup = four_bar_setup()
model, system, q0, v0 = setup.model, setup.system, setup.q0, setup.v0
print("consistent start q0 =", np.round(q0, 6), " |φ| =", np.abs(system.position_error(q0)).max())

trajectory = mb.simulate(system, q0, v0, 4.0, dt=0.01, method="DOP853", rtol=1e-10, atol=1e-12)
print(f"energy drift {np.ptp(trajectory.energy):.2e} J, max residual {trajectory.residual.max():.2e}")
# the system names each curve after its joint with its unit (rad, rad/s) and gives the rows' unit (N)
for path in plot_trajectory(trajectory, out, "four_bar", system,
                            multiplier_labels=["pin force on the rocker along the coupler's x",
                                               "pin force on the rocker along the coupler's z"]):
    print("wrote", path)
