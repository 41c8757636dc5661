"""Contact manifolds of the GJK/EPA pairs (:func:`multibody.kernels.collision.clip_manifold`).

A hull face resting on a hull face gives the corners of their overlap (as box on box does), a cylinder standing on a
hull points of its rim, a capsule lying along a cylinder two points; edge–edge and vertex–face contacts stay one
point; swapping a and b flips the normals only; on random poses every point lies on both surfaces and the deepest is
GJK/EPA's contact.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation
from test_collision import CUBE, I3, random_rotation, rows_as_set, run_pair

from multibody.kernels import collision as C

TOL = 1e-12


def cuboid(hx, hy, hz):
    """The 8 vertices of the box of half-extents ``(hx, hy, hz)``."""
    return np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)])


def hull(vertices, R=I3, p=(0.0, 0.0, 0.0)):
    return (C.CONVEX, (0, 0, 0), np.asarray(R, float), np.asarray(p, float), np.asarray(vertices, float))


def swapped(rows):
    """Rows of the pair (b, a) as those of (a, b): the normals flipped."""
    rows = rows.copy()
    rows[:, 3:6] *= -1
    return rows


# ---------------------------------------------------------------------------------------------------------------------
# faces on faces


@pytest.mark.parametrize("yaw", [0.0, 0.3])
def test_hull_cube_on_a_hull_cube_gives_the_overlap_corners_as_box_on_box(yaw):
    """A unit hull cube resting 1e-4 deep on another, shifted by (0.3, 0.2): the four corners of the faces' overlap,
    with the points, normals and depths of the box–box routine to 1e-12; a smaller cube turned by a yaw on the
    larger one: its own four corners."""
    R = Rotation.from_euler("z", yaw).as_matrix()
    half = 0.5 if yaw == 0.0 else 0.2
    p = np.array([0.3, 0.2, 0.5 + half - 1e-4]) if yaw == 0.0 else np.array([0.1, 0.05, 0.7 - 1e-4])
    rows = run_pair(hull(cuboid(half, half, half), R, p), hull(CUBE))
    boxes = run_pair((C.BOX, (half, half, half), R, p), (C.BOX, (0.5, 0.5, 0.5), I3, (0, 0, 0)))
    assert len(rows) == len(boxes) == 4
    np.testing.assert_allclose(rows_as_set(rows, 12), rows_as_set(boxes, 12), atol=TOL)
    np.testing.assert_allclose(rows[:, 6], -1e-4, atol=TOL)
    np.testing.assert_allclose(rows_as_set(swapped(run_pair(hull(CUBE), hull(cuboid(half, half, half), R, p))), 12),
                               rows_as_set(rows, 12), atol=TOL)


@pytest.mark.parametrize("gap", [1e-12, 3e-12, 1e-11, 3e-11, 1e-10, 1e-7])
def test_a_hull_cube_a_little_above_a_hull_slab(gap):
    """A hull cube ``gap`` above a wide hull slab (GJK's nearest points in a triangle of A − B, ``gap`` apart): the
    normal is the face's to 1e-15 (the triangle's normal, not the difference of the nearly equal witnesses), so the
    contact is the cube's four lower corners with that gap."""
    R = Rotation.from_euler("z", 0.25).as_matrix()
    a = hull(CUBE, R, (0.123, 0.0, 0.6 + gap))
    b = hull(cuboid(20.0, 20.0, 0.1))
    single = run_pair(a, b, convex=True)
    np.testing.assert_allclose(single[0, 3:6], [0, 0, 1], atol=1e-15)
    rows = run_pair(a, b)
    corners = (R @ CUBE.T).T[CUBE[:, 2] < 0] + [0.123, 0.0, 0.6 + 0.5 * gap]
    np.testing.assert_allclose(rows_as_set(rows[:, :3], 12), rows_as_set(corners, 12), atol=TOL)
    np.testing.assert_allclose(rows[:, 3:], np.tile([0, 0, 1, gap], (4, 1)), atol=1e-15)


def test_hull_prism_lying_over_the_edge_of_a_hull_slab():
    """A triangular prism (hull) lying on its rectangular face across the edge x = 1 of a hull slab: the face is
    clipped at the edge, so the points are its two corners over the slab and the two where its long edges cross
    x = 1, at the depth 1e-4."""
    prism = np.array([[x, y, z] for x in (-0.4, 0.4) for y, z in ((-0.2, 0.0), (0.2, 0.0), (0.0, 0.3))])
    slab = cuboid(1.0, 1.0, 0.1)
    rows = run_pair(hull(prism, I3, (0.9, 0.0, 0.1 - 1e-4)), hull(slab))
    expected = [[x, y, 0.1 - 0.5e-4, 0, 0, 1, -1e-4] for x in (0.5, 1.0) for y in (-0.2, 0.2)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)
    back = run_pair(hull(slab), hull(prism, I3, (0.9, 0.0, 0.1 - 1e-4)))
    np.testing.assert_allclose(rows_as_set(swapped(back)), rows_as_set(expected), atol=TOL)


def test_hull_prism_and_cube_overhanging_a_box_face():
    """A hull overhanging the edge x = 1 of a box face (its vertices not all over the face): its lower face is cut at
    the edge, as box on box does, instead of keeping only the vertices over the face (which would leave a cube
    supported on one line, its centre beyond it)."""
    box = (C.BOX, (1.0, 1.0, 0.5), I3, (0.0, 0.0, 0.0))
    p = np.array([0.95, 0.3, 0.6 - 1e-4])
    rows = run_pair(hull(cuboid(0.1, 0.1, 0.1), I3, p), box)
    boxes = run_pair((C.BOX, (0.1, 0.1, 0.1), I3, p), box)
    assert len(rows) == 4
    np.testing.assert_allclose(rows_as_set(rows, 12), rows_as_set(boxes, 12), atol=TOL)
    prism = np.array([[x, y, z] for x in (-0.4, 0.4) for y, z in ((-0.2, 0.0), (0.2, 0.0), (0.0, 0.3))])
    rows = run_pair(hull(prism, I3, (0.9, 0.0, 0.5 - 1e-4)), box)
    expected = [[x, y, 0.5 - 0.5e-4, 0, 0, 1, -1e-4] for x in (0.5, 1.0) for y in (-0.2, 0.2)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=TOL)


def test_box_edge_on_a_hull_prism_face():
    """A box whose lower edge lies along the slanted face of a hull wedge (the face's normal is no box face's, so
    the box-face rule does not apply): the box's edge, clipped to the face, gives its two ends."""
    wedge = np.array([[x, y, z] for x in (-1.0, 1.0) for y, z in ((-1.0, -0.5), (1.0, -0.5), (1.0, 0.5))])
    face = np.array([0.0, -1.0, 2.0]) / np.sqrt(5.0)  # the outward normal of the wedge's slanted face −y + 2z = 0
    assert np.allclose((wedge @ face)[[0, 2, 3, 5]], 0.0) and (wedge @ face < 1e-12).all()
    # the box: half-extents (0.3, 0.2, 0.2), one edge (along x) on the face, turned so its faces make 30° and 60°
    # with the slanted face: its lowest edge touches the face 1e-4 deep
    tilt = np.arctan2(2.0, -1.0) - np.radians(30.0)
    R = Rotation.from_euler("x", tilt).as_matrix()
    h = np.array([0.3, 0.2, 0.2])
    corner = R @ np.array([0.0, -h[1], -h[2]])  # the box's edge at y, z = −h in its frame
    p = np.array([0.1, 0.0, 0.0]) - corner - 1e-4 * face
    rows = run_pair((C.BOX, tuple(h), R, p), hull(wedge))
    ends = [np.array([0.1 + s * 0.3, 0.0, 0.0]) - 0.5e-4 * face for s in (-1.0, 1.0)]
    expected = [np.r_[x, face, -1e-4] for x in ends]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)


def test_cylinder_standing_and_lying_on_a_hull():
    """A cylinder standing on its cap 1e-4 deep in a hull slab: four points a quarter turn apart on its rim; lying on
    its side, the two ends of its lowest line; a capsule lying over the slab's edge: its end and the edge; a capsule
    lying along the side of a cylinder: two points, at the ends of the overlap of their lines."""
    slab = hull(cuboid(1.0, 1.0, 0.1))
    R = Rotation.from_euler("xz", [1e-9, 0.7]).as_matrix()
    rows = run_pair((C.CYLINDER, (0.2, 0.3, 0), R, (0.1, 0.2, 0.4 - 1e-4)), slab)
    assert len(rows) == 4
    np.testing.assert_allclose(np.hypot(rows[:, 0] - 0.1, rows[:, 1] - 0.2), 0.2, atol=1e-9)
    np.testing.assert_allclose(rows[:, 2:], np.tile([0.1 - 0.5e-4, 0, 0, 1, -1e-4], (4, 1)), atol=1e-9)
    around = np.sort(np.arctan2(rows[:, 1] - 0.2, rows[:, 0] - 0.1))
    np.testing.assert_allclose(np.diff(around), np.pi / 2, atol=1e-9)
    lying = Rotation.from_euler("x", np.pi / 2).as_matrix()
    rows = run_pair((C.CYLINDER, (0.2, 0.3, 0), lying, (0.1, 0.2, 0.3 - 1e-4)), slab)
    expected = [[0.1, 0.2 + y, 0.1 - 0.5e-4, 0, 0, 1, -1e-4] for y in (-0.3, 0.3)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)
    # a capsule (r 0.05, half length 0.4) lying along x over the slab's edge x = 1: its end and the edge
    along = Rotation.from_euler("y", np.pi / 2).as_matrix()
    capsule = (C.CAPSULE, (0.05, 0.4, 0), along, (0.9, 0.3, 0.15 - 1e-4))
    rows = run_pair(capsule, slab)
    expected = [[x, 0.3, 0.1 - 0.5e-4, 0, 0, 1, -1e-4] for x in (0.5, 1.0)]
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)
    # a capsule (r 0.05, half length 0.4) along x on a cylinder (r 0.2, half length 0.3) lying along x
    capsule = (C.CAPSULE, (0.05, 0.4, 0), along, (0.5, 0.0, 0.25 - 1e-4))
    cylinder = (C.CYLINDER, (0.2, 0.3, 0), along, (0.0, 0.0, 0.0))
    expected = [[x, 0.0, 0.2 - 0.5e-4, 0, 0, 1, -1e-4] for x in (0.1, 0.3)]
    rows = run_pair(capsule, cylinder)
    np.testing.assert_allclose(rows_as_set(rows), rows_as_set(expected), atol=1e-9)
    np.testing.assert_allclose(rows_as_set(swapped(run_pair(cylinder, capsule))), rows_as_set(expected), atol=1e-9)


def test_edge_on_edge_and_vertex_on_face_give_one_point():
    """Two hull cubes with crossed edges touching, and a hull cube standing on a corner on a hull slab: one contact
    each, GJK/EPA's."""
    diagonal = Rotation.from_euler("x", np.pi / 4).as_matrix()
    crossed = Rotation.from_euler("zy", [np.pi / 2, np.pi / 4]).as_matrix()
    s = np.sqrt(0.5)
    a = hull(CUBE, diagonal, (0.0, 0.0, 2 * s - 1e-4))
    b = hull(CUBE, crossed, (0.0, 0.0, 0.0))
    rows = run_pair(a, b)
    assert len(rows) == 1
    np.testing.assert_allclose(rows[0], [0, 0, s - 0.5e-4, 0, 0, 1, -1e-4], atol=1e-9)
    np.testing.assert_allclose(rows, run_pair(a, b, convex=True), atol=TOL)
    corner = Rotation.align_vectors([[0, 0, -1]], [[-1, -1, -1]])[0].as_matrix()
    a = hull(CUBE, corner, (0.2, 0.1, np.sqrt(0.75) - 1e-4))
    rows = run_pair(a, hull(cuboid(1.0, 1.0, 0.1), I3, (0, 0, -0.1)))
    assert len(rows) == 1
    np.testing.assert_allclose(rows[0], [0.2, 0.1, -0.5e-4, 0, 0, 1, -1e-4], atol=1e-9)


# ---------------------------------------------------------------------------------------------------------------------
# random poses


def random_hull(rng):
    """The hull of 12 random points on an ellipsoid, with its facets' planes ``A x + c ≤ 0`` (unit ``A``)."""
    points = rng.standard_normal((12, 3))
    points *= rng.uniform(0.1, 0.4, 3) / np.linalg.norm(points, axis=1, keepdims=True)
    shape = ConvexHull(points)
    return points[shape.vertices], shape.equations


def surface_distance(equations, R, p, x):
    """The signed distance of the world point ``x`` to a hull's surface (exact inside, a lower bound outside)."""
    local = R.T @ (x - p)
    return np.max(equations[:, :3] @ local + equations[:, 3])


def face_to_face(rng, points_a, equations_a, points_b, equations_b):
    """A pose of hull a with a random face on a random face of hull b, 1e-4 deep, the faces' centroids a little apart:
    ``(R_a, p_a, R_b, p_b)``."""
    R_b = random_rotation(rng)
    p_b = rng.uniform(-0.2, 0.2, 3)
    fa = rng.integers(len(equations_a))
    fb = rng.integers(len(equations_b))
    n_b = R_b @ equations_b[fb, :3]
    # a's face normal turned onto −n_b, then a random turn about n_b
    turn = Rotation.align_vectors([-n_b], [equations_a[fa, :3]])[0]
    R_a = Rotation.from_rotvec(rng.uniform(-np.pi, np.pi) * n_b).as_matrix() @ turn.as_matrix()
    on_a = points_a[np.abs(points_a @ equations_a[fa, :3] + equations_a[fa, 3]) < 1e-9].mean(axis=0)
    on_b = R_b @ points_b[np.abs(points_b @ equations_b[fb, :3] + equations_b[fb, 3]) < 1e-9].mean(axis=0) + p_b
    shift = rng.uniform(-0.03, 0.03, 3)
    shift -= (shift @ n_b) * n_b
    p_a = on_b + shift - 1e-4 * n_b - R_a @ on_a
    return R_a, p_a, R_b, p_b


@pytest.mark.parametrize("placed", [False, True])
def test_random_hulls_points_on_both_surfaces_and_the_deepest_is_epa(placed):
    """Random hull pairs, in random poses or with a face on a face: every point's witnesses ``point ± (gap/2) n`` lie
    on a's and b's surfaces, to rounding (1e-12 m) but where a feature took in a vertex lying within its band under
    a face (``FEATURE_ANGLE`` times the hull's radius: the face's polygon then bends to that vertex), and the deepest
    point's gap is GJK/EPA's (to 1e-9 m); faces on faces give several points, swapping a and b the same points."""
    rng = np.random.default_rng(21 + placed)
    several = 0
    exact = total = 0
    for _ in range(100):
        points_a, equations_a = random_hull(rng)
        points_b, equations_b = random_hull(rng)
        if placed:
            R_a, p_a, R_b, p_b = face_to_face(rng, points_a, equations_a, points_b, equations_b)
        else:
            R_a, p_a, R_b, p_b = random_rotation(rng), rng.uniform(-0.3, 0.3, 3), random_rotation(rng), \
                rng.uniform(-0.3, 0.3, 3)
        a, b = hull(points_a, R_a, p_a), hull(points_b, R_b, p_b)
        rows = run_pair(a, b, margin=1e-3)
        single = run_pair(a, b, margin=1e-3, convex=True)
        assert len(rows) >= 1 or len(single) == 0
        if len(single) == 0:
            continue
        assert len(rows) <= C.MANIFOLD_POINTS
        np.testing.assert_allclose(rows[:, 6].min(), single[0, 6], atol=1e-9)
        for row in rows:
            n, gap = row[3:6], row[6]
            assert gap < 1e-3
            on_a = abs(surface_distance(equations_a, R_a, p_a, row[:3] + 0.5 * gap * n))
            on_b = abs(surface_distance(equations_b, R_b, p_b, row[:3] - 0.5 * gap * n))
            assert on_a <= C.FEATURE_ANGLE * np.linalg.norm(points_a, axis=1).max()
            assert on_b <= C.FEATURE_ANGLE * np.linalg.norm(points_b, axis=1).max()
            exact += on_a <= 1e-12 and on_b <= 1e-12
            total += 1
        several += len(rows) >= 3
        if len(rows) <= 3:
            # (unreduced manifolds: the same points either way, to rounding; a reduction to 4 may keep others)
            back = swapped(run_pair(b, a, margin=1e-3))
            assert len(back) == len(rows)
            distance = np.abs(rows[:, None, :7] - back[None, :, :7]).max(axis=2)
            assert distance.min(axis=1).max() <= 1e-12 and distance.min(axis=0).max() <= 1e-12
    assert exact >= 0.95 * total
    if placed:
        assert several >= 50
