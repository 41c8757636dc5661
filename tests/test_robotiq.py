"""gym-hil's Robotiq 2F-85 gripper (examples/robotiq_gripper.py), a closed-loop linkage read from MJCF: its
model against MuJoCo's, the degrees of freedom its equalities leave, and its object-free stroke (closure
residual and multipliers). Skipped when gym-hil is not installed (``pip install --no-deps gym-hil``)."""

import os
import runpy
import warnings

import numpy as np
import pytest

import multibody as mb
from multibody.check import compare_with_mujoco

mujoco = pytest.importorskip("mujoco")

EXAMPLE = os.path.join(os.path.dirname(__file__), os.pardir, "examples", "robotiq_gripper.py")


@pytest.fixture(scope="module")
def example():
    """The functions of the example (run without its ``__main__`` part)."""
    return runpy.run_path(EXAMPLE)


@pytest.fixture(scope="module")
def panda(example):
    path = example["panda_xml"]()
    if path is None:
        pytest.skip("gym-hil is not installed (pip install --no-deps gym-hil)")
    return path


@pytest.fixture(scope="module")
def gripper(example, panda):
    """``(model, xml)`` of the gripper alone."""
    return example["load_gripper"](panda)


@pytest.fixture(scope="module")
def stroke(example, gripper):
    """``(system, trajectory, tau)`` of the example's 1 s stroke."""
    return example["close_gripper"](*gripper, duration=1.0)


@pytest.fixture(autouse=True)
def _in_tmp_path(tmp_path, monkeypatch):
    # MuJoCo may write MUJOCO_LOG.TXT into the working directory
    monkeypatch.chdir(tmp_path)


def mujoco_model(xml):
    reference = mujoco.MjModel.from_xml_string(xml)
    reference.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    return reference


def compare_quietly(xml):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return compare_with_mujoco(xml, samples=5)


def test_gripper_alone_is_mujocos_model_and_the_panda_gripper(example, panda, gripper):
    """The extracted document compiles in MuJoCo to the same model as ours (M, h, dynamics, placements,
    Jacobians), and its mass matrix is the gripper's block of the whole Panda's, at any arm configuration:
    the gripper's bodies, inertias and joints are those of panda.xml."""
    model, xml = gripper
    _, rows, _ = compare_quietly(xml)
    failed = [f"{row.quantity}: {row.error:.2e}" for row in rows if not row.ok]
    assert not failed, failed
    assert model.joint_names == tuple(f"{side}_{part}_joint" for side in ("right", "left")
                                      for part in ("driver", "coupler", "spring_link", "follower"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        whole = mb.load_mjcf(panda)
    columns = [whole.idx_v[whole.joint_index(name)] for name in model.joint_names]
    rng = np.random.default_rng(1)
    for _ in range(3):
        q_whole = whole.random_configuration(rng)
        q = q_whole[[whole.idx_q[whole.joint_index(name)] for name in model.joint_names]]
        M = mb.mass_matrix(model, q)
        np.testing.assert_allclose(M, mb.mass_matrix(whole, q_whole)[np.ix_(columns, columns)],
                                   rtol=0, atol=1e-12 * np.abs(M).max())


@pytest.mark.filterwarnings("ignore::multibody.RankDeficientWarning")
def test_degrees_of_freedom_equal_mujocos(gripper):
    """Eight joints less the rank of the equality rows (two planar point closures of three rows and rank
    two, and the drivers' coupling): three degrees of freedom, as MuJoCo's equality rows (``efc_J`` after
    ``mj_forward``) leave, at ``qpos0`` and at states on the constraints away from it."""
    model, xml = gripper
    reference = mujoco_model(xml)
    data = mujoco.MjData(reference)
    system = mb.ConstrainedSystem(model, model.equality_constraints)
    rng = np.random.default_rng(0)
    states = [np.zeros(model.nq)] + [system.project(0.3 * rng.standard_normal(model.nq), np.zeros(model.nv))[0]
                                     for _ in range(3)]
    for q in states:
        A = np.vstack([c.jacobian(model, q) for c in model.equality_constraints])
        data.qpos[:], _ = mb.to_mujoco(model, q, np.zeros(model.nv))
        mujoco.mj_forward(reference, data)
        rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        J = data.efc_J.reshape(data.nefc, reference.nv)[rows]
        assert A.shape == J.shape == (7, 8)
        assert np.abs(data.efc_pos[rows]).max() < 1e-10
        assert model.nv - np.linalg.matrix_rank(A) == reference.nv - np.linalg.matrix_rank(J) == 3


def test_springs_are_the_files(example, gripper):
    """The springs the example adds back (MuJoCo's ``jnt_stiffness`` and ``qpos_spring``) sit on the model's
    spring-link joints, the velocity coordinates of those joints by name: the file's ``2f85`` class gives
    them ``stiffness="0.05" springref="2.62"``."""
    model, xml = gripper
    stiffness, spring = example["joint_springs"](mujoco_model(xml))
    springs = [model.idx_v[model.joint_index(f"{side}_spring_link_joint")] for side in ("right", "left")]
    expected = np.zeros(model.nv)
    expected[springs] = 1.0
    np.testing.assert_array_equal(stiffness, 0.05 * expected)
    np.testing.assert_array_equal(spring, 2.62 * expected)


def test_the_example_compiles_the_document_in_mujoco_once_per_use(example, gripper, monkeypatch):
    """Besides ``load_mjcf``, MuJoCo compiles the gripper's document once for the stroke's springs and once for
    its own simulation of the stroke, which reads the springs from its compiled model."""
    model, xml = gripper
    compile_, compiled = mujoco.MjModel.from_xml_string, []
    monkeypatch.setattr(mujoco.MjModel, "from_xml_string", staticmethod(
        lambda text: compiled.append(text) or compile_(text)))
    tau = example["stroke_torques"](model, xml)
    assert example["mujoco_stroke"](xml, model, tau, [0.0, 1e-3]).shape == (2, model.nq)
    assert compiled == [xml, xml]


def test_stroke_keeps_the_closures_and_closes(example, gripper, stroke):
    """The 1 s stroke: the closure residual stays within what the step ends' projection leaves (its
    tolerance times the rows' largest absolute row sum, margin 10; measured 1.0e-12); the drivers end near
    the PD's target (its steady error, the springs' pull over its gain) and the pads close by more than
    80 mm; the stops only ever push the couplers back into their range (their multipliers are never
    positive), as a joint limit does, so holding them there is what the limits would do."""
    model, _ = gripper
    system, trajectory, _ = stroke
    assert trajectory.t[-1] == pytest.approx(1.0)
    A = system.jacobian(trajectory.q)
    assert trajectory.residual.max() <= 10 * trajectory.projection_tolerance * np.abs(A).sum(axis=2).max()
    driver = model.idx_q[model.joint_index("right_driver_joint")]
    assert abs(trajectory.q[-1, driver] - example["CLOSED"]) < 0.02
    width = example["opening"](model, trajectory.q)
    assert width[0] - width[-1] > 0.08
    lam = example["multipliers"](system, trajectory)
    for side in ("right", "left"):
        assert lam[f"{side} coupler stop"].max() <= 0.0


def test_multipliers_satisfy_the_equations_of_motion(gripper, stroke):
    """At every output state, the trajectory's multipliers satisfy ``M a + h = τ + Aᵀλ`` (``τ`` the example's
    torques less the joints' damping, ``a`` from ``ConstrainedSystem.solve``) to the rounding of its terms
    (measured up to 0.25 of ε times their size), and ``A a = γ`` to 1e-10 (the minimum-norm solve of the
    9 rows of rank 7 leaves up to 9e-12)."""
    model, _ = gripper
    system, trajectory, tau = stroke
    for t, q, v, lam in zip(trajectory.t, trajectory.q, trajectory.v, trajectory.lam):
        torque = tau(t, q, v) - model.damping * v
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mb.RankDeficientWarning)
            solution = system.solve(q, v, torque, t)
        M, h = mb.mass_matrix(model, q), mb.bias_forces(model, q, v)
        terms = (np.abs(M).max() * np.abs(solution.a).max() + np.abs(h).max() + np.abs(torque).max()
                 + np.abs(solution.A).max() * np.abs(lam).max())
        assert np.abs(M @ solution.a + h - torque - solution.A.T @ lam).max() <= 10 * np.finfo(float).eps * terms
        assert np.abs(solution.A @ solution.a - solution.gamma).max() <= 1e-10


def test_example_writes_its_figure(example, panda, tmp_path, capsys):
    example["main"](str(tmp_path), panda)
    assert [p.name for p in tmp_path.iterdir() if p.suffix == ".png"] == ["robotiq_gripper.png"]
    out = capsys.readouterr().out
    assert "8 joints, 9 rows of rank 7: 1 degree(s) of freedom in the stroke" in out
