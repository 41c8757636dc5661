"""Trajectory optimisation with the analytical step derivatives: iLQR swings the double pendulum up and
drives a Panda's hand to a target.

iLQR (W. Li and E. Todorov, ICINCO 2004; with the regularisation and line search of Y. Tassa, T. Erez
and E. Todorov, IROS 2012) linearises the dynamics along the current trajectory, solves the resulting
time-varying LQR problem backwards, and rolls the improved controls forward. Each iteration needs the
derivatives of every step, ``∂x⁺/∂x`` and ``∂x⁺/∂u``: ``mb.rk4_step_derivatives`` gives them for all
steps of the horizon in one batched call, from ``mb.forward_dynamics_derivatives``.

Writes the cost against iteration and the motions, and prints the time per iteration.
Run: python examples/swing_up.py [output_folder]
"""

from __future__ import annotations

import sys
import time

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure


def rollout(model, x0, controls, dt):
    """States ``(N + 1, 2 nv)`` of the RK4 steps from ``x0`` under ``controls (N, nv)``."""
    nv = model.nv
    states = np.empty((len(controls) + 1, 2 * nv))
    states[0] = x0
    for k, u in enumerate(controls):
        states[k + 1] = np.concatenate(mb.rk4_step(model, states[k, :nv], states[k, nv:], u, dt))
    return states


def ilqr(model, x0, controls, dt, running, terminal, iterations=100, tolerance=1e-5):
    """Minimise ``Σ_k running(x_k, u_k) + terminal(x_N)`` over the controls (N, nv) from ``x0``.

    ``running(X, U)`` and ``terminal(x)`` return ``(cost, gradient(s), Hessian(s))``, batched over the
    steps for ``running``: ``(l (N,), l_x (N, n), l_u (N, m), l_xx (N, n, n), l_uu (N, m, m))``.
    Returns the controls, the states and the cost of each iteration.
    """
    nv = model.nv
    states = rollout(model, x0, controls, dt)

    def total(states, controls):
        return running(states[:-1], controls)[0].sum() + terminal(states[-1])[0]

    costs, mu = [total(states, controls)], 1e-6
    for _ in range(iterations):
        # the derivatives of every step at once: ∂x⁺/∂x = [[∂q⁺/∂q, ∂q⁺/∂v], [∂v⁺/∂q, ∂v⁺/∂v]], ∂x⁺/∂u
        _, d = mb.rk4_step_derivatives(model, states[:-1, :nv], states[:-1, nv:], controls, dt)
        A = np.block([[d.dq_dq, d.dq_dv], [d.dv_dq, d.dv_dv]])
        B = np.concatenate([d.dq_dtau, d.dv_dtau], axis=-2)
        _, l_x, l_u, l_xx, l_uu = running(states[:-1], controls)
        _, V_x, V_xx = terminal(states[-1])
        gains, feedforward = np.empty((len(controls), nv, 2 * nv)), np.empty((len(controls), nv))
        for k in range(len(controls) - 1, -1, -1):
            # Q_x = l_x + Aᵀ V_x, Q_u = l_u + Bᵀ V_x, Q_xx = l_xx + Aᵀ V_xx A,
            # Q_uu = l_uu + Bᵀ (V_xx + μ1) B, Q_ux = Bᵀ (V_xx + μ1) A
            regularised = V_xx + mu * np.eye(2 * nv)
            Q_x, Q_u = l_x[k] + A[k].T @ V_x, l_u[k] + B[k].T @ V_x
            Q_xx = l_xx[k] + A[k].T @ V_xx @ A[k]
            Q_uu = l_uu[k] + B[k].T @ regularised @ B[k]
            Q_ux = B[k].T @ regularised @ A[k]
            # u = ū + k + K (x − x̄):  K = −Q_uu⁻¹ Q_ux, k = −Q_uu⁻¹ Q_u
            solved = np.linalg.solve(Q_uu, np.concatenate([Q_ux, Q_u[:, None]], axis=1))
            K, kff = -solved[:, :-1], -solved[:, -1]
            gains[k], feedforward[k] = K, kff
            # V_x = Q_x + Kᵀ Q_uu k + Kᵀ Q_u + Q_uxᵀ k ;  V_xx = Q_xx + Kᵀ Q_uu K + Kᵀ Q_ux + Q_uxᵀ K
            V_x = Q_x + K.T @ Q_uu @ kff + K.T @ Q_u + Q_ux.T @ kff
            V_xx = Q_xx + K.T @ Q_uu @ K + K.T @ Q_ux + Q_ux.T @ K
            V_xx = 0.5 * (V_xx + V_xx.T)
        for alpha in (1.0, 0.5, 0.25, 0.1, 0.03, 0.01):
            trial_states, trial_controls = np.empty_like(states), np.empty_like(controls)
            trial_states[0] = x0
            for k in range(len(controls)):
                trial_controls[k] = controls[k] + alpha * feedforward[k] + gains[k] @ (trial_states[k] - states[k])
                trial_states[k + 1] = np.concatenate(
                    mb.rk4_step(model, trial_states[k, :nv], trial_states[k, nv:], trial_controls[k], dt))
            cost = total(trial_states, trial_controls)
            if np.isfinite(cost) and cost < costs[-1]:
                break
        else:
            mu *= 10.0  # no decrease along the step: lean towards gradient descent
            if mu > 1e6:
                break
            continue
        mu = max(mu / 3.0, 1e-9)
        states, controls = trial_states, trial_controls
        costs.append(cost)
        if costs[-2] - costs[-1] < tolerance * costs[-2]:
            break
    return controls, states, np.array(costs)


def quadratic_running(model, x_goal, state_weight, control_weight, u_ref=None):
    """``½ (x − x*)ᵀ Q (x − x*) + ½ (u − u_ref)ᵀ R (u − u_ref)`` per step, with its derivatives."""
    Q, R = np.diag(state_weight), np.diag(control_weight)
    u_ref = np.zeros(model.nv) if u_ref is None else u_ref

    def running(X, U):
        dx, du = X - x_goal, U - u_ref
        cost = 0.5 * np.einsum("ki,ij,kj->k", dx, Q, dx) + 0.5 * np.einsum("ki,ij,kj->k", du, R, du)
        n = len(X)
        return cost, dx @ Q, du @ R, np.broadcast_to(Q, (n,) + Q.shape), np.broadcast_to(R, (n,) + R.shape)

    return running


def swing_up(out):
    """The double pendulum from hanging at rest (q = 0) to upright at rest (q = [π, 0]) in 2.5 s."""
    model = mb.robots.load("double_pendulum")
    dt, steps = 0.01, 250
    x0, x_goal = np.zeros(4), np.array([np.pi, 0.0, 0.0, 0.0])
    final_weight = np.array([4000.0, 4000.0, 400.0, 400.0])
    running = quadratic_running(model, x_goal, np.full(4, 1e-2), np.full(2, 1e-2))

    def terminal(x):
        dx = x - x_goal
        return 0.5 * dx @ (final_weight * dx), final_weight * dx, np.diag(final_weight)

    start = time.perf_counter()
    controls, states, costs = ilqr(model, x0, np.zeros((steps, 2)), dt, running, terminal, iterations=200)
    elapsed = time.perf_counter() - start
    print(f"double pendulum swing-up: {len(costs) - 1} iterations, {1e3 * elapsed / max(len(costs) - 1, 1):.1f} ms "
          f"per iteration; final state error {np.abs(states[-1] - x_goal).max():.2e} (rad, rad/s)")
    times = dt * np.arange(steps + 1)
    figure = new_figure((10, 4))
    angles, torques = figure.subplots(1, 2)
    angles.plot(times, states[:, 0], label="shoulder")
    angles.plot(times, states[:, 1], label="elbow")
    angles.axhline(np.pi, color="grey", lw=0.8, ls="--", label="upright shoulder (π)")
    angles.set(xlabel="time (s)", ylabel="joint angle (rad)", title="Double pendulum swing-up")
    angles.legend()
    torques.step(times[:-1], controls[:, 0], where="post", label="shoulder")
    torques.step(times[:-1], controls[:, 1], where="post", label="elbow")
    torques.set(xlabel="time (s)", ylabel="joint torque (N·m)", title="Optimal torques (zero-order hold)")
    torques.legend()
    return costs, save_figure(figure, out, "swing_up_motion", dpi=120)


def panda_reach(out):
    """A Panda's hand from its start to a target point 1 s later, at rest, with little effort."""
    model = mb.robots.load("panda")
    nv, dt, steps = model.nv, 0.01, 100
    q_start = 0.5 * (np.clip(model.lower, -3, 3) + np.clip(model.upper, -3, 3))
    q_target = q_start + np.array([0.6, 0.3, -0.4, 0.5, 0.3, -0.4, 0.2, 0.0, 0.0])
    hand = "panda_hand_tcp"
    p_target = mb.frame_placement(model, q_target, hand)[:3, 3]
    x0 = np.concatenate([q_start, np.zeros(nv)])
    u_hold = mb.generalized_gravity(model, q_start)
    running = quadratic_running(model, x0, np.concatenate([np.zeros(nv), np.full(nv, 1e-3)]), np.full(nv, 1e-4),
                                u_ref=u_hold)
    position_weight, velocity_weight = 1e5, 10.0

    def terminal(x):
        # ½ w_p |p(q) − p*|² + ½ w_v |v|², Gauss–Newton Hessian w_p Jᵀ J from the hand's Jacobian
        q, v = x[:nv], x[nv:]
        error = mb.frame_placement(model, q, hand)[:3, 3] - p_target
        J = mb.jacobian(model, q, hand)[:3]
        gradient = np.concatenate([position_weight * J.T @ error, velocity_weight * v])
        hessian = np.zeros((2 * nv, 2 * nv))
        hessian[:nv, :nv] = position_weight * J.T @ J
        hessian[nv:, nv:] = velocity_weight * np.eye(nv)
        return 0.5 * position_weight * error @ error + 0.5 * velocity_weight * v @ v, gradient, hessian

    start = time.perf_counter()
    controls, states, costs = ilqr(model, x0, np.tile(u_hold, (steps, 1)), dt, running, terminal, iterations=100)
    elapsed = time.perf_counter() - start
    distance = np.linalg.norm(mb.frame_placement(model, states[:, :nv], hand)[:, :3, 3] - p_target, axis=-1)
    print(f"Panda reach: {len(costs) - 1} iterations, {1e3 * elapsed / max(len(costs) - 1, 1):.1f} ms per iteration; "
          f"final hand distance to the target {1e3 * distance[-1]:.3f} mm, final speed "
          f"{np.abs(states[-1, nv:]).max():.2e} rad/s")
    figure = new_figure((6, 4))
    axes = figure.subplots()
    axes.semilogy(dt * np.arange(steps + 1), np.maximum(distance, 1e-9))
    axes.set(xlabel="time (s)", ylabel="hand distance to the target (m)", title="Panda reach by iLQR")
    return costs, save_figure(figure, out, "swing_up_panda_reach", dpi=120)


def main(out):
    pendulum_costs, pendulum_path = swing_up(out)
    panda_costs, panda_path = panda_reach(out)
    figure = new_figure((6, 4))
    axes = figure.subplots()
    axes.semilogy(pendulum_costs, "o-", ms=3, label="double pendulum swing-up")
    axes.semilogy(panda_costs, "s-", ms=3, label="Panda reach")
    axes.set(xlabel="iLQR iteration", ylabel="total cost (dimensionless)", title="Cost against iteration")
    axes.legend()
    cost_path = save_figure(figure, out, "swing_up_cost", dpi=120)
    for path in (cost_path, pendulum_path, panda_path):
        print("wrote", path)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
