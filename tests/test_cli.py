"""The command line: help, --version, info, check, demo --list (running a demo is exercised in
test_nonholonomic_simulation.py)."""

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


@pytest.mark.parametrize("command", ["info", "check"])
def test_missing_file_directory_and_unknown_robot_give_one_message_and_status(capsys, tmp_path, command):
    """info and check answer the same wrong input with the same line on standard error and status 2,
    before check looks for Pinocchio."""
    cases = {
        str(tmp_path / "absent.urdf"): f"multibody {command}: no such file: {str(tmp_path / 'absent.urdf')!r}",
        str(tmp_path): f"multibody {command}: {str(tmp_path)!r} is a directory; give a URDF file or a robot name",
        "no_such_robot": f"multibody {command}: 'no_such_robot' is neither a URDF file nor a known robot: "
                         "no shipped robot named 'no_such_robot'",
    }
    for source, message in cases.items():
        assert main([command, source]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.startswith(message), captured.err
        assert captured.err.count("\n") == 1


def test_info_takes_a_robot_name_or_a_path(capsys):
    assert main(["info", "diff_drive"]) == 0
    by_name = capsys.readouterr().out
    assert main(["info", mb.robots.path("diff_drive")]) == 0
    assert capsys.readouterr().out == by_name
    assert main(["info", "diff_drive", "--floating-base"]) == 0
    assert "nq = 13, nv = 11" in capsys.readouterr().out


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"multibody {mb.__version__}"


def test_demo_list(capsys):
    from multibody.demos import DEMOS

    assert main(["demo", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == sorted(DEMOS)
    assert "rolling-ball" in DEMOS and any(line.startswith("rolling-ball") and "ball rolling" in line for line in lines)
    assert main(["demo"]) == 2
    assert "give a demo name, or --list" in capsys.readouterr().err
    assert main(["demo", "no-such-demo"]) == 2
    assert "multibody demo: unknown demo 'no-such-demo'; available: " in capsys.readouterr().err


def test_check_against_pinocchio(capsys):
    pytest.importorskip("pinocchio")
    assert main(["check", mb.robots.path("double_pendulum"), "--samples", "3"]) == 0
    out = capsys.readouterr().out
    assert "all quantities agree with Pinocchio" in out
    assert "coriolis (recursive)" in out and "forward dynamics, backward error" in out
