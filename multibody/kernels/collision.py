"""Contact detection between convex shapes and against a half-space, compiled and allocation-free.

Each function reads a geometry as its shape code, its ``size (3,)`` in kernel convention, its hull
``vertices (k, 3)`` (geometry frame; used by ``CONVEX`` only, any array otherwise) and its world pose
``R (3, 3)``, ``p (3,)`` (the geometry frame in the world: ``x_world = R x_geometry + p``), and writes
contact rows ``[px, py, pz, nx, ny, nz, gap]`` (``CONTACT_COLUMNS``) into ``out (MAX_PAIR_CONTACTS, 7)``:

* ``n``: unit normal in world axes, pointing from the other object (``b``, or the half-space) into ``a``;
* ``gap``: the signed distance between the two surfaces along ``n`` (m; negative is penetration);
* ``p``: for a pair, the midpoint of the two surfaces' witness points ``(x_a + x_b)/2`` with
  ``x_a − x_b = gap · n``; against a half-space, the point on ``a``'s surface (its feature).

Sizes (kernel convention): sphere ``(r, 0, 0)``; box half-extents ``(hx, hy, hz)``; capsule and
cylinder ``(r, half length, 0)``, their axis the geometry frame's z; convex ``(0, 0, 0)`` with its
vertices. Every feature with ``gap < margin`` is reported, at most ``MAX_PAIR_CONTACTS`` per call;
scratch lives in ``ws`` (float64, ``PAIR_WORKSPACE`` entries). The code keeps to the subset that Numba
compiles for CUDA too (:mod:`multibody.gpu`): loops, scalars and tuples, no allocation.

Sources: C. Ericson, *Real-Time Collision Detection*, Morgan Kaufmann 2005 (RTCD) for the primitive
tests, the closest points, the separating-axis test of boxes and the polygon clipping;
E. G. Gilbert, D. W. Johnson, S. S. Keerthi, "A fast procedure for computing the distance between
complex objects in three-dimensional space", IEEE J. Robotics and Automation 4(2), 1988 (GJK);
G. van den Bergen, *Collision Detection in Interactive 3D Environments*, Morgan Kaufmann 2003, §4.3
(the GJK loop and its termination) and §4.3.8 (the expanding polytope algorithm, EPA); and
D. Gregorius, "Robust Contact Creation for Physics Simulations", GDC 2015, for the reference-face clipping
and the reduction of a manifold to the points spanning the largest area.
"""

from __future__ import annotations

import math

from .jit import njit
from .spatial import (
    add3,
    cross,
    dot3,
    larger,
    load3,
    rotate,
    rotate_back,
    row3,
    scale3,
    smaller,
    store_row,
    sub3,
)

#: Shape codes (``CollisionTable.shapes``).
SPHERE, BOX, CAPSULE, CYLINDER, CONVEX = 0, 1, 2, 3, 4
#: Most contact rows one call writes, and the columns of a row ``[px, py, pz, nx, ny, nz, gap]``.
MAX_PAIR_CONTACTS = 8
CONTACT_COLUMNS = 7

#: Capacities of the GJK simplex and the EPA polytope (vertices, faces, horizon edges).
SIMPLEX_SIZE = 4
EPA_VERTICES = 64
EPA_FACES = 128
EPA_EDGES = 128
#: Support features of the GJK/EPA pairs (:func:`clip_manifold`): most vertices of one shape's feature polygon (its
#: extreme points along as many directions evenly spread in the contact plane), and the angle (rad, as its sine) within
#: which a face, an edge or a cap counts as perpendicular to the contact normal (a hull's vertices within that angle
#: times its radius of the support plane form its feature, so a vertex that close under a face bends the face's
#: polygon, whose points then lie within that distance of the surface).
FEATURE_VERTICES = 16
FEATURE_ANGLE = 1e-4
#: Most points of a clipped manifold: the deepest, and three more spanning the largest area.
MANIFOLD_POINTS = 4
#: Most vertices of a clipped polygon (a polygon of m vertices clipped by k planes has at most m + k).
CLIP_VERTICES = 2 * FEATURE_VERTICES
#: Workspace layout: per simplex/polytope vertex ``[w, a, b]`` (9), per face ``[i, j, k, n, d, state]`` (8; state
#: 0 removed, 1 live, 2 live and already tested in this expansion), a stack of faces to visit.
WS_SIMPLEX = 0
WS_LAMBDA = WS_SIMPLEX + 9 * SIMPLEX_SIZE
WS_EPA_VERTICES = WS_LAMBDA + SIMPLEX_SIZE
WS_EPA_FACES = WS_EPA_VERTICES + 9 * EPA_VERTICES
WS_EPA_EDGES = WS_EPA_FACES + 8 * EPA_FACES
WS_EPA_STACK = WS_EPA_EDGES + 2 * EPA_EDGES
WS_CLIP = WS_EPA_STACK + EPA_FACES
WS_SELECT = WS_CLIP + 2 * 3 * CLIP_VERTICES
WS_PLANE = WS_SELECT + MAX_PAIR_CONTACTS
#: The two support features' polygons (``FEATURE_VERTICES`` points each) of :func:`clip_manifold`.
WS_FEATURE_A = WS_PLANE + 3
WS_FEATURE_B = WS_FEATURE_A + 3 * FEATURE_VERTICES
#: Size of ``ws`` (float64 entries) for :func:`halfspace_contacts` and :func:`pair_contacts`.
PAIR_WORKSPACE = WS_FEATURE_B + 3 * FEATURE_VERTICES

#: GJK/EPA outcomes.
SEPARATED, DISTANCE, OVERLAP, DEGENERATE = 0, 1, 2, 3
#: Iteration limits of GJK and EPA.
GJK_ITERATIONS = 128
#: Relative tolerances (of a length scale of the pair): GJK's and EPA's termination, the face
#: preference of the box–box axis choice, and "parallel" for edges and capsule axes.
GJK_TOLERANCE = 1e-13
EPA_TOLERANCE = 1e-10
AXIS_PREFERENCE = 1e-10
PARALLEL = 1e-10


# ---------------------------------------------------------------------------------------------------------------------
# small helpers


@njit(cache=True, error_model="numpy")
def rotation9(R):
    """The (3, 3) array ``R`` as the row-major 9-tuple of :mod:`multibody.kernels.spatial`."""
    return row3(R, 0, 0) + row3(R, 1, 0) + row3(R, 2, 0)


@njit(cache=True, error_model="numpy")
def norm3(a):
    return math.sqrt(dot3(a, a))


@njit(cache=True, error_model="numpy")
def clamp(x, lo, hi):
    """``x`` limited to ``[lo, hi]`` (written out: Numba's CUDA target does not compile the builtin
    ``min``/``max`` of floats)."""
    return lo if x < lo else (hi if x > hi else x)


@njit(cache=True, error_model="numpy")
def least3(a, b, c):
    """The least of three numbers."""
    m = a if a < b else b
    return m if m < c else c


@njit(cache=True, error_model="numpy")
def axis_of(R, k):
    """Column ``k`` of the row-major rotation ``R``: the geometry frame's axis k in world axes."""
    return (R[k], R[3 + k], R[6 + k])


@njit(cache=True, error_model="numpy")
def write_contact(out, count, point, normal, gap):
    """Row ``count`` of ``out`` ← ``[point, normal, gap]`` while rows are left; the new count."""
    if count >= out.shape[0]:
        return count
    store_row(out, count, 0, point + normal + (gap,))
    return count + 1


@njit(cache=True, error_model="numpy")
def write_pair(out, count, x_a, x_b, normal, gap, margin):
    """A pair's contact from its witness points ``x_a`` (on a) and ``x_b`` (on b): the row at their
    midpoint, written when ``gap < margin`` (so never for a NaN gap)."""
    if not gap < margin:
        return count
    return write_contact(out, count, scale3(0.5, add3(x_a, x_b)), normal, gap)


@njit(cache=True, error_model="numpy")
def any_perpendicular(u):
    """A unit vector perpendicular to the unit vector ``u``: ``u ×`` the axis least aligned with it."""
    ax, ay, az = abs(u[0]), abs(u[1]), abs(u[2])
    if ax <= ay and ax <= az:
        e = (1.0, 0.0, 0.0)
    elif ay <= az:
        e = (0.0, 1.0, 0.0)
    else:
        e = (0.0, 0.0, 1.0)
    c = cross(u, e)
    return scale3(1.0 / norm3(c), c)


@njit(cache=True, error_model="numpy")
def bounding_radius(shape, size, vertices):
    """Radius of a ball about the geometry frame's origin holding the shape (m)."""
    if shape == SPHERE:
        return size[0]
    if shape == BOX:
        return math.sqrt(size[0] * size[0] + size[1] * size[1] + size[2] * size[2])
    if shape == CAPSULE:
        return size[0] + size[1]
    if shape == CYLINDER:
        return math.sqrt(size[0] * size[0] + size[1] * size[1])
    r = 0.0
    for i in range(vertices.shape[0]):
        length = norm3(row3(vertices, i, 0))
        if length > r:
            r = length
    return r


@njit(cache=True, error_model="numpy")
def as_tuples(size, R, p):
    """A geometry's ``size (3,)``, ``R (3, 3)`` and ``p (3,)`` arrays as the tuples the helpers take."""
    return load3(size, 0), rotation9(R), load3(p, 0)


@njit(cache=True, error_model="numpy")
def pair_scale(shape_a, size_a, vertices_a, p_a, shape_b, size_b, vertices_b, p_b):
    """A length of the pair (m), to which GJK's and EPA's tolerances are relative: the bounding radii and
    the distance between the geometry origins."""
    return bounding_radius(shape_a, size_a, vertices_a) + bounding_radius(shape_b, size_b, vertices_b) \
        + norm3(sub3(p_a, p_b))


@njit(cache=True, error_model="numpy")
def core_radius(shape, size):
    """The radius by which a shape rounds its core (sphere: a point; capsule: a segment); 0 otherwise."""
    if shape == SPHERE or shape == CAPSULE:
        return size[0]
    return 0.0


@njit(cache=True, error_model="numpy")
def support(shape, size, vertices, R, p, d, rounded):
    """A point of the shape farthest along the world direction ``d`` (its support point), in world
    coordinates: of the core (sphere: its centre; capsule: its segment) when ``rounded`` is False, of
    the whole shape when True (the core's point plus the radius along ``d``).

    In the geometry frame, with ``d' = Rᵀ d``: box ``(sign(d'ᵢ) hᵢ)``; segment ``(0, 0, sign(d'_z) h)``;
    cylinder ``(r d'_⊥/|d'_⊥|, sign(d'_z) h)``; hull ``argmax_v d'·v`` (van den Bergen 2003, §4.3.1)."""
    dl = rotate_back(R, d)
    if shape == BOX:
        local = (math.copysign(size[0], dl[0]), math.copysign(size[1], dl[1]), math.copysign(size[2], dl[2]))
    elif shape == CAPSULE:
        local = (0.0, 0.0, math.copysign(size[1], dl[2]))
    elif shape == CYLINDER:
        s = math.sqrt(dl[0] * dl[0] + dl[1] * dl[1])
        z = math.copysign(size[1], dl[2])
        if s > 0.0:
            local = (size[0] * dl[0] / s, size[0] * dl[1] / s, z)
        else:
            local = (0.0, 0.0, z)
    elif shape == CONVEX:
        best = 0
        best_value = -math.inf
        for i in range(vertices.shape[0]):
            value = dl[0] * vertices[i, 0] + dl[1] * vertices[i, 1] + dl[2] * vertices[i, 2]
            if value > best_value:
                best_value = value
                best = i
        local = row3(vertices, best, 0)
    else:
        local = (0.0, 0.0, 0.0)
    x = add3(p, rotate(R, local))
    if rounded:
        r = core_radius(shape, size)
        nd = norm3(d)
        if r > 0.0 and nd > 0.0:
            x = add3(x, scale3(r / nd, d))
    return x


# ---------------------------------------------------------------------------------------------------------------------
# closest points (RTCD chapter 5)


@njit(cache=True, error_model="numpy")
def closest_on_segment(x, a, b):
    """Parameter ``t ∈ [0, 1]`` of the point ``a + t (b − a)`` nearest ``x`` (RTCD §5.1.2):
    ``t = clamp((x − a)·(b − a) / |b − a|², 0, 1)``."""
    ab = sub3(b, a)
    denominator = dot3(ab, ab)
    if denominator <= 0.0:
        return 0.0
    return clamp(dot3(sub3(x, a), ab) / denominator, 0.0, 1.0)


@njit(cache=True, error_model="numpy")
def closest_between_segments(p1, q1, p2, q2):
    """Parameters ``(s, t)`` of the closest points ``p1 + s d1`` and ``p2 + t d2`` of the segments
    ``[p1, q1]`` and ``[p2, q2]`` (RTCD §5.1.9, ``ClosestPtSegmentSegment``): with ``d1 = q1 − p1``,
    ``d2 = q2 − p2``, ``r = p1 − p2``, ``a = d1·d1``, ``e = d2·d2``, ``f = d2·r``, ``c = d1·r``,
    ``b = d1·d2``, ``s = clamp((b f − c e)/(a e − b²))``, ``t = (b s + f)/e``, each re-clamped in turn.
    Parallel segments (``a e − b² = 0``) take ``s = 0``."""
    d1 = sub3(q1, p1)
    d2 = sub3(q2, p2)
    r = sub3(p1, p2)
    a = dot3(d1, d1)
    e = dot3(d2, d2)
    f = dot3(d2, r)
    if a <= 0.0 and e <= 0.0:
        return 0.0, 0.0
    if a <= 0.0:
        return 0.0, clamp(f / e, 0.0, 1.0)
    c = dot3(d1, r)
    if e <= 0.0:
        return clamp(-c / a, 0.0, 1.0), 0.0
    b = dot3(d1, d2)
    denominator = a * e - b * b
    s = 0.0
    if denominator > PARALLEL * a * e:
        s = clamp((b * f - c * e) / denominator, 0.0, 1.0)
    # t = (b s + f)/e, and s recomputed where t is clamped
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = clamp(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t = 1.0
        s = clamp((b - c) / a, 0.0, 1.0)
    return s, t


@njit(cache=True, error_model="numpy")
def closest_on_triangle(a, b, c):
    """Barycentric coordinates ``(u, v, w)`` of the point of triangle ``abc`` nearest the origin, by
    its Voronoi regions (RTCD §5.1.5, ``ClosestPtPointTriangle`` with ``p = 0``); a degenerate triangle
    takes the nearest of its edges."""
    ab = sub3(b, a)
    ac = sub3(c, a)
    # vertex region A: d1 = ab·(p − a) ≤ 0, d2 = ac·(p − a) ≤ 0
    d1 = -dot3(ab, a)
    d2 = -dot3(ac, a)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    d3 = -dot3(ab, b)
    d4 = -dot3(ac, b)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    d5 = -dot3(ab, c)
    d6 = -dot3(ac, c)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    total = va + vb + vc
    if total > 0.0:
        # face region: (u, v, w) = (va, vb, vc) / (va + vb + vc)
        v = vb / total
        w = vc / total
        return 1.0 - v - w, v, w
    origin = (0.0, 0.0, 0.0)
    t_ab = closest_on_segment(origin, a, b)
    t_bc = closest_on_segment(origin, b, c)
    t_ca = closest_on_segment(origin, c, a)
    x_ab = add3(a, scale3(t_ab, ab))
    x_bc = add3(b, scale3(t_bc, sub3(c, b)))
    x_ca = add3(c, scale3(t_ca, sub3(a, c)))
    n_ab, n_bc, n_ca = dot3(x_ab, x_ab), dot3(x_bc, x_bc), dot3(x_ca, x_ca)
    if n_ab <= n_bc and n_ab <= n_ca:
        return 1.0 - t_ab, t_ab, 0.0
    if n_bc <= n_ca:
        return 0.0, 1.0 - t_bc, t_bc
    return t_ca, 0.0, 1.0 - t_ca


# ---------------------------------------------------------------------------------------------------------------------
# half-space


@njit(cache=True, error_model="numpy")
def halfspace_point(out, count, x, normal, height, radius, margin):
    """A point feature ``x`` rounded by ``radius`` against ``n·x ≥ h``: ``gap = n·x − h − radius``, the
    surface point ``x − radius n``."""
    gap = dot3(normal, x) - height - radius
    if not gap < margin:
        return count
    return write_contact(out, count, sub3(x, scale3(radius, normal)), normal, gap)


@njit(cache=True, error_model="numpy")
def halfspace_contacts(shape, size, vertices, R, p, normal, height, margin, out, ws):
    """Contacts of a geometry with the half-space ``n·x ≥ height`` (``normal (3,)``, made unit here;
    ``height`` in m): every feature with ``gap = n·x − height < margin`` (a point's signed distance to
    a plane, RTCD §5.2.2–5.2.3), with the normal ``n`` (from the half-space into the geometry) and the point on the
    geometry's surface. Returns the count of rows written into ``out (MAX_PAIR_CONTACTS, 7)``.

    * sphere: its lowest point ``c − r n``;
    * box: its corners ``p + R (±hx, ±hy, ±hz)`` (a box resting on a face gives its 4 lowest);
    * capsule: the lowest points of its two end spheres ``p ± h R e_z − r n``;
    * cylinder: per end disc of centre ``c = p ± h a`` (axis ``a = R e_z``), four rim points a quarter
      turn apart, ``c + r (cos θ u + sin θ (a × u))``, starting from the lowest, ``u = −(n − (n·a) a)/|·|``
      (the disc's x axis where the disc is parallel to the plane): standing on its face gives 4 rim
      points, lying on its side the two lowest rim points;
    * convex hull: its vertices; where more than ``MAX_PAIR_CONTACTS`` are within the margin, the
      deepest and the extreme ones along ``MAX_PAIR_CONTACTS − 1`` directions in the plane, evenly
      spread over the full turn, so that the kept points span the supporting polygon.
    """
    Rt = rotation9(R)
    pt = load3(p, 0)
    n = load3(normal, 0)
    n = scale3(1.0 / norm3(n), n)
    count = 0
    if shape == SPHERE:
        return halfspace_point(out, count, pt, n, height, size[0], margin)
    if shape == BOX:
        for k in range(8):
            local = (size[0] if k & 1 else -size[0], size[1] if k & 2 else -size[1], size[2] if k & 4 else -size[2])
            count = halfspace_point(out, count, add3(pt, rotate(Rt, local)), n, height, 0.0, margin)
        return count
    if shape == CAPSULE:
        a = axis_of(Rt, 2)
        count = halfspace_point(out, count, add3(pt, scale3(size[1], a)), n, height, size[0], margin)
        return halfspace_point(out, count, sub3(pt, scale3(size[1], a)), n, height, size[0], margin)
    if shape == CYLINDER:
        a = axis_of(Rt, 2)
        # u: the downhill direction in the disc's plane, −(n − (n·a) a), normalised
        tangential = sub3(scale3(dot3(n, a), a), n)
        length = norm3(tangential)
        if length > PARALLEL:
            u = scale3(1.0 / length, tangential)
        else:
            u = axis_of(Rt, 0)
        w = cross(a, u)
        for side in range(2):
            centre = add3(pt, scale3(size[1] if side == 0 else -size[1], a))
            count = halfspace_point(out, count, add3(centre, scale3(size[0], u)), n, height, 0.0, margin)
            count = halfspace_point(out, count, add3(centre, scale3(size[0], w)), n, height, 0.0, margin)
            count = halfspace_point(out, count, sub3(centre, scale3(size[0], w)), n, height, 0.0, margin)
            count = halfspace_point(out, count, sub3(centre, scale3(size[0], u)), n, height, 0.0, margin)
        return count
    return halfspace_hull(vertices, Rt, pt, n, height, margin, out, ws)


@njit(cache=True, error_model="numpy")
def halfspace_hull(vertices, R, p, n, height, margin, out, ws):
    """A convex hull's vertices against ``n·x ≥ height`` (see :func:`halfspace_contacts`); ``ws[WS_SELECT:]``
    holds the indices of the kept vertices."""
    candidates = 0
    deepest = -1
    deepest_gap = math.inf
    for i in range(vertices.shape[0]):
        gap = dot3(n, add3(p, rotate(R, row3(vertices, i, 0)))) - height
        if gap < margin:
            candidates += 1
            if gap < deepest_gap:
                deepest_gap = gap
                deepest = i
    if candidates == 0:
        return 0
    if candidates <= out.shape[0]:
        count = 0
        for i in range(vertices.shape[0]):
            count = halfspace_point(out, count, add3(p, rotate(R, row3(vertices, i, 0))), n, height, 0.0, margin)
        return count
    # more candidates than rows: the deepest, then the extreme candidate along t_k = cos θ_k e1 + sin θ_k e2
    e1 = any_perpendicular(n)
    e2 = cross(n, e1)
    kept = 0
    ws[WS_SELECT] = deepest
    kept = 1
    for k in range(out.shape[0] - 1):
        angle = 2.0 * math.pi * k / (out.shape[0] - 1)
        t = add3(scale3(math.cos(angle), e1), scale3(math.sin(angle), e2))
        best = -1
        best_value = -math.inf
        for i in range(vertices.shape[0]):
            x = add3(p, rotate(R, row3(vertices, i, 0)))
            if dot3(n, x) - height < margin and dot3(t, x) > best_value:
                best_value = dot3(t, x)
                best = i
        seen = False
        for j in range(kept):
            if int(ws[WS_SELECT + j]) == best:
                seen = True
        if not seen:
            ws[WS_SELECT + kept] = best
            kept += 1
    count = 0
    for j in range(kept):
        x = add3(p, rotate(R, row3(vertices, int(ws[WS_SELECT + j]), 0)))
        count = halfspace_point(out, count, x, n, height, 0.0, margin)
    return count


# ---------------------------------------------------------------------------------------------------------------------
# analytic pairs (RTCD chapters 4 and 5)


@njit(cache=True, error_model="numpy")
def spheres(c_a, r_a, c_b, r_b, margin, out, count):
    """Two balls (a sphere, or the nearest point of a capsule's segment): ``d = c_a − c_b``,
    ``n = d/|d|``, ``gap = |d| − r_a − r_b`` (RTCD §4.3.1); witnesses ``c_a − r_a n`` and ``c_b + r_b n``.
    Coincident centres take ``n = e_z``."""
    d = sub3(c_a, c_b)
    distance = norm3(d)
    if distance > 0.0:
        n = scale3(1.0 / distance, d)
    else:
        n = (0.0, 0.0, 1.0)
    gap = distance - r_a - r_b
    return write_pair(out, count, sub3(c_a, scale3(r_a, n)), add3(c_b, scale3(r_b, n)), n, gap, margin)


@njit(cache=True, error_model="numpy")
def sphere_box(c, r, size, R, p, margin, out, count):
    """A sphere (centre ``c``, radius ``r``: object a) against a box (object b). In the box frame
    ``c' = Rᵀ (c − p)``; outside, the box's nearest point is ``q = clamp(c', −h, h)`` (RTCD §5.1.4,
    ``ClosestPtPointOBB``, and the sphere–OBB test on it) and ``n = R (c' − q)/|c' − q|``,
    ``gap = |c' − q| − r``; inside, the face of least depth ``k = argmin (hₖ − |c'ₖ|)`` gives ``n = sign(c'ₖ) R eₖ`` and ``gap = −(hₖ − |c'ₖ|) − r``."""
    cl = rotate_back(R, sub3(c, p))
    q = (clamp(cl[0], -size[0], size[0]), clamp(cl[1], -size[1], size[1]), clamp(cl[2], -size[2], size[2]))
    d = sub3(cl, q)
    distance = norm3(d)
    if distance > 0.0:
        n = rotate(R, scale3(1.0 / distance, d))
        gap = distance - r
        x_b = add3(p, rotate(R, q))
    else:
        # inside: push out through the nearest face
        k = 0
        depth = size[0] - abs(cl[0])
        for i in range(1, 3):
            if size[i] - abs(cl[i]) < depth:
                depth = size[i] - abs(cl[i])
                k = i
        sign = 1.0 if cl[k] >= 0.0 else -1.0
        n = scale3(sign, axis_of(R, k))
        gap = -depth - r
        x_b = add3(c, scale3(depth, n))
    return write_pair(out, count, sub3(c, scale3(r, n)), x_b, n, gap, margin)


@njit(cache=True, error_model="numpy")
def segment_of(size, R, p):
    """End points ``p ∓ h R e_z`` of a capsule's (or cylinder's) axis segment."""
    a = scale3(size[1], axis_of(R, 2))
    return sub3(p, a), add3(p, a)


@njit(cache=True, error_model="numpy")
def capsules(size_a, R_a, p_a, size_b, R_b, p_b, margin, out, count):
    """Two capsules: the closest points of their segments (RTCD §5.1.9) as two balls (RTCD §4.5.1).
    Parallel axes overlapping along their length give two contacts, at the ends of the overlap
    interval of a's segment (where each is closest to b's segment), so that one capsule lying on
    another is supported along the line."""
    a0, a1 = segment_of(size_a, R_a, p_a)
    b0, b1 = segment_of(size_b, R_b, p_b)
    da = sub3(a1, a0)
    db = sub3(b1, b0)
    c = cross(da, db)
    laa = dot3(da, da)
    lbb = dot3(db, db)
    if laa > 0.0 and lbb > 0.0 and dot3(c, c) <= PARALLEL * PARALLEL * laa * lbb:
        # overlap of b's end points projected on a's axis: [max(0, min t), min(1, max t)]
        t0 = dot3(sub3(b0, a0), da) / laa
        t1 = dot3(sub3(b1, a0), da) / laa
        lo = clamp(t0 if t0 < t1 else t1, 0.0, 1.0)
        hi = clamp(t1 if t0 < t1 else t0, 0.0, 1.0)
        if hi > lo:
            for t in (lo, hi):
                x = add3(a0, scale3(t, da))
                y = add3(b0, scale3(closest_on_segment(x, b0, b1), db))
                count = spheres(x, size_a[0], y, size_b[0], margin, out, count)
            return count
    s, t = closest_between_segments(a0, a1, b0, b1)
    return spheres(add3(a0, scale3(s, da)), size_a[0], add3(b0, scale3(t, db)), size_b[0], margin, out, count)


@njit(cache=True, error_model="numpy")
def box_separation(axis, h_a, R_a, h_b, R_b, t):
    """Separation of two boxes along the unit ``axis`` (RTCD §4.4.1): ``|L·t| − (Σ hₐᵢ |L·aᵢ| + Σ h_bⱼ |L·bⱼ|)``
    with ``t = p_b − p_a``; positive: a separating axis."""
    r_a = h_a[0] * abs(dot3(axis, axis_of(R_a, 0))) + h_a[1] * abs(dot3(axis, axis_of(R_a, 1))) \
        + h_a[2] * abs(dot3(axis, axis_of(R_a, 2)))
    r_b = h_b[0] * abs(dot3(axis, axis_of(R_b, 0))) + h_b[1] * abs(dot3(axis, axis_of(R_b, 1))) \
        + h_b[2] * abs(dot3(axis, axis_of(R_b, 2)))
    return abs(dot3(axis, t)) - r_a - r_b


@njit(cache=True, error_model="numpy")
def clip_polygon(ws, source, m, target, e, offset):
    """Sutherland–Hodgman: the polygon of ``m`` vertices at ``ws[source:]`` clipped to ``e·x ≤ offset``,
    written at ``ws[target:]`` (RTCD §8.3.4); returns its vertex count."""
    k = 0
    for i in range(m):
        cur = load3(ws, source + 3 * i)
        nxt = load3(ws, source + 3 * ((i + 1) % m))
        dc = dot3(e, cur) - offset
        dn = dot3(e, nxt) - offset
        if dc <= 0.0 and k < CLIP_VERTICES:
            store_row_flat(ws, target + 3 * k, cur)
            k += 1
        # the edge crosses the plane: its intersection x = cur + dc/(dc − dn) (nxt − cur)
        if ((dc < 0.0 and dn > 0.0) or (dc > 0.0 and dn < 0.0)) and k < CLIP_VERTICES:
            store_row_flat(ws, target + 3 * k, add3(cur, scale3(dc / (dc - dn), sub3(nxt, cur))))
            k += 1
    return k


@njit(cache=True, error_model="numpy")
def store_row_flat(x, start, values):
    """``x[start : start + 3] = values`` for a 3-tuple."""
    x[start] = values[0]
    x[start + 1] = values[1]
    x[start + 2] = values[2]


@njit(cache=True, error_model="numpy")
def box_face_contacts(h_ref, R_ref, p_ref, k, n, h_inc, R_inc, p_inc, flip, margin, out, count, ws):
    """Face contact of two boxes by reference-face clipping (D. Gregorius, "Robust Contact Creation for Physics
    Simulations", GDC 2015; the clipping is Sutherland–Hodgman's, RTCD §8.3.4):
    the reference box's face ``k`` with outward normal ``n`` (towards the incident box), the incident box's
    face most opposed to ``n`` clipped by the reference face's four side planes; each clipped corner ``x``
    with ``gap = n·(x − c_ref) < margin`` (``c_ref = p_ref + h_k n``) gives a contact at the midpoint of
    ``x`` and its projection on the reference face. The normal written is ``n``, or ``−n`` when ``flip``
    (the reference box is b)."""
    # incident face: the axis j of the incident box with the largest |n·bⱼ|, its outward normal against n
    j = 0
    best = -1.0
    for i in range(3):
        value = abs(dot3(n, axis_of(R_inc, i)))
        if value > best:
            best = value
            j = i
    sign = -1.0 if dot3(n, axis_of(R_inc, j)) > 0.0 else 1.0
    u_axis = (j + 1) % 3
    v_axis = (j + 2) % 3
    centre = add3(p_inc, scale3(sign * h_inc[j], axis_of(R_inc, j)))
    u = scale3(h_inc[u_axis], axis_of(R_inc, u_axis))
    v = scale3(h_inc[v_axis], axis_of(R_inc, v_axis))
    source = WS_CLIP
    target = WS_CLIP + 3 * CLIP_VERTICES
    store_row_flat(ws, source, add3(centre, add3(u, v)))
    store_row_flat(ws, source + 3, add3(centre, sub3(v, u)))
    store_row_flat(ws, source + 6, sub3(centre, add3(u, v)))
    store_row_flat(ws, source + 9, add3(centre, sub3(u, v)))
    m = 4
    # the reference face's side planes ±eᵢ·x ≤ ±eᵢ·p_ref + hᵢ, i ≠ k
    for i in range(3):
        if i == k:
            continue
        e = axis_of(R_ref, i)
        for s in (1.0, -1.0):
            es = scale3(s, e)
            m = clip_polygon(ws, source, m, target, es, dot3(es, p_ref) + h_ref[i])
            source, target = target, source
            if m == 0:
                return count
    face = dot3(n, p_ref) + h_ref[k]
    normal = scale3(-1.0, n) if flip else n
    for i in range(m):
        x = load3(ws, source + 3 * i)
        gap = dot3(n, x) - face
        if gap < margin:
            count = write_contact(out, count, sub3(x, scale3(0.5 * gap, n)), normal, gap)
    return count


@njit(cache=True, error_model="numpy")
def boxes(h_a, vertices_a, R_a, p_a, h_b, vertices_b, R_b, p_b, margin, out, count, ws):
    """Two boxes by the separating-axis test over their 15 axes (RTCD §4.4.1: the 3 + 3 face normals and
    the 9 edge cross products ``aᵢ × bⱼ``, unit, parallel pairs skipped): the axis of largest separation
    ``s(L) = |L·t| − r_a(L) − r_b(L)`` (``t = p_b − p_a``) is the contact normal; none within the margin
    when ``s > margin``. A face axis (preferred over an edge axis within a relative ``AXIS_PREFERENCE``)
    gives the clipped face polygon's corners (:func:`box_face_contacts`: 4 for a box resting on a larger
    one); an edge axis gives one point, the midpoint of the closest points of the two supporting edges
    (RTCD §5.1.9), with ``gap = n·(x_a − x_b)``.

    For overlapping boxes ``−s`` is the depth (the least translation that separates two polytopes is along
    one of these axes). For separated boxes ``s`` is a lower bound of the distance, exact when the nearest
    features are a face and what lies over it, or two edges: so they are measured by GJK
    (:func:`gjk`), and where its direction is not the axis's (corners or an edge and a corner beside each
    other), the single GJK contact is the answer."""
    t = sub3(p_b, p_a)
    scale = norm3(h_a) + norm3(h_b)
    tolerance = AXIS_PREFERENCE * scale
    best = -math.inf
    best_axis = -1
    for i in range(6):
        axis = axis_of(R_a, i) if i < 3 else axis_of(R_b, i - 3)
        s = box_separation(axis, h_a, R_a, h_b, R_b, t)
        if s > best + (tolerance if i >= 3 else 0.0):
            best = s
            best_axis = i
    if best > margin:
        return count
    best_edge = -math.inf
    edge = -1
    for i in range(3):
        for j in range(3):
            c = cross(axis_of(R_a, i), axis_of(R_b, j))
            length = norm3(c)
            if length <= PARALLEL:
                continue
            s = box_separation(scale3(1.0 / length, c), h_a, R_a, h_b, R_b, t)
            if s > best_edge:
                best_edge = s
                edge = 3 * i + j
    use_edge = edge >= 0 and best_edge > best + tolerance
    separation = best_edge if use_edge else best
    if separation > margin:
        return count
    # the axis as the contact normal, from b into a
    if use_edge:
        c = cross(axis_of(R_a, edge // 3), axis_of(R_b, edge % 3))
        axis = scale3(1.0 / norm3(c), c)
    else:
        axis = axis_of(R_a, best_axis) if best_axis < 3 else axis_of(R_b, best_axis - 3)
    normal = axis if dot3(axis, t) < 0.0 else scale3(-1.0, axis)
    if separation > 0.0:
        status, v, x_a, x_b, _ = gjk(BOX, h_a, vertices_a, R_a, p_a, BOX, h_b, vertices_b, R_b, p_b, False, margin,
                                     scale + norm3(t), ws)
        if status == SEPARATED:
            return count
        if status == DISTANCE:
            distance = norm3(v)
            direction = scale3(1.0 / distance, v)
            if dot3(direction, normal) < 1.0 - PARALLEL:
                return write_pair(out, count, x_a, x_b, direction, distance, margin)
    if use_edge:
        i = edge // 3
        j = edge % 3
        # n = −normal points from a to b: a's supporting edge along n, b's along −n
        ea = (0.0, 0.0, 0.0)
        eb = (0.0, 0.0, 0.0)
        for k in range(3):
            if k != i:
                ea = sub3(ea, scale3(math.copysign(h_a[k], dot3(normal, axis_of(R_a, k))), axis_of(R_a, k)))
            if k != j:
                eb = add3(eb, scale3(math.copysign(h_b[k], dot3(normal, axis_of(R_b, k))), axis_of(R_b, k)))
        a0 = add3(p_a, sub3(ea, scale3(h_a[i], axis_of(R_a, i))))
        a1 = add3(p_a, add3(ea, scale3(h_a[i], axis_of(R_a, i))))
        b0 = add3(p_b, sub3(eb, scale3(h_b[j], axis_of(R_b, j))))
        b1 = add3(p_b, add3(eb, scale3(h_b[j], axis_of(R_b, j))))
        s, u = closest_between_segments(a0, a1, b0, b1)
        x_a = add3(a0, scale3(s, sub3(a1, a0)))
        x_b = add3(b0, scale3(u, sub3(b1, b0)))
        return write_pair(out, count, x_a, x_b, normal, dot3(normal, sub3(x_a, x_b)), margin)
    if best_axis < 3:
        return box_face_contacts(h_a, R_a, p_a, best_axis, scale3(-1.0, normal), h_b, R_b, p_b, True, margin, out,
                                 count, ws)
    return box_face_contacts(h_b, R_b, p_b, best_axis - 3, normal, h_a, R_a, p_a, False, margin, out, count, ws)


# ---------------------------------------------------------------------------------------------------------------------
# GJK and EPA (Gilbert, Johnson & Keerthi 1988; van den Bergen 2003, §4.3)


@njit(cache=True, error_model="numpy")
def support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, d, rounded,
                       ws, slot):
    """``w = s_A(d) − s_B(−d)``, the support point of the Minkowski difference ``A − B`` along ``d``,
    stored with its two parts at ``ws[slot : slot + 9]`` as ``[w, s_A, s_B]``; returns ``w``."""
    x_a = support(shape_a, size_a, vertices_a, R_a, p_a, d, rounded)
    x_b = support(shape_b, size_b, vertices_b, R_b, p_b, scale3(-1.0, d), rounded)
    w = sub3(x_a, x_b)
    store_row_flat(ws, slot, w)
    store_row_flat(ws, slot + 3, x_a)
    store_row_flat(ws, slot + 6, x_b)
    return w


@njit(cache=True, error_model="numpy")
def copy_vertex(ws, source, target):
    for k in range(9):
        ws[target + k] = ws[source + k]


@njit(cache=True, error_model="numpy")
def simplex_closest(ws, m):
    """The point ``v`` of the simplex of ``m`` vertices at ``ws[WS_SIMPLEX:]`` nearest the origin, with
    the simplex reduced to the vertices whose barycentric weight (kept at ``ws[WS_LAMBDA:]``) is
    positive (GJK's sub-algorithm, by the Voronoi regions of RTCD §5.1.2, §5.1.5 and §5.1.6). Returns
    ``(m', v)``; ``m' = 4`` when the origin is inside the tetrahedron."""
    w0 = load3(ws, WS_SIMPLEX)
    for k in range(SIMPLEX_SIZE):
        ws[WS_LAMBDA + k] = 0.0
    if m == 1:
        ws[WS_LAMBDA] = 1.0
    elif m == 2:
        w1 = load3(ws, WS_SIMPLEX + 9)
        t = closest_on_segment((0.0, 0.0, 0.0), w0, w1)
        ws[WS_LAMBDA] = 1.0 - t
        ws[WS_LAMBDA + 1] = t
    elif m == 3:
        l0, l1, l2 = closest_on_triangle(w0, load3(ws, WS_SIMPLEX + 9), load3(ws, WS_SIMPLEX + 18))
        ws[WS_LAMBDA] = l0
        ws[WS_LAMBDA + 1] = l1
        ws[WS_LAMBDA + 2] = l2
    else:
        # tetrahedron (RTCD §5.1.6): the nearest point of each face whose plane has the origin on the
        # side away from the fourth vertex; none such: the origin is inside
        best = math.inf
        inside = True
        for f in range(4):
            i0, i1, i2, i3 = (f + 1) % 4, (f + 2) % 4, (f + 3) % 4, f
            a = load3(ws, WS_SIMPLEX + 9 * i0)
            b = load3(ws, WS_SIMPLEX + 9 * i1)
            c = load3(ws, WS_SIMPLEX + 9 * i2)
            d = load3(ws, WS_SIMPLEX + 9 * i3)
            normal = cross(sub3(b, a), sub3(c, a))
            side_origin = -dot3(a, normal)
            side_other = dot3(sub3(d, a), normal)
            scale = dot3(normal, normal)
            if side_origin * side_other < 0.0 or side_other * side_other <= 1e-24 * scale * scale:
                inside = False
                l0, l1, l2 = closest_on_triangle(a, b, c)
                x = add3(add3(scale3(l0, a), scale3(l1, b)), scale3(l2, c))
                distance = dot3(x, x)
                if distance < best:
                    best = distance
                    for k in range(SIMPLEX_SIZE):
                        ws[WS_LAMBDA + k] = 0.0
                    ws[WS_LAMBDA + i0] = l0
                    ws[WS_LAMBDA + i1] = l1
                    ws[WS_LAMBDA + i2] = l2
        if inside:
            return 4, (0.0, 0.0, 0.0)
    # v = Σ λᵢ wᵢ over the vertices kept, compacted to the front
    v = (0.0, 0.0, 0.0)
    kept = 0
    for k in range(m):
        weight = ws[WS_LAMBDA + k]
        if weight > 0.0:
            v = add3(v, scale3(weight, load3(ws, WS_SIMPLEX + 9 * k)))
            if kept != k:
                copy_vertex(ws, WS_SIMPLEX + 9 * k, WS_SIMPLEX + 9 * kept)
            ws[WS_LAMBDA + kept] = weight
            kept += 1
    return kept, v


@njit(cache=True, error_model="numpy")
def gjk(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, rounded, limit, scale, ws):
    """GJK distance of the shapes' cores (``rounded`` False) or of the whole shapes (van den Bergen 2003,
    Algorithm 4.5): from ``v ∈ A − B``, repeat ``w = s_{A−B}(−v)``, stop when ``|v|² − v·w ≤ ε |v|²``,
    else ``v`` ← the point of ``conv(W ∪ {w})`` nearest the origin, ``W`` reduced to its support.

    Returns ``(status, v, x_a, x_b, m)``: ``SEPARATED`` when ``v·w > limit |v|`` (the distance exceeds
    ``limit``), ``DISTANCE`` with ``v = x_a − x_b`` the nearest points' difference, or ``OVERLAP`` (the
    origin in ``A − B``, the simplex of ``m`` vertices left in ``ws`` for EPA)."""
    d = sub3(p_a, p_b)
    if dot3(d, d) <= 0.0:
        d = (1.0, 0.0, 0.0)
    v = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, d,
                           rounded, ws, WS_SIMPLEX)
    ws[WS_LAMBDA] = 1.0
    m = 1
    tiny = (GJK_TOLERANCE * scale) ** 2
    for _ in range(GJK_ITERATIONS):
        vv = dot3(v, v)
        if vv <= tiny:
            return OVERLAP, v, v, v, m
        slot = WS_SIMPLEX + 9 * m
        w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                               scale3(-1.0, v), rounded, ws, slot)
        vw = dot3(v, w)
        if vw > 0.0 and vw * vw > limit * limit * vv:
            return SEPARATED, v, v, v, m
        # |v|² − v·w bounds |v| (|v| − distance): converged
        if vv - vw <= GJK_TOLERANCE * vv:
            break
        repeated = False
        for k in range(m):
            e = sub3(w, load3(ws, WS_SIMPLEX + 9 * k))
            if dot3(e, e) <= tiny:
                repeated = True
        if repeated:
            break
        m, v_new = simplex_closest(ws, m + 1)
        if m == 4:
            return OVERLAP, v, v, v, m
        if dot3(v_new, v_new) >= vv:
            # no progress in floating point: v is as near as this arithmetic gets
            break
        v = v_new
    # nearest points x_a = Σ λᵢ aᵢ, x_b = Σ λᵢ bᵢ
    x_a = (0.0, 0.0, 0.0)
    x_b = (0.0, 0.0, 0.0)
    total = 0.0
    for k in range(m):
        weight = ws[WS_LAMBDA + k]
        total += weight
        x_a = add3(x_a, scale3(weight, load3(ws, WS_SIMPLEX + 9 * k + 3)))
        x_b = add3(x_b, scale3(weight, load3(ws, WS_SIMPLEX + 9 * k + 6)))
    x_a = scale3(1.0 / total, x_a)
    x_b = scale3(1.0 / total, x_b)
    v = sub3(x_a, x_b)
    if dot3(v, v) <= tiny:
        return OVERLAP, v, x_a, x_b, m
    if m == 3:
        # the nearest point inside a triangle w₀w₁w₂ of A − B: v = (u·w₀) u with u the triangle's unit normal, whose
        # cross product of long edges keeps its direction to rounding, where v = x_a − x_b, a difference of nearly
        # equal points, keeps only |v|'s digits (a face over a face or a vertex a little apart)
        w0 = load3(ws, WS_SIMPLEX)
        e1 = sub3(load3(ws, WS_SIMPLEX + 9), w0)
        e2 = sub3(load3(ws, WS_SIMPLEX + 18), w0)
        u = cross(e1, e2)
        length = norm3(u)
        if length > PARALLEL * norm3(e1) * norm3(e2):
            u = scale3(1.0 / length, u)
            v = scale3(dot3(u, w0), u)
    return DISTANCE, v, x_a, x_b, m


@njit(cache=True, error_model="numpy")
def epa_add_face(ws, faces, i, j, k):
    """Face ``(i, j, k)`` of the polytope (counter-clockwise seen from outside) into a free slot: its unit
    normal ``n`` and its plane's distance from the origin ``n·wᵢ``; a degenerate face gets distance ∞
    (never expanded). Returns the face count and the slot used; the caller leaves room
    (:func:`epa_free_faces`)."""
    slot = -1
    for f in range(faces):
        if ws[WS_EPA_FACES + 8 * f + 7] == 0.0:
            slot = f
            break
    if slot < 0:
        slot = faces
        faces += 1
    a = load3(ws, WS_EPA_VERTICES + 9 * i)
    b = load3(ws, WS_EPA_VERTICES + 9 * j)
    c = load3(ws, WS_EPA_VERTICES + 9 * k)
    normal = cross(sub3(b, a), sub3(c, a))
    length = norm3(normal)
    base = WS_EPA_FACES + 8 * slot
    ws[base] = i
    ws[base + 1] = j
    ws[base + 2] = k
    if length > 0.0:
        normal = scale3(1.0 / length, normal)
        ws[base + 6] = dot3(normal, a)
    else:
        ws[base + 6] = math.inf
    store_row_flat(ws, base + 3, normal)
    ws[base + 7] = 1.0
    return faces, slot


@njit(cache=True, error_model="numpy")
def epa_add_edge(ws, edges, i, j):
    """Horizon bookkeeping: the edge ``(i, j)`` of a removed face cancels its reverse ``(j, i)`` (the two
    faces sharing it are both removed), else joins the horizon. Returns the edge count (−1: full)."""
    for e in range(edges):
        if int(ws[WS_EPA_EDGES + 2 * e]) == j and int(ws[WS_EPA_EDGES + 2 * e + 1]) == i:
            last = edges - 1
            ws[WS_EPA_EDGES + 2 * e] = ws[WS_EPA_EDGES + 2 * last]
            ws[WS_EPA_EDGES + 2 * e + 1] = ws[WS_EPA_EDGES + 2 * last + 1]
            return last
    if edges >= EPA_EDGES:
        return -1
    ws[WS_EPA_EDGES + 2 * edges] = i
    ws[WS_EPA_EDGES + 2 * edges + 1] = j
    return edges + 1


@njit(cache=True, error_model="numpy")
def epa_barycentric(ws, i, j, k, z):
    """Barycentric coordinates ``(u, v, w)`` of the point ``z`` in the plane of the EPA vertices ``a, b, c``
    (indices ``i, j, k``) (RTCD §3.4, unclamped): with ``v₀ = b − a``, ``v₁ = c − a``, ``v₂ = z − a`` and
    ``dᵢⱼ = vᵢ·vⱼ``, ``v = (d₁₁ d₂₀ − d₀₁ d₂₁)/D``, ``w = (d₀₀ d₂₁ − d₀₁ d₂₀)/D``, ``D = d₀₀ d₁₁ − d₀₁²``."""
    a = load3(ws, WS_EPA_VERTICES + 9 * i)
    v0 = sub3(load3(ws, WS_EPA_VERTICES + 9 * j), a)
    v1 = sub3(load3(ws, WS_EPA_VERTICES + 9 * k), a)
    v2 = sub3(z, a)
    d00, d01, d11 = dot3(v0, v0), dot3(v0, v1), dot3(v1, v1)
    d20, d21 = dot3(v2, v0), dot3(v2, v1)
    denominator = d00 * d11 - d01 * d01
    if denominator <= 0.0:
        return 1.0, 0.0, 0.0
    v = (d11 * d20 - d01 * d21) / denominator
    w = (d00 * d21 - d01 * d20) / denominator
    return 1.0 - v - w, v, w


@njit(cache=True, error_model="numpy")
def epa_free_faces(ws, faces):
    """Slots of removed faces among the first ``faces``, free for new ones."""
    free = 0
    for f in range(faces):
        if ws[WS_EPA_FACES + 8 * f + 7] == 0.0:
            free += 1
    return free


@njit(cache=True, error_model="numpy")
def epa_neighbour(ws, faces, i, j):
    """The live face holding the directed edge ``(j, i)``: the neighbour across edge ``(i, j)``; −1 if none."""
    for f in range(faces):
        base = WS_EPA_FACES + 8 * f
        if ws[base + 7] == 0.0:
            continue
        a, b, c = int(ws[base]), int(ws[base + 1]), int(ws[base + 2])
        if (a == j and b == i) or (b == j and c == i) or (c == j and a == i):
            return f
    return -1


@njit(cache=True, error_model="numpy")
def epa_remove_visible(ws, faces, first, w):
    """Remove the faces that the new vertex ``w`` sees (``n·(w − a) > 0``), grown across edges from the face
    ``first`` (which sees it), so that the removed faces form one patch and its boundary, the horizon, one
    loop (van den Bergen 2003, §4.3.8, the silhouette); the horizon's directed edges are left at
    ``ws[WS_EPA_EDGES:]``. Returns their count, −1 when a table is full."""
    edges = 0
    top = 0
    ws[WS_EPA_STACK] = first
    top = 1
    ws[WS_EPA_FACES + 8 * first + 7] = 0.0
    while top > 0:
        top -= 1
        f = int(ws[WS_EPA_STACK + top])
        base = WS_EPA_FACES + 8 * f
        corners = (int(ws[base]), int(ws[base + 1]), int(ws[base + 2]))
        for e in range(3):
            i = corners[e]
            j = corners[(e + 1) % 3]
            edges = epa_add_edge(ws, edges, i, j)
            if edges < 0:
                return -1
            g = epa_neighbour(ws, faces, i, j)
            if g < 0 or ws[WS_EPA_FACES + 8 * g + 7] != 1.0:
                continue
            other = WS_EPA_FACES + 8 * g
            if dot3(load3(ws, other + 3), sub3(w, load3(ws, WS_EPA_VERTICES + 9 * int(ws[other])))) > 0.0:
                ws[other + 7] = 0.0
                if top >= EPA_FACES:
                    return -1
                ws[WS_EPA_STACK + top] = g
                top += 1
            else:
                # seen and kept: not tested again in this pass
                ws[other + 7] = 2.0
    for f in range(faces):
        if ws[WS_EPA_FACES + 8 * f + 7] == 2.0:
            ws[WS_EPA_FACES + 8 * f + 7] = 1.0
    return edges


@njit(cache=True, error_model="numpy")
def epa(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, rounded, m, scale, ws):
    """Penetration depth by the expanding polytope algorithm (van den Bergen 2003, §4.3.8): from GJK's
    simplex around the origin (grown to a tetrahedron), repeatedly take the polytope's face nearest the
    origin (unit outward normal ``n``, distance ``d``) and the support point ``w = s_{A−B}(n)``; stop when
    ``n·w − d ≤ ε``, else add ``w``, remove the faces it sees and close the hole with faces on the horizon.

    Returns ``(status, depth, n, x_a, x_b)``: ``OVERLAP`` with ``x_a − x_b = depth · n`` the witness points
    (barycentric on the nearest face), so that a's contact normal is ``−n``; ``DEGENERATE`` when
    ``A − B`` is flat (no tetrahedron)."""
    for k in range(m):
        copy_vertex(ws, WS_SIMPLEX + 9 * k, WS_EPA_VERTICES + 9 * k)
    tolerance = EPA_TOLERANCE * scale
    zero = (0.0, 0.0, 0.0)
    # grow the simplex to a tetrahedron with support points off its affine hull
    if m == 1:
        w0 = load3(ws, WS_EPA_VERTICES)
        for k in range(6):
            d = (1.0 if k == 0 else (-1.0 if k == 1 else 0.0), 1.0 if k == 2 else (-1.0 if k == 3 else 0.0),
                 1.0 if k == 4 else (-1.0 if k == 5 else 0.0))
            w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                                   d, rounded, ws, WS_EPA_VERTICES + 9)
            if norm3(sub3(w, w0)) > tolerance:
                m = 2
                break
        if m == 1:
            return DEGENERATE, 0.0, zero, zero, zero
    if m == 2:
        w0 = load3(ws, WS_EPA_VERTICES)
        line = sub3(load3(ws, WS_EPA_VERTICES + 9), w0)
        line = scale3(1.0 / norm3(line), line)
        e1 = any_perpendicular(line)
        e2 = cross(line, e1)
        for k in range(6):
            angle = math.pi * k / 3.0
            d = add3(scale3(math.cos(angle), e1), scale3(math.sin(angle), e2))
            w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                                   d, rounded, ws, WS_EPA_VERTICES + 18)
            if norm3(cross(sub3(w, w0), line)) > tolerance:
                m = 3
                break
        if m == 2:
            return DEGENERATE, 0.0, zero, zero, zero
    if m == 3:
        w0 = load3(ws, WS_EPA_VERTICES)
        normal = cross(sub3(load3(ws, WS_EPA_VERTICES + 9), w0), sub3(load3(ws, WS_EPA_VERTICES + 18), w0))
        normal = scale3(1.0 / norm3(normal), normal)
        w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                               normal, rounded, ws, WS_EPA_VERTICES + 27)
        if abs(dot3(normal, sub3(w, w0))) <= tolerance:
            w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                                   scale3(-1.0, normal), rounded, ws, WS_EPA_VERTICES + 27)
            if abs(dot3(normal, sub3(w, w0))) <= tolerance:
                return DEGENERATE, 0.0, zero, zero, zero
    w0 = load3(ws, WS_EPA_VERTICES)
    w1 = load3(ws, WS_EPA_VERTICES + 9)
    w2 = load3(ws, WS_EPA_VERTICES + 18)
    w3 = load3(ws, WS_EPA_VERTICES + 27)
    volume = dot3(sub3(w1, w0), cross(sub3(w2, w0), sub3(w3, w0)))
    if abs(volume) <= tolerance ** 3:
        return DEGENERATE, 0.0, zero, zero, zero
    if volume < 0.0:
        # orient (w0, w1, w2, w3) positively: swap w1 and w2
        for k in range(9):
            x = ws[WS_EPA_VERTICES + 9 + k]
            ws[WS_EPA_VERTICES + 9 + k] = ws[WS_EPA_VERTICES + 18 + k]
            ws[WS_EPA_VERTICES + 18 + k] = x
    for f in range(EPA_FACES):
        ws[WS_EPA_FACES + 8 * f + 7] = 0.0
    # the outward faces of a positively oriented tetrahedron
    faces = 0
    faces, _ = epa_add_face(ws, faces, 0, 2, 1)
    faces, _ = epa_add_face(ws, faces, 0, 1, 3)
    faces, _ = epa_add_face(ws, faces, 0, 3, 2)
    faces, _ = epa_add_face(ws, faces, 1, 2, 3)
    vertices = 4
    intact = True
    while True:
        best = -1
        best_distance = math.inf
        for f in range(faces):
            base = WS_EPA_FACES + 8 * f
            if ws[base + 7] != 0.0 and ws[base + 6] < best_distance:
                best_distance = ws[base + 6]
                best = f
        if best < 0:
            return DEGENERATE, 0.0, zero, zero, zero
        base = WS_EPA_FACES + 8 * best
        i, j, k = int(ws[base]), int(ws[base + 1]), int(ws[base + 2])
        n = load3(ws, base + 3)
        if vertices >= EPA_VERTICES:
            break
        w = support_difference(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, n,
                               rounded, ws, WS_EPA_VERTICES + 9 * vertices)
        if dot3(n, w) - best_distance <= tolerance:
            break
        edges = epa_remove_visible(ws, faces, best, w)
        if edges < 0 or faces + edges > EPA_FACES + epa_free_faces(ws, faces):
            # out of room: the nearest face found so far is the answer (its vertices are kept)
            intact = False
            break
        broken = False
        for e in range(edges):
            faces, f = epa_add_face(ws, faces, int(ws[WS_EPA_EDGES + 2 * e]), int(ws[WS_EPA_EDGES + 2 * e + 1]),
                                    vertices)
            # the polytope only grows, so no new face may be nearer the origin than the face expanded:
            # one that is, a sliver whose normal rounding has turned, ends the expansion
            broken = broken or ws[WS_EPA_FACES + 8 * f + 6] < best_distance - tolerance
        if broken:
            intact = False
            break
        vertices += 1
    # witnesses: barycentric coordinates of z = d n on the nearest face; of the faces in its plane (a
    # polytope's face is split into triangles), the one holding z
    z = scale3(best_distance, n)
    l0, l1, l2 = epa_barycentric(ws, i, j, k, z)
    for f in range(faces):
        base = WS_EPA_FACES + 8 * f
        if not intact or least3(l0, l1, l2) >= 0.0:
            break
        if ws[base + 7] == 0.0 or abs(ws[base + 6] - best_distance) > tolerance \
                or dot3(load3(ws, base + 3), n) < 1.0 - PARALLEL:
            continue
        fi, fj, fk = int(ws[base]), int(ws[base + 1]), int(ws[base + 2])
        m0, m1, m2 = epa_barycentric(ws, fi, fj, fk, z)
        if least3(m0, m1, m2) > least3(l0, l1, l2):
            i, j, k = fi, fj, fk
            l0, l1, l2 = m0, m1, m2
    # x_a = Σ λ a, x_b = Σ λ b over the face's vertices [w, a, b]
    vi, vj, vk = WS_EPA_VERTICES + 9 * i, WS_EPA_VERTICES + 9 * j, WS_EPA_VERTICES + 9 * k
    x_a = add3(add3(scale3(l0, load3(ws, vi + 3)), scale3(l1, load3(ws, vj + 3))), scale3(l2, load3(ws, vk + 3)))
    x_b = add3(add3(scale3(l0, load3(ws, vi + 6)), scale3(l1, load3(ws, vj + 6))), scale3(l2, load3(ws, vk + 6)))
    return OVERLAP, best_distance, n, x_a, x_b


@njit(cache=True, error_model="numpy")
def convex_contact(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, count,
                   ws):
    """One contact between any two convex shapes by GJK and EPA on their support functions.

    Spheres and capsules enter as their cores (a point, a segment) rounded by their radii ``r_a``, ``r_b``:
    GJK on the cores gives the distance ``δ`` and nearest points ``y_a``, ``y_b`` exactly for polytope
    cores, and ``n = (y_a − y_b)/δ``, ``gap = δ − r_a − r_b``, witnesses ``y_a − r_a n``, ``y_b + r_b n``.
    Where the cores overlap, EPA on the cores gives the depth ``d`` and direction ``m`` of ``A − B``
    (``n = −m``, ``gap = −d − r_a − r_b``), and where their difference is flat (two segments crossing),
    EPA on the whole, rounded shapes. The single contact point is the midpoint of the two witnesses,
    the points of a and b deepest in (or nearest to) each other.
    """
    ha, Ra, pa = as_tuples(size_a, R_a, p_a)
    hb, Rb, pb = as_tuples(size_b, R_b, p_b)
    r_a = core_radius(shape_a, ha)
    r_b = core_radius(shape_b, hb)
    scale = pair_scale(shape_a, ha, vertices_a, pa, shape_b, hb, vertices_b, pb)
    limit = margin + r_a + r_b
    status, v, y_a, y_b, m = gjk(shape_a, ha, vertices_a, Ra, pa, shape_b, hb, vertices_b, Rb, pb, False, limit,
                                 scale, ws)
    if status == SEPARATED:
        return count
    if status == DISTANCE:
        distance = norm3(v)
        n = scale3(1.0 / distance, v)
        return write_pair(out, count, sub3(y_a, scale3(r_a, n)), add3(y_b, scale3(r_b, n)), n, distance - r_a - r_b,
                          margin)
    status, depth, direction, y_a, y_b = epa(shape_a, ha, vertices_a, Ra, pa, shape_b, hb, vertices_b, Rb, pb, False,
                                             m, scale, ws)
    if status == OVERLAP:
        n = scale3(-1.0, direction)
        return write_pair(out, count, sub3(y_a, scale3(r_a, n)), add3(y_b, scale3(r_b, n)), n, -depth - r_a - r_b,
                          margin)
    # flat core difference: the whole shapes
    status, v, y_a, y_b, m = gjk(shape_a, ha, vertices_a, Ra, pa, shape_b, hb, vertices_b, Rb, pb, True, margin,
                                 scale, ws)
    if status == SEPARATED:
        return count
    if status == DISTANCE:
        distance = norm3(v)
        return write_pair(out, count, y_a, y_b, scale3(1.0 / distance, v), distance, margin)
    status, depth, direction, y_a, y_b = epa(shape_a, ha, vertices_a, Ra, pa, shape_b, hb, vertices_b, Rb, pb, True,
                                             m, scale, ws)
    if status == OVERLAP:
        return write_pair(out, count, y_a, y_b, scale3(-1.0, direction), -depth, margin)
    # a flat shape touching: zero gap along the difference's normal is undefined; report none
    return count


@njit(cache=True, error_model="numpy")
def box_capsule(size_a, vertices_a, R_a, p_a, size_b, vertices_b, R_b, p_b, margin, out, count, ws):
    """A box (a) against a capsule (b). GJK on the box and the capsule's segment gives their distance ``δ``
    and direction ``n`` (from the capsule into the box). Where ``n`` is a face normal of the box, the
    segment is clipped to the face's slab (Liang–Barsky, ``|e_i·(x − p_a)| ≤ hᵢ`` for the face's two side
    axes) and each end ``x`` of the clipped segment gives a contact with ``gap = d(x) − r``, ``d(x)`` its
    height over the face plane: a capsule lying on a face is supported at both ends, a tilted one where it
    comes within the margin. Otherwise, and where the segment enters the box, one contact by
    :func:`convex_contact`."""
    ha, Ra, pa = as_tuples(size_a, R_a, p_a)
    hb, Rb, pb = as_tuples(size_b, R_b, p_b)
    r = hb[0]
    scale = pair_scale(BOX, ha, vertices_a, pa, CAPSULE, hb, vertices_b, pb)
    status, v, _, _, _ = gjk(BOX, ha, vertices_a, Ra, pa, CAPSULE, hb, vertices_b, Rb, pb, False, margin + r,
                                 scale, ws)
    if status == SEPARATED:
        return count
    if status == DISTANCE:
        n = scale3(1.0 / norm3(v), v)
        face = -1
        for k in range(3):
            if abs(dot3(n, axis_of(Ra, k))) >= 1.0 - PARALLEL:
                face = k
        if face >= 0:
            # the segment in the box frame, clipped to the slabs of the two side axes
            s0, s1 = segment_of(hb, Rb, pb)
            l0 = rotate_back(Ra, sub3(s0, pa))
            l1 = rotate_back(Ra, sub3(s1, pa))
            lo = 0.0
            hi = 1.0
            for i in range(3):
                if i == face:
                    continue
                d = l1[i] - l0[i]
                if d == 0.0:
                    if abs(l0[i]) > ha[i]:
                        hi = -1.0
                    continue
                t0 = (-ha[i] - l0[i]) / d
                t1 = (ha[i] - l0[i]) / d
                lo = clamp(t0 if t0 < t1 else t1, lo, 1.0)
                hi = clamp(t1 if t0 < t1 else t0, 0.0, hi)
            if lo <= hi:
                side = -1.0 if dot3(n, axis_of(Ra, face)) > 0.0 else 1.0  # the face's outward normal is −n
                ends = 2 if hi > lo else 1
                for e in range(ends):
                    t = lo if e == 0 else hi
                    local = add3(l0, scale3(t, sub3(l1, l0)))
                    height = side * local[face] - ha[face]
                    x = add3(s0, scale3(t, sub3(s1, s0)))
                    count = write_pair(out, count, add3(x, scale3(height, n)), add3(x, scale3(r, n)), n, height - r,
                                       margin)
                return count
    return convex_contact(BOX, size_a, vertices_a, R_a, p_a, CAPSULE, size_b, vertices_b, R_b, p_b, margin, out, count,
                          ws)


@njit(cache=True, error_model="numpy")
def box_face_manifold(size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, count, ws):
    """A box (a) against a cylinder or a convex hull (b). GJK/EPA (:func:`convex_contact`) gives the
    nearest contact and its normal ``N`` (from b into the box). Where ``N`` is a face normal of the box,
    b is taken against that face's plane, the half-space ``m·x ≥ m·p_a + h_k`` with ``m = −N``
    (:func:`halfspace_contacts`: a cylinder standing on the face gives its rim points, a hull its vertices),
    each moved to the midpoint ``x − (gap/2) m`` of its two witnesses, when all of them are over the face
    (``|e_i·(x − p_a)| ≤ h_i`` on its two side axes). Where some overhang the face, and where ``N`` is no face
    normal of the box (an edge or a corner of the box on b), the clipped manifold of the two support features
    (:func:`clip_manifold`: b's feature cut at the face's edges)."""
    single = convex_contact(BOX, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                            count, ws)
    if single == count:
        return count
    normal = row3(out, count, 3)
    Ra = rotation9(R_a)
    face = -1
    for k in range(3):
        if abs(dot3(normal, axis_of(Ra, k))) >= 1.0 - PARALLEL:
            face = k
    if face < 0:
        return clip_manifold(BOX, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                             count, single, ws)
    first = row3(out, count, 0) + row3(out, count, 3) + (out[count, 6],)
    m = scale3(-1.0, normal)
    pa = load3(p_a, 0)
    e = axis_of(Ra, face)
    outward = e if dot3(e, m) > 0.0 else scale3(-1.0, e)
    store_row_flat(ws, WS_PLANE, outward)
    height = dot3(outward, pa) + size_a[face]
    found = halfspace_contacts(shape_b, size_b, vertices_b, R_b, p_b, ws[WS_PLANE:WS_PLANE + 3], height, margin,
                               out[count:], ws)
    kept = count
    for i in range(count, count + found):
        x = row3(out, i, 0)
        gap = out[i, 6]
        over = True
        for k in range(3):
            if k != face and abs(dot3(axis_of(Ra, k), sub3(x, pa))) > size_a[k] * (1.0 + PARALLEL):
                over = False
        if over:
            store_row(out, kept, 0, sub3(x, scale3(0.5 * gap, outward)) + scale3(-1.0, outward) + (gap,))
            kept += 1
    if kept == count + found:
        return kept
    # b overhangs the face: its support feature clipped at the face's edges
    store_row(out, count, 0, first)
    return clip_manifold(BOX, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, count,
                         count + 1, ws)


# ---------------------------------------------------------------------------------------------------------------------
# contact manifolds of the GJK/EPA pairs: support features clipped against each other


@njit(cache=True, error_model="numpy")
def feature_point(shape, size, vertices, R, p, d, t, top, band):
    """The point of a shape's support feature along the unit world direction ``d`` that lies farthest along the
    world direction ``t`` (perpendicular to ``d``), in world coordinates, on the whole (rounded) shape.

    The support feature is the set of the shape's points farthest along ``d``, where a face or an edge within
    ``FEATURE_ANGLE`` of perpendicular to ``d`` counts as perpendicular: in the geometry frame, with ``d' = Rᵀ d``
    and ``t' = Rᵀ t``, box ``(sign(d'ᵢ or t'ᵢ) hᵢ)``, ``t'ᵢ`` where ``|d'ᵢ| ≤ FEATURE_ANGLE`` (a face, an edge or a
    corner); capsule ``(0, 0, sign(d'_z or t'_z) h) + r d`` (its side line or an end); cylinder: its cap disc
    ``(r t'_⊥/|t'_⊥|, sign(d'_z) h)`` where ``|d'_⊥| ≤ FEATURE_ANGLE``, else ``(r d'_⊥/|d'_⊥|, sign(d'_z or t'_z) h)``
    (its side line or a rim point); hull: of its vertices ``v`` with ``d'·v ≥ top − band`` (``top = max_v d'·v``,
    ``band`` in m), the one with the largest ``t'·v``; sphere: ``p + r d``."""
    dl = rotate_back(R, d)
    tl = rotate_back(R, t)
    if shape == BOX:
        local = (math.copysign(size[0], dl[0] if abs(dl[0]) > FEATURE_ANGLE else tl[0]),
                 math.copysign(size[1], dl[1] if abs(dl[1]) > FEATURE_ANGLE else tl[1]),
                 math.copysign(size[2], dl[2] if abs(dl[2]) > FEATURE_ANGLE else tl[2]))
    elif shape == CAPSULE:
        local = (0.0, 0.0, math.copysign(size[1], dl[2] if abs(dl[2]) > FEATURE_ANGLE else tl[2]))
    elif shape == CYLINDER:
        if math.sqrt(dl[0] * dl[0] + dl[1] * dl[1]) <= FEATURE_ANGLE:
            z = math.copysign(size[1], dl[2])
            radial = (tl[0], tl[1])
        else:
            z = math.copysign(size[1], dl[2] if abs(dl[2]) > FEATURE_ANGLE else tl[2])
            radial = (dl[0], dl[1])
        length = math.sqrt(radial[0] * radial[0] + radial[1] * radial[1])
        if length > 0.0:
            local = (size[0] * radial[0] / length, size[0] * radial[1] / length, z)
        else:
            local = (size[0], 0.0, z)
    elif shape == CONVEX:
        best = 0
        best_value = -math.inf
        for i in range(vertices.shape[0]):
            v = row3(vertices, i, 0)
            if dot3(dl, v) >= top - band and dot3(tl, v) > best_value:
                best_value = dot3(tl, v)
                best = i
        local = row3(vertices, best, 0)
    else:
        local = (0.0, 0.0, 0.0)
    return add3(add3(p, rotate(R, local)), scale3(core_radius(shape, size), d))


@njit(cache=True, error_model="numpy")
def support_polygon(shape, size, vertices, R, p, d, e1, e2, ws, at):
    """A shape's support feature along the unit world direction ``d`` (:func:`feature_point`) as a convex polygon
    written at ``ws[at:]``: its extreme points along ``FEATURE_VERTICES`` directions ``t_k = cos θ_k e1 + sin θ_k e2``
    evenly spread over the full turn of the plane of the unit vectors ``e1 ⟂ e2`` (both ⟂ ``d``), repeats dropped.
    The extreme point of a convex set turns with ``t``, so the vertices come counter-clockwise about ``e1 × e2``.
    Returns their count: 1 a point, 2 a segment, more a polygon (a hull face of more vertices gives the extreme
    ones: a polygon inside the face; a cylinder's cap, its rim at ``FEATURE_VERTICES`` points)."""
    top = 0.0
    band = 0.0
    if shape == SPHERE:
        store_row_flat(ws, at, feature_point(shape, size, vertices, R, p, d, e1, top, band))
        return 1
    if shape == CONVEX:
        dl = rotate_back(R, d)
        top = -math.inf
        for i in range(vertices.shape[0]):
            top = larger(top, dot3(dl, row3(vertices, i, 0)))
        # a face within FEATURE_ANGLE of perpendicular to d rises by at most that angle times the hull's radius
        band = FEATURE_ANGLE * bounding_radius(shape, size, vertices)
    count = 0
    for k in range(FEATURE_VERTICES):
        angle = 2.0 * math.pi * k / FEATURE_VERTICES
        t = add3(scale3(math.cos(angle), e1), scale3(math.sin(angle), e2))
        x = feature_point(shape, size, vertices, R, p, d, t, top, band)
        if count == 0 or not same3(x, load3(ws, at + 3 * (count - 1))):
            store_row_flat(ws, at + 3 * count, x)
            count += 1
    if count > 1 and same3(load3(ws, at), load3(ws, at + 3 * (count - 1))):
        count -= 1
    return count


@njit(cache=True, error_model="numpy")
def same3(a, b):
    """Whether two 3-tuples are equal entry by entry."""
    return a[0] == b[0] and a[1] == b[1] and a[2] == b[2]


@njit(cache=True, error_model="numpy")
def polygon_normal(ws, at, m):
    """Twice the vector area of the polygon of ``m`` vertices ``x_i`` at ``ws[at:]``, along the normal about which the
    vertices turn counter-clockwise: Newell's normal ``Σᵢ x_i × x_{i+1}`` (indices mod ``m``; M. E. Newell's method,
    as in C. Ericson, *Real-Time Collision Detection*, chapter 12, "Geometrical Robustness"), summed as the fan of
    triangles from ``x_0``, whose terms are smaller where the polygon lies far from the origin and whose sum is the
    same for a closed polygon."""
    x0 = load3(ws, at)
    total = (0.0, 0.0, 0.0)
    # Σᵢ₌₁^{m−2} (x_i − x_0) × (x_{i+1} − x_0)
    for i in range(1, m - 1):
        total = add3(total, cross(sub3(load3(ws, at + 3 * i), x0), sub3(load3(ws, at + 3 * (i + 1)), x0)))
    return total


@njit(cache=True, error_model="numpy")
def feature_dimension(ws, at, m, tolerance):
    """The dimension of the feature of ``m`` points at ``ws[at:]``: 0 a point, 1 a segment, 2 a polygon; a polygon
    of area below ``tolerance²`` (m²) is made the segment of its first point and the point farthest from it."""
    if m == 1:
        return 0
    if m == 2:
        return 1
    if norm3(polygon_normal(ws, at, m)) > 2.0 * tolerance * tolerance:
        return 2
    x0 = load3(ws, at)
    far = 1
    far_distance = -1.0
    for i in range(1, m):
        distance = norm3(sub3(load3(ws, at + 3 * i), x0))
        if distance > far_distance:
            far_distance = distance
            far = i
    store_row_flat(ws, at + 3, load3(ws, at + 3 * far))
    return 1


@njit(cache=True, error_model="numpy")
def area_gain(q0, q1, q2, x, normal):
    """How far outside the triangle ``q0 q1 q2`` (counter-clockwise about ``normal``) the point ``x`` lies, as
    twice the area it adds: ``max_j −((q_{j+1} − q_j) × (x − q_j))·normal``, 0 or less inside."""
    a = -dot3(cross(sub3(q1, q0), sub3(x, q0)), normal)
    b = -dot3(cross(sub3(q2, q1), sub3(x, q1)), normal)
    c = -dot3(cross(sub3(q0, q2), sub3(x, q2)), normal)
    return -least3(-a, -b, -c)


@njit(cache=True, error_model="numpy")
def reduce_manifold(ws, source, m, normal, origin, sign, margin, tolerance, out, count):
    """The clipped incident points ``x_i`` (``m`` at ``ws[source:]``), each with its gap
    ``g_i = sign · normal·(x_i − origin)`` to the reference feature's plane (through ``origin``, unit ``normal``
    from b into a; ``sign`` +1 when the reference is b's, −1 when a's), reduced to at most ``MANIFOLD_POINTS`` of
    those with ``g < margin``, keeping the area largest (D. Gregorius, "Robust Contact Creation for Physics
    Simulations", GDC 2015, contact reduction): the deepest ``x₀`` (the first within ``tolerance`` of the least gap),
    the farthest from it ``x₁``, the one making the largest triangle ``x₂``, and the one adding the most area
    outside that triangle ``x₃`` (:func:`area_gain`); points closer than ``tolerance`` (m) to the line or triangle
    already kept add none. Each is written as the midpoint ``x − sign (g/2) normal`` of its two witnesses, with
    ``normal`` and ``g``, from row ``count`` of ``out``; returns the new count (``count``: none within the margin)."""
    least = math.inf
    for i in range(m):
        least = smaller(least, sign * dot3(normal, sub3(load3(ws, source + 3 * i), origin)))
    if not least < margin:
        return count
    i0 = -1
    for i in range(m):
        if i0 < 0 and sign * dot3(normal, sub3(load3(ws, source + 3 * i), origin)) <= least + tolerance:
            i0 = i
    ws[WS_SELECT] = i0
    kept = 1
    x0 = load3(ws, source + 3 * i0)
    # x₁: the farthest from x₀ in the contact plane
    i1 = -1
    best = tolerance
    for i in range(m):
        x = load3(ws, source + 3 * i)
        if sign * dot3(normal, sub3(x, origin)) < margin:
            offset = sub3(x, x0)
            distance = norm3(sub3(offset, scale3(dot3(offset, normal), normal)))
            if distance > best:
                best = distance
                i1 = i
    if i1 >= 0:
        ws[WS_SELECT + 1] = i1
        kept = 2
        x1 = load3(ws, source + 3 * i1)
        # x₂: the largest triangle x₀ x₁ x, twice its area |((x₁ − x₀) × (x − x₀))·n|
        i2 = -1
        best = tolerance * best
        for i in range(m):
            x = load3(ws, source + 3 * i)
            if sign * dot3(normal, sub3(x, origin)) < margin:
                area = abs(dot3(cross(sub3(x1, x0), sub3(x, x0)), normal))
                if area > best:
                    best = area
                    i2 = i
        if i2 >= 0:
            x2 = load3(ws, source + 3 * i2)
            if dot3(cross(sub3(x1, x0), sub3(x2, x0)), normal) < 0.0:
                i1, i2 = i2, i1
                x1, x2 = x2, x1
            ws[WS_SELECT + 1] = i1
            ws[WS_SELECT + 2] = i2
            kept = 3
            # x₃: the most area added outside the triangle, compared as above with the longest side's tolerance
            i3 = -1
            best = tolerance * norm3(sub3(x1, x0))
            for i in range(m):
                x = load3(ws, source + 3 * i)
                if sign * dot3(normal, sub3(x, origin)) < margin:
                    gain = area_gain(x0, x1, x2, x, normal)
                    if gain > best:
                        best = gain
                        i3 = i
            if i3 >= 0 and MANIFOLD_POINTS > 3:
                ws[WS_SELECT + 3] = i3
                kept = 4
    for j in range(kept):
        x = load3(ws, source + 3 * int(ws[WS_SELECT + j]))
        gap = sign * dot3(normal, sub3(x, origin))
        count = write_contact(out, count, sub3(x, scale3(0.5 * sign * gap, normal)), normal, gap)
    return count


@njit(cache=True, error_model="numpy")
def clip_manifold(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, count,
                  single, ws):
    """The contact manifold of two convex shapes about their GJK/EPA contact, row ``count`` of ``out`` (written by
    :func:`convex_contact`; ``single = count + 1``, or ``count`` when there is none), by clipping their support
    features (D. Gregorius, "Robust Contact Creation for Physics Simulations", GDC 2015; RTCD §8.3.4 for the
    Sutherland–Hodgman clipping). With that contact's normal ``n`` (from b into a):

    * each shape's support feature: a's along ``−n``, b's along ``n`` (:func:`support_polygon`: a face, an edge or
      a vertex of a hull or a box, a cylinder's cap disc or side line, a capsule's side line);
    * a vertex on either side: the GJK/EPA contact alone; two edges not parallel (within ``FEATURE_ANGLE``): the
      same;
    * otherwise the reference feature is the one of higher dimension (two faces: the one whose normal is nearer
      ``n``, a's on a tie), the other the incident one; the contact normal ``N`` is the reference face's normal
      (:func:`polygon_normal`) or, for an edge, ``n`` made perpendicular to it, ``n − (n·u) u`` normalised;
    * the incident feature is clipped by the reference face's side planes ``((x_{i+1} − x_i) × N)·(x − x_i) ≤ 0``
      (for an edge, the planes through its ends across it) (:func:`clip_polygon`);
    * each clipped point ``x`` has the gap ``g = ±N·(x − x_ref)`` to the reference plane, and those with
      ``g < margin`` are reduced to at most ``MANIFOLD_POINTS`` spanning the largest area (:func:`reduce_manifold`).

    A hull resting face down on a hull gives the corners of the faces' overlap; a cylinder standing on its cap,
    points of its rim. Returns the new count; the GJK/EPA contact where clipping keeps no point."""
    if single == count or shape_a == SPHERE or shape_b == SPHERE:
        return single
    n = row3(out, count, 3)
    ha, Ra, pa = as_tuples(size_a, R_a, p_a)
    hb, Rb, pb = as_tuples(size_b, R_b, p_b)
    tolerance = PARALLEL * pair_scale(shape_a, ha, vertices_a, pa, shape_b, hb, vertices_b, pb)
    e1 = any_perpendicular(n)
    e2 = cross(n, e1)
    k_a = support_polygon(shape_a, ha, vertices_a, Ra, pa, scale3(-1.0, n), e1, e2, ws, WS_FEATURE_A)
    k_b = support_polygon(shape_b, hb, vertices_b, Rb, pb, n, e1, e2, ws, WS_FEATURE_B)
    dim_a = feature_dimension(ws, WS_FEATURE_A, k_a, tolerance)
    dim_b = feature_dimension(ws, WS_FEATURE_B, k_b, tolerance)
    if dim_a == 0 or dim_b == 0:
        return single
    if dim_a == 1:
        k_a = 2
    if dim_b == 1:
        k_b = 2
    if dim_a == 2 and dim_b == 2:
        w_a = polygon_normal(ws, WS_FEATURE_A, k_a)
        w_b = polygon_normal(ws, WS_FEATURE_B, k_b)
        reference_b = abs(dot3(w_b, n)) * norm3(w_a) > abs(dot3(w_a, n)) * norm3(w_b)
    elif dim_a == 1 and dim_b == 1:
        u_a = sub3(load3(ws, WS_FEATURE_A + 3), load3(ws, WS_FEATURE_A))
        u_b = sub3(load3(ws, WS_FEATURE_B + 3), load3(ws, WS_FEATURE_B))
        if norm3(cross(u_a, u_b)) > FEATURE_ANGLE * norm3(u_a) * norm3(u_b):
            return single
        reference_b = False
    else:
        reference_b = dim_b > dim_a
    reference = WS_FEATURE_B if reference_b else WS_FEATURE_A
    k_ref = k_b if reference_b else k_a
    incident = WS_FEATURE_A if reference_b else WS_FEATURE_B
    m = k_a if reference_b else k_b
    sign = 1.0 if reference_b else -1.0
    origin = load3(ws, reference)
    # N: the reference face's unit normal, or for an edge of direction u, n − (n·u) u normalised
    if k_ref >= 3:
        normal = polygon_normal(ws, reference, k_ref)
        normal = scale3(1.0 / norm3(normal), normal)
    else:
        u = sub3(load3(ws, reference + 3), origin)
        u = scale3(1.0 / norm3(u), u)
        normal = sub3(n, scale3(dot3(n, u), u))
        normal = scale3(1.0 / norm3(normal), normal)
    source = WS_CLIP
    target = WS_CLIP + 3 * CLIP_VERTICES
    for i in range(3 * m):
        ws[source + i] = ws[incident + i]
    if k_ref >= 3:
        # the incident feature cut by each side plane of the face, ((x_{i+1} − x_i) × N)·(x − x_i) ≤ 0
        for i in range(k_ref):
            x_i = load3(ws, reference + 3 * i)
            side = cross(sub3(load3(ws, reference + 3 * ((i + 1) % k_ref)), x_i), normal)
            m = clip_polygon(ws, source, m, target, side, dot3(side, x_i))
            source, target = target, source
            if m == 0:
                return single
    else:
        # cut by the planes through the edge's ends x_0, x_1 across it: u·x ≤ u·x_1 and −u·x ≤ −u·x_0
        u = sub3(load3(ws, reference + 3), origin)
        m = clip_polygon(ws, source, m, target, u, dot3(u, load3(ws, reference + 3)))
        source, target = target, source
        if m == 0:
            return single
        u = scale3(-1.0, u)
        m = clip_polygon(ws, source, m, target, u, dot3(u, origin))
        source, target = target, source
        if m == 0:
            return single
    first = row3(out, count, 0) + row3(out, count, 3) + (out[count, 6],)
    written = reduce_manifold(ws, source, m, normal, origin, sign, margin, tolerance, out, count)
    if written > count:
        return written
    store_row(out, count, 0, first)
    return single


@njit(cache=True, error_model="numpy")
def convex_manifold(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, count,
                    ws):
    """Contacts between any two convex shapes: the GJK/EPA contact (:func:`convex_contact`) grown into the clipped
    manifold of the shapes' support features (:func:`clip_manifold`). Returns the new count."""
    single = convex_contact(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                            count, ws)
    return clip_manifold(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                         count, single, ws)


# ---------------------------------------------------------------------------------------------------------------------
# dispatch


@njit(cache=True, error_model="numpy")
def ordered_pair_contacts(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                          ws):
    """:func:`pair_contacts` for ``shape_a ≤ shape_b``."""
    count = 0
    if shape_a == SPHERE and shape_b == SPHERE:
        return spheres(load3(p_a, 0), size_a[0], load3(p_b, 0), size_b[0], margin, out, count)
    if shape_a == SPHERE and shape_b == BOX:
        return sphere_box(load3(p_a, 0), size_a[0], load3(size_b, 0), rotation9(R_b), load3(p_b, 0), margin, out,
                          count)
    if shape_a == SPHERE and shape_b == CAPSULE:
        b0, b1 = segment_of(load3(size_b, 0), rotation9(R_b), load3(p_b, 0))
        c = load3(p_a, 0)
        y = add3(b0, scale3(closest_on_segment(c, b0, b1), sub3(b1, b0)))
        return spheres(c, size_a[0], y, size_b[0], margin, out, count)
    if shape_a == CAPSULE and shape_b == CAPSULE:
        return capsules(load3(size_a, 0), rotation9(R_a), load3(p_a, 0), load3(size_b, 0), rotation9(R_b),
                        load3(p_b, 0), margin, out, count)
    if shape_a == BOX and shape_b == CAPSULE:
        return box_capsule(size_a, vertices_a, R_a, p_a, size_b, vertices_b, R_b, p_b, margin, out, count, ws)
    if shape_a == BOX and (shape_b == CYLINDER or shape_b == CONVEX):
        return box_face_manifold(size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                                 count, ws)
    if shape_a == BOX and shape_b == BOX:
        return boxes(load3(size_a, 0), vertices_a, rotation9(R_a), load3(p_a, 0), load3(size_b, 0), vertices_b,
                     rotation9(R_b), load3(p_b, 0), margin, out, count, ws)
    return convex_manifold(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out,
                           count, ws)


@njit(cache=True, error_model="numpy")
def pair_contacts(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b, margin, out, ws):
    """Contacts between geometries a and b (each: shape code, ``size (3,)``, ``vertices (k, 3)``, world
    ``R (3, 3)``, ``p (3,)``), every one with ``gap < margin`` (m), written into ``out (MAX_PAIR_CONTACTS, 7)``
    with normals from b into a; returns the count.

    Analytic: sphere–sphere, sphere–box, sphere–capsule, capsule–capsule (:func:`capsules`; two points for
    parallel axes) and box–box (:func:`boxes`; the clipped face polygon's corners, or one edge–edge
    point); box–capsule by GJK with the segment clipped on a face (:func:`box_capsule`; two points for a
    capsule lying on a face); box–cylinder and box–hull by GJK/EPA, and where its normal is a box face's,
    the other shape against that face (:func:`box_face_manifold`: a cylinder standing on a box gives its
    rim points; otherwise as below). Any other pair (cylinder or convex hull with a sphere, a capsule, a
    cylinder or a hull): GJK/EPA's contact grown into the clipped manifold of the two shapes' support
    features (:func:`convex_manifold`: a hull face on a hull face gives the corners of their overlap, a cylinder
    standing on a hull points of its rim, at most ``MANIFOLD_POINTS``; a vertex, or two edges crossing, one
    point). Either order: the pair is computed with the lower
    shape code first and its normals flipped when a and b were swapped, so the gaps and points are the
    same and the normals opposite."""
    if shape_a <= shape_b:
        return ordered_pair_contacts(shape_a, size_a, vertices_a, R_a, p_a, shape_b, size_b, vertices_b, R_b, p_b,
                                     margin, out, ws)
    count = ordered_pair_contacts(shape_b, size_b, vertices_b, R_b, p_b, shape_a, size_a, vertices_a, R_a, p_a, margin,
                                  out, ws)
    for i in range(count):
        for k in range(3, 6):
            out[i, k] = -out[i, k]
    return count
