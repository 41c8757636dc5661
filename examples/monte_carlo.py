"""Monte Carlo: 10 000 balls rolling down a tilted plane, simulated as one batch.

Each ball (1 kg, r = 0.1 m, solid: I = 2/5 m r²) starts at the same point of a plane tilted by α and
rolls without slipping (``mb.RollingSphere``; the balls do not touch each other). Its centre is launched
with a random velocity, u along the slope (downhill positive) and w across it, both normal with a
standard deviation of 0.2 m/s, and the ball spins at random about the plane's normal. Rolling, the
centre accelerates down the slope at

    a = 5/7 g sin α        (a sliding block: g sin α)

whatever the spin, so at t_final it has moved s = u t + ½ a t² along the slope: for normal u, the
displacements are normal with mean ½ a t² and standard deviation 0.2 m/s · t. All balls are integrated
together by RK4 (``mb.simulate`` with q0 (N, 7), v0 (N, 6)), each stage of all of them in one compiled
call on all cores. The figure shows the histogram of the simulated displacements against that
density, and each ball's difference from its own closed form.

Run: python examples/monte_carlo.py [output_folder]
"""

import sys
import time

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
N, alpha, radius, g = 10_000, 0.2, 0.1, 9.81  # balls, tilt (rad), radius (m), gravity (m/s²)
t_final, dt = 1.0, 0.01                         # s: 100 RK4 steps
spread = 0.2                                    # m/s, of each launch velocity component

ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
normal = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
downhill = np.array([np.cos(alpha), 0.0, -np.sin(alpha)])  # along the slope, where gravity pulls
across = np.array([0.0, 1.0, 0.0])
system = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", radius, plane_normal=normal)])

# Every ball at the same place, upright (body frame = world frame, so v is in world axes too); the centre's
# velocity in the plane and ω = n × ẋ / r + spin n, which rolls without slipping.
rng = np.random.default_rng(2024)
q0 = ball.neutral()
q0[:3] = radius * normal
u, w, spin = rng.normal(0.0, spread, N), rng.normal(0.0, spread, N), rng.normal(0.0, 5.0, N)
centre_velocity = u[:, None] * downhill + w[:, None] * across
omega = np.cross(normal, centre_velocity) / radius + spin[:, None] * normal
v0 = np.concatenate([centre_velocity, omega], axis=1)

print(f"{N} balls, RK4 with dt = {dt} s up to t_final = {t_final} s ({round(t_final / dt)} steps), "
      f"{mb.get_num_threads()} threads")
start = time.perf_counter()
trajectory = mb.simulate(system, q0, v0, t_final, dt=dt, method="RK4")
wall = time.perf_counter() - start
print(f"wall time {wall:.1f} s: {wall / (N * round(t_final / dt)) * 1e6:.2f} µs per ball and step; "
      f"{int(trajectory.completed.sum())} of {N} completed; largest constraint residual "
      f"{np.nanmax(trajectory.residual):.1e}")

# displacement along the slope at t_final, simulated and closed form
acceleration = 5.0 / 7.0 * g * np.sin(alpha)
s = (trajectory.q[:, -1, :3] - q0[:3]) @ downhill
s_closed = u * t_final + 0.5 * acceleration * t_final**2
error = np.abs(s - s_closed)
mean, deviation = 0.5 * acceleration * t_final**2, spread * t_final
print(f"mean displacement {s.mean():.4f} m, standard deviation {s.std():.4f} m (the density: ½ (5/7) g sin α t² = "
      f"{mean:.4f} m and {deviation:.4f} m; a sliding block's mean {0.5 * g * np.sin(alpha) * t_final**2:.4f} m)")
print(f"largest difference of a ball from its own closed form u t + ½ a t²: {error.max():.1e} m")

figure = new_figure((10.0, 4.0))
left, right = figure.subplots(1, 2)
left.hist(s, bins=80, density=True, alpha=0.6, label=f"{N} simulated balls")
x = np.linspace(s.min(), s.max(), 400)
left.plot(x, np.exp(-0.5 * ((x - mean) / deviation) ** 2) / (deviation * np.sqrt(2 * np.pi)), "k",
          label=f"closed form: normal, σ = {spread} m/s · t")
left.axvline(mean, color="k", linestyle=":", label="rolling: ½ (5/7) g sin α t²")
left.axvline(0.5 * g * np.sin(alpha) * t_final**2, color="tab:red", linestyle="--", label="sliding: ½ g sin α t²")
left.set_xlabel(f"displacement down the slope at t = {t_final:g} s (m)")
left.set_ylabel("probability density (1/m)")
left.set_title(f"rolling down a plane tilted by {alpha} rad")
left.legend(fontsize=8, loc="upper left")
floor = 1e-18  # m: where exact zeros are drawn on the log axis
right.hist(np.maximum(error, floor), bins=np.geomspace(floor, max(error.max(), 10 * floor), 40))
right.set_xscale("log")
right.set_xlabel(f"|simulated − closed form| (m; zeros drawn at {floor:.0e} m)")
right.set_ylabel("balls (count)")
right.set_title("each ball against its closed form")
path = save_figure(figure, out, "monte_carlo", dpi=110)
print("wrote", path)
