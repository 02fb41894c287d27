"""``<sensor>`` blocks of ``<ros2_control>`` and force_torque_sensor_broadcaster: what maps, what is refused."""

from __future__ import annotations

from pathlib import Path

import pytest

from hild.config import load_config
from hild.importers.ros2_control.report import ImportFailure
from tests.importers.helpers import ROBOTS, copy_robot, import_robot

HAND_ARM = ROBOTS / "hand_arm"


def with_sensor(tmp_path: Path, sensor: str, controllers: str | None = None) -> tuple[Path, Path]:
    """A copy of the hand arm whose <sensor> block is ``sensor`` (and whose controllers file is ``controllers``)."""
    robot = copy_robot(HAND_ARM, tmp_path)
    urdf = robot / "hand_arm.urdf"
    text = urdf.read_text()
    start, end = text.index('    <sensor name="wrist_ft">'), text.index("    </sensor>") + len("    </sensor>")
    urdf.write_text(text[:start] + sensor + text[end:])
    yaml_path = robot / "hand_arm_controllers.yaml"
    if controllers is not None:
        yaml_path.write_text(controllers)
    return urdf, yaml_path


ARM_ONLY = """\
controller_manager:
  ros__parameters:
    update_rate: 500
    arm_controller:
      type: joint_trajectory_controller/JointTrajectoryController
arm_controller:
  ros__parameters:
    joints: [lift, wrist]
"""


def test_an_imu_sensor_maps_to_the_twins_imu(tmp_path: Path) -> None:
    interfaces = "".join(
        f'<state_interface name="{n}"/>'
        for n in ("orientation.x", "orientation.y", "orientation.z", "orientation.w", "angular_velocity.x")
    )
    urdf, controllers = with_sensor(
        tmp_path, f'<sensor name="wrist_imu">{interfaces}<param name="frame_id">wrist_link</param></sensor>', ARM_ONLY
    )
    result = import_robot(urdf, controllers, tmp_path / "out.yaml")
    sensor = load_config(result.config).config.hardware["twin"].sensors["wrist_imu"]
    assert (sensor.type, sensor.frame_id) == ("imu", "wrist_link")
    mapped = [f.text for f in result.report.of("mapped") if "wrist_imu" in f.text]
    assert mapped and "it also offers angular_velocity.y" in mapped[0]  # the twin gives the full set


def test_a_sensor_of_another_kind_is_not_supported(tmp_path: Path) -> None:
    urdf, controllers = with_sensor(
        tmp_path,
        '<sensor name="range"><state_interface name="range"/><param name="frame_id">ft_link</param></sensor>',
        ARM_ONLY,
    )
    with pytest.raises(ImportFailure, match="neither a force/torque sensor's nor an IMU's"):
        import_robot(urdf, controllers, tmp_path / "out.yaml")  # partial without --allow-partial
    result = import_robot(urdf, controllers, tmp_path / "out.yaml", allow_partial=True)
    assert not load_config(result.config).config.hardware["twin"].sensors


def test_a_sensor_frame_that_is_no_link_is_refused_at_its_line(tmp_path: Path) -> None:
    urdf, controllers = with_sensor(
        tmp_path,
        '<sensor name="wrist_ft"><state_interface name="force.z"/>\n<param name="frame_id">tool0</param></sensor>',
        ARM_ONLY,
    )
    with pytest.raises(ImportFailure, match="frame_id 'tool0' is not a link of the URDF") as failure:
        import_robot(urdf, controllers, tmp_path / "out.yaml")
    assert "hand_arm.urdf:" in str(failure.value)


def test_a_broadcaster_naming_no_force_torque_sensor_is_refused(tmp_path: Path) -> None:
    text = (HAND_ARM / "hand_arm_controllers.yaml").read_text().replace("sensor_name: wrist_ft", "sensor_name: tcp_fts")
    sensor = '<sensor name="wrist_ft"><state_interface name="force.x"/><param name="frame_id">ft_link</param></sensor>'
    urdf, controllers = with_sensor(tmp_path, sensor, text)
    with pytest.raises(ImportFailure, match=r"sensor_name 'tcp_fts' is no force/torque <sensor>.*wrist_ft"):
        import_robot(urdf, controllers, tmp_path / "out.yaml")
