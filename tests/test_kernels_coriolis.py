"""The Coriolis-matrix kernel (:mod:`multibody.kernels.coriolis`), one state per call.

Checked against Pinocchio's ``computeCoriolisMatrix``, against the NumPy ``mb.coriolis_matrix``, and
for its two defining identities: ``C v + g = h`` (Pinocchio's ``nonLinearEffects``) and
``Ṁ = C + Cᵀ``, with ``Ṁ`` a central difference of ``mb.mass_matrix`` along ``q ⊕ v t``. Models: Panda
and UR5 (fixed base), Solo12 and Talos (free flyer), random trees with every joint kind (in their
own joint order, and depth first for their Pinocchio twins, which need that order).
Error measure: ``max|ours − ref| / max(1, max|ref|)``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import multibody as mb
from multibody.kernels.coriolis import coriolis_matrix, workspace_size
from multibody.tree import compile_tree

from conftest import pinocchio_twin
from dyn_helpers import assert_rel, depth_first_model, erd_urdf, q_to_pinocchio, random_tree_model

TOL = 1e-12
N_STATES = 5
EMPTY = np.zeros(0)

ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", False),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos_reduced": ("talos_data/robots/talos_reduced.urdf", True),
}
TWINS = ["random_tree_0", "random_tree_1", "random_tree_2"]
PINOCCHIO_MODELS = list(ROBOTS) + [f"twin-{name}" for name in TWINS]
ALL_MODELS = PINOCCHIO_MODELS + TWINS


@functools.lru_cache(maxsize=None)
def get_model(name):
    """``(model, pinocchio model or None)``: twins are the random trees reordered depth first."""
    if name.startswith("twin-"):
        pin = pytest.importorskip("pinocchio")
        model = depth_first_model(random_tree_model(int(name[-1])))[0]
        return model, pinocchio_twin(pin, model)[0]
    if name.startswith("random_tree_"):
        return random_tree_model(int(name[-1])), None
    path, floating = ROBOTS[name]
    path = erd_urdf(path)
    model = mb.load_urdf(path, floating_base=floating)
    pmodel = None
    try:
        import pinocchio as pin
        pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    except ImportError:
        pass
    return model, pmodel


def states(model, seed=0):
    rng = np.random.default_rng(seed)
    return [(model.random_configuration(rng), rng.standard_normal(model.nv)) for _ in range(N_STATES)]


def kernel_C(model, q, v):
    """The kernel called directly, on a workspace and an output full of NaN (nothing may be read unwritten)."""
    tree = compile_tree(model)
    out = np.full((model.nv, model.nv), np.nan)
    ws = np.full(workspace_size(model.njoints, model.nv), np.nan)
    coriolis_matrix(tree.joints, tree.reals, tree.bodies, np.ascontiguousarray(q, dtype=float),
                    np.ascontiguousarray(v, dtype=float), EMPTY, EMPTY, out, ws)
    return out


def pinocchio_or_skip(name):
    pin = pytest.importorskip("pinocchio")
    model, pmodel = get_model(name)
    if pmodel is None:
        pytest.skip("Pinocchio is not installed")
    return pin, model, pmodel


@pytest.mark.parametrize("name", PINOCCHIO_MODELS)
def test_matches_pinocchio(name):
    pin, model, pmodel = pinocchio_or_skip(name)
    data = pmodel.createData()
    for q, v in states(model):
        ref = np.array(pin.computeCoriolisMatrix(pmodel, data, q_to_pinocchio(model, q), v))
        assert_rel(kernel_C(model, q, v)[None], ref[None], TOL, f"{name}: C vs computeCoriolisMatrix")


@pytest.mark.parametrize("name", ALL_MODELS)
def test_matches_numpy(name):
    model = get_model(name)[0]
    for q, v in states(model, seed=1):
        assert_rel(kernel_C(model, q, v)[None], mb.coriolis_matrix(model, q, v)[None], TOL, f"{name}: C vs mb")


@pytest.mark.parametrize("name", PINOCCHIO_MODELS)
def test_bias_forces_pinocchio(name):
    """``C v + g = h`` with Pinocchio's ``g`` and ``h``."""
    pin, model, pmodel = pinocchio_or_skip(name)
    data = pmodel.createData()
    for q, v in states(model, seed=2):
        q_pin = q_to_pinocchio(model, q)
        g = np.array(pin.computeGeneralizedGravity(pmodel, data, q_pin))
        h = np.array(pin.nonLinearEffects(pmodel, data, q_pin, v))
        assert_rel((kernel_C(model, q, v) @ v + g)[None], h[None], TOL, f"{name}: C v + g vs nonLinearEffects")


@pytest.mark.parametrize("name", TWINS)
def test_bias_forces_numpy(name):
    """``C v + g = h`` on the random trees in their own (not depth-first) joint order."""
    model = get_model(name)[0]
    for q, v in states(model, seed=2):
        h = mb.bias_forces(model, q, v) - mb.generalized_gravity(model, q)
        assert_rel((kernel_C(model, q, v) @ v)[None], h[None], TOL, f"{name}: C v vs h − g")


@pytest.mark.parametrize("name", ALL_MODELS)
def test_mass_matrix_rate(name):
    """``Ṁ = C + Cᵀ``, with ``Ṁ`` the fourth-order central difference of ``M(q ⊕ v t)`` at ``t = 0``
    (truncation ``O(t⁴)``, rounding ``O(ε / t)``: both near 1e-12 of ``|M|`` at ``t = 1e-3``)."""
    model = get_model(name)[0]
    t = 1e-3
    for q, v in states(model, seed=3):
        M = {s: mb.mass_matrix(model, model.integrate(q, v, s * t)) for s in (-2, -1, 1, 2)}
        M_dot = (M[-2] - 8.0 * M[-1] + 8.0 * M[1] - M[2]) / (12.0 * t)
        C = kernel_C(model, q, v)
        scale = max(1.0, np.abs(mb.mass_matrix(model, q)).max())
        assert np.abs(C + C.T - M_dot).max() <= 1e-9 * scale, f"{name}: Ṁ ≠ C + Cᵀ"


@pytest.mark.parametrize("name", ["panda", "random_tree_0"])
def test_zero_velocity(name):
    """``C(q, 0) = 0``, for ``v = 0`` and for ``v`` of length 0."""
    model = get_model(name)[0]
    q = states(model)[0][0]
    assert np.array_equal(kernel_C(model, q, np.zeros(model.nv)), np.zeros((model.nv, model.nv)))
    assert np.array_equal(kernel_C(model, q, EMPTY), np.zeros((model.nv, model.nv)))


def test_linear_in_velocity():
    """``C(q, v)`` is linear in ``v``."""
    model = get_model("random_tree_1")[0]
    (q, v), (_, w) = states(model)[:2]
    C = kernel_C(model, q, 2.0 * v - 3.0 * w)
    np.testing.assert_allclose(C, 2.0 * kernel_C(model, q, v) - 3.0 * kernel_C(model, q, w),
                               rtol=0, atol=1e-12 * max(1.0, np.abs(C).max()))


def test_plain_python_agrees():
    """The kernel run as plain Python (``py_func``) gives the compiled result."""
    model = get_model("random_tree_2")[0]
    tree = compile_tree(model)
    q, v = states(model)[0]
    out = np.empty((model.nv, model.nv))
    coriolis_matrix.py_func(tree.joints, tree.reals, tree.bodies, q, v, EMPTY, EMPTY, out,
                            np.empty(workspace_size(model.njoints, model.nv)))
    C = kernel_C(model, q, v)
    np.testing.assert_allclose(out, C, rtol=0, atol=1e-13 * max(1.0, np.abs(C).max()))
