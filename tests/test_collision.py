"""Contact detection kernels (:mod:`multibody.kernels.collision`).

Closed forms for each shape against a half-space (flat and tilted) and for each analytic pair (gaps,
normals, points, counts), the margin rule, the swap of a and b, box-on-box manifolds, and GJK/EPA
(:func:`convex_contact`) agreeing with the analytic routines on seeded random poses.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from multibody.kernels import collision as C

NO_VERTICES = np.zeros((1, 3))
I3 = np.eye(3)
TOL = 1e-12


def run_halfspace(shape, size, R, p, normal=(0.0, 0.0, 1.0), height=0.0, margin=1e-3, vertices=NO_VERTICES):
    out = np.full((C.MAX_PAIR_CONTACTS, C.CONTACT_COLUMNS), np.nan)
    ws = np.zeros(C.PAIR_WORKSPACE)
    n = C.halfspace_contacts(shape, np.asarray(size, float), vertices, np.asarray(R, float), np.asarray(p, float),
                             np.asarray(normal, float), float(height), float(margin), out, ws)
    return out[:n].copy()


def run_pair(a, b, margin=1e-3, convex=False):
    """``a``, ``b``: (shape, size, R, p[, vertices]) tuples; ``convex``: GJK/EPA whatever the shapes."""
    out = np.full((C.MAX_PAIR_CONTACTS, C.CONTACT_COLUMNS), np.nan)
    ws = np.zeros(C.PAIR_WORKSPACE)
    args = []
    for g in (a, b):
        shape, size, R, p = g[:4]
        vertices = g[4] if len(g) > 4 else NO_VERTICES
        args += [shape, np.asarray(size, float), vertices, np.asarray(R, float), np.asarray(p, float)]
    if convex:
        n = C.convex_contact(*args, float(margin), out, 0, ws)
    else:
        n = C.pair_contacts(*args, float(margin), out, ws)
    return out[:n].copy()


def rows_as_set(rows, decimals=9):
    return sorted(tuple(np.round(r, decimals)) for r in rows)


def random_rotation(rng):
    return Rotation.random(random_state=rng).as_matrix()


CUBE = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])


# ---------------------------------------------------------------------------------------------------------------------
# half-space


def test_sphere_on_ground_and_on_a_tilted_plane():
    rows = run_halfspace(C.SPHERE, (0.3, 0, 0), I3, (1.0, 2.0, 0.2999))
    np.testing.assert_allclose(rows, [[1.0, 2.0, -1e-4, 0, 0, 1, -1e-4]], atol=TOL)
    assert len(run_halfspace(C.SPHERE, (0.3, 0, 0), I3, (1.0, 2.0, 0.3011))) == 0  # gap 1.1e-3 ≥ margin
    # plane n·x ≥ h with n = (0, sin α, cos α), unnormalised input
    alpha = 0.4
    n = np.array([0.0, np.sin(alpha), np.cos(alpha)])
    c = np.array([0.3, -1.0, 2.0])
    h = 0.7
    rows = run_halfspace(C.SPHERE, (0.25, 0, 0), I3, c, normal=3 * n, height=h, margin=10.0)
    gap = n @ c - h - 0.25
    np.testing.assert_allclose(rows, [np.r_[c - 0.25 * n, n, gap]], atol=TOL)


def test_box_resting_gives_its_four_lowest_corners():
    h = np.array([0.4, 0.3, 0.2])
    yaw = Rotation.from_euler("z", 0.7).as_matrix()
    p = np.array([0.1, -0.2, 0.2 - 1e-5])
    rows = run_halfspace(C.BOX, h, yaw, p)
    assert len(rows) == 4
    corners = [p + yaw @ (np.array([sx, sy, -1]) * h) for sx in (-1, 1) for sy in (-1, 1)]
    expected = [np.r_[x, 0, 0, 1, -1e-5] for x in corners]
    np.testing.assert_allclose(np.array(rows_as_set(rows, 12)), np.array(rows_as_set(expected, 12)), atol=TOL)


def test_box_on_a_tilted_plane_and_the_margin():
    alpha = 0.3
    R_plane = Rotation.from_euler("x", alpha).as_matrix()  # its z axis is the plane's normal
    n = R_plane[:, 2]
    h = np.array([0.5, 0.5, 0.25])
    # the box aligned with the plane, its bottom face 2e-4 above it: four corners, gap 2e-4
    p = R_plane @ np.array([0.0, 0.0, 0.25 + 2e-4]) + 0.5 * n
    rows = run_halfspace(C.BOX, h, R_plane, p, normal=n, height=0.5)
    assert len(rows) == 4
    np.testing.assert_allclose(rows[:, 6], 2e-4, atol=TOL)
    np.testing.assert_allclose(rows[:, 3:6], np.tile(n, (4, 1)), atol=TOL)
    # tipped about its own x axis by 2e-3 rad: two bottom corners rise by hy sin(2e-3) ≈ 1e-3, out of the margin
    tip = R_plane @ Rotation.from_euler("x", 2e-3).as_matrix()
    rows = run_halfspace(C.BOX, h, tip, p, normal=n, height=0.5, margin=1e-3)
    corners = [p + tip @ (np.array([sx, sy, sz]) * h) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    gaps = sorted(n @ x - 0.5 for x in corners)
    assert len(rows) == sum(g < 1e-3 for g in gaps) == 2
    np.testing.assert_allclose(sorted(rows[:, 6]), gaps[:2], atol=TOL)


def test_capsule_lying_and_standing():
    r, half = 0.1, 0.4
    lying = Rotation.from_euler("y", np.pi / 2).as_matrix()
    rows = run_halfspace(C.CAPSULE, (r, half, 0), lying, (0.0, 0.0, r - 1e-4))
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set([[half, 0, -1e-4, 0, 0, 1, -1e-4],
                                                              [-half, 0, -1e-4, 0, 0, 1, -1e-4]]), atol=TOL)
    rows = run_halfspace(C.CAPSULE, (r, half, 0), I3, (0.0, 0.0, half + r))
    np.testing.assert_allclose(rows, [[0, 0, 0, 0, 0, 1, 0]], atol=TOL)


def test_cylinder_standing_and_lying_on_the_ground():
    r, half = 0.2, 0.3
    rows = run_halfspace(C.CYLINDER, (r, half, 0), Rotation.from_euler("z", 0.3).as_matrix(), (1.0, 0.0, half))
    assert len(rows) == 4
    np.testing.assert_allclose(rows[:, 2], 0.0, atol=TOL)
    np.testing.assert_allclose(rows[:, 6], 0.0, atol=TOL)
    np.testing.assert_allclose(np.hypot(rows[:, 0] - 1.0, rows[:, 1]), r, atol=TOL)
    # four points a quarter turn apart: they span the disc (their centroid is its centre)
    np.testing.assert_allclose(rows[:, :2].mean(axis=0), [1.0, 0.0], atol=TOL)
    lying = Rotation.from_euler("x", np.pi / 2).as_matrix()  # axis along −y
    rows = run_halfspace(C.CYLINDER, (r, half, 0), lying, (0.0, 0.0, r - 1e-4))
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set([[0, half, -1e-4, 0, 0, 1, -1e-4],
                                                              [0, -half, -1e-4, 0, 0, 1, -1e-4]]), atol=TOL)
    # tilted by 0.2 rad about x: the lowest rim point of the lower disc, at depth 1e-4
    tilt = Rotation.from_euler("x", 0.2).as_matrix()
    lowest = r * np.sin(0.2) + half * np.cos(0.2)
    rows = run_halfspace(C.CYLINDER, (r, half, 0), tilt, (0.0, 0.0, lowest - 1e-4))
    assert len(rows) == 1
    np.testing.assert_allclose(rows[0, 6], -1e-4, atol=TOL)
    np.testing.assert_allclose(rows[0, :3], tilt @ [0, -r, -half] + [0, 0, lowest - 1e-4], atol=TOL)


def test_convex_hull_of_a_cube_equals_the_box_against_a_halfspace():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = random_rotation(rng)
        p = rng.uniform(-0.2, 0.9, 3)
        normal = rng.standard_normal(3)
        box = run_halfspace(C.BOX, (0.5, 0.5, 0.5), R, p, normal=normal, height=0.1, margin=0.3)
        hull = run_halfspace(C.CONVEX, (0, 0, 0), R, p, normal=normal, height=0.1, margin=0.3, vertices=CUBE)
        assert rows_as_set(box) == rows_as_set(hull)


def test_convex_hull_with_many_vertices_keeps_the_deepest_and_the_extreme_ones():
    angles = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    ring = np.c_[np.cos(angles), np.sin(angles)]
    prism = np.r_[np.c_[ring, -0.1 * np.ones(32)], np.c_[ring, 0.1 * np.ones(32)]]
    tilt = Rotation.from_euler("x", 1e-5).as_matrix()  # the vertex at −y is the deepest
    rows = run_halfspace(C.CONVEX, (0, 0, 0), tilt, (0, 0, 0.1), vertices=prism, margin=1e-3)
    assert len(rows) == C.MAX_PAIR_CONTACTS
    gaps = [(tilt @ v)[2] + 0.1 for v in prism]
    assert np.isclose(rows[:, 6].min(), min(gaps), atol=TOL)
    assert np.all(rows[:, 6] < 1e-3)
    # the kept points are vertices of the bottom polygon and span it: the polygon of 7 of its 32 vertices
    # spread evenly has area ≥ (7/2) sin(2π/7) ≈ 0.87 π, the 32-gon's 0.99 π
    np.testing.assert_allclose(np.hypot(rows[:, 0], rows[:, 1]), 1.0, atol=1e-4)
    assert ConvexHull(rows[:, :2]).volume >= 0.85 * np.pi
    assert len({tuple(np.round(r, 12)) for r in rows}) == len(rows)


# ---------------------------------------------------------------------------------------------------------------------
# analytic pairs


def test_sphere_sphere():
    rows = run_pair((C.SPHERE, (0.3, 0, 0), I3, (0, 0, 1.0)), (C.SPHERE, (0.5, 0, 0), I3, (0, 0.6, 0.2)), margin=1.0)
    d = np.array([0, -0.6, 0.8])
    n = d / 1.0
    x_a = np.array([0, 0, 1.0]) - 0.3 * n
    x_b = np.array([0, 0.6, 0.2]) + 0.5 * n
    np.testing.assert_allclose(rows, [np.r_[(x_a + x_b) / 2, n, 0.2]], atol=TOL)
    assert len(run_pair((C.SPHERE, (0.3, 0, 0), I3, (0, 0, 1.0)), (C.SPHERE, (0.5, 0, 0), I3, (0, 0.6, 0.2)))) == 0


def test_sphere_box_face_edge_corner_and_inside():
    box = (C.BOX, (0.5, 0.4, 0.3), Rotation.from_euler("z", np.pi / 2).as_matrix(), (1.0, 0.0, 0.0))
    # world extents of the box: x ∈ [0.6, 1.4], y ∈ [−0.5, 0.5], z ∈ [−0.3, 0.3]
    face = run_pair((C.SPHERE, (0.2, 0, 0), I3, (1.1, 0.1, 0.5 - 1e-4)), box)
    np.testing.assert_allclose(face, [[1.1, 0.1, 0.3 - 0.5e-4, 0, 0, 1, -1e-4]], atol=TOL)
    corner = np.array([1.4, 0.5, 0.3])
    d = np.array([1.0, 2.0, 2.0]) / 3.0
    assert len(run_pair((C.SPHERE, (0.2, 0, 0), I3, corner + 0.25 * d), box)) == 0  # gap 0.05 ≥ margin
    rows = run_pair((C.SPHERE, (0.2, 0, 0), I3, corner + 0.25 * d), box, margin=0.1)
    np.testing.assert_allclose(rows, [np.r_[corner + 0.025 * d, d, 0.05]], atol=TOL)
    edge = np.array([1.4, 0.0, 0.3])
    e = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)
    rows = run_pair((C.SPHERE, (0.2, 0, 0), I3, edge + 0.19 * e), box)
    np.testing.assert_allclose(rows, [np.r_[edge - 0.005 * e, e, -0.01]], atol=TOL)
    # centre inside, nearest face x = 1.4 at 0.1: depth 0.1 + r
    rows = run_pair((C.SPHERE, (0.2, 0, 0), I3, (1.3, 0.1, 0.0)), box)
    np.testing.assert_allclose(rows, [[(1.1 + 1.4) / 2, 0.1, 0, 1, 0, 0, -0.3]], atol=TOL)


def test_sphere_capsule():
    capsule = (C.CAPSULE, (0.1, 0.5, 0), Rotation.from_euler("y", np.pi / 2).as_matrix(), (0.0, 0.0, 0.0))
    rows = run_pair((C.SPHERE, (0.2, 0, 0), I3, (0.3, 0.0, 0.29)), capsule)
    np.testing.assert_allclose(rows, [[0.3, 0, 0.095, 0, 0, 1, -0.01]], atol=TOL)
    # beyond the end x = 0.5: the end ball
    c = np.array([0.5, 0.0, 0.0]) + 0.3 * np.array([0.6, 0.0, 0.8])
    rows = run_pair((C.SPHERE, (0.2, 0, 0), I3, c), capsule, margin=0.1)
    n = np.array([0.6, 0.0, 0.8])
    np.testing.assert_allclose(rows, [np.r_[np.array([0.5, 0, 0]) + 0.1 * n, n, 0.0]], atol=TOL)


def test_capsule_capsule_crossed_and_parallel():
    along_x = Rotation.from_euler("y", np.pi / 2).as_matrix()
    along_y = Rotation.from_euler("x", np.pi / 2).as_matrix()
    rows = run_pair((C.CAPSULE, (0.1, 0.5, 0), along_y, (0.2, 0.1, 0.25)),
                    (C.CAPSULE, (0.2, 0.5, 0), along_x, (0, 0, 0)), margin=0.1)
    np.testing.assert_allclose(rows, [[0.2, 0, 0.175, 0, 0, 1, -0.05]], atol=TOL)
    # one lying on the other along x, shifted by 0.3: the overlap x ∈ [−0.2, 0.5] gives two points
    rows = run_pair((C.CAPSULE, (0.1, 0.5, 0), along_x, (0.3, 0.0, 0.3 - 1e-4)),
                    (C.CAPSULE, (0.2, 0.5, 0), along_x, (0, 0, 0)))
    expected = [[x, 0, 0.2 - 0.5e-4, 0, 0, 1, -1e-4] for x in (-0.2, 0.5)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)


def test_capsule_on_a_box_face():
    """A capsule lying on a box's top face is supported at its two end points (clipped to the face where it
    overhangs); tipped, only its lower end is within the margin; standing, one point."""
    box = (C.BOX, (1.0, 0.5, 0.5), I3, (0.0, 0.0, 0.0))
    along_x = Rotation.from_euler("y", np.pi / 2).as_matrix()
    r, half = 0.1, 0.4
    rows = run_pair(box, (C.CAPSULE, (r, half, 0), along_x, (0.2, 0.1, 0.6 - 1e-4)))
    expected = [[x, 0.1, 0.5 - 0.5e-4, 0, 0, -1, -1e-4] for x in (-0.2, 0.6)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)
    swapped = run_pair((C.CAPSULE, (r, half, 0), along_x, (0.2, 0.1, 0.6 - 1e-4)), box)
    np.testing.assert_allclose(swapped[:, 3:6], np.tile([0, 0, 1.0], (2, 1)), atol=TOL)
    # overhanging the face's edge x = 1: clipped there
    rows = run_pair(box, (C.CAPSULE, (r, half, 0), along_x, (0.9, 0.1, 0.6 + 2e-4)))
    expected = [[x, 0.1, 0.5 + 1e-4, 0, 0, -1, 2e-4] for x in (0.5, 1.0)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)
    # tipped by 0.01 rad about y: the ends' heights differ by 2 half sin(0.01) ≈ 8e-3, beyond the margin
    tipped = Rotation.from_euler("y", np.pi / 2 + 0.01).as_matrix()
    rows = run_pair(box, (C.CAPSULE, (r, half, 0), tipped, (0.0, 0.0, 0.6 + half * np.sin(0.01) - 1e-4)))
    assert len(rows) == 1
    np.testing.assert_allclose(rows[0, 6], -1e-4, atol=TOL)
    np.testing.assert_allclose(rows[0, :3], tipped @ [0, 0, half] + [0, 0, 0.6 + half * np.sin(0.01) - 1e-4]
                               + [0, 0, -r + 0.5e-4], atol=TOL)
    rows = run_pair(box, (C.CAPSULE, (r, half, 0), I3, (0.3, 0.2, 0.5 + half + r + 1e-4)))
    np.testing.assert_allclose(rows, [[0.3, 0.2, 0.5 + 0.5e-4, 0, 0, -1, 1e-4]], atol=TOL)


def test_box_on_a_larger_box_gives_four_corners_with_the_gap():
    big = (C.BOX, (2.0, 2.0, 0.5), I3, (0.0, 0.0, 0.0))
    for yaw in (0.0, 0.3, np.pi / 4):
        R = Rotation.from_euler("z", yaw).as_matrix()
        p = np.array([0.3, -0.2, 0.5 + 0.25 - 2e-4])
        rows = run_pair((C.BOX, (0.4, 0.3, 0.25), R, p), big)
        corners = [p + R @ np.array([sx * 0.4, sy * 0.3, -0.25]) for sx in (-1, 1) for sy in (-1, 1)]
        expected = [np.r_[x + [0, 0, 1e-4], 0, 0, 1, -2e-4] for x in corners]
        assert len(rows) == 4
        np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)
        swapped = run_pair(big, (C.BOX, (0.4, 0.3, 0.25), R, p))
        flipped = swapped.copy()
        flipped[:, 3:6] *= -1
        np.testing.assert_allclose(rows_as_set(flipped), rows_as_set(expected), atol=1e-9)


def test_box_overlapping_a_box_gives_the_overlap_polygon_corners():
    # equal boxes, the top one shifted by (0.5, 0.25): overlap x ∈ [0, 0.5], y ∈ [−0.25, 0.5]
    a = (C.BOX, (0.5, 0.5, 0.5), I3, (0.5, 0.25, 1.0 - 1e-3))
    rows = run_pair(a, (C.BOX, (0.5, 0.5, 0.5), I3, (0.0, 0.0, 0.0)), margin=1e-2)
    expected = [[x, y, 0.5 - 0.5e-3, 0, 0, 1, -1e-3] for x in (0.0, 0.5) for y in (-0.25, 0.5)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)
    # rotated by 45°: the clipped octagon has 8 corners
    R = Rotation.from_euler("z", np.pi / 4).as_matrix()
    rows = run_pair((C.BOX, (0.5, 0.5, 0.5), R, (0.0, 0.0, 1.0 - 1e-3)),
                    (C.BOX, (0.5, 0.5, 0.5), I3, (0.0, 0.0, 0.0)))
    assert len(rows) == 8
    np.testing.assert_allclose(rows[:, 6], -1e-3, atol=TOL)
    # every corner on the boundary of both squares
    np.testing.assert_allclose(np.max(np.abs(rows[:, :2]), axis=1), 0.5, atol=TOL)
    rotated = rows[:, :2] @ R[:2, :2]
    np.testing.assert_allclose(np.max(np.abs(rotated), axis=1), 0.5, atol=TOL)


def test_box_edge_on_box_edge_gives_one_point():
    # a's edge along x on top (rolled 45°), b's edge along y at the bottom (pitched 45°)
    Ra = Rotation.from_euler("x", np.pi / 4).as_matrix()
    Rb = Rotation.from_euler("y", np.pi / 4).as_matrix()
    s = 0.5 * np.sqrt(2)
    rows = run_pair((C.BOX, (0.5, 0.5, 0.5), Ra, (0.1, 0.2, 2 * s - 1e-3)), (C.BOX, (0.5, 0.5, 0.5), Rb, (0, 0, 0)),
                    margin=1e-2)
    np.testing.assert_allclose(rows, [[0.0, 0.2, s - 0.5e-3, 0, 0, 1, -1e-3]], atol=TOL)


# ---------------------------------------------------------------------------------------------------------------------
# symmetry and GJK/EPA against the analytic routines


def random_geometry(shape, rng):
    if shape == C.CONVEX:
        # a random polytope: the hull of 12 points on an ellipsoid
        points = rng.standard_normal((12, 3))
        points *= rng.uniform(0.1, 0.4, 3) / np.linalg.norm(points, axis=1, keepdims=True)
        return (shape, (0, 0, 0), random_rotation(rng), rng.uniform(-0.4, 0.4, 3), points)
    if shape == C.SPHERE:
        size = (rng.uniform(0.1, 0.5), 0, 0)
    elif shape == C.BOX:
        size = tuple(rng.uniform(0.1, 0.5, 3))
    else:
        size = (rng.uniform(0.05, 0.3), rng.uniform(0.1, 0.5), 0)
    p = rng.uniform(-0.4, 0.4, 3)
    return (shape, size, random_rotation(rng), p)


PAIRS = [(C.SPHERE, C.SPHERE), (C.SPHERE, C.BOX), (C.SPHERE, C.CAPSULE), (C.CAPSULE, C.CAPSULE), (C.BOX, C.BOX),
         (C.BOX, C.CAPSULE), (C.CYLINDER, C.BOX), (C.CYLINDER, C.SPHERE), (C.CYLINDER, C.CYLINDER),
         (C.CONVEX, C.CAPSULE), (C.CONVEX, C.CONVEX)]


@pytest.mark.parametrize("shapes", PAIRS)
def test_swapping_a_and_b_flips_the_normals_and_keeps_gaps_and_points(shapes):
    rng = np.random.default_rng(sum(shapes))
    for _ in range(40):
        a = random_geometry(shapes[0], rng)
        b = random_geometry(shapes[1], rng)
        ab = run_pair(a, b, margin=1.0)
        ba = run_pair(b, a, margin=1.0)
        assert len(ab) == len(ba) >= 1
        ba[:, 3:6] *= -1
        np.testing.assert_allclose(rows_as_set(ab, 6), rows_as_set(ba, 6), atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(ab[:, 3:6], axis=1), 1.0, atol=TOL)


@pytest.mark.parametrize("shapes", [(C.SPHERE, C.SPHERE), (C.SPHERE, C.BOX), (C.BOX, C.SPHERE), (C.SPHERE, C.CAPSULE),
                                    (C.CAPSULE, C.CAPSULE), (C.BOX, C.CAPSULE), (C.CAPSULE, C.BOX)])
def test_gjk_epa_agrees_with_the_analytic_routines(shapes):
    """One contact each (random poses never make parallel axes or a capsule flat on a face): the same row;
    box–capsule on a face reports the clipped segment's ends, the nearer of which is GJK's contact."""
    rng = np.random.default_rng(10 + 7 * shapes[0] + shapes[1])
    overlaps = 0
    for _ in range(80):
        a = random_geometry(shapes[0], rng)
        b = random_geometry(shapes[1], rng)
        analytic = run_pair(a, b, margin=10.0)
        gjk = run_pair(a, b, margin=10.0, convex=True)
        assert len(gjk) == 1 and 1 <= len(analytic) <= 2
        nearest = analytic[np.argmin(analytic[:, 6])]
        overlaps += nearest[6] < 0
        np.testing.assert_allclose(nearest, gjk[0], atol=1e-9, rtol=0)
    assert 10 <= overlaps <= 70  # both separated and penetrating poses were drawn


def test_gjk_epa_agrees_with_box_box():
    """Separated boxes: the nearest contact is GJK's (distance, normal). Overlapping boxes: the box–box axis
    of least penetration is EPA's depth and direction (both are the least translation separating two
    polytopes); the clipped points are no deeper than that depth."""
    rng = np.random.default_rng(3)
    separated = overlapping = 0
    for _ in range(200):
        a = random_geometry(C.BOX, rng)
        b = random_geometry(C.BOX, rng)
        gjk = run_pair(a, b, margin=10.0, convex=True)
        analytic = run_pair(a, b, margin=10.0)
        nearest = analytic[np.argmin(analytic[:, 6])]
        assert np.all(analytic[:, 3:6] == nearest[3:6])
        np.testing.assert_allclose(nearest[3:6], gjk[0, 3:6], atol=1e-9)
        if gjk[0, 6] > 0:
            np.testing.assert_allclose(nearest[6], gjk[0, 6], atol=1e-9)
            separated += 1
        else:
            normal = nearest[3:6]
            ra = np.sum(np.asarray(a[1]) * np.abs(a[2].T @ normal))
            rb = np.sum(np.asarray(b[1]) * np.abs(b[2].T @ normal))
            np.testing.assert_allclose(abs(normal @ (a[3] - b[3])) - ra - rb, gjk[0, 6], atol=1e-9)
            assert analytic[:, 6].min() >= gjk[0, 6] - 1e-9
            overlapping += 1
    assert separated >= 30 and overlapping >= 50


def test_boxes_corner_to_corner_give_the_distance():
    """Two unit cubes corner to corner along the diagonal d, 0.1 apart: the separating-axis value 0.1/√3 is a
    lower bound; the contact is at the corners' midpoint, along d, with gap 0.1."""
    d = np.ones(3) / np.sqrt(3)
    a = (C.BOX, (0.5, 0.5, 0.5), I3, np.full(3, 0.5) + 0.1 * d)
    b = (C.BOX, (0.5, 0.5, 0.5), I3, -np.full(3, 0.5))
    np.testing.assert_allclose(run_pair(a, b, margin=0.2), [np.r_[0.05 * d, d, 0.1]], atol=1e-12)
    assert len(run_pair(a, b, margin=0.09)) == 0


def test_cylinder_against_a_sphere_closed_form():
    """Sphere centre at radial distance ρ and height z in the cylinder's frame: outside,
    gap = √(max(ρ − r, 0)² + max(|z| − h, 0)²) − r_s; inside, gap = −min(r − ρ, h − |z|) − r_s."""
    rng = np.random.default_rng(4)
    inside = 0
    for _ in range(150):
        r, h = rng.uniform(0.1, 0.4), rng.uniform(0.1, 0.4)
        R = random_rotation(rng)
        p = rng.uniform(-0.3, 0.3, 3)
        rs = rng.uniform(0.05, 0.3)
        c = rng.uniform(-0.5, 0.5, 3)
        local = R.T @ (c - p)
        rho, z = np.hypot(local[0], local[1]), abs(local[2])
        if rho <= r and z <= h:
            gap = -min(r - rho, h - z) - rs
            inside += 1
        else:
            gap = np.hypot(max(rho - r, 0.0), max(z - h, 0.0)) - rs
        for rows, sign in ((run_pair((C.SPHERE, (rs, 0, 0), I3, c), (C.CYLINDER, (r, h, 0), R, p), margin=10.0), 1),
                           (run_pair((C.CYLINDER, (r, h, 0), R, p), (C.SPHERE, (rs, 0, 0), I3, c), margin=10.0), -1)):
            assert len(rows) == 1
            np.testing.assert_allclose(rows[0, 6], gap, atol=1e-9)
            # the sphere's witness, point + gap/2 n (n into the sphere), is its point nearest (deepest in) the
            # cylinder; on a curved surface the direction converges as the square root of the gap's tolerance
            n = sign * rows[0, 3:6]
            np.testing.assert_allclose(rows[0, :3] + 0.5 * rows[0, 6] * n, c - rs * n, atol=1e-6)
    assert inside >= 10


def test_cylinder_against_its_many_sided_prism():
    """A cylinder and the convex hull of a 128-sided prism inscribed in it, against boxes, spheres, capsules
    and cylinders: the gaps differ by at most the prism's inset r (1 − cos(π/128))."""
    angles = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    rng = np.random.default_rng(11)
    for k in range(120):
        r, h = rng.uniform(0.1, 0.4), rng.uniform(0.1, 0.4)
        ring = np.c_[r * np.cos(angles), r * np.sin(angles)]
        prism = np.r_[np.c_[ring, -h * np.ones(128)], np.c_[ring, h * np.ones(128)]]
        R = random_rotation(rng)
        p = rng.uniform(-0.3, 0.3, 3)
        other = random_geometry([C.BOX, C.SPHERE, C.CAPSULE, C.CYLINDER][k % 4], rng)
        cylinder = run_pair((C.CYLINDER, (r, h, 0), R, p), other, margin=10.0)
        hull = run_pair((C.CONVEX, (0, 0, 0), R, p, prism), other, margin=10.0)
        assert len(cylinder) >= 1 and len(hull) >= 1
        assert abs(cylinder[:, 6].min() - hull[:, 6].min()) <= r * (1 - np.cos(np.pi / 128)) + 1e-9


def test_convex_hull_of_a_cube_equals_the_box_in_pairs():
    rng = np.random.default_rng(5)
    for shape in (C.SPHERE, C.CAPSULE, C.BOX):
        for _ in range(30):
            R = random_rotation(rng)
            p = rng.uniform(-0.3, 0.3, 3)
            other = random_geometry(shape, rng)
            hull = run_pair((C.CONVEX, (0, 0, 0), R, p, CUBE), other, margin=10.0)
            box = run_pair((C.BOX, (0.5, 0.5, 0.5), R, p), other, margin=10.0, convex=True)
            # against a box face the hull reports every vertex within the margin: the nearest is GJK/EPA's
            np.testing.assert_allclose(hull[np.argmin(hull[:, 6])], box[0], atol=1e-9)
            if shape == C.SPHERE:
                np.testing.assert_allclose(hull, run_pair((C.BOX, (0.5, 0.5, 0.5), R, p), other, margin=10.0),
                                           atol=1e-9)


def test_cylinder_standing_and_lying_on_a_box():
    """Against a box face, a cylinder gives what it gives against the face's plane, where over the face: standing,
    four rim points; lying, the two lowest rim points; overhanging the edge, its cap cut at the edge."""
    box = (C.BOX, (1.0, 1.0, 0.5), I3, (0.0, 0.0, 0.0))
    yaw = Rotation.from_euler("z", 0.4).as_matrix()
    rows = run_pair((C.CYLINDER, (0.2, 0.3, 0), yaw, (0.1, 0.2, 0.8 - 1e-4)), box)
    assert len(rows) == 4
    np.testing.assert_allclose(rows[:, 3:], np.tile([0, 0, 1, -1e-4], (4, 1)), atol=TOL)
    np.testing.assert_allclose(np.hypot(rows[:, 0] - 0.1, rows[:, 1] - 0.2), 0.2, atol=TOL)
    np.testing.assert_allclose(rows[:, 2], 0.5 - 0.5e-4, atol=TOL)
    on_plane = run_halfspace(C.CYLINDER, (0.2, 0.3, 0), yaw, (0.1, 0.2, 0.8 - 1e-4), height=0.5)
    np.testing.assert_allclose(rows_as_set(rows[:, :2]), rows_as_set(on_plane[:, :2]), atol=TOL)
    swapped = run_pair(box, (C.CYLINDER, (0.2, 0.3, 0), yaw, (0.1, 0.2, 0.8 - 1e-4)))
    np.testing.assert_allclose(rows_as_set(swapped[:, :3]), rows_as_set(rows[:, :3]), atol=TOL)
    np.testing.assert_allclose(swapped[:, 3:6], -rows[:, 3:6], atol=TOL)
    lying = Rotation.from_euler("x", np.pi / 2).as_matrix()
    rows = run_pair((C.CYLINDER, (0.2, 0.3, 0), lying, (0.1, 0.2, 0.7 + 1e-4)), box)
    expected = [[0.1, 0.2 + y, 0.5 + 0.5e-4, 0, 0, 1, 1e-4] for y in (-0.3, 0.3)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)
    # standing over the face's edge x = 1: its cap cut at the edge (clip_manifold), four points on the cap over the
    # face, the rim point (0.85, 0) and the two ends of the cut among them
    rows = run_pair((C.CYLINDER, (0.2, 0.3, 0), I3, (1.05, 0.0, 0.8 - 1e-4)), box)
    assert len(rows) == 4
    np.testing.assert_allclose(rows[:, 2:], np.tile([0.5 - 0.5e-4, 0, 0, 1, -1e-4], (4, 1)), atol=1e-12)
    assert (rows[:, 0] <= 1.0 + 1e-12).all() and (np.hypot(rows[:, 0] - 1.05, rows[:, 1]) <= 0.2 + 1e-12).all()
    assert np.isclose(rows[:, :2], [0.85, 0.0], atol=1e-12).all(axis=1).any()
    cut = np.isclose(rows[:, 0], 1.0, atol=1e-12)
    assert cut.sum() == 2 and rows[cut, 1].min() < 0.0 < rows[cut, 1].max()


def test_convex_hull_of_a_cube_on_a_box_gives_its_corners():
    """A hull (the cube's vertices) resting on a larger box: its four lower corners, as box on box does."""
    big = (C.BOX, (2.0, 2.0, 0.5), I3, (0.0, 0.0, 0.0))
    R = Rotation.from_euler("z", 0.3).as_matrix()
    p = np.array([0.3, -0.2, 1.0 - 2e-4])
    hull = run_pair((C.CONVEX, (0, 0, 0), R, p, CUBE), big)
    box = run_pair((C.BOX, (0.5, 0.5, 0.5), R, p), big)
    assert len(hull) == 4
    np.testing.assert_allclose(rows_as_set(hull), rows_as_set(box), atol=1e-9)


def test_pairs_beyond_the_margin_give_nothing():
    rng = np.random.default_rng(8)
    for shapes in PAIRS:
        a = random_geometry(shapes[0], rng)
        b = random_geometry(shapes[1], rng)
        far = b[:3] + (np.asarray(b[3]) + [3.0, 0, 0],) + b[4:]
        assert len(run_pair(a, far, margin=0.5)) == 0
        assert len(run_pair(far, a, margin=0.5)) == 0


def test_non_finite_poses_end_without_contacts_or_hanging():
    """A NaN in a pose ends every loop (GJK's and EPA's are bounded) and writes no contact."""
    rng = np.random.default_rng(2)
    for shapes in PAIRS:
        a = random_geometry(shapes[0], rng)
        b = random_geometry(shapes[1], rng)
        bad = a[:3] + (np.array([np.nan, 0.0, 0.0]),) + a[4:]
        assert len(run_pair(bad, b, margin=10.0)) == 0
        assert len(run_pair(b, bad, margin=10.0)) == 0
        assert len(run_halfspace(bad[0], bad[1], bad[2], bad[3], margin=10.0,
                                 vertices=bad[4] if len(bad) > 4 else NO_VERTICES)) == 0
