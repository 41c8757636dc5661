"""URDF ``<dynamics>`` and ``<limit>`` kept in the model, and what ``mb.simulate`` does with them.

* ``model.damping``, ``friction``, ``effort_limit``, ``velocity_limit`` (``(nv,)``), ``lower`` and
  ``upper`` (``(nq,)``) equal Pinocchio's ``damping``, ``friction``, ``effortLimit``,
  ``velocityLimit``, ``lowerPositionLimit`` and ``upperPositionLimit`` on example-robot-data robots,
  mapped where the conventions differ (see :func:`expected_from_pinocchio`).
* Models built in Python get no damping or friction and no limits unless the builder is given them.
* ``simulate(..., joint_damping=True)`` applies ``−D v``; ``limits="warn" | "error" | "ignore"``
  reports positions outside ``[lower, upper]``.
"""

from __future__ import annotations

import glob
import os
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody.simulation import JointLimitWarning
from multibody.robots import EXAMPLE_ROBOTS
from multibody.urdf import UNBOUNDED_LIMIT, URDFError

from conftest import erd_urdf

# The robots the issue names: (URDF path, floating base) as mb.robots ships them.
ROBOTS = {name: EXAMPLE_ROBOTS[name] for name in ("panda", "ur5", "solo12", "talos", "double_pendulum_continuous")}
DBL_MAX = np.finfo(float).max


def pinocchio_model(pin, urdf, floating_base):
    return pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer()) if floating_base else pin.buildModelFromUrdf(urdf)


def _unbounded(x):
    """Pinocchio's ``±DBL_MAX`` (the free flyer's "no limit") as ``±inf``."""
    x = np.array(x, dtype=float)
    return np.where(x >= DBL_MAX, np.inf, np.where(x <= -DBL_MAX, -np.inf, x))


def expected_from_pinocchio(model, pmodel):
    """Our ``(damping, friction, effort_limit, velocity_limit, lower, upper)`` from Pinocchio's model.

    Per-velocity quantities are equal, with ``DBL_MAX`` (Pinocchio's free flyer) read as ``inf``.
    Positions, joint by joint:
    * continuous: one unbounded angle here, ``(cos θ, sin θ)`` within ±1.01 there;
    * free flyer: unbounded position and a quaternion within ±1 here, ``±DBL_MAX`` there;
    * one coordinate: Pinocchio's values, except that a side at or beyond ``UNBOUNDED_LIMIT`` is
      unbounded here (a side the URDF's ``<limit>`` leaves out is 0 in both, the URDF specification's
      default).
    """
    per_dof = [_unbounded(getattr(pmodel, name)) for name in ("damping", "friction", "effortLimit", "velocityLimit")]
    lower, upper = [], []
    for joint, name in zip(model.joints, model.joint_names):
        pjoint = pmodel.joints[pmodel.getJointId(name)]
        assert pjoint.idx_v == model.idx_v[model.joint_index(name)]
        if isinstance(joint, jt.Continuous):
            assert pjoint.nq == 2
            lower.append([-np.inf])
            upper.append([np.inf])
        elif isinstance(joint, jt.FreeFlyer):
            assert np.all(pmodel.lowerPositionLimit[pjoint.idx_q:pjoint.idx_q + 7] <= -1.0)
            lower.append(joint.default_limits[0])
            upper.append(joint.default_limits[1])
        else:
            assert joint.nq == pjoint.nq == 1
            lo, hi = pmodel.lowerPositionLimit[pjoint.idx_q], pmodel.upperPositionLimit[pjoint.idx_q]
            lower.append([-np.inf if lo <= -UNBOUNDED_LIMIT else lo])
            upper.append([np.inf if hi >= UNBOUNDED_LIMIT else hi])
    return (*per_dof, np.concatenate(lower or [[]]), np.concatenate(upper or [[]]))


ATTRIBUTES = ("damping", "friction", "effort_limit", "velocity_limit", "lower", "upper")


def assert_like_pinocchio(model, pmodel):
    for attribute, expected in zip(ATTRIBUTES, expected_from_pinocchio(model, pmodel)):
        np.testing.assert_array_equal(getattr(model, attribute), expected, err_msg=attribute)


# ----------------------------------------------------------------------------- equal to Pinocchio

@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_limits_and_dynamics_equal_pinocchio(pin, name):
    relative, floating_base = ROBOTS[name]
    urdf = erd_urdf(relative)
    model = mb.load_urdf(urdf, floating_base=floating_base)
    pmodel = pinocchio_model(pin, urdf, floating_base)
    assert (model.nv,) == model.damping.shape == model.friction.shape == model.effort_limit.shape \
        == model.velocity_limit.shape
    assert (model.nq,) == model.lower.shape == model.upper.shape
    assert_like_pinocchio(model, pmodel)


def test_panda_values_as_written(pin):
    """The numbers the issue quotes: damping 0.003 (arm) and 0.3 (fingers), effort 87 N·m."""
    model = mb.load_urdf(erd_urdf(ROBOTS["panda"][0]))
    np.testing.assert_array_equal(model.damping, [0.003] * 7 + [0.3] * 2)
    np.testing.assert_array_equal(model.effort_limit[:4], [87.0] * 4)
    np.testing.assert_array_equal(model.friction, np.zeros(9))


def test_every_example_robot_data_urdf_equals_pinocchio(pin, erd_dir):
    """Every URDF of example-robot-data that both load, fixed and floating, under the same mapping."""
    checked = 0
    for urdf in sorted(glob.glob(os.path.join(erd_dir, "*", "*", "*.urdf"))):
        for floating_base in (False, True):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    model = mb.load_urdf(urdf, floating_base=floating_base)
                except URDFError:
                    continue  # xacro leftovers and files that are not a single tree
            try:
                pmodel = pinocchio_model(pin, urdf, floating_base)
            except (RuntimeError, ValueError):
                continue
            assert_like_pinocchio(model, pmodel)
            checked += 1
    assert checked > 50


def test_limit_arrays_are_read_only():
    model = mb.load_urdf(erd_urdf(ROBOTS["panda"][0]))
    for attribute in ATTRIBUTES:
        with pytest.raises(ValueError, match="read-only"):
            getattr(model, attribute)[0] = 1.0


# ----------------------------------------------------------------------------- URDF documents

def one_joint(kind, extra="", name="j"):
    return (f'<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
            f'<inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>'
            f'<joint name="{name}" type="{kind}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
            f'{extra}</joint></robot>')


def test_urdf_dynamics_and_limits_read():
    model = mb.load_urdf(one_joint("revolute", '<limit lower="-1" upper="2" effort="5" velocity="3"/>'
                                               '<dynamics damping="0.5" friction="0.25"/>'))
    assert (model.damping[0], model.friction[0], model.effort_limit[0], model.velocity_limit[0]) == (0.5, 0.25, 5, 3)
    assert (model.lower[0], model.upper[0]) == (-1.0, 2.0)


def test_urdf_defaults_when_not_given():
    """No <dynamics>: no damping or friction; no effort or velocity: no limit (inf)."""
    model = mb.load_urdf(one_joint("continuous"))
    assert (model.damping[0], model.friction[0]) == (0.0, 0.0)
    assert (model.effort_limit[0], model.velocity_limit[0]) == (np.inf, np.inf)
    assert (model.lower[0], model.upper[0]) == (-np.inf, np.inf)
    model = mb.load_urdf(one_joint("prismatic", '<limit lower="-1" upper="1"/><dynamics damping="2"/>'))
    assert (model.damping[0], model.friction[0], model.effort_limit[0]) == (2.0, 0.0, np.inf)


def test_continuous_joint_keeps_effort_and_velocity_but_no_position_limits(pin):
    xml = one_joint("continuous", '<limit lower="-1" upper="1" effort="5" velocity="2"/><dynamics damping="0.5"/>')
    model, pmodel = mb.load_urdf(xml), pin.buildModelFromXML(xml)
    np.testing.assert_array_equal(model.effort_limit, pmodel.effortLimit)
    np.testing.assert_array_equal(model.velocity_limit, pmodel.velocityLimit)
    np.testing.assert_array_equal(model.damping, pmodel.damping)
    assert (model.lower[0], model.upper[0]) == (-np.inf, np.inf)


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_multi_coordinate_joints_ignore_limit_and_dynamics_as_pinocchio(pin, kind):
    xml = one_joint(kind, '<limit lower="-1" upper="1" effort="5" velocity="2"/><dynamics damping="0.5" friction="1"/>')
    model, pmodel = mb.load_urdf(xml), pin.buildModelFromXML(xml)
    np.testing.assert_array_equal(model.damping, pmodel.damping)
    np.testing.assert_array_equal(model.friction, pmodel.friction)
    np.testing.assert_array_equal(model.effort_limit, _unbounded(pmodel.effortLimit))
    np.testing.assert_array_equal(model.velocity_limit, _unbounded(pmodel.velocityLimit))
    assert np.all(model.effort_limit == np.inf) and np.all(model.damping == 0.0)


@pytest.mark.parametrize("kind, limit, expected", [
    ("revolute", '<limit effort="35" velocity="20"/>', (0.0, 0.0)),
    ("revolute", '<limit lower="-1.5" effort="35" velocity="20"/>', (-1.5, 0.0)),
    ("revolute", '<limit upper="2" effort="35" velocity="20"/>', (0.0, 2.0)),
    ("prismatic", '<limit upper="0.5" effort="35" velocity="20"/>', (0.0, 0.5)),
    ("prismatic", '<limit effort="35" velocity="20"/>', (0.0, 0.0)),
])
def test_limit_without_lower_or_upper_reads_zero_as_the_specification_and_pinocchio(pin, kind, limit, expected):
    """A ``<limit>`` that leaves out ``lower`` or ``upper`` gives that side 0 (the URDF specification,
    urdfdom, Pinocchio: centauro's wheels and the quadruped's knees in example-robot-data have such limits)."""
    xml = one_joint(kind, limit)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a joint held at 0 warns: the test below)
        model = mb.load_urdf(xml)
    pmodel = pin.buildModelFromXML(xml)
    assert (model.lower[0], model.upper[0]) == expected
    np.testing.assert_array_equal(model.lower, pmodel.lowerPositionLimit)
    np.testing.assert_array_equal(model.upper, pmodel.upperPositionLimit)


@pytest.mark.parametrize("kind, limit, absent, remedy", [
    ("revolute", '<limit effort="35" velocity="20"/>', " (lower and upper absent", "or make it continuous"),
    ("revolute", '<limit lower="0" effort="35" velocity="20"/>', " (upper absent", "or make it continuous"),
    ("revolute", '<limit lower="0" upper="0" effort="35" velocity="20"/>', ", which", "or make it continuous"),
    ("prismatic", '<limit effort="35" velocity="20"/>', " (lower and upper absent", "give its range"),
])
def test_joint_held_at_zero_by_its_limits_warns(kind, limit, absent, remedy):
    with pytest.warns(UserWarning, match=r"<joint name='j'>/<limit>: the limits are lower = upper = 0") as caught:
        mb.load_urdf(one_joint(kind, limit))
    message = str(caught[0].message)
    assert f"lower = upper = 0{absent}" in message and f"{kind} joint still" in message and remedy in message
    assert os.path.basename(caught[0].filename) == os.path.basename(__file__)  # points at the caller


def test_lower_above_an_absent_upper_says_the_upper_reads_zero():
    with pytest.raises(URDFError, match=r"<joint name='j'>/<limit>.*lower limit 1 exceeds upper limit 0 "
                                        r"\(upper absent: the URDF specification reads 0\)"):
        mb.load_urdf(one_joint("revolute", '<limit lower="1" effort="1" velocity="1"/>'))


@pytest.mark.parametrize("kind, limit", [
    ("revolute", '<limit lower="-1" upper="1" effort="1" velocity="1"/>'),
    ("revolute", '<limit lower="0" upper="1" effort="1" velocity="1"/>'),
    ("continuous", '<limit effort="35" velocity="20"/>'),
])
def test_joints_with_a_range_or_continuous_load_silently(kind, limit):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = mb.load_urdf(one_joint(kind, limit))
    if kind == "continuous":  # no position limits, whatever <limit> says
        assert (model.lower[0], model.upper[0]) == (-np.inf, np.inf)


def test_huge_effort_and_velocity_mean_none():
    model = mb.load_urdf(one_joint("revolute", f'<limit lower="-1" upper="1" effort="{UNBOUNDED_LIMIT:g}" '
                                               'velocity="1e300"/>'))
    assert (model.effort_limit[0], model.velocity_limit[0]) == (np.inf, np.inf)


@pytest.mark.parametrize("extra, where, what", [
    ('<limit lower="-1" upper="1" effort="-1" velocity="1"/>', "<limit>", "effort='-1' must not be negative"),
    ('<limit lower="-1" upper="1" effort="1" velocity="-2"/>', "<limit>", "velocity='-2' must not be negative"),
    ('<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics damping="-0.1"/>', "<dynamics>",
     "damping='-0.1' must not be negative"),
    ('<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics friction="abc"/>', "<dynamics>",
     "'abc' is not a decimal number"),
    ('<limit lower="-1" upper="1" effort="nan" velocity="1"/>', "<limit>", "'nan' is not a decimal number"),
    ('<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics damping="inf"/>', "<dynamics>",
     "'inf' is not a decimal number"),
    ('<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics damping="1e400"/>', "<dynamics>",
     "damping='1e400': numbers must be finite"),
    ('<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics friction="1e60"/>', "<dynamics>",
     "friction='1e60': magnitude above 1e+50"),
])
def test_bad_dynamics_and_limits_name_the_element(extra, where, what):
    with pytest.raises(URDFError) as error:
        mb.load_urdf(one_joint("revolute", extra))
    assert f"<joint name='j'>/{where}" in str(error.value) and what in str(error.value)


def test_fixed_joint_dynamics_go_nowhere():
    xml = one_joint("fixed", '<dynamics damping="3"/><limit effort="1" velocity="1"/>')
    model = mb.load_urdf(xml)
    assert model.nv == 0 and model.damping.shape == (0,) and model.effort_limit.shape == (0,)


def test_mimic_joint_keeps_its_own_limits(pin):
    """A mimicking joint stays a coordinate (as in Pinocchio's default), with its own <limit> and <dynamics>."""
    xml = ('<robot name="r"><link name="a"/>'
           + "".join(f'<link name="{n}"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" '
                     f'ixz="0" iyz="0"/></inertial></link>' for n in ("b", "c"))
           + '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
             '<limit lower="-1" upper="1" effort="4" velocity="2"/><dynamics damping="0.1"/></joint>'
             '<joint name="j2" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>'
             '<limit lower="-2" upper="2" effort="6" velocity="3"/><dynamics damping="0.2" friction="0.3"/>'
             '<mimic joint="j1" multiplier="2"/></joint></robot>')
    model, pmodel = mb.load_urdf(xml), pin.buildModelFromXML(xml)
    assert model.mimic and model.nv == pmodel.nv == 2
    for attribute, pin_name in zip(ATTRIBUTES, ("damping", "friction", "effortLimit", "velocityLimit",
                                               "lowerPositionLimit", "upperPositionLimit")):
        np.testing.assert_array_equal(getattr(model, attribute), getattr(pmodel, pin_name), err_msg=attribute)


# ----------------------------------------------------------------------------- models built in Python

def test_builder_defaults_and_arguments():
    b = mb.ModelBuilder("arm")
    b.add_body("base", jt.FreeFlyer(), inertia=mb.inertia.box(1.0, [0.2, 0.2, 0.2]))
    b.add_body("link", jt.Revolute([0, 0, 1]), parent="base", inertia=mb.inertia.box(1.0, [0.1, 0.1, 0.5]),
               damping=0.5, friction=0.1, effort_limit=20.0, velocity_limit=[3.0], lower=[-1.0], upper=[1.0])
    model = b.build()
    np.testing.assert_array_equal(model.damping, [0.0] * 6 + [0.5])
    np.testing.assert_array_equal(model.friction, [0.0] * 6 + [0.1])
    np.testing.assert_array_equal(model.effort_limit, [np.inf] * 6 + [20.0])
    np.testing.assert_array_equal(model.velocity_limit, [np.inf] * 6 + [3.0])
    np.testing.assert_array_equal(model.lower, [-np.inf] * 3 + [-1.0] * 4 + [-1.0])
    for attribute in ATTRIBUTES:
        assert not getattr(model, attribute).flags.writeable


@pytest.mark.parametrize("kwargs, message", [
    (dict(damping=-1.0), "damping of joint 'j' must not be negative"),
    (dict(friction=np.inf), "friction of joint 'j' must be finite"),
    (dict(effort_limit=[1.0, 2.0]), r"effort_limit of joint 'j' must have shape \(1,\)"),
    (dict(velocity_limit=np.nan), "velocity_limit of joint 'j' must be numbers"),
])
def test_builder_refuses_bad_joint_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        mb.ModelBuilder().add_body("b", jt.Revolute(), joint_name="j", **kwargs)


def test_model_checks_shapes():
    model = mb.robots.load("double_pendulum")
    fields = {name: getattr(model, name) for name in model.__dataclass_fields__}
    with pytest.raises(ValueError, match=r"Model: damping must have shape \(2,\)"):
        mb.Model(**{**fields, "damping": np.zeros(3)})


# ----------------------------------------------------------------------------- simulate: limits

@pytest.fixture(scope="module")
def panda():
    model = mb.load_urdf(erd_urdf(ROBOTS["panda"][0]))
    # Mid-range: inside every limit (the neutral configuration is not: joint 4 must bend).
    return model, (model.lower + model.upper) / 2


def run_panda(panda, **kwargs):
    model, q0 = panda
    return mb.simulate(model, q0, np.zeros(model.nv), 1.0, dt=0.01, **kwargs)


def test_passive_panda_warns_once_per_joint_that_leaves_its_limits(panda):
    model, _ = panda
    reference = run_panda(panda, limits="ignore")
    outside = (reference.q < model.lower) | (reference.q > model.upper)
    leaving = [name for name, s in zip(model.joint_names, model.idx_q) if outside[:, s].any()]
    assert len(leaving) >= 3  # under gravity, with nothing holding it, a passive Panda falls through its limits
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trajectory = run_panda(panda)
    limit_warnings = [w for w in caught if issubclass(w.category, JointLimitWarning)]
    assert len(limit_warnings) == len(caught)
    assert sorted(name for name in model.joint_names if any(f"'{name}'" in str(w.message) for w in limit_warnings)) \
        == sorted(leaving)
    assert len(limit_warnings) == len(leaving)  # once per joint
    for w in limit_warnings:
        assert os.path.basename(w.filename) == os.path.basename(__file__)  # points at the caller
        name = next(name for name in leaving if f"'{name}'" in str(w.message))
        s = model.idx_q[model.joint_index(name)]
        k = int(np.argmax(outside[:, s]))  # first output time outside
        assert f"t = {trajectory.t[k]:.6g} s" in str(w.message)
        assert f"q = {trajectory.q[k, s]:.6g}" in str(w.message)
    np.testing.assert_array_equal(trajectory.q, reference.q)


def test_passive_panda_limits_error_names_joint_time_value(panda):
    model, _ = panda
    reference = run_panda(panda, limits="ignore")
    outside = (reference.q < model.lower) | (reference.q > model.upper)
    k = int(np.flatnonzero(outside.any(axis=1))[0])
    s = int(np.flatnonzero(outside[k])[0])
    joint = model.joint_names[int(np.searchsorted(model.idx_q, s, side="right")) - 1]
    with pytest.raises(mb.SimulationError) as error:
        run_panda(panda, limits="error")
    message = str(error.value)
    assert f"'{joint}'" in message and f"t = {reference.t[k]:.6g} s" in message and f"q = {reference.q[k, s]:.6g}" in message
    partial = error.value.trajectory
    assert len(partial) == k + 1 and partial.t[-1] == reference.t[k] and partial.status == message
    np.testing.assert_array_equal(partial.q, reference.q[:k + 1])
    assert partial.v.shape == (k + 1, model.nv) and partial.energy.shape == (k + 1,)


def test_limits_ignore_is_silent(panda):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run_panda(panda, limits="ignore")


def test_limits_inside_is_silent():
    """A pendulum with wide limits never leaves them: no warning."""
    b = mb.ModelBuilder("pendulum")
    b.add_body("bob", jt.Revolute([0, 1, 0]), inertia=mb.inertia.point_mass(1.0, [0, 0, -1]), lower=[-1.0], upper=[1.0])
    model = b.build()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mb.simulate(model, [0.5], [0.0], 2.0)


def test_bad_limits_mode_names_the_choices(panda):
    model, q0 = panda
    with pytest.raises(ValueError, match=r"limits must be one of \('warn', 'error', 'ignore'\), got 'loud'"):
        mb.simulate(model, q0, np.zeros(model.nv), 0.1, limits="loud")


def test_free_flyer_quaternion_is_not_reported():
    """Unit-norm components sit at ±1 by construction; rounding past them is no excursion."""
    b = mb.ModelBuilder("spinning")
    b.add_body("box", jt.FreeFlyer(), inertia=mb.inertia.box(1.0, [0.1, 0.2, 0.3]))
    model = b.build()
    q0 = np.array([0, 0, 0, 1.0, 0, 0, 0])  # qx = 1 at the upper bound
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trajectory = mb.simulate(model, q0, [0, 0, 0, 3.0, 0.01, 0], 1.0, method="RK4", dt=0.01)
    assert np.abs(trajectory.q[:, 3:]).max() <= 1.0 + 1e-12


# ----------------------------------------------------------------------------- simulate: joint damping

def damped_pendulum(damping=0.3):
    b = mb.ModelBuilder("damped_pendulum")
    b.add_body("bob", jt.Revolute([0, 1, 0]), inertia=mb.inertia.point_mass(1.0, [0, 0, -1]), damping=damping)
    return b.build()


def test_joint_damping_dissipates_energy_monotonically():
    model = damped_pendulum()
    trajectory = mb.simulate(model, [1.0], [0.0], 10.0, method="DOP853", rtol=1e-11, atol=1e-12, joint_damping=True)
    assert np.all(np.diff(trajectory.energy) <= 1e-10)
    # from 1 rad (E = −g cos 1 ≈ −5.3 J) the swing decays as e^{−0.15 t} towards the bottom (−9.81 J)
    assert trajectory.energy[-1] < -9.0
    undamped = mb.simulate(model, [1.0], [0.0], 10.0, method="DOP853", rtol=1e-11, atol=1e-12)
    assert np.ptp(undamped.energy) < 1e-8  # damping is off by default


def test_joint_damping_equals_the_same_force_given_as_tau():
    model = damped_pendulum(0.7)
    damped = mb.simulate(model, [1.0], [0.5], 3.0, joint_damping=True)
    by_hand = mb.simulate(model, [1.0], [0.5], 3.0, tau=lambda t, q, v: -model.damping * v)
    np.testing.assert_allclose(damped.q, by_hand.q, rtol=0, atol=1e-14)
    np.testing.assert_allclose(damped.v, by_hand.v, rtol=0, atol=1e-14)
    # with a constant force on top
    damped = mb.simulate(model, [1.0], [0.5], 3.0, joint_damping=True, tau=[0.2])
    by_hand = mb.simulate(model, [1.0], [0.5], 3.0, tau=lambda t, q, v: 0.2 - model.damping * v)
    np.testing.assert_allclose(damped.q, by_hand.q, rtol=0, atol=1e-14)


def test_joint_damping_matches_closed_form():
    """A slider without gravity, ``m ẍ = −d ẋ``: ``v = v₀ e^{−d t / m}``, ``x = x₀ + v₀ m / d (1 − e^{−d t / m})``."""
    mass, d, v0 = 2.0, 0.8, 1.5
    b = mb.ModelBuilder("slider", gravity=(0.0, 0.0, 0.0))
    b.add_body("block", jt.Prismatic([1, 0, 0]), inertia=mb.inertia.box(mass, [0.1, 0.1, 0.1]), damping=d)
    model = b.build()
    trajectory = mb.simulate(model, [0.0], [v0], 5.0, method="DOP853", rtol=1e-12, atol=1e-14, joint_damping=True)
    decay = np.exp(-d * trajectory.t / mass)
    np.testing.assert_allclose(trajectory.v[:, 0], v0 * decay, rtol=0, atol=1e-11)
    np.testing.assert_allclose(trajectory.q[:, 0], v0 * mass / d * (1 - decay), rtol=0, atol=1e-11)
    np.testing.assert_allclose(trajectory.energy, 0.5 * mass * (v0 * decay) ** 2, rtol=0, atol=1e-10)


def test_constrained_system_reaches_its_models_damping_and_limits():
    """A ConstrainedSystem wraps a Model: its damping and limits apply as for the model itself."""
    b = mb.ModelBuilder("damped_pendulum")
    b.add_body("bob", jt.Revolute([0, 1, 0]), inertia=mb.inertia.point_mass(1.0, [0, 0, -1]), damping=0.4,
               lower=[-0.5], upper=[0.5])
    model = b.build()
    with pytest.warns(JointLimitWarning, match="'bob_joint'.*left its limits"):
        wrapped = mb.simulate(mb.ConstrainedSystem(model, []), [1.0], [0.0], 2.0, joint_damping=True)
    with pytest.warns(JointLimitWarning):
        plain = mb.simulate(model, [1.0], [0.0], 2.0, joint_damping=True)
    np.testing.assert_allclose(wrapped.q, plain.q, rtol=0, atol=1e-12)
    assert wrapped.energy[-1] < wrapped.energy[0] - 0.1


def test_joint_damping_needs_a_model():
    sympy = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    x = dynamicsymbols("x")
    system = mb.LagrangianSystem([x], sympy.Rational(1, 2) * x.diff() ** 2, x ** 2 / 2).numeric()
    with pytest.raises(ValueError, match="joint_damping=True needs a system built on a Model"):
        mb.simulate(system, [1.0], [0.0], 1.0, joint_damping=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mb.simulate(system, [1.0], [0.0], 1.0, limits="error")  # no model, no limits
