"""Spatial algebra identities (RBDA ch. 2), rotations, SO(3)/SE(3) exp/log, and batching."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

import multibody as mb
from multibody import spatial as sp

TOL = 1e-12


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def random_rotation(rng, shape=()):
    quat = rng.standard_normal(shape + (4,))
    return sp.quat_to_rotation(quat / np.linalg.norm(quat, axis=-1, keepdims=True))


def random_pose(rng, shape=()):
    return random_rotation(rng, shape), rng.standard_normal(shape + (3,))


def random_unit(rng):
    a = rng.standard_normal(3)
    return a / np.linalg.norm(a)


# ----------------------------------------------------------------------------- cross products

def test_motion_cross_matches_its_matrix(rng):
    for _ in range(20):
        m1, m2 = rng.standard_normal(6), rng.standard_normal(6)
        assert_allclose(sp.motion_cross(m1, m2), sp.motion_cross_matrix(m1) @ m2, atol=TOL)
        # antisymmetry of the Lie bracket
        assert_allclose(sp.motion_cross(m1, m2), -sp.motion_cross(m2, m1), atol=TOL)
        assert_allclose(sp.motion_cross(m1, m1), np.zeros(6), atol=TOL)


def test_motion_cross_matrix_block_structure():
    v, w = np.array([1.0, 2.0, 3.0]), np.array([-0.5, 0.25, 2.0])
    X = sp.motion_cross_matrix(np.concatenate([v, w]))
    assert_allclose(X[:3, :3], sp.skew(w))
    assert_allclose(X[:3, 3:], sp.skew(v))
    assert_allclose(X[3:, :3], np.zeros((3, 3)))
    assert_allclose(X[3:, 3:], sp.skew(w))


def test_skew_is_cross_product(rng):
    a, b = rng.standard_normal(3), rng.standard_normal(3)
    assert_allclose(sp.skew(a) @ b, np.cross(a, b), atol=TOL)
    assert_allclose(sp.skew(a), -sp.skew(a).T)


def test_force_cross_matrix_is_minus_transpose(rng):
    for _ in range(20):
        m, f = rng.standard_normal(6), rng.standard_normal(6)
        assert_allclose(sp.force_cross_matrix(m), -sp.motion_cross_matrix(m).T, atol=0)
        assert_allclose(sp.force_cross(m, f), sp.force_cross_matrix(m) @ f, atol=TOL)


def test_cross_products_duality(rng):
    # <m × x, f> + <x, m ×* f> = 0 for every motion m, x and force f.
    for _ in range(20):
        m, x, f = rng.standard_normal(6), rng.standard_normal(6), rng.standard_normal(6)
        assert abs(sp.motion_cross(m, x) @ f + x @ sp.force_cross(m, f)) < 1e-12


def test_jacobi_identity(rng):
    a, b, c = rng.standard_normal((3, 6))
    total = (sp.motion_cross(a, sp.motion_cross(b, c)) + sp.motion_cross(b, sp.motion_cross(c, a))
             + sp.motion_cross(c, sp.motion_cross(a, b)))
    assert_allclose(total, np.zeros(6), atol=1e-12)


# ----------------------------------------------------------------------------- transforms

def test_motion_transform_layout(rng):
    R, p = random_pose(rng)
    X = sp.motion_transform(R, p)
    assert_allclose(X[:3, :3], R)
    assert_allclose(X[:3, 3:], sp.skew(p) @ R, atol=TOL)
    assert_allclose(X[3:, :3], np.zeros((3, 3)))
    assert_allclose(X[3:, 3:], R)


def test_motion_transform_is_velocity_of_a_rigid_point(rng):
    # A body with (v_B at B's origin, ω_B) in B-coordinates: in A-coordinates, the velocity of the
    # body point at A's origin is R v_B + (R ω_B) × (0 − p) = R v_B + p × R ω_B.
    R, p = random_pose(rng)
    m_B = rng.standard_normal(6)
    w_A = R @ m_B[3:]
    expected = np.concatenate([R @ m_B[:3] + np.cross(w_A, -p), w_A])
    assert_allclose(sp.motion_transform(R, p) @ m_B, expected, atol=TOL)


def test_duality_invariance(rng):
    # <ᴬX_B m, ᴬX_B* f> = <m, f>: power does not depend on the coordinates.
    for _ in range(20):
        R, p = random_pose(rng)
        m, f = rng.standard_normal(6), rng.standard_normal(6)
        Xm, Xf = sp.motion_transform(R, p), sp.force_transform(R, p)
        assert abs((Xm @ m) @ (Xf @ f) - m @ f) < 1e-12
        assert_allclose(Xf, np.linalg.inv(Xm).T, atol=1e-12)


def test_vector_transforms_match_matrices(rng):
    R, p = random_pose(rng)
    f, Xf = rng.standard_normal(6), sp.force_transform(R, p)
    assert_allclose(sp.transform_force(R, p, f), Xf @ f, atol=TOL)
    assert_allclose(sp.inverse_transform_force(R, p, Xf @ f), f, atol=TOL)


def test_transform_commutes_with_cross_product(rng):
    # X (a × b) = (X a) × (X b), and X* (a ×* f) = (X a) ×* (X* f).
    R, p = random_pose(rng)
    a, b, f = rng.standard_normal((3, 6))
    X, Xf = sp.motion_transform(R, p), sp.force_transform(R, p)
    assert_allclose(X @ sp.motion_cross(a, b), sp.motion_cross(X @ a, X @ b), atol=1e-12)
    assert_allclose(Xf @ sp.force_cross(a, f), sp.force_cross(X @ a, Xf @ f), atol=1e-12)


def test_transform_composition(rng):
    R_AB, p_AB = random_pose(rng)
    R_BC, p_BC = random_pose(rng)
    R_AC, p_AC = sp.compose(R_AB, p_AB, R_BC, p_BC)
    # the homogeneous matrices multiply
    assert_allclose(sp.pose_matrix(R_AC, p_AC), sp.pose_matrix(R_AB, p_AB) @ sp.pose_matrix(R_BC, p_BC), atol=TOL)
    # and so do the 6×6 motion and force transforms
    assert_allclose(sp.motion_transform(R_AC, p_AC),
                    sp.motion_transform(R_AB, p_AB) @ sp.motion_transform(R_BC, p_BC), atol=1e-12)
    assert_allclose(sp.force_transform(R_AC, p_AC),
                    sp.force_transform(R_AB, p_AB) @ sp.force_transform(R_BC, p_BC), atol=1e-12)


def test_inverse_pose(rng):
    R, p = random_pose(rng)
    R_inv, p_inv = sp.inverse_pose(R, p)
    assert_allclose(sp.pose_matrix(R_inv, p_inv), np.linalg.inv(sp.pose_matrix(R, p)), atol=TOL)
    R_id, p_id = sp.compose(R, p, R_inv, p_inv)
    assert_allclose(R_id, np.eye(3), atol=TOL)
    assert_allclose(p_id, np.zeros(3), atol=TOL)
    assert_allclose(sp.motion_transform(R_inv, p_inv), np.linalg.inv(sp.motion_transform(R, p)), atol=1e-12)


def test_transforms_match_pinocchio(rng, pin):
    R, p = random_pose(rng)
    M = pin.SE3(R, p)
    assert_allclose(sp.motion_transform(R, p), M.action, atol=TOL)
    assert_allclose(sp.force_transform(R, p), M.dualAction, atol=TOL)
    m, f = rng.standard_normal(6), rng.standard_normal(6)
    assert_allclose(sp.motion_cross(m, f), pin.Motion(m).cross(pin.Motion(f)).vector, atol=TOL)
    assert_allclose(sp.force_cross(m, f), pin.Motion(m).cross(pin.Force(f)).vector, atol=TOL)


# ----------------------------------------------------------------------------- rotations

def test_axis_angle_rotation_is_a_rotation(rng):
    axis = random_unit(rng)
    R = sp.axis_angle_rotation(axis, 0.7)
    assert_allclose(R @ R.T, np.eye(3), atol=TOL)
    assert abs(np.linalg.det(R) - 1.0) < TOL
    assert_allclose(R @ axis, axis, atol=TOL)
    assert_allclose(R, Rotation.from_rotvec(0.7 * axis).as_matrix(), atol=TOL)


def test_rpy_to_rotation_closed_form(rng):
    for _ in range(10):
        r, p, y = rng.uniform(-np.pi, np.pi, 3)
        cr, sr, cp, sp_, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        # Rz(y) Ry(p) Rx(r), written out (URDF spec: fixed axes X, then Y, then Z).
        expected = np.array([
            [cy * cp, cy * sp_ * sr - sy * cr, cy * sp_ * cr + sy * sr],
            [sy * cp, sy * sp_ * sr + cy * cr, sy * sp_ * cr - cy * sr],
            [-sp_, cp * sr, cp * cr],
        ])
        assert_allclose(sp.rpy_to_rotation([r, p, y]), expected, atol=TOL)
        # extrinsic x-y-z Euler angles in SciPy's lower-case convention are the same thing
        assert_allclose(sp.rpy_to_rotation([r, p, y]), Rotation.from_euler("xyz", [r, p, y]).as_matrix(), atol=TOL)


def test_rpy_single_axes():
    a = 0.3
    c, s = np.cos(a), np.sin(a)
    assert_allclose(sp.rpy_to_rotation([a, 0, 0]), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=TOL)
    assert_allclose(sp.rpy_to_rotation([0, a, 0]), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=TOL)
    assert_allclose(sp.rpy_to_rotation([0, 0, a]), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=TOL)


def test_pose_from_xyz_rpy():
    X = sp.pose_from_xyz_rpy([1.0, 2.0, 3.0], [0.1, 0.2, 0.3])
    assert X.shape == (4, 4)
    assert_allclose(X[:3, 3], [1, 2, 3])
    assert_allclose(X[:3, :3], sp.rpy_to_rotation([0.1, 0.2, 0.3]))
    assert_allclose(X[3], [0, 0, 0, 1])


def test_quaternion_convention_xyzw():
    # A quarter turn about z: q = [0, 0, sin(π/4), cos(π/4)].
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    assert_allclose(sp.quat_to_rotation(q), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=TOL)
    assert_allclose(sp.rotation_to_quat(sp.axis_angle_rotation([0, 0, 1], np.pi / 2)), q, atol=TOL)


def test_quat_to_rotation_matches_scipy(rng):
    quats = rng.standard_normal((50, 4))
    quats /= np.linalg.norm(quats, axis=-1, keepdims=True)
    assert_allclose(sp.quat_to_rotation(quats), Rotation.from_quat(quats).as_matrix(), atol=TOL)


def test_quat_to_rotation_of_slightly_non_unit_quaternion_is_a_rotation(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    R = sp.quat_to_rotation(q * (1.0 + 1e-7))
    assert_allclose(R @ R.T, np.eye(3), atol=TOL)
    assert_allclose(R, sp.quat_to_rotation(q), atol=TOL)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.5, 2.0, np.pi - 1e-6, np.pi - 1e-9, np.pi])
def test_quaternion_round_trip(rng, angle):
    for _ in range(50):
        axis = random_unit(rng)
        R = sp.axis_angle_rotation(axis, angle)
        q = sp.rotation_to_quat(R)
        assert abs(np.linalg.norm(q) - 1.0) < TOL
        assert q[3] >= 0.0
        assert_allclose(sp.quat_to_rotation(q), R, atol=TOL)
        # the quaternion of a rotation by θ about a is ±[sin(θ/2) a, cos(θ/2)]
        expected = np.concatenate([np.sin(angle / 2) * axis, [np.cos(angle / 2)]])
        assert min(np.abs(q - expected).max(), np.abs(q + expected).max()) < 1e-12


def test_rotation_to_quat_of_negative_w_quaternion(rng):
    # q and −q are the same rotation; the round trip returns the one with w ≥ 0.
    for _ in range(50):
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        q = -q if q[3] > 0 else q
        back = sp.rotation_to_quat(sp.quat_to_rotation(q))
        assert back[3] >= 0
        assert_allclose(back, -q, atol=TOL)


def test_quat_multiply_matches_rotation_product(rng):
    q1, q2 = rng.standard_normal((2, 4))
    q1, q2 = q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2)
    assert_allclose(sp.quat_to_rotation(sp.quat_multiply(q1, q2)),
                    sp.quat_to_rotation(q1) @ sp.quat_to_rotation(q2), atol=TOL)
    assert_allclose(sp.quat_multiply(q1, sp.quat_conjugate(q1)), [0, 0, 0, 1], atol=TOL)


# ----------------------------------------------------------------------------- exp / log

ANGLES = [0.0, 1e-9, 1e-6, 9e-5, 0.01, 0.5, 2.0, 3.0, np.pi - 1e-6, np.pi - 1e-9]


@pytest.mark.parametrize("angle", ANGLES)
def test_so3_exp_log_round_trip(rng, angle):
    for _ in range(20):
        w = angle * random_unit(rng)
        R = sp.so3_exp(w)
        assert_allclose(R, expm(sp.skew(w)), atol=TOL)
        assert_allclose(sp.so3_log(R), w, atol=TOL, rtol=1e-9)
        assert_allclose(sp.so3_exp(sp.so3_log(R)), R, atol=TOL)


def test_so3_log_tiny_angle_relative_accuracy(rng):
    w = 1e-9 * random_unit(rng)
    assert_allclose(sp.so3_log(sp.so3_exp(w)), w, rtol=1e-9, atol=0)
    assert_allclose(sp.quat_log(sp.quat_exp(w)), w, rtol=1e-12, atol=0)


def test_so3_log_at_pi(rng):
    axis = random_unit(rng)
    R = sp.axis_angle_rotation(axis, np.pi)
    w = sp.so3_log(R)
    assert abs(np.linalg.norm(w) - np.pi) < 1e-12
    assert min(np.abs(w - np.pi * axis).max(), np.abs(w + np.pi * axis).max()) < 1e-12
    assert_allclose(sp.so3_exp(w), R, atol=TOL)


def test_so3_log_angle_at_most_pi(rng):
    # A rotation vector longer than π comes back as the equivalent shorter one.
    axis = random_unit(rng)
    w = sp.so3_log(sp.so3_exp(4.0 * axis))
    assert_allclose(w, (4.0 - 2 * np.pi) * axis, atol=TOL)


def _se3_expm(m):
    """Reference exp of a twist through the 4×4 matrix exponential."""
    A = np.zeros((4, 4))
    A[:3, :3] = sp.skew(m[3:])
    A[:3, 3] = m[:3]
    return expm(A)


SE3_ANGLES = [0.0, 1e-9, 1e-6, 9e-5, 0.01, 0.5, 2.0, 3.0, np.pi - 1e-6]


@pytest.mark.parametrize("angle", SE3_ANGLES)
def test_se3_exp_log_round_trip(rng, angle):
    for _ in range(20):
        m = np.concatenate([rng.standard_normal(3), angle * random_unit(rng)])
        R, p = sp.se3_exp(m)
        assert_allclose(sp.pose_matrix(R, p), _se3_expm(m), atol=1e-12)
        assert_allclose(sp.se3_log(R, p), m, atol=TOL)


@pytest.mark.parametrize("angle", [1.5e-4, 1e-3])
def test_se3_log_accuracy_just_above_small_angle_threshold(rng, angle):
    worst = 0.0
    for _ in range(50):
        m = np.concatenate([rng.standard_normal(3), angle * random_unit(rng)])
        worst = max(worst, np.abs(sp.se3_log(*sp.se3_exp(m)) - m).max())
    assert worst < 1e-12


def test_se3_exp_log_match_pinocchio(rng, pin):
    for angle in (1e-9, 0.3, 2.5):
        m = np.concatenate([rng.standard_normal(3), angle * random_unit(rng)])
        M = pin.exp6(pin.Motion(m))
        R, p = sp.se3_exp(m)
        assert_allclose(R, M.rotation, atol=TOL)
        assert_allclose(p, M.translation, atol=TOL)
        assert_allclose(sp.se3_log(M.rotation, M.translation), pin.log6(M).vector, atol=TOL)


# ----------------------------------------------------------------------------- spatial inertia

def random_body(rng):
    size = rng.uniform(0.1, 1.0, 3)
    box = mb.inertia.box(rng.uniform(0.5, 5.0), size)
    return box.transformed(sp.pose_from_xyz_rpy(rng.standard_normal(3), rng.uniform(-np.pi, np.pi, 3)))


def test_spatial_inertia_layout_and_energy(rng):
    body = random_body(rng)
    I = body.spatial
    m, c = body.mass, body.com
    assert_allclose(I, I.T, atol=1e-12)
    assert_allclose(I[:3, :3], m * np.eye(3))
    assert_allclose(I[3:, :3], m * sp.skew(c), atol=1e-12)
    # kinetic energy ½ Vᵀ I V = ½ m |v_c|² + ½ ωᵀ I_c ω with v_c = v + ω × c
    V = rng.standard_normal(6)
    v_c = V[:3] + np.cross(V[3:], c)
    expected = 0.5 * m * v_c @ v_c + 0.5 * V[3:] @ body.rotational @ V[3:]
    assert abs(0.5 * V @ I @ V - expected) < 1e-12 * max(1.0, expected)


def test_spatial_inertia_positive_semidefinite(rng):
    for _ in range(20):
        I = random_body(rng).spatial
        assert np.linalg.eigvalsh(I).min() > 0
    # a point mass: PSD with a 3-dimensional null space (rotations about the point)
    I = mb.inertia.point_mass(2.0, [0.3, -0.1, 0.5]).spatial
    eig = np.linalg.eigvalsh(I)
    assert eig.min() > -1e-12
    assert np.sum(np.abs(eig) < 1e-12) == 3


def test_transform_inertia_matches_inertia_transformed(rng):
    for _ in range(10):
        body = random_body(rng)
        X = sp.pose_from_xyz_rpy(rng.standard_normal(3), rng.uniform(-np.pi, np.pi, 3))
        R, p = X[:3, :3], X[:3, 3]
        assert_allclose(sp.transform_inertia(R, p, body.spatial), body.transformed(X).spatial, atol=1e-12)
        # momentum transforms as a force: I_A (X v_B) = X* (I_B v_B)
        v_B = rng.standard_normal(6)
        assert_allclose(body.transformed(X).spatial @ (sp.motion_transform(R, p) @ v_B),
                        sp.force_transform(R, p) @ (body.spatial @ v_B), atol=1e-11)


def test_spatial_inertia_matches_pinocchio(rng, pin):
    body = random_body(rng)
    pin_inertia = pin.Inertia(body.mass, body.com, body.rotational)
    assert_allclose(body.spatial, pin_inertia.matrix(), atol=1e-12)


# ----------------------------------------------------------------------------- batching

BATCH = (2, 3)


def _stacked(fn, *arrays):
    """fn applied to each element of the (2, 3) batch, stacked back."""
    out = [[fn(*(a[i, j] for a in arrays)) for j in range(BATCH[1])] for i in range(BATCH[0])]
    if isinstance(out[0][0], tuple):
        return tuple(np.array([[o[k] for o in row] for row in out]) for k in range(len(out[0][0])))
    return np.array(out)


def _check_batched(fn, *arrays):
    batched = fn(*arrays)
    stacked = _stacked(fn, *arrays)
    if isinstance(batched, tuple):
        for b, s in zip(batched, stacked):
            assert b.shape == s.shape
            assert_allclose(b, s, atol=1e-14, rtol=1e-14)
    else:
        assert batched.shape == stacked.shape
        assert batched.shape[:2] == BATCH
        assert_allclose(batched, stacked, atol=1e-14, rtol=1e-14)


def test_batched_shapes_equal_stacked_calls(rng):
    m1, m2 = rng.standard_normal(BATCH + (6,)), rng.standard_normal(BATCH + (6,))
    w = rng.standard_normal(BATCH + (3,))
    quat = rng.standard_normal(BATCH + (4,))
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    R, p = random_pose(rng, BATCH)
    R2, p2 = random_pose(rng, BATCH)
    mass = rng.uniform(1, 2, BATCH)
    Ic = np.einsum("...ij,...kj->...ik", R, R) * 0.1 + np.eye(3) * 0.2

    _check_batched(sp.skew, w)
    _check_batched(sp.motion_cross, m1, m2)
    _check_batched(sp.force_cross, m1, m2)
    _check_batched(sp.motion_cross_matrix, m1)
    _check_batched(sp.force_cross_matrix, m1)
    _check_batched(sp.quat_to_rotation, quat)
    _check_batched(sp.rotation_to_quat, R)
    _check_batched(sp.quat_multiply, quat, quat[::-1])
    _check_batched(sp.quat_exp, w)
    _check_batched(sp.quat_log, quat)
    _check_batched(sp.so3_exp, w)
    _check_batched(sp.so3_log, R)
    _check_batched(sp.se3_exp, m1)
    _check_batched(sp.se3_log, R, p)
    _check_batched(sp.rpy_to_rotation, w)
    _check_batched(sp.pose_matrix, R, p)
    _check_batched(sp.compose, R, p, R2, p2)
    _check_batched(sp.inverse_pose, R, p)
    _check_batched(sp.motion_transform, R, p)
    _check_batched(sp.force_transform, R, p)
    _check_batched(sp.transform_force, R, p, m1)
    _check_batched(sp.inverse_transform_force, R, p, m1)
    _check_batched(sp.spatial_inertia, mass, w, Ic)
    I6 = sp.spatial_inertia(mass, w, Ic)
    _check_batched(sp.transform_inertia, R, p, I6)


def test_batched_small_and_large_angles_mixed(rng):
    # The small-angle branches are selected element-wise inside one batch.
    w = np.stack([1e-9 * random_unit(rng), 2.0 * random_unit(rng), np.zeros(3), 3.1 * random_unit(rng)])
    R = sp.so3_exp(w)
    for k in range(4):
        assert_allclose(R[k], sp.so3_exp(w[k]), atol=1e-15)
    assert_allclose(sp.so3_log(R), w, atol=TOL)


def test_quat_rotate_and_rate_equal_the_matrix_and_the_product(rng):
    quat = rng.standard_normal((5, 4)) * 1.2  # not unit: rotations of q / |q|
    x, omega = rng.standard_normal((2, 5, 3))
    assert_allclose(sp.quat_rotate(quat, x), sp.matvec(sp.quat_to_rotation(quat), x), atol=1e-14)
    pure = np.concatenate([omega, np.zeros((5, 1))], axis=-1)
    assert_allclose(sp.quat_rate(quat, omega), 0.5 * sp.quat_multiply(quat, pure), atol=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-8, 9.9e-5, 1.01e-4, 1e-3, 0.1, 1.0, 3.0, 6.0])
def test_left_jacobian_inverse_and_quaternion_exponential_to_high_precision(angle):
    """``J_l(w)⁻¹ x`` and ``quat_exp(w)`` against 40-digit arithmetic, on both sides of the small-angle
    switch: the closed forms keep their absolute digits down to θ = 0."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 40
    rng = np.random.default_rng(int(angle * 1e3) + 17)
    for _ in range(10):
        axis = rng.standard_normal(3)
        w, x = angle * axis / np.linalg.norm(axis), rng.standard_normal(3)
        W = mpmath.matrix([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        theta = mpmath.sqrt(sum(mpmath.mpf(c) ** 2 for c in w))
        c = mpmath.mpf(1) / 12 if theta == 0 else (1 - theta / 2 * mpmath.cot(theta / 2)) / theta**2
        X = mpmath.matrix(x.tolist())
        reference = X - W * X / 2 + c * W * W * X
        # the condition of J_l⁻¹ grows towards θ = 2π (|c| ≈ 12 at θ = 6)
        assert_allclose(sp.so3_left_jacobian_inverse_times(w, x), [float(r) for r in reference],
                        rtol=0, atol=2e-15 * (1 + float(abs(c)) * angle**2) * np.linalg.norm(x))
        half_sinc = mpmath.mpf(0.5) if theta == 0 else mpmath.sin(theta / 2) / theta
        assert_allclose(sp.quat_exp(w), [float(half_sinc * c_) for c_ in w] + [float(mpmath.cos(theta / 2))],
                        rtol=0, atol=2e-16)


def test_batch_shape_broadcasts_only_when_shapes_differ():
    assert sp.batch_shape((4, 2), (4, 2)) == (4, 2)
    assert sp.batch_shape((), ()) == ()
    assert sp.batch_shape((4, 1), (3,), ()) == (4, 3)
    with pytest.raises(ValueError):
        sp.batch_shape((4,), (3,))


def test_float_array_takes_any_numbers_of_the_right_last_axis():
    """``sp.float_array``: numbers of shape ``(..., size)`` as floats; another last axis, or a scalar, is a
    ``ValueError`` naming the argument and both shapes (``require_last_axis``)."""
    x = sp.float_array([[1, 2, 3]], 3, "q")
    assert x.dtype == np.float64 and x.shape == (1, 3)
    with pytest.raises(ValueError, match=r"q must have shape \(\.\.\., 3\), got \(2, 4\)"):
        sp.float_array(np.zeros((2, 4)), 3, "q")
    with pytest.raises(ValueError, match=r"v must have shape \(\.\.\., 2\), got \(\)"):
        sp.require_last_axis(np.float64(1.0), 2, "v")


def test_kernel_larger_and_smaller_are_the_builtin_max_and_min():
    """The kernels' ``larger``/``smaller`` (which the CUDA target compiles) give exactly what the builtin ``max``/
    ``min`` give, compiled and in Python, NaN in either place, signed zeros, infinities and integers included, and
    their left fold is the builtin of three arguments."""
    import itertools
    import math

    import numba

    from multibody.kernels.spatial import larger, smaller

    @numba.njit
    def builtin(a, b, c):
        return max(a, b), min(a, b), max(a, b, c), min(a, b, c)

    @numba.njit
    def helpers(a, b, c):
        return larger(a, b), smaller(a, b), larger(larger(a, b), c), smaller(smaller(a, b), c)

    def same(x, y):
        return (math.isnan(x) and math.isnan(y)) or (x == y and math.copysign(1.0, x) == math.copysign(1.0, y))

    values = (1.5, -2.0, 0.0, -0.0, math.inf, -math.inf, math.nan)
    for a, b, c in itertools.product(values, repeat=3):
        expected = builtin(a, b, c)
        assert all(map(same, helpers(a, b, c), expected)), (a, b, c)
        assert all(map(same, helpers.py_func(a, b, c), (max(a, b), min(a, b), max(a, b, c), min(a, b, c)))), (a, b, c)
    assert helpers(3, 7, 5) == builtin(3, 7, 5) == (7, 3, 7, 3)
    assert helpers(2, 2.5, 1) == builtin(2, 2.5, 1)
