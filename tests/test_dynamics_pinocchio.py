"""Dynamics cross-checked against Pinocchio on example-robot-data robots, fixed and floating base.

For every robot and base type, 20 random states (``q`` from ``model.random_configuration``;
``v``, ``a``, ``tau`` and external forces standard normal). Our side is evaluated batched
(``q`` of shape ``(20, nq)``), Pinocchio one state at a time. Error measure, per state:
``max|ours − pin| / max(1, max|pin|)``, required ≤ 1e-10 everywhere.

Pinocchio's ``crba`` and ``computeMinverse`` fill only the upper triangle: both are symmetrised.
Pinocchio's external forces are a list of ``pin.Force`` with one entry for the universe (index 0);
ours are ``(..., njoints, 6)`` over the moving joints, ``[linear; angular]`` in the same local frames.
"""

from __future__ import annotations

import functools
import zlib

import numpy as np
import pytest

import multibody as mb
from multibody.kinematics import joint_world_poses
from multibody.model import suspicious_inertias

from conftest import pinocchio_twin
from dyn_helpers import (assert_rel, coordinate_tree_model, depth_first_model, erd_urdf, q_to_pinocchio,
                         random_tree_model)

pin = pytest.importorskip("pinocchio")

N_STATES = 20
TOL = 1e-10

ROBOTS = {
    "double_pendulum": "double_pendulum_description/urdf/double_pendulum.urdf",
    "double_pendulum_continuous": "double_pendulum_description/urdf/double_pendulum_continuous.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "panda": "panda_description/urdf/panda.urdf",
    "solo12": "solo_description/robots/solo12.urdf",
    "anymal_b": "anymal_b_simple_description/robots/anymal.urdf",
    "talos_reduced": "talos_data/robots/talos_reduced.urdf",
    "simple_humanoid": "simple_humanoid_description/urdf/simple_humanoid.urdf",
    "tiago": "tiago_description/robots/tiago.urdf",  # continuous wheel joints
    # Romeo's finger and hand joints move no mass (placeholder links), so its M(q) is singular
    # (rank 31 of 55 with a fixed base): checked for everything except ABA and M⁻¹.
    "romeo": "romeo_description/urdf/romeo.urdf",
}
SINGULAR_MASS_MATRIX = {"romeo"}

# Random trees built with mb.ModelBuilder and rebuilt joint by joint in Pinocchio by conftest's
# pinocchio_twin: every joint type (planar, spherical, translation, revolute/prismatic about random
# axes, continuous) and branches, which the URDF robots do not cover. Pinocchio needs them in
# depth-first joint order (see dyn_helpers.depth_first_model). ``floating`` is None for them.
TWINS = {
    "random_tree_0": lambda: depth_first_model(random_tree_model(0))[0],
    "random_tree_1": lambda: depth_first_model(random_tree_model(1))[0],
    "coordinate_tree_0": lambda: depth_first_model(coordinate_tree_model(0))[0],
}


def _params(names, bases=(False, True)):
    return [pytest.param(name, floating, id=f"{name}-{'floating' if floating else 'fixed'}")
            for name in names for floating in bases]


_TWIN_PARAMS = [pytest.param(name, None, id=f"twin-{name}") for name in TWINS]
ALL = _params(ROBOTS) + _TWIN_PARAMS
INVERTIBLE = _params([name for name in ROBOTS if name not in SINGULAR_MASS_MATRIX]) + _TWIN_PARAMS
# The Christoffel Coriolis matrix needs v = q̇ for every joint: fixed base only (the free-flyer's
# quaternion breaks it). It forms ∂M/∂q, O(nv⁵) per state with NumPy's unoptimised einsum, so the
# 55-DoF Romeo is left out and large models use only the first few states.
CHRISTOFFEL = _params([name for name in ROBOTS if name != "romeo"], bases=(False,)) + [
    pytest.param("coordinate_tree_0", None, id="twin-coordinate_tree_0")]
CHRISTOFFEL_STATES_LARGE = 3  # for nv > 12


class Case:
    """A robot loaded by both libraries, 20 random states and Pinocchio's results for them."""

    def __init__(self, name, floating):
        self.name = name
        if name in TWINS:
            self.model = TWINS[name]()
            self.pmodel, _ = pinocchio_twin(pin, self.model)
        else:
            path = erd_urdf(ROBOTS[name])
            self.model = mb.load_urdf(path, floating_base=floating)
            self.pmodel = (pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating
                           else pin.buildModelFromUrdf(path))
        model, pmodel = self.model, self.pmodel
        assert list(pmodel.names)[1:] == list(model.joint_names)
        assert pmodel.nv == model.nv

        rng = np.random.default_rng([zlib.crc32(name.encode()), int(bool(floating))])
        self.q = model.random_configuration(rng, shape=(N_STATES,))
        self.v = rng.standard_normal((N_STATES, model.nv))
        self.a = rng.standard_normal((N_STATES, model.nv))
        self.tau = rng.standard_normal((N_STATES, model.nv))
        self.f_ext = rng.standard_normal((N_STATES, model.njoints, 6))
        self.q_pin = q_to_pinocchio(model, self.q)
        assert self.q_pin.shape == (N_STATES, pmodel.nq)
        self.frame_rotations = self._joint_frame_rotations()
        self._ref = {}

    def _joint_frame_rotations(self):
        """``R_JJ'``: Pinocchio's joint frame J' in ours J, from the world poses at the first state.

        The identity for URDF models; a twin's continuous joint (Pinocchio's RUBZ) has a rotated frame
        J' with the same origin. Pinocchio takes f_ext in J', so our forces are rotated into it.
        """
        data = self.pmodel.createData()
        pin.forwardKinematics(self.pmodel, data, self.q_pin[0])
        R_WJ, p_WJ = joint_world_poses(self.model, self.q[0])
        rotations = []
        for i in range(self.model.njoints):
            oMi = data.oMi[i + 1]
            np.testing.assert_allclose(oMi.translation, p_WJ[i], atol=1e-12)  # same origins
            rotations.append(R_WJ[i].T @ oMi.rotation)
        if self.name not in TWINS:
            np.testing.assert_allclose(rotations, np.broadcast_to(np.eye(3), (self.model.njoints, 3, 3)), atol=1e-12)
        return np.array(rotations)

    def pin_forces(self, k):
        """Our f_ext of state k as Pinocchio's list (universe first, zero), each in Pinocchio's joint frame."""
        forces = [pin.Force.Zero()]
        for f, R in zip(self.f_ext[k], self.frame_rotations):
            forces.append(pin.Force(R.T @ f[:3], R.T @ f[3:]))
        return forces

    def ref(self, what):
        """Pinocchio's ``what`` for all states, stacked (computed once)."""
        if what not in self._ref:
            pm, data = self.pmodel, self.pmodel.createData()
            out = []
            for k in range(N_STATES):
                q, v, a, tau = self.q_pin[k], self.v[k], self.a[k], self.tau[k]
                if what == "M":
                    r = _symmetrised(pin.crba(pm, data, q))
                elif what == "Minv":
                    r = _symmetrised(pin.computeMinverse(pm, data, q))
                elif what == "C":
                    r = pin.computeCoriolisMatrix(pm, data, q, v)
                elif what == "g":
                    r = pin.computeGeneralizedGravity(pm, data, q)
                elif what == "h":
                    r = pin.nonLinearEffects(pm, data, q, v)
                elif what == "rnea":
                    r = pin.rnea(pm, data, q, v, a)
                elif what == "rnea_fext":
                    r = pin.rnea(pm, data, q, v, a, self.pin_forces(k))
                elif what == "aba":
                    r = pin.aba(pm, data, q, v, tau)
                elif what == "aba_fext":
                    r = pin.aba(pm, data, q, v, tau, self.pin_forces(k))
                elif what in ("rnea_derivatives", "rnea_derivatives_fext"):
                    forces = (self.pin_forces(k),) if what.endswith("fext") else ()
                    r = np.stack(pin.computeRNEADerivatives(pm, data, q, v, a, *forces)[:2])
                elif what in ("aba_derivatives", "aba_derivatives_fext"):
                    forces = (self.pin_forces(k),) if what.endswith("fext") else ()
                    dq, dv, dtau = pin.computeABADerivatives(pm, data, q, v, tau, *forces)
                    r = np.stack([dq, dv, _symmetrised(dtau)])
                elif what == "gravity_derivatives":
                    r = pin.computeGeneralizedGravityDerivatives(pm, data, q)
                elif what == "T":
                    r = pin.computeKineticEnergy(pm, data, q, v)
                elif what == "U":
                    r = pin.computePotentialEnergy(pm, data, q)
                else:
                    raise KeyError(what)
                out.append(np.array(r, dtype=float, copy=True))
            self._ref[what] = np.stack(out)
        return self._ref[what]


def _symmetrised(upper):
    upper = np.triu(np.asarray(upper))
    return upper + np.triu(upper, 1).T


@functools.lru_cache(maxsize=None)
def get_case(name, floating):
    return Case(name, floating)


# ----------------------------------------------------------------------------- setup sanity

@pytest.mark.parametrize("name, floating", ALL)
def test_models_line_up(name, floating):
    """Same sizes and joint order as Pinocchio; the singular-M exclusion is a property of the file."""
    case = get_case(name, floating)
    model, pmodel = case.model, case.pmodel
    assert model.nv == pmodel.nv
    assert model.njoints == pmodel.njoints - 1
    n_continuous = sum(isinstance(j, mb.joints.Continuous) for j in model.joints)
    assert model.nq + n_continuous == pmodel.nq
    if floating:
        assert model.joint_names[0] == "root_joint"
    singular = any("moves no mass" in text for text in suspicious_inertias(model))
    assert singular == (name in SINGULAR_MASS_MATRIX)
    if name in TWINS:  # a twin's continuous joints sit in rotated Pinocchio frames
        n_rotated = sum(not np.allclose(R, np.eye(3)) for R in case.frame_rotations)
        assert 0 < n_rotated <= n_continuous


# ----------------------------------------------------------------------------- mass matrix

@pytest.mark.parametrize("method", ["crba", "lagrangian"])
@pytest.mark.parametrize("name, floating", ALL)
def test_mass_matrix(name, floating, method):
    case = get_case(name, floating)
    M = mb.mass_matrix(case.model, case.q, method=method)
    assert M.shape == (N_STATES, case.model.nv, case.model.nv)
    assert_rel(M, case.ref("M"), TOL, f"mass_matrix[{method}]")


@pytest.mark.parametrize("name, floating", INVERTIBLE)
def test_inverse_mass_matrix(name, floating):
    # M⁻¹ is ill-conditioned when M is: expect errors of about cond(M)·eps. The worst here is the
    # double pendulum on a free-flyer (cond(M) ≈ 5e4, so cond·eps ≈ 1.2e-11; seen 5e-12), inside 1e-10
    # for every robot, so none needs a cond(M)-based bound.
    case = get_case(name, floating)
    Minv = mb.inverse_mass_matrix(case.model, case.q)
    assert Minv.shape == (N_STATES, case.model.nv, case.model.nv)
    assert_rel(Minv, case.ref("Minv"), TOL, "inverse_mass_matrix")


# ----------------------------------------------------------------------------- Coriolis, gravity, bias

@pytest.mark.parametrize("name, floating", ALL)
def test_coriolis_matrix_recursive(name, floating):
    case = get_case(name, floating)
    C = mb.coriolis_matrix(case.model, case.q, case.v)
    assert C.shape == (N_STATES, case.model.nv, case.model.nv)
    assert_rel(C, case.ref("C"), TOL, "coriolis_matrix[recursive]")


@pytest.mark.parametrize("name, floating", CHRISTOFFEL)
def test_coriolis_matrix_lagrangian(name, floating):
    case = get_case(name, floating)
    n = N_STATES if case.model.nv <= 12 else CHRISTOFFEL_STATES_LARGE
    C = mb.coriolis_matrix(case.model, case.q[:n], case.v[:n], method="lagrangian")
    assert_rel(C, case.ref("C")[:n], TOL, "coriolis_matrix[lagrangian]")


@pytest.mark.parametrize("name, floating", ALL)
def test_generalized_gravity(name, floating):
    case = get_case(name, floating)
    g = mb.generalized_gravity(case.model, case.q)
    assert g.shape == (N_STATES, case.model.nv)
    assert_rel(g, case.ref("g"), TOL, "generalized_gravity")


@pytest.mark.parametrize("name, floating", ALL)
def test_bias_forces(name, floating):
    case = get_case(name, floating)
    h = mb.bias_forces(case.model, case.q, case.v)
    assert h.shape == (N_STATES, case.model.nv)
    assert_rel(h, case.ref("h"), TOL, "bias_forces")


# ----------------------------------------------------------------------------- RNEA and ABA

@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
@pytest.mark.parametrize("name, floating", ALL)
def test_inverse_dynamics(name, floating, with_fext):
    case = get_case(name, floating)
    if with_fext:
        tau = mb.inverse_dynamics(case.model, case.q, case.v, case.a, f_ext=case.f_ext)
        ref = case.ref("rnea_fext")
        # The external forces must matter, or this would not test them.
        assert np.abs(ref - case.ref("rnea")).max() > 1e-3
    else:
        tau = mb.inverse_dynamics(case.model, case.q, case.v, case.a)
        ref = case.ref("rnea")
    assert tau.shape == (N_STATES, case.model.nv)
    assert_rel(tau, ref, TOL, "inverse_dynamics")


@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
@pytest.mark.parametrize("name, floating", INVERTIBLE)
def test_forward_dynamics(name, floating, with_fext):
    case = get_case(name, floating)
    if with_fext:
        acc = mb.forward_dynamics(case.model, case.q, case.v, case.tau, f_ext=case.f_ext)
        ref = case.ref("aba_fext")
        assert np.abs(ref - case.ref("aba")).max() > 1e-3
    else:
        acc = mb.forward_dynamics(case.model, case.q, case.v, case.tau)
        ref = case.ref("aba")
    assert acc.shape == (N_STATES, case.model.nv)
    assert_rel(acc, ref, TOL, "forward_dynamics")


# ----------------------------------------------------------------------------- energies

@pytest.mark.parametrize("name, floating", ALL)
def test_kinetic_energy(name, floating):
    case = get_case(name, floating)
    T = mb.kinetic_energy(case.model, case.q, case.v)
    assert T.shape == (N_STATES,)
    assert np.all(T > 0.0)
    assert_rel(T, case.ref("T"), TOL, "kinetic_energy")


@pytest.mark.parametrize("name, floating", ALL)
def test_potential_energy(name, floating):
    case = get_case(name, floating)
    U = mb.potential_energy(case.model, case.q)
    assert U.shape == (N_STATES,)
    assert_rel(U, case.ref("U"), TOL, "potential_energy")


# ----------------------------------------------------------------------------- derivatives

@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
@pytest.mark.parametrize("name, floating", ALL)
def test_inverse_dynamics_derivatives(name, floating, with_fext):
    """``(∂τ/∂q, ∂τ/∂v)`` in the tangent space equal Pinocchio's ``computeRNEADerivatives``."""
    case = get_case(name, floating)
    f_ext = case.f_ext if with_fext else None
    dtau_dq, dtau_dv = mb.inverse_dynamics_derivatives(case.model, case.q, case.v, case.a, f_ext=f_ext)
    ref = case.ref("rnea_derivatives_fext" if with_fext else "rnea_derivatives")
    assert dtau_dq.shape == dtau_dv.shape == (N_STATES, case.model.nv, case.model.nv)
    assert_rel(dtau_dq, ref[:, 0], TOL, "dtau_dq")
    assert_rel(dtau_dv, ref[:, 1], TOL, "dtau_dv")


@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
@pytest.mark.parametrize("name, floating", INVERTIBLE)
def test_forward_dynamics_derivatives(name, floating, with_fext):
    """``(∂a/∂q, ∂a/∂v, ∂a/∂τ)`` equal Pinocchio's ``computeABADerivatives``."""
    case = get_case(name, floating)
    f_ext = case.f_ext if with_fext else None
    da = mb.forward_dynamics_derivatives(case.model, case.q, case.v, case.tau, f_ext=f_ext)
    ref = case.ref("aba_derivatives_fext" if with_fext else "aba_derivatives")
    for k, what in enumerate(("da_dq", "da_dv", "da_dtau")):
        assert da[k].shape == (N_STATES, case.model.nv, case.model.nv)
        assert_rel(da[k], ref[:, k], TOL, what)


@pytest.mark.parametrize("name, floating", ALL)
def test_gravity_derivatives(name, floating):
    """``∂g/∂q`` equals Pinocchio's ``computeGeneralizedGravityDerivatives``."""
    case = get_case(name, floating)
    dg_dq = mb.gravity_derivatives(case.model, case.q)
    assert dg_dq.shape == (N_STATES, case.model.nv, case.model.nv)
    assert_rel(dg_dq, case.ref("gravity_derivatives"), TOL, "dg_dq")
