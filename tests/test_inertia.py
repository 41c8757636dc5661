"""Mass properties: primitives and meshes against closed forms, the parallel-axis sum, validity checks."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

import multibody as mb
from multibody.inertia import Inertia
from multibody.spatial import pose_from_xyz_rpy

trimesh = pytest.importorskip("trimesh")


# ----------------------------------------------------------------------------- primitives

def test_box_closed_form():
    m, (a, b, c) = 2.5, (0.3, 0.5, 0.7)
    I = mb.inertia.box(m, (a, b, c), center=(1.0, 2.0, 3.0))
    assert I.mass == m
    assert_allclose(I.com, [1, 2, 3])
    assert_allclose(I.rotational, np.diag([m * (b**2 + c**2) / 12, m * (a**2 + c**2) / 12, m * (a**2 + b**2) / 12]),
                    rtol=1e-15)


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_cylinder_closed_form(axis):
    m, r, L = 3.0, 0.2, 0.9
    I = mb.inertia.cylinder(m, r, L, axis=axis)
    k = "xyz".index(axis)
    expected = np.full(3, m * (3 * r**2 + L**2) / 12)
    expected[k] = m * r**2 / 2
    assert_allclose(I.rotational, np.diag(expected), rtol=1e-15)
    assert_allclose(I.com, np.zeros(3))


def test_cylinder_bad_axis():
    with pytest.raises(ValueError, match="axis"):
        mb.inertia.cylinder(1.0, 0.1, 1.0, axis="w")


def test_sphere_and_hollow_sphere_closed_forms():
    m, r = 4.0, 0.3
    assert_allclose(mb.inertia.sphere(m, r).rotational, 0.4 * m * r**2 * np.eye(3), rtol=1e-15)
    assert_allclose(mb.inertia.hollow_sphere(m, r).rotational, 2 / 3 * m * r**2 * np.eye(3), rtol=1e-15)


def test_point_mass():
    I = mb.inertia.point_mass(1.5, [0.1, -0.2, 0.3])
    assert I.mass == 1.5
    assert_allclose(I.com, [0.1, -0.2, 0.3])
    assert_allclose(I.rotational, np.zeros((3, 3)))
    # about the frame origin: m (|c|² 1 − c cᵀ)
    c = np.array([0.1, -0.2, 0.3])
    assert_allclose(I.spatial[3:, 3:], 1.5 * (c @ c * np.eye(3) - np.outer(c, c)), atol=1e-15)
    assert I.problems() == []


@pytest.mark.parametrize("make", [
    lambda: mb.inertia.box(1.0, (0.0, 1.0, 1.0)),
    lambda: mb.inertia.sphere(1.0, -0.1),
    lambda: mb.inertia.cylinder(1.0, 0.1, np.nan),
])
def test_primitives_refuse_non_positive_sizes(make):
    with pytest.raises(ValueError, match="positive"):
        make()


def test_inertia_shape_checks():
    with pytest.raises(ValueError, match=r"\(3,\)"):
        Inertia(1.0, [0.0, 0.0], np.eye(3))
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        Inertia(1.0, [0.0, 0.0, 0.0], np.eye(2))


def test_inertia_is_immutable():
    I = mb.inertia.box(1.0, (1, 2, 3))
    with pytest.raises(ValueError):
        I.rotational[0, 0] = 5.0
    with pytest.raises(ValueError):
        I.com[0] = 5.0
    with pytest.raises(AttributeError):
        I.mass = 2.0


# ----------------------------------------------------------------------------- transformed and sum

def test_transformed_rotates_tensor_and_moves_com():
    I = mb.inertia.box(2.0, (0.2, 0.4, 0.6), center=(0.1, 0.0, 0.0))
    X = pose_from_xyz_rpy([1.0, 2.0, 3.0], [0.0, 0.0, np.pi / 2])
    J = I.transformed(X)
    assert J.mass == 2.0
    assert_allclose(J.com, [1.0, 2.1, 3.0], atol=1e-15)
    # a quarter turn about z swaps the x and y moments
    assert_allclose(J.rotational, np.diag(np.diag(I.rotational)[[1, 0, 2]]), atol=1e-15)


def test_addition_of_point_masses_by_hand():
    # Two point masses: com = Σ mᵢ xᵢ / M and I_c = Σ mᵢ (|dᵢ|² 1 − dᵢ dᵢᵀ), dᵢ = xᵢ − com.
    m1, x1 = 1.0, np.array([1.0, 0.0, 0.0])
    m2, x2 = 3.0, np.array([0.0, 2.0, 1.0])
    total = mb.inertia.point_mass(m1, x1) + mb.inertia.point_mass(m2, x2)
    com = (m1 * x1 + m2 * x2) / 4.0
    expected = sum(m * ((x - com) @ (x - com) * np.eye(3) - np.outer(x - com, x - com)) for m, x in ((m1, x1), (m2, x2)))
    assert total.mass == 4.0
    assert_allclose(total.com, com, atol=1e-15)
    assert_allclose(total.rotational, expected, atol=1e-14)


def test_addition_parallel_axis_theorem_general():
    rng = np.random.default_rng(3)
    a = mb.inertia.box(1.3, (0.2, 0.3, 0.4)).transformed(pose_from_xyz_rpy(rng.standard_normal(3), [0.3, -0.2, 1.0]))
    b = mb.inertia.cylinder(0.7, 0.1, 0.5).transformed(pose_from_xyz_rpy(rng.standard_normal(3), [1.0, 0.5, 0.0]))
    s = a + b
    com = (a.mass * a.com + b.mass * b.com) / (a.mass + b.mass)
    expected = np.zeros((3, 3))
    for part in (a, b):
        d = part.com - com
        expected += part.rotational + part.mass * (d @ d * np.eye(3) - np.outer(d, d))
    assert_allclose(s.com, com, atol=1e-15)
    assert_allclose(s.rotational, expected, atol=1e-14)
    # spatial inertias about a common frame simply add
    assert_allclose(s.spatial, a.spatial + b.spatial, atol=1e-13)
    # and the sum commutes
    assert_allclose((b + a).rotational, s.rotational, atol=1e-15)


def test_two_half_boxes_make_a_box():
    m, (a, b, c) = 2.0, (0.4, 0.3, 0.2)
    left = mb.inertia.box(m / 2, (a / 2, b, c), center=(-a / 4, 0, 0))
    right = mb.inertia.box(m / 2, (a / 2, b, c), center=(a / 4, 0, 0))
    whole = mb.inertia.box(m, (a, b, c))
    s = left + right
    assert_allclose(s.com, np.zeros(3), atol=1e-16)
    assert_allclose(s.rotational, whole.rotational, rtol=1e-14)


def test_zero_plus_body_is_body():
    body = mb.inertia.box(1.0, (0.1, 0.2, 0.3), center=(0.5, 0.0, 0.0))
    s = Inertia.zero() + body
    assert s.mass == body.mass
    assert_allclose(s.com, body.com)
    assert_allclose(s.rotational, body.rotational)
    z = Inertia.zero() + Inertia.zero()
    assert z.mass == 0.0 and z.problems() == []


# ----------------------------------------------------------------------------- validity checks

def test_problems_valid_bodies():
    assert mb.inertia.box(1.0, (1, 2, 3)).problems() == []
    assert mb.inertia.cylinder(1.0, 0.1, 2.0).problems() == []
    assert Inertia.zero().problems() == []
    # a thin rod: I₁ + I₂ = I₃ holds with equality for a lamina; a rod has I_axial = 0
    assert Inertia(1.0, np.zeros(3), np.diag([1 / 12, 1 / 12, 0.0])).problems() == []


def test_problems_negative_mass():
    problems = Inertia(-1.0, np.zeros(3), np.eye(3)).problems()
    assert len(problems) == 1 and "negative mass" in problems[0]


def test_problems_not_positive_semidefinite():
    problems = Inertia(1.0, np.zeros(3), np.diag([-1.0, 1.0, 1.0])).problems()
    assert len(problems) == 1 and "positive semi-definite" in problems[0]


def test_problems_triangle_inequality():
    problems = Inertia(1.0, np.zeros(3), np.diag([1.0, 1.0, 5.0])).problems()
    assert len(problems) == 1 and "triangle" in problems[0]
    # the same tensor rotated is still caught (principal moments are used)
    R = pose_from_xyz_rpy(rpy=[0.3, 0.2, 0.1])
    rotated = Inertia(1.0, np.zeros(3), np.diag([1.0, 1.0, 5.0])).transformed(R)
    assert any("triangle" in p for p in rotated.problems())


def test_problems_non_symmetric_and_non_finite():
    assert any("symmetric" in p for p in Inertia(1.0, np.zeros(3), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]).problems())
    assert any("non-finite" in p for p in Inertia(np.nan, np.zeros(3), np.eye(3)).problems())


# ----------------------------------------------------------------------------- meshes

def test_from_mesh_box_exact():
    a, b, c, density = 0.3, 0.5, 0.7, 1200.0
    I = mb.inertia.from_mesh(trimesh.creation.box(extents=(a, b, c)), density)
    expected = mb.inertia.box(density * a * b * c, (a, b, c))
    assert I.mass == pytest.approx(expected.mass, rel=1e-12)
    assert_allclose(I.com, np.zeros(3), atol=1e-15)
    assert_allclose(I.rotational, expected.rotational, rtol=1e-12, atol=1e-12 * np.abs(expected.rotational).max())


def test_from_mesh_translated_box_reports_com_and_central_inertia():
    mesh = trimesh.creation.box(extents=(0.2, 0.4, 0.6))
    mesh.apply_translation([1.0, -2.0, 0.5])
    I = mb.inertia.from_mesh(mesh, 500.0)
    expected = mb.inertia.box(500.0 * 0.2 * 0.4 * 0.6, (0.2, 0.4, 0.6))
    assert_allclose(I.com, [1.0, -2.0, 0.5], atol=1e-12)
    # the tensor is about the centre of mass, not the mesh origin; shifting it there cancels a
    # term m |c|² ≈ 130 kg m² against the origin tensor, so rounding is ~1e-16 of that
    shift = I.mass * I.com @ I.com
    assert_allclose(I.rotational, expected.rotational, rtol=1e-12, atol=1e-14 * shift)


def test_from_mesh_icosphere_within_rigorous_bounds():
    """An icosphere is a polyhedron inscribed in the sphere of radius r (its vertices lie on it),
    and it contains the ball of radius r_in = the smallest distance from the centre to a face plane.
    The moment of inertia about any axis through the centre grows with the set (the integrand
    ρ d² is positive), so I_ball(r_in) ≤ I_mesh ≤ I_ball(r), and likewise for the mass. These are
    the honest bounds of the discretisation; the values are then also compared against the
    analytic sphere formula using the mesh's own mass, which differs only through the (tiny)
    difference of radial mass distribution.
    """
    r, density = 0.2, 1000.0
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=r)
    I = mb.inertia.from_mesh(mesh, density)
    normals = mesh.face_normals
    r_in = np.min(np.abs(np.einsum("ij,ij->i", normals, mesh.triangles[:, 0, :])))
    assert 0.99 * r < r_in < r

    def ball(radius):
        mass = density * 4 / 3 * np.pi * radius**3
        return mass, 0.4 * mass * radius**2

    (m_lo, i_lo), (m_hi, i_hi) = ball(r_in), ball(r)
    assert m_lo <= I.mass <= m_hi
    moments = np.linalg.eigvalsh(I.rotational)
    assert np.all(moments >= i_lo) and np.all(moments <= i_hi)
    assert_allclose(I.com, np.zeros(3), atol=1e-12)
    # icosahedral symmetry makes the tensor exactly isotropic (up to rounding)
    assert_allclose(I.rotational, moments.mean() * np.eye(3), atol=1e-12 * moments.mean())
    # mass ~ r³ and I ~ m r²: with the mesh mass the analytic value needs only r² from the shape;
    # the effective radius lies in [r_in, r], so the relative error is below 1 − (r_in / r)².
    analytic = mb.inertia.sphere(I.mass, r).rotational[0, 0]
    assert abs(moments.mean() - analytic) / analytic <= 1.0 - (r_in / r) ** 2


def _regular_prism(n, R, L, density):
    """Closed form of a prism over a regular n-gon of circumradius R, length L along z."""
    area = 0.5 * n * R**2 * np.sin(2 * np.pi / n)
    # polar second moment of area of a regular n-gon about its centre
    polar = n * R**4 / 12 * np.sin(2 * np.pi / n) * (2 + np.cos(2 * np.pi / n))
    mass = density * area * L
    izz = density * L * polar
    ixx = density * L * polar / 2 + mass * L**2 / 12
    return mass, np.diag([ixx, ixx, izz])


@pytest.mark.parametrize("sections", [4, 32, 256])
def test_from_mesh_cylinder_is_exact_regular_prism(sections):
    r, L, density = 0.1, 0.5, 1000.0
    mesh = trimesh.creation.cylinder(radius=r, height=L, sections=sections)
    I = mb.inertia.from_mesh(mesh, density)
    mass, tensor = _regular_prism(sections, r, L, density)
    assert I.mass == pytest.approx(mass, rel=1e-12)
    assert_allclose(I.rotational, tensor, rtol=1e-10, atol=1e-12 * tensor.max())
    if sections == 256:
        # Against the smooth cylinder of the same mass: per unit mass the n-gon's polar moment is
        # R² (2 + cos α) / 6 with α = 2π/n, the disc's R² / 2, so the axial moment is low by the
        # relative amount (1 − cos α) / 3 ≈ 1.0e-4 here, and the transverse ones by less.
        alpha = 2 * np.pi / sections
        bound = (1 - np.cos(alpha)) / 3
        smooth = mb.inertia.cylinder(I.mass, r, L).rotational
        assert_allclose(np.diag(I.rotational), np.diag(smooth), rtol=bound * (1 + 1e-6))
        assert abs(I.rotational[2, 2] / smooth[2, 2] - (1 - bound)) < 1e-10


def test_from_mesh_non_watertight_raises():
    mesh = trimesh.creation.box(extents=(1, 1, 1))
    open_mesh = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces[:-1], process=False)
    assert not open_mesh.is_watertight
    with pytest.raises(ValueError, match="watertight"):
        mb.inertia.from_mesh(open_mesh, 1000.0)


def test_from_mesh_refuses_non_positive_density():
    with pytest.raises(ValueError, match="density"):
        mb.inertia.from_mesh(trimesh.creation.box(extents=(1, 1, 1)), 0.0)
