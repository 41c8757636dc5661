"""A chain of parallelograms swinging through its flat configurations, where the loop closures lose rank.

Six cranks pivot on the ground 1 m apart; a bar joins the tips of each neighbouring pair, so the chain
is six parallelograms closed by planar loop closures (twelve rows, thirteen joints, one degree of
freedom). Where every bar lies on the ground line (crank angle φ = 0 or π) the rows along the bars
vanish: the linkage could go on as parallelograms or fold. The chain starts at rest 0.5 rad above the
horizontal and swings under gravity through the flat configurations again and again.

Its motion has a closed one-degree-of-freedom form: with every crank at φ and every bar level,
Lagrange's equation of the lecture note is ``J φ̈ = −C g cos φ``, where ``J`` is the moment of inertia of
the whole chain about the cranks' pivots and ``C g cos φ`` the moment of gravity. The figure compares
the simulated crank angle with that reduction, and the forces the closures carry (their multipliers).
Across the bars they carry the bars' weight and inertia. Along the bars they peak at each passage: a force along
a bar turns a crank with the lever ``L sin φ``, so near flat the torques the cranks need take forces of
order ``1/sin φ`` (the toggle effect). With redundant closures these are the minimum-norm forces, finite
on every output sample.
Run: python examples/parallelogram_chain.py [output_folder]
"""

import sys

import numpy as np
from scipy.integrate import solve_ivp

import multibody as mb
from multibody.plotting import new_figure, save_figure

out = sys.argv[1] if len(sys.argv) > 1 else "output"
CELLS, LENGTH, MASS, THICKNESS, G = 6, 1.0, 1.0, 0.05, 9.81
Y = [0.0, 1.0, 0.0]  # every joint turns about y: the mechanism moves in the x–z plane

# Cranks V0 … V6 on the ground, bars H1 … H6 hinged on the tips of V0 … V5.
bar = mb.inertia.box(MASS, [LENGTH, THICKNESS, THICKNESS], center=[LENGTH / 2, 0.0, 0.0])
builder = mb.ModelBuilder("parallelogram chain")
for k in range(CELLS + 1):
    builder.add_body(f"V{k}", mb.joints.Revolute(Y), placement=mb.spatial.pose_from_xyz_rpy([k * LENGTH, 0, 0]),
                     inertia=bar)
for k in range(1, CELLS + 1):
    builder.add_body(f"H{k}", mb.joints.Revolute(Y), parent=f"V{k - 1}",
                     placement=mb.spatial.pose_from_xyz_rpy([LENGTH, 0, 0]), inertia=bar)
model = builder.build()

# Each bar's tip closes on the next crank's tip; frame A (at the bar's tip) is turned by +90° about x so
# that its x–y plane is the mechanism's plane. Rows: the gap along A's x (the bar) and y.
tip = mb.spatial.pose_from_xyz_rpy([LENGTH, 0, 0])
in_plane = mb.spatial.pose_from_xyz_rpy([LENGTH, 0, 0], [np.pi / 2, 0, 0])
system = mb.ConstrainedSystem(model, [mb.LoopClosure(f"H{k}", f"V{k}", frame_a=in_plane, frame_b=tip, kind="planar")
                                      for k in range(1, CELLS + 1)])

# Crank angle φ above the horizontal: a crank joint turns by −φ, a bar back by +φ (staying level).
start = 0.5
q0 = np.concatenate([np.full(CELLS + 1, -start), np.full(CELLS, start)])
trajectory = mb.simulate(system, q0, np.zeros(model.nv), 10.0, dt=0.005, method="DOP853", rtol=1e-10,
                         atol=1e-12)
phi = -trajectory.q[:, 0]

# J φ̈ = −C g cos φ: each crank turns about its end (a box of length L, thickness w), each bar translates
# on a circle of radius L; crank centres at height (L/2) sin φ, bars at L sin φ.
J = (CELLS + 1) * (MASS * (LENGTH**2 + THICKNESS**2) / 12 + MASS * (LENGTH / 2) ** 2) + CELLS * MASS * LENGTH**2
C = MASS * LENGTH * ((CELLS + 1) / 2 + CELLS)
reduction = solve_ivp(lambda t, y: [y[1], -C * G * np.cos(y[0]) / J], (0.0, 10.0), [start, 0.0], method="DOP853",
                      rtol=1e-12, atol=1e-12, t_eval=trajectory.t)
error = np.abs(phi - reduction.y[0])
passages = np.count_nonzero(np.diff(np.sign(np.sin(phi))))
print(f"{passages} flat passages in 10 s; crank angle off the reduction by at most {error.max():.2e} rad; "
      f"largest residual {trajectory.residual.max():.2e}")

figure = new_figure((7.0, 6.5))
angle, gap, force = figure.subplots(3, 1, sharex=True)
angle.plot(trajectory.t, phi, label="simulated (DOP853, rtol 1e-10)")
angle.plot(trajectory.t, reduction.y[0], "--", label="one-degree-of-freedom reduction")
for flat in (0.0, -np.pi):
    angle.axhline(flat, color="0.6", lw=0.8)
angle.set_ylabel("crank angle φ (rad)")
angle.legend(loc="upper right", fontsize=8)
gap.semilogy(trajectory.t, np.maximum(error, 1e-16))
gap.set_ylabel("|φ − φ_reduction| (rad)")
# The closures' rows: along each bar (A's x), then across it (A's y), in N.
along, across = np.abs(trajectory.lam[:, 0::2]).max(axis=1), np.abs(trajectory.lam[:, 1::2]).max(axis=1)
force.semilogy(trajectory.t, along, lw=0.8, label="along a bar")
force.semilogy(trajectory.t, across, lw=0.8, label="across a bar")
force.set_ylabel("largest closure force (N)")
force.legend(loc="upper right", fontsize=8)
force.set_xlabel("t (s)")
figure.suptitle(f"{CELLS} parallelograms through their flat configurations ({passages} passages)")
print("wrote", save_figure(figure, out, "parallelogram_chain"))
