"""`hild import ros2-control` through hild's own command line."""

from __future__ import annotations

from pathlib import Path

import pytest

from hild.cli import main
from hild.config import load_config
from tests.importers.helpers import MY_ARM, RRBOT


def test_cli_imports_prints_the_report_and_refuses_a_second_run_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    output = tmp_path / "arm.yaml"
    argv = [
        "import",
        "ros2-control",
        "--urdf",
        str(MY_ARM / "urdf" / "my_arm.urdf.xacro"),
        "--controllers",
        str(MY_ARM / "config" / "my_arm_controllers.yaml"),
        "-o",
        str(output),
        "--package-root",
        f"my_arm_description={MY_ARM}",
        "--xacro-arg",
        "prefix:=left_",
        "--robot-name",
        "left arm",
        "--allow-partial",  # its admittance controller has no hild counterpart
    ]
    assert main(argv) == 1  # with prefix left_, the controllers' joint names do not exist
    err = capsys.readouterr().err
    assert "controller 'arm_controller' names joint 'shoulder_pan', which does not exist" in err
    assert err.rstrip().endswith("nothing was written") and not output.exists()

    controllers = tmp_path / "controllers.yaml"
    text = (MY_ARM / "config" / "my_arm_controllers.yaml").read_text()
    for joint in ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3", "gripper_finger_left"):
        text = text.replace(f"- {joint}", f"- left_{joint}").replace(f"{joint}:", f"left_{joint}:")
        text = text.replace(f"[{joint},", f"[left_{joint},").replace(f" {joint},", f" left_{joint},")
    controllers.write_text(text)
    argv[5] = str(controllers)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "Mapped (" in out and "Approximated (" in out and "Not supported (" in out
    assert f"wrote {output}" in out
    cfg = load_config(output).config
    assert cfg.robot.name == "left_arm"
    assert "left_shoulder_pan" in cfg.joints and (tmp_path / "arm.urdf").is_file()

    assert main(argv) == 1
    assert "exists: pass --force" in capsys.readouterr().err
    assert main([*argv, "--force"]) == 0


def test_cli_rejects_malformed_options(capsys: pytest.CaptureFixture[str]) -> None:
    base = ["import", "ros2-control", "--urdf", str(RRBOT / "rrbot.urdf"), "--controllers", "c.yaml", "-o", "o.yaml"]
    for bad in (["--package-root", "nodir"], ["--xacro-arg", "novalue"]):
        with pytest.raises(SystemExit) as info:
            main(base + bad)
        assert info.value.code == 2
    assert "expected NAME:=VALUE" in capsys.readouterr().err


def test_cli_several_controller_files_launch_arguments_and_partial_imports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    arm3 = RRBOT.parent / "arm3"
    base = ["import", "ros2-control", "--urdf", str(arm3 / "urdf" / "arm3.urdf.xacro"), "-o"]
    files = [str(arm3 / "config" / "arm3_controllers.yaml"), str(arm3 / "config" / "update_rate.yaml")]
    argv = [*base, str(tmp_path / "a" / "arm3.yaml"), "--controllers", *files, "--arg", "prefix=right_"]
    assert main(argv) == 0
    cfg = load_config(tmp_path / "a" / "arm3.yaml").config
    assert cfg.update_rate == 250 and "right_pan" in cfg.joints
    capsys.readouterr()
    repeated = [*base, str(tmp_path / "b" / "arm3.yaml"), "--controllers", files[0], "--controllers", files[1]]
    assert main([*repeated, "--arg", "prefix:=", "--xacro-arg", "collision:=mesh", "--keep-self-contacts"]) == 0
    assert "contacts kept (--keep-self-contacts)" in capsys.readouterr().out
    assert main([*base, str(tmp_path / "c" / "arm3.yaml"), "--controllers", *files]) == 1
    assert "$(var prefix) has no value: pass --arg prefix=VALUE" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main([*argv, "--arg", "=x"])
    assert info.value.code == 2 and "expected NAME=VALUE" in capsys.readouterr().err

    my_arm = ["--urdf", str(MY_ARM / "urdf" / "my_arm.urdf.xacro")]
    my_arm += ["--controllers", str(MY_ARM / "config" / "my_arm_controllers.yaml")]
    out = tmp_path / "d" / "arm.yaml"
    assert main(["import", "ros2-control", *my_arm, "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "controller 'admittance_controller'" in err and "--allow-partial" in err and not out.exists()
    assert main(["import", "ros2-control", *my_arm, "-o", str(out), "--allow-partial"]) == 0
    assert "partial import (--allow-partial): 1 left out" in capsys.readouterr().out
