"""The command line: help, info, check (demo is exercised in test_nonholonomic_simulation.py)."""

import pytest

import multibody as mb
from multibody.cli import main


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for command in ("demo", "info", "check"):
        assert command in out


def test_info_prints_tree_sizes_mass_and_warnings(capsys, tmp_path):
    assert main(["info", "double_pendulum"]) == 0
    out = capsys.readouterr().out
    assert "nq = 2, nv = 2" in out and "total mass = 2 kg" in out
    assert "shoulder [continuous axis [0.0, 1.0, 0.0]] -> link1 1 kg" in out
    # A suspicious inertia is reported: a placeholder link with impossible numbers fixed to a valid body.
    urdf = tmp_path / "placeholder.urdf"
    urdf.write_text(
        '<robot name="r"><link name="base"/>'
        '<link name="arm"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/>'
        '</inertial></link>'
        '<link name="tag"><inertial><mass value="0.000001"/><inertia ixx="0" iyy="0" izz="0.000003" ixy="0" ixz="0" iyz="0"/>'
        '</inertial></link>'
        '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>'
        '<joint name="f" type="fixed"><parent link="arm"/><child link="tag"/></joint></robot>')
    assert main(["info", str(urdf)]) == 0
    out = capsys.readouterr().out
    assert "warning: link 'tag': principal moments violate the triangle inequality" in out
    assert "warning: link 'tag': placeholder mass" in out


def test_info_on_bad_input_exits_with_a_message(capsys, tmp_path):
    urdf = tmp_path / "bad.urdf"
    urdf.write_text('<robot name="x"><link name="a"/><link name="b"/>'
                    '<joint name="j" type="bogus"><parent link="a"/><child link="b"/></joint></robot>')
    assert main(["info", str(urdf)]) == 2
    err = capsys.readouterr().err
    assert "bad.urdf" in err and "<joint name='j'>" in err and "unknown joint type 'bogus'" in err
    with pytest.raises(SystemExit, match="neither a URDF file nor a shipped robot"):
        main(["info", "no_such_robot"])


def test_check_against_pinocchio(capsys):
    pytest.importorskip("pinocchio")
    assert main(["check", mb.robots.path("double_pendulum"), "--samples", "3"]) == 0
    out = capsys.readouterr().out
    assert "all quantities agree with Pinocchio" in out
    assert "coriolis (recursive)" in out and "forward dynamics, backward error" in out
