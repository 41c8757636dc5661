"""The velocity-level contact solver (:mod:`multibody.kernels.complementarity`, through
:func:`multibody.contact_problem.solve`).

* One contact: sticking (``u = 0``, ``x = −G⁻¹ c`` inside the cone), sliding against the closed form of
  a point mass (the impulse on the cone's edge opposite the slip) and the same answer, rotated, after a
  rotation of the tangent plane (the cone is isotropic), separating (``x = 0``).
* A box flat on the ground from the box's own Jacobians and mass matrix (four contacts, ``G`` of rank 6
  for 12 rows): the normal impulses sum to ``m g dt`` at rest and when sliding, where the friction
  impulse is ``μ m g dt`` against the motion.
* A stack of three boxes: each interface carries the weight above it.
* Bilateral, unilateral and frictionless contact blocks against an exact enumeration of active sets.
* Pinocchio 4's ``ADMMConstraintSolver`` on the same Delassus problem (three contacts: two slide, one sticks).
* 500 random strongly coupled problems (up to 8 contacts, ``μ`` up to 1.5, ``G`` singular in most), all solved.
* The polish's damped least squares against NumPy's, and the symmetric answer it keeps from far starts.
* Warm start, NaN input, an iteration limit, an indefinite ``G``, a diverging iteration, and every status's
  message.
* (Its lowering to PTX for the CUDA target is in ``test_cuda_target.py``.)
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import multibody as mb
from multibody import contact_problem
from multibody.contact_problem import BILATERAL, CONTACT, UNILATERAL, STATUS_MESSAGES, solve
from multibody.inertia import box as box_inertia
from multibody.joints import FreeFlyer
from multibody.kernels import complementarity

TOLERANCE = 1e-12
G_EARTH = 9.81


def natural_residual(G, c, kinds, mu, x):
    """The residual of the problem at ``x`` computed here from its definition, independently of the
    kernel: per block, the distance of ``û`` from ``K*`` and ``|x·û|/‖x‖``, and how far ``x`` is from
    ``K``."""
    u = G @ x + c
    starts, _ = contact_problem.block_starts(kinds)
    worst = 0.0
    for b, (kind, i) in enumerate(zip(kinds, starts)):
        if kind == BILATERAL:
            worst = max(worst, abs(u[i]))
        elif kind == UNILATERAL:
            worst = max(worst, -u[i], -x[i] * 1e6, abs(x[i] * u[i]) / abs(x[i]) if x[i] else 0.0)
        else:
            xb, ub = x[i:i + 3], u[i:i + 3].copy()
            ub[0] += mu[b] * np.hypot(ub[1], ub[2])
            # distance from K* = {μ‖û_T‖ ≤ û_N}, sampled finely enough for the tests' magnitudes
            n, t = ub[0], np.hypot(ub[1], ub[2])
            if mu[b] * t > n:
                worst = max(worst, np.hypot(n, t) if t <= -mu[b] * n else (mu[b] * t - n) / np.hypot(1, mu[b]))
            assert np.hypot(xb[1], xb[2]) <= mu[b] * xb[0] * (1 + 1e-14) + 1e-300, "x outside the cone"
            if np.linalg.norm(xb):
                worst = max(worst, abs(xb @ ub) / np.linalg.norm(xb))
    return worst


def sticking_velocity_bound(x, mu, residual):
    """The largest ``‖u‖`` of a contact whose impulse ``x`` is strictly inside ``K_μ`` and whose natural
    residual is ``residual``: ``x·û ≥ ‖û‖ (μ x_N − ‖x_T‖)/√(1 + μ²)`` for ``û ∈ K_μ*``,
    ``|x·û| ≤ residual ‖x‖`` and ``‖u‖ ≤ (1 + μ) ‖û‖``."""
    margin = mu * x[0] - np.hypot(x[1], x[2])
    assert margin > 0.0, "the impulse is not inside the cone"
    return (1 + mu) * np.hypot(1, mu) * np.linalg.norm(x) * residual / margin


def spd(rng, n, condition=10.0):
    """A random symmetric positive definite matrix with eigenvalues in [1, condition]."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return Q @ np.diag(np.geomspace(1.0, condition, n)) @ Q.T


# ----------------------------------------------------------------------------- one contact

def test_sticking_contact_has_zero_velocity_and_impulse_inside_the_cone():
    rng = np.random.default_rng(1)
    G = spd(rng, 3)
    # the impulse that stops the contact, chosen well inside the cone, and the free velocity it cancels
    x_stick = np.array([2.0, 0.3, -0.4])
    c = -G @ x_stick
    result = solve(G, c, ["contact"], 0.8, tolerance=TOLERANCE)
    assert result.status == complementarity.CONVERGED, result.message
    np.testing.assert_allclose(result.x, x_stick, rtol=0, atol=1e-11)
    assert result.residual <= TOLERANCE
    assert natural_residual(G, c, [CONTACT], [0.8], result.x) <= 2 * TOLERANCE
    assert np.linalg.norm(result.u) <= sticking_velocity_bound(result.x, 0.8, 2 * TOLERANCE)


def test_sliding_point_mass_matches_the_closed_form_and_the_cone_is_isotropic():
    # a point mass m: G = I/m. With c_N < 0 and a slip too fast to stop, x_N = −m c_N, and the friction
    # impulse lies on the cone's edge opposite the slip, x_T = −μ x_N c_T/‖c_T‖, u_T = c_T + x_T/m.
    mass, mu = 2.0, 0.3
    G = np.eye(3) / mass
    c = np.array([-0.5, 0.4, -0.3])
    x_normal = -mass * c[0]
    slip = c[1:] / np.linalg.norm(c[1:])
    expected = np.concatenate([[x_normal], -mu * x_normal * slip])
    result = solve(G, c, ["contact"], mu, tolerance=TOLERANCE)
    assert result.status == complementarity.CONVERGED, result.message
    np.testing.assert_allclose(result.x, expected, rtol=0, atol=1e-11)
    np.testing.assert_allclose(result.u[1:], c[1:] + expected[1:] / mass, rtol=0, atol=1e-11)
    assert abs(result.u[0]) <= TOLERANCE

    # a general G (normal and tangents coupled), then the tangent plane rotated: the answer rotates with it
    rng = np.random.default_rng(2)
    G = spd(rng, 3, condition=4.0)
    c = np.array([-0.5, 1.5, -0.7])
    base = solve(G, c, ["contact"], mu, tolerance=TOLERANCE)
    assert base.status == complementarity.CONVERGED, base.message
    assert np.hypot(base.x[1], base.x[2]) == pytest.approx(mu * base.x[0], rel=1e-10)  # sliding: on the edge
    for angle in (0.3, 1.0, 2.5):
        R = np.eye(3)
        R[1:, 1:] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
        rotated = solve(R @ G @ R.T, R @ c, ["contact"], mu, tolerance=TOLERANCE)
        assert rotated.status == complementarity.CONVERGED, rotated.message
        np.testing.assert_allclose(rotated.x, R @ base.x, rtol=0, atol=1e-10)


def test_separating_contact_has_zero_impulse():
    rng = np.random.default_rng(3)
    G = spd(rng, 3)
    c = np.array([0.2, 1.0, -3.0])
    result = solve(G, c, ["contact"], 0.5, tolerance=TOLERANCE)
    assert result.status == complementarity.CONVERGED, result.message
    assert np.all(result.x == 0.0)
    np.testing.assert_array_equal(result.u, c)


def test_projection_on_the_cone_keeps_tiny_impulses_inside_it():
    # impulses whose squares underflow (a contact about to open, its impulse decayed to 1e-167 N·s)
    for scale in (1.0, 1e-160, 1e-300):
        w = scale * np.array([0.1, -1.2, -1.6])
        z = np.zeros(3)
        complementarity.project_primal(CONTACT, 0.6, w, z, 0)
        # on the cone's edge: z_N = (w_N + μ‖w_T‖)/(1 + μ²), z_T along w_T
        normal = scale * (0.1 + 0.6 * 2.0) / 1.36
        np.testing.assert_allclose(z, [normal, 0.6 * normal * -0.6, 0.6 * normal * -0.8], rtol=1e-14)
        assert np.hypot(z[1], z[2]) <= 0.6 * z[0] * (1 + 1e-15)


# ----------------------------------------------------------------------------- a box on the ground

def box_on_ground(v, mass=2.0, size=(0.4, 0.3, 0.2), dt=1e-3):
    """``G`` and ``c`` of a box of ``mass`` resting flat on the plane ``z = 0`` with body velocity ``v (6,)``
    (linear, angular), from its Jacobians at the four lowest corners (rows: normal z, then x, y) and its
    mass matrix: ``G = J M⁻¹ Jᵀ``, ``c = J (v + dt M⁻¹ (τ − h))``."""
    builder = mb.ModelBuilder("box")
    builder.add_body("box", joint=FreeFlyer(), inertia=box_inertia(mass, size))
    model = builder.build()
    q = model.neutral()
    q[2] = size[2] / 2
    v = np.asarray(v, dtype=float)
    rows = []
    for sx, sy in itertools.product((-1, 1), (-1, 1)):
        corner = np.array([sx * size[0] / 2, sy * size[1] / 2, -size[2] / 2])
        J = mb.jacobian(model, q, "box", point=corner)[:3]
        rows += [J[2], J[0], J[1]]
    J = np.array(rows)
    M = mb.mass_matrix(model, q)
    v_free = v + dt * mb.forward_dynamics(model, q, v, np.zeros(model.nv))
    return J @ np.linalg.solve(M, J.T), J @ v_free, mass * G_EARTH * dt


def test_box_flat_on_the_ground_carries_its_weight_with_a_singular_delassus_matrix():
    G, c, weight = box_on_ground(np.zeros(6))
    assert np.linalg.matrix_rank(G, tol=1e-9) == 6
    result = solve(G, c, ["contact"] * 4, 0.5, tolerance=TOLERANCE)
    assert result.status == complementarity.CONVERGED, result.message
    assert result.residual <= TOLERANCE
    assert natural_residual(G, c, [CONTACT] * 4, [0.5] * 4, result.x) <= 2 * TOLERANCE
    assert result.x[0::3].sum() == pytest.approx(weight, rel=1e-10)
    for k in range(4):  # sticking: the box stays still
        assert np.linalg.norm(result.u[3 * k : 3 * k + 3]) <= sticking_velocity_bound(result.x[3 * k : 3 * k + 3], 0.5,
                                                                                     2 * TOLERANCE)
    # from x = 0 the symmetric problem gets the symmetric distribution
    np.testing.assert_allclose(result.x[0::3], weight / 4, rtol=1e-9)


def test_box_sliding_on_the_ground_is_braked_by_mu_m_g_dt_against_its_motion():
    mu = 0.4
    direction = np.array([0.6, 0.8, 0.0])
    G, c, weight = box_on_ground(np.concatenate([1.5 * direction, np.zeros(3)]))
    result = solve(G, c, ["contact"] * 4, mu, tolerance=TOLERANCE, max_iterations=5000)
    assert result.status == complementarity.CONVERGED, result.message
    assert result.residual <= TOLERANCE
    # the Newton polish takes ADMM's iterate to the tolerance once the four corners are found sliding
    # (ADMM alone needs hundreds of iterations for 1e-12 m/s here)
    assert result.iterations <= 20
    assert result.x[0::3].sum() == pytest.approx(weight, rel=1e-10)
    friction = np.array([result.x[1::3].sum(), result.x[2::3].sum()])
    np.testing.assert_allclose(friction, -mu * weight * direction[:2], rtol=1e-9)


def test_stack_of_boxes_carries_the_weight_above_each_interface():
    # three boxes of 2, 1 and 0.5 kg stacked on the ground, four corner contacts per interface, from the
    # Jacobians of the corners (relative ones between boxes) and the mass matrix: G (36, 36) of rank 18
    masses, size, dt = (2.0, 1.0, 0.5), (0.4, 0.3, 0.2), 1e-3
    builder = mb.ModelBuilder("stack")
    for k, mass in enumerate(masses):
        builder.add_body(f"box{k}", joint=FreeFlyer(), inertia=box_inertia(mass, size))
    model = builder.build()
    q = model.neutral()
    for k in range(3):
        q[7 * k + 2] = (k + 0.5) * size[2]
    rows = []
    for k in range(3):
        for sx, sy in itertools.product((-1, 1), (-1, 1)):
            corner = np.array([sx * size[0] / 2, sy * size[1] / 2, -size[2] / 2])
            J = mb.jacobian(model, q, f"box{k}", point=corner)[:3]
            if k > 0:  # the velocity relative to the same point of the box below
                J = J - mb.jacobian(model, q, f"box{k - 1}", point=corner + [0.0, 0.0, size[2]])[:3]
            rows += [J[2], J[0], J[1]]
    J = np.array(rows)
    v = np.zeros(model.nv)
    G = J @ np.linalg.solve(mb.mass_matrix(model, q), J.T)
    c = J @ (v + dt * mb.forward_dynamics(model, q, v, np.zeros(model.nv)))
    assert np.linalg.matrix_rank(G, tol=1e-9) == 18
    result = solve(G, c, ["contact"] * 12, 0.5, tolerance=TOLERANCE)
    assert result.status == complementarity.CONVERGED, result.message
    assert result.residual <= TOLERANCE
    for k in range(3):
        above = sum(masses[k:]) * G_EARTH * dt
        assert result.x[12 * k : 12 * k + 12 : 3].sum() == pytest.approx(above, rel=1e-10)
        np.testing.assert_allclose(result.x[12 * k : 12 * k + 12 : 3], above / 4, rtol=1e-9)


# ----------------------------------------------------------------------------- mixed blocks

def enumerate_frictionless(G, c, kinds):
    """The solution of the frictionless problem (contact blocks with μ = 0) by trying every active set of
    its sign-constrained rows: a row is either free (bilateral, or active: ``u = 0``) or ``x = 0``; the
    set whose solution has ``x ≥ 0`` and ``u ≥ 0`` where required. Contact tangents carry no impulse."""
    starts, m = contact_problem.block_starts(kinds)
    signed, fixed_zero, free = [], [], []
    for kind, i in zip(kinds, starts):
        if kind == BILATERAL:
            free.append(i)
        elif kind == UNILATERAL:
            signed.append(i)
        else:
            signed.append(i)
            fixed_zero += [i + 1, i + 2]
    for active in itertools.product((False, True), repeat=len(signed)):
        rows = free + [i for i, a in zip(signed, active) if a]
        x = np.zeros(m)
        if rows:
            x[rows] = np.linalg.solve(G[np.ix_(rows, rows)], -c[rows])
        u = G @ x + c
        if all(x[i] >= -1e-12 and u[i] >= -1e-12 for i in signed):
            return x
    raise AssertionError("no active set solves the problem")


def test_bilateral_unilateral_and_frictionless_contact_blocks_match_an_enumeration_of_active_sets():
    rng = np.random.default_rng(4)
    kinds = [BILATERAL, CONTACT, UNILATERAL, BILATERAL, CONTACT, UNILATERAL, UNILATERAL]
    m = 11
    for trial in range(6):
        J = rng.standard_normal((m, 14))
        G = J @ np.linalg.solve(spd(rng, 14, 100.0), J.T)
        c = rng.standard_normal(m)
        expected = enumerate_frictionless(G, c, kinds)
        result = solve(G, c, kinds, 0.0, tolerance=TOLERANCE, max_iterations=20000)
        assert result.status == complementarity.CONVERGED, (trial, result.message, result.residual)
        np.testing.assert_allclose(result.x, expected, rtol=0, atol=1e-9 * max(1.0, np.max(np.abs(expected))))
        assert natural_residual(G, c, kinds, np.zeros(len(kinds)), result.x) <= 2 * TOLERANCE


def test_bilateral_unilateral_and_frictional_contact_blocks_meet_their_conditions():
    # a physical problem (c = J v) with every kind of block: the conditions checked here from their
    # definition, and the bilateral rows' velocities zero
    rng = np.random.default_rng(7)
    kinds = [CONTACT, BILATERAL, UNILATERAL, CONTACT, BILATERAL, CONTACT, UNILATERAL]
    mus = [0.6, 0.0, 0.0, 0.3, 0.0, 0.9, 0.0]
    m = 13
    for trial in range(5):
        J = rng.standard_normal((m, 18))
        G = J @ np.linalg.solve(spd(rng, 18, 50.0), J.T)
        c = J @ rng.standard_normal(18)
        result = solve(G, c, kinds, mus, tolerance=TOLERANCE)
        assert result.status == complementarity.CONVERGED, (trial, result.message, result.residual)
        assert natural_residual(G, c, kinds, mus, result.x) <= 2 * TOLERANCE
        assert np.max(np.abs(result.u[[3, 8]])) <= TOLERANCE
        np.testing.assert_allclose(result.u, G @ result.x + c, rtol=0, atol=1e-14 * np.max(np.abs(c)) * m)


# ----------------------------------------------------------------------------- random problems

def random_problem(rng, mu_max=1.5, max_contacts=8):
    """A random contact problem with a solution: ``G = J M⁻¹ Jᵀ`` for ``n`` coordinates (``n`` below the
    ``3 k`` rows of ``k`` contacts in most: ``G`` singular), rows strongly coupled (sharing a common part),
    ``c = J v`` and friction up to ``mu_max``. Each contact's tangent rows are orthogonal to a velocity
    ``v*`` that opens every contact (``J_N v* > 0``): ``J v*`` is inside ``K_μ*``, the condition of Acary,
    Cadoux, Lemaréchal & Malick (*C. R. Math.* 349, 2011) for a solution to exist."""
    contacts = int(rng.integers(1, max_contacts + 1))
    m = 3 * contacts
    n = int(rng.integers(3, m + 4))
    A = rng.standard_normal((n, n))
    M = A @ A.T + 0.05 * n * np.eye(n)
    J = rng.standard_normal((m, n)) + rng.uniform(0, 3) * rng.standard_normal(n)
    opening = rng.standard_normal(n)
    for k in range(contacts):
        for t in (1, 2):
            J[3 * k + t] -= (J[3 * k + t] @ opening) / (opening @ opening) * opening
        if J[3 * k] @ opening < 0:
            J[3 * k] *= -1
        J[3 * k] += 0.1 * opening / np.linalg.norm(opening)
    G = J @ np.linalg.solve(M, J.T)
    G = (G + G.T) / 2
    return G, J @ (3 * rng.standard_normal(n)), rng.uniform(0, mu_max, contacts)


def test_random_strongly_coupled_problems_are_all_solved():
    rng = np.random.default_rng(39)
    singular = large_friction = 0
    for trial in range(500):
        G, c, mus = random_problem(rng)
        kinds = [CONTACT] * len(mus)
        result = solve(G, c, kinds, mus, tolerance=TOLERANCE, max_iterations=20000)
        assert result.status == complementarity.CONVERGED, (trial, result.message, result.residual)
        assert natural_residual(G, c, kinds, mus, result.x) <= 2 * TOLERANCE
        singular += np.linalg.matrix_rank(G) < len(c)
        large_friction += mus.max() > 1.0
    assert singular > 200 and large_friction > 200


def test_damped_least_squares_equals_numpy_on_a_singular_jacobian():
    rng = np.random.default_rng(11)
    m, damping = 6, 1e-7
    J = rng.standard_normal((m, 3)) @ rng.standard_normal((3, m))  # rank 3
    # b in the range of J: the least-squares residual is small, and the answer conditioned by cond(A) ~ 3e4
    # rather than its square
    b = J @ rng.standard_normal(m)
    B = np.zeros((m + 1, 2 * m))
    B[:m, :m], B[:m, m:], B[m, :m] = J.T, np.sqrt(damping) * np.eye(m), b
    complementarity.damped_least_squares(B, m)
    expected = np.linalg.lstsq(np.vstack([J, np.sqrt(damping) * np.eye(m)]), np.r_[b, np.zeros(m)], rcond=None)[0]
    np.testing.assert_allclose(B[m, :m], expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_polish_from_far_keeps_the_symmetric_distribution_of_a_box():
    # Newton steps of the length of the impulses themselves along a singular G: the rounding they leave on the
    # null space (the corners' impulses ½(−1, 1, 1, −1)) stays at the rounding of the impulses
    G, c, weight = box_on_ground(np.zeros(6))
    starts, m = contact_problem.block_starts([CONTACT] * 4)
    kinds, mus = np.full(4, CONTACT), np.full(4, 0.5)
    largest = np.linalg.eigvalsh(G).max()
    for distance in (1.0, 100.0):
        x = np.zeros(m)
        x[0::3] = (1 + distance) * weight / 4
        scratch = [np.zeros(m) for _ in range(6)] + [np.zeros((m, m)), np.zeros((m + 1, 2 * m))]
        _, residual = complementarity.polish(G, c, kinds, starts, mus, 1 / largest, 50, TOLERANCE, x, *scratch)
        assert residual <= TOLERANCE
        np.testing.assert_allclose(scratch[5][0::3], weight / 4, rtol=1e-11)


# ----------------------------------------------------------------------------- Pinocchio

def test_impulses_equal_pinocchio_admm_on_the_same_delassus_problem(pin):
    # three contacts on a 12-dof system: G positive definite, a unique solution
    rng = np.random.default_rng(10)
    contacts, mus = 3, [0.3, 0.5, 0.2]
    J = rng.standard_normal((3 * contacts, 12))
    G = J @ np.linalg.solve(spd(rng, 12, 20.0), J.T)
    c = J @ (-J[0::3].T @ np.ones(contacts) + 2.0 * rng.standard_normal(12))
    ours = solve(G, c, ["contact"] * contacts, mus, tolerance=TOLERANCE)
    assert ours.status == complementarity.CONVERGED, ours.message
    # Pinocchio's cone is ‖λ_T‖ ≤ μ λ_z in the rows (t1, t2, n) of each contact
    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "body")
    model.appendBodyToJoint(joint, pin.Inertia.FromBox(2.0, 0.4, 0.3, 0.2), pin.SE3.Identity())
    models, datas = pin.StdVec_ConstraintModel(), pin.StdVec_ConstraintData()
    for mu in mus:
        contact = pin.PointContactConstraintModel(model, joint)
        contact.setFriction(mu)
        models.append(pin.ConstraintModel(contact))
        datas.append(models[-1].createData())
    order = np.concatenate([[3 * k + 1, 3 * k + 2, 3 * k] for k in range(contacts)])
    settings = pin.ADMMSolverSettings()
    settings.max_iterations = 10000
    settings.mu_prox = 1e-9
    settings.absolute_feasibility_tol = settings.absolute_complementarity_tol = TOLERANCE
    settings.relative_feasibility_tol = settings.relative_complementarity_tol = 1e-14
    assert settings.solve_ncp  # De Saxcé's problem, not its convex relaxation
    result = pin.ADMMSolverResult()
    assert pin.ADMMConstraintSolver(3 * contacts).solve(pin.DelassusOperatorDense(G[np.ix_(order, order)]), c[order],
                                                        models, datas, settings, result)
    theirs = np.asarray(result.retrieveConstraintImpulses())
    # the first and last contacts slide (impulses on the cones' edges), the middle one sticks
    for k in range(contacts):
        x = ours.x[3 * k : 3 * k + 3]
        assert x[0] > 1.0
        assert (np.hypot(x[1], x[2]) == pytest.approx(mus[k] * x[0], rel=1e-10)) == (k != 1)
    np.testing.assert_allclose(ours.x[order], theirs, rtol=0, atol=1e-10)


# ----------------------------------------------------------------------------- warm start and statuses

def test_warm_start_reduces_iterations():
    v = np.array([1.0, 0.5, 0.0, 0.0, 0.0, 0.3])
    G, c, _ = box_on_ground(v)
    cold = solve(G, c, ["contact"] * 4, 0.3, tolerance=TOLERANCE, max_iterations=5000)
    assert cold.status == complementarity.CONVERGED, cold.message
    # a nearby problem (the next step's: the box a little slower) from the previous solution
    _, c_next, _ = box_on_ground(0.99 * v)
    cold_next = solve(G, c_next, ["contact"] * 4, 0.3, tolerance=TOLERANCE, max_iterations=5000)
    warm_next = solve(G, c_next, ["contact"] * 4, 0.3, tolerance=TOLERANCE, max_iterations=5000, warm_start=cold.x)
    assert cold_next.status == warm_next.status == complementarity.CONVERGED, warm_next.message
    assert warm_next.iterations < cold_next.iterations
    # the solution itself as the warm start: no iteration
    again = solve(G, c, ["contact"] * 4, 0.3, tolerance=10 * TOLERANCE, warm_start=cold.x)
    assert again.status == complementarity.CONVERGED and again.iterations == 0


def diverging():
    """A problem whose iterates overflow with every penalty: a free velocity of 1e307 m/s, which the first
    projection scales by ``1/ρ`` (``ρ`` at most about ``0.05 λ_max``) past the largest float."""
    return solve(np.eye(3), np.array([-1e307, 0.0, 0.0]), ["contact"], 0.3)


def test_an_iteration_that_overflows_is_reported_diverged_with_the_last_finite_iterate():
    result = diverging()
    assert result.status == complementarity.DIVERGED
    assert "diverged" in result.message
    # every run (one per penalty) overflowed at its first iteration; the warm start is the best iterate found
    assert result.iterations == complementarity.PENALTIES
    np.testing.assert_array_equal(result.x, np.zeros(3))
    np.testing.assert_array_equal(result.u, [-1e307, 0.0, 0.0])
    assert result.residual == 1e307


def test_every_status_is_reached_and_has_its_message():
    G, c, _ = box_on_ground(np.array([1.0, 0.5, 0.0, 0.0, 0.0, 0.3]))
    reached = {}
    result = solve(G, c, ["contact"] * 4, 0.3, tolerance=TOLERANCE, max_iterations=5000)
    reached[result.status] = result
    result = solve(G, c, ["contact"] * 4, 0.3, tolerance=TOLERANCE, max_iterations=1)
    assert result.status == complementarity.MAX_ITERATIONS and result.iterations == 1
    assert result.residual > TOLERANCE
    reached[result.status] = result
    for bad in ("G", "c"):
        G_bad, c_bad = G.copy(), c.copy()
        if bad == "G":
            G_bad[1, 1] = np.nan
        else:
            c_bad[4] = np.inf
        result = solve(G_bad, c_bad, ["contact"] * 4, 0.3)
        assert result.status == complementarity.NOT_FINITE, bad
        assert np.all(np.isnan(result.x)) and np.isnan(result.residual)
        reached[result.status] = result
    result = solve(-np.eye(3), np.array([-1.0, 0.0, 0.0]), ["contact"], 0.3)
    assert result.status == complementarity.INDEFINITE
    reached[result.status] = result
    result = diverging()
    assert result.status == complementarity.DIVERGED
    reached[result.status] = result
    assert set(reached) == set(STATUS_MESSAGES)
    for status, result in reached.items():
        assert result.message == STATUS_MESSAGES[status]


def test_bad_input_gets_a_message_naming_the_argument():
    G, c = np.eye(3), np.array([-1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"mu\[0\] must be ≥ 0"):
        solve(G, c, ["contact"], -0.1)
    with pytest.raises(ValueError, match=r"G must have shape \(3, 3\)"):
        solve(np.eye(2), c, ["contact"], 0.5)
    with pytest.raises(ValueError, match=r"c must have shape \(3,\)"):
        solve(G, c[:2], ["contact"], 0.5)
    with pytest.raises(ValueError, match=r"kinds\[1\] must be"):
        solve(np.eye(4), np.zeros(4), ["contact", "sliding"], 0.5)
    with pytest.raises(ValueError, match=r"mu must be a number or have shape \(1,\)"):
        solve(G, c, ["contact"], [0.5, 0.5])
    with pytest.raises(ValueError, match="warm_start must have shape"):
        solve(G, c, ["contact"], 0.5, warm_start=np.zeros(2))
    with pytest.raises(ValueError, match="tolerance must be a positive number"):
        solve(G, c, ["contact"], 0.5, tolerance=0.0)
    with pytest.raises(ValueError, match="max_iterations must be an integer"):
        solve(G, c, ["contact"], 0.5, max_iterations=0)
    with pytest.raises(ValueError, match="G must be symmetric"):
        solve(np.triu(np.ones((3, 3))), c, ["contact"], 0.5)
