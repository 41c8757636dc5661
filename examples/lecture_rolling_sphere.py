"""The lecture note's rolling sphere in its five coordinates, with its two nonholonomic constraints.

Two coordinates (x, y) for the centre on an inclined plane (x downhill, slope α) and three Euler
angles (yaw ψ, pitch θ, roll φ: R = Rz(ψ) Ry(θ) Rx(φ)) for the orientation. Rolling without
slipping makes the contact point's velocity vanish:

    ẋ − r ω_y = 0,    ẏ + r ω_x = 0,

two Pfaffian constraints A(q) q̇ = 0 on the five coordinates, handled by Lagrange multipliers.
The same ball as a URDF free body with the engine's RollingSphere gives the same motion, and both
roll downhill at 5/7 g sin α.
Writes lecture_rolling_sphere.png (the centre's path, both models) to the output folder.
Run: python examples/lecture_rolling_sphere.py [output_folder]
"""

import sys

import numpy as np
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
x, y, psi, theta, phi = q = dynamicsymbols("x y psi theta phi")
m, r, g, alpha = sp.symbols("m r g alpha", positive=True)
t = dynamicsymbols._t


def rotation(axis, angle):
    c, s = sp.cos(angle), sp.sin(angle)
    return {"x": sp.Matrix([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": sp.Matrix([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": sp.Matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


# World angular velocity of R = Rz(ψ) Ry(θ) Rx(φ): each rate about its own, already rotated, axis.
omega = (psi.diff(t) * sp.Matrix([0, 0, 1]) + theta.diff(t) * rotation("z", psi) * sp.Matrix([0, 1, 0])
         + phi.diff(t) * rotation("z", psi) * rotation("y", theta) * sp.Matrix([1, 0, 0]))
inertia = sp.Rational(2, 5) * m * r**2  # uniform sphere: the same about every axis
T = sp.Rational(1, 2) * m * (x.diff(t) ** 2 + y.diff(t) ** 2) + sp.Rational(1, 2) * inertia * (omega.T * omega)[0, 0]
U = -m * g * sp.sin(alpha) * x  # x runs downhill
ball = mb.LagrangianSystem(q, T, U)

# Rolling: the rows of A(q) q̇ = 0, read off the contact-point velocity.
rates = [coordinate.diff(t) for coordinate in q]
contact = [x.diff(t) - r * omega[1], y.diff(t) + r * omega[0]]
A = [[sp.expand(row).coeff(rate) for rate in rates] for row in contact]
values = {"m": 1.0, "r": 0.1, "g": 9.81, "alpha": 0.3}
rolling = ball.pfaffian(A, r=values["r"], name="rolling")
system = mb.ConstrainedSystem(ball.numeric(**values), [rolling])

q0 = np.array([0.0, 0.0, 0.2, 0.3, 0.1])      # generic orientation, away from θ = ±π/2
v0 = np.array([0.0, 0.5, 0.0, 0.0, 0.0])       # rolling across the slope; projection adds the spin
q0, v0 = system.project(q0, v0)
duration = 2.0
five = mb.simulate(system, q0, v0, duration, dt=0.02, method="DOP853", rtol=1e-12, atol=1e-14)
downhill = 0.5 * (5 / 7) * values["g"] * np.sin(values["alpha"]) * five.t**2
print(f"five coordinates: x(t) − (5/7) g sin α t²/2 stays within {np.abs(five.q[:, 0] - downhill).max():.1e} m; "
      f"residual {five.residual.max():.1e}")

# The same ball as a free body (URDF) with the engine's rolling constraint on the tilted plane.
free = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
tilt = values["alpha"]
normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
downhill_axis, across_axis = np.array([np.cos(tilt), 0.0, -np.sin(tilt)]), np.array([0.0, 1.0, 0.0])
plane = np.column_stack([downhill_axis, across_axis, normal])  # plane coordinates -> world
R_plane = np.array(sp.lambdify(q[2:], rotation("z", psi) * rotation("y", theta) * rotation("x", phi))(*q0[2:]),
                   dtype=float)
R0 = plane @ R_plane
omega0 = np.array(sp.lambdify([q, rates], omega, "numpy")(q0, v0), dtype=float).reshape(3)
q_free = np.concatenate([plane @ [q0[0], q0[1], values["r"]], mb.spatial.rotation_to_quat(R0)])
v_free = np.concatenate([R0.T @ plane @ [v0[0], v0[1], 0.0], R0.T @ plane @ omega0])
engine = mb.ConstrainedSystem(free, [mb.RollingSphere("ball", values["r"], plane_normal=normal)])
body = mb.simulate(engine, q_free, v_free, duration, dt=0.02, method="DOP853", rtol=1e-12, atol=1e-14)
centre_in_plane = (body.q[:, :3] @ plane)[:, :2]
print(f"free body + RollingSphere: centre differs from the five-coordinate model by "
      f"{np.abs(centre_in_plane - five.q[:, :2]).max():.1e} m")

figure = new_figure((6.0, 4.0))
axes = figure.subplots()
axes.plot(five.q[:, 1], five.q[:, 0], label="five coordinates (LagrangianSystem.pfaffian)")
axes.plot(centre_in_plane[:, 1], centre_in_plane[:, 0], "--", label="free body + mb.RollingSphere")
axes.invert_yaxis()
axes.set_xlabel("y, across the slope (m)")
axes.set_ylabel("x, down the slope (m)")
axes.set_title(f"centre of the rolling ball, {duration:g} s on a slope of {values['alpha']} rad")
axes.legend(fontsize=8)
path = save_figure(figure, out, "lecture_rolling_sphere", dpi=100)
print("wrote", path)
