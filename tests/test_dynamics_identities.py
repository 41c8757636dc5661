"""Identities that tie the dynamics algorithms together, and textbook closed forms.

Models: seeded random trees that use every joint type (``conftest.random_tree_model``: free-flyer,
revolute with random axes, continuous, prismatic, planar, spherical, translation, fixed
attachments, branches), random trees whose joints all have ``v = q̇`` (``coordinate_tree_model``,
for the Christoffel Coriolis matrix and ``∂M/∂q``), and Solo12 on a free-flyer.

Tolerances: algebraic identities between exact algorithms hold to rounding, checked at 1e-10
relative (``max|lhs − rhs| / max(1, max|rhs|)``); finite-difference checks are justified where they
are made.
"""

from __future__ import annotations

import functools
import zlib

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody.dynamics import mass_matrix_derivative

from dyn_helpers import (STATUE_URDF, assert_rel, coordinate_permutations, coordinate_tree_model, depth_first_model,
                         dynamics_calls, erd_urdf, random_tree_model)

TOL = 1e-10
N_STATES = 4


@functools.lru_cache(maxsize=None)
def get_model(name):
    if name.startswith("random_tree_"):
        return random_tree_model(int(name.rsplit("_", 1)[1]))
    if name.startswith("coordinate_tree_"):
        return coordinate_tree_model(int(name.rsplit("_", 1)[1]))
    if name == "solo12_floating":
        return mb.load_urdf(erd_urdf("solo_description/robots/solo12.urdf"), floating_base=True)
    raise KeyError(name)


RANDOM_TREES = [f"random_tree_{k}" for k in range(3)]
COORDINATE_TREES = [f"coordinate_tree_{k}" for k in range(3)]
GENERAL = RANDOM_TREES + ["solo12_floating"]
EVERY = GENERAL + COORDINATE_TREES


def states(model, seed, n=N_STATES, velocity_scale=1.0):
    """``n`` random ``(q, v, a, tau, f_ext)``, batched along the first axis (seeded by ``seed`` and the model)."""
    rng = np.random.default_rng([seed, zlib.crc32(model.name.encode())])
    q = model.random_configuration(rng, shape=(n,))
    v = velocity_scale * rng.standard_normal((n, model.nv))
    a = rng.standard_normal((n, model.nv))
    tau = rng.standard_normal((n, model.nv))
    f_ext = rng.standard_normal((n, model.njoints, 6))
    return q, v, a, tau, f_ext


def test_models_cover_every_joint_type():
    kinds = {joint.kind for name in RANDOM_TREES for joint in get_model(name).joints}
    assert kinds >= {"revolute", "continuous", "prismatic", "planar", "spherical", "free-flyer", "translation"}
    for name in RANDOM_TREES + COORDINATE_TREES:
        model = get_model(name)
        assert np.any(model.body_joints >= 0) and len(model.body_names) > model.njoints  # fixed attachments
        assert len(set(model.parents.tolist())) < model.njoints  # some joint has two children: a branch
    coordinate_kinds = {joint.kind for name in COORDINATE_TREES for joint in get_model(name).joints}
    assert coordinate_kinds == {"revolute", "continuous", "prismatic", "translation"}


# ============================================================================= CRBA, RNEA, ABA

@pytest.mark.parametrize("name", EVERY)
def test_mass_matrix_columns_are_rnea_of_unit_accelerations(name):
    """``M[:, k] = inverse_dynamics(q, v, e_k) − bias_forces(q, v)``."""
    model = get_model(name)
    q, v, *_ = states(model, 1)
    M = mb.mass_matrix(model, q)
    h = mb.bias_forces(model, q, v)
    # One batched call: q, v of shape (n, 1, ·) against the nv unit accelerations (nv, nv).
    tau = mb.inverse_dynamics(model, q[:, None, :], v[:, None, :], np.eye(model.nv))
    columns = tau - h[:, None, :]  # [state, k, :] = M[:, k]
    assert_rel(np.swapaxes(columns, -1, -2), M, TOL, "RNEA(e_k) − h vs M")
    # Symmetric up to rounding (the diagonal blocks Sᵀ I S of multi-DoF joints are not bit-symmetric).
    assert_rel(M, np.swapaxes(M, -1, -2), 1e-14, "M symmetric")
    assert np.all(np.linalg.eigvalsh(M) > 0.0)


@pytest.mark.parametrize("name", EVERY)
def test_forward_dynamics_inverts_inverse_dynamics(name):
    model = get_model(name)
    q, v, a, _, f_ext = states(model, 2)
    tau = mb.inverse_dynamics(model, q, v, a)
    assert_rel(mb.forward_dynamics(model, q, v, tau), a, TOL, "ABA(RNEA(a))")
    tau_f = mb.inverse_dynamics(model, q, v, a, f_ext=f_ext)
    assert_rel(mb.forward_dynamics(model, q, v, tau_f, f_ext=f_ext), a, TOL, "ABA(RNEA(a, f), f)")
    # And the other way round: RNEA(ABA(τ)) = τ.
    assert_rel(mb.inverse_dynamics(model, q, v, mb.forward_dynamics(model, q, v, tau_f, f_ext=f_ext), f_ext=f_ext),
               tau_f, TOL, "RNEA(ABA(τ, f), f)")


@pytest.mark.parametrize("name", EVERY)
def test_forward_dynamics_is_minv_times_net_force(name):
    """``a = M⁻¹ (τ − h)``, from two independent routes (CRBA + solve, and ABA)."""
    model = get_model(name)
    q, v, _, tau, _ = states(model, 3)
    M = mb.mass_matrix(model, q)
    expected = np.linalg.solve(M, (tau - mb.bias_forces(model, q, v))[..., None])[..., 0]
    # Both sides carry an error of about cond(M)·eps·|a|; cond(M) < 1e5 for these models.
    assert np.linalg.cond(M).max() < 1e5
    assert_rel(mb.forward_dynamics(model, q, v, tau), expected, TOL, "ABA vs solve(M, τ − h)")


def _joint_body_jacobians(model, q):
    """Per moving joint i: ``J_i (n, 6, nv)`` of its joint frame, in joint-frame axes, ``[linear; angular]``.

    Built from the public world-aligned ``mb.jacobian`` of the body whose frame is the joint frame.
    """
    poses = mb.forward_kinematics(model, q)
    out = []
    for i in range(model.njoints):
        bodies = [b for b in np.flatnonzero(model.body_joints == i)
                  if np.allclose(model.body_placements[b], np.eye(4), atol=0.0)]
        b = bodies[0]
        R = poses[..., b, :3, :3]
        J = mb.jacobian(model, q, b)
        Rt = np.swapaxes(R, -1, -2)
        out.append(np.concatenate([Rt @ J[..., :3, :], Rt @ J[..., 3:, :]], axis=-2))
    return out


@pytest.mark.parametrize("name", GENERAL + ["coordinate_tree_0"])
def test_external_forces_enter_as_jacobian_transpose(name):
    """``τ(f) = τ(0) − Σᵢ Jᵢᵀ fᵢ`` and ``a(f) = a(0) + M⁻¹ Σᵢ Jᵢᵀ fᵢ``, with ``Jᵢ`` in joint i's frame.

    This pins the f_ext convention (joint frame, at its origin, ``[force; torque]``) independently
    of Pinocchio, through the kinematics module's Jacobians.
    """
    model = get_model(name)
    q, v, a, tau, f_ext = states(model, 4)
    generalized = sum(np.einsum("...ck,...c->...k", J, f_ext[:, i, :])
                      for i, J in enumerate(_joint_body_jacobians(model, q)))
    assert np.abs(generalized).max() > 1e-2
    assert_rel(mb.inverse_dynamics(model, q, v, a, f_ext=f_ext),
               mb.inverse_dynamics(model, q, v, a) - generalized, TOL, "RNEA with f_ext")
    M = mb.mass_matrix(model, q)
    expected = mb.forward_dynamics(model, q, v, tau) + np.linalg.solve(M, generalized[..., None])[..., 0]
    assert_rel(mb.forward_dynamics(model, q, v, tau, f_ext=f_ext), expected, TOL, "ABA with f_ext")


@pytest.mark.parametrize("name", EVERY)
def test_inverse_mass_matrix_inverts_mass_matrix(name):
    model = get_model(name)
    q, *_ = states(model, 5)
    M = mb.mass_matrix(model, q)
    Minv = mb.inverse_mass_matrix(model, q)
    identity = np.broadcast_to(np.eye(model.nv), M.shape)
    # ‖M⁻¹M − I‖ is about cond(M)·eps; cond(M) < 1e5 here, so 1e-10 leaves a wide margin.
    assert np.linalg.cond(M).max() < 1e5
    assert_rel(Minv @ M, identity, TOL, "M⁻¹ M")
    assert_rel(M @ Minv, identity, TOL, "M M⁻¹")
    assert_rel(Minv, np.swapaxes(Minv, -1, -2), TOL, "M⁻¹ symmetric")


@pytest.mark.parametrize("name", EVERY)
def test_lagrangian_mass_matrix_equals_crba(name):
    model = get_model(name)
    q, *_ = states(model, 6)
    assert_rel(mb.mass_matrix(model, q, method="lagrangian"), mb.mass_matrix(model, q), TOL, "Σ JᵀIJ vs CRBA")


# ============================================================================= Coriolis

# Central differences of M along q(t) = integrate(q, t v) with step ε = 1e-5: truncation error
# ε²/6 · |d³M/dt³| ≈ 1e-10 · O(10) and rounding error ≈ eps · max|M| / ε ≈ 1e-11 · O(10) — both far
# below 1e-6 (relative to max(1, max|Ṁ|)), which any error in C (of order |C| ≥ 0.1) would exceed.
FD_STEP = 1e-5
FD_TOL = 1e-6


@pytest.mark.parametrize("name", EVERY)
def test_mass_matrix_rate_is_coriolis_plus_transpose(name):
    """``Ṁ = C + Cᵀ``, Ṁ by central differences along the configuration exponential."""
    model = get_model(name)
    q, v, *_ = states(model, 7)
    M_plus = mb.mass_matrix(model, model.integrate(q, v, FD_STEP))
    M_minus = mb.mass_matrix(model, model.integrate(q, v, -FD_STEP))
    M_dot = (M_plus - M_minus) / (2 * FD_STEP)
    C = mb.coriolis_matrix(model, q, v)
    assert np.abs(M_dot).max() > 1e-2  # (Solo12's light legs: ≈ 0.04)
    assert_rel(C + np.swapaxes(C, -1, -2), M_dot, FD_TOL, "C + Cᵀ vs finite-difference Ṁ")


@pytest.mark.parametrize("name", EVERY)
def test_coriolis_times_v_plus_gravity_is_bias(name):
    model = get_model(name)
    q, v, *_ = states(model, 8)
    C = mb.coriolis_matrix(model, q, v)
    g = mb.generalized_gravity(model, q)
    assert_rel(np.einsum("...ij,...j->...i", C, v) + g, mb.bias_forces(model, q, v), TOL, "C v + g vs h")
    # C is linear in v.
    assert_rel(mb.coriolis_matrix(model, q, 2.5 * v), 2.5 * C, TOL, "C(q, 2.5 v)")


@pytest.mark.parametrize("name", COORDINATE_TREES)
def test_christoffel_coriolis_equals_recursive(name):
    model = get_model(name)
    q, v, *_ = states(model, 9)
    assert_rel(mb.coriolis_matrix(model, q, v, method="lagrangian"), mb.coriolis_matrix(model, q, v),
               TOL, "Christoffel C vs recursive C")


def _single_joint_model(joint):
    b = mb.ModelBuilder(f"only_{joint.kind}")
    b.add_body("body", joint, inertia=mb.inertia.box(2.0, [0.3, 0.2, 0.1], center=[0.1, 0.0, -0.2]))
    return b.build()


@pytest.mark.parametrize("joint", [jt.Spherical(), jt.Planar(), jt.FreeFlyer()], ids=lambda j: j.kind)
def test_christoffel_coriolis_refuses_joints_with_v_not_qdot(joint):
    model = _single_joint_model(joint)
    q = model.random_configuration(0)
    v = np.ones(model.nv)
    with pytest.raises(ValueError, match="recursive"):
        mb.coriolis_matrix(model, q, v, method="lagrangian")
    # The recursive one is fine there.
    assert mb.coriolis_matrix(model, q, v).shape == (model.nv, model.nv)


def test_christoffel_coriolis_refuses_random_tree_with_spherical():
    model = get_model("random_tree_0")
    assert any(isinstance(j, jt.Spherical) for j in model.joints)
    q, v, *_ = states(model, 10, n=1)
    with pytest.raises(ValueError):
        mb.coriolis_matrix(model, q, v, method="lagrangian")


@pytest.mark.parametrize("name", COORDINATE_TREES)
def test_mass_matrix_derivative_matches_central_differences(name):
    """``∂M/∂q_k`` against ``(M(q + ε e_k) − M(q − ε e_k)) / 2ε`` (ε = 1e-5, see FD_TOL)."""
    model = get_model(name)
    assert model.nq == model.nv
    q, *_ = states(model, 11, n=2)
    dM = mass_matrix_derivative(model, q)
    assert dM.shape == (2, model.nv, model.nv, model.nv)
    steps = FD_STEP * np.eye(model.nq)
    fd = (mb.mass_matrix(model, q[:, None, :] + steps) - mb.mass_matrix(model, q[:, None, :] - steps)) / (2 * FD_STEP)
    assert np.abs(fd).max() > 0.1
    assert_rel(dM, fd, FD_TOL, "∂M/∂q vs central differences")
    # Each slice is symmetric, and contracting with v gives Ṁ = C + Cᵀ.
    assert_rel(dM, np.swapaxes(dM, -1, -2), TOL, "∂M/∂q_k symmetric")
    v = np.random.default_rng(12).standard_normal((2, model.nv))
    C = mb.coriolis_matrix(model, q, v)
    assert_rel(np.einsum("...kij,...k->...ij", dM, v), C + np.swapaxes(C, -1, -2), TOL, "Σ_k ∂M/∂q_k v_k vs C + Cᵀ")


# ============================================================================= energy

@pytest.mark.parametrize("name", EVERY)
def test_kinetic_energy_is_quadratic_form_of_mass_matrix(name):
    model = get_model(name)
    q, v, *_ = states(model, 13)
    T = mb.kinetic_energy(model, q, v)
    assert_rel(T, 0.5 * np.einsum("...i,...ij,...j->...", v, mb.mass_matrix(model, q), v), TOL, "T vs ½ vᵀMv",
               batch_ndim=0)


@pytest.mark.parametrize("name", EVERY)
def test_mechanical_energy_is_kinetic_plus_potential(name):
    """The one-pass kernel of ``T + U`` (what a trajectory's ``energy`` holds) sums the same terms as the kinetic
    and potential energy kernels: equal bit for bit, one state and a batch."""
    from multibody.dynamics import mechanical_energy

    model = get_model(name)
    q, v, *_ = states(model, 17)
    E = mechanical_energy(model, q, v)
    assert E.shape == q.shape[:-1]
    np.testing.assert_array_equal(E, mb.kinetic_energy(model, q, v) + mb.potential_energy(model, q))
    one, one_v = np.ascontiguousarray(q[0]), np.ascontiguousarray(v[0])
    assert mechanical_energy(model, one, one_v) == mb.kinetic_energy(model, one, one_v) + mb.potential_energy(model, one)


# dE/dt by central differences along the motion, Richardson-extrapolated from steps ε and ε/2
# (ε = 1e-4 s), see test_work_energy. A plain central difference is only second-order: on Solo12,
# whose light links reach |a| ≈ 8e3 under unit torques, its error is ≈ 5e-4 at ε = 1e-4 (it does
# converge as ε², checked while writing this test). The extrapolation cancels the ε² term, leaving
# O(ε⁴) truncation (≲ 1e-9 here) and rounding ≈ 2·eps·max|E|/ε ≈ 2·2.2e-16·300/1e-4 ≈ 1.3e-9.
# The bound 1e-7 · max(1, |P|) on the power P is well above both, while a wrong sign or factor
# in any of T, U, g, C, M or ABA changes dE/dt by O(|P|) ≳ 0.1.
ENERGY_STEP = 1e-4
ENERGY_TOL = 1e-7


def _energy_rate(model, q, v, tau):
    """``dE/dt`` at ``(q, v)`` along ``a = forward_dynamics(q, v, τ)``, by Richardson-extrapolated differences.

    ``q(±ε) = integrate(q, ±ε v + ½ ε² a)`` and ``v(±ε) = v ± ε a`` deviate from the true motion by
    an odd O(ε³) and an even O(ε²) term, both of which cancel in the central difference, so each
    quotient is second-order accurate; ``(4 D(ε/2) − D(ε)) / 3`` removes the ε² error term.
    """
    acc = mb.forward_dynamics(model, q, v, tau)

    def central(eps):
        def energy(sign):
            q_t = model.integrate(q, sign * eps * v + 0.5 * eps**2 * acc)
            return mb.kinetic_energy(model, q_t, v + sign * eps * acc) + mb.potential_energy(model, q_t)
        return (energy(+1) - energy(-1)) / (2 * eps)

    return (4 * central(ENERGY_STEP / 2) - central(ENERGY_STEP)) / 3


@pytest.mark.parametrize("name", EVERY)
def test_work_energy(name):
    """``dE/dt = vᵀτ`` along the motion ``a = forward_dynamics(q, v, τ)``, ``E = T + U``."""
    model = get_model(name)
    q, v, _, tau, _ = states(model, 14)
    power = np.einsum("...i,...i->...", v, tau)
    assert np.abs(power).min() > 0.1
    assert_rel(_energy_rate(model, q, v, tau), power, ENERGY_TOL, "dE/dt vs vᵀτ", batch_ndim=0)
    # Without torques, energy is conserved to the same accuracy.
    assert_rel(_energy_rate(model, q, v, np.zeros_like(tau)), np.zeros(len(q)), ENERGY_TOL, "dE/dt, τ = 0",
               batch_ndim=0)


@pytest.mark.parametrize("name", EVERY)
def test_generalized_gravity_is_gradient_of_potential(name):
    """``dU/dt = gᵀ v`` along ``q(t) = integrate(q, t v)``; central differences, ε = 1e-5 (FD_TOL)."""
    model = get_model(name)
    q, v, *_ = states(model, 15)
    dU = (mb.potential_energy(model, model.integrate(q, v, FD_STEP))
          - mb.potential_energy(model, model.integrate(q, v, -FD_STEP))) / (2 * FD_STEP)
    gv = np.einsum("...i,...i->...", mb.generalized_gravity(model, q), v)
    assert np.abs(gv).max() > 0.1
    assert_rel(dU, gv, FD_TOL, "dU/dt vs gᵀv", batch_ndim=0)


# ============================================================================= joint order

@pytest.mark.parametrize("name", RANDOM_TREES + COORDINATE_TREES)
def test_results_do_not_depend_on_joint_order(name):
    """The same tree with its joints in depth-first order gives the permuted results.

    The random trees attach bodies to random earlier parents, so subtrees are not contiguous in v;
    the depth-first versions are the ones checked against Pinocchio (which needs that order), so
    this carries the Pinocchio check over to the original order.
    """
    model = get_model(name)
    dfs, order = depth_first_model(model)
    assert order != sorted(order)
    iq, iv = coordinate_permutations(model, order)
    q, v, a, tau, f_ext = states(model, 19)
    Q, V, A, TAU, F = q[:, iq], v[:, iv], a[:, iv], tau[:, iv], f_ext[:, order]
    ours, theirs = dynamics_calls(model), dynamics_calls(dfs)
    assert ours.keys() == theirs.keys()
    for what in ours:
        x = ours[what](q, v, tau if what.startswith("forward") else a, f_ext)
        y = theirs[what](Q, V, TAU if what.startswith("forward") else A, F)
        if what == "mass_matrix_derivative":
            x = x[:, iv][:, :, iv][:, :, :, iv]
        elif x.ndim == 3:
            x = x[:, iv][:, :, iv]
        elif x.ndim == 2:
            x = x[:, iv]
        assert_rel(x, y, TOL, f"{what}: original vs depth-first order")


# ============================================================================= batching

BATCH_MODELS = ["random_tree_0", "coordinate_tree_1", "solo12_floating"]


def _stacked(fn, q, v, a, f):
    """``fn`` on every sample of the common batch shape, stacked back into that shape."""
    batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], a.shape[:-1], f.shape[:-2])
    q, v = np.broadcast_to(q, batch + q.shape[-1:]), np.broadcast_to(v, batch + v.shape[-1:])
    a, f = np.broadcast_to(a, batch + a.shape[-1:]), np.broadcast_to(f, batch + f.shape[-2:])
    results = [fn(q[idx], v[idx], a[idx], f[idx]) for idx in np.ndindex(*batch)]
    return np.stack(results).reshape(batch + np.shape(results[0]))


def _batch_inputs(model, seed, q_shape, v_shape):
    rng = np.random.default_rng(seed)
    q = model.random_configuration(rng, shape=q_shape)
    v = rng.standard_normal(v_shape + (model.nv,))
    a = rng.standard_normal(v_shape + (model.nv,))
    f = rng.standard_normal(v_shape + (model.njoints, 6))
    return q, v, a, f


@pytest.mark.parametrize("q_shape, v_shape", [((3,), (3,)), ((2, 3), (2, 3)), ((), (4,)), ((3,), ()), ((3, 1), (4,))],
                         ids=["3", "2x3", "single_q-vs-4", "3-vs-single_v", "3x1-vs-4"])
@pytest.mark.parametrize("name", BATCH_MODELS)
def test_batched_calls_equal_stacked_single_calls(name, q_shape, v_shape):
    model = get_model(name)
    q, v, a, f = _batch_inputs(model, 16, q_shape, v_shape)
    batch = np.broadcast_shapes(q_shape, v_shape)
    calls = dynamics_calls(model)
    if name.startswith("coordinate_tree"):
        assert "coriolis_matrix[lagrangian]" in calls and "mass_matrix_derivative" in calls
    first = dict(v=v.reshape(-1, model.nv)[0], a=a.reshape(-1, model.nv)[0], f=f.reshape(-1, model.njoints, 6)[0])
    for what, fn in calls.items():
        single = fn(q.reshape(-1, model.nq)[0], first["v"], first["a"], first["f"])
        batched = fn(q, v, a, f)
        uses_v = not what.startswith(("mass_matrix", "generalized_gravity", "inverse_mass", "potential"))
        if uses_v:
            stacked = _stacked(fn, q, v, a, f)
            assert batched.shape == batch + np.shape(single), what
        else:  # a function of q alone has q's batch shape
            stacked = _stacked(fn, q, first["v"], first["a"], first["f"])
            assert batched.shape == q_shape + np.shape(single), what
        # Same arithmetic on every sample (forward dynamics and M⁻¹ of one configuration take CRBA and LU
        # instead of the sweeps): only rounding may differ.
        np.testing.assert_allclose(batched, stacked, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(stacked).max()),
                                   err_msg=what)


# ============================================================================= textbook closed forms

GRAVITY = 9.81


def test_simple_pendulum_closed_form():
    """Point mass m = 1 kg at l = 1 m, continuous joint about +y, gravity (0, 0, −9.81).

    Bob position: ``R_y(θ) (0, 0, −l) = (−l sin θ, 0, −l cos θ)``, so
    ``U = −m gᵀ c = m g₀ z = −m g₀ l cos θ``, ``g(θ) = ∂U/∂θ = m g₀ l sin θ`` (positive for θ > 0:
    gravity pulls back towards θ = 0), ``M = m l²``, ``T = ½ m l² θ̇²``, ``C = 0``.
    """
    model = mb.robots.load("pendulum")
    m, l = 1.0, 1.0
    assert model.nq == model.nv == 1
    np.testing.assert_array_equal(model.gravity, [0.0, 0.0, -GRAVITY])
    theta = np.linspace(-3.0, 3.0, 13)[:, None]
    theta_dot = np.linspace(-2.0, 2.0, 13)[:, None]
    tau = np.linspace(5.0, -5.0, 13)[:, None]

    bob = mb.forward_kinematics(model, theta)[:, model.body_names.index("bob")]
    # The bob's frame is at the pivot; its mass sits at (0, 0, −l) in that frame.
    c = np.einsum("nij,j->ni", bob[:, :3, :3], [0.0, 0.0, -l]) + bob[:, :3, 3]
    np.testing.assert_allclose(c, np.column_stack([-l * np.sin(theta[:, 0]), 0 * theta[:, 0], -l * np.cos(theta[:, 0])]),
                               atol=1e-14)

    np.testing.assert_allclose(mb.mass_matrix(model, theta), np.full((13, 1, 1), m * l**2), rtol=1e-14)
    np.testing.assert_allclose(mb.generalized_gravity(model, theta), m * GRAVITY * l * np.sin(theta), atol=1e-13)
    np.testing.assert_allclose(mb.potential_energy(model, theta), -m * GRAVITY * l * np.cos(theta[:, 0]), atol=1e-13)
    np.testing.assert_allclose(mb.kinetic_energy(model, theta, theta_dot), 0.5 * m * l**2 * theta_dot[:, 0] ** 2,
                               atol=1e-14)
    np.testing.assert_allclose(mb.coriolis_matrix(model, theta, theta_dot), np.zeros((13, 1, 1)), atol=1e-14)
    np.testing.assert_allclose(mb.forward_dynamics(model, theta, theta_dot, tau),
                               (tau - m * GRAVITY * l * np.sin(theta)) / (m * l**2), atol=1e-13)
    np.testing.assert_allclose(mb.inverse_dynamics(model, theta, theta_dot, tau),
                               m * l**2 * tau + m * GRAVITY * l * np.sin(theta), atol=1e-13)
    np.testing.assert_allclose(mb.inverse_mass_matrix(model, theta), np.full((13, 1, 1), 1.0 / (m * l**2)), rtol=1e-14)


def test_double_pendulum_closed_form():
    """Two uniform rods (m = 1 kg, L = 1 m, centre at L/2), both joints about +y, hanging along −z.

    With I₁ = m₁L₁²/3 about joint 1, I₂ = m₂L₂²/3 about joint 2, lc = L/2, β = m₂ L₁ lc₂:
    ``M = [[I₁ + I₂ + m₂L₁² + 2β cos q₂, I₂ + β cos q₂], [I₂ + β cos q₂, I₂]]``,
    Christoffel ``C = β sin q₂ [[−q̇₂, −(q̇₁ + q̇₂)], [q̇₁, 0]]``,
    ``U = −g₀ (m₁ lc₁ + m₂ L₁) cos q₁ − g₀ m₂ lc₂ cos(q₁ + q₂)`` and ``g = ∂U/∂q``.
    """
    model = mb.robots.load("double_pendulum")
    m1 = m2 = 1.0
    L1 = L2 = 1.0
    lc1, lc2 = L1 / 2, L2 / 2
    I1, I2 = m1 * L1**2 / 3, m2 * L2**2 / 3
    beta = m2 * L1 * lc2
    rng = np.random.default_rng(17)
    q = rng.uniform(-np.pi, np.pi, (10, 2))
    qd = rng.standard_normal((10, 2))
    q1, q2 = q[:, 0], q[:, 1]
    c2, s2 = np.cos(q2), np.sin(q2)

    M = np.empty((10, 2, 2))
    M[:, 0, 0] = I1 + I2 + m2 * L1**2 + 2 * beta * c2
    M[:, 0, 1] = M[:, 1, 0] = I2 + beta * c2
    M[:, 1, 1] = I2
    C = beta * s2[:, None, None] * np.stack([np.stack([-qd[:, 1], -(qd[:, 0] + qd[:, 1])], -1),
                                             np.stack([qd[:, 0], 0 * qd[:, 0]], -1)], -2)
    U = -GRAVITY * (m1 * lc1 + m2 * L1) * np.cos(q1) - GRAVITY * m2 * lc2 * np.cos(q1 + q2)
    g = np.column_stack([GRAVITY * (m1 * lc1 + m2 * L1) * np.sin(q1) + GRAVITY * m2 * lc2 * np.sin(q1 + q2),
                         GRAVITY * m2 * lc2 * np.sin(q1 + q2)])
    h = np.einsum("nij,nj->ni", C, qd) + g

    # The URDF writes 1/12 as 0.0833333333333333 (15 digits): relative error ≤ 1e-14 in M.
    tol = dict(rtol=0, atol=1e-13)
    np.testing.assert_allclose(mb.mass_matrix(model, q), M, **tol)
    np.testing.assert_allclose(mb.mass_matrix(model, q, method="lagrangian"), M, **tol)
    np.testing.assert_allclose(mb.coriolis_matrix(model, q, qd), C, **tol)
    np.testing.assert_allclose(mb.coriolis_matrix(model, q, qd, method="lagrangian"), C, **tol)
    np.testing.assert_allclose(mb.generalized_gravity(model, q), g, **tol)
    np.testing.assert_allclose(mb.potential_energy(model, q), U, **tol)
    np.testing.assert_allclose(mb.bias_forces(model, q, qd), h, **tol)
    np.testing.assert_allclose(mb.kinetic_energy(model, q, qd), 0.5 * np.einsum("ni,nij,nj->n", qd, M, qd), **tol)
    tau = rng.standard_normal((10, 2))
    np.testing.assert_allclose(mb.forward_dynamics(model, q, qd, tau),
                               np.linalg.solve(M, (tau - h)[..., None])[..., 0], rtol=0, atol=1e-12)


def test_free_floating_rigid_body_closed_form():
    """The statue on a free-flyer: one rigid body of 3 kg with its centre of mass at c = (0, 0, 2.2/3) m.

    In the body frame at its origin (free-flyer ``v = [v_lin; ω]``, local): released at rest it
    falls with ``a = [Rᵀ g₀; 0]`` (every point accelerates with gravity, no rotation), and the
    generalized gravity is minus the gravity wrench, ``g = −[m Rᵀ g₀; c × m Rᵀ g₀]``.
    """
    model = mb.load_urdf(STATUE_URDF, floating_base=True)
    assert (model.nq, model.nv) == (7, 6)
    mass, com = 3.0, np.array([0.0, 0.0, 2.2 / 3.0])
    q = model.random_configuration(np.random.default_rng(18), shape=(5,))
    R = mb.spatial.quat_to_rotation(q[:, 3:])
    gravity_body = np.einsum("nji,j->ni", R, [0.0, 0.0, -GRAVITY])  # Rᵀ g₀
    zeros = np.zeros((5, 6))
    expected_a = np.concatenate([gravity_body, np.zeros((5, 3))], axis=-1)
    np.testing.assert_allclose(mb.forward_dynamics(model, q, zeros, zeros), expected_a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(mb.inverse_dynamics(model, q, zeros, expected_a), zeros, rtol=0, atol=1e-12)
    expected_g = -np.concatenate([mass * gravity_body, np.cross(com, mass * gravity_body)], axis=-1)
    np.testing.assert_allclose(mb.generalized_gravity(model, q), expected_g, rtol=0, atol=1e-12)
    np.testing.assert_allclose(mb.mass_matrix(model, q)[:, :3, :3], np.broadcast_to(mass * np.eye(3), (5, 3, 3)),
                               rtol=0, atol=1e-13)
    np.testing.assert_allclose(mb.potential_energy(model, q), mass * GRAVITY * (q[:, 2] + (R @ com)[:, 2]),
                               rtol=0, atol=1e-12)
