"""Figures: names and units read back from the Axes, rotations drawn as angles, the backend left alone."""

import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest

import multibody as mb
from multibody.plotting import plot_trajectory, roll_pitch_yaw, state_curves, trajectory_figures
from multibody.spatial import rotation_to_quat, rpy_to_rotation

UNITS = ("(m)", "(rad)", "(m/s)", "(rad/s)", "(N)", "(N·m)", "(J)")


def synthetic(system, v, t_final=1.0, n=41, residual=None, tolerance=1e-12):
    """A trajectory moving with constant velocity ``v`` from the neutral configuration (no dynamics)."""
    model = system if isinstance(system, mb.Model) else system.model
    rows = 0 if isinstance(system, mb.Model) else system.num_rows
    t = np.linspace(0.0, t_final, n)
    q = model.integrate(model.neutral(), np.outer(t, v))
    return mb.Trajectory(t=t, q=q, v=np.tile(v, (n, 1)), lam=np.outer(np.ones(n), np.arange(1.0, rows + 1)),
                         energy=np.linspace(1.0, 1.0 + 1e-9, n), residual=np.zeros(n) if residual is None else residual,
                         row_names=list(getattr(system, "row_names", [])), projection_tolerance=tolerance)


def panels(figure):
    """``{y label: {curve label: y data}}`` of every Axes of ``figure``."""
    return {ax.get_ylabel(): {line.get_label(): line.get_ydata() for line in ax.get_lines()} for ax in figure.axes}


def legend(ax):
    return [text.get_text() for text in ax.get_legend().get_texts()]


@pytest.fixture(scope="module")
def diff_drive():
    robot = mb.robots.load("diff_drive")
    wheels = [mb.RollingDisc(name, 0.08, axis=(0.0, 1.0, 0.0), normal=False) for name in ("left_wheel", "right_wheel")]
    return mb.ConstrainedSystem(robot, wheels)


def test_planar_base_coordinates_and_velocities_are_named_apart_with_units(diff_drive):
    # the planar joint turns by 2 rad/s for 3 s: θ passes π and keeps growing (unwrapped)
    trajectory = synthetic(diff_drive, np.array([0.1, 0.0, 2.0, 3.0, -4.0]), t_final=3.0)
    figure = trajectory_figures(trajectory, diff_drive)["state"]
    drawn = panels(figure)
    assert set(drawn) == {"position (m)", "angle (rad)", "velocity (m/s)", "angular velocity (rad/s)"}
    assert list(drawn["position (m)"]) == ["base_planar x", "base_planar y"]
    assert list(drawn["angle (rad)"]) == ["base_planar θ", "left_wheel_joint", "right_wheel_joint"]
    assert list(drawn["velocity (m/s)"]) == ["base_planar vx", "base_planar vy"]
    assert list(drawn["angular velocity (rad/s)"]) == ["base_planar ω", "left_wheel_joint", "right_wheel_joint"]
    # θ itself, not cos θ and sin θ; each wheel's speed on its own curve
    np.testing.assert_allclose(drawn["angle (rad)"]["base_planar θ"], 2.0 * trajectory.t, atol=1e-12)
    np.testing.assert_array_equal(drawn["angular velocity (rad/s)"]["left_wheel_joint"], trajectory.v[:, 3])
    np.testing.assert_array_equal(drawn["angular velocity (rad/s)"]["base_planar ω"], trajectory.v[:, 2])
    for ax in figure.axes:
        assert legend(ax) == [line.get_label() for line in ax.get_lines()]
    assert [ax.get_xlabel() for ax in figure.axes[-2:]] == ["t (s)", "t (s)"]


def test_free_flyer_orientation_is_roll_pitch_yaw():
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    v = np.array([0.5, 0.0, 1.0, 4.0, 0.0, 0.0])  # spinning about the body x axis at 4 rad/s
    trajectory = synthetic(ball, v, t_final=2.0)
    drawn = panels(trajectory_figures(trajectory, ball)["state"])
    assert list(drawn["position (m)"]) == ["root_joint x", "root_joint y", "root_joint z"]
    assert list(drawn["angle (rad)"]) == ["root_joint roll", "root_joint pitch", "root_joint yaw"]
    assert list(drawn["velocity (m/s)"]) == ["root_joint vx", "root_joint vy", "root_joint vz"]
    assert list(drawn["angular velocity (rad/s)"]) == ["root_joint ωx", "root_joint ωy", "root_joint ωz"]
    assert not any("q" in name for curves in drawn.values() for name in curves)  # no quaternion components
    # roll grows through ±π to 8 rad instead of wrapping
    np.testing.assert_allclose(drawn["angle (rad)"]["root_joint roll"], 4.0 * trajectory.t, atol=1e-9)
    np.testing.assert_allclose(drawn["angle (rad)"]["root_joint yaw"], 0.0, atol=1e-9)


def test_joints_name_the_curves_with_their_units_and_without_the_system_the_axes_say_so():
    slider_crank = mb.robots.load("slider_crank")  # crank and rod continuous (rad), slider prismatic (m)
    trajectory = replace(synthetic(slider_crank, np.array([2.0, -1.0, 0.3])), joint_names=list(slider_crank.joint_names))
    drawn = panels(trajectory_figures(trajectory, slider_crank)["state"])
    assert {label: list(curves) for label, curves in drawn.items()} == {
        "angle (rad)": ["crank_joint", "rod_joint"], "angular velocity (rad/s)": ["crank_joint", "rod_joint"],
        "position (m)": ["slider_joint"], "velocity (m/s)": ["slider_joint"]}
    np.testing.assert_array_equal(drawn["position (m)"]["slider_joint"], trajectory.q[:, 2])
    # without the system: the joints the trajectory records name the columns; no unit is made up
    drawn = panels(trajectory_figures(trajectory)["state"])
    assert {label: list(curves) for label, curves in drawn.items()} == {
        "q (units unknown: pass system=)": ["crank_joint", "rod_joint", "slider_joint"],
        "v (units unknown: pass system=)": ["crank_joint", "rod_joint", "slider_joint"]}


def test_roll_pitch_yaw_inverts_urdf_rpy():
    rpy = np.array([[0.3, -0.4, 1.2], [-2.0, 1.0, -3.0], [0.0, 0.0, 0.0]])
    quat = rotation_to_quat(rpy_to_rotation(rpy))
    # one state at a time, so that unwrapping along time does not join them
    np.testing.assert_allclose(np.vstack([roll_pitch_yaw(q[None]) for q in quat]), rpy, atol=1e-12)


def test_every_axis_has_a_unit_and_residuals_are_logarithmic(diff_drive):
    trajectory = synthetic(diff_drive, np.array([0.1, 0.0, 0.5, 1.0, 1.0]))
    figures = trajectory_figures(trajectory, diff_drive)
    assert set(figures) == {"state", "energy", "residual", "multipliers"}
    for name, figure in figures.items():
        for ax in figure.axes:
            assert ax.get_ylabel().endswith(UNITS) or name == "residual", (name, ax.get_ylabel())
    residual = figures["residual"].axes[0]
    assert residual.get_yscale() == "log"
    assert residual.get_ylabel() == "max(|φ|, |A v + b|) (m, m/s)"
    # exact zeros are drawn below the tolerance line, not dropped by the log scale
    curves = {line.get_label(): line.get_ydata() for line in residual.get_lines()}
    zeros = curves["residual (exact zeros drawn at 1e-14)"]
    assert np.all(zeros > 0.0) and np.all(zeros < 1e-12)
    assert "projection tolerance 1e-12" in curves
    multipliers = figures["multipliers"].axes
    assert [ax.get_ylabel() for ax in multipliers] == ["λ (N)"]
    assert legend(multipliers[0]) == diff_drive.row_names
    assert figures["energy"].axes[0].get_ylabel() == "E − E₀ (J)"


def test_multiplier_units_follow_the_constraint_rows():
    four_bar = mb.robots.load("four_bar")
    closure = mb.LoopClosure("coupler_tip", "rocker_tip", kind="revolute")  # 3 force rows, 2 moment rows
    user = mb.Holonomic(lambda q, t: np.array([q[0] - q[2]]), name="user")
    system = mb.ConstrainedSystem(four_bar, [closure, user])
    figures = trajectory_figures(synthetic(system, np.zeros(3)), system)
    ylabels = [ax.get_ylabel() for ax in figures["multipliers"].axes]
    assert ylabels == ["λ (N)", "λ (N·m)", "λ (J per unit of φ)"]
    assert [len(ax.get_lines()) for ax in figures["multipliers"].axes] == [3, 2, 1]
    assert figures["residual"].axes[0].get_ylabel() == "max(|φ|, |A v + b|) (units of φ, of A v + b)"
    units = ["N", "N", "N", "N·m", "N·m", "N·m"]
    figures = trajectory_figures(synthetic(system, np.zeros(3)), system, multiplier_units=units)
    assert [ax.get_ylabel() for ax in figures["multipliers"].axes] == ["λ (N)", "λ (N·m)"]
    assert figures["residual"].axes[0].get_ylabel() == "max(|φ|, |A v + b|) (m or rad, m/s or rad/s)"


def test_symbolic_system_names_and_given_units():
    sp = pytest.importorskip("sympy")
    from sympy.physics.mechanics import dynamicsymbols

    x, theta = dynamicsymbols("x theta")
    m, l, g = sp.symbols("m l g", positive=True)
    T = m / 2 * (x.diff() ** 2 + l**2 * theta.diff() ** 2)
    system = mb.LagrangianSystem([x, theta], T, m * g * l * (1 - sp.cos(theta))).numeric(m=1.0, l=1.0, g=9.81)
    n = 5
    trajectory = mb.Trajectory(t=np.linspace(0, 1, n), q=np.zeros((n, 2)), v=np.zeros((n, 2)), lam=np.zeros((n, 0)),
                               energy=np.zeros(n), residual=np.zeros(n))
    q_curves, v_curves = state_curves(trajectory, system)
    assert [c.name for c in q_curves] == [c.name for c in v_curves] == ["x", "theta"]
    drawn = panels(trajectory_figures(trajectory, system, coordinate_units=["m", "rad"])["state"])
    assert {label: list(curves) for label, curves in drawn.items()} == {
        "position (m)": ["x"], "velocity (m/s)": ["x"], "angle (rad)": ["theta"], "angular velocity (rad/s)": ["theta"]}
    assert set(trajectory_figures(trajectory, system)) == {"state", "energy"}  # no constraints


def test_wrong_labels_and_systems_are_refused(diff_drive):
    trajectory = synthetic(diff_drive, np.zeros(5))
    with pytest.raises(ValueError, match=r"one name per degree of freedom \(5\), got 6"):
        state_curves(trajectory, diff_drive, coordinate_labels=["x", "y", "cos θ", "sin θ", "left", "right"])
    with pytest.raises(ValueError, match="pass the system that was simulated"):
        state_curves(trajectory, mb.robots.load("double_pendulum"))
    # without a system: the columns of q, named as given, units unknown
    q_curves, v_curves = state_curves(trajectory, coordinate_labels=["x", "y", "c", "s", "l", "r"])
    assert [c.name for c in q_curves] == ["x", "y", "c", "s", "l", "r"]
    assert [c.name for c in v_curves] == [f"v[{k}]" for k in range(5)]
    assert {c.unit for c in q_curves + v_curves} == {""}


def test_plot_trajectory_writes_the_files(tmp_path, diff_drive):
    paths = plot_trajectory(synthetic(diff_drive, np.ones(5)), tmp_path / "figures", "dd", diff_drive)
    assert [os.path.basename(p) for p in paths] == ["dd_state.png", "dd_energy.png", "dd_residual.png",
                                                    "dd_multipliers.png"]
    assert all(os.path.getsize(p) > 1000 for p in paths)


def test_plotting_is_an_attribute_of_the_package():
    assert mb.plotting.plot_trajectory is plot_trajectory


def test_the_backend_is_left_alone(tmp_path):
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        import multibody as mb
        assert "matplotlib" not in sys.modules, "import multibody imported matplotlib"
        import matplotlib
        matplotlib.use("svg")
        plotting = mb.plotting
        assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
        model = mb.robots.load("double_pendulum")
        n = 4
        trajectory = mb.Trajectory(t=np.arange(n) * 0.1, q=np.zeros((n, 2)), v=np.zeros((n, 2)),
                                   lam=np.zeros((n, 0)), energy=np.zeros(n), residual=np.zeros(n))
        plotting.plot_trajectory(trajectory, {str(tmp_path)!r}, "p", model)
        plotting.plot_path(np.zeros((n, 2)), {str(tmp_path)!r}, "p", "path")
        assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
        assert "matplotlib.pyplot" not in sys.modules
        print("ok")
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"
