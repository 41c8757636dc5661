"""A bead sliding on a wire, done both ways the lecture note describes.

1. Cartesian coordinates (x, y, z) of the bead, held on the wire r(s) by Lagrange multipliers:
   the multipliers come out as the normal force the wire exerts (N, world axes).
2. The lecture note's single generalized coordinate s along the wire: T = ½ m |r'(s)|² ṡ², U = m g z(s),
   so Lagrange's equation reads m |r'|² s̈ + m (r'·r'') ṡ² + m g z'(s) = 0. No multiplier at all.

The two trajectories agree, and the normal force m r̈ − m g of the second matches the multipliers
of the first. Two wires: a helix, and a curve of your choosing (here a tilted, wavy loop).
Run: python examples/bead_on_wire.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.demos import bead_on_wire_setup, helix, wavy_loop
from multibody.plotting import plot_trajectory

out = sys.argv[1] if len(sys.argv) > 1 else "output"
m, g = 0.2, 9.81  # kg, m/s²


class BeadOnWire:
    """The bead in its one generalized coordinate s: a mechanical system for mb.simulate."""

    nq = nv = 1

    def __init__(self, curve, mass, gravity):
        self.curve, self.mass, self.gravity = curve, mass, gravity

    def _derivatives(self, s, h=1e-3):
        r = self.curve
        d1 = (8 * (r(s + h) - r(s - h)) - (r(s + 2 * h) - r(s - 2 * h))) / (12 * h)
        d2 = (-r(s + 2 * h) + 16 * r(s + h) - 30 * r(s) + 16 * r(s - h) - r(s - 2 * h)) / (12 * h * h)
        return d1, d2

    def mass_matrix(self, q):
        d1, _ = self._derivatives(q[0])
        return np.array([[self.mass * d1 @ d1]])  # M = m |r'|²

    def bias_forces(self, q, v):
        d1, d2 = self._derivatives(q[0])
        return np.array([self.mass * (d1 @ d2) * v[0] ** 2 + self.mass * self.gravity * d1[2]])

    def integrate(self, q, v, dt=1.0):
        return q + v * dt

    def energy(self, q, v):
        d1, _ = self._derivatives(q[0])
        return 0.5 * self.mass * (d1 @ d1) * v[0] ** 2 + self.mass * self.gravity * self.curve(q[0])[2]


for name, curve, s_range in (("helix", helix, (-40.0, 15.0)), ("wavy_loop", wavy_loop, (-3 * np.pi, 3 * np.pi))):
    s0, s_dot0, duration = 1.0, 2.0, 3.0
    minimal = BeadOnWire(curve, m, g)

    # 1. Cartesian coordinates (a translation joint) held on the wire by mb.PointOnCurve, with multipliers:
    #    built in multibody/demos.py (also `multibody demo bead-on-wire`).
    cartesian_setup = bead_on_wire_setup(curve, s_range, mass=m, gravity=g, s0=s0, s_dot0=s_dot0)
    cartesian = mb.simulate(cartesian_setup.system, cartesian_setup.q0, cartesian_setup.v0, duration, dt=0.01,
                            method="DOP853", rtol=1e-11, atol=1e-12)
    # 2. The generalized coordinate s.
    generalized = mb.simulate(minimal, np.array([s0]), np.array([s_dot0]), duration, dt=0.01,
                              method="DOP853", rtol=1e-11, atol=1e-12)

    s, s_dot = generalized.q[:, 0], generalized.v[:, 0]
    s_ddot = np.array([mb.ConstrainedSystem(minimal).forward_dynamics(q, v)[0][0]
                       for q, v in zip(generalized.q, generalized.v)])
    d1, d2 = minimal._derivatives(s)
    normal_force = m * (d2 * s_dot[:, None] ** 2 + d1 * s_ddot[:, None]) - m * np.array([0.0, 0.0, -g])
    print(f"{name}: max |x_cartesian − r(s)| = {np.abs(cartesian.q - curve(s)).max():.2e} m, "
          f"max |λ − normal force| = {np.abs(cartesian.lam - normal_force).max():.2e} N, "
          f"energy drift {np.ptp(cartesian.energy):.2e} J")
    for path in plot_trajectory(cartesian, out, f"bead_{name}", coordinate_labels=["x", "y", "z"],
                                multiplier_labels=["N_x (N)", "N_y (N)", "N_z (N)"]):
        print("wrote", path)
