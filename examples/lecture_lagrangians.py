"""The lecture note's examples, written the textbook way: coordinates, T and U, then Lagrange's equations.

1. A particle under gravity: x and y are cyclic, so ẋ and ẏ stay constant; z̈ = −g.
2. The simple pendulum: θ̈ + (g/l) sin θ = 0, and linearised about θ = 0, ω² = g/l.
3. A particle under an inverse-square force in polar coordinates: θ is cyclic, so m r² θ̇ is
   conserved; the radial equation is m r̈ − m r θ̇² = −k/r²; a Kepler orbit closes after
   2π √(a³ m / k).
4. The bead on a helical wire in its one coordinate s.
Writes lecture_kepler.png (the orbit, and m r² θ̇ along it) to the output folder.
Run: python examples/lecture_lagrangians.py [output_folder]
"""

import sys

import numpy as np
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
m, g, l, k = sp.symbols("m g l k", positive=True)

print("1. particle under gravity")
x, y, z = dynamicsymbols("x y z")
particle = mb.LagrangianSystem([x, y, z], sp.Rational(1, 2) * m * (x.diff() ** 2 + y.diff() ** 2 + z.diff() ** 2), m * g * z)
for equation in particle.equations():
    print("  ", equation)
print("   cyclic:", particle.cyclic_coordinates(), " conserved:", particle.conserved_momenta())

print("2. simple pendulum")
theta = dynamicsymbols("theta")
pendulum = mb.LagrangianSystem([theta], sp.Rational(1, 2) * m * l**2 * theta.diff() ** 2, m * g * l * (1 - sp.cos(theta)))
print("  ", pendulum.equations()[0])
print("   small oscillations: ω² =", pendulum.linearize({theta: 0})[2][0])
print("   H =", pendulum.hamiltonian())

print("3. inverse-square force in polar coordinates")
r, phi = dynamicsymbols("r phi")
kepler = mb.LagrangianSystem([r, phi], sp.Rational(1, 2) * m * (r.diff() ** 2 + r**2 * phi.diff() ** 2), -k / r)
for equation in kepler.equations():
    print("  ", equation)
print("   cyclic:", kepler.cyclic_coordinates(), " conserved:", kepler.conserved_momenta())
values = {"m": 1.0, "k": 1.0}
r0, speed = 1.0, 1.2                                    # start at perihelion, tangential speed
energy = 0.5 * speed**2 - values["k"] / r0              # per unit mass
a = -values["k"] / (2 * energy)                         # semi-major axis
period = 2 * np.pi * np.sqrt(a**3 * values["m"] / values["k"])
orbit = mb.simulate(kepler.numeric(**values), np.array([r0, 0.0]), np.array([0.0, speed / r0]), period,
                    dt=period / 400, method="DOP853", rtol=1e-12, atol=1e-14)
angular_momentum = orbit.q[:, 0] ** 2 * orbit.v[:, 1]
print(f"   after one period 2π√(a³m/k) = {period:.6f} s: r back to {orbit.q[-1, 0]:.10f} (started {r0}), "
      f"θ advanced by {orbit.q[-1, 1] / (2 * np.pi):.10f} turns")
print(f"   m r² θ̇ constant to {np.ptp(angular_momentum):.1e}")

print("4. bead on a helix (radius R, rise c per radian) in its coordinate s")
s = dynamicsymbols("s")
R, c = sp.symbols("R c", positive=True)
bead = mb.LagrangianSystem([s], sp.Rational(1, 2) * m * (R**2 + c**2) * s.diff() ** 2, m * g * c * s)
print("  ", bead.equations()[0], "  →  s̈ =", sp.solve(bead.equations()[0], s.diff(dynamicsymbols._t, 2))[0])

# The figure: the Kepler orbit of part 3 in the plane, and its angular momentum (m = k = 1, SI units).
figure = new_figure((9.0, 4.0))
left, right = figure.subplots(1, 2)
left.plot(orbit.q[:, 0] * np.cos(orbit.q[:, 1]), orbit.q[:, 0] * np.sin(orbit.q[:, 1]))
left.plot([0.0], [0.0], "k*", label="centre of force")
left.plot([r0], [0.0], "o", label="start (perihelion)")
left.set_aspect("equal")
left.set_xlabel("x = r cos θ (m)")
left.set_ylabel("y = r sin θ (m)")
left.set_title("one period of the orbit")
left.legend(fontsize=8)
right.plot(orbit.t, angular_momentum - angular_momentum[0])
right.set_xlabel("t (s)")
right.set_ylabel("m r² θ̇ − its initial value (kg·m²/s)")
right.set_title("θ is cyclic: its momentum is conserved")
path = save_figure(figure, out, "lecture_kepler", dpi=100)
print("wrote", path)
