"""Chains of parallelograms through their flat configurations, where the loop closures lose rank.

The mechanism, in the x–z plane (revolute joints about y, 1 m bars of 1 kg, boxes 0.05 m thick):
``cells + 1`` cranks ``V0 … VN`` pivot on the ground at ``x = 0, 1, …, N``; the bar ``Hk`` is jointed to
the tip of ``V(k−1)`` and closed on the tip of ``Vk`` by a planar loop closure (frame A at the tip of
``Hk``, turned so that its x–y plane is the mechanism's plane; its rows are the gap ``tip Vk − tip Hk``
along A's x and y). Each cell is a parallelogram; ``2N + 1`` joints and ``2N`` rows leave one degree of
freedom, the crank angle ``φ`` (every crank at ``φ`` above the horizontal, every bar ``Hk`` horizontal):
``θ_Vk = −φ``, ``ψ_Hk = φ`` (a joint angle ``θ`` about y turns x into ``(cos θ, 0, −sin θ)``).

Near the flat configurations (``φ = 0`` or ``π``: every bar on the ground line) the x rows of the
closures shrink as ``sin φ`` (the row of cell k is ``sin φ (e_V(k−1) − e_Vk)``), so the Jacobian's
smallest singular values are about ``φ``; at flat they vanish and the cell may also fold (bar ``Hk``
turning with crank ``Vk``), a bifurcation.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import multibody as mb

from constraint_helpers import (G, LENGTH, MASS, THICKNESS, assert_close, crank_state, parallelogram_chain,
                                planar_closures)


def world_closure(cells):
    """The same closures written by hand as one user ``Holonomic``: rows ``(x, z)`` of ``tip Vk − tip Hk``
    in world coordinates, cell by cell, with the exact Jacobian and ``γ = −d²φ/dt²`` at ``a = 0``.

    In units of L, with ``α_k = θ_V(k−1) + ψ_Hk`` (the bar's angle) and ``tip Vk = (k + cos θ_Vk, −sin θ_Vk)``:
    ``φ_x = 1 + cos θ_Vk − cos θ_V(k−1) − cos α_k``, ``φ_z = −sin θ_Vk + sin θ_V(k−1) + sin α_k``, so ``γ_x = cos θ_Vk θ̇_Vk² − cos θ_V(k−1) θ̇_V(k−1)² − cos α_k α̇_k²`` and
    ``γ_z = −(sin θ_Vk θ̇_Vk² − sin θ_V(k−1) θ̇_V(k−1)² − sin α_k α̇_k²)``.
    """
    n = cells

    def split(x):
        return x[: n + 1], x[n + 1 :]

    def phi(q, t=0.0):
        theta, psi = split(q)
        rows = []
        for k in range(1, n + 1):
            alpha = theta[k - 1] + psi[k - 1]
            rows += [1.0 + np.cos(theta[k]) - np.cos(theta[k - 1]) - np.cos(alpha),
                     -np.sin(theta[k]) + np.sin(theta[k - 1]) + np.sin(alpha)]
        return LENGTH * np.array(rows)

    def jacobian(q, t=0.0):
        theta, psi = split(q)
        A = np.zeros((2 * n, 2 * n + 1))
        for k in range(1, n + 1):
            alpha, r = theta[k - 1] + psi[k - 1], 2 * (k - 1)
            A[r, [k, k - 1, n + k]] = -np.sin(theta[k]), np.sin(theta[k - 1]) + np.sin(alpha), np.sin(alpha)
            A[r + 1, [k, k - 1, n + k]] = -np.cos(theta[k]), np.cos(theta[k - 1]) + np.cos(alpha), np.cos(alpha)
        return LENGTH * A

    def gamma(q, v, t=0.0):
        (theta, psi), (rate, psi_rate) = split(q), split(v)
        rows = []
        for k in range(1, n + 1):
            alpha, alpha_rate = theta[k - 1] + psi[k - 1], rate[k - 1] + psi_rate[k - 1]
            rows += [np.cos(theta[k]) * rate[k] ** 2 - np.cos(theta[k - 1]) * rate[k - 1] ** 2 - np.cos(alpha) * alpha_rate**2,
                     -np.sin(theta[k]) * rate[k] ** 2 + np.sin(theta[k - 1]) * rate[k - 1] ** 2 + np.sin(alpha) * alpha_rate**2]
        return LENGTH * np.array(rows)

    return mb.Holonomic(phi, jacobian, "world closures", gamma=gamma)


# ----------------------------------------------------------------------------- two parallelograms at rest

#: Joint torques on V0, V1, V2, H1, H2: their components along ``e_V0 − e_V1`` and ``e_V1 − e_V2``, the
#: directions the x rows nearly lose, are met by x forces of about ``1/angle``.
TORQUES = np.array([1.0, -2.0, 0.5, 0.3, -0.7])


@pytest.mark.parametrize("angle", [1e-3, 1e-6, 1e-9])
def test_two_parallelograms_near_flat_match_a_non_redundant_closure(angle):
    """The two-parallelogram reproduction: minimum-norm multipliers, finite and equal to 1e-8 (relative to
    their size) to those of the same chain closed by another, non-redundant set of rows.

    The reference set is :func:`world_closure`: the same two pin joints written as four user rows in world
    coordinates. It is non-redundant: its rank is 4 = m away from flat, since the z row of cell k is the
    only row with a ``ψ_Hk`` column (``cos α_k ≠ 0``) and the x rows ``sin φ (e_V(k−1) − e_Vk)`` involve the
    cranks alone, independent of each other; near flat the x rows are small but still independent (rank 4
    at these angles). A single row along the non-degenerate direction (z) in place of a planar closure
    would not do: with 5 joints and 3 rows the chain would gain a degree of freedom, the nearly lost
    direction, and its multipliers would differ (no x force at all).

    Both sets describe the same constraint manifold, so at a state on it the generalized constraint
    force ``Aᵀλ`` and the accelerations are the same whatever each set's row conventions: ``Aᵀλ`` is the
    unique force, in the span of the constraint normals, that keeps ``A a = γ``. Here the rows also
    correspond one to one (frame A's x and y are the world's x and z while ``Hk`` is horizontal, and the
    rotation of frame A does not enter ``A`` where the gap is zero), so ``λ`` is compared too.

    The reference's rows come from a user constraint evaluated in Python and pass to the compiled solve as
    arrays, the planar closures' from the compiled program: two sets of rows, one rank rule. Both must give
    the multipliers of the KKT system to about ``ε`` relative to their size at ``1e-9`` rad, where the rows
    are graded by 1e9 (which a bidiagonal SVD would resolve only to ``ε · 1e9``).
    """
    cells = 2
    model = parallelogram_chain(cells)
    planar = mb.ConstrainedSystem(model, planar_closures(cells))
    world = mb.ConstrainedSystem(model, [world_closure(cells)])
    q, v = crank_state(cells, angle)
    assert np.abs(planar.position_error(q)).max() < 1e-15 and np.abs(world.position_error(q)).max() < 1e-15
    assert planar.rank(q) == world.rank(q) == 4
    found, expected = planar.solve(q, v, TORQUES), world.solve(q, v, TORQUES)
    assert found.rank == expected.rank == 4
    assert np.all(np.isfinite(found.lam))
    # the nearly lost rows carry a force of about 1/angle: large, yet finite and exact
    assert 0.1 < np.abs(found.lam).max() * angle < 10.0
    assert_close(planar.jacobian(q), world.jacobian(q), 1e-15, scale=1.0, what="rows")
    lam_scale = np.abs(expected.lam).max()
    assert_close(found.lam, expected.lam, 1e-8, scale=lam_scale, what="multipliers")
    force_scale = np.abs(expected.A.T @ expected.lam).max() + np.abs(TORQUES).max()
    assert_close(found.A.T @ found.lam, expected.A.T @ expected.lam, 1e-8, scale=force_scale, what="A^T lambda")
    assert_close(found.a, expected.a, 1e-8, scale=max(1.0, np.abs(expected.a).max()), what="accelerations")
    # the equations hold: M a + h = τ + Aᵀ λ and A a = γ
    M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
    assert_close(M @ found.a + h, TORQUES + found.A.T @ found.lam, 1e-9, scale=force_scale, what="M a + h")
    assert_close(found.A @ found.a, found.gamma, 1e-9, scale=max(1.0, np.abs(found.a).max()), what="A a")


@pytest.mark.parametrize("angle", [1e-3, 1e-6, 1e-9])
def test_two_parallelograms_with_a_redundant_rod_get_the_minimum_norm_multipliers(angle):
    """The same chain with a redundant fifth row, a rod between the tips of ``V0`` and ``V2`` (length 2,
    true of every parallelogram state): rank 4 of 5 rows, and the multipliers must be the minimum-norm ones.

    At these states ``tip V2 − tip V0 = (2, 0)``, so the rod's row ``φ = 2 − |tip V0 − tip V2|`` is
    ``−∂(x_V2 − x_V0)/∂q``, and the sum of the two x rows is ``∂(x_V2 − x_V0)/∂q − Σ ∂cos α_k/∂q`` with
    ``∂cos α_k = −sin α_k ∂α_k = 0`` (the bars are horizontal): rows ``x1 + x2 + rod = 0``, so ``Aᵀ`` has the
    null vector ``n = (1, 0, 1, 0, 1)`` (rows x1, z1, x2, z2, rod). The multipliers that meet the same
    force are ``(λ_planar, 0) + s n``; the minimum-norm ones have ``s = −(λ_planar, 0)·n / 3``.
    """
    cells = 2
    model = parallelogram_chain(cells)
    tip = [LENGTH, 0.0, 0.0]
    redundant = mb.ConstrainedSystem(model, planar_closures(cells) + [mb.Distance("V0", "V2", 2.0, point_a=tip, point_b=tip)])
    planar = mb.ConstrainedSystem(model, planar_closures(cells))
    q, v = crank_state(cells, angle)
    assert redundant.rank(q) == 4 and redundant.num_rows == 5
    found, reference = redundant.solve(q, v, TORQUES), planar.solve(q, v, TORQUES)
    assert found.rank == 4
    null = np.array([1.0, 0.0, 1.0, 0.0, 1.0])
    assert np.abs(found.A.T @ null).max() <= 1e-15
    extended = np.append(reference.lam, 0.0)
    minimum_norm = extended - (extended @ null) / (null @ null) * null
    assert_close(found.lam, minimum_norm, 1e-8, scale=np.abs(minimum_norm).max(), what="minimum-norm multipliers")
    force_scale = np.abs(reference.A.T @ reference.lam).max() + np.abs(TORQUES).max()
    assert_close(found.A.T @ found.lam, reference.A.T @ reference.lam, 1e-8, scale=force_scale, what="A^T lambda")
    assert_close(found.a, reference.a, 1e-8, scale=max(1.0, np.abs(reference.a).max()), what="accelerations")


@pytest.mark.parametrize("rate", [1e3, 1e5, 1e7])
@pytest.mark.parametrize("angle", [0.3, 1e-3])
def test_a_fast_crank_leaves_full_rank_rows_consistent(angle, rate):
    """Crank ``V2`` alone spinning at ``rate`` rad/s (the others at rest): the rows of cell 2 get
    ``γ ~ rate²`` (up to 1e14), those of cell 1 stay of order 1, and the two cells share crank ``V1``, so the
    singular vectors mix their rows. With full rank every right-hand side is met; what is left of cell 1's
    rows is the rounding of cell 2's terms (``ε · 1e14``), which the consistency check must judge against
    those terms, not against cell 1's own, on the compiled program's rows and on rows from Python alike. Then the
    equations hold to that rounding."""
    cells = 2
    model = parallelogram_chain(cells)
    q, _ = crank_state(cells, angle)
    v = np.zeros(2 * cells + 1)
    v[cells] = rate
    M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
    for system in (mb.ConstrainedSystem(model, planar_closures(cells)), mb.ConstrainedSystem(model, [world_closure(cells)])):
        solution = system.solve(q, v)
        assert solution.rank == 4
        force = solution.A.T @ solution.lam
        assert_close(M @ solution.a + h, force, 1e-9, scale=np.abs(force).max() + np.abs(h).max(), what="M a + h")
        # A backward-stable solve leaves of A a − γ the rounding of its terms, ε (|A| |a| + |γ|) (measured up to
        # 1.3 times it: 7.3e-7 at 1e-3 rad, 1e3 rad/s); margin 10.
        rounding = np.finfo(float).eps * (np.abs(solution.A) @ np.abs(solution.a) + np.abs(solution.gamma)).max()
        assert_close(solution.A @ solution.a, solution.gamma, 10.0 * rounding, scale=1.0, what="A a")


def test_forty_cell_chain_solves_near_flat():
    """One compiled step of the 81-bar chain (40 cells, 80 rows) 1e-6 rad from flat, moving: full rank,
    finite multipliers, and the equations of motion to 1e-9 of the forces' size."""
    cells = 40
    model = parallelogram_chain(cells)
    system = mb.ConstrainedSystem(model, planar_closures(cells))
    q, v = crank_state(cells, 1e-6, 3.0)
    solution = system.solve(q, v)
    assert solution.rank == system.num_rows == 80
    assert np.all(np.isfinite(solution.lam))
    M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
    force = solution.A.T @ solution.lam
    assert_close(M @ solution.a + h, force, 1e-9, scale=np.abs(force).max() + np.abs(h).max(), what="M a + h")
    assert_close(solution.A @ solution.a, solution.gamma, 1e-9, scale=max(1.0, np.abs(solution.a).max()), what="A a")


@pytest.mark.parametrize("angle", [1e-4, 1e-6])
def test_near_flat_a_tiny_residual_hides_a_velocity_that_the_projection_removes(angle):
    """Why ``simulate`` decides by the projection's move and not by the residual: 1e-6 rad from flat, a
    differential crank rate of 1e-7 rad/s leaves a residual of ``1e-7 · angle`` (below the default
    tolerance of 1e-12), yet the projection moves the rates by most of 1e-7, back to a parallelogram
    motion. Turning crank ``V2`` and bar ``H2`` together (the folding motion) keeps the tip of ``H2`` on
    the tip of ``V2`` to first order across the bar; along the bar, cell 2's x row ``≈ sin φ (e_V1 − e_V2)``
    gives ``|A v| = sin φ · δ``, and the projection divides by the row's size."""
    cells = 2
    model = parallelogram_chain(cells)
    system = mb.ConstrainedSystem(model, planar_closures(cells))
    q, v = crank_state(cells, angle, 3.0)
    drift = v.copy()
    drift[[cells, 2 * cells]] += 1e-7  # crank V2 and bar H2 together: cell 2 starts to fold
    # the residual 1e-7 sin φ of the folding rate, and the rounding of the rows' terms ε |A| |v| (measured: the
    # first term to 1e-3 of it); margin 10
    A = system.solve(q, drift).A
    estimate = 1e-7 * np.sin(angle) + np.finfo(float).eps * (np.abs(A) @ np.abs(drift)).max()
    assert system.residual(q, drift) <= 10.0 * estimate
    q_p, v_p = system.project(q, drift)
    assert np.abs(q_p - q).max() == 0.0
    # a parallelogram motion again: every crank at one rate, every bar turning back by it
    assert np.ptp(v_p[: cells + 1]) <= 1e-14 and np.abs(v_p[: cells] + v_p[cells + 1 :]).max() <= 1e-14
    assert np.abs(v_p - drift).max() > 5e-8


@pytest.mark.parametrize("batched", [True, False], ids=["compiled batch", "state by state"])
def test_output_states_are_projected_by_the_move_too(batched):
    """The trajectory's output states (dense output between steps) are projected as the steps' ends are:
    a state 1e-6 rad from flat whose folding rate of 1e-7 rad/s leaves a residual of 1e-13, below the
    tolerance, comes out as its projection; a state on the constraints comes out unchanged. ``batched``:
    the system's batched calls, or (a system that does not take batches) one state at a time."""
    from multibody.simulation import _trajectory

    class OneStateAtATime(mb.ConstrainedSystem):
        batched = property(lambda self: False)

    cells = 2
    model = parallelogram_chain(cells)
    system = (mb.ConstrainedSystem if batched else OneStateAtATime)(model, planar_closures(cells))
    assert system.batched == batched
    q, v = crank_state(cells, 1e-6, 3.0)
    drift = v.copy()
    drift[[cells, 2 * cells]] += 1e-7
    assert system.residual(q, drift) <= 1e-12
    states = np.array([np.concatenate([q, drift]), np.concatenate([q, v])])
    trajectory = _trajectory(system, np.array([0.0, 0.1]), states, lambda t, q, v: None, "completed", 1e-12)
    q_p, v_p = system.project(q, drift)
    np.testing.assert_array_equal(trajectory.q[0], q_p)
    np.testing.assert_array_equal(trajectory.v[0], v_p)
    assert np.abs(trajectory.v[0] - drift).max() > 5e-8
    np.testing.assert_array_equal(trajectory.v[1], v)


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (flat: the closures lose rank there)
@pytest.mark.parametrize("angle", [1e-3, 1e-6, 1e-9, 1e-12])
def test_the_projection_reports_how_near_flat_the_rows_are(angle):
    """The conditioning that :meth:`ConstrainedSystem.projection` returns with the projected state, and by
    which ``simulate`` evaluates a step's stages on the constraints (``NEAR_SINGULAR``), falls as the
    angle from flat: the x rows shrink as ``sin φ``. It counts the directions that the rank tolerance
    drops (1e-12 rad from flat) but not the rows' rounding; on the compiled program's rows and on the same rows
    evaluated in Python it is that ratio or a lower bound on it within a factor ``m`` (the LQ factor's bound)."""
    cells = 2
    model = parallelogram_chain(cells)
    system = mb.ConstrainedSystem(model, planar_closures(cells))
    q, v = crank_state(cells, angle, 1.0)
    compiled = system.projection(q, v)[2]
    system.__dict__["_compiled_step"] = None  # the cached property, withheld: the rows evaluated in Python
    try:
        by_python_rows = system.projection(q, v)[2]
    finally:
        del system.__dict__["_compiled_step"]
    # the compiled step's LQ factor bounds it from below within a factor m (4 rows), the rotations give it
    m = system.num_rows
    assert by_python_rows / m <= compiled * (1.0 + 1e-8) and compiled <= by_python_rows * (1.0 + 1e-8)
    assert 0.1 * angle <= by_python_rows <= angle
    far = system.projection(*crank_state(cells, 0.5, 1.0))[2]
    assert far > mb.simulation.NEAR_SINGULAR


# ----------------------------------------------------------------------------- ten cells through flat

CELLS = 10
HORIZON = 20.0
START = 0.5  # rad above the horizontal, at rest

#: ``J = (N + 1) (m (L² + w²)/12 + m (L/2)²) + N m L²``: each crank turns by ``φ`` about its pivot (a box
#: of length L and thickness w about its end), each bar translates, every point on a circle of radius
#: L at speed ``L φ̇``; ``U = m g L ((N + 1)/2 + N) sin φ`` (crank centres at height ``(L/2) sin φ``, bar
#: centres at ``L sin φ``), so ``C = m L ((N + 1)/2 + N)`` and Lagrange's equation is ``J φ̈ = −C g cos φ``.
INERTIA = (CELLS + 1) * (MASS * (LENGTH**2 + THICKNESS**2) / 12 + MASS * (LENGTH / 2) ** 2) + CELLS * MASS * LENGTH**2
MOMENT = MASS * LENGTH * ((CELLS + 1) / 2 + CELLS)


def reduction(t, y):
    return [y[1], -MOMENT * G * np.cos(y[0]) / INERTIA]


@functools.lru_cache(maxsize=None)
def exact_crank():
    """``φ(t)`` of the one-degree-of-freedom reduction, DOP853 at rtol 1e-12 (a dense output)."""
    return solve_ivp(reduction, (0.0, HORIZON), [START, 0.0], method="DOP853", rtol=1e-12, atol=1e-12,
                     dense_output=True).sol


@functools.lru_cache(maxsize=None)
def reduction_error(method, rtol):
    """The reduction's own error at the output times when integrated by ``method`` at ``rtol``: what the
    integrator itself leaves over 20 s (RK45 at rtol 1e-8: 5e-6)."""
    times = np.linspace(0.0, HORIZON, 501)
    run = solve_ivp(reduction, (0.0, HORIZON), [START, 0.0], method=method, rtol=rtol, atol=rtol * 1e-2, t_eval=times)
    return float(np.abs(run.y[0] - exact_crank()(times)[0]).max())


@pytest.mark.parametrize("method, rtol", [
    ("RK45", 1e-8),
    ("RK45", 1e-9),
    ("RK45", 1e-10),
    ("RK45", 1e-11),
    ("DOP853", 1e-8),
    ("DOP853", 1e-9),
    ("DOP853", 1e-10),
    ("DOP853", 1e-11),
])
def test_ten_cells_pass_through_flat_as_their_one_degree_of_freedom_reduction(method, rtol):
    """Ten cells (21 bars, 20 rows) from ``φ = 0.5`` rad at rest swing under gravity through ``φ = 0``, down,
    and up through ``φ = −π`` and back, passing a flat configuration 31 times in 20 s. Every crank must
    follow the reduction's ``φ(t)`` (``θ_Vk = −φ``) and every bar stay horizontal (``θ_V(k−1) + ψ_Hk = 0``) at
    the 501 output times, to ``max(1e-6, 10 e)``, where ``e`` is the error that the same integrator at the same
    tolerances leaves on the reduction itself (RK45 at rtol 1e-8 leaves 5e-6 on the one equation, so 1e-6
    cannot be asked of it). The full system takes other steps than the reduction: its crank error was measured
    up to 1.25 e (RK45 at rtol 1e-8 and 1e-9), hence the margin of 10.

    atol is ``rtol / 100`` (angles and rates of order 1). Runtime of each case: about 1–3 s. They pass because
    ``simulate`` projects a step's end state when the projection moves it, not when the residual is large:
    near flat the rounding left in the folding motion shows in the residual only multiplied by the distance to
    flat (:func:`test_near_flat_a_tiny_residual_hides_a_velocity_that_the_projection_removes`); because the
    steps that start near flat (:data:`multibody.simulation.NEAR_SINGULAR`) evaluate their stages on the
    constraints, where off them the rows that the rank drops leave a right-hand side that reads as inconsistent
    (DOP853 at rtol 1e-9 stopped at 4.2 s, at 1e-11 at 1.6 s); and because those steps measure their local
    error on the constraints' tangent space, without the stages' accelerations along the nearly dependent
    rows, which the rows fix only to rounding divided by the distance to flat and the projection removes
    (measured in full, they shrank RK45's steps to 4e-11 s: at rtol 1e-10 it stalled at 12.51 s, at 1e-11 at
    0.97 s).
    """
    model = parallelogram_chain(CELLS)
    system = mb.ConstrainedSystem(model, planar_closures(CELLS))
    q0, v0 = crank_state(CELLS, START)
    trajectory = mb.simulate(system, q0, v0, HORIZON, method=method, rtol=rtol, atol=rtol * 1e-2, progress=False)
    phi = exact_crank()(trajectory.t)[0]
    assert trajectory.t[-1] == HORIZON
    passages = np.count_nonzero(np.diff(np.sign(np.sin(phi))))
    assert passages >= 30
    cranks, bars = trajectory.q[:, : CELLS + 1], trajectory.q[:, CELLS + 1 :]
    crank_error = np.abs(cranks + phi[:, None]).max()
    bar_angle = np.abs(cranks[:, :-1] + bars).max()
    bound = max(1e-6, 10.0 * reduction_error(method, rtol))
    assert crank_error <= bound, f"crank angles off the reduction by {crank_error:.3g} (bound {bound:.3g})"
    assert bar_angle <= bound, f"a bar turned by {bar_angle:.3g} rad (bound {bound:.3g})"


def test_ten_cells_pass_through_flat_with_fixed_rk4_steps():
    """The same passages with ``"RK4"`` at ``dt = 0.01`` s (2000 steps, every stage of the steps that start
    near flat on the constraints): the cranks follow the reduction's ``φ(t)`` and the bars stay horizontal
    to 1e-6 (measured: 1.4e-7, RK4's own error at this step)."""
    model = parallelogram_chain(CELLS)
    system = mb.ConstrainedSystem(model, planar_closures(CELLS))
    q0, v0 = crank_state(CELLS, START)
    trajectory = mb.simulate(system, q0, v0, HORIZON, method="RK4", dt=0.01, progress=False)
    phi = exact_crank()(trajectory.t)[0]
    assert np.count_nonzero(np.diff(np.sign(np.sin(phi)))) >= 30
    cranks, bars = trajectory.q[:, : CELLS + 1], trajectory.q[:, CELLS + 1 :]
    assert np.abs(cranks + phi[:, None]).max() <= 1e-6
    assert np.abs(cranks[:, :-1] + bars).max() <= 1e-6


def test_a_stall_near_flat_is_reported_with_its_cause():
    """LSODA (multistep formulas whose error is measured on every component, and whose stiff mode takes
    Jacobians of the stages' projected field) at rtol 1e-10 creeps from t ≈ 0.31 s, where the rows are near
    singular: ``simulate`` stops once its last 1000 steps advance less than 1e-6 of the run, and says that the
    constraints are near a singular configuration there, with what to try instead; the trajectory up to then
    follows the reduction."""
    model = parallelogram_chain(CELLS)
    system = mb.ConstrainedSystem(model, planar_closures(CELLS))
    q0, v0 = crank_state(CELLS, START)
    with pytest.raises(mb.SimulationError, match=r"LSODA stalled at t = 0\.3\d* s: its last 1000 steps") as info:
        mb.simulate(system, q0, v0, 2.0, method="LSODA", rtol=1e-10, atol=1e-12, progress=False)
    message = str(info.value)
    assert "near a singular configuration" in message and "method='DOP853'" in message
    partial = info.value.trajectory
    phi = exact_crank()(partial.t)[0]
    assert np.abs(partial.q[:, : CELLS + 1] + phi[:, None]).max() <= 1e-6


# ----------------------------------------------------------------------------- the error on the tangent space

def test_row_space_projectors_give_what_the_projection_removes():
    """``row_space_projectors``: ``P = M⁻¹Aᵀ (A M⁻¹ Aᵀ)⁺ A`` is an ``M``-orthogonal projector onto the rows' range,
    the closed form where the rows have full rank, the position one from the rows with a position level only
    (the rolling ball's contact height, not its rolling rows), and on a consistent state the velocity
    projection of ``v + e`` is ``v + (I − P) e``."""
    from multibody.demos import rolling_ball_setup

    setup = rolling_ball_setup()
    cases = [(setup.system, setup.q0, setup.v0)]
    chain = mb.ConstrainedSystem(parallelogram_chain(2), planar_closures(2))
    cases.append((chain, *crank_state(2, 0.4)))
    rng = np.random.default_rng(3)
    for system, q0, v0 in cases:
        q, v = system.project(q0, v0)
        position, velocity = system.row_space_projectors(q)
        M = system.system.mass_matrix(q)
        A = system.jacobian(q)
        for P, rows in ((position, A[system._position_mask]), (velocity, A)):
            np.testing.assert_allclose(P @ P, P, atol=1e-12)
            np.testing.assert_allclose(M @ P, (M @ P).T, atol=1e-12)
            np.testing.assert_allclose(rows @ (np.eye(system.nv) - P), 0.0, atol=1e-12)
            if np.linalg.matrix_rank(rows) == len(rows):
                M_inv_At = np.linalg.solve(M, rows.T)
                np.testing.assert_allclose(P, M_inv_At @ np.linalg.solve(rows @ M_inv_At, rows), atol=1e-12)
        e = rng.standard_normal(system.nv)
        np.testing.assert_allclose(system.project(q, v + e)[1], v + e - velocity @ e, atol=1e-12)
    ball = cases[0][0]
    assert np.linalg.matrix_rank(ball.row_space_projectors(setup.q0)[0]) == 1  # the contact height only


def test_the_error_norm_near_a_singular_configuration_measures_what_the_tangent_map_leaves():
    """The adaptive run's error norm (``stepping.error_norm``) with a tangent map ``Π`` measures the estimates
    ``Π Σ_j e_j K_j`` (for DOP853 both of its estimates), and without one the estimates themselves: a component
    that the map removes leaves the norm, which falls."""
    from multibody.integrators import EMBEDDED
    from multibody.kernels import stepping

    rng = np.random.default_rng(0)
    n = 3
    tangent = np.diag([1.0, 1.0, 0.0])  # the third component leaves the measure
    y0, y1, atol = rng.standard_normal(n), rng.standard_normal(n), np.full(n, 1e-3)
    scratch = [np.zeros(n) for _ in range(3)]
    for name, pair in EMBEDDED.items():
        e = np.array(pair.e)
        e3 = np.zeros(e.size) if pair.e3 is None else np.array(pair.e3)
        K = rng.standard_normal((pair.stages + 1, n))
        left = K @ tangent.T
        for h in (0.1, 0.05):
            near = stepping.error_norm(K, e, e3, pair.e3 is not None, h, y0, y1, atol, 1e-6, True, tangent, *scratch)
            plain = stepping.error_norm(left, e, e3, pair.e3 is not None, h, y0, y1, atol, 1e-6, False, tangent,
                                        *scratch)
            assert near == pytest.approx(plain, rel=1e-14), name
            assert near < stepping.error_norm(K, e, e3, pair.e3 is not None, h, y0, y1, atol, 1e-6, False, tangent,
                                              *scratch), name


def test_tangent_map_removes_the_normal_parts_on_a_curved_configuration_space():
    """``_tangent_map`` on the rolling ball (a free body: its chart's velocity alignment ``T`` is not the
    identity; one row with a position level, two rolling rows): an error estimate whose ``δ`` lies along the
    position row and whose ``ẇ = T v`` has ``v`` along the rows' range (``P`` of
    ``ConstrainedSystem.row_space_projectors``) maps to zero, and a tangent one maps to itself."""
    from multibody.demos import rolling_ball_setup
    from multibody.simulation import Charts, _tangent_map

    setup = rolling_ball_setup()
    system, charts = setup.system, Charts(setup.system.system)
    rng = np.random.default_rng(5)
    q, v = system.project(setup.q0, setup.v0 + rng.standard_normal(system.nv))
    y = charts.to_chart(np.concatenate([q, v]))
    T = system.system.velocity_alignment(q)
    assert np.abs(T - np.eye(system.nv)).max() > 0.1
    position, velocity = system.row_space_projectors(q)
    e = rng.standard_normal((4, system.nv))
    normal = np.concatenate([position @ e[0], T @ velocity @ e[1]])
    tangent = np.concatenate([e[2] - position @ e[2], T @ (e[3] - velocity @ e[3])])
    mapped = np.array([normal, tangent]) @ _tangent_map(system, charts, q, 0.0, y).T
    np.testing.assert_allclose(mapped[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(mapped[1], tangent, atol=1e-12)
