"""Equations of motion of a URDF robot, M a + C v + g = τ, and the identities that tie them together.

Loads the shipped double pendulum (or any URDF given on the command line), evaluates M, C, g at a
batch of random states, and checks Ṁ = C + Cᵀ by finite differences and ABA(RNEA(a)) = a.
Writes urdf_equations_of_motion.png (the three identities' errors, state by state) to the output folder.
Run: python examples/urdf_equations_of_motion.py [output_folder] [path/to/robot.urdf [--floating-base]]
(an argument ending in .urdf is the robot, any other the output folder)
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

arguments = [argument for argument in sys.argv[1:] if not argument.startswith("--")]
urdfs = [argument for argument in arguments if argument.lower().endswith(".urdf")]
folders = [argument for argument in arguments if not argument.lower().endswith(".urdf")]
out = folders[0] if folders else "output"
if urdfs:
    model = mb.load_urdf(urdfs[0], floating_base="--floating-base" in sys.argv, invalid_inertia="warn")
else:
    model = mb.robots.load("double_pendulum")
print(model)

rng = np.random.default_rng(0)
n = 100
q = model.random_configuration(rng, shape=(n,))   # (n, nq)
v = rng.standard_normal((n, model.nv))            # (n, nv)
a = rng.standard_normal((n, model.nv))

M = mb.mass_matrix(model, q)                      # (n, nv, nv)
C = mb.coriolis_matrix(model, q, v)
g = mb.generalized_gravity(model, q)
tau = mb.inverse_dynamics(model, q, v, a)         # RNEA

equation_error = np.abs(np.einsum("nij,nj->ni", M, a) + np.einsum("nij,nj->ni", C, v) + g - tau).max(axis=-1)
aba_error = np.abs(mb.forward_dynamics(model, q, v, tau) - a).max(axis=-1)
print("max |M a + C v + g − τ|        :", equation_error.max())
print("max |ABA(RNEA(a)) − a|         :", aba_error.max())

eps = 1e-6
M_dot = (mb.mass_matrix(model, model.integrate(q, v, eps)) - mb.mass_matrix(model, model.integrate(q, v, -eps))) / (2 * eps)
skew_error = np.abs(M_dot - C - np.swapaxes(C, -1, -2)).max(axis=(-2, -1))
print("max |Ṁ − (C + Cᵀ)| (fin. diff.):", skew_error.max())

# The figure: each identity's largest error in each of the n states, on a log scale (units of a
# revolute joint; a prismatic coordinate reads N, m/s² and kg/s).
figure = new_figure((10.0, 3.4))
floor = 1e-18  # exact zeros drawn here
panels = [(equation_error, "|M a + C v + g − τ|∞ (N·m)"), (aba_error, "|ABA(RNEA(a)) − a|∞ (rad/s²)"),
          (skew_error, "|Ṁ − (C + Cᵀ)|∞ (kg·m²/s)")]
for axes, (error, label) in zip(figure.subplots(1, 3), panels):
    axes.semilogy(np.maximum(error, floor), ".")
    axes.set_xlabel("random state")
    axes.set_ylabel(label)
axes.set_title(f"finite differences, step {eps:g} s", fontsize=9)
figure.suptitle(f"{model.name}: identities of the equations of motion at {n} random states")
path = save_figure(figure, out, "urdf_equations_of_motion", dpi=100)
print("wrote", path)
