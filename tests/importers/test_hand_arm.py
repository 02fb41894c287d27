"""[hands] done when: an arm with a parallel gripper and a wrist F/T sensor, described the usual ros2_control way
(tests/importers/robots/hand_arm: one actuated knuckle and five ``<mimic>`` joints, a ``<sensor>`` block, a
GripperActionController and a force_torque_sensor_broadcaster in the YAML), imports without ``--allow-partial``,
holds at start with no fault, closes on a box in the twin (``stalled: true``; the box held while the arm moves),
publishes a wrench that matches MuJoCo's within the sensor's noise, and answers a ROS 2 ParallelGripperCommand goal
from pyzeros."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hild.action import GoalResult
from hild.api.goals import GoalEndpoint
from hild.config import load_config
from hild.crossing.ring import RingReader
from hild.cycle.engine import Engine
from hild.importers.ros2_control.importer import ImportResult
from tests.api.conftest import running
from tests.importers.helpers import ROBOTS, import_robot

HAND_ARM = ROBOTS / "hand_arm"
BOX_HALF_WIDTH = 0.02  # m, across the fingers
FORCE_NOISE, TORQUE_NOISE = 0.05, 0.002  # the twin's default F/T noise (std dev)
WRENCH = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")
# What the test adds to the imported twin: a table under the open gripper and a box on it, between the fingers.
SCENE = {
    "objects": [
        {"name": "table", "size": [0.1, 0.1, 0.01], "pos": [0.0, 0.0, 0.01], "fixed": True},
        {"name": "box", "size": [BOX_HALF_WIDTH, 0.015, 0.02], "pos": [0.0, 0.0, 0.04], "mass": 0.05},
    ],
    "friction_cone": "elliptic",
    "impratio": 10,
}


def imported(tmp_path: Path) -> ImportResult:
    return import_robot(HAND_ARM / "hand_arm.urdf", HAND_ARM / "hand_arm_controllers.yaml", tmp_path / "hand_arm.yaml")


def with_scene(result: ImportResult, ros2: bool = False) -> Path:
    """The imported config with the box on a table added to its twin, on the lockstep clock."""
    data = yaml.safe_load(result.config.read_text())
    data["hardware"]["twin"]["params"].update(SCENE)
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    if ros2:
        data["ros2"] = {"domain_id": 0, "namespace": "/"}
    path = result.config.with_name("hand_arm_scene.yaml")
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def started(config: Path) -> Engine:
    engine = Engine(load_config(config))
    engine.start()
    return engine


def goal(engine: Engine, controller: str, body: dict[str, Any], limit_s: float = 10.0) -> GoalResult:
    endpoint = GoalEndpoint.of(engine.manager.records[controller].instance.action_server())
    reply = endpoint.submit(body)
    assert reply["ok"], reply["error"]
    for _ in range(int(limit_s * engine.update_rate)):
        engine.run_cycles(1)
        for result in endpoint.collect():
            if result.goal_id == reply["goal_id"]:
                return result
    raise AssertionError(f"{controller}: no result after {limit_s} s")


def box_position(engine: Engine) -> np.ndarray:
    twin = engine.hardware[0].component
    return np.array(twin.data.body("box").xpos)


@pytest.fixture(scope="module")
def result(tmp_path_factory: pytest.TempPathFactory) -> ImportResult:
    return imported(tmp_path_factory.mktemp("hand_arm"))


def test_it_imports_without_allow_partial_with_the_hand_and_the_sensor_mapped(result: ImportResult) -> None:
    assert not result.report.partial
    cfg = load_config(result.config).config
    assert list(cfg.joints) == ["lift", "wrist", "finger_joint"]
    assert len(cfg.mimic_joints) == 5 and {m.joint for m in cfg.mimic_joints.values()} == {"finger_joint"}
    sensor = cfg.hardware["twin"].sensors["wrist_ft"]
    assert (sensor.type, sensor.frame_id) == ("force_torque", "ft_link")
    gripper = cfg.controllers["gripper_controller"]
    assert gripper.type == "parallel_gripper"
    assert gripper.params["closed_position"] == 0.8 and gripper.params["open_position"] == 0.0  # found on the twin
    assert gripper.params["max_effort"] == 1.5 and gripper.params["allow_stalling"] is True
    broadcaster = cfg.controllers["ft_broadcaster"]
    assert broadcaster.type == "force_torque_sensor_broadcaster" and broadcaster.autostart
    assert broadcaster.params == {"sensor_name": "wrist_ft", "frame_id": "ft_link", "publish_rate": 100.0}
    assert cfg.joints["finger_joint"].hold.kp >= 1.5 / (0.02 * 0.8)  # stiff enough to press with max_effort


def test_it_holds_at_start_with_no_fault(result: ImportResult) -> None:
    engine = started(with_scene(result))
    start, box = engine.state.position.copy(), box_position(engine)
    engine.run_cycles(1000)
    assert not engine.supervisor.fault.any() and not any(engine.sensor_gate.fault_text)
    np.testing.assert_allclose(engine.state.position, start, atol=1e-3)
    np.testing.assert_allclose(box_position(engine), box, atol=1e-3)  # the open fingers do not touch the box


def test_it_closes_on_the_box_and_carries_it_while_the_arm_moves(result: ImportResult) -> None:
    engine = started(with_scene(result))
    assert engine.switch(["gripper_controller", "arm_controller"], []).ok
    closed = goal(engine, "gripper_controller", {"position": "close"}).as_dict()
    assert closed["status"] == "succeeded" and closed["stalled"] is True and closed["reached_goal"] is False
    assert 0.2 < closed["position"] < 0.6  # stopped on the box, far from the closed end (0.8)
    assert closed["effort"] == pytest.approx(1.5, rel=0.05)  # pressing with max_effort
    before = box_position(engine)
    moved = goal(engine, "arm_controller", {"positions": [0.08, 0.8]}).as_dict()  # up 8 cm, wrist turned 0.8 rad
    assert moved["status"] == "succeeded"
    engine.run_cycles(500)
    after = box_position(engine)
    assert after[2] - before[2] == pytest.approx(0.08, abs=0.005)  # lifted off the table with the hand
    assert np.linalg.norm(after[:2] - before[:2]) < 0.005  # still between the fingers, on the wrist's axis


def mujoco_wrench(engine: Engine) -> np.ndarray:
    """MuJoCo's own force and torque sensors at the site the twin added for wrist_ft."""
    data = engine.hardware[0].component.data
    return np.concatenate([data.sensor("hild_wrist_ft_force").data, data.sensor("hild_wrist_ft_torque").data])


def test_the_wrench_matches_mujocos_within_the_sensors_noise(result: ImportResult) -> None:
    engine = started(with_scene(result))
    interfaces = engine.sensors.index_of([f"wrist_ft/{i}" for i in WRENCH])
    broadcaster = engine.manager.records["ft_broadcaster"].instance
    reader = RingReader(broadcaster.outputs()["wrench"].ring)
    deviations, published = [], []
    for _ in range(500):
        truth = mujoco_wrench(engine)  # MuJoCo's sensors as the last physics step left them: what the cycle reads
        engine.run_cycles(1)
        deviations.append(engine.sensors.values[interfaces] - truth)
        for seq, stamp, fields in reader.read():
            published.append((broadcaster.outputs()["wrench"].message(seq, stamp, fields), truth))
    deviations = np.array(deviations)
    assert np.abs(deviations[:, :3]).max() < 5 * FORCE_NOISE and np.abs(deviations[:, 3:]).max() < 5 * TORQUE_NOISE
    assert deviations[:, :3].std() == pytest.approx(FORCE_NOISE, rel=0.3)  # noise, not a bias or a frozen value
    assert not any(engine.sensor_gate.fault_text)
    # What the JSON topic carries (100 Hz: the newest sample of each read) is the same wrench, in ft_link.
    assert len(published) >= 90
    for message, truth in published[-10:]:
        assert message["frame_id"] == "ft_link" and message["fresh"]
        sent = [message["force"][a] for a in "xyz"] + [message["torque"][a] for a in "xyz"]
        np.testing.assert_allclose(sent[:3], truth[:3], atol=5 * FORCE_NOISE)
        np.testing.assert_allclose(sent[3:], truth[3:], atol=5 * TORQUE_NOISE)
    # MuJoCo's force sensor carries what hangs below ft_link: the gripper's weight (the box rests on the table).
    hanging = engine.hardware[0].component.model.body_subtreemass[engine.hardware[0].component.model.body("ft_link").id]
    assert np.linalg.norm(mujoco_wrench(engine)[:3]) == pytest.approx(hanging * 9.81, rel=0.01)


def test_it_answers_a_ros2_parallel_gripper_command_goal_from_pyzeros(result: ImportResult) -> None:
    pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")
    from tests.api.ros2.test_gripper_action import grasp_from_pyzeros  # pyzeros' message types: the extra

    with running(Engine(load_config(with_scene(result, ros2=True)))) as daemon:
        got = grasp_from_pyzeros(daemon, "pyzeros_hand_arm", 0.8, 1.0, 0.5, "gripper_controller", "finger_joint")
    assert got["switched"].ok and got["accepted"].accepted
    done = got["result"]
    assert done.status == 4 and done.result.stalled and not done.result.reached_goal  # SUCCEEDED: on the box
    assert list(done.result.state.name) == ["finger_joint"]
    assert 0.2 < done.result.state.position[0] < 0.6
    assert done.result.state.effort[0] == pytest.approx(1.0, rel=0.05)  # the goal's own max effort
