"""A parallelogram of unit bars at rest near its flat configuration, where the loop closure's Jacobian
loses rank: its smallest singular value is about the angle from flat. One rank decision on the
singular values of ``A L⁻ᵀ`` (not the eigenvalues of ``G``, which square them) keeps that direction,
so the multipliers stay finite and equal those of the same loop closed by more rows (a redundant
point closure), instead of a false "inconsistent constraints"."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import pose_from_xyz_rpy

from constraint_helpers import assert_close

Y = (0.0, 1.0, 0.0)


def parallelogram():
    """Bars of 1 m in the x–z plane: a left bar on the ground at the origin, a top bar on its tip, and a
    right bar on the ground at x = 1; the top bar's tip is to meet the right bar's tip."""
    bar = mb.inertia.box(1.0, [1.0, 0.05, 0.05], center=[0.5, 0.0, 0.0])
    b = mb.ModelBuilder("parallelogram")
    b.add_body("left", mb.joints.Revolute(Y), inertia=bar)
    b.add_body("top", mb.joints.Revolute(Y), parent="left", placement=pose_from_xyz_rpy([1.0, 0, 0]), inertia=bar)
    b.add_body("right", mb.joints.Revolute(Y), placement=pose_from_xyz_rpy([1.0, 0, 0]), inertia=bar)
    return b.build()


def closed(model, kind):
    tip = pose_from_xyz_rpy([1.0, 0, 0])
    # frame A at the top bar's tip, axes turned so that its x-y plane is the mechanism's x-z plane
    plane = pose_from_xyz_rpy([1.0, 0, 0], [np.pi / 2, 0, 0])
    return mb.ConstrainedSystem(model, [mb.LoopClosure("top", "right", frame_a=plane if kind == "planar" else tip,
                                                       frame_b=tip, kind=kind)])


@pytest.mark.parametrize("angle", [1e-3, 1e-6, 1e-9])
def test_multipliers_stay_finite_and_minimum_norm_near_flat(angle):
    model = parallelogram()
    # a parallelogram: the left and right bars at the same angle, the top bar parallel to the ground
    q = np.array([-angle, angle, -angle])
    planar, point = closed(model, "planar"), closed(model, "point")
    assert np.abs(planar.position_error(q)).max() < 1e-15
    assert planar.rank(q) == 2 and point.rank(q) == 2
    # joint torques that push along the direction the closure nearly loses: its force grows as 1/angle
    tau = np.array([1.0, -2.0, 0.5])
    a_planar, lam_planar = planar.forward_dynamics(q, np.zeros(3), tau)
    a_point, lam_point = point.forward_dynamics(q, np.zeros(3), tau)
    assert np.all(np.isfinite(lam_planar)) and np.all(np.isfinite(lam_point))
    # the equations hold: M a + h = τ + Aᵀ λ and A a = γ
    M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, np.zeros(3))
    A = planar.jacobian(q)
    force_scale = np.abs(A.T @ lam_planar).max() + np.abs(tau).max()
    assert np.abs(M @ a_planar + h - tau - A.T @ lam_planar).max() <= 1e-9 * force_scale
    assert np.abs(A @ a_planar - planar.acceleration_rhs(q, np.zeros(3))).max() <= 1e-9 * max(1.0, np.abs(a_planar).max())
    # the same forces: the point closure's redundant y row carries nothing
    scale = max(1.0, np.abs(lam_point).max())
    # (frame A of the planar closure has its x and y along the world's x and z, as the point closure's x and z)
    assert_close(lam_point[[0, 2]], lam_planar, 1e-8, scale=scale, what="multipliers")
    assert abs(lam_point[1]) <= 1e-8 * scale
    assert_close(a_point, a_planar, 1e-8, scale=max(1.0, np.abs(a_planar).max()), what="accelerations")
