"""The Whipple bicycle of examples/whipple_bicycle.py against the benchmark of Meijaard, Papadopoulos, Ruina
and Schwab, "Linearized dynamics equations for the balance and steer of a bicycle: a benchmark and review",
Proc. R. Soc. A 463 (2007) 1955–1982.

The references are the paper's published numbers: its coefficient matrices M, C₁, K₀, K₂ of the lean and
steer equations ``M q̈ + v C₁ q̇ + (g K₀ + v² K₂) q = 0`` (the example's ``PUBLISHED_MATRICES``), checked
here against the paper's expressions of their entries evaluated from the parameters of its Table 1; and
its Table 2, the eigenvalues at 0, 1, …, 10 m/s and the weave and
capsize speeds, written out below. The model itself is built from the library's parts (a free-flyer rear
frame, revolute joints, two ``mb.RollingDisc``) and knows nothing of these formulas.
"""

import importlib.util
import os

import numpy as np
import pytest
from scipy.optimize import brentq

import multibody as mb

EXAMPLE = os.path.join(os.path.dirname(__file__), "..", "examples", "whipple_bicycle.py")

#: Meijaard et al. (2007), Table 2: the eigenvalues (1/s) of the lean and steer at v = 0, 1, …, 10 m/s,
#: per speed the weave pair (two real roots at 0 m/s), the capsize root and the castering root, with the
#: table's 14 decimals (13 for the castering roots at 3 and 6 m/s, as far as the transcriptions we could
#: check agree).
TABLE_2 = {
    0: [5.53094371765393, 3.13164324790656, -3.13164324790656, -5.53094371765393],
    1: [3.52696170990070 + 0.80774027519930j, 3.52696170990070 - 0.80774027519930j, -3.13423125066578,
        -7.11008014637442],
    2: [2.68234517512745 + 1.68066296590675j, 2.68234517512745 - 1.68066296590675j, -3.07158645641514,
        -8.67387984831735],
    3: [1.70675605663975 + 2.31582447384325j, 1.70675605663975 - 2.31582447384325j, -2.63366137253667,
        -10.3510146724592],
    4: [0.41325331521125 + 3.07910818603206j, 0.41325331521125 - 3.07910818603206j, -1.42944427361326,
        -12.15861426576447],
    5: [-0.77534188219585 + 4.46486771378823j, -0.77534188219585 - 4.46486771378823j, -0.32286642900409,
        -14.07838969279822],
    6: [-1.52644486584142 + 5.87673060598709j, -1.52644486584142 - 5.87673060598709j, -0.00406690076970,
        -16.0853712309803],
    7: [-2.13875644258362 + 7.19525913329805j, -2.13875644258362 - 7.19525913329805j, 0.10268170574766,
        -18.15788466125262],
    8: [-2.69348683581097 + 8.46037971396931j, -2.69348683581097 - 8.46037971396931j, 0.14327879765713,
        -20.27940894394569],
    9: [-3.21675402252485 + 9.69377351531791j, -3.21675402252485 - 9.69377351531791j, 0.15790184030917,
        -22.43788559040858],
    10: [-3.72016840437287 + 10.90681139476287j, -3.72016840437287 - 10.90681139476287j, 0.16105338653172,
         -24.62459635017404],
}
#: Table 2: the weave and capsize speeds (m/s).
WEAVE_SPEED, CAPSIZE_SPEED = 4.29238253634111, 6.02426201538837


@pytest.fixture(scope="module")
def bicycle():
    """The example as a module."""
    spec = importlib.util.spec_from_file_location("whipple_bicycle", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def built(bicycle):
    return bicycle.build_bicycle()


def matrices_from_parameters(p):
    """M, C₁, K₀, K₂ of the benchmark from its parameters ``p`` (the paper's axes, z down), by the paper's
    expressions of their entries: total mass, centre of mass and inertia of the whole bicycle, the front
    assembly's inertia about the steer axis, the trail ratio μ and the gyrostatic coefficients S_R, S_F,
    S_T and S_A."""
    w, c, lam = p["w"], p["c"], p["lam"]
    r_R, m_R, (I_Rxx, I_Ryy) = p["r_R"], p["m_R"], p["I_R"]
    x_B, z_B, m_B, I_B = p["x_B"], p["z_B"], p["m_B"], np.asarray(p["I_B"])
    x_H, z_H, m_H, I_H = p["x_H"], p["z_H"], p["m_H"], np.asarray(p["I_H"])
    r_F, m_F, (I_Fxx, I_Fyy) = p["r_F"], p["m_F"], p["I_F"]
    sin, cos = np.sin(lam), np.cos(lam)
    # the whole bicycle: mass, centre of mass, inertia about the rear contact (wheels' I_zz = I_xx)
    m_T = m_R + m_B + m_H + m_F
    x_T = (x_B * m_B + x_H * m_H + w * m_F) / m_T
    z_T = (-r_R * m_R + z_B * m_B + z_H * m_H - r_F * m_F) / m_T
    I_Txx = I_Rxx + I_B[0, 0] + I_H[0, 0] + I_Fxx + m_R * r_R**2 + m_B * z_B**2 + m_H * z_H**2 + m_F * r_F**2
    I_Txz = I_B[0, 2] + I_H[0, 2] - m_B * x_B * z_B - m_H * x_H * z_H + m_F * w * r_F
    I_Tzz = I_Rxx + I_B[2, 2] + I_H[2, 2] + I_Fxx + m_B * x_B**2 + m_H * x_H**2 + m_F * w**2
    # the front assembly (front frame and wheel) and its inertia about the steer axis
    m_A = m_H + m_F
    x_A, z_A = (x_H * m_H + w * m_F) / m_A, (z_H * m_H - r_F * m_F) / m_A
    I_Axx = I_H[0, 0] + I_Fxx + m_H * (z_H - z_A) ** 2 + m_F * (r_F + z_A) ** 2
    I_Axz = I_H[0, 2] - m_H * (x_H - x_A) * (z_H - z_A) + m_F * (w - x_A) * (r_F + z_A)
    I_Azz = I_H[2, 2] + I_Fxx + m_H * (x_H - x_A) ** 2 + m_F * (w - x_A) ** 2
    u_A = (x_A - w - c) * cos - z_A * sin
    I_All = m_A * u_A**2 + I_Axx * sin**2 + 2 * I_Axz * sin * cos + I_Azz * cos**2
    I_Alx = -m_A * u_A * z_A + I_Axx * sin + I_Axz * cos
    I_Alz = m_A * u_A * x_A + I_Axz * sin + I_Azz * cos
    mu = c / w * cos
    S_R, S_F = I_Ryy / r_R, I_Fyy / r_F
    S_T, S_A = S_R + S_F, m_A * u_A + mu * m_T * x_T
    return {
        "M": np.array([[I_Txx, I_Alx + mu * I_Txz], [I_Alx + mu * I_Txz, I_All + 2 * mu * I_Alz + mu**2 * I_Tzz]]),
        "K0": np.array([[m_T * z_T, -S_A], [-S_A, -S_A * sin]]),
        "K2": np.array([[0.0, (S_T - m_T * z_T) * cos / w], [0.0, (S_A + S_F * sin) * cos / w]]),
        "C1": np.array([[0.0, mu * S_T + S_F * cos + I_Txz * cos / w - mu * m_T * z_T],
                        [-(mu * S_T + S_F * cos), I_Alz * cos / w + mu * (S_A + I_Tzz * cos / w)]]),
    }


def table(speed):
    return np.sort_complex(np.array(TABLE_2[speed], dtype=complex))


# ----------------------------------------------------------------------------- the references agree

def test_the_parameters_give_the_published_matrices(bicycle):
    # Table 1's parameters through the paper's expressions: the published matrices, which carry 14 decimals (rounding
    # of 5e-15), to the rounding of the formulas' terms (entries up to 81, a few ulps each).
    computed = matrices_from_parameters(bicycle.BENCHMARK)
    for name, published in bicycle.PUBLISHED_MATRICES.items():
        np.testing.assert_allclose(computed[name], published, rtol=0, atol=5e-15 + 8 * np.spacing(81.0),
                                   err_msg=name)


def test_the_published_matrices_give_the_published_eigenvalues(bicycle):
    # det(M s² + v C₁ s + g K₀ + v² K₂) = 0 against Table 2, which was computed from the unrounded
    # matrices: the published ones' rounding (5e-15 an entry, on entries up to 81) moves the roots by up to
    # 8.5e-13 (the castering root of -18.2 at 7 m/s), hence 1e-11.
    for speed in TABLE_2:
        np.testing.assert_allclose(bicycle.benchmark_eigenvalues(float(speed)), table(speed), rtol=0, atol=1e-11,
                                   err_msg=f"v = {speed} m/s")

    def growth(speed):
        return bicycle.benchmark_eigenvalues(speed).real.max()

    assert brentq(growth, 3.0, 5.0, xtol=1e-14) == pytest.approx(WEAVE_SPEED, abs=1e-12)
    assert brentq(growth, 5.0, 8.0, xtol=1e-14) == pytest.approx(CAPSIZE_SPEED, abs=1e-12)


# ----------------------------------------------------------------------------- the model

def test_the_upright_bicycle_stands_on_both_wheels_with_the_benchmark_geometry(bicycle, built):
    model, system = built
    p = bicycle.BENCHMARK
    q, v = bicycle.upright_state(model, 0.0)
    rear, front = system.constraints
    # contacts on the ground at the rear contact (the origin) and a wheelbase ahead
    np.testing.assert_allclose(rear.contact_point(model, q), [0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(front.contact_point(model, q), [p["w"], 0.0, 0.0], atol=1e-15)
    # zero pitch is consistent: the constraints hold there and the projection leaves the state alone
    assert np.abs(system.position_error(q)).max() <= 1e-15
    q_projected, _ = system.project(q, v)
    np.testing.assert_array_equal(q_projected, q)
    # the steer axis, tilted back by λ from the vertical, meets the ground the trail c ahead of the front
    # contact
    steer = model.joint_index("steer")
    X_steer = mb.forward_kinematics(model, q)[model.body_index("front_frame")]
    axis = X_steer[:3, :3] @ model.joints[steer].axis
    assert np.arccos(abs(axis[2])) == pytest.approx(p["lam"], abs=1e-15)
    on_ground = X_steer[:3, 3] - X_steer[2, 3] / axis[2] * axis
    np.testing.assert_allclose(on_ground, [p["w"] + p["c"], 0.0, 0.0], atol=1e-15)
    # the whole bicycle: mass m_T and centre of mass (x_T, −z_T) of the paper's expressions
    assert model.total_mass == pytest.approx(94.0, rel=1e-15)
    np.testing.assert_allclose(mb.center_of_mass(model, q), [(0.3 * 85 + 0.9 * 4 + 1.02 * 3) / 94, 0.0,
                                                               (0.3 * 2 + 0.9 * 85 + 0.7 * 4 + 0.35 * 3) / 94],
                               rtol=1e-15)


def test_the_straight_upright_motion_is_steady(bicycle, built):
    # Rolling straight at 5 m/s needs no acceleration; the ground carries the weight, split by the moments
    # about the rear contact: N_F w = m_T g x_T.
    model, system = built
    q, v = bicycle.upright_state(model, 5.0)
    assert np.abs(system.velocity_error(q, v)).max() <= 1e-15
    a, lam = system.forward_dynamics(q, v)
    weight = 94.0 * 9.81
    assert np.abs(a).max() <= 1e-12
    normal_front = weight * mb.center_of_mass(model, q)[0] / bicycle.BENCHMARK["w"]
    np.testing.assert_allclose(lam[[2, 5]], [weight - normal_front, normal_front], rtol=1e-13)
    np.testing.assert_allclose(lam[[0, 1, 3, 4]], 0.0, atol=1e-12)


def test_a_push_at_5_m_s_dies_out_and_at_2_m_s_the_bicycle_falls(bicycle, built):
    # 5 m/s lies in the self-stable range (4.29, 6.02) m/s, where every lean and steer mode decays; at
    # 2 m/s the weave pair grows at 2.68/s (Table 2): a push that leans the bicycle by less than 0.08 rad in
    # its first 0.85 s has it lying past 0.9 rad (52°) 0.85 s later. Rolling forces do no work: the energy
    # drifts by the integration's error only, within DOP853's rtol of 1e-10 (measured 9.6e-13 and 3.4e-11
    # relative) and shrinking with it (3.4e-11 to 1.3e-13 at rtol 1e-12 for the fall), where a dissipation
    # would stay.
    _, system = built
    stable = bicycle.push(system, 5.0, 0.5, 10.0)
    lean, steer = bicycle.lean_and_steer(stable.q)
    assert np.abs(lean).max() > 0.1 and np.abs(lean[-100:]).max() < 0.02 * np.abs(lean).max()
    assert np.abs(steer[-100:]).max() < 0.02 * np.abs(steer).max()
    assert np.ptp(stable.energy) <= 1e-10 * np.abs(stable.energy).max()
    assert stable.residual.max() <= 1e-11
    falling = bicycle.push(system, 2.0, 0.1, 1.7)
    lean, _ = bicycle.lean_and_steer(falling.q)
    assert np.abs(lean[falling.t <= 0.85]).max() < 0.08 and np.abs(lean[-1]) > 0.9
    drift = np.ptp(falling.energy) / np.abs(falling.energy).max()
    assert drift <= 1e-10
    q0, v0 = falling.q[0], falling.v[0]
    tighter = mb.simulate(system, q0, v0, 1.7, dt=0.01, method="DOP853", rtol=1e-12, atol=1e-14)
    assert np.ptp(tighter.energy) / np.abs(tighter.energy).max() < drift / 10


def test_small_pushes_follow_the_benchmark_linear_equations_to_third_order(bicycle, built):
    # The nonlinear lean and steer after a push φ̇₀ = ε differ from the benchmark's linear response
    # exp(A t) (0, 0, ε, 0) by terms of third order: the bicycle is symmetric left to right, so the response
    # is odd in ε. Doubling ε multiplies the difference by 8; the ε⁵ terms change that ratio by 3 (b/a) ε²
    # with b/a ≈ −0.2 (from ε = 0.04), 5e-4 at ε = 0.01, so 8 ± 0.005 holds with a margin of 10; the
    # integration's error (rtol 1e-10 on angles of 2e-3 rad) is 1e-6 of the difference.
    _, system = built
    differences, amplitudes = [], []
    for push in (0.01, 0.02):
        trajectory = bicycle.push(system, 5.0, push, 2.0, dt=0.02)
        lean, steer = bicycle.lean_and_steer(trajectory.q)
        linear = bicycle.benchmark_response(5.0, push, trajectory.t)
        differences.append(max(np.abs(lean - linear[0]).max(), np.abs(steer - linear[1]).max()))
        amplitudes.append(np.abs(linear).max())
    assert differences[0] < 1e-3 * amplitudes[0]
    assert differences[1] / differences[0] == pytest.approx(8.0, abs=0.005)


# ----------------------------------------------------------------------------- the linearized model

@pytest.fixture(scope="module")
def linearizations(bicycle, built):
    """``system.linearize`` about the straight upright motion at each speed of Table 2."""
    _, system = built
    return {speed: bicycle.upright_linearization(system, float(speed)) for speed in TABLE_2}


def test_the_linearized_bicycle_has_the_eigenvalues_of_table_2(bicycle, linearizations):
    # Seven position coordinates (x, y, yaw, lean, steer, the wheels' angles: the two contact heights fix
    # the height and pitch) and three velocities (speed, lean rate, steer rate: the four rolling rows fix the
    # rest). The lean and steer eigenvalues meet the table to 1e-10 relative; they come from a matrix of
    # norm up to 180, whose eigenvalues carry a rounding of 1e-16 · 180 (the smallest root, 0.004 at 6 m/s,
    # comes out 5.7e-14 off, 1.4e-11 relative), hence an absolute 1e-12 besides.
    for speed, linearization in linearizations.items():
        assert (linearization.p, linearization.k) == (7, 3)
        assert linearization.A.shape == (10, 10)
        ours = np.sort_complex(np.linalg.eigvals(bicycle.lean_steer_matrix(linearization)))
        np.testing.assert_allclose(ours, table(speed), rtol=1e-10, atol=1e-12, err_msg=f"v = {speed} m/s")


def test_the_other_six_eigenvalues_are_zero(bicycle, linearizations):
    # The shifts along x and y, the turn about the vertical, the wheels' turns and the speed span an
    # invariant subspace Z of A (Qᵀ A Z = 0 for Q its orthogonal complement) on which A is nilpotent
    # (X² = 0 for A Z = Z X: the turn drifts along y at the speed, the speed along x and the wheels' angles,
    # and those stay), so A has six zero eigenvalues. Both hold to the accuracy of A's entries, about 1e-13
    # (its lean and steer roots, up to 24/s, meet Table 2 to 8.4e-13), hence 1e-12 (measured 4.2e-14 and
    # 2.1e-14). Computed from A as a whole they are those of two 2×2 Jordan blocks, which a rounding ε |A|
    # of A moves to about √(v ε |A|) (measured up to 4e-8): bounded by |A| √ε, three orders below the
    # smallest lean and steer root (0.004/s at 6 m/s).
    eps = np.finfo(float).eps
    for speed, linearization in linearizations.items():
        A = linearization.A
        Z = bicycle.steady_motion_directions(linearization)
        Q = np.linalg.svd(Z)[0][:, 6:]
        X = np.linalg.lstsq(Z, A @ Z, rcond=None)[0]
        assert np.abs(Q.T @ A @ Z).max() <= 1e-12
        assert np.abs(X @ X).max() <= 1e-12
        assert X[1, 2] == pytest.approx(speed, abs=1e-12)
        magnitudes = np.sort(np.abs(np.linalg.eigvals(A)))
        assert magnitudes[5] <= np.linalg.norm(A, 2) * np.sqrt(eps) < 1e-3 * magnitudes[6]


def test_the_weave_and_capsize_speeds_of_the_linearized_bicycle(bicycle, built):
    # Where the largest real part of the lean and steer eigenvalues crosses zero (brentq to 1e-13 m/s). A
    # root off by e moves the crossing by e over the slope of its real part: the weave pair's (1.2/s per
    # m/s, real parts within 2.4e-13 of the table) by 2e-13 m/s, the capsize root's (0.1/s per m/s, within
    # 6e-14 near zero) by 6e-13 m/s; hence 2e-12 and 6e-12 (measured 1.8e-13 and 3.4e-13 to 4.1e-13).
    _, system = built
    weave, capsize = bicycle.stable_speed_range(system)
    assert weave == pytest.approx(WEAVE_SPEED, abs=2e-12)
    assert capsize == pytest.approx(CAPSIZE_SPEED, abs=6e-12)


def test_the_example_draws_its_figure(bicycle, tmp_path):
    # The example's figure at reduced cost: three speeds, short pushes.
    path, summary = bicycle.main(str(tmp_path), speeds=[0.0, 5.0, 10.0], pushes=((5.0, 0.5, 2.0), (2.0, 0.1, 1.0)))
    assert path == str(tmp_path / "whipple_bicycle.png") and os.path.getsize(path) > 0
    assert abs(summary["weave speed error (m/s)"]) < 2e-12 and abs(summary["capsize speed error (m/s)"]) < 6e-12
    assert summary["largest eigenvalue difference (1/s)"] < 1e-11
    assert summary["5 m/s: energy drift (relative)"] < 1e-10 and summary["2 m/s: energy drift (relative)"] < 1e-10
