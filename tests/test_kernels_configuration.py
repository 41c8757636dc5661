"""The configuration-space kernels (:mod:`multibody.kernels.configuration`) called directly, one state
at a time, against a NumPy reference (the per-joint maps on :mod:`multibody.spatial` that
:class:`multibody.Model` used before it ran these kernels; reproduced to rounding) and against
Pinocchio's ``integrate`` and ``difference``; and :class:`multibody.Model`'s maps, which run the kernels
through the batch driver, against direct kernel calls state by state.

Models: the random trees with every joint kind (free flyer, spherical, planar, translation, revolute
and prismatic about random axes, continuous), Solo12 and Talos on a free flyer, Panda fixed. Rotation
vectors are also taken small (``|ω|`` from 1e-3 down to 1e-9 and exactly 0, across the 1e-4 and 1e-2
switches to series) and near π. Error measure: ``max|ours − ref| / max(1, max|ref|)``.
"""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody import spatial as sp
from multibody.kernels import configuration as cfg
from multibody.tree import compile_tree

from conftest import erd_urdf, pinocchio_twin, q_from_pinocchio, q_to_pinocchio, random_tree_model

#: Agreement with the NumPy reference: the same formulas, summed in other orders
TOL = 1e-14
#: Agreement with Pinocchio (other formulas, e.g. its SE(3) log from the rotation matrix's trace)
PIN_TOL = 1e-12
N_STATES = 10

URDFS = {
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos": ("talos_data/robots/talos_reduced.urdf", True),
    "panda": ("panda_description/urdf/panda.urdf", False),
}
MODELS = ["random_tree_0", "random_tree_1", "random_tree_2", *URDFS]

_EMPTY = np.zeros(0)


def load_model(name):
    if name.startswith("random_tree_"):
        return random_tree_model(int(name.rsplit("_", 1)[1]))
    path, floating = URDFS[name]
    return mb.load_urdf(erd_urdf(path), floating_base=floating)


_CASES = {}


def case(name):
    """``(model, compiled tree)``, built once per session."""
    if name not in _CASES:
        model = load_model(name)
        _CASES[name] = model, compile_tree(model)
    return _CASES[name]


def call(kernel, tree, x0, x1=_EMPTY, shape=None):
    """One direct kernel call; ``out`` starts as NaN so that an entry left unwritten shows."""
    out = np.full(shape, np.nan)
    kernel(tree.joints, tree.reals, tree.bodies, np.ascontiguousarray(x0, dtype=float),
           np.ascontiguousarray(x1, dtype=float), _EMPTY, _EMPTY, out, np.empty(cfg.workspace_size(tree.njoints, tree.nv)))
    return out


def rel(ours, ref):
    ours, ref = np.asarray(ours), np.asarray(ref)
    assert ours.shape == ref.shape
    return np.abs(ours - ref).max(initial=0.0) / max(1.0, np.abs(ref).max(initial=0.0))


def assert_close(ours, ref, tol, what):
    err = rel(ours, ref)
    assert err <= tol, f"{what}: relative error {err:.3e} > {tol:.1e}"
    return err


def rotation_blocks(model):
    """``(q slice, v slice)`` of the quaternion and rotation vector of every spherical and free-flyer
    joint, and ``(None, v index)`` of every planar angle."""
    blocks = []
    for joint, iq, iv in zip(model.joints, model.idx_q, model.idx_v):
        if isinstance(joint, jt.Spherical):
            blocks.append((slice(iq, iq + 4), slice(iv, iv + 3)))
        elif isinstance(joint, jt.FreeFlyer):
            blocks.append((slice(iq + 3, iq + 7), slice(iv + 3, iv + 6)))
        elif isinstance(joint, jt.Planar):
            blocks.append((None, slice(iv + 2, iv + 3)))
    return blocks


def with_rotation_angle(model, v, angle, rng, planar=True):
    """``v`` with every rotation vector (and planar angle, if ``planar``) set to magnitude ``angle`` in a
    random direction."""
    v = v.copy()
    for q_block, s in rotation_blocks(model):
        if q_block is None and not planar:
            continue
        direction = rng.standard_normal(s.stop - s.start)
        v[s] = angle * direction / np.linalg.norm(direction)
    return v


def states(model, seed, angle=None, planar=True):
    """``N_STATES`` random ``(q, v)``; rotation vectors of magnitude ``angle`` when given (planar angles too
    if ``planar``)."""
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q = model.random_configuration(rng)
        v = rng.standard_normal(model.nv)
        yield q, (v if angle is None else with_rotation_angle(model, v, angle, rng, planar))


# ----------------------------------------------------------------------------- NumPy reference

def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _se2_v(theta):
    """``(a, b)`` of the SE(2) ``V(θ)``: ``sin θ/θ``, ``(1 − cos θ)/θ = 2 sin²(θ/2)/θ``; series below 1e-4."""
    small = np.abs(theta) < 1e-4
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 * theta - theta**3 / 24.0, 2.0 * np.sin(0.5 * t) ** 2 / t)
    return a, b


def _turned(quat, delta):
    """``exp(δ) ⊗ quat``, unit."""
    return _unit(sp.quat_multiply(sp.quat_exp(delta), quat))


def _planar_integrate(q, v):
    c0, s0 = _unit(q[2:4])
    theta = v[2]
    a, b = _se2_v(theta)
    dx, dy = a * v[0] - b * v[1], b * v[0] + a * v[1]
    c1, s1 = np.cos(theta), np.sin(theta)
    return np.array([q[0] + c0 * dx - s0 * dy, q[1] + s0 * dx + c0 * dy, c0 * c1 - s0 * s1, s0 * c1 + c0 * s1])


def _planar_difference(q0, q1):
    (c0, s0), (c1, s1) = _unit(q0[2:4]), _unit(q1[2:4])
    theta = np.arctan2(c0 * s1 - s0 * c1, c0 * c1 + s0 * s1)
    ex, ey = q1[0] - q0[0], q1[1] - q0[1]
    dx, dy = c0 * ex + s0 * ey, -s0 * ex + c0 * ey
    a, b = _se2_v(theta)
    det = a * a + b * b
    return np.array([(a * dx + b * dy) / det, (-b * dx + a * dy) / det, theta])


def _planar_chart(q0, delta):
    c0, s0 = _unit(q0[2:4])
    c, s = np.cos(delta[2]), np.sin(delta[2])
    return np.array([q0[0] + delta[0], q0[1] + delta[1], c * c0 - s * s0, s * c0 + c * s0])


def _free_flyer_integrate(q, v):
    _, dp = sp.se3_exp(v)
    return np.concatenate([q[:3] + sp.quat_to_rotation(q[3:]) @ dp, _unit(sp.quat_multiply(q[3:], sp.quat_exp(v[3:])))])


def _free_flyer_difference(q0, q1):
    R0, R1 = sp.quat_to_rotation(q0[3:]), sp.quat_to_rotation(q1[3:])
    return sp.se3_log(*sp.compose(*sp.inverse_pose(R0, q0[:3]), R1, q1[:3]))


def _rotation_blocks(R, n):
    T = np.zeros((n, n))
    for k in range(0, n, 3):
        T[k : k + 3, k : k + 3] = R
    return T


#: Per joint class: the maps of one joint's blocks (``None``: the vector-space default)
_REFERENCE = {
    jt.Planar: dict(
        integrate=_planar_integrate,
        difference=_planar_difference,
        configuration_rate=lambda q, v: np.array([q[2] * v[0] - q[3] * v[1], q[3] * v[0] + q[2] * v[1],
                                                  -q[3] * v[2], q[2] * v[2]]),
        chart=_planar_chart,
        chart_rate=lambda d, w: w,
        velocity_alignment=lambda q: np.array([[q[2], -q[3], 0.0], [q[3], q[2], 0.0], [0.0, 0.0, 1.0]]),
        velocity_coupling=lambda v: np.array([-v[2] * v[1], v[2] * v[0], 0.0]),
        chart_magnitude=lambda q: np.array([abs(q[0]), abs(q[1]), 1.0]),
        normalize=lambda q: np.concatenate([q[:2], _unit(q[2:4])]),
    ),
    jt.Spherical: dict(
        integrate=lambda q, v: _unit(sp.quat_multiply(q, sp.quat_exp(v))),
        difference=lambda q0, q1: sp.quat_log(sp.quat_multiply(sp.quat_conjugate(q0), q1)),
        configuration_rate=sp.quat_rate,
        chart=_turned,
        chart_rate=sp.so3_left_jacobian_inverse_times,
        velocity_alignment=sp.quat_to_rotation,
        velocity_coupling=lambda v: np.zeros(3),
        chart_magnitude=lambda q: np.ones(3),
        normalize=_unit,
    ),
    jt.FreeFlyer: dict(
        integrate=_free_flyer_integrate,
        difference=_free_flyer_difference,
        configuration_rate=lambda q, v: np.concatenate([sp.quat_rotate(q[3:], v[:3]), sp.quat_rate(q[3:], v[3:])]),
        chart=lambda q0, d: np.concatenate([q0[:3] + d[:3], _turned(q0[3:], d[3:])]),
        chart_rate=lambda d, w: np.concatenate([w[:3], sp.so3_left_jacobian_inverse_times(d[3:], w[3:])]),
        velocity_alignment=lambda q: _rotation_blocks(sp.quat_to_rotation(q[3:]), 6),
        velocity_coupling=lambda v: np.concatenate([np.cross(v[3:], v[:3]), np.zeros(3)]),
        chart_magnitude=lambda q: np.concatenate([np.abs(q[:3]), np.ones(3)]),
        normalize=lambda q: np.concatenate([q[:3], _unit(q[3:])]),
    ),
}
_VECTOR_SPACE = dict(
    integrate=lambda q, v: q + v,
    difference=lambda q0, q1: q1 - q0,
    configuration_rate=lambda q, v: v,
    chart=lambda q0, d: q0 + d,
    chart_rate=lambda d, w: w,
    velocity_alignment=lambda q: np.eye(q.shape[-1]),
    velocity_coupling=lambda v: np.zeros(v.shape[-1]),
    chart_magnitude=np.abs,
    normalize=lambda q: q,
)
#: ``(a, b, result)`` of each map: ``q``- or ``v``-shaped (``"T"``: the ``(nv, nv)`` matrix)
_LAYOUTS = {"integrate": "qvq", "difference": "qqv", "configuration_rate": "qvq", "chart": "qvq", "chart_rate": "vvv",
            "velocity_alignment": "q-T", "velocity_coupling": "v-v", "chart_magnitude": "q-v", "normalize": "q-q"}


def reference(name, model, a, b=None):
    """The NumPy reference of the map ``name`` of one state, joint by joint."""
    layout = _LAYOUTS[name]
    out = np.zeros((model.nv, model.nv)) if layout[2] == "T" else np.empty(model.nq if layout[2] == "q" else model.nv)
    for joint, iq, iv in zip(model.joints, model.idx_q, model.idx_v):
        blocks = {"q": slice(iq, iq + joint.nq), "v": slice(iv, iv + joint.nv)}
        fn = _REFERENCE.get(type(joint), _VECTOR_SPACE)[name]
        args = [a[blocks[layout[0]]]] + ([] if b is None else [b[blocks[layout[1]]]])
        if layout[2] == "T":
            out[blocks["v"], blocks["v"]] = fn(*args)
        else:
            out[blocks[layout[2]]] = fn(*args)
    return out


# Angles (rad) across the series switches (1e-2 for V(ω), 1e-4 for log and J_l⁻¹), 0 and near π
ANGLES = [None, 0.5, 2e-2, 5e-3, 1e-3, 1.5e-4, 5e-5, 1e-9, 0.0, np.pi - 1e-3, np.pi - 1e-7]


# ----------------------------------------------------------------------------- against the NumPy reference

@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("angle", ANGLES, ids=lambda a: "random" if a is None else f"{a:.3g}")
def test_integrate_difference_rate_match_reference(name, angle):
    model, tree = case(name)
    nq, nv = model.nq, model.nv
    for q, v in states(model, 1, angle):
        q1 = call(cfg.integrate, tree, q, v, (1, nq))
        assert_close(q1[0], reference("integrate", model, q, v), TOL, "integrate")
        # the difference of configurations the step v apart: rotation angle |ω| < π
        assert_close(call(cfg.difference, tree, q, q1[0], (1, nv))[0], reference("difference", model, q, q1[0]), TOL, "difference")
        assert_close(call(cfg.configuration_rate, tree, q, v, (1, nq))[0], reference("configuration_rate", model, q, v), TOL,
                     "configuration_rate")


@pytest.mark.parametrize("name", MODELS)
def test_difference_of_random_configurations_matches_reference(name):
    model, tree = case(name)
    rng = np.random.default_rng(2)
    for _ in range(N_STATES):
        q0, q1 = model.random_configuration(rng), model.random_configuration(rng)
        assert_close(call(cfg.difference, tree, q0, q1, (1, model.nv))[0], reference("difference", model, q0, q1), TOL, "difference")


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("angle", ANGLES, ids=lambda a: "random" if a is None else f"{a:.3g}")
def test_charts_match_reference(name, angle):
    model, tree = case(name)
    nq, nv = model.nq, model.nv
    rng = np.random.default_rng(3)
    for q, delta in states(model, 4, angle):
        w = rng.standard_normal(nv)
        assert_close(call(cfg.chart, tree, q, delta, (1, nq))[0], reference("chart", model, q, delta), TOL, "chart")
        assert_close(call(cfg.chart_rate, tree, delta, w, (1, nv))[0], reference("chart_rate", model, delta, w), TOL, "chart_rate")


@pytest.mark.parametrize("name", MODELS)
def test_alignment_coupling_magnitude_normalize_match_reference(name):
    model, tree = case(name)
    nq, nv = model.nq, model.nv
    rng = np.random.default_rng(5)
    for q, v in states(model, 6):
        T = call(cfg.velocity_alignment, tree, q, shape=(nv, nv))
        assert_close(T, reference("velocity_alignment", model, q), TOL, "velocity_alignment")
        assert_close(T @ T.T, np.eye(nv), 1e-14, "T orthogonal")
        assert_close(call(cfg.velocity_coupling, tree, v, shape=(1, nv))[0], reference("velocity_coupling", model, v), TOL,
                     "velocity_coupling")
        assert_close(call(cfg.chart_magnitude, tree, q, shape=(1, nv))[0], reference("chart_magnitude", model, q), TOL,
                     "chart_magnitude")
        # quaternions and planar pairs scaled off the unit sphere
        off = q.copy()
        for s, _ in rotation_blocks(model):
            if s is not None:
                off[s] *= rng.uniform(0.5, 2.0)
        for joint, iq in zip(model.joints, model.idx_q):
            if isinstance(joint, jt.Planar):
                off[iq + 2 : iq + 4] *= rng.uniform(0.5, 2.0)
        unit = call(cfg.normalize, tree, off, shape=(1, nq))[0]
        assert_close(unit, reference("normalize", model, off), TOL, "normalize")
        assert_close(call(cfg.normalize, tree, q, shape=(1, nq))[0], q, TOL, "normalize of a unit q")


# ----------------------------------------------------------------------------- the Model's maps (batch driver)

_MODEL_MAPS = [  # (Model method, kernel, input layouts, result shape of one state: "q", "v" or "T")
    ("integrate", cfg.integrate, "qv", "q"), ("difference", cfg.difference, "qq", "v"),
    ("configuration_rate", cfg.configuration_rate, "qv", "q"), ("chart", cfg.chart, "qv", "q"),
    ("chart_coordinates", cfg.chart_coordinates, "qq", "v"),
    ("chart_rate", cfg.chart_rate, "vv", "v"), ("velocity_alignment", cfg.velocity_alignment, "q", "T"),
    ("velocity_coupling", cfg.velocity_coupling, "v", "v"), ("chart_magnitude", cfg.chart_magnitude, "q", "v"),
    ("normalize", cfg.normalize, "q", "q"),
]


@pytest.mark.parametrize("name", ["random_tree_0", "solo12"])
@pytest.mark.parametrize("method, kernel, inputs, result", _MODEL_MAPS, ids=[m[0] for m in _MODEL_MAPS])
def test_model_maps_run_the_kernels_with_broadcast_batches(name, method, kernel, inputs, result):
    """``Model.<map>`` on one state and on broadcast batches ``(3, 1, ·)`` × ``(4, ·)`` equals the kernel called
    state by state; ``integrate`` scales ``v`` by ``dt``."""
    model, tree = case(name)
    rng = np.random.default_rng(14)
    size = {"q": model.nq, "v": model.nv}
    draw = {"q": lambda shape: model.random_configuration(rng, shape),
            "v": lambda shape: rng.standard_normal(shape + (model.nv,))}
    shape = (model.nv, model.nv) if result == "T" else (1, size[result])

    def direct(*xs):
        out = call(kernel, tree, *xs, shape=shape)
        return out if result == "T" else out[0]

    one = [draw[k](()) for k in inputs]
    assert_close(getattr(model, method)(*one), direct(*one), 0.0, method)
    batches = [draw[inputs[0]]((3, 1))] + [draw[k]((4,)) for k in inputs[1:]]
    ours = getattr(model, method)(*batches)
    assert ours.shape == ((3, 4) if len(inputs) == 2 else (3, 1)) + shape[(0 if result == "T" else 1):]
    for i in range(ours.shape[0]):
        for j in range(ours.shape[1]):
            assert_close(ours[i, j], direct(*([batches[0][i, 0]] + [b[j] for b in batches[1:]])), 0.0, method)
    if method == "integrate":
        assert_close(model.integrate(*one, dt=0.25), direct(one[0], 0.25 * one[1]), 0.0, "integrate with dt")


# ----------------------------------------------------------------------------- identities

@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("angle", ANGLES, ids=lambda a: "random" if a is None else f"{a:.3g}")
@pytest.mark.parametrize("forward, inverse", [(cfg.integrate, cfg.difference), (cfg.chart, cfg.chart_coordinates)],
                         ids=["integrate-difference", "chart-chart_coordinates"])
def test_maps_and_their_inverses_round_trip(name, angle, forward, inverse):
    """``inverse(q, forward(q, v)) = v`` for rotation angles below π, and ``forward(q, inverse(q, q₁)) = q₁``
    for any two configurations (quaternions up to sign): ``difference`` undoes ``integrate`` (``q ⊕ v``)
    and ``chart_coordinates`` undoes ``chart``."""
    model, tree = case(name)
    nq, nv = model.nq, model.nv
    rng = np.random.default_rng(7)
    for q, v in states(model, 8, angle):
        if angle is None:
            v = 0.5 * v  # rotation angles below π
        q1 = call(forward, tree, q, v, (1, nq))[0]
        assert_close(call(inverse, tree, q, q1, (1, nv))[0], v, TOL, "inverse(q, forward(q, v))")
        q1 = model.random_configuration(rng)
        back = call(forward, tree, q, call(inverse, tree, q, q1, (1, nv))[0], (1, nq))[0]
        for s, _ in rotation_blocks(model):
            if s is not None and back[s] @ q1[s] < 0.0:
                back[s] = -back[s]
        assert_close(back, q1, 1e-13, "forward(q, inverse(q, q₁))")


@pytest.mark.parametrize("name", ["random_tree_0", "solo12"])
def test_configuration_rate_is_derivative_of_integrate(name):
    """``q̇ = d/dt (q ⊕ t v)`` at ``t = 0``, by central differences."""
    model, tree = case(name)
    h = 1e-6
    for q, v in states(model, 9):
        forward = call(cfg.integrate, tree, q, h * v, (1, model.nq))[0]
        backward = call(cfg.integrate, tree, q, -h * v, (1, model.nq))[0]
        rate = call(cfg.configuration_rate, tree, q, v, (1, model.nq))[0]
        assert_close((forward - backward) / (2 * h), rate, 1e-8, "q̇")


def test_chart_rate_of_aligned_velocity_follows_integrate():
    """Moving the chart coordinates with ``δ̇ = J_l(δ)⁻¹ T v`` follows ``q ⊕ v t`` to first order in ``t``."""
    model, tree = case("random_tree_0")
    rng = np.random.default_rng(10)
    h = 1e-6
    for q, v in states(model, 11):
        delta = 0.3 * rng.standard_normal(model.nv)
        q_c = call(cfg.chart, tree, q, delta, (1, model.nq))[0]
        T = call(cfg.velocity_alignment, tree, q_c, shape=(model.nv, model.nv))
        rate = call(cfg.chart_rate, tree, delta, T @ v, (1, model.nv))[0]
        ahead = call(cfg.chart, tree, q, delta + h * rate, (1, model.nq))[0]
        moved = call(cfg.integrate, tree, q_c, h * v, (1, model.nq))[0]
        assert_close((ahead - moved) / h, np.zeros(model.nq), 1e-5, "chart following the motion")


# ----------------------------------------------------------------------------- against Pinocchio

def _pinocchio_case(pin, name):
    model, tree = case(name)
    if name.startswith("random_tree_"):
        pmodel, _ = pinocchio_twin(pin, model)
    else:
        path, floating = URDFS[name]
        path = erd_urdf(path)
        pmodel = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    assert pmodel.nv == model.nv
    return model, tree, pmodel


def _aligned_quaternions(model, q, q_ref):
    """``q`` with each quaternion's sign matched to ``q_ref``'s (the same rotation)."""
    q = q.copy()
    for s, _ in rotation_blocks(model):
        if s is not None and q[s] @ q_ref[s] < 0.0:
            q[s] = -q[s]
    return q


def _wrapped(model, dv):
    """Velocity differences with continuous angles wrapped to (−π, π] (Pinocchio's points on the circle)."""
    dv = dv.copy()
    for joint, iv in zip(model.joints, model.idx_v):
        if isinstance(joint, jt.Continuous):
            dv[iv] = (dv[iv] + np.pi) % (2 * np.pi) - np.pi
    return dv


@pytest.mark.parametrize("name", ["solo12", "panda", "random_tree_0", "random_tree_1"])
@pytest.mark.parametrize("angle", [None, 1e-3, 5e-5, 1e-9, 0.0, np.pi - 1e-3],
                         ids=lambda a: "random" if a is None else f"{a:.3g}")
def test_integrate_difference_match_pinocchio(pin, name, angle):
    """Planar angles stay random: Pinocchio's SE(2) maps lose digits for small angles (1e-11 of the
    displacement at 1e-3 rad, 1e-7 at 1e-9 rad); :func:`test_planar_small_angles_exact` covers ours."""
    model, tree, pmodel = _pinocchio_case(pin, name)
    rng = np.random.default_rng(12)
    for q, v in states(model, 13, angle, planar=False):
        q_pin = q_to_pinocchio(model, q)
        ours = call(cfg.integrate, tree, q, v, (1, model.nq))[0]
        theirs = pin.integrate(pmodel, q_pin, v)
        aligned = _aligned_quaternions(model, ours, q_from_pinocchio(model, theirs))
        assert_close(q_to_pinocchio(model, aligned), theirs, PIN_TOL, "integrate")
        q1 = model.random_configuration(rng)
        for target in (q1, ours):
            dv = call(cfg.difference, tree, q, target, (1, model.nv))[0] - pin.difference(pmodel, q_pin, q_to_pinocchio(model, target))
            assert_close(_wrapped(model, dv), np.zeros(model.nv), PIN_TOL, "difference")


@pytest.mark.parametrize("theta", [0.3, 1e-2, 1e-3, 1.5e-4, 5e-5, 1e-9, 0.0, -1e-7])
def test_planar_small_angles_exact(theta):
    """The planar joint's SE(2) exponential and logarithm against the closed form in 50-digit arithmetic."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 50
    model = mb.ModelBuilder("plane")
    model.add_body("slider", jt.Planar(), parent=None, inertia=mb.inertia.box(1.0, [0.1, 0.2, 0.3]))
    model = model.build()
    tree = compile_tree(model)
    theta0, x, y, vx, vy = 0.7, 0.3, -0.2, 1.3, -0.4
    q = np.array([x, y, np.cos(theta0), np.sin(theta0)])
    v = np.array([vx, vy, theta])
    ours = call(cfg.integrate, tree, q, v, (1, 4))[0]
    t = mpmath.mpf(theta)
    # V(θ) = [[sin θ/θ, −(1 − cos θ)/θ], [(1 − cos θ)/θ, sin θ/θ]] (limit [[1, 0], [0, 1]] at 0)
    a = mpmath.sin(t) / t if theta != 0.0 else mpmath.mpf(1)
    b = (1 - mpmath.cos(t)) / t if theta != 0.0 else mpmath.mpf(0)
    dx, dy = a * vx - b * vy, b * vx + a * vy
    c0, s0 = mpmath.mpf(q[2]), mpmath.mpf(q[3])
    exact = [x + c0 * dx - s0 * dy, y + s0 * dx + c0 * dy, mpmath.cos(mpmath.atan2(s0, c0) + t),
             mpmath.sin(mpmath.atan2(s0, c0) + t)]
    # (1 − cos θ)/θ computed as 2 sin²(θ/2)/θ keeps its digits on both sides of the series switch (1e-4 rad)
    assert_close(ours, np.array([float(e) for e in exact]), 4e-16, "SE(2) exp")
    assert_close(call(cfg.difference, tree, q, ours, (1, 3))[0], v, 4e-16, "SE(2) log")


def test_workspace_size_is_the_exponential_terms_scratch():
    """Three 3×3 matrices for ``exponential_terms``, whatever the tree's size; the other maps need none."""
    assert cfg.workspace_size(30, 40) == cfg.workspace_size(1, 1) == 27
