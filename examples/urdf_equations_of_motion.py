"""Equations of motion of a URDF robot, M a + C v + g = τ, and the identities that tie them together.

Loads the shipped double pendulum (or any URDF given on the command line), evaluates M, C, g at a
batch of random states, and checks Ṁ = C + Cᵀ by finite differences and ABA(RNEA(a)) = a.
Run: python examples/urdf_equations_of_motion.py [path/to/robot.urdf [--floating-base]]
"""

import sys

import numpy as np

import multibody as mb

if len(sys.argv) > 1:
    model = mb.load_urdf(sys.argv[1], floating_base="--floating-base" in sys.argv, invalid_inertia="warn")
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

print("max |M a + C v + g − τ|        :", np.abs(np.einsum("nij,nj->ni", M, a) + np.einsum("nij,nj->ni", C, v) + g - tau).max())
print("max |ABA(RNEA(a)) − a|         :", np.abs(mb.forward_dynamics(model, q, v, tau) - a).max())

eps = 1e-6
M_dot = (mb.mass_matrix(model, model.integrate(q, v, eps)) - mb.mass_matrix(model, model.integrate(q, v, -eps))) / (2 * eps)
print("max |Ṁ − (C + Cᵀ)| (fin. diff.):", np.abs(M_dot - C - np.swapaxes(C, -1, -2)).max())
