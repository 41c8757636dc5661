"""Analytical derivatives of the dynamics against central differences, on random trees of every joint
kind (free flyer, spherical, planar, translation, revolute, continuous, prismatic), and batched against
single calls. Agreement with Pinocchio on the example-robot-data robots is in
``test_dynamics_pinocchio.py``.

The central differences take steps of ``1e-6 · max(1, |q|)`` in the tangent space
(``q ⊕ δq = model.integrate(q, δq)``); their truncation and rounding errors stay below ``3e-9`` of the
scale of the entries here, so ``1e-7`` relative leaves a margin of 30 while any wrong term, which
changes entries by their own size, fails.
"""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb

from dyn_helpers import assert_rel, central_differences, central_differences_vector, random_tree_model

FD_TOL = 1e-7
SEEDS = [0, 1, 2]


def _state(model, seed):
    rng = np.random.default_rng(seed)
    q = model.random_configuration(rng)
    v, a, tau = rng.standard_normal((3, model.nv))
    f_ext = rng.standard_normal((model.njoints, 6))
    return q, v, a, tau, f_ext


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
def test_inverse_dynamics_derivatives_match_central_differences(seed, with_fext):
    model = random_tree_model(seed)
    q, v, a, _, f_ext = _state(model, seed)
    f_ext = f_ext if with_fext else None
    dtau_dq, dtau_dv = mb.inverse_dynamics_derivatives(model, q, v, a, f_ext=f_ext)
    fd_q = central_differences(lambda x: mb.inverse_dynamics(model, x, v, a, f_ext=f_ext), model, q)
    fd_v = central_differences_vector(lambda x: mb.inverse_dynamics(model, q, x, a, f_ext=f_ext), v)
    assert_rel(dtau_dq, fd_q, FD_TOL, "dtau_dq", batch_ndim=0)
    assert_rel(dtau_dv, fd_v, FD_TOL, "dtau_dv", batch_ndim=0)


@pytest.mark.parametrize("seed", SEEDS)
def test_forward_dynamics_derivatives_match_central_differences(seed):
    model = random_tree_model(seed)
    q, v, _, tau, f_ext = _state(model, seed)
    da_dq, da_dv, da_dtau = mb.forward_dynamics_derivatives(model, q, v, tau, f_ext=f_ext)
    fd = {
        "da_dq": central_differences(lambda x: mb.forward_dynamics(model, x, v, tau, f_ext=f_ext), model, q),
        "da_dv": central_differences_vector(lambda x: mb.forward_dynamics(model, q, x, tau, f_ext=f_ext), v),
        "da_dtau": central_differences_vector(lambda x: mb.forward_dynamics(model, q, v, x, f_ext=f_ext), tau),
    }
    for name, ours in zip(fd, (da_dq, da_dv, da_dtau)):
        assert_rel(ours, fd[name], FD_TOL, name, batch_ndim=0)
    np.testing.assert_allclose(da_dtau, mb.inverse_mass_matrix(model, q), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_gravity_derivatives_match_central_differences(seed):
    model = random_tree_model(seed)
    q = _state(model, seed)[0]
    fd = central_differences(lambda x: mb.generalized_gravity(model, x), model, q)
    assert_rel(mb.gravity_derivatives(model, q), fd, FD_TOL, "dg_dq", batch_ndim=0)
    # g(q) is τ at v = a = 0
    zero = np.zeros(model.nv)
    np.testing.assert_array_equal(mb.gravity_derivatives(model, q),
                                  mb.inverse_dynamics_derivatives(model, q, zero, zero)[0])


def test_batched_derivatives_equal_single_calls():
    model = random_tree_model(0)
    rng = np.random.default_rng(5)
    q = model.random_configuration(rng, shape=(2, 3))
    v, a, tau = rng.standard_normal((3, 2, 3, model.nv))
    f_ext = rng.standard_normal((3, model.njoints, 6))  # broadcasts against (2, 3)
    batched = (mb.inverse_dynamics_derivatives(model, q, v, a, f_ext=f_ext)
               + mb.forward_dynamics_derivatives(model, q, v, tau, f_ext=f_ext) + (mb.gravity_derivatives(model, q),))
    for i in range(2):
        for j in range(3):
            single = (mb.inverse_dynamics_derivatives(model, q[i, j], v[i, j], a[i, j], f_ext=f_ext[j])
                      + mb.forward_dynamics_derivatives(model, q[i, j], v[i, j], tau[i, j], f_ext=f_ext[j])
                      + (mb.gravity_derivatives(model, q[i, j]),))
            for ours, ref in zip(batched, single):
                assert ours.shape == (2, 3, model.nv, model.nv)
                np.testing.assert_array_equal(ours[i, j], ref)


def test_bad_inputs_are_refused_with_their_names():
    model = random_tree_model(0)
    q, v, a, tau, _ = _state(model, 0)
    with pytest.raises(ValueError, match="a"):
        mb.inverse_dynamics_derivatives(model, q, v, a[:-1])
    with pytest.raises(ValueError, match="f_ext"):
        mb.forward_dynamics_derivatives(model, q, v, tau, f_ext=np.zeros((model.njoints, 3)))
    with pytest.raises(ValueError, match="do not broadcast"):
        mb.inverse_dynamics_derivatives(model, q, np.zeros((2, model.nv)), np.zeros((3, model.nv)))
    with pytest.raises(ValueError):
        mb.gravity_derivatives(model, q[:-1])

