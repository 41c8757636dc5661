"""A Panda reaching a pose: inverse kinematics for the goal, then a computed-torque controller that tracks
a minimum-jerk joint trajectory from the start to it.

1. Inverse kinematics (``mb.inverse_kinematics``) finds the configuration ``q_goal`` that puts the hand
   frame ``panda_hand_tcp`` at a target pose, starting from (and held near, in the null space) the start
   configuration, within the joint limits.
2. The reference is the minimum-jerk path in joint space (T. Flash and N. Hogan, "The coordination of
   arm movements", J. Neurosci. 5 (1985) 1688–1703): ``q_ref(t) = q_start + (q_goal − q_start) s(t/T)``
   with ``s(τ) = 10 τ³ − 15 τ⁴ + 6 τ⁵``, which starts and ends at rest with zero acceleration.
3. The computed-torque controller (B. Siciliano, L. Sciavicco, L. Villani and G. Oriolo, *Robotics:
   Modelling, Planning and Control*, Springer 2009, §8.5.2) cancels the dynamics and imposes
   ``ë + K_d ė + K_p e = 0`` on the tracking error ``e = q_ref − q``::

       τ = M(q) (q̈_ref + K_p e + K_d ė) + h(q, v)        (mb.mass_matrix, mb.bias_forces)

4. ``mb.simulate`` integrates the arm by fixed-step RK4 at 1 kHz with that ``τ(t, q, v)``. The simulated
   arm also has the URDF's viscous joint damping (``joint_damping=True``), which the controller does not
   model: its feedback keeps the tracking error small all the same.

Writes three figures to the output folder: the hand's position and orientation errors, the joint
angles on their reference with the tracking error, and the centre of mass (``mb.center_of_mass``), all
against time.
Run: python examples/panda_reach.py [output_folder]
"""

import sys
import time

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
start_wall = time.perf_counter()
model = mb.robots.load("panda")  # example-robot-data's Panda: 7 arm joints and 2 finger joints
hand = "panda_hand_tcp"
arm = slice(0, 7)

# ----------------------------------------------------------------------------- the goal, by inverse kinematics

q_start = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4, 0.02, 0.02])
X_start = mb.frame_placement(model, q_start, hand)
# target: the hand 15 cm forward, 20 cm to the side and 20 cm lower, turned 60° about the vertical
turn = mb.spatial.axis_angle_rotation(np.array([0.0, 0.0, 1.0]), np.pi / 3)
X_goal = np.eye(4)
X_goal[:3, :3] = turn @ X_start[:3, :3]
X_goal[:3, 3] = X_start[:3, 3] + np.array([0.15, 0.20, -0.20])

ik = mb.inverse_kinematics(model, {hand: X_goal}, q0=q_start, posture=q_start)
if not ik.converged:
    sys.exit(f"inverse kinematics did not converge: error {ik.error:.2e}")
q_goal = ik.q
print(f"inverse kinematics: |e| = {ik.error:.1e} (m and rad) after {ik.iterations} steps")
print("q_goal (rad, m) =", np.round(q_goal, 4))

# ----------------------------------------------------------------------------- reference and controller

T_move, t_final, dt = 2.0, 3.0, 1e-3
K_p, K_d = 400.0, 40.0  # ë + 40 ė + 400 e = 0: critically damped, natural frequency 20 rad/s


def minimum_jerk(t):
    """``(q_ref, v_ref, a_ref)`` at time ``t`` (s): rad, rad/s, rad/s² (m, m/s, m/s² for the fingers)."""
    tau = min(max(t / T_move, 0.0), 1.0)
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T_move if t < T_move else 0.0
    dds = (60 * tau - 180 * tau**2 + 120 * tau**3) / T_move**2 if t < T_move else 0.0
    step = q_goal - q_start
    return q_start + s * step, ds * step, dds * step


def computed_torque(t, q, v):
    """``τ = M(q) (q̈_ref + K_p e + K_d ė) + h(q, v)`` (N·m, N)."""
    q_ref, v_ref, a_ref = minimum_jerk(t)
    a_command = a_ref + K_p * (q_ref - q) + K_d * (v_ref - v)
    return mb.mass_matrix(model, q) @ a_command + mb.bias_forces(model, q, v)


# ----------------------------------------------------------------------------- simulation

start_sim = time.perf_counter()
trajectory = mb.simulate(model, q_start, np.zeros(model.nv), t_final, dt=dt, method="RK4", tau=computed_torque,
                         joint_damping=True)
sim_wall = time.perf_counter() - start_sim
t = trajectory.t

X_hand = mb.frame_placement(model, trajectory.q, hand)
position_error = np.linalg.norm(X_hand[:, :3, 3] - X_goal[:3, 3], axis=-1)
orientation_error = np.linalg.norm(mb.spatial.so3_log(X_goal[:3, :3].T @ X_hand[:, :3, :3]), axis=-1)
reference = np.array([minimum_jerk(ti)[0] for ti in t])
com = mb.center_of_mass(model, trajectory.q)

print(f"final end-effector error: position {position_error[-1]:.2e} m, orientation {orientation_error[-1]:.2e} rad")
print(f"largest joint tracking error {np.abs(trajectory.q - reference)[:, arm].max():.1e} rad")
print(f"wall time: simulation of {t_final:g} s at 1 kHz {sim_wall:.2f} s, whole script "
      f"{time.perf_counter() - start_wall:.2f} s")

# ----------------------------------------------------------------------------- figures

paths = []

figure = new_figure()
ax_position, ax_orientation = figure.subplots(2, 1, sharex=True)
ax_position.semilogy(t, position_error, color="C0")
ax_position.set_ylabel("distance to goal (m)")
ax_orientation.semilogy(t, orientation_error, color="C1")
ax_orientation.set_ylabel("angle to goal (rad)")
ax_orientation.set_xlabel("time (s)")
for ax in (ax_position, ax_orientation):
    ax.axvline(T_move, color="0.6", linestyle=":", linewidth=1.0)
    ax.grid(True, which="both", alpha=0.3)
ax_position.set_title("Panda reach: hand pose error to the goal (dotted: end of the reference motion)")
paths.append(save_figure(figure, out, "panda_reach_error"))

# The arm tracks its reference to within a milliradian, so a reference drawn in the curves' own style
# would hide under them: it is a wide pale band beneath each curve, and the lower panel shows the gap.
figure = new_figure(figsize=(7.0, 6.0))
ax, ax_error = figure.subplots(2, 1, sharex=True, height_ratios=(2, 1))
for k in range(7):
    ax.plot(t, reference[:, k], color=f"C{k}", linewidth=6.0, alpha=0.3, solid_capstyle="butt")
    ax.plot(t, trajectory.q[:, k], color=f"C{k}", linewidth=1.2, label=model.joint_names[k])
    ax_error.plot(t, 1e3 * (trajectory.q[:, k] - reference[:, k]), color=f"C{k}", linewidth=1.0)
ax.set_ylabel("joint angle (rad)")
ax.set_title("Arm joints (lines) on their minimum-jerk reference (pale bands; dotted: its end)")
ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.0, 1.0))
ax_error.set_ylabel("q − q_ref (mrad)")
ax_error.set_xlabel("time (s)")
for axis in (ax, ax_error):
    axis.axvline(T_move, color="0.6", linestyle=":", linewidth=1.0)
    axis.grid(True, alpha=0.3)
paths.append(save_figure(figure, out, "panda_reach_joints"))

figure = new_figure()
ax = figure.subplots()
for k, axis in enumerate("xyz"):
    ax.plot(t, com[:, k], label=f"{axis}")
ax.set_xlabel("time (s)")
ax.set_ylabel("centre of mass, world (m)")
ax.set_title("Centre of mass of the moving links")
ax.legend()
ax.grid(True, alpha=0.3)
paths.append(save_figure(figure, out, "panda_reach_com"))

for path in paths:
    print("wrote", path)
