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
