"""Centre of mass, centroidal momentum and frames (placements, Jacobians and their time variation,
velocities and accelerations in Pinocchio's three references) against Pinocchio on UR5, Panda, Solo12
and Talos (both on a free flyer) and on random trees through their Pinocchio twins; against finite
differences; batched calls against stacked single ones; bad references refused."""

import numpy as np
import pytest

import multibody as mb

from conftest import import_pinocchio, pinocchio_twin, q_to_pinocchio, random_tree_model
from dyn_helpers import STATUE_URDF, rel_err
from test_kinematics import PIN_IDS, PIN_ROBOTS, load_both

REFERENCES = ("world", "local", "local_world_aligned")

#: Tolerances on ``max|ours − Pinocchio| / max(1, max|Pinocchio|)``: the issue's
TOL = 1e-12
TOL_CENTROIDAL = 1e-10

_CACHE = {}


def robot_pair(relative, floating_base):
    """Our model, Pinocchio's (a copy with a frame at an offset point on a few bodies), the Pinocchio
    frame id of each of our bodies and ``[(body, point, frame id)]`` of the offset frames."""
    pin = import_pinocchio()
    key = (relative, floating_base)
    if key not in _CACHE:
        model, pmodel = load_both(relative, floating_base)
        pmodel = pin.Model(pmodel)  # a copy: the frames added here stay out of test_kinematics' cache
        frame_ids = [pmodel.getFrameId(name, pin.BODY) for name in model.body_names]
        assert all(fid < pmodel.nframes for fid in frame_ids)
        _CACHE[key] = (model, pmodel, frame_ids, add_point_frames(pin, model, pmodel, frame_ids))
    return _CACHE[key]


def twin_pair(seed):
    pin = import_pinocchio()
    key = ("tree", seed)
    if key not in _CACHE:
        model = random_tree_model(seed)
        pmodel, frame_ids = pinocchio_twin(pin, model)
        _CACHE[key] = (model, pmodel, frame_ids, add_point_frames(pin, model, pmodel, frame_ids))
    return _CACHE[key]


def add_point_frames(pin, model, pmodel, frame_ids, count=4):
    """Pinocchio frames at random points of ``count`` bodies, with the bodies' axes."""
    rng = np.random.default_rng(7)
    points = []
    for b in rng.choice(model.nbodies, size=min(count, model.nbodies), replace=False):
        frame = pmodel.frames[frame_ids[b]]
        point = rng.uniform(-0.3, 0.3, size=3)
        placement = frame.placement * pin.SE3(np.eye(3), point)
        fid = pmodel.addFrame(pin.Frame(f"{model.body_names[b]}_point", frame.parentJoint, frame_ids[b], placement,
                                        pin.FrameType.OP_FRAME))
        points.append((model.body_names[b], point, fid))
    return points


class Worst:
    """The largest relative error seen per quantity, checked against its tolerance."""

    def __init__(self):
        self.errors = {}

    def check(self, what, ours, ref, tol=TOL):
        ours, ref = np.asarray(ours), np.asarray(ref)
        assert ours.shape == ref.shape, f"{what}: shape {ours.shape} != {ref.shape}"
        err = float(rel_err(ours[None], ref[None])[0])
        self.errors[what] = max(err, self.errors.get(what, 0.0))
        assert err <= tol, f"{what}: relative error {err:.3e} > {tol:.0e}"


def compare_with_pinocchio(model, pmodel, frame_ids, point_frames, states=3, seed=0):
    """Every quantity of this module at ``states`` random states; returns the worst errors."""
    pin = import_pinocchio()
    data = pmodel.createData()
    rng = np.random.default_rng(seed)
    worst = Worst()
    frames = {rf: getattr(pin, rf.upper()) for rf in REFERENCES}
    for _ in range(states):
        q, v, a = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        q_pin = q_to_pinocchio(model, q)

        pin.centerOfMass(pmodel, data, q_pin, v, a)
        worst.check("com", mb.center_of_mass(model, q), data.com[0])
        worst.check("vcom", mb.center_of_mass_velocity(model, q, v), data.vcom[0])
        worst.check("acom", mb.center_of_mass_acceleration(model, q, v, a), data.acom[0])
        worst.check("Jcom", mb.center_of_mass_jacobian(model, q), pin.jacobianCenterOfMass(pmodel, data, q_pin))
        worst.check("Ag", mb.centroidal_momentum_matrix(model, q), pin.computeCentroidalMap(pmodel, data, q_pin),
                    TOL_CENTROIDAL)
        worst.check("hg", mb.centroidal_momentum(model, q, v),
                    pin.computeCentroidalMomentum(pmodel, data, q_pin, v).vector)
        pin.computeCentroidalMapTimeVariation(pmodel, data, q_pin, v)
        worst.check("dAg", mb.centroidal_momentum_matrix_derivative(model, q, v), data.dAg, TOL_CENTROIDAL)

        pin.forwardKinematics(pmodel, data, q_pin, v, a)
        pin.computeJointJacobians(pmodel, data, q_pin)
        pin.computeJointJacobiansTimeVariation(pmodel, data, q_pin, v)
        pin.updateFramePlacements(pmodel, data)
        targets = [(name, None, fid) for name, fid in zip(model.body_names, frame_ids)] + point_frames
        for name, point, fid in targets:
            if point is None:
                worst.check("placement", mb.frame_placement(model, q, name), data.oMf[fid].homogeneous)
            for reference in REFERENCES:
                rf = frames[reference]
                worst.check(f"J {reference}", mb.jacobian(model, q, name, point, reference=reference),
                            pin.getFrameJacobian(pmodel, data, fid, rf))
                worst.check(f"dJ {reference}", mb.jacobian_time_variation(model, q, v, name, point, reference),
                            pin.getFrameJacobianTimeVariation(pmodel, data, fid, rf))
                velocity = pin.getFrameVelocity(pmodel, data, fid, rf).vector
                worst.check(f"velocity {reference}", mb.point_velocity(model, q, v, name, point, reference), velocity)
                if point is None:
                    worst.check(f"frame_velocity {reference}", mb.frame_velocity(model, q, v, name, reference),
                                velocity)
                # classical world-aligned, spatial otherwise (module docstring of multibody.kinematics)
                acceleration = (pin.getFrameClassicalAcceleration if reference == "local_world_aligned"
                                else pin.getFrameAcceleration)(pmodel, data, fid, rf).vector
                worst.check(f"acceleration {reference}", mb.point_acceleration(model, q, v, a, name, point, reference),
                            acceleration)
    return worst.errors


@pytest.mark.parametrize("relative,floating_base", PIN_ROBOTS, ids=PIN_IDS)
def test_robots_match_pinocchio(relative, floating_base):
    compare_with_pinocchio(*robot_pair(relative, floating_base))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_trees_match_pinocchio_twin(seed):
    """Every joint kind, axes off the coordinate axes, branches, links fixed to moving bodies and a
    massive body fixed to the world (in Pinocchio's universe, left out of the centre of mass)."""
    compare_with_pinocchio(*twin_pair(seed), seed=10 + seed)


# ----------------------------------------------------------------------------- what is counted

def test_center_of_mass_counts_the_moving_bodies_only():
    """Panda's ``panda_link0`` is fixed to the world: it is not in the centre of mass, as in Pinocchio."""
    pin = import_pinocchio()
    model, pmodel, _, _ = robot_pair(*PIN_ROBOTS[1])
    link0 = model.body_inertias[model.body_index("panda_link0")]
    assert link0.mass > 0
    q = model.random_configuration(np.random.default_rng(3))
    data = pmodel.createData()
    pin.centerOfMass(pmodel, data, q)
    assert data.mass[0] == pytest.approx(model.total_mass - link0.mass, rel=1e-14)
    # M ċ is the linear momentum of the moving mass: A_G's linear rows are M J_c
    A = mb.centroidal_momentum_matrix(model, q)
    np.testing.assert_allclose(A[:3], data.mass[0] * mb.center_of_mass_jacobian(model, q), atol=1e-13)


def test_no_moving_mass_gives_nan():
    """A model with no moving bodies has no centre of mass: NaN, not an error."""
    model = mb.load_urdf(STATUE_URDF)
    assert model.nq == 0
    assert np.isnan(mb.center_of_mass(model, np.zeros(0))).all()


# ----------------------------------------------------------------------------- identities, finite differences

@pytest.mark.parametrize("seed", [0, 1])
def test_identities_and_finite_differences(seed):
    """``h_G = A_G v``, ``ċ = J_c v``, ``c̈ = J_c a + J̇_c v`` with ``J̇_c = Ȧ_G,linear / M``, and the
    time derivatives of ``c``, ``A_G``, the Jacobians and the placements along ``q(t) = q ⊕ t v``."""
    model = random_tree_model(seed)
    rng = np.random.default_rng(seed)
    q, v, a = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
    mass = sum(inertia.mass for inertia in model.joint_inertias)
    A, A_dot = mb.centroidal_momentum_matrix(model, q), mb.centroidal_momentum_matrix_derivative(model, q, v)
    J_c = mb.center_of_mass_jacobian(model, q)
    np.testing.assert_allclose(mb.centroidal_momentum(model, q, v), A @ v, atol=1e-12)
    np.testing.assert_allclose(mb.center_of_mass_velocity(model, q, v), J_c @ v, atol=1e-12)
    np.testing.assert_allclose(mb.center_of_mass_acceleration(model, q, v, a), J_c @ a + A_dot[:3] @ v / mass,
                               atol=1e-12)

    h = 1e-6

    def rate(f):
        return (f(model.integrate(q, v, h)) - f(model.integrate(q, v, -h))) / (2 * h)

    np.testing.assert_allclose(rate(lambda x: mb.center_of_mass(model, x)), J_c @ v, atol=1e-8)
    np.testing.assert_allclose(rate(lambda x: mb.centroidal_momentum_matrix(model, x)), A_dot, atol=1e-7)
    body = model.body_names[-1]
    point = rng.uniform(-0.3, 0.3, size=3)
    for reference in REFERENCES:
        J_dot = mb.jacobian_time_variation(model, q, v, body, point, reference)
        np.testing.assert_allclose(rate(lambda x: mb.jacobian(model, x, body, point, reference)), J_dot, atol=1e-7,
                                   err_msg=reference)
    # the world-aligned linear velocity is the rate of the placement's position
    X_dot = rate(lambda x: mb.frame_placement(model, x, body))
    np.testing.assert_allclose(X_dot[:3, 3], mb.frame_velocity(model, q, v, body)[:3], atol=1e-8)


def test_frame_placement_is_forward_kinematics():
    model = random_tree_model(1)
    q = model.random_configuration(np.random.default_rng(4), shape=(3,))
    X = mb.forward_kinematics(model, q)
    for b, name in enumerate(model.body_names):
        np.testing.assert_array_equal(mb.frame_placement(model, q, name), X[:, b])
        np.testing.assert_array_equal(mb.frame_placement(model, q, b), X[:, b])


def test_default_reference_is_local_world_aligned():
    model = random_tree_model(0)
    rng = np.random.default_rng(5)
    q, v, a = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
    body = model.body_names[-2]
    for f, args in ((mb.jacobian, (q, body)), (mb.jacobian_time_variation, (q, v, body)),
                    (mb.point_velocity, (q, v, body)), (mb.point_acceleration, (q, v, a, body))):
        np.testing.assert_array_equal(f(model, *args), f(model, *args, reference="local_world_aligned"))
    np.testing.assert_array_equal(mb.frame_velocity(model, q, v, body), mb.point_velocity(model, q, v, body))


# ----------------------------------------------------------------------------- batches and refusals

def test_batched_equals_stacked_single_calls():
    """A ``(2, 3)`` batch, with ``v`` or ``point`` broadcast from one row, equals the single calls; an empty
    batch gives an empty result."""
    model = random_tree_model(2)
    rng = np.random.default_rng(6)
    q = model.random_configuration(rng, shape=(2, 3))
    v, a = rng.standard_normal((2, 3, model.nv)), rng.standard_normal((1, 3, model.nv))
    point = rng.uniform(-0.3, 0.3, size=3)
    body = model.body_names[-1]
    calls = {
        "center_of_mass": lambda q, v, a: mb.center_of_mass(model, q),
        "center_of_mass_velocity": lambda q, v, a: mb.center_of_mass_velocity(model, q, v),
        "center_of_mass_acceleration": lambda q, v, a: mb.center_of_mass_acceleration(model, q, v, a),
        "center_of_mass_jacobian": lambda q, v, a: mb.center_of_mass_jacobian(model, q),
        "centroidal_momentum_matrix": lambda q, v, a: mb.centroidal_momentum_matrix(model, q),
        "centroidal_momentum": lambda q, v, a: mb.centroidal_momentum(model, q, v),
        "centroidal_momentum_matrix_derivative": lambda q, v, a: mb.centroidal_momentum_matrix_derivative(model, q, v),
        "frame_placement": lambda q, v, a: mb.frame_placement(model, q, body),
    }
    for reference in REFERENCES:
        calls[f"jacobian {reference}"] = lambda q, v, a, r=reference: mb.jacobian(model, q, body, point, r)
        calls[f"jacobian_time_variation {reference}"] = \
            lambda q, v, a, r=reference: mb.jacobian_time_variation(model, q, v, body, point, r)
        calls[f"frame_velocity {reference}"] = lambda q, v, a, r=reference: mb.frame_velocity(model, q, v, body, r)
        calls[f"point_acceleration {reference}"] = \
            lambda q, v, a, r=reference: mb.point_acceleration(model, q, v, a, body, point, r)
    for name, f in calls.items():
        batched = f(q, v, a)
        single = np.array([[f(q[i, j], v[i, j], a[0, j]) for j in range(3)] for i in range(2)])
        assert batched.shape == single.shape, name
        np.testing.assert_array_equal(batched, single, err_msg=name)
        empty = f(q[:0, 0], v[:0, 0], a[:0, 0])
        assert empty.shape == (0,) + single.shape[2:], name


def test_non_finite_input_gives_nan_for_that_state():
    model = random_tree_model(0)
    rng = np.random.default_rng(8)
    q, v = model.random_configuration(rng, shape=(2,)), rng.standard_normal((2, model.nv))
    v[0, 0] = np.nan
    with pytest.warns(RuntimeWarning):
        h = mb.centroidal_momentum(model, q, v)
    assert np.isnan(h[0]).all() and np.isfinite(h[1]).all()
    with pytest.warns(RuntimeWarning):
        A_dot = mb.centroidal_momentum_matrix_derivative(model, q, v)
    assert np.isnan(A_dot[0]).all() and np.isfinite(A_dot[1]).all()


@pytest.mark.parametrize("reference", ["LOCAL", "global", "", None, 1])
def test_bad_reference_raises(reference):
    model = random_tree_model(0)
    rng = np.random.default_rng(9)
    q, v = model.random_configuration(rng), rng.standard_normal(model.nv)
    body = model.body_names[-1]
    calls = [lambda: mb.jacobian(model, q, body, reference=reference),
             lambda: mb.jacobian_time_variation(model, q, v, body, reference=reference),
             lambda: mb.point_velocity(model, q, v, body, reference=reference),
             lambda: mb.point_acceleration(model, q, v, v, body, reference=reference),
             lambda: mb.frame_velocity(model, q, v, body, reference=reference)]
    for call in calls:
        with pytest.raises(ValueError, match="reference must be one of 'world', 'local', 'local_world_aligned'"):
            call()


def test_unknown_frame_raises():
    model = random_tree_model(0)
    with pytest.raises(ValueError, match="unknown body 'nowhere'"):
        mb.frame_placement(model, model.neutral(), "nowhere")
