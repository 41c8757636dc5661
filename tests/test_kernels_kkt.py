"""The one constrained solve (multibody.kernels.kkt) on the compiled constraint program's rows against the same
solve on the rows the constraints evaluate in Python, passed as arrays.

The Python rows are reached by withholding the compiled step from a system; for the built-in constraints they are
the same rows (each constraint's own compiled evaluation), ``M`` and ``h`` the same compiled passes, so both paths
give the same accelerations and multipliers to 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.constrained import STATUS_ERRORS
from multibody.kernels import kkt
from multibody.spatial import pose_from_xyz_rpy

from constraint_helpers import assert_close, four_bar


def python_rows_solution(system, q, v, tau=None):
    system.__dict__["_compiled_step"] = None  # the cached property, withheld
    try:
        return system.solve(q, v, tau)
    finally:
        del system.__dict__["_compiled_step"]


def compare(system, q, v, tau=None, tol=1e-12):
    """The compiled program's solution and that of the rows evaluated in Python agree to ``tol`` relative."""
    assert system._compiled_step is not None
    fast, slow = system.solve(q, v, tau), python_rows_solution(system, q, v, tau)
    assert np.array_equal(fast.A, slow.A) and fast.rank == slow.rank
    scale = max(1.0, np.abs(slow.a).max(), np.abs(slow.lam).max())
    assert_close(fast.a, slow.a, tol, scale=scale, what="a")
    assert_close(fast.lam, slow.lam, tol, scale=scale, what="λ")
    assert_close(fast.gamma, slow.gamma, tol, scale=max(1.0, np.abs(slow.gamma).max()), what="γ")
    return fast


def ball():
    return mb.load_urdf(mb.robots.path("ball"), floating_base=True)


TILTED = (np.sin(0.1), 0.0, np.cos(0.1))
BALL_CONSTRAINTS = {
    "sphere": lambda: [mb.RollingSphere("ball", 0.1, plane_normal=TILTED, plane_point=(0.0, 0.0, -0.2))],
    "sphere without normal row": lambda: [mb.RollingSphere("ball", 0.1, normal=False)],
    "disc": lambda: [mb.RollingDisc("ball", 0.1, axis=(0.3, 1.0, 0.2), plane_normal=TILTED)],
    "knife edge": lambda: [mb.KnifeEdge("ball", point=(0.0, 0.05, 0.0), direction=(1.0, 0.2, 0.0))],
    "distance": lambda: [mb.Distance("ball", None, 0.5, point_a=(0.1, 0.0, 0.0), point_b=(0.2, 0.3, 0.4))],
    "sphere and knife edge": lambda: [mb.RollingSphere("ball", 0.1), mb.KnifeEdge("ball")],
}


@pytest.mark.parametrize("baumgarte", [None, (3.0, 4.0)], ids=["plain", "baumgarte"])
@pytest.mark.parametrize("name", list(BALL_CONSTRAINTS))
def test_compiled_step_matches_python_rows_on_a_free_body(name, baumgarte):
    model = ball()
    system = mb.ConstrainedSystem(model, BALL_CONSTRAINTS[name](), baumgarte=baumgarte)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, v, tau = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        compare(system, q, v, tau)
    compare(system, q, v)  # no joint forces


@pytest.mark.parametrize("kind", ["point", "planar", "revolute", "weld"])
def test_compiled_loop_closures_match_python_rows(kind):
    model = mb.robots.load("double_pendulum") if kind == "planar" else mb.load_urdf(mb.robots.path("ball"),
                                                                                        floating_base=True)
    rng = np.random.default_rng(7)
    body = model.body_names[-1]
    constraint = mb.LoopClosure(body, None, frame_a=pose_from_xyz_rpy([0.05, 0.02, 0.1], [0.1, 0.2, 0.3]),
                                frame_b=pose_from_xyz_rpy([0.3, -0.1, 0.2], [0.3, -0.2, 0.1]), kind=kind)
    system = mb.ConstrainedSystem(model, [constraint], baumgarte=2.0)
    for _ in range(4):
        compare(system, model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv))


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the redundancy, below)
def test_redundant_rows_give_the_minimum_norm_multipliers():
    """The planar four-bar closed by a point constraint: the out-of-plane row is redundant (rank 2 of 3)."""
    model, tip, pivot = four_bar()
    system = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=pose_from_xyz_rpy(pivot), frame_b=tip)])
    rng = np.random.default_rng(11)
    q, v = system.project(np.array([0.9, -0.9, -0.8]), rng.standard_normal(model.nv))
    solution = compare(system, q, v)
    assert solution.rank < system.num_rows
    # the minimum-norm multipliers: λ = G⁺ (γ − A a_free), G = A M⁻¹ Aᵀ, by LAPACK's pseudo-inverse; λ has no part
    # in the kernel of Aᵀ (the redundant direction), which moves no body
    M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
    A = solution.A
    M_inv_At = np.linalg.solve(M, A.T)
    expected = np.linalg.pinv(A @ M_inv_At, rcond=1e-10) @ (solution.gamma + A @ np.linalg.solve(M, h))
    assert_close(solution.lam, expected, 1e-10, scale=np.abs(expected).max(), what="minimum-norm λ")
    _, singular_values, Vt = np.linalg.svd(A.T)
    kernel = Vt[np.sum(singular_values > 1e-10 * singular_values[0]) :]
    assert kernel.shape[0] == system.num_rows - solution.rank
    assert_close(kernel @ solution.lam, np.zeros(len(kernel)), 1e-12, scale=np.abs(solution.lam).max(),
                 what="λ along the kernel of Aᵀ")


def test_joint_coupling_is_compiled():
    model = mb.robots.load("double_pendulum")
    system = mb.ConstrainedSystem(model, [mb.JointCoupling(model.joint_names[0], model.joint_names[1], 2.0, 0.1)])
    rng = np.random.default_rng(2)
    solution = compare(system, rng.standard_normal(2), rng.standard_normal(2), rng.standard_normal(2))
    assert_close(solution.a[1], 2.0 * solution.a[0], 1e-12, scale=1.0, what="coupled accelerations")


def test_a_user_constraint_is_solved_as_the_same_compiled_rows():
    """A user's Python constraint (``Holonomic``) with the rows of a ``JointCoupling`` (``q₁ = 2 q₀ + 0.1``): its
    rows, evaluated in Python and passed as arrays, and the coupling's compiled program go through the same
    compiled solve, to the same accelerations and multipliers to 1e-12, also with Baumgarte terms and
    redundant (a second coupling)."""
    model = mb.robots.load("double_pendulum")
    coupling = mb.JointCoupling(model.joint_names[0], model.joint_names[1], 2.0, 0.1)
    user = mb.Holonomic(lambda q, t: np.array([q[1] - 2.0 * q[0] - 0.1]),
                        jacobian=lambda q, t: np.array([[-2.0, 1.0]]), name="user gear")
    rng = np.random.default_rng(21)
    for baumgarte in (None, (2.0, 3.0)):
        compiled = mb.ConstrainedSystem(model, [coupling], baumgarte=baumgarte)
        python = mb.ConstrainedSystem(model, [user], baumgarte=baumgarte)
        redundant = mb.ConstrainedSystem(model, [coupling, user], baumgarte=baumgarte)
        assert compiled._compiled_step is not None and python._compiled_step is None
        for _ in range(3):
            q, v, tau = rng.standard_normal(2), rng.standard_normal(2), rng.standard_normal(2)
            fast, slow, both = compiled.solve(q, v, tau), python.solve(q, v, tau), redundant.solve(q, v, tau)
            scale = max(1.0, np.abs(fast.a).max(), np.abs(fast.lam).max())
            assert_close(slow.a, fast.a, 1e-12, scale=scale, what="a")
            assert_close(slow.lam, fast.lam, 1e-12, scale=scale, what="λ")
            assert both.rank == 1
            assert_close(both.a, fast.a, 1e-12, scale=scale, what="a, redundant")
            # the minimum-norm multipliers share the force equally between the two equal rows
            assert_close(both.lam, np.full(2, fast.lam[0] / 2.0), 1e-12, scale=scale, what="λ, redundant")


@pytest.mark.parametrize("rows", ["program", "python"])
def test_batch_equals_single_states(rows):
    """A batch is solved state by state, on the program's rows and on rows evaluated in Python (one call of the
    compiled solve for the whole batch): each state as alone, and the two kinds of rows alike to 1e-12."""
    model = ball()
    system = mb.ConstrainedSystem(model, BALL_CONSTRAINTS["sphere"](), baumgarte=1.0)
    assert system.batched
    rng = np.random.default_rng(5)
    q = np.stack([model.random_configuration(rng) for _ in range(4)])
    v, tau = rng.standard_normal((4, model.nv)), rng.standard_normal(model.nv)
    program = system.solve(q, v, tau)
    if rows == "python":
        system.__dict__["_compiled_step"] = None  # the cached property, withheld
    batch = system.solve(q, v, tau)
    for k in range(4):
        single = system.solve(q[k], v[k], tau)
        assert np.array_equal(batch.a[k], single.a) and np.array_equal(batch.lam[k], single.lam)
        assert batch.rank[k] == single.rank == program.rank[k]
    scale = max(1.0, np.abs(program.a).max(), np.abs(program.lam).max())
    assert_close(batch.a, program.a, 1e-12, scale=scale, what="a")
    assert_close(batch.lam, program.lam, 1e-12, scale=scale, what="λ")


def test_steps_the_compiled_solve_cannot_take_raise_the_errors_of_their_status():
    model = ball()
    q = model.neutral()
    q[:3] = (0.5, 0.0, 0.0)
    v = np.array([0.0, 0.3, 0.0, 0.0, 0.0, 1.0])
    # the same rod twice: redundant but consistent, one row counts
    twice = mb.ConstrainedSystem(model, [mb.Distance("ball", None, 0.5), mb.Distance("ball", None, 0.5)])
    assert compare(twice, q, v).rank == 1
    # rods of different lengths on the same point: Baumgarte's −β² φ asks for two accelerations at once
    different = mb.ConstrainedSystem(model, [mb.Distance("ball", None, 0.5), mb.Distance("ball", None, 0.6)],
                                     baumgarte=(0.0, 1.0))
    with pytest.raises(mb.ConstraintError, match="inconsistent"):
        different.solve(q, v)
    # a disc lying flat has no contact direction
    flat = mb.ConstrainedSystem(model, [mb.RollingDisc("ball", 0.1, axis=(0.0, 0.0, 1.0))])
    with pytest.raises(ValueError, match="lies flat"):
        flat.solve(model.neutral(), np.zeros(model.nv))
    # an indefinite mass matrix
    massless = mb.ModelBuilder("ghost")
    massless.add_body("p", mb.joints.Translation())
    ghost = massless.build(check_inertia=False)
    with pytest.raises(mb.ConstraintError, match="positive definite"):
        mb.ConstrainedSystem(ghost, [mb.Distance("p", None, 1.0)]).solve(np.array([1.0, 0.0, 0.0]), np.zeros(3))


def test_non_finite_input_gives_nan_with_a_warning():
    model = ball()
    system = mb.ConstrainedSystem(model, BALL_CONSTRAINTS["sphere"]())
    v = np.zeros(model.nv)
    v[0] = np.nan
    with pytest.warns(RuntimeWarning, match="NaN"):
        solution = system.solve(model.neutral(), v)
    assert np.isnan(solution.a).all()


def test_row_orthogonalization_and_cholesky_agree_with_lapack():
    rng = np.random.default_rng(0)
    for m, n in ((1, 3), (2, 5), (5, 7), (12, 14), (6, 4)):
        B = rng.standard_normal((m, n))
        U, sigma = np.empty((m, m)), np.empty(m)
        work = B.copy()
        kkt.orthogonalize_rows(work, U, sigma, m)
        assert_close(U @ np.diag(sigma**2) @ U.T, B @ B.T, 1e-13, scale=np.abs(B @ B.T).max(), what="U diag(σ²) Uᵀ")
        assert_close(U.T @ U, np.eye(m), 1e-13, scale=1.0, what="UᵀU")
        expected = np.zeros(m)
        expected[: min(m, n)] = np.linalg.svd(B, compute_uv=False)
        assert_close(np.sort(sigma)[::-1], expected, 1e-13, scale=expected.max(), what="singular values")
    for m in (1, 2, 5, 12):
        X = rng.standard_normal((m, m + 2))
        G = X @ X.T
        L = G.copy()
        assert kkt.cholesky(L, m)
        x = rng.standard_normal(m)
        solved = x.copy()
        kkt.cholesky_solve(L, m, solved)
        assert_close(G @ solved, x, 1e-10, scale=np.abs(x).max(), what="M⁻¹ x")
    assert not kkt.cholesky(-np.eye(3), 3)



def graded(rng, m, n, smallest):
    """A random ``(m, n)`` matrix whose rows are scaled from 1 down to ``smallest`` (the grading of a
    closed chain's rows near a singular configuration), with its rows shuffled."""
    return (np.geomspace(1.0, smallest, m)[:, None] * rng.standard_normal((m, n)))[rng.permutation(m)]


def test_pivoted_lq_factors_the_metric_gram_matrix():
    """``Π B = L Q``: ``L Lᵀ = Π B Bᵀ Πᵀ`` with ``L`` lower triangular, its diagonal non-increasing in size
    (the pivoting), and ``|L|`` has ``B``'s singular values."""
    rng = np.random.default_rng(1)
    for m, n, smallest in ((1, 3, 1.0), (3, 5, 1e-3), (12, 14, 1e-8), (6, 6, 1.0)):
        B = graded(rng, m, n, smallest)
        work, order, norms = B.copy(), np.empty(m), np.empty(m)
        kkt.pivoted_lq(work, m, n, order, norms)
        L = np.tril(work[:, :m])
        P = B[order.astype(int)]
        assert_close(L @ L.T, P @ P.T, 1e-14, scale=np.abs(B @ B.T).max(), what="L Lᵀ")
        assert np.all(np.diff(np.abs(np.diag(L))) <= 1e-15)
        assert_close(np.linalg.svd(L, compute_uv=False), np.linalg.svd(B, compute_uv=False), 1e-13, scale=1.0,
                     what="singular values")


@pytest.mark.parametrize("smallest, full", [(1e-3, True), (1e-8, True), (1e-11, False), (0.0, False)])
def test_full_rank_certified_by_the_lq_factor_and_solved_as_by_rotations(smallest, full):
    """:func:`kkt.metric_solve` solves by the LQ factor only where ``1/‖L⁻¹‖_F > rank_tolerance ‖L‖_F``
    proves that every singular value counts (rank tolerance 1e-10; rows graded down to ``smallest``, a
    zero row at 0); there its multipliers equal the rotations' minimum-norm ones to rounding, whatever the
    grading (both factorisations resolve graded rows to relative accuracy), and elsewhere it is the
    rotations' solve. The conditioning it returns is the smallest singular value above rounding over the
    largest (the rows graded to 1e-11 count, the zero row does not) after rotations, and after the LQ
    factor a lower bound on it within a factor ``m``."""
    rng = np.random.default_rng(2)
    m, n = 12, 14
    B = graded(rng, m, n, smallest if smallest else 1e-3)
    if not smallest:
        B[3] = 0.0
    rhs = B @ rng.standard_normal(n)  # consistent, as the step's right-hand side at a state on the constraints
    W, Y, scratch, V, sigma = np.empty((m, n)), np.empty((m, n)), np.empty((m, n)), np.empty((m, m)), np.empty(m)
    coefficients, magnitudes, lam, order, norms = (np.empty(m) for _ in range(5))
    rank, every_row, conditioning = kkt.metric_solve(np.eye(n), B, W, Y, scratch, V, sigma, rhs, 1e-10, m, n,
                                                     coefficients, magnitudes, lam, order, norms)  # M = I
    singular_values = np.linalg.svd(B, compute_uv=False)
    above_rounding = singular_values[singular_values > m * 2.0**-52 * singular_values[0]]
    ratio = above_rounding[-1] / above_rounding[0]
    if full:
        assert ratio / m <= conditioning <= ratio
    else:
        assert_close(conditioning, ratio, 1e-8, scale=ratio, what="conditioning")
    assert np.array_equal(Y, B)
    assert every_row == full
    work, U, s = B.copy(), np.empty((m, m)), np.empty(m)
    kkt.orthogonalize_rows(work, U, s, m)
    expected = np.empty(m)
    expected_rank = kkt.minimum_norm(U, s, rhs, 1e-10, m, np.empty(m), np.empty(m), expected)
    assert rank == expected_rank and (rank == m) == full
    assert_close(lam, expected, 1e-12, scale=np.abs(expected).max(), what="λ")


# ----------------------------------------------------------------------------- projection

def python_rows_projection(system, q, v, **options):
    system.__dict__["_compiled_step"] = None  # the cached property, withheld
    try:
        return system.project(q, v, **options)
    finally:
        del system.__dict__["_compiled_step"]


def projection_systems():
    """Systems whose projection moves both positions and velocities: a ball on a tilted plane (one row
    with a position level beside two without), a four-bar closed by a point (redundant), and a loop
    closure on a floating body (its rows all with position levels, the free flyer's group steps)."""
    model, tip, pivot = four_bar()
    floating = ball()
    return {
        "ball": (floating, mb.ConstrainedSystem(floating, BALL_CONSTRAINTS["sphere"]())),
        "four-bar": (model, mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=pose_from_xyz_rpy(pivot),
                                                                        frame_b=tip)])),
        "weld": (floating, mb.ConstrainedSystem(floating, [mb.LoopClosure(
            "ball", None, frame_b=pose_from_xyz_rpy([0.3, -0.1, 0.2], [0.3, -0.2, 0.1]), kind="weld")])),
    }


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the four-bar's redundant row)
@pytest.mark.parametrize("name", ["ball", "four-bar", "weld"])
def test_compiled_projection_matches_python_rows(name):
    """The compiled projection (one kernel call: the Gauss–Newton steps and the velocity projection)
    gives the state of the same corrections on rows evaluated in Python to rounding, on the constraints, for one
    state and for a batch."""
    model, system = projection_systems()[name]
    rng = np.random.default_rng(4)
    q = np.stack([model.integrate(model.neutral() if name != "four-bar" else np.array([0.9, -0.9, -0.8]),
                                  0.2 * rng.standard_normal(model.nv)) for _ in range(3)])
    v = rng.standard_normal((3, model.nv))
    q_batch, v_batch = system.project(q, v)
    for k in range(3):
        fast, slow = system.project(q[k], v[k]), python_rows_projection(system, q[k], v[k])
        assert np.abs(fast[0] - q[k]).max() > 1e-3  # the positions moved
        assert_close(fast[0], slow[0], 1e-12, scale=1.0, what="q")
        assert_close(fast[1], slow[1], 1e-12, scale=max(1.0, np.abs(slow[1]).max()), what="v")
        assert np.array_equal(q_batch[k], fast[0]) and np.array_equal(v_batch[k], fast[1])
        assert system.residual(*fast) <= 1e-12


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the four-bar's redundant row)
def test_compiled_projection_that_does_not_converge_raises():
    model, system = projection_systems()["four-bar"]
    q = np.array([0.3, -0.2, 0.4])  # far from the loop: more than one Gauss–Newton step
    with pytest.raises(mb.ConstraintError, match=r"did not converge: \|φ\| = .* after 1 iterations"):
        system.project(q, np.zeros(3), max_iterations=1)
    with pytest.raises(mb.ConstraintError, match=r"did not converge: \|φ\| = .* after 1 iterations"):
        python_rows_projection(system, q, np.zeros(3), max_iterations=1)
    assert system.residual(*system.project(q, np.zeros(3))) <= 1e-12


def test_compiled_projection_normalizes_the_quaternion_first():
    """A quaternion off unit norm by rounding (within the models' tolerance, so that the state passes the
    checks unchanged) is normalised before the Gauss–Newton steps, as on rows evaluated in Python."""
    model, system = projection_systems()["ball"]
    rng = np.random.default_rng(8)
    q = model.integrate(model.neutral(), 0.2 * rng.standard_normal(model.nv))
    q[3:7] *= 1.0 + 1e-9
    v = rng.standard_normal(model.nv)
    assert model.is_one_state(q, v)
    fast, slow = system.project(q, v), python_rows_projection(system, q, v)
    assert abs(np.linalg.norm(fast[0][3:7]) - 1.0) <= 1e-15
    assert_close(fast[0], slow[0], 1e-14, scale=1.0, what="q")
    assert_close(fast[1], slow[1], 1e-12, scale=max(1.0, np.abs(slow[1]).max()), what="v")


# ----------------------------------------------------------------------------- status codes and their messages

def failing_systems():
    """``{status: (system, failing call, error type, message)}``: a state where each failure of the compiled solve
    or projection happens."""
    model = ball()
    q = model.neutral()
    q[:3] = (0.5, 0.0, 0.0)
    v = np.array([0.0, 0.3, 0.0, 0.0, 0.0, 1.0])
    massless = mb.ModelBuilder("ghost")
    massless.add_body("p", mb.joints.Translation())
    ghost = massless.build(check_inertia=False)
    ghost_rod = mb.ConstrainedSystem(ghost, [mb.Distance("p", None, 1.0)])
    # rods of different lengths on the same point: Baumgarte's −β² φ asks for two accelerations at once
    rods = mb.ConstrainedSystem(model, [mb.Distance("ball", None, 0.5, name="short"),
                                        mb.Distance("ball", None, 0.6, name="long")], baumgarte=(0.0, 1.0))
    flat = mb.ConstrainedSystem(model, [mb.RollingDisc("ball", 0.1, axis=(0.0, 0.0, 1.0), name="coin")])
    closed, loop = projection_systems()["four-bar"]
    nan_state = q.copy()
    nan_state[0] = np.nan
    return {
        kkt.NOT_POSITIVE_DEFINITE: (ghost_rod, lambda s: s.solve(np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                                    mb.ConstraintError, "the mass matrix is not positive definite at this configuration"),
        kkt.INCONSISTENT: (rods, lambda s: s.solve(q, v), mb.ConstraintError,
                           r"inconsistent constraints: no accelerations satisfy all 2 rows \(rank 1\); row "
                           r"'(short|long)\[0\]' is off by -?\d"),
        kkt.UNDEFINED: (flat, lambda s: s.solve(model.neutral(), np.zeros(model.nv)), ValueError,
                        "coin: the disc lies flat on the plane; its contact point is undefined"),
        kkt.NOT_CONVERGED: (loop, lambda s: s.project(np.array([0.3, -0.2, 0.4]), np.zeros(3), max_iterations=1),
                            mb.ConstraintError, r"projection onto the position constraints did not converge: "
                                                r"\|φ\| = \S+ after 1 iterations"),
        kkt.NON_FINITE: (mb.ConstrainedSystem(model, BALL_CONSTRAINTS["sphere"]()),
                         lambda s: s.project(nan_state, np.zeros(model.nv)), mb.ConstraintError,
                         "the constrained step has a non-finite input"),
    }


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the four-bar's redundant row)
@pytest.mark.filterwarnings("ignore:.*NaN:RuntimeWarning")  # (the non-finite state, warned about by the checks)
@pytest.mark.parametrize("rows", ["program", "python"])
def test_every_status_reaches_its_message(rows):
    """Each failure of the compiled solve and projection is a status of its output row, and the one table
    (``STATUS_ERRORS``) raises its message, on the compiled program's rows and on rows evaluated in Python (a
    disc lying flat there raises from the constraint's own evaluation, with the same message)."""
    cases = failing_systems()
    assert set(STATUS_ERRORS) == set(cases) == {kkt.NOT_POSITIVE_DEFINITE, kkt.INCONSISTENT, constraints_undefined(),
                                                kkt.NOT_CONVERGED, kkt.NON_FINITE}
    for status, (system, call, error, message) in cases.items():
        assert system._compiled_step is not None
        if rows == "python":
            system.__dict__["_compiled_step"] = None  # the cached property, withheld
        with pytest.raises(error, match=message):
            call(system)


def constraints_undefined():
    from multibody.kernels import constraints

    return constraints.UNDEFINED


def test_the_status_outputs_report_the_failure():
    """The compiled solve on rows given as arrays reports each failure in its output row: the status, the rank,
    and for inconsistent rows the row furthest off and by how much, ``γ_i − (A a)_i`` there."""
    rng = np.random.default_rng(12)
    nv = 4
    X = rng.standard_normal((nv, nv))
    M, h = X @ X.T + np.eye(nv), rng.standard_normal(nv)
    A = rng.standard_normal((2, nv))
    A = np.vstack([A, A[0]])  # a repeated row: rank 2 of 3
    system = mb.ConstrainedSystem(mb.robots.load("double_pendulum"))  # (its rank tolerance; the arrays are their own)
    consistent = np.array([1.0, 2.0, 1.0])
    a, lam, tail = system._solve_arrays(M, h, None, A, consistent)
    assert tail[kkt.STATUS] == kkt.SOLVED and tail[kkt.RANK] == 2 and tail[kkt.ROW] == -1
    assert_close(A @ a, consistent, 1e-12, scale=2.0, what="A a")
    assert_close(lam[0], lam[2], 1e-12, scale=np.abs(lam).max(), what="the repeated row's share")
    off = np.array([1.0, 2.0, 1.5])
    a, lam, tail = system._solve_arrays(M, h, None, A, off)
    assert tail[kkt.STATUS] == kkt.INCONSISTENT and tail[kkt.RANK] == 2 and tail[kkt.ROW] in (0, 2)
    # the minimum-norm solution meets the mean of the two contradictory rows: each is off by half their difference
    assert_close(abs(tail[kkt.VALUE]), 0.25, 1e-12, scale=1.0, what="how far the row is off")
    _, _, tail = system._solve_arrays(M, h, None, A, off, check=False)
    assert tail[kkt.STATUS] == kkt.SOLVED
    _, _, tail = system._solve_arrays(-M, h, None, A, consistent)
    assert tail[kkt.STATUS] == kkt.NOT_POSITIVE_DEFINITE
    _, _, tail = system._solve_arrays(M, h * np.nan, None, A, consistent)
    assert tail[kkt.STATUS] == kkt.NON_FINITE
