"""The lecture note's simple pendulum, built in Python, against its Lagrangian.

The lecture note writes T = ½ m l² θ̇² and U = m g l (1 − cos θ), so Lagrange's equation gives
M = m l² and g(θ) = ∂U/∂θ = m g l sin θ. Here the same numbers come out of the recursive engine.
Run: python examples/lecture_pendulum.py
"""

import numpy as np

import multibody as mb

m, l, g = 2.0, 0.75, 9.81  # kg, m, m/s²

builder = mb.ModelBuilder("pendulum", gravity=(0.0, 0.0, -g))
# A point mass hanging at −l along z, swinging about the y axis.
builder.add_body("bob", joint=mb.joints.Revolute([0.0, 1.0, 0.0]), inertia=mb.inertia.point_mass(m, [0.0, 0.0, -l]))
pendulum = builder.build()

theta = np.linspace(-np.pi, np.pi, 9)[:, None]  # a batch of 9 angles, shape (9, 1)
theta_dot = np.full_like(theta, 0.5)             # rad/s

M = mb.mass_matrix(pendulum, theta)[:, 0, 0]
gravity = mb.generalized_gravity(pendulum, theta)[:, 0]
kinetic = mb.kinetic_energy(pendulum, theta, theta_dot)
potential = mb.potential_energy(pendulum, theta)  # zero at the pivot height

print(" θ (rad)    M − m l²     g − m g l sin θ   T − ½ m l² θ̇²   U − (−m g l cos θ)")
for row in zip(theta[:, 0], M - m * l**2, gravity - m * g * l * np.sin(theta[:, 0]),
               kinetic - 0.5 * m * l**2 * theta_dot[:, 0] ** 2, potential + m * g * l * np.cos(theta[:, 0])):
    print("  ".join(f"{x: .3e}" for x in row))
