"""The config loader: a valid file loads; each kind of bad file gives a message naming where and what."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from hild.cli import main
from hild.config import ConfigError, json_schema, load_config
from tests.conftest import merge, mock_robot


def issues_of(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return [str(i) for i in info.value.issues]


def test_valid_config_loads_with_plugins(write_config: Callable[..., Path]) -> None:
    loaded = load_config(write_config(mock_robot()))
    assert loaded.joint_names == ("a", "b", "c")
    assert loaded.driver_params["bus"].initial_positions == {"a": 0.1, "b": -0.2, "c": 0.3}
    assert loaded.controller_params["fwd"].command_timeout == 0.2
    assert "robot 'mock3' at 500 Hz" in loaded.summary()


def test_unknown_key_names_line_path_and_allowed_keys(write_config: Callable[..., Path]) -> None:
    text = """\
robot: {name: r}
update_rate: 500
hardware:
  bus: {driver: mock, joints: {a: {}}}
joints:
  a:
    limits: {position: {lower: -1, upper: 1}, velocity: 1, effort: 1}
    hold: {kp: 1, kd: 1, kpp: 3}
"""
    [issue] = issues_of(write_config(text))
    assert issue.startswith(f"{write_config(text)}:8: joints.a.hold.kpp: unknown key")
    assert "allowed: kp, kd" in issue


def test_wrong_type_says_expected_and_found(write_config: Callable[..., Path]) -> None:
    [issue] = issues_of(write_config(merge(mock_robot(), {"update_rate": "fast"})))
    assert ": update_rate: expected:" in issue
    assert "number" in issue
    assert "found 'fast' (str)" in issue


def test_missing_key_and_bad_limits_are_all_reported(write_config: Callable[..., Path]) -> None:
    data = mock_robot()
    del data["joints"]["a"]["hold"]
    data["joints"]["b"]["limits"]["position"] = {"lower": 1, "upper": -1}
    data["joints"]["c"]["limits"]["soft_margin"] = 5.0
    issues = issues_of(write_config(data))
    assert any("joints.a.hold: missing required key" in i for i in issues)
    assert any("joints.b.limits.position" in i and "must be below upper" in i for i in issues)
    assert any("joints.c.limits" in i and "soft_margin 5.0 leaves no room" in i for i in issues)


def test_duplicate_yaml_key_is_an_error(write_config: Callable[..., Path]) -> None:
    text = "robot: {name: r}\nupdate_rate: 500\nupdate_rate: 1000\n"
    issues = issues_of(write_config(text))
    assert any(":3: update_rate: duplicate key" in i for i in issues)


def test_invalid_yaml_gives_a_line(write_config: Callable[..., Path]) -> None:
    [issue] = issues_of(write_config("robot: {name: r\nupdate_rate: [\n"))
    assert "not valid YAML" in issue


def test_cross_references(write_config: Callable[..., Path]) -> None:
    data = mock_robot()
    data["hardware"]["second"] = {"driver": "mock", "joints": {"a": {}, "ghost": {}}}
    data["joints"]["lonely"] = data["joints"]["a"]
    data["controllers"]["fwd"]["params"]["joints"] = ["a", "nope"]
    data["controllers"]["fwd"]["fallback_controllers"] = ["fwd", "missing"]
    issues = issues_of(write_config(data))
    text = "\n".join(issues)
    assert "hardware.second.joints.a: joint 'a' already belongs to hardware 'bus'" in text
    assert "hardware.second.joints.ghost: joint 'ghost' is not defined under joints" in text
    assert "joints.lonely: joint 'lonely' belongs to no hardware component" in text
    assert "controllers.fwd.params.joints[1]: unknown joint 'nope'" in text
    assert "controllers.fwd.fallback_controllers[0]: a controller cannot be its own fallback" in text
    assert "controllers.fwd.fallback_controllers[1]: unknown controller 'missing'" in text


def test_unknown_plugins_and_bad_plugin_params(write_config: Callable[..., Path]) -> None:
    data = merge(
        mock_robot(),
        {
            "hardware": {"bus": {"driver": "warpdrive"}},
            "controllers": {"fwd": {"params": {"interface": "torque"}}, "x": {"type": "magic"}},
        },
    )
    text = "\n".join(issues_of(write_config(data)))
    assert "hardware.bus.driver: unknown driver 'warpdrive' (known: " in text and "mock" in text
    assert "controllers.x.type: unknown controller type 'magic'" in text
    assert "controllers.fwd.params.interface: expected:" in text and "found 'torque'" in text


def test_conflicting_autostart_claims(write_config: Callable[..., Path]) -> None:
    data = mock_robot()
    data["controllers"]["fwd"]["autostart"] = True
    data["controllers"]["fwd2"] = dict(data["controllers"]["fwd"])
    text = "\n".join(issues_of(write_config(data)))
    assert "controllers.fwd2.autostart: claims 'a/position' like 'fwd'; both autostart" in text


def test_missing_model_file(write_config: Callable[..., Path]) -> None:
    text = "\n".join(issues_of(write_config(merge(mock_robot(), {"robot": {"model": "nowhere.xml"}}))))
    assert "robot.model: file not found" in text


def test_cli_check_exit_codes(write_config: Callable[..., Path], capsys: pytest.CaptureFixture[str]) -> None:
    good = write_config(mock_robot(), "good.yaml")
    bad = write_config(merge(mock_robot(), {"update_rate": 0}), "bad.yaml")
    assert main(["check", str(good)]) == 0
    assert "ok" in capsys.readouterr().out
    assert main(["check", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "1 error(s)" in err and "update_rate" in err and "found 0 (int)" in err


def test_schema_includes_plugin_params(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema == json.loads(json.dumps(json_schema()))
    assert schema["additionalProperties"] is False
    variants = {v["if"]["properties"]["type"]["const"]: v for v in schema["$defs"]["ControllerSection"]["allOf"]}
    fwd = variants["forward_command"]["then"]["properties"]["params"]
    assert set(fwd["properties"]) == {"joints", "interface", "command_timeout"}
    drivers = {v["if"]["properties"]["driver"]["const"] for v in schema["$defs"]["HardwareSection"]["allOf"]}
    assert {"mock", "mujoco"} <= drivers


def test_missing_robot_description_file(write_config: Callable[..., Path]) -> None:
    """`hild check` names the URDF ROS 2 would be given, not only the daemon at run time."""
    data = merge(mock_robot(), {"ros2": {"robot_description": "nowhere.urdf"}})
    assert "ros2.robot_description: file not found" in "\n".join(issues_of(write_config(data)))
