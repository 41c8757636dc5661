"""Derivatives of constrained dynamics (``ConstrainedSystem.forward_dynamics_derivatives``): ``a`` and
``λ`` with respect to ``q`` (tangent space), ``v`` and ``τ``, against central differences of
``ConstrainedSystem.forward_dynamics`` for the rolling sphere, the rolling disc, the knife edge, the
four-bar, user ``Holonomic`` and ``Pfaffian`` rows and Baumgarte terms; against Pinocchio's
``computeConstraintDynamicsDerivatives`` for a Panda with its hand welded (6-D) and pinned (3-D).

The reference differences take steps of ``1e-6 · max(1, |x|)`` (error up to about ``1e-8`` of the
entries' scale, from rounding); ours differentiate only the constraint rows numerically, by five-point
differences (about ``1e-12``), and the rest analytically. ``1e-7`` relative leaves a margin of ten over
the reference's own error while any missing term fails by its own size.
"""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody.spatial import pose_from_xyz_rpy

from constraint_helpers import four_bar
from dyn_helpers import assert_rel, central_differences, central_differences_vector
from rolling_helpers import BALL_RADIUS, coin, free_ball, lean_rotation, quat, sleigh, tilted_normal

FD_TOL = 1e-7


def _ball():
    model = free_ball()
    system = mb.ConstrainedSystem(model, [mb.RollingSphere("ball", BALL_RADIUS, plane_normal=tilted_normal(0.4, 0.2))])
    rng = np.random.default_rng(1)
    q = np.concatenate([[0.2, -0.1, 0.3], quat(mb.spatial.rpy_to_rotation(rng.uniform(-1, 1, 3)))])
    return system, q, rng.standard_normal(model.nv)


def _coin():
    model = coin()
    system = mb.ConstrainedSystem(model, [mb.RollingDisc("coin", 0.5, axis=[0.0, 0.0, 1.0])])
    rng = np.random.default_rng(2)
    q = np.concatenate([[0.1, 0.2, 0.45], quat(lean_rotation(0.3, 0.4, 0.5))])
    return system, q, rng.standard_normal(model.nv)


def _sleigh():
    model, blade = sleigh()
    rng = np.random.default_rng(3)
    return mb.ConstrainedSystem(model, [blade]), model.random_configuration(rng), rng.standard_normal(model.nv)


def _four_bar(baumgarte=None):
    model, tip, pivot = four_bar()
    # frame A's x–y plane is the mechanism's x–z plane
    in_plane = pose_from_xyz_rpy(pivot, [np.pi / 2, 0.0, 0.0])
    system = mb.ConstrainedSystem(model, [mb.LoopClosure(None, "link3", frame_a=in_plane, frame_b=tip, kind="planar")],
                                  baumgarte=baumgarte)
    rng = np.random.default_rng(4)
    q, v = system.project(np.array([-1.2, 1.0, 1.5]) + 0.1 * rng.standard_normal(3), rng.standard_normal(3))
    return system, q, v


def _user_rows():
    """A particle pendulum held by a user ``Holonomic`` distance and a user ``Pfaffian`` row."""
    builder = mb.ModelBuilder("particle")
    builder.add_body("p", mb.joints.Translation(), inertia=mb.Inertia(1.5, [0, 0, 0], np.zeros((3, 3))))
    model = builder.build()
    held = mb.Holonomic(lambda q, t: np.array([q @ q - 1.0]), lambda q, t: 2.0 * q[None, :])
    sideways = mb.Pfaffian(lambda q, t: np.array([[q[1], -q[0], 0.3 * q[2]]]), lambda q, t: np.array([0.1 * q[0]]))
    system = mb.ConstrainedSystem(model, [held, sideways], baumgarte=(2.0, 3.0))
    return system, np.array([0.6, 0.0, -0.8]), np.array([0.1, 0.7, 0.2])


SYSTEMS = {"rolling_sphere": _ball, "rolling_disc": _coin, "knife_edge": _sleigh, "four_bar": _four_bar,
           "four_bar_baumgarte": lambda: _four_bar((5.0, 7.0)), "user_rows": _user_rows}


@pytest.mark.parametrize("name", list(SYSTEMS))
def test_constrained_derivatives_match_central_differences(name):
    system, q, v = SYSTEMS[name]()
    tau = np.random.default_rng(7).standard_normal(system.nv)
    derivatives = system.forward_dynamics_derivatives(q, v, tau)
    a, lam = system.forward_dynamics(q, v, tau)
    m = system.num_rows
    assert derivatives.da_dq.shape == derivatives.da_dv.shape == derivatives.da_dtau.shape == (system.nv, system.nv)
    assert derivatives.dlam_dq.shape == derivatives.dlam_dv.shape == derivatives.dlam_dtau.shape == (m, system.nv)

    def both(q_, v_, tau_):
        return np.concatenate(system.forward_dynamics(q_, v_, tau_))

    model = system.model
    references = {
        "q": central_differences(lambda x: both(x, v, tau), model, q),
        "v": central_differences_vector(lambda x: both(q, x, tau), v),
        "tau": central_differences_vector(lambda x: both(q, v, x), tau),
    }
    for x, reference in references.items():
        ours = np.concatenate([getattr(derivatives, f"da_d{x}"), getattr(derivatives, f"dlam_d{x}")])
        assert_rel(ours, reference, FD_TOL, f"d(a, λ)/d{x}", batch_ndim=0)


def test_without_constraints_equal_the_model_derivatives():
    model, _, _ = four_bar()
    system = mb.ConstrainedSystem(model, [])
    rng = np.random.default_rng(8)
    q, v, tau = model.random_configuration(rng), rng.standard_normal(3), rng.standard_normal(3)
    derivatives = system.forward_dynamics_derivatives(q, v, tau)
    for ours, reference in zip((derivatives.da_dq, derivatives.da_dv, derivatives.da_dtau),
                               mb.forward_dynamics_derivatives(model, q, v, tau)):
        np.testing.assert_allclose(ours, reference, rtol=1e-12, atol=1e-12)
    assert derivatives.dlam_dq.shape == (0, 3)


def test_batched_equal_single_calls():
    system, q, v = _ball()
    rng = np.random.default_rng(9)
    qs = np.stack([q, system.model.integrate(q, 0.1 * rng.standard_normal(system.nv))])
    vs, taus = np.stack([v, -v]), rng.standard_normal((2, system.nv))
    assert system.batched
    batched = system.forward_dynamics_derivatives(qs, vs, taus)
    for k in range(2):
        single = system.forward_dynamics_derivatives(qs[k], vs[k], taus[k])
        for name in ("da_dq", "da_dv", "da_dtau", "dlam_dq", "dlam_dv", "dlam_dtau"):
            np.testing.assert_allclose(getattr(batched, name)[k], getattr(single, name), rtol=1e-12, atol=1e-12,
                                       err_msg=name)


def test_a_symbolic_system_is_differentiated_too():
    """A ``LagrangianSystem`` (no ``Model``): a particle in polar coordinates ``(r, θ)`` in gravity, held on
    the spiral ``r = 1 + θ/10`` by a user ``Holonomic`` row; ``∂(M a + h)`` by central differences."""
    sympy = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    r, theta = dynamicsymbols("r theta")
    m, g = sympy.symbols("m g", positive=True)
    lagrangian = mb.LagrangianSystem([r, theta], m / 2 * (r.diff() ** 2 + r**2 * theta.diff() ** 2),
                                     m * g * r * sympy.sin(theta))
    spiral = mb.Holonomic(lambda q, t: np.array([q[0] - 1.0 - 0.1 * q[1]]), lambda q, t: np.array([[1.0, -0.1]]))
    system = mb.ConstrainedSystem(lagrangian.numeric(m=1.3, g=9.81), [spiral])
    q, v, tau = np.array([1.05, 0.5]), np.array([0.1, 1.0]), np.array([0.2, -0.3])
    derivatives = system.forward_dynamics_derivatives(q, v, tau)

    def both(q_, v_, tau_):
        return np.concatenate(system.forward_dynamics(q_, v_, tau_))

    for x, reference in {"q": central_differences_vector(lambda x: both(x, v, tau), q),
                         "v": central_differences_vector(lambda x: both(q, x, tau), v),
                         "tau": central_differences_vector(lambda x: both(q, v, x), tau)}.items():
        ours = np.concatenate([getattr(derivatives, f"da_d{x}"), getattr(derivatives, f"dlam_d{x}")])
        assert_rel(ours, reference, FD_TOL, f"d(a, λ)/d{x}", batch_ndim=0)


@pytest.mark.parametrize("kind", ["weld", "point"])
def test_panda_with_its_hand_held_matches_pinocchio(kind, pin):
    """Panda with the hand welded to the world (6 rows) or its origin pinned (3 rows), against
    ``computeConstraintDynamicsDerivatives`` with ``CONTACT_6D`` (``LOCAL``) and ``CONTACT_3D``
    (``LOCAL_WORLD_ALIGNED``), no Baumgarte terms, at consistent states.

    ``a(q, v, τ)`` is the same function in both libraries, also away from the constraint manifold: the
    weld holds the hand's spatial acceleration at zero in both; the pin holds the classical acceleration
    of the hand's origin at zero, in world axes here (``LoopClosure(None, "panda_hand", ...)``, frame A the
    world) and in Pinocchio. So are the pin's multipliers (the force on the hand, world axes), which are
    compared too; the weld's moment rows are defined differently (module :mod:`multibody.constraints`).
    Measured agreement: about ``1e-12`` relative.
    """
    from dyn_helpers import erd_urdf

    path = erd_urdf("panda_description/urdf/panda.urdf")
    model, pmodel = mb.load_urdf(path), pin.buildModelFromUrdf(path)
    data = pmodel.createData()
    rng = np.random.default_rng(10)
    q0 = model.random_configuration(rng)
    hand_pose = mb.frame_placement(model, q0, "panda_hand")
    if kind == "weld":
        constraint = mb.LoopClosure("panda_hand", None, frame_b=hand_pose, kind="weld")
        contact, reference = pin.ContactType.CONTACT_6D, pin.ReferenceFrame.LOCAL
    else:
        constraint = mb.LoopClosure(None, "panda_hand", frame_a=pose_from_xyz_rpy(hand_pose[:3, 3]), kind="point")
        contact, reference = pin.ContactType.CONTACT_3D, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    system = mb.ConstrainedSystem(model, [constraint])
    frame = pmodel.frames[pmodel.getFrameId("panda_hand")]
    for _ in range(3):
        q, v = system.project(model.integrate(q0, 0.05 * rng.standard_normal(model.nv)), rng.standard_normal(model.nv))
        tau = rng.standard_normal(model.nv)
        ours = system.forward_dynamics_derivatives(q, v, tau)
        constraint_model = pin.RigidConstraintModel(contact, pmodel, frame.parentJoint, frame.placement, 0,
                                                    pin.SE3(hand_pose[:3, :3], hand_pose[:3, 3]), reference)
        constraint_data = constraint_model.createData()
        pin.initConstraintDynamics(pmodel, data, [constraint_model], [constraint_data])
        settings = pin.ProximalSettings(1e-14, 0.0, 100)
        pin.constraintDynamics(pmodel, data, q, v, tau, [constraint_model], [constraint_data], settings)
        pin.computeConstraintDynamicsDerivatives(pmodel, data, [constraint_model], [constraint_data], settings)
        assert_rel(ours.da_dq, data.ddq_dq, 1e-10, "da_dq", batch_ndim=0)
        assert_rel(ours.da_dv, data.ddq_dv, 1e-10, "da_dv", batch_ndim=0)
        assert_rel(ours.da_dtau, data.ddq_dtau, 1e-10, "da_dtau", batch_ndim=0)
        if kind == "point":
            assert_rel(ours.dlam_dq, data.dlambda_dq, 1e-10, "dlam_dq", batch_ndim=0)
            assert_rel(ours.dlam_dv, data.dlambda_dv, 1e-10, "dlam_dv", batch_ndim=0)
            assert_rel(ours.dlam_dtau, data.dlambda_dtau, 1e-10, "dlam_dtau", batch_ndim=0)
