"""The array contract of every public batched function (docs/api.md, "Array arguments"), as one property.

Accepted, with the same result as float64 C-contiguous input: lists, integer arrays, non-contiguous
views, Fortran order, read-only arrays, float32 (computed in float64), any number of leading batch
axes, one argument without batch axes next to batched ones, and an empty batch, which gives an
empty result. Refused with ``ValueError`` or ``TypeError`` naming the argument: a wrong last axis,
batches that do not broadcast, complex numbers, strings, ``None`` and object arrays.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import multibody as mb

from conftest import random_tree_model

MODEL = random_tree_model(3, n_extra=2)
BODY = MODEL.body_names[-1]

# name -> (function of keyword arrays, its arguments in order)
FUNCTIONS = {
    "mass_matrix": (lambda q: mb.mass_matrix(MODEL, q), ("q",)),
    "coriolis_matrix": (lambda q, v: mb.coriolis_matrix(MODEL, q, v), ("q", "v")),
    "generalized_gravity": (lambda q: mb.generalized_gravity(MODEL, q), ("q",)),
    "bias_forces": (lambda q, v: mb.bias_forces(MODEL, q, v), ("q", "v")),
    "inverse_dynamics": (lambda q, v, a, f_ext: mb.inverse_dynamics(MODEL, q, v, a, f_ext=f_ext), ("q", "v", "a", "f_ext")),
    "forward_dynamics": (lambda q, v, tau, f_ext: mb.forward_dynamics(MODEL, q, v, tau, f_ext=f_ext),
                         ("q", "v", "tau", "f_ext")),
    "joint_reaction_forces": (lambda q, v, a: mb.joint_reaction_forces(MODEL, q, v, a), ("q", "v", "a")),
    "inverse_mass_matrix": (lambda q: mb.inverse_mass_matrix(MODEL, q), ("q",)),
    "kinetic_energy": (lambda q, v: mb.kinetic_energy(MODEL, q, v), ("q", "v")),
    "potential_energy": (lambda q: mb.potential_energy(MODEL, q), ("q",)),
    "forward_kinematics": (lambda q: mb.forward_kinematics(MODEL, q), ("q",)),
    "jacobian": (lambda q, point: mb.jacobian(MODEL, q, BODY, point), ("q", "point")),
    "jacobian_time_variation": (lambda q, v, point: mb.jacobian_time_variation(MODEL, q, v, BODY, point),
                                ("q", "v", "point")),
    "integrate": (lambda q, v: MODEL.integrate(q, v), ("q", "v")),
    "difference": (lambda q, q1: MODEL.difference(q, q1), ("q", "q1")),
    "configuration_rate": (lambda q, v: MODEL.configuration_rate(q, v), ("q", "v")),
    # the derivatives' tuples stacked on an axis after the batch axes
    "inverse_dynamics_derivatives": (
        lambda q, v, a, f_ext: np.stack(mb.inverse_dynamics_derivatives(MODEL, q, v, a, f_ext=f_ext), axis=-3),
        ("q", "v", "a", "f_ext")),
    "forward_dynamics_derivatives": (
        lambda q, v, tau, f_ext: np.stack(mb.forward_dynamics_derivatives(MODEL, q, v, tau, f_ext=f_ext), axis=-3),
        ("q", "v", "tau", "f_ext")),
    "gravity_derivatives": (lambda q: mb.gravity_derivatives(MODEL, q), ("q",)),
    # the linearization's [A | B] (it refuses non-finite states, as simulate does)
    "linearize": (lambda q, v, tau: (lambda lin: np.concatenate([lin.A, lin.B], axis=-1))(mb.linearize(MODEL, q, v, tau)),
                  ("q", "v", "tau")),
}

FORMS = ["list", "integer", "strided", "fortran", "read-only", "float32", "unbatched"]


def arguments(batch, rng):
    """Valid float64 C-contiguous arguments with leading axes ``batch``."""
    return {
        "q": MODEL.random_configuration(rng, shape=batch),
        "q1": MODEL.random_configuration(rng, shape=batch),
        "v": rng.standard_normal(batch + (MODEL.nv,)),
        "a": rng.standard_normal(batch + (MODEL.nv,)),
        "tau": rng.standard_normal(batch + (MODEL.nv,)),
        "f_ext": rng.standard_normal(batch + (MODEL.njoints, 6)),
        "point": rng.standard_normal(batch + (3,)),
    }


def transformed(form, x, name):
    """``(x in the form, the float64 array it stands for)``, or ``None`` when the form does not apply."""
    if form == "list":
        return x.tolist(), x
    if form == "integer":
        if name in ("q", "q1"):
            return None  # integer values are not on the configuration manifold
        whole = np.round(3 * x).astype(np.int64)
        return whole, whole.astype(float)
    if form == "strided":
        wide = np.zeros(x.shape[:-1] + (2 * x.shape[-1],))
        wide[..., ::2] = x
        return wide[..., ::2], x
    if form == "fortran":
        return np.asfortranarray(x), x
    if form == "read-only":
        frozen = x.copy()
        frozen.setflags(write=False)
        return frozen, x
    if form == "float32":
        if name in ("q", "q1"):
            return None  # float32 rounding leaves the unit sphere by more than the tolerance
        single = x.astype(np.float32)
        return single, single.astype(float)
    if form == "unbatched":
        core = 2 if name == "f_ext" else 1
        one = x[(0,) * (x.ndim - core)]
        return one, np.broadcast_to(one, x.shape).copy()
    raise AssertionError(form)


@given(name=st.sampled_from(sorted(FUNCTIONS)), form=st.sampled_from(FORMS), which=st.integers(0, 3),
       batch=st.sampled_from([(), (1,), (3,), (2, 3)]), seed=st.integers(0, 2**31 - 1))
def test_every_accepted_array_form_gives_the_float64_result(name, form, which, batch, seed):
    function, names = FUNCTIONS[name]
    values = arguments(batch, np.random.default_rng(seed))
    args = {n: values[n] for n in names}
    target = names[which % len(names)]
    pair = transformed(form, args[target], target)
    if pair is None or (form in ("unbatched", "fortran") and not batch) or (form == "unbatched" and len(names) == 1):
        return
    given_form, meaning = pair
    expected = function(**{**args, target: meaning})
    result = function(**{**args, target: given_form})
    assert np.shape(result) == np.shape(expected)
    np.testing.assert_array_equal(result, expected)


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_an_empty_batch_gives_an_empty_result(name):
    function, names = FUNCTIONS[name]
    single = function(**{n: x for n, x in arguments((), np.random.default_rng(0)).items() if n in names})
    empty = {n: np.zeros((0,) + x.shape) for n, x in arguments((), np.random.default_rng(0)).items() if n in names}
    result = function(**empty)
    assert np.shape(result) == (0,) + np.shape(single)


BAD = {
    "wrong last axis": lambda x: np.zeros(x.shape[:-1] + (x.shape[-1] + 1,)),
    "complex": lambda x: x.astype(complex),
    "string": lambda x: "abc",
    "None": lambda x: None,
    "object array": lambda x: np.array([object()] * x.shape[-1]),
}


@pytest.mark.parametrize("bad", sorted(BAD))
@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_refused_input_names_the_argument(name, bad):
    function, names = FUNCTIONS[name]
    values = arguments((), np.random.default_rng(1))
    for target in names:
        if bad == "None" and (target in ("point", "f_ext") or (name, target) == ("linearize", "tau")):
            continue  # None is a valid value there: the body origin, no external force, no joint forces
        args = {n: values[n] for n in names}
        args[target] = BAD[bad](args[target])
        with pytest.raises((ValueError, TypeError), match=target):
            function(**args)


@pytest.mark.parametrize("name", [n for n in sorted(FUNCTIONS) if len(FUNCTIONS[n][1]) > 1])
def test_batches_that_do_not_broadcast_are_refused(name):
    function, names = FUNCTIONS[name]
    two, three = arguments((2,), np.random.default_rng(2)), arguments((3,), np.random.default_rng(3))
    args = {n: (two if k == 0 else three)[n] for k, n in enumerate(names)}
    with pytest.raises(ValueError, match="broadcast"):
        function(**args)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the non-finite input's warning, by design
@given(name=st.sampled_from(sorted(FUNCTIONS)), which=st.integers(0, 3), value=st.sampled_from([np.nan, np.inf, -np.inf]),
       entry=st.integers(0, 100), seed=st.integers(0, 2**31 - 1))
def test_a_non_finite_input_never_gives_a_finite_answer(name, which, value, entry, seed):
    """NaN or ±inf anywhere in one state's input: that state's result is NaN throughout (the kernels'
    rule), or the call raises ``ValueError``; the other state of the batch is unaffected."""
    function, names = FUNCTIONS[name]
    args = {n: x for n, x in arguments((2,), np.random.default_rng(seed)).items() if n in names}
    target = names[which % len(names)]
    bad = args[target].copy()
    bad[1].flat[entry % bad[1].size] = value
    try:
        result = function(**{**args, target: bad})
    except ValueError:
        return
    clean = function(**args)
    assert np.isnan(result[1]).all()
    np.testing.assert_array_equal(result[0], clean[0])


# ============================================================================= out=

# name -> (function of keyword arrays and out, its arguments): every function that takes out=
OUT_FUNCTIONS = {
    "mass_matrix": (lambda q, out: mb.mass_matrix(MODEL, q, out=out), ("q",)),
    "mass_matrix[lagrangian]": (lambda q, out: mb.mass_matrix(MODEL, q, method="lagrangian", out=out), ("q",)),
    "coriolis_matrix": (lambda q, v, out: mb.coriolis_matrix(MODEL, q, v, out=out), ("q", "v")),
    "generalized_gravity": (lambda q, out: mb.generalized_gravity(MODEL, q, out=out), ("q",)),
    "bias_forces": (lambda q, v, out: mb.bias_forces(MODEL, q, v, out=out), ("q", "v")),
    "inverse_dynamics": (lambda q, v, a, f_ext, out: mb.inverse_dynamics(MODEL, q, v, a, f_ext=f_ext, out=out),
                         ("q", "v", "a", "f_ext")),
    "forward_dynamics": (lambda q, v, tau, f_ext, out: mb.forward_dynamics(MODEL, q, v, tau, f_ext=f_ext, out=out),
                         ("q", "v", "tau", "f_ext")),
    "joint_reaction_forces": (lambda q, v, a, out: mb.joint_reaction_forces(MODEL, q, v, a, out=out), ("q", "v", "a")),
    "inverse_mass_matrix": (lambda q, out: mb.inverse_mass_matrix(MODEL, q, out=out), ("q",)),
    "kinetic_energy": (lambda q, v, out: mb.kinetic_energy(MODEL, q, v, out=out), ("q", "v")),
    "potential_energy": (lambda q, out: mb.potential_energy(MODEL, q, out=out), ("q",)),
    "forward_kinematics": (lambda q, out: mb.forward_kinematics(MODEL, q, out=out), ("q",)),
    "frame_placement": (lambda q, out: mb.frame_placement(MODEL, q, BODY, out=out), ("q",)),
    "jacobian": (lambda q, point, out: mb.jacobian(MODEL, q, BODY, point, out=out), ("q", "point")),
    "jacobian_time_variation": (lambda q, v, point, out: mb.jacobian_time_variation(MODEL, q, v, BODY, point, out=out),
                                ("q", "v", "point")),
    "center_of_mass_jacobian": (lambda q, out: mb.center_of_mass_jacobian(MODEL, q, out=out), ("q",)),
    "centroidal_momentum_matrix": (lambda q, out: mb.centroidal_momentum_matrix(MODEL, q, out=out), ("q",)),
    "centroidal_momentum": (lambda q, v, out: mb.centroidal_momentum(MODEL, q, v, out=out), ("q", "v")),
    "centroidal_momentum_matrix_derivative": (
        lambda q, v, out: mb.centroidal_momentum_matrix_derivative(MODEL, q, v, out=out), ("q", "v")),
}


def _out_call(name, batch, seed=0):
    """``(function of out, the result without out)`` of OUT_FUNCTIONS[name] on valid arguments of ``batch``."""
    function, names = OUT_FUNCTIONS[name]
    args = {n: x for n, x in arguments(batch, np.random.default_rng(seed)).items() if n in names}
    return (lambda out: function(**args, out=out)), function(**args, out=None)


@pytest.mark.parametrize("batch", [(), (1,), (3,), (2, 3)])
@pytest.mark.parametrize("name", sorted(OUT_FUNCTIONS))
def test_out_receives_the_result_and_is_returned(name, batch):
    call, expected = _out_call(name, batch)
    out = np.full(np.shape(expected), np.nan)
    assert call(out) is out
    np.testing.assert_array_equal(out, expected)


def _read_only(shape):
    x = np.empty(shape)
    x.setflags(write=False)
    return x


#: out arrays that cannot receive a result of shape ``shape``, and what the error says they are
BAD_OUT = {
    "shape": (lambda shape: np.empty((4,) + shape), lambda shape: f"a float64 array of shape {(4,) + shape}"),
    "float32": (lambda shape: np.empty(shape, np.float32), lambda shape: f"a float32 array of shape {shape}"),
    "not C-contiguous": (lambda shape: np.empty(shape + (2,))[..., 0],
                         lambda shape: f"a not C-contiguous float64 array of shape {shape}"),
    "read-only": (_read_only, lambda shape: f"a read-only float64 array of shape {shape}"),
    "list": (lambda shape: np.empty(shape).tolist(), lambda shape: "list"),
}


@pytest.mark.parametrize("bad", sorted(BAD_OUT))
@pytest.mark.parametrize("name", sorted(OUT_FUNCTIONS))
def test_out_that_cannot_receive_the_result_is_refused(name, bad):
    """ValueError naming the shape expected and what was given."""
    call, expected = _out_call(name, (3,))
    make, got = BAD_OUT[bad]
    with pytest.raises(ValueError, match=f"^out must be .*{re.escape(str(expected.shape))}.*, got {re.escape(got(expected.shape))}$"):
        call(make(expected.shape))


@pytest.mark.parametrize("batch", [(), (3,)])
def test_out_may_be_an_input(batch):
    """An out that is also an input (τ into the buffer of v) gives the result of separate arrays."""
    values = arguments(batch, np.random.default_rng(4))
    q, v, a = values["q"], values["v"], values["a"]
    expected = mb.inverse_dynamics(MODEL, q, v, a)
    assert mb.inverse_dynamics(MODEL, q, v, a, out=v) is v
    np.testing.assert_array_equal(v, expected)
