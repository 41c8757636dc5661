"""LQR from ``mb.linearize``: a cart-pole held upright, then a unicycle's pitch held by its pedals.

The cart-pole is read from a URDF string (a cart on a prismatic joint along x, a pole on a continuous
joint about y, upright at ``θ = 0``); only the cart is pushed. ``mb.linearize(model, q_up, 0, 0)`` gives
its first-order dynamics about the upright equilibrium in minimal coordinates, ``ẋ = A x + B δτ`` with
``x = [s; u]``, ``δq = position_basis s``, ``δv = velocity_basis u + dependent_rates s``. The
linear-quadratic regulator minimises ``∫ xᵀ Q x + δτ_cᵀ R δτ_c dt`` over the cart's force ``δτ_c``:
``δτ_c = −K x``, ``K = R⁻¹ B_cᵀ X`` with ``X`` the stabilising solution of the continuous algebraic
Riccati equation ``Aᵀ X + X A − X B_c R⁻¹ B_cᵀ X + Q = 0`` (R. E. Kalman, "Contributions to the theory of
optimal control", Bol. Soc. Mat. Mexicana 5, 1960; solved by ``scipy.linalg.solve_continuous_are``),
``B_c`` the column of ``B`` of the cart's joint. The nonlinear
closed loop, simulated by ``mb.simulate(..., tau=controller)`` from the pole tipped by 0.3 rad, returns
to the upright at rest at the rate of the closed loop's eigenvalues.

The same recipe balances the unicycle of ``examples/unicycle.py`` about its upright roll at 6 m/s, from
``ConstrainedSystem.linearize``: its 10 minimal coordinates (6 positions on the ground, 4 rolling
velocities) contain modes the pedals cannot reach (the heading, the side-to-side motion and the lean at
first order), so the regulator is designed on the controllable subspace, spanned by the columns of the
controllability matrix ``[B, A B, A² B, …]`` (the Kalman decomposition: that subspace is invariant
under ``A``, so ``ẋ_c = T_cᵀ A T_c x_c + T_cᵀ B δτ`` with ``x_c = T_cᵀ x``; R. E. Kalman, "Mathematical
description of linear dynamical systems", SIAM J. Control 1, 1963), less the place along the ground, which
the dynamics ignore: it holds the pitch, its rate and the speed, about the steady roll at the unicycle's
current place and heading.

Writes ``cartpole_lqr.png`` (cart position, pole angle, velocities and force against time) and
``unicycle_lqr.png`` (pitch, lean, speed and pedal torque).
Run: python examples/cartpole_lqr.py [output_folder]
"""

from __future__ import annotations

import os
import runpy
import sys

import numpy as np
import scipy.linalg

import multibody as mb
from multibody.plotting import new_figure, save_figure

CART_POLE_URDF = """<robot name="cart_pole">
  <link name="rail"/>
  <joint name="slide" type="prismatic">
    <parent link="rail"/><child link="cart"/><axis xyz="1 0 0"/>
    <limit lower="-10" upper="10" effort="100" velocity="10"/>
  </joint>
  <link name="cart">
    <inertial><mass value="1.5"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="hinge" type="continuous">
    <parent link="cart"/><child link="pole"/><axis xyz="0 1 0"/>
  </joint>
  <link name="pole">
    <inertial><origin xyz="0 0 0.6"/><mass value="0.4"/>
      <inertia ixx="0.05" iyy="0.05" izz="0.0001" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
</robot>"""


def lqr(A, B, Q, R):
    """The LQR gain ``K (m, n)`` of ``ẋ = A x + B u`` (``A (n, n)``, ``B (n, m)``: a linearization's ``A`` and
    the columns of its ``B`` of the pushed joints) and the closed loop ``A − B K``; ``Q (n, n)``,
    ``R (m, m)``, both symmetric, ``Q`` positive semi-definite and ``R`` definite. ``K = R⁻¹ Bᵀ X`` with
    ``X`` from the continuous algebraic Riccati equation (module docstring)."""
    X = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K = np.linalg.solve(R, B.T @ X)
    return K, A - B @ K


def controllable_subspace(A, B, tolerance=1e-9):
    """Orthonormal basis ``T_c (n, c)`` of the range of the controllability matrix ``[B, A B, …, Aⁿ⁻¹ B]``
    of ``A (n, n)``, ``B (n, m)``: the singular vectors whose singular values exceed ``tolerance`` times the
    largest, the blocks scaled to unit size so that fast and slow rates count alike."""
    n = len(A)
    blocks, block = [], B / np.linalg.norm(B)
    for _ in range(n):
        blocks.append(block)
        block = A @ block
        block = block / max(np.linalg.norm(block), np.finfo(float).tiny)
    U, sigma, _ = np.linalg.svd(np.concatenate(blocks, axis=1))
    return U[:, : int(np.sum(sigma > tolerance * sigma[0]))]


def decay_bound(closed_loop):
    """``(α, κ)`` of the bound ``|x(t)| ≤ κ e^{α t} |x(0)|`` of ``ẋ = A_cl x``: ``α`` the largest real part of
    the eigenvalues of ``A_cl``, ``κ`` the condition number of its eigenvector matrix (``A_cl = V Λ V⁻¹``,
    ``|e^{A_cl t}| ≤ |V| |V⁻¹| e^{α t}``)."""
    eigenvalues, vectors = np.linalg.eig(closed_loop)
    return float(eigenvalues.real.max()), float(np.linalg.cond(vectors))


# ----------------------------------------------------------------------------- the cart-pole

def cart_pole():
    """The cart-pole :class:`~multibody.model.Model` of :data:`CART_POLE_URDF`: ``q = [x (m), θ (rad)]``, the pole
    upright at ``θ = 0`` (its centre of mass 0.6 m above the hinge), positive tipping it towards +x."""
    return mb.load_urdf(CART_POLE_URDF)


def cart_pole_regulator(model, Q=np.diag([10.0, 100.0, 1.0, 10.0]), R=np.array([[0.1]])):
    """The linearization at the upright equilibrium (``mb.linearize``), the cart's velocity index, the gain
    ``K (1, 4)`` and the closed loop; ``Q`` weighs ``[x, θ, ẋ, θ̇]`` (in the minimal coordinates, which
    are these without constraints), ``R`` the cart's force (N⁻²)."""
    q_up, rest = model.neutral(), np.zeros(model.nv)
    linearization = mb.linearize(model, q_up, rest, rest)
    cart = model.idx_v[model.joint_index("slide")]
    K, closed_loop = lqr(linearization.A, linearization.B[:, [cart]], Q, R)
    return linearization, cart, K, closed_loop


class Regulator:
    """``τ(t, q, v) = τ₀ + δτ`` with ``δτ = −K [s; u]`` on the joints ``inputs``, ``[s; u]`` the minimal
    coordinates of the state's deviation from the linearization's ``(q, v)`` (``linearization.coordinates``
    of ``model.difference(q₀, q)`` and ``v − v₀``), or from ``reference(t, q) -> (q₀, v₀)``.
    ``gain_basis (p + k, c)``: the coordinates the gain acts on, ``x_c = gain_basisᵀ [s; u]`` (default all)."""

    def __init__(self, model, linearization, inputs, K, reference=None, gain_basis=None):
        self.model, self.linearization, self.inputs, self.K = model, linearization, list(inputs), K
        self.reference = reference
        self.gain_basis = gain_basis

    def state(self, t, q, v):
        """The minimal coordinates ``[s; u] (p + k,)`` of ``(q, v)`` at time ``t`` (s)."""
        q0, v0 = (self.linearization.q, self.linearization.v) if self.reference is None else self.reference(t, q)
        return self.linearization.coordinates(self.model.difference(q0, q), v - v0)

    def __call__(self, t, q, v):
        x = self.state(t, q, v)
        if self.gain_basis is not None:
            x = self.gain_basis.T @ x
        tau = np.array(self.linearization.tau, dtype=float)
        tau[self.inputs] -= self.K @ x
        return tau


def balance_cart_pole(tilt=0.3, duration=6.0, dt=0.01, rtol=1e-9):
    """The nonlinear closed loop from the pole tipped by ``tilt`` (rad) at rest: ``(model, regulator,
    closed loop (4, 4), trajectory, states (n, 4), forces (n,) N)``."""
    model = cart_pole()
    linearization, cart, K, closed_loop = cart_pole_regulator(model)
    controller = Regulator(model, linearization, [cart], K)
    q0 = np.array([0.0, tilt])
    trajectory = mb.simulate(model, q0, np.zeros(model.nv), duration, dt=dt, method="RK45", tau=controller,
                             rtol=rtol, atol=1e-2 * rtol)
    states = np.array([controller.state(t, q, v) for t, q, v in zip(trajectory.t, trajectory.q, trajectory.v)])
    forces = np.array([controller(t, q, v)[cart] for t, q, v in zip(trajectory.t, trajectory.q, trajectory.v)])
    return model, controller, closed_loop, trajectory, states, forces


# ----------------------------------------------------------------------------- the unicycle

def unicycle_example():
    """The functions of ``examples/unicycle.py``."""
    return runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "unicycle.py"))


def regulated_subspace(A, B, tolerance=1e-9):
    """Orthonormal basis ``T (n, r)`` of the coordinates a regulator of ``ẋ = A x + B u`` can act on: the
    controllable subspace ``T_c`` (:func:`controllable_subspace`) without the directions that ``A`` maps to
    zero in it (shifts along a symmetry, such as the place on the ground, which the dynamics ignore and a
    regulator need not hold). Since ``A`` vanishes on those, ``y = Tᵀ x`` obeys ``ẏ = Tᵀ A T y + Tᵀ B u``
    whatever the shift."""
    T_c = controllable_subspace(A, B, tolerance)
    A_c = T_c.T @ A @ T_c
    U, sigma, _ = np.linalg.svd(A_c.T)
    # the left singular vectors of A_cᵀ with non-zero singular values span the row space of A_c: null(A_c)⊥
    return T_c @ U[:, : int(np.sum(sigma > tolerance * sigma[0]))]


def unicycle_regulator(speed=6.0, q_weight=10.0, r_weight=1e-3):
    """LQR on the pedals of the unicycle rolling upright and straight at ``speed`` (m/s), linearized by
    ``ConstrainedSystem.linearize``: returns ``(unicycle functions, system, linearization, T (10, r),
    K (1, r), closed loop (r, r), reference)``. ``Q = q_weight · I`` on the regulated coordinates
    ``Tᵀ [s; u]`` (:func:`regulated_subspace`), ``R = r_weight`` (N⁻² m⁻²) on the pedals' torque.
    ``reference(t, q)`` is the steady roll at the unicycle's place, heading and wheel angle: the rolling
    constraint and the dynamics do not change when the unicycle moves or turns on the ground, so neither
    does the linearization, and the regulator holds pitch and speed wherever the lean takes it."""
    unicycle = unicycle_example()
    dimensions = unicycle["Unicycle"]()
    system = dimensions.system()
    model = system.model
    q_up, v_up = unicycle["start"](dimensions, system, speed)
    linearization = system.linearize(q_up, v_up)
    axle = model.idx_v[model.joint_index("axle")]
    T = regulated_subspace(linearization.A, linearization.B[:, [axle]])
    A_r, B_r = T.T @ linearization.A @ T, T.T @ linearization.B[:, [axle]]
    K, closed_loop = lqr(A_r, B_r, q_weight * np.eye(len(A_r)), np.array([[r_weight]]))

    def reference(t, q):
        # upright at the same place, heading and wheel angle, rolling at `speed` (free-flyer velocities are in
        # the rider's frame, the same for every heading)
        steady = q.copy()
        steady[2] = q_up[2]
        heading = unicycle["yaw_lean_pitch"](q[3:7])[0]
        steady[3:7] = mb.spatial.rotation_to_quat(mb.spatial.axis_angle_rotation([0.0, 0.0, 1.0], heading))
        return steady, v_up

    return unicycle, system, linearization, T, K, closed_loop, reference


def ride_with_lqr(speed=6.0, lean=0.02, pitch=0.05, duration=4.0, dt=0.01, rtol=1e-9):
    """The unicycle under the LQR pedals from ``lean`` and ``pitch`` (rad) at ``speed`` (m/s): ``(regulator,
    closed loop, trajectory, yaw-lean-pitch (n, 3) rad, torques (n,) N·m)``."""
    unicycle, system, linearization, T, K, closed_loop, reference = unicycle_regulator(speed)
    model = system.model
    axle = model.idx_v[model.joint_index("axle")]
    controller = Regulator(model, linearization, [axle], K, reference=reference, gain_basis=T)
    q0, v0 = unicycle["start"](unicycle["Unicycle"](), system, speed, lean, pitch)
    trajectory = mb.simulate(system, q0, v0, duration, dt=dt, method="RK45", tau=controller, rtol=rtol,
                             atol=1e-2 * rtol)
    angles = unicycle["yaw_lean_pitch"](trajectory.q[:, 3:7])
    torques = np.array([controller(t, q, v)[axle] for t, q, v in zip(trajectory.t, trajectory.q, trajectory.v)])
    return controller, closed_loop, trajectory, angles, torques


def main(out):
    model, controller, closed_loop, trajectory, states, forces = balance_cart_pole()
    alpha, kappa = decay_bound(closed_loop)
    norms = np.linalg.norm(states, axis=1)
    print(f"cart-pole: K = {np.round(controller.K[0], 3).tolist()}; closed-loop eigenvalues "
          f"{np.round(np.linalg.eigvals(closed_loop), 3).tolist()}")
    print(f"  |x| from {norms[0]:.3f} to {norms[-1]:.2e} in {trajectory.t[-1]:g} s; the linear bound κ e^(αt) |x0| "
          f"(α = {alpha:.3f} 1/s, κ = {kappa:.2f}) gives {kappa * np.exp(alpha * trajectory.t[-1]) * norms[0]:.2e}; "
          f"largest force {np.abs(forces).max():.2f} N")
    figure = new_figure((10.0, 6.5))
    figure.suptitle("Cart-pole: LQR from mb.linearize about the upright, from the pole tipped by 0.3 rad")
    (position, velocity), (force, norm) = figure.subplots(2, 2, sharex=True)
    position.plot(trajectory.t, trajectory.q[:, 0], label="cart x (m)")
    position.plot(trajectory.t, trajectory.q[:, 1], label="pole θ (rad)")
    position.set(ylabel="position (m, rad)")
    velocity.plot(trajectory.t, trajectory.v[:, 0], label="cart ẋ (m/s)")
    velocity.plot(trajectory.t, trajectory.v[:, 1], label="pole θ̇ (rad/s)")
    velocity.set(ylabel="velocity (m/s, rad/s)")
    force.plot(trajectory.t, forces, color="k")
    force.set(xlabel="time (s)", ylabel="force on the cart (N)")
    norm.semilogy(trajectory.t, norms, label="|[s; u]| of the simulation")
    norm.semilogy(trajectory.t, kappa * np.exp(alpha * trajectory.t) * norms[0], "--", color="0.5",
                  label="κ e^(α t) |x(0)| (closed-loop eigenvalues)")
    norm.set(xlabel="time (s)", ylabel="state norm (SI units)")
    for axes in (position, velocity, norm):
        axes.legend(fontsize=8)
    paths = [save_figure(figure, out, "cartpole_lqr")]

    for speed in (2.0, 6.0):
        # the upright roll's own modes: the pitch falls at either speed; the lean falls at 2 m/s and weaves at 6
        eigenvalues = np.linalg.eigvals(unicycle_regulator(speed)[2].A)
        moving = eigenvalues[np.abs(eigenvalues) > 1e-6 * np.abs(eigenvalues).max()]
        print(f"unicycle rolling upright at {speed:g} m/s: non-zero open-loop eigenvalues "
              f"{', '.join(f'{z.real:+.3f}{z.imag:+.3f}j' for z in np.sort_complex(moving))} (1/s)")
    controller, closed_loop, trajectory, angles, torques = ride_with_lqr()
    alpha, _ = decay_bound(closed_loop)
    # the wheel centre's velocity along the ground (the rider's origin; free-flyer velocities are in its frame)
    world = np.einsum("nij,nj->ni", mb.spatial.quat_to_rotation(trajectory.q[:, 3:7]), trajectory.v[:, :3])
    speed = np.linalg.norm(world[:, :2], axis=1)
    print(f"unicycle at 6 m/s: {controller.gain_basis.shape[1]} regulated coordinates of "
          f"{controller.gain_basis.shape[0]}, slowest closed-loop rate {alpha:.3f} 1/s; pitch "
          f"{angles[0, 2]:.3f} -> {angles[-1, 2]:.1e} rad, lean at most {np.abs(angles[:, 1]).max():.3f} rad, "
          f"torque at most {np.abs(torques).max():.1f} N·m; max residual {trajectory.residual.max():.2e}")
    figure = new_figure((10.0, 6.5))
    figure.suptitle("Unicycle at 6 m/s: LQR pedals from ConstrainedSystem.linearize, "
                    "from pitch 0.05 rad and lean 0.02 rad")
    (pitch, lean), (forward, torque) = figure.subplots(2, 2, sharex=True)
    pitch.plot(trajectory.t, angles[:, 2])
    pitch.set(ylabel="pitch θ (rad, forward)")
    lean.plot(trajectory.t, angles[:, 1])
    lean.set(ylabel="lean φ (rad, to the right)")
    forward.plot(trajectory.t, speed)
    forward.set(xlabel="time (s)", ylabel="forward speed (m/s)")
    torque.plot(trajectory.t, torques, color="k")
    torque.set(xlabel="time (s)", ylabel="pedal torque (N·m)")
    paths.append(save_figure(figure, out, "unicycle_lqr"))
    for path in paths:
        print("wrote", path)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
