"""The twin's sensors: MuJoCo's force/torque (and IMU) sensors at a site, added when the model has none."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

from drivers.mujoco.twin import MujocoTwin
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.dynamics.model import SensorMount, load_model
from hild.hardware import HardwareError
from tests.conftest import CONFIGS
from tests.helpers import component

FORCE_NOISE = 0.05  # N: the twin's default std dev per force component
G = 9.81


def arm6(tmp_path: Path, sensors: dict[str, Any], model: str = "arm6.xml") -> Engine:
    """arm6 on the twin in lockstep, with ``sensors`` on its component, started."""
    for name in ("arm6.xml", "arm6.urdf"):
        shutil.copy(CONFIGS / name, tmp_path)
    config = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    config["clock"] = {"source": "sim", "real_time_factor": 0}
    config["hardware"]["twin"]["params"]["model"] = model
    if model.endswith(".urdf"):  # no keyframes in a URDF: the same home pose, joint by joint
        del config["hardware"]["twin"]["params"]["keyframe"]
        home = dict(zip(config["joints"], [0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0], strict=True))
        config["hardware"]["twin"]["params"]["initial_positions"] = home
    config["hardware"]["twin"]["sensors"] = sensors
    config["controllers"] = {
        "ftb": {"type": "force_torque_sensor_broadcaster", "params": {"sensor_name": "wrist_ft"}, "autostart": True}
    }
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    engine = Engine(load_config(path))
    engine.start()
    return engine


def twin(engine: Engine) -> MujocoTwin:
    return component(engine, MujocoTwin)


def mujoco_force(engine: Engine, site: str) -> np.ndarray:
    """MuJoCo's own force sensor at ``site`` (what the twin read, before its noise)."""
    m, d = twin(engine).model, twin(engine).data
    sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, site)
    i = next(
        i for i in range(m.nsensor) if m.sensor_type[i] == mujoco.mjtSensor.mjSENS_FORCE and m.sensor_objid[i] == sid
    )
    return np.array(d.sensordata[m.sensor_adr[i] : m.sensor_adr[i] + 3])


WRIST = {"wrist_ft": {"type": "force_torque", "frame_id": "wrist_3_link"}}


def test_at_rest_the_wrist_sensor_reads_mujocos_force_within_its_noise_the_weight_below_it(tmp_path: Path) -> None:
    engine = arm6(tmp_path, WRIST)
    engine.run_cycles(250)  # settle in hold
    force = engine.sensors.values[:3].copy()
    exact = mujoco_force(engine, "hild_wrist_ft")
    assert np.all(np.abs(force - exact) < 5 * FORCE_NOISE)  # the same values, plus the noise
    assert np.any(force != exact)  # the noise is really there
    m = twin(engine).model
    below = m.body_subtreemass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wrist_3_link")]
    assert abs(np.linalg.norm(exact) - below * G) < 0.01 * below * G  # the weight of what hangs below the sensor
    assert engine.sensors.fresh[0]
    assert engine.status()["sensors"][0]["fault"] is None


def test_a_load_pressed_on_the_tool_changes_the_reading(tmp_path: Path) -> None:
    engine = arm6(tmp_path, WRIST)
    engine.run_cycles(250)
    at_rest = mujoco_force(engine, "hild_wrist_ft")
    m, d = twin(engine).model, twin(engine).data
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wrist_3_link")
    d.xfrc_applied[body, :3] = [0.0, 0.0, -20.0]  # 20 N pressing down on the tool
    engine.run_cycles(250)  # hold re-settles against it
    pressed = engine.sensors.values[:3].copy()
    change = np.linalg.norm(pressed - at_rest)
    assert abs(change - 20.0) < 1.0, change  # the 20 N, seen in the sensor's frame
    assert np.all(np.abs(pressed - mujoco_force(engine, "hild_wrist_ft")) < 5 * FORCE_NOISE)


def test_sim_noise_is_seeded_and_keeps_the_frozen_check_quiet(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first, second = arm6(tmp_path / "a", WRIST), arm6(tmp_path / "b", WRIST)
    first.run_cycles(100)
    second.run_cycles(100)
    np.testing.assert_array_equal(first.sensors.values, second.sensors.values)  # seeded: runs repeat
    assert not [e for e in first.events.drain() if "frozen" in e.message]


def test_a_urdf_arm_gets_its_sensor_added_on_a_link(tmp_path: Path) -> None:
    """A URDF cannot declare MuJoCo sensors: the twin adds the site and the pair before compiling. On tool0 (an empty
    flange: nothing hangs below it) the sensor reads nothing but its noise, until a load is pressed on the flange."""
    engine = arm6(tmp_path, {"wrist_ft": {"type": "force_torque", "frame_id": "tool0"}}, model="arm6.urdf")
    engine.run_cycles(100)
    assert np.linalg.norm(mujoco_force(engine, "hild_wrist_ft")) < 1e-6
    assert np.all(np.abs(engine.sensors.values[:3]) < 5 * FORCE_NOISE)
    m, d = twin(engine).model, twin(engine).data
    d.xfrc_applied[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool0"), :3] = [15.0, 0.0, 0.0]
    engine.run_cycles(250)
    exact = mujoco_force(engine, "hild_wrist_ft")
    assert abs(np.linalg.norm(exact) - 15.0) < 0.1
    assert np.all(np.abs(engine.sensors.values[:3] - exact) < 5 * FORCE_NOISE)


def test_an_imu_reads_gravity_and_a_unit_quaternion(tmp_path: Path) -> None:
    engine = arm6(tmp_path, {**WRIST, "wrist_imu": {"type": "imu", "frame_id": "forearm_link"}})
    engine.run_cycles(100)
    imu = engine.sensors.values[6:]
    assert abs(np.linalg.norm(imu[:4]) - 1.0) < 1e-9  # orientation x, y, z, w without noise by default
    assert np.all(np.abs(imu[4:7]) < 0.05)  # at rest: noise only
    assert abs(np.linalg.norm(imu[7:]) - G) < 0.2  # the accelerometer reads gravity's reaction


def test_the_models_own_sensors_at_a_site_are_used_not_doubled(tmp_path: Path) -> None:
    xml = (CONFIGS / "arm6.xml").read_text()
    xml = xml.replace("</mujoco>", '<sensor><force site="tool"/><torque site="tool"/></sensor></mujoco>')
    (tmp_path / "arm6_sensed.xml").write_text(xml)
    mount = SensorMount("wrist_ft", "force_torque", "wrist_3_link", site="tool")
    assert load_model(tmp_path / "arm6_sensed.xml", sensors=[mount]).nsensor == 2
    assert load_model(CONFIGS / "arm6.xml", sensors=[mount]).nsensor == 2  # added when missing


def test_a_frame_that_is_no_body_is_refused_at_configure(tmp_path: Path) -> None:
    with pytest.raises(HardwareError, match="frame 'flange' is not a body of the model"):
        arm6(tmp_path, {"wrist_ft": {"type": "force_torque", "frame_id": "flange"}})
    with pytest.raises(HardwareError, match="no site 'nowhere'"):
        arm6(tmp_path, {"wrist_ft": {"type": "force_torque", "frame_id": "x", "params": {"site": "nowhere"}}})
