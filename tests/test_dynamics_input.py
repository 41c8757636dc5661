"""Input checking of the dynamics functions: shapes, dtypes, unit quaternions, non-finite values,
external-force shapes, unknown methods, and a model without degrees of freedom.
"""

from __future__ import annotations

import functools
import re
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody.dynamics import mass_matrix_derivative

from dyn_helpers import STATUE_URDF, assert_rel, coordinate_tree_model, random_tree_model


@functools.lru_cache(maxsize=None)
def tree():
    """Free-flyer, revolute, continuous, prismatic, planar, spherical, translation joints."""
    return random_tree_model(0)


@functools.lru_cache(maxsize=None)
def coordinate_tree():
    return coordinate_tree_model(0)


# name -> (model factory, function(model, q, v, a, f), the array arguments it takes)
FUNCTIONS = {
    "mass_matrix": (tree, lambda m, q, v, a, f: mb.mass_matrix(m, q), ("q",)),
    "mass_matrix[lagrangian]": (tree, lambda m, q, v, a, f: mb.mass_matrix(m, q, method="lagrangian"), ("q",)),
    "coriolis_matrix": (tree, lambda m, q, v, a, f: mb.coriolis_matrix(m, q, v), ("q", "v")),
    "coriolis_matrix[lagrangian]": (coordinate_tree, lambda m, q, v, a, f: mb.coriolis_matrix(m, q, v, method="lagrangian"),
                                    ("q", "v")),
    "mass_matrix_derivative": (coordinate_tree, lambda m, q, v, a, f: mass_matrix_derivative(m, q), ("q",)),
    "generalized_gravity": (tree, lambda m, q, v, a, f: mb.generalized_gravity(m, q), ("q",)),
    "bias_forces": (tree, lambda m, q, v, a, f: mb.bias_forces(m, q, v), ("q", "v")),
    "inverse_dynamics": (tree, lambda m, q, v, a, f: mb.inverse_dynamics(m, q, v, a, f_ext=f), ("q", "v", "a", "f_ext")),
    "forward_dynamics": (tree, lambda m, q, v, a, f: mb.forward_dynamics(m, q, v, a, f_ext=f), ("q", "v", "tau", "f_ext")),
    "inverse_mass_matrix": (tree, lambda m, q, v, a, f: mb.inverse_mass_matrix(m, q), ("q",)),
    "kinetic_energy": (tree, lambda m, q, v, a, f: mb.kinetic_energy(m, q, v), ("q", "v")),
    "potential_energy": (tree, lambda m, q, v, a, f: mb.potential_energy(m, q), ("q",)),
}

# (function, argument) pairs over the vector arguments q, v, a/tau.
VECTOR_ARGS = [pytest.param(fn, arg, id=f"{fn}-{arg}") for fn, (_, _, args) in FUNCTIONS.items()
               for arg in args if arg != "f_ext"]


def valid_inputs(model, seed=0, batch=()):
    rng = np.random.default_rng(seed)
    return dict(
        q=model.random_configuration(rng, shape=batch),
        v=rng.standard_normal(batch + (model.nv,)),
        a=rng.standard_normal(batch + (model.nv,)),
        f_ext=rng.standard_normal(batch + (model.njoints, 6)),
    )


def call(name, **replace):
    """Call FUNCTIONS[name] on valid inputs with some of them replaced (``tau`` is the ``a`` slot)."""
    make_model, fn, _ = FUNCTIONS[name]
    model = make_model()
    inputs = valid_inputs(model)
    if "tau" in replace:
        replace["a"] = replace.pop("tau")
    inputs.update(replace)
    return fn(model, inputs["q"], inputs["v"], inputs["a"], inputs["f_ext"])


def arg_size(name, arg):
    model = FUNCTIONS[name][0]()
    return model.nq if arg == "q" else model.nv


def test_valid_inputs_work():
    """The baseline every failure case below perturbs: valid inputs give finite results, no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in FUNCTIONS:
            assert np.all(np.isfinite(call(name))), name


# ============================================================================= shapes

@pytest.mark.parametrize("name, arg", VECTOR_ARGS)
@pytest.mark.parametrize("bad", ["one_more", "one_less", "scalar", "transposed_batch"])
def test_wrong_shape_names_the_expected_shape(name, arg, bad):
    size = arg_size(name, arg)
    good = valid_inputs(FUNCTIONS[name][0](), batch=(2,))[arg if arg != "tau" else "a"]
    value = {
        "one_more": np.zeros(size + 1),
        "one_less": np.zeros(size - 1),
        "scalar": np.float64(0.5),
        "transposed_batch": good.T,  # (size, 2): batch axis last by mistake
    }[bad]
    with pytest.raises(ValueError, match=rf"^{arg} must have shape {re.escape(f'(..., {size})')}"):
        call(name, **{arg: value})


@pytest.mark.parametrize("name", ["coriolis_matrix", "inverse_dynamics", "forward_dynamics", "kinetic_energy"])
def test_incompatible_batch_shapes_raise(name):
    model = FUNCTIONS[name][0]()
    inputs = valid_inputs(model, batch=(3,))
    with pytest.raises(ValueError):
        call(name, q=inputs["q"], v=valid_inputs(model, batch=(2,))["v"])


# ============================================================================= dtypes

def _bad_dtype(kind, good):
    if kind == "strings":
        return np.array([str(x) for x in good.ravel()]).reshape(good.shape)
    if kind == "string_list":
        return [str(x) for x in good]
    if kind == "complex":
        return good.astype(complex)  # zero imaginary part: still refused, a complex q is a mistake
    if kind == "object":
        return np.array(list(good), dtype=object)
    if kind == "object_with_none":
        return [None] + list(good[1:])
    raise KeyError(kind)


@pytest.mark.parametrize("name, arg", VECTOR_ARGS)
@pytest.mark.parametrize("kind", ["strings", "string_list", "complex", "object", "object_with_none"])
def test_wrong_dtype_raises_value_error(name, arg, kind):
    model = FUNCTIONS[name][0]()
    good = valid_inputs(model)[arg if arg != "tau" else "a"]
    with pytest.raises(ValueError, match=rf"^{arg} must be (a )?real"):
        call(name, **{arg: _bad_dtype(kind, good)})


@pytest.mark.parametrize("name", ["inverse_dynamics", "forward_dynamics"])
def test_wrong_dtype_f_ext_raises(name):
    good = valid_inputs(tree())["f_ext"]
    for bad in (good.astype(complex), good.astype(str), good.astype(object)):
        with pytest.raises(ValueError, match=r"^f_ext must be (a )?real"):
            call(name, f_ext=bad)


@pytest.mark.parametrize("name", list(FUNCTIONS))
def test_lists_and_integer_arrays_are_accepted(name):
    """Plain lists and integer dtypes are real numbers: same results as float arrays."""
    model = FUNCTIONS[name][0]()
    inputs = valid_inputs(model)
    expected = call(name)
    as_lists = {k: x.tolist() for k, x in inputs.items()}
    np.testing.assert_array_equal(call(name, **as_lists), expected)
    integer_v = np.arange(model.nv) % 3 - 1
    np.testing.assert_array_equal(call(name, v=integer_v, a=integer_v),
                                  call(name, v=integer_v.astype(float), a=integer_v.astype(float)))


# ============================================================================= unit quaternions

def _unit_blocks(model):
    """(joint name, slice of q) of every quaternion and planar (cos θ, sin θ) pair."""
    out = []
    for joint, name, s in zip(model.joints, model.joint_names, model.idx_q):
        if isinstance(joint, jt.FreeFlyer):
            out.append((name, slice(s + 3, s + 7)))
        elif isinstance(joint, jt.Spherical):
            out.append((name, slice(s, s + 4)))
        elif isinstance(joint, jt.Planar):
            out.append((name, slice(s + 2, s + 4)))
    return out


Q_FUNCTIONS = [name for name, (make, _, _) in FUNCTIONS.items() if make is tree]


def test_tree_has_every_unit_norm_block():
    kinds = {type(tree().joints[tree().joint_names.index(name)]) for name, _ in _unit_blocks(tree())}
    assert kinds == {jt.FreeFlyer, jt.Spherical, jt.Planar}


@pytest.mark.parametrize("block", range(len(_unit_blocks(random_tree_model(0)))))
@pytest.mark.parametrize("name", Q_FUNCTIONS)
def test_non_unit_quaternion_beyond_tolerance_raises(name, block):
    model = tree()
    joint_name, sl = _unit_blocks(model)[block]
    q = valid_inputs(model, batch=(3,))["q"]
    q[1, sl] *= 1.0 + 3 * jt.UNIT_NORM_TOLERANCE  # one bad sample in a batch
    with pytest.raises(ValueError, match=re.escape(repr(joint_name))):
        call(name, q=q)
    with pytest.raises(ValueError, match=re.escape(repr(joint_name))):  # one state alone (its own check)
        call(name, q=q[1])
    q[1, sl] *= 0.5  # far inside the sphere too
    with pytest.raises(ValueError, match="unit norm"):
        call(name, q=q)
    with pytest.raises(ValueError, match="unit norm"):
        call(name, q=q[1])


@pytest.mark.parametrize("name", Q_FUNCTIONS)
def test_quaternion_within_tolerance_is_used_normalised(name):
    model = tree()
    inputs = valid_inputs(model, seed=3, batch=(2,))
    q = inputs["q"].copy()
    for k, (_, sl) in enumerate(_unit_blocks(model)):
        sign = 1.0 if k % 2 == 0 else -1.0
        q[:, sl] *= 1.0 + sign * 0.5 * jt.UNIT_NORM_TOLERANCE
    assert not np.allclose(q, model.normalize(q), rtol=0, atol=1e-8)
    out = call(name, **{**inputs, "q": q})
    ref = call(name, **{**inputs, "q": model.normalize(q)})
    # Off-unit inputs used as-is would change results by ~5e-7 relative; normalised, only rounding differs.
    assert_rel(out, ref, 1e-12, f"{name} with a slightly non-unit quaternion", batch_ndim=0)


# ============================================================================= NaN and inf

def _nan_position(model):
    """A coordinate that every output depends on: the first joint after the free-flyer base."""
    assert isinstance(model.joints[0], jt.FreeFlyer)
    return int(model.idx_q[1])


@pytest.mark.parametrize("name", list(FUNCTIONS))
def test_nan_in_q_warns_and_propagates(name):
    model = FUNCTIONS[name][0]()
    inputs = valid_inputs(model, batch=(3,))
    q = inputs["q"].copy()
    pos = _nan_position(model) if isinstance(model.joints[0], jt.FreeFlyer) else int(model.idx_q[1])
    q[1, pos] = np.nan
    with pytest.warns(RuntimeWarning, match="q contains NaN"):
        out = call(name, **{**inputs, "q": q})
    assert np.isnan(out[1]).any()
    # The other samples of the batch are unaffected.
    clean = call(name, **inputs)
    assert np.all(np.isfinite(out[[0, 2]]))
    np.testing.assert_allclose(out[[0, 2]], clean[[0, 2]], rtol=1e-13, atol=1e-13)


def test_nan_in_free_flyer_pose_warns_and_propagates():
    """A NaN base position warns and reaches the output, as docs/conventions.md promises, even for
    M(q), which does not depend on the base pose in exact arithmetic."""
    model = tree()
    q = valid_inputs(model)["q"]
    q[0] = np.nan
    with pytest.warns(RuntimeWarning, match="NaN"):
        M = mb.mass_matrix(model, q)
    assert np.isnan(M).any()
    with pytest.warns(RuntimeWarning, match="NaN"):
        assert np.isnan(mb.potential_energy(model, q))


V_FUNCTIONS = [pytest.param(fn, arg, id=f"{fn}-{arg}") for fn, (_, _, args) in FUNCTIONS.items()
               for arg in args if arg in ("v", "a", "tau", "f_ext")]


# NumPy's own "invalid value encountered" warnings (inf − inf, 0 · inf) are expected here.
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("value", [np.nan, np.inf], ids=["nan", "inf"])
@pytest.mark.parametrize("name, arg", V_FUNCTIONS)
def test_non_finite_velocity_like_inputs_warn_and_propagate(name, arg, value):
    model = FUNCTIONS[name][0]()
    key = "a" if arg == "tau" else arg
    x = valid_inputs(model, batch=(2,))[key].copy()
    x[1].flat[0] = value
    with pytest.warns(RuntimeWarning, match=f"{arg} contains NaN or infinite"):
        out = call(name, **{arg: x})
    assert not np.all(np.isfinite(out[1]))
    assert np.isnan(out[1]).any() or np.isinf(out[1]).any()
    assert np.all(np.isfinite(out[0]))


SINGLE_STATE_ARGS = [pytest.param(fn, arg, id=f"{fn}-{arg}") for fn, (_, _, args) in FUNCTIONS.items()
                     for arg in args if arg != "f_ext" and "[" not in fn]


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("value", [np.nan, np.inf], ids=["nan", "inf"])
@pytest.mark.parametrize("name, arg", SINGLE_STATE_ARGS)
def test_non_finite_entry_of_one_state_warns_and_propagates(name, arg, value):
    """One state, as a single call passes it (C-contiguous float64 vectors of the right sizes), with a
    non-finite entry outside the quaternions: the single call's path, which leaves the entries to the
    kernel's output, warns as the full checks do and returns the kernel's NaN."""
    model = FUNCTIONS[name][0]()
    key = "a" if arg == "tau" else arg
    x = valid_inputs(model)[key].copy()
    x[0] = value  # (in q: the free flyer's x position, outside its quaternion)
    with pytest.warns(RuntimeWarning, match=f"{arg} contains NaN or infinite"):
        out = call(name, **{arg: x})
    assert np.isnan(out).all()  # the kernels fill their whole output with NaN


@pytest.mark.parametrize("reference", ["world", "local", "local_world_aligned"])
def test_non_finite_configuration_of_one_jacobian_warns_and_propagates(reference):
    model = tree()
    q = valid_inputs(model)["q"]
    q[0] = np.nan
    with pytest.warns(RuntimeWarning, match="q contains NaN or infinite"):
        J = mb.jacobian(model, q, model.body_names[-1], reference=reference)
    assert np.isnan(J).all()


def test_body_names_of_numpy_strings_are_found():
    model = tree()
    assert model.body_index(np.str_(model.body_names[2])) == 2
    assert model.body_index(2) == 2 and model.body_index(-1) == model.nbodies - 1
    with pytest.raises(ValueError, match="unknown body"):
        model.body_index("no such body")


# ============================================================================= f_ext, methods

@pytest.mark.parametrize("name", ["inverse_dynamics", "forward_dynamics"])
@pytest.mark.parametrize("shape", ["with_universe", "three_components", "flat", "transposed"])
def test_wrong_f_ext_shape_raises(name, shape):
    nj = tree().njoints
    value = {
        "with_universe": np.zeros((nj + 1, 6)),  # Pinocchio's list has an entry for the universe; ours does not
        "three_components": np.zeros((nj, 3)),
        "flat": np.zeros(6 * nj),
        "transposed": np.zeros((6, nj)),
    }[shape]
    with pytest.raises(ValueError, match=re.escape(f"(..., {nj}, 6)")):
        call(name, f_ext=value)


@pytest.mark.parametrize("name", ["inverse_dynamics", "forward_dynamics"])
def test_f_ext_batch_must_broadcast(name):
    model = tree()
    inputs = valid_inputs(model, batch=(3,))
    with pytest.raises(ValueError):
        call(name, **{**inputs, "f_ext": np.zeros((2, model.njoints, 6))})
    # One force set broadcasts against a batch of states, like any other argument.
    f = valid_inputs(model, seed=5)["f_ext"]
    out = call(name, **{**inputs, "f_ext": f})
    expected = call(name, **{**inputs, "f_ext": np.broadcast_to(f, (3,) + f.shape)})
    np.testing.assert_allclose(out, expected, rtol=1e-13, atol=1e-13)


def test_zero_f_ext_equals_none():
    model = tree()
    inputs = valid_inputs(model, batch=(2,))
    zero = np.zeros((2, model.njoints, 6))
    for fn in (mb.inverse_dynamics, mb.forward_dynamics):
        # Equal up to rounding (the two paths broadcast differently).
        assert_rel(fn(model, inputs["q"], inputs["v"], inputs["a"], f_ext=zero),
                   fn(model, inputs["q"], inputs["v"], inputs["a"]), 1e-13, fn.__name__)


@pytest.mark.parametrize("method", ["foo", "CRBA", "aba", "", None])
def test_unknown_mass_matrix_method(method):
    model = tree()
    with pytest.raises(ValueError, match="crba"):
        mb.mass_matrix(model, model.neutral(), method=method)


@pytest.mark.parametrize("method", ["foo", "Recursive", "christoffel", "crba", None])
def test_unknown_coriolis_method(method):
    model = tree()
    with pytest.raises(ValueError, match="recursive"):
        mb.coriolis_matrix(model, model.neutral(), np.zeros(model.nv), method=method)


# ============================================================================= no degrees of freedom

@pytest.mark.parametrize("batch", [(), (3,), (2, 4)], ids=["single", "3", "2x4"])
def test_zero_dof_model(batch):
    model = mb.load_urdf(STATUE_URDF)
    assert (model.nq, model.nv, model.njoints) == (0, 0, 0)
    assert len(model.body_names) == 3
    q = np.zeros(batch + (0,))
    v = np.zeros(batch + (0,))
    f = np.zeros(batch + (0, 6))
    matrices = {
        "mass_matrix": mb.mass_matrix(model, q),
        "mass_matrix[lagrangian]": mb.mass_matrix(model, q, method="lagrangian"),
        "coriolis_matrix": mb.coriolis_matrix(model, q, v),
        "coriolis_matrix[lagrangian]": mb.coriolis_matrix(model, q, v, method="lagrangian"),
        "inverse_mass_matrix": mb.inverse_mass_matrix(model, q),
    }
    vectors = {
        "generalized_gravity": mb.generalized_gravity(model, q),
        "bias_forces": mb.bias_forces(model, q, v),
        "inverse_dynamics": mb.inverse_dynamics(model, q, v, v),
        "inverse_dynamics[f_ext]": mb.inverse_dynamics(model, q, v, v, f_ext=f),
        "forward_dynamics": mb.forward_dynamics(model, q, v, v),
        "forward_dynamics[f_ext]": mb.forward_dynamics(model, q, v, v, f_ext=f),
    }
    for what, x in matrices.items():
        assert x.shape == batch + (0, 0), what
    for what, x in vectors.items():
        assert x.shape == batch + (0,), what
    assert mass_matrix_derivative(model, q).shape == batch + (0, 0, 0)
    T, U = mb.kinetic_energy(model, q, v), mb.potential_energy(model, q)
    assert np.shape(T) == batch and np.shape(U) == batch
    # Nothing moves: no kinetic energy, and bodies fixed to the world carry no (constant) potential.
    np.testing.assert_array_equal(T, np.zeros(batch))
    np.testing.assert_array_equal(U, np.zeros(batch))
    with pytest.raises(ValueError, match=re.escape("(..., 0)")):
        mb.mass_matrix(model, np.zeros(1))


@pytest.mark.parametrize("ghost", [mb.joints.Revolute([0, 0, 1]), mb.joints.Spherical()])
def test_singular_mass_matrix_names_the_massless_joint(ghost):
    builder = mb.ModelBuilder("massless_leaf")
    builder.add_body("arm", joint=mb.joints.Revolute([0, 0, 1]), inertia=mb.inertia.box(1.0, (1, 0.1, 0.1)))
    builder.add_body("ghost", parent="arm", joint=ghost, joint_name="ghost_joint")
    model = builder.build()
    q, v = model.neutral(), np.zeros(model.nv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # reported as an error, not as NaN with a warning
        with pytest.raises(np.linalg.LinAlgError, match="ghost_joint"):
            mb.forward_dynamics(model, q, v, v)
        with pytest.raises(np.linalg.LinAlgError, match="ghost_joint"):
            mb.inverse_mass_matrix(model, q)


def test_nan_warns_once_per_call():
    model = mb.robots.load("double_pendulum")
    with pytest.warns(RuntimeWarning) as record:
        mb.generalized_gravity(model, np.array([np.nan, 0.0]))
    assert len(record) == 1
    with pytest.warns(RuntimeWarning) as record:
        mb.bias_forces(model, np.zeros(2), np.array([np.nan, 0.0]))
    assert len(record) == 1
    for q, v in [(np.zeros(2), np.array([np.nan, 0.0])), (np.array([np.nan, 0.0]), np.zeros(2)),
                 (np.zeros((3, 2)), np.array([[np.nan, 0.0]] * 3))]:
        with pytest.warns(RuntimeWarning) as record:
            a = mb.forward_dynamics(model, q, v, np.zeros(2))
        assert len(record) == 1 and np.isnan(a).all()


# ============================================================================= finite inputs that overflow

HUGE_V = 1e160  # v² overflows float64 (1.8e308); v alone does not

# name -> function(model, q, v) of every public function whose result has velocity-product terms
VELOCITY_PRODUCTS = {
    "inverse_dynamics": lambda m, q, v: mb.inverse_dynamics(m, q, v, np.zeros_like(v)),
    "bias_forces": mb.bias_forces,
    "joint_reaction_forces": lambda m, q, v: mb.joint_reaction_forces(m, q, v, np.zeros_like(v)),
    "forward_dynamics": lambda m, q, v: mb.forward_dynamics(m, q, v, np.zeros_like(v)),
    "kinetic_energy": mb.kinetic_energy,
    "mass_matrix_and_bias": mb.dynamics.mass_matrix_and_bias,
    "inverse_dynamics_derivatives": lambda m, q, v: mb.inverse_dynamics_derivatives(m, q, v, np.zeros_like(v)),
    "forward_dynamics_derivatives": lambda m, q, v: mb.forward_dynamics_derivatives(m, q, v, np.zeros_like(v)),
}


def _hostile_state(batch, states=((),), scale=HUGE_V):
    """Valid ``q, v`` of ``tree()`` with ``batch`` axes, ``v`` of the ``states`` scaled by ``scale``."""
    inputs = valid_inputs(tree(), seed=5, batch=batch)
    q, v = inputs["q"], inputs["v"]
    for state in states:
        v[state] *= scale
    return q, v


@pytest.mark.parametrize("name", list(VELOCITY_PRODUCTS))
def test_overflowing_velocities_raise_naming_v(name):
    """v of 1e160: the velocity products overflow, and the error says so (no NaN, no singular mass matrix)."""
    q, v = _hostile_state(())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FloatingPointError, match=r"overflowed float64: v has entries up to \d\.\d+e\+160; "
                                                     r"the velocity-product terms overflow float64$") as error:
            VELOCITY_PRODUCTS[name](tree(), q, v)
    assert "singular" not in str(error.value)


@pytest.mark.parametrize("name", list(VELOCITY_PRODUCTS))
def test_overflowing_velocities_of_a_batch_name_the_state(name):
    q, v = _hostile_state((2, 3), states=((1, 2), (1, 0)))  # in C order (1, 0) comes first
    with pytest.raises(FloatingPointError, match=re.escape("at state (1, 0) of the batch (the first of 2 states): v "
                                                           "has entries up to")):
        VELOCITY_PRODUCTS[name](tree(), q, v)
    q, v = _hostile_state((2, 3), states=((0, 1),))
    with pytest.raises(FloatingPointError, match=re.escape("at state (0, 1) of the batch: v has entries up to")):
        VELOCITY_PRODUCTS[name](tree(), q, v)


@pytest.mark.parametrize("batch", [(), (3,)], ids=["one", "batch"])
def test_coriolis_matrix_of_huge_velocities_is_linear_until_it_overflows(batch):
    """``C(q, v)`` is linear in ``v``: 1e160 velocities give 1e160 times ``C`` of the unscaled ones; at
    1e307 the products with the inertias overflow, and the error names ``v``."""
    q, v = _hostile_state(batch, scale=1.0)
    C = mb.coriolis_matrix(tree(), q, v)
    huge = mb.coriolis_matrix(tree(), q, HUGE_V * v)
    assert np.all(np.isfinite(huge))
    assert_rel(huge / HUGE_V, C, 1e-13, "C(1e160 v) / 1e160", batch_ndim=len(batch))
    with pytest.raises(FloatingPointError, match="v has entries up to .*e\\+307; the velocity-product terms overflow"):
        mb.coriolis_matrix(tree(), q, 1e307 * v)


@pytest.mark.parametrize("batch", [(), (3,)], ids=["one", "batch"])
def test_huge_torques_and_accelerations_are_no_overflow(batch):
    """τ of 1e160 and accelerations of 1e200 stay within float64 through the linear terms ``M⁻¹ τ`` and
    ``M a``: the results are those, finite (the bias forces of ordinary velocities vanish beside them)."""
    model = tree()
    inputs = valid_inputs(model, seed=6, batch=batch)
    q, v, unit = inputs["q"], inputs["v"], inputs["a"]
    M_unit = np.einsum("...ij,...j->...i", mb.mass_matrix(model, q), unit)
    a = mb.forward_dynamics(model, q, v, 1e160 * unit)
    assert np.all(np.isfinite(a))
    # (ABA's accelerations carry cond(M) ≈ 4e3 times the rounding)
    assert_rel(np.einsum("...ij,...j->...i", mb.mass_matrix(model, q), a) / 1e160, unit, 1e-11, "M a / 1e160",
               batch_ndim=len(batch))
    tau = mb.inverse_dynamics(model, q, v, 1e200 * unit)
    assert np.all(np.isfinite(tau))
    assert_rel(tau / 1e200, M_unit, 1e-13, "τ / 1e200", batch_ndim=len(batch))


@pytest.mark.parametrize("name, arg", [("forward_dynamics", "tau"), ("inverse_dynamics", "a"),
                                       ("inverse_dynamics", "f_ext")])
@pytest.mark.parametrize("batch", [(), (2,)], ids=["one", "batch"])
def test_a_linear_term_that_overflows_names_its_input(name, arg, batch):
    """1e308 in τ (``M⁻¹ τ``), a (``M a``) or f_ext (``Jᵀ f``) overflows; the error names that input,
    not the velocities beside it."""
    model = tree()
    inputs = valid_inputs(model, seed=7, batch=batch)
    q, v, a, f_ext = inputs["q"], 1e50 * inputs["v"], inputs["a"], None  # v large, though v² stays finite
    if arg == "f_ext":
        f_ext = np.full_like(inputs["f_ext"], 1e308)
    else:
        a = np.full_like(a, 1e308)
    function = {"forward_dynamics": lambda: mb.forward_dynamics(model, q, v, a),
                "inverse_dynamics": lambda: mb.inverse_dynamics(model, q, v, a, f_ext=f_ext)}[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (the input check's sum of 1e308s overflows too, and says nothing)
        with pytest.raises(FloatingPointError, match=rf"{arg} has entries up to 1e\+308; the .* overflow float64$"):
            function()


def _far_prismatic(batch, distance):
    """A configuration of ``tree()`` whose first prismatic joint is ``distance`` (m) out."""
    model = tree()
    q = valid_inputs(model, seed=8, batch=batch)["q"]
    start = next(s for joint, s in zip(model.joints, model.idx_q) if isinstance(joint, jt.Prismatic))
    q[..., start] = distance
    return model, q


@pytest.mark.parametrize("name, distance", [("mass_matrix", 1e160), ("inverse_mass_matrix", 1e160),
                                            ("forward_dynamics", 1e160), ("generalized_gravity", 1.7e308),
                                            ("potential_energy", 1.7e308)])
@pytest.mark.parametrize("batch", [(), (2,)], ids=["one", "batch"])
def test_a_configuration_far_out_overflows_and_names_q(name, distance, batch):
    """A prismatic joint far out: the inertias about the joints above (m p², beyond 1e154 m) or the
    gravity moments (m g p, near float64's largest number) overflow; the error names q, and the mass
    matrix is not called singular."""
    model, q = _far_prismatic(batch, distance)
    zero = np.zeros(batch + (model.nv,))
    function = {"mass_matrix": lambda: mb.mass_matrix(model, q),
                "inverse_mass_matrix": lambda: mb.inverse_mass_matrix(model, q),
                "forward_dynamics": lambda: mb.forward_dynamics(model, q, zero, zero),
                "generalized_gravity": lambda: mb.generalized_gravity(model, q),
                "potential_energy": lambda: mb.potential_energy(model, q)}[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FloatingPointError, match=re.escape(f"q has entries up to {distance:.3g}; the terms of the "
                                                               "bodies' positions (moments, inertias about the joints)")):
            function()


def test_a_model_too_heavy_for_float64_is_no_singular_mass_matrix():
    """Ordinary inputs on a model whose own numbers overflow (1e306 kg at 100 m): the error says that no
    input explains it, and forward dynamics does not call the mass matrix singular."""
    builder = mb.ModelBuilder("heavy")
    builder.add_body("arm", joint=jt.Revolute([0, 0, 1]), inertia=mb.inertia.point_mass(1e306, (100.0, 0, 0)))
    model = builder.build()
    q, one = np.zeros(1), np.ones(1)
    for function in (lambda: mb.mass_matrix(model, q), lambda: mb.forward_dynamics(model, q, one, one),
                     lambda: mb.inverse_mass_matrix(model, q[None])):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # the compiled tree's own overflow of m c²
            with pytest.raises(FloatingPointError, match="no input's size explains it .*: the model's masses, "
                                                         "inertias or lengths are too large for float64"):
                function()
