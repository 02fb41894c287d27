"""Sensors in the config: hardware.<component>.sensors, checked when the config loads (docs/config.md, "Sensors")."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml

from hild.config import ConfigError, load_config
from hild.interfaces import SensorLayout
from tests.conftest import CONFIGS, mock_robot


def with_sensors(sensors: dict[str, Any], config: dict[str, Any] | None = None) -> dict[str, Any]:
    config = config or mock_robot()
    config["hardware"]["bus"]["sensors"] = sensors
    return config


def load(config: dict[str, Any], tmp_path: Path) -> Any:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return load_config(path)


def refusal(config: dict[str, Any], tmp_path: Path) -> str:
    with pytest.raises(ConfigError) as caught:
        load(config, tmp_path)
    return str(caught.value)


FT = {"type": "force_torque", "frame_id": "tool"}
IMU = {"type": "imu", "frame_id": "base"}


def test_sensors_load_with_their_interfaces_and_default_ranges(tmp_path: Path) -> None:
    loaded = load(with_sensors({"wrist_ft": FT, "imu": {**IMU, "limits": {"angular_velocity": 10}}}), tmp_path)
    layout = SensorLayout.of(loaded.config)
    assert layout.names == ("wrist_ft", "imu")
    assert layout.sensors[0].interfaces() == [
        f"wrist_ft/{v}" for v in ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")
    ]
    assert layout.sensors[1].interfaces()[:4] == [f"imu/orientation.{a}" for a in "xyzw"]
    assert layout.sensors[1].interfaces()[4:] == [
        *(f"imu/angular_velocity.{a}" for a in "xyz"),
        *(f"imu/linear_acceleration.{a}" for a in "xyz"),
    ]
    assert layout.sensors[0].bounds == (500.0,) * 3 + (50.0,) * 3
    assert layout.sensors[1].bounds == (float("inf"),) * 4 + (10.0,) * 3 + (160.0,) * 3
    summary = loaded.summary()
    assert "sensor wrist_ft: force_torque in tool (force 500, torque 50)" in summary
    assert "sensor imu: imu in base (angular_velocity 10, linear_acceleration 160)" in summary


def test_a_sensor_named_as_a_joint_is_refused(tmp_path: Path) -> None:
    assert "sensor 'a' has a joint's name" in refusal(with_sensors({"a": FT}), tmp_path)


def test_sensor_names_are_unique_across_the_robot(tmp_path: Path) -> None:
    config = with_sensors({"ft": FT})
    config["hardware"]["hand"] = {"driver": "mock", "joints": {"c": {}}, "sensors": {"ft": FT}}
    del config["hardware"]["bus"]["joints"]["c"]
    assert "sensor 'ft' is already declared under hardware 'bus'" in refusal(config, tmp_path)


def test_limits_of_another_sensor_type_are_refused(tmp_path: Path) -> None:
    message = refusal(with_sensors({"ft": {**FT, "limits": {"angular_velocity": 3}}}), tmp_path)
    assert "limits ['angular_velocity'] do not apply to force_torque sensors" in message


def test_a_driver_without_sensors_refuses_them_clearly(tmp_path: Path) -> None:
    """The CAN drivers read no sensors: a config that gives them one is refused, naming the driver."""
    config = yaml.safe_load((CONFIGS / "arm6_can.yaml").read_text())
    shutil.copy(CONFIGS / "arm6.xml", tmp_path)
    component = next(iter(config["hardware"]))
    config["hardware"][component]["sensors"] = {"wrist_ft": FT}
    driver = config["hardware"][component]["driver"]
    assert driver == "mit_can"
    assert f"sensors.wrist_ft.type: driver {driver!r} cannot read a force_torque sensor: it reads no sensors" in (
        refusal(config, tmp_path)
    )


def test_a_sensors_params_are_the_drivers_sensor_params(tmp_path: Path) -> None:
    message = refusal(with_sensors({"ft": {**FT, "params": {"nosie": 1}}}), tmp_path)
    assert "hardware.bus.sensors.ft.params.nosie: unknown key" in message


def test_a_broadcaster_of_an_unknown_sensor_is_refused(tmp_path: Path) -> None:
    config = with_sensors({"imu": IMU})
    config["controllers"]["ftb"] = {"type": "force_torque_sensor_broadcaster", "params": {"sensor_name": "imu"}}
    message = refusal(config, tmp_path)
    assert "reads 'imu/force.x', which no sensor provides" in message


def test_a_broadcaster_takes_a_sensor_or_interface_names_not_both(tmp_path: Path) -> None:
    config = with_sensors({"ft": FT})
    config["controllers"]["ftb"] = {
        "type": "force_torque_sensor_broadcaster",
        "params": {"sensor_name": "ft", "interface_names": {"force": {"x": "ft/force.x"}}},
    }
    assert "give sensor_name or interface_names, not both" in refusal(config, tmp_path)
