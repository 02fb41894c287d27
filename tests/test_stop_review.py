"""``hild check`` with the robot's model loaded (issue [trust], finding 6): a limp stop of a gravity-loaded joint
is a warning naming the joints, their torque and the fix; a model file the daemon could not use — missing, named by
a hardware section, not loadable, or without the config's joints — is an error, so ``check`` no longer says ok
where ``run`` fails."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from hild.cli import main
from hild.config import ConfigError, load_config
from hild.config.stop_review import check_with_model, review_model
from tests.conftest import CONFIGS

Write = Callable[..., Path]


def twin_doc(**safety: float) -> dict[str, Any]:
    data = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    data["safety"] = {**data.get("safety", {}), **safety}
    return data


def vcan_doc(**safety: float) -> dict[str, Any]:
    data = yaml.safe_load((CONFIGS / "arm6_vcan.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["safety"] = {**data["safety"], **safety}
    return data


def limp_warnings(path: Path) -> list[str]:
    loaded = load_config(path)
    check_with_model(loaded)
    return [n for n in loaded.notes if "stopping releases" in n]


def test_a_limp_stop_of_gravity_loaded_joints_is_a_warning_naming_them(write_config: Write) -> None:
    path = write_config(twin_doc())
    (warning,) = limp_warnings(path)
    assert warning.startswith(f"warning: {path}:")  # file:line, like every other finding
    assert ": safety.stop_descent: 0 s, so stopping releases gravity-loaded joints limp: shoulder_lift (up to " in (
        warning
    )
    assert "effort limit 150" in warning
    assert "wrist_3" not in warning and "shoulder_pan" not in warning  # no weight on them
    assert "set safety.stop_descent (e.g. 2.0 s" in warning
    assert "on_deactivate" not in warning  # the twin has no such param: no fix it cannot take
    assert limp_warnings(write_config(twin_doc(stop_descent=2.0))) == []


def test_drives_that_hold_at_stop_draw_no_warning(write_config: Write) -> None:
    data = vcan_doc(stop_descent=0.0)
    (warning,) = limp_warnings(write_config(data))  # on_deactivate: disable → limp
    assert "or on_deactivate: hold on hardware arm" in warning
    data["hardware"]["arm"]["params"]["on_deactivate"] = "hold"
    assert limp_warnings(write_config(data)) == []


def test_weightless_joints_draw_no_warning(write_config: Write) -> None:
    data = twin_doc()
    for joint in data["joints"].values():  # 2 % of this dwarfs what the arm weighs
        joint["limits"]["effort"] = 1e6
    assert limp_warnings(write_config(data)) == []


def test_the_verdict_does_not_change_between_runs(write_config: Write) -> None:
    path = write_config(twin_doc())
    assert review_model(load_config(path)) == review_model(load_config(path))


def test_check_prints_the_warning_and_passes(write_config: Write, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(write_config(twin_doc()))]) == 0
    out = capsys.readouterr().out
    assert "  warning: " in out and "stopping releases gravity-loaded joints limp" in out and out.endswith("ok\n")


def test_a_missing_model_file_of_a_hardware_section_fails_the_check(
    write_config: Write, capsys: pytest.CaptureFixture[str]
) -> None:
    data = twin_doc()
    data["hardware"]["twin"]["params"]["model"] = "nowhere.xml"
    path = write_config(data)
    with pytest.raises(ConfigError) as refused:
        load_config(path)
    assert "hardware.twin.params.model" in str(refused.value) and "nowhere.xml" in str(refused.value)
    assert main(["check", str(path)]) == 1
    assert "file not found" in capsys.readouterr().err


def test_a_missing_robot_model_fails_the_check(write_config: Write, capsys: pytest.CaptureFixture[str]) -> None:
    data = vcan_doc()
    data["robot"]["model"] = "nowhere.xml"
    assert main(["check", str(write_config(data))]) == 1
    err = capsys.readouterr().err
    assert "robot.model: file not found" in err and "nowhere.xml" in err


def test_a_model_the_daemon_could_not_use_fails_the_check(
    write_config: Write, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></mujoco>")
    data = vcan_doc()
    data["robot"]["model"] = str(broken)
    path = write_config(data)
    load_config(path)  # the file exists: the loader alone says nothing
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"{path}:" in err and "robot.model: model " in err and "MuJoCo could not load it" in err

    data = twin_doc()
    data["joints"]["elbow_renamed"] = data["joints"].pop("elbow")
    data["hardware"]["twin"]["joints"]["elbow_renamed"] = data["hardware"]["twin"]["joints"].pop("elbow")
    data["controllers"] = {}  # they name the elbow too; not what this is about
    assert main(["check", str(write_config(data, "renamed.yaml"))]) == 1
    assert "joints not in the model: elbow_renamed" in capsys.readouterr().err


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_configs_pass_the_check(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    limp = "stopping releases gravity-loaded joints limp" in out
    assert limp == ("twin" in path.name)  # the CAN configs lower the arm; the twins say why they do not
