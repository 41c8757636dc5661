"""Joint armature (``model.armature``, rotor inertia per velocity coordinate) in every algorithm.

Against Pinocchio with ``pin_model.armature`` set to the same random values (0.05 to 0.5 kg m² or kg) on
example-robot-data robots, fixed and floating, and on a random tree that uses every joint type: ``M``
(both methods), ``M⁻¹``, RNEA, ABA, the RNEA and ABA derivatives and the kinetic energy, to 1e-12
relative (``max|ours − pin| / max(1, max|pin|)``, per state; measured at most 4e-14). Our kinetic energy
is ``½ vᵀ M v`` with the armature in ``M``, as Pinocchio's ``computeKineticEnergy`` and MuJoCo's
``mj_energyVel`` have it; Pinocchio 4.1 leaves the armature of its unaligned revolute joints
(``JointModelRevoluteUnaligned``, the random tree's revolute joints) out of that energy though its ``crba``
holds it, so on the random tree the energy is checked against ``½ vᵀ M_pin v``.

Then what needs no Pinocchio: URDF models have zero armature; ``C`` and ``g`` do not see it and
``Ṁ = C + Cᵀ`` holds with it; a closed four-bar with armature solves ``M a + h = τ + Aᵀλ`` with the
armature in ``M`` (and matches Pinocchio's ``constraintDynamics``); the variational integrator converges
to the same motion as ABA; batches equal single calls; bad armature is refused with errors naming it.
"""

from __future__ import annotations

import functools
import zlib

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody.inertia import point_mass
from multibody.model import suspicious_inertias
from multibody.spatial import pose_from_xyz_rpy
from multibody.tree import ARMATURE

from conftest import pinocchio_twin
from constraint_helpers import four_bar
from dyn_helpers import (assert_rel, coordinate_tree_model, depth_first_model, dynamics_calls, erd_urdf,
                         q_to_pinocchio, random_tree_model)

TOL = 1e-12
N_STATES = 8

ROBOTS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "panda": ("panda_description/urdf/panda.urdf", False),
    "tiago": ("tiago_description/robots/tiago.urdf", False),  # continuous wheel joints
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos_reduced": ("talos_data/robots/talos_reduced.urdf", True),
    "random_tree_1": (None, None),  # every joint type: free flyer, planar, spherical, translation, ...
}


def random_armature(nv, seed):
    return np.random.default_rng(seed).uniform(0.05, 0.5, nv)


def _symmetrised(upper):
    upper = np.triu(np.asarray(upper))
    return upper + np.triu(upper, 1).T


class Case:
    """A robot with random armature, loaded by both libraries, and ``N_STATES`` random states."""

    def __init__(self, pin, name):
        path, floating = ROBOTS[name]
        seed = zlib.crc32(name.encode())
        if path is None:
            bare = depth_first_model(random_tree_model(1))[0]
            self.model = bare.with_armature(random_armature(bare.nv, seed))
            self.pmodel, _ = pinocchio_twin(pin, self.model)
        else:
            path = erd_urdf(path)
            bare = mb.load_urdf(path, floating_base=floating)
            self.model = bare.with_armature(random_armature(bare.nv, seed))
            self.pmodel = (pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating
                           else pin.buildModelFromUrdf(path))
            self.pmodel.armature = self.model.armature.copy()
        self.bare, self.twin = bare, path is None
        assert list(self.pmodel.names)[1:] == list(self.model.joint_names)
        rng = np.random.default_rng([seed, 1])
        self.q = self.model.random_configuration(rng, shape=(N_STATES,))
        self.v, self.a, self.tau = rng.standard_normal((3, N_STATES, self.model.nv))
        self.q_pin = q_to_pinocchio(self.model, self.q)

    @functools.cached_property
    def ref(self):
        """Pinocchio's results, stacked over the states."""
        pin = pytest.importorskip("pinocchio")
        pm, data = self.pmodel, self.pmodel.createData()
        out = {}
        for k in range(N_STATES):
            q, v, a, tau = self.q_pin[k], self.v[k], self.a[k], self.tau[k]
            M = _symmetrised(pin.crba(pm, data, q))
            # (copies: Pinocchio returns its data's arrays, which the next call overwrites)
            rnea_dq, rnea_dv, rnea_da = (np.array(x) for x in pin.computeRNEADerivatives(pm, data, q, v, a))
            aba_dq, aba_dv, aba_dtau = (np.array(x) for x in pin.computeABADerivatives(pm, data, q, v, tau))
            T = 0.5 * v @ M @ v if self.twin else pin.computeKineticEnergy(pm, data, q, v)
            values = {"M": M, "Minv": _symmetrised(pin.computeMinverse(pm, data, q)), "rnea": pin.rnea(pm, data, q, v, a),
                      "aba": pin.aba(pm, data, q, v, tau), "dtau_dq": rnea_dq, "dtau_dv": rnea_dv,
                      "dtau_da": _symmetrised(rnea_da), "da_dq": aba_dq, "da_dv": aba_dv, "da_dtau": _symmetrised(aba_dtau),
                      "T": T}
            for key, value in values.items():
                out.setdefault(key, []).append(np.array(value, dtype=float, copy=True))
        return {key: np.stack(value) for key, value in out.items()}


@functools.lru_cache(maxsize=None)
def get_case(name):
    return Case(pytest.importorskip("pinocchio"), name)


# ============================================================================= against Pinocchio

@pytest.mark.parametrize("name", list(ROBOTS))
def test_dynamics_with_armature_match_pinocchio(pin, name):
    """M (CRBA and Σ Jᵀ I J), M⁻¹, RNEA, ABA and the kinetic energy with the armature, to 1e-12."""
    case = get_case(name)
    model, ref = case.model, case.ref
    q, v, a, tau = case.q, case.v, case.a, case.tau
    assert_rel(mb.mass_matrix(model, q), ref["M"], TOL, "mass_matrix[crba]")
    assert_rel(mb.mass_matrix(model, q, method="lagrangian"), ref["M"], TOL, "mass_matrix[lagrangian]")
    assert_rel(mb.inverse_mass_matrix(model, q), ref["Minv"], TOL, "inverse_mass_matrix")
    assert_rel(mb.inverse_dynamics(model, q, v, a), ref["rnea"], TOL, "inverse_dynamics")
    assert_rel(mb.forward_dynamics(model, q, v, tau), ref["aba"], TOL, "forward_dynamics")
    assert_rel(mb.kinetic_energy(model, q, v), ref["T"], TOL, "kinetic_energy")
    # the armature matters: it moves M's diagonal by itself, and the accelerations by far more than 1e-12
    np.testing.assert_allclose(np.diagonal(ref["M"] - mb.mass_matrix(case.bare, q), axis1=-2, axis2=-1),
                               np.broadcast_to(model.armature, (N_STATES, model.nv)), rtol=1e-12, atol=1e-12)
    assert np.abs(mb.forward_dynamics(case.bare, q, v, tau) - ref["aba"]).max() > 1e-2


@pytest.mark.parametrize("name", list(ROBOTS))
def test_derivatives_with_armature_match_pinocchio(pin, name):
    """``∂τ/∂(q, v)`` (unchanged by the armature), ``∂τ/∂a = M`` and ``∂a/∂(q, v, τ)`` with the armature, to 1e-12."""
    case = get_case(name)
    model, ref = case.model, case.ref
    q, v, a, tau = case.q, case.v, case.a, case.tau
    dtau_dq, dtau_dv = mb.inverse_dynamics_derivatives(model, q, v, a)
    assert_rel(dtau_dq, ref["dtau_dq"], TOL, "dtau_dq")
    assert_rel(dtau_dv, ref["dtau_dv"], TOL, "dtau_dv")
    assert_rel(mb.mass_matrix(model, q), ref["dtau_da"], TOL, "dtau_da = M")
    for what, ours in zip(("da_dq", "da_dv", "da_dtau"), mb.forward_dynamics_derivatives(model, q, v, tau)):
        assert_rel(ours, ref[what], TOL, what)


# ============================================================================= the model field

def test_urdf_models_have_zero_armature(erd_dir):
    """A URDF has no armature: zeros, read-only, and zero in the compiled tree; ``with_armature`` gives a
    new model and leaves this one unchanged."""
    for floating in (False, True):
        model = mb.load_urdf(erd_urdf("panda_description/urdf/panda.urdf"), floating_base=floating)
        assert model.armature.shape == (model.nv,) and not model.armature.flags.writeable
        np.testing.assert_array_equal(model.armature, np.zeros(model.nv))
        np.testing.assert_array_equal(model.tree.reals[:, ARMATURE:], 0.0)
        heavier = model.with_armature(np.arange(model.nv) + 1.0)
        np.testing.assert_array_equal(model.armature, np.zeros(model.nv))
        np.testing.assert_array_equal(heavier.armature, np.arange(model.nv) + 1.0)
        assert not heavier.armature.flags.writeable and heavier.joint_names == model.joint_names
    assert mb.ModelBuilder("empty").build().armature.shape == (0,)


def test_builder_places_armature_per_coordinate_in_model_and_tree():
    """``add_body(armature=)`` takes a number for every coordinate of the joint or one per coordinate; the
    model holds them in ``v`` order and the compiled tree at ``ARMATURE + k`` of each joint's row."""
    b = mb.ModelBuilder("arm")
    b.add_body("base", jt.FreeFlyer(), inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1]), armature=0.0)
    b.add_body("ball", jt.Spherical(), parent="base", placement=pose_from_xyz_rpy([0.2, 0, 0]),
               inertia=mb.inertia.box(1.0, [0.1, 0.1, 0.4]), armature=[0.1, 0.2, 0.3])
    b.add_body("fixed", jt.Fixed(), parent="ball", placement=pose_from_xyz_rpy([0, 0, 0.2]))
    b.add_body("hinge", jt.Revolute([0, 1, 0]), parent="fixed", inertia=point_mass(0.5, [0.3, 0, 0]), armature=0.7)
    model = b.build()
    np.testing.assert_array_equal(model.armature, [0, 0, 0, 0, 0, 0, 0.1, 0.2, 0.3, 0.7])
    reals = model.tree.reals
    np.testing.assert_array_equal(reals[0, ARMATURE:], np.zeros(6))
    np.testing.assert_array_equal(reals[1, ARMATURE:], [0.1, 0.2, 0.3, 0, 0, 0])
    np.testing.assert_array_equal(reals[2, ARMATURE:], [0.7, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(reals[3, ARMATURE:], np.zeros(6))  # the world's row
    np.testing.assert_array_equal(model.with_armature(0.25).armature, np.full(model.nv, 0.25))


@pytest.mark.parametrize("bad, message", [
    (-0.1, r"must not be negative, got \[-0.1\]"),
    (np.nan, "must be finite"),
    (np.inf, "must be finite"),
    ([0.1, 0.2], r"must have shape \(1,\), got \(2,\)"),
    ("heavy", "must be numbers"),
])
def test_bad_armature_is_refused_naming_it(bad, message):
    b = mb.ModelBuilder("pendulum")
    with pytest.raises(ValueError, match=f"armature of joint 'rod_joint' {message}"):
        b.add_body("rod", jt.Revolute([0, 1, 0]), inertia=point_mass(1.0, [0, 0, -1]), armature=bad)
    model = mb.robots.load("pendulum")
    with pytest.raises(ValueError, match=f"^armature {message}"):
        model.with_armature(bad)
    with pytest.raises(ValueError, match="armature must be numbers, one per velocity coordinate"):
        model.with_armature([[0.1], [0.2, 0.3]])
    fields = {f: getattr(model, f) for f in ("name", "joints", "joint_names", "parents", "joint_placements",
                                              "body_names", "body_joints", "body_placements", "body_inertias",
                                              "lower", "upper")}
    if not isinstance(bad, str):
        with pytest.raises(ValueError, match=f"^Model: armature {message}"):
            mb.Model(**fields, armature=np.atleast_1d(np.asarray(bad, dtype=float)))


# ============================================================================= identities without Pinocchio

def test_pendulum_accelerates_as_its_inertia_plus_armature_say():
    """One revolute joint: ``(m l² + I + J) θ̈ = τ − g(θ)`` with ``J`` the armature; RNEA adds ``J θ̈``, the
    kinetic energy ``½ J θ̇²``, and ``C``, ``g`` and ``h`` do not change."""
    bare = mb.robots.load("pendulum")
    J = 0.3
    model = bare.with_armature([J])
    q, v, tau = np.array([0.7]), np.array([1.3]), np.array([0.4])
    inertia = mb.mass_matrix(bare, q)[0, 0]
    g = mb.generalized_gravity(bare, q)
    a = mb.forward_dynamics(model, q, v, tau)
    np.testing.assert_allclose(a, (tau - g) / (inertia + J), rtol=1e-14)
    np.testing.assert_allclose(mb.inverse_dynamics(model, q, v, a), tau, rtol=1e-14)
    np.testing.assert_allclose(mb.kinetic_energy(model, q, v), 0.5 * (inertia + J) * v[0] ** 2, rtol=1e-14)
    np.testing.assert_array_equal(mb.generalized_gravity(model, q), mb.generalized_gravity(bare, q))
    np.testing.assert_array_equal(mb.bias_forces(model, q, v), mb.bias_forces(bare, q, v))
    np.testing.assert_array_equal(mb.coriolis_matrix(model, q, v), mb.coriolis_matrix(bare, q, v))


@pytest.mark.parametrize("maker", [lambda: random_tree_model(0), lambda: coordinate_tree_model(0)],
                         ids=["random_tree_0", "coordinate_tree_0"])
def test_coriolis_identities_hold_with_armature(maker):
    """``C`` is that of the bare bodies (the armature is constant), ``Ṁ = C + Cᵀ`` along the motion with the
    armature in ``M`` (central differences with step 1e-5: truncation and rounding about 1e-10, against a
    tolerance of 1e-6 relative, as ``tests/test_dynamics_identities.py`` argues), ``C v + g = h``, and
    ``T = ½ vᵀ M v``; the Christoffel ``C`` of the Σ Jᵀ I J matrix agrees where it applies."""
    bare = maker()
    model = bare.with_armature(random_armature(bare.nv, 5))
    rng = np.random.default_rng(6)
    q = model.random_configuration(rng, shape=(3,))
    v = rng.standard_normal((3, model.nv))
    C = mb.coriolis_matrix(model, q, v)
    np.testing.assert_array_equal(C, mb.coriolis_matrix(bare, q, v))
    step = 1e-5
    M_dot = (mb.mass_matrix(model, model.integrate(q, v, step)) - mb.mass_matrix(model, model.integrate(q, v, -step))) / (
        2 * step)
    assert_rel(C + np.swapaxes(C, -1, -2), M_dot, 1e-6, "C + Cᵀ vs finite-difference Ṁ")
    assert_rel(np.einsum("...ij,...j->...i", C, v) + mb.generalized_gravity(model, q), mb.bias_forces(model, q, v),
               1e-12, "C v + g = h")
    M = mb.mass_matrix(model, q)
    assert_rel(mb.kinetic_energy(model, q, v), 0.5 * np.einsum("...i,...ij,...j->...", v, M, v), 1e-12, "T = ½ vᵀ M v")
    if model.is_vector_space:
        assert_rel(mb.coriolis_matrix(model, q, v, method="lagrangian"), C, 1e-12, "Christoffel C")


def test_rotor_is_no_body():
    """The joint reaction forces are the bodies' share: ``Sᵀ f = τ − armature ⊙ a``; the centroidal momentum
    and the centre of mass are those of the bodies."""
    bare = random_tree_model(2)
    model = bare.with_armature(random_armature(bare.nv, 9))
    rng = np.random.default_rng(10)
    q = model.random_configuration(rng)
    v, a = rng.standard_normal((2, model.nv))
    forces = mb.joint_reaction_forces(model, q, v, a)
    np.testing.assert_array_equal(forces, mb.joint_reaction_forces(bare, q, v, a))
    projected = np.concatenate([joint.motion_subspace.T @ f for joint, f in zip(model.joints, forces)])
    tau = mb.inverse_dynamics(model, q, v, a)
    assert_rel(projected[None], (tau - model.armature * a)[None], 1e-12, "Sᵀ f = τ − armature ⊙ a")
    np.testing.assert_array_equal(mb.centroidal_momentum(model, q, v), mb.centroidal_momentum(bare, q, v))


def test_armature_alone_keeps_a_massless_joint_regular():
    """A joint that moves no mass makes ``M`` singular; armature on it makes ``M`` regular, and forward
    dynamics, ``M⁻¹`` and ``suspicious_inertias`` follow."""
    b = mb.ModelBuilder("massless_tip")
    b.add_body("arm", jt.Revolute([0, 1, 0]), inertia=point_mass(1.0, [0.5, 0, 0]))
    b.add_body("tip", jt.Revolute([0, 0, 1]), parent="arm", placement=pose_from_xyz_rpy([1.0, 0, 0]))
    bare = b.build()
    model = bare.with_armature([0.0, 0.2])
    q, v, tau = np.array([0.3, -0.4]), np.array([0.5, 1.0]), np.array([0.1, 0.2])
    assert any("moves no mass" in text for text in suspicious_inertias(bare))
    assert not any("moves no mass" in text for text in suspicious_inertias(model))
    with pytest.raises(np.linalg.LinAlgError, match="joint 'tip_joint' moves no inertia"):
        mb.forward_dynamics(bare, q, v, tau)
    M = mb.mass_matrix(model, q)
    a = mb.forward_dynamics(model, q, v, tau)
    assert_rel(a[None], np.linalg.solve(M, tau - mb.bias_forces(model, q, v))[None], 1e-12, "a = M⁻¹ (τ − h)")
    assert_rel(mb.inverse_mass_matrix(model, q)[None], np.linalg.inv(M)[None], 1e-12, "M⁻¹")


def test_batches_equal_single_calls():
    """Every batched dynamics function (and the derivatives) with armature equals its single calls."""
    bare = random_tree_model(1)
    model = bare.with_armature(random_armature(bare.nv, 11))
    rng = np.random.default_rng(12)
    n = 3
    q = model.random_configuration(rng, shape=(n,))
    v, a = rng.standard_normal((2, n, model.nv))
    f = rng.standard_normal((n, model.njoints, 6))
    calls = dict(dynamics_calls(model))
    calls["inverse_dynamics_derivatives"] = lambda q, v, a, f: np.stack(mb.inverse_dynamics_derivatives(model, q, v, a))
    calls["forward_dynamics_derivatives"] = lambda q, v, a, f: np.stack(mb.forward_dynamics_derivatives(model, q, v, a))
    for name, call in calls.items():
        batch = np.asarray(call(q, v, a, f))
        single = [np.asarray(call(q[k], v[k], a[k], f[k])) for k in range(n)]
        axis = 1 if name.endswith("derivatives") else 0
        np.testing.assert_array_equal(batch, np.stack(single, axis=axis), err_msg=name)


# ============================================================================= constrained dynamics

@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")  # (the point closure's redundant y row)
def test_closed_four_bar_with_armature(pin):
    """The four-bar of ``constraint_helpers.four_bar`` pinned at its tip, with armature on its joints:
    ``M a + h = τ + Aᵀλ`` and ``A a = γ`` with the armature in ``M``, to 1e-12 of the terms; ``a`` and ``λ``
    equal Pinocchio's ``constraintDynamics`` (whose ``M`` holds the armature too) to 1e-9, the tolerance of
    ``tests/test_constraints.py``'s comparison (Pinocchio's proximal iterations); a batch equals its states.
    """
    bare, tip, pivot = four_bar()
    model = bare.with_armature([0.4, 0.25, 0.1])
    closure = mb.LoopClosure(None, "link3", frame_a=pose_from_xyz_rpy(pivot), frame_b=tip)
    system, plain = mb.ConstrainedSystem(model, [closure]), mb.ConstrainedSystem(bare, [closure])
    pmodel, _ = pinocchio_twin(pin, model)
    np.testing.assert_array_equal(pmodel.armature, model.armature)
    constraint = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, pmodel, 3, pin.SE3(tip[:3, :3], tip[:3, 3]), 0,
                                          pin.SE3(np.eye(3), pivot), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    rng = np.random.default_rng(13)
    states = []
    for _ in range(3):
        q, v = system.project(np.array([-1.2, 1.0, 1.5]) + 0.2 * rng.standard_normal(3), 2.0 * rng.standard_normal(3))
        states.append((q, v, rng.standard_normal(3)))
    for q, v, tau in states:
        a, lam = system.forward_dynamics(q, v, tau)
        A, gamma = system.acceleration_level(q, v)
        M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
        np.testing.assert_array_equal(np.diag(M - mb.mass_matrix(bare, q)) > 0.0, True)
        scale = max(np.abs(M @ a).max(), np.abs(h).max(), np.abs(tau).max(), np.abs(A.T @ lam).max())
        assert np.abs(M @ a + h - tau - A.T @ lam).max() <= 1e-12 * scale
        assert np.abs(A @ a - gamma).max() <= 1e-12 * max(np.abs(gamma).max(), np.abs(A).max() * np.abs(a).max())
        assert np.abs(a - plain.forward_dynamics(q, v, tau)[0]).max() > 1e-2  # the armature matters
        pdata, cdata = pmodel.createData(), constraint.createData()
        pin.initConstraintDynamics(pmodel, pdata, [constraint], [cdata])
        settings = pin.ProximalSettings(1e-14, 1e-8, 100)
        a_pin = pin.constraintDynamics(pmodel, pdata, q, v, tau, [constraint], [cdata], settings).copy()
        assert settings.iter < 100
        assert np.abs(a - a_pin).max() <= 1e-9 * max(1.0, np.abs(a_pin).max())
        assert np.abs(lam - pdata.lambda_c).max() <= 1e-9 * max(1.0, np.abs(pdata.lambda_c).max())
    q, v, tau = (np.stack(x) for x in zip(*states))
    a, lam = system.forward_dynamics(q, v, tau)
    for k, (q_k, v_k, tau_k) in enumerate(states):
        a_k, lam_k = system.forward_dynamics(q_k, v_k, tau_k)
        np.testing.assert_allclose(a[k], a_k, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(lam[k], lam_k, rtol=1e-13, atol=1e-13)


# ============================================================================= integrators

def spherical_pendulum():
    """A box hanging 0.4 m below a spherical joint, with anisotropic armature on the joint's three axes."""
    b = mb.ModelBuilder("spherical_pendulum")
    b.add_body("bob", jt.Spherical(), inertia=mb.inertia.box(1.5, [0.1, 0.2, 0.3], center=[0, 0, -0.4]),
               armature=[0.05, 0.2, 0.1])
    q0 = mb.spatial.rotation_to_quat(mb.spatial.rpy_to_rotation([0.8, 0.3, 0.0]))
    return b.build(), q0, np.array([0.5, -1.0, 2.0])


def armature_pendulum():
    return mb.robots.load("pendulum").with_armature([0.3]), np.array([1.0]), np.array([0.0])


@pytest.mark.parametrize("maker", [armature_pendulum, spherical_pendulum], ids=["pendulum", "spherical"])
def test_variational_integrator_converges_to_the_aba_motion(maker):
    """The variational integrator (midpoint rule) reads ``M`` with the armature from its Lagrangian terms: its
    final state after 1 s converges at second order to DOP853's (rtol 1e-13) on ABA's accelerations,
    observed order within 0.2 of 2, as ``tests/test_variational.py`` requires without armature. Had it left
    the armature out, its error would stop falling at the armature's effect (above 1e-2 here)."""
    model, q0, v0 = maker()
    t_final = 1.0
    reference = mb.simulate(model, q0, v0, t_final, dt=t_final, method="DOP853", rtol=1e-13, atol=1e-14)
    bare = mb.simulate(model.with_armature(np.zeros(model.nv)), q0, v0, t_final, dt=t_final, method="DOP853",
                       rtol=1e-13, atol=1e-14)
    assert np.abs(bare.v[-1] - reference.v[-1]).max() > 1e-2
    errors = []
    for n in (40, 80, 160):
        run = mb.simulate(model, q0, v0, t_final, method="variational", dt=t_final / n)
        errors.append(max(np.abs(run.q[-1] - reference.q[-1]).max(), np.abs(run.v[-1] - reference.v[-1]).max()))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.2), f"errors {errors}, observed orders {orders}"
