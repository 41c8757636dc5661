"""The lecture note's simple pendulum, built in Python, against its Lagrangian.

The lecture note writes T = ½ m l² θ̇² and U = m g l (1 − cos θ), so Lagrange's equation gives
M = m l² and g(θ) = ∂U/∂θ = m g l sin θ. Here the same numbers come out of the recursive engine.
Writes lecture_pendulum.png (M and g against θ, engine and closed form) to the output folder.
Run: python examples/lecture_pendulum.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
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

# The figure: the engine's g(θ) and M(θ) (dots) on the closed forms (lines), over a finer batch.
fine = np.linspace(-np.pi, np.pi, 41)[:, None]
figure = new_figure((9.0, 3.6))
left, right = figure.subplots(1, 2)
left.plot(fine[:, 0], m * g * l * np.sin(fine[:, 0]), "k", label="m g l sin θ")
left.plot(fine[:, 0], mb.generalized_gravity(pendulum, fine)[:, 0], "o", markersize=4, label="mb.generalized_gravity")
left.set_xlabel("θ (rad)")
left.set_ylabel("g(θ) (N·m)")
left.legend(fontsize=8)
right.plot(fine[:, 0], np.full(len(fine), m * l**2), "k", label="m l²")
right.plot(fine[:, 0], mb.mass_matrix(pendulum, fine)[:, 0, 0], "o", markersize=4, label="mb.mass_matrix")
right.set_xlabel("θ (rad)")
right.set_ylabel("M(θ) (kg·m²)")
right.legend(fontsize=8)
figure.suptitle(f"simple pendulum, m = {m} kg, l = {l} m")
path = save_figure(figure, out, "lecture_pendulum", dpi=100)
print("wrote", path)
