"""Holonomy of the rolling ball: roll it once around a closed loop, and it comes back turned.

The lecture note's point about nonholonomic systems: returning the coordinates of the centre to where
they started does not return the orientation. Here the centre of a ball of radius r is driven
once around a circle of radius R, rolling without slipping and without spinning about the
vertical (ω = n × ẋ / r, the rolling constraint solved for ω). After the loop the ball is turned by

    θ = 2π √(1 + (R/r)²)   (mod 2π)

about a tilted axis. We integrate the orientation on SO(3) with the model's own exponential map.
Writes rolling_ball_holonomy.png (the rotation angle along the loop) to the output folder.
Run: python examples/rolling_ball_holonomy.py [output_folder]
"""

import sys

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
r, R, steps = 0.1, 0.25, 20000          # ball radius, loop radius (m), integration steps
ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
normal = np.array([0.0, 0.0, 1.0])
speed = 1.0                                # m/s along the loop
period = 2 * np.pi * R / speed


def body_velocity(q, t):
    """Free-flyer velocity (body frame) of the ball when its centre follows the circle at time t."""
    phi = speed * t / R
    centre_velocity = speed * np.array([-np.sin(phi), np.cos(phi), 0.0])
    omega = np.cross(normal, centre_velocity) / r          # rolling, no spin about n
    R_WB = mb.spatial.quat_to_rotation(q[3:])
    return np.concatenate([R_WB.T @ centre_velocity, R_WB.T @ omega])


q = ball.neutral()
q[:3] = [R, 0.0, r]
dt = period / steps
times, angles = [0.0], [0.0]               # the ball's rotation angle from its start, along the loop
for k in range(steps):  # midpoint rule on the configuration manifold
    t = k * dt
    q_half = ball.integrate(q, body_velocity(q, t), dt / 2)
    q = ball.integrate(q, body_velocity(q_half, t + dt / 2), dt)
    if (k + 1) % 100 == 0:
        times.append(t + dt)
        angles.append(np.linalg.norm(mb.spatial.so3_log(mb.spatial.quat_to_rotation(q[3:]))))

rotation = mb.spatial.quat_to_rotation(q[3:])
turned = np.linalg.norm(mb.spatial.so3_log(rotation))
expected = 2 * np.pi * np.sqrt(1 + (R / r) ** 2) % (2 * np.pi)
expected = min(expected, 2 * np.pi - expected)  # the rotation angle in [0, π]
rolling = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", r)])
print(f"centre back at the start: |Δx| = {np.linalg.norm(q[:3] - [R, 0.0, r]):.2e} m")
print(f"orientation turned by {turned:.9f} rad; the closed form gives {expected:.9f} rad")
print(f"rolling constraint residual along the way (end state): {rolling.residual(q, body_velocity(q, period)):.2e}")

figure = new_figure((6.0, 3.6))
axes = figure.subplots()
axes.plot(times, angles, label="rotation angle from the start (in [0, π])")
axes.axhline(expected, color="k", linestyle="--", label="closed form after one loop")
axes.set_xlabel("t (s)")
axes.set_ylabel("angle (rad)")
axes.set_title(f"ball r = {r} m rolled once around a circle R = {R} m")
axes.legend(fontsize=8)
path = save_figure(figure, out, "rolling_ball_holonomy", dpi=100)
print("wrote", path)
