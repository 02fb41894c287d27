"""configs/arm6_gripper_can.yaml against `hild emulate`'s drives with the MuJoCo twin behind them, in lockstep.

The gripper motor is a Damiao DM4310 (id 0x07, reply 0x17) driving the slide joint ``gripper`` of arm6_gripper.xml
through OpenArm's transmission (23.8 rad/m, the motor turning negative to open); ``gripper_mirror`` follows it in the
model through a joint equality (a mimic joint, not driven). The rig is tests/drivers/can/test_emulate_runtime.py's:
an in-process CAN-FD ``virtual`` bus, a cycle is ``engine.step`` then ``runtime.service(t + dt)``.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from drivers.can.emulator import DamiaoFirmware
from drivers.can.emulator.runtime import RuntimeOptions, build_runtime
from drivers.can.protocol.models import MODELS
from drivers.mujoco.plant import TwinPlant
from hild.config import load_config
from tests.conftest import CONFIGS
from tests.drivers.can.test_emulate_runtime import CanRig
from tests.test_engine import send

REDUCTION = 1.0472 / 0.044  # rad/m: OpenArm's DM4310 turns 60° from closed to 0.044 m open
ARM = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


def gripper_can() -> dict[str, Any]:
    """configs/arm6_gripper_can.yaml on the sim clock, on a private CAN-FD virtual bus, model path made absolute."""
    data = yaml.safe_load((CONFIGS / "arm6_gripper_can.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6_gripper.xml")
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    bus = data["hardware"]["arm"]["params"]["bus"]
    data["hardware"]["arm"]["params"]["bus"] = {
        "interface": "virtual",
        "channel": f"gripper-{uuid.uuid4().hex[:10]}",
        "fd": bus["fd"],
        "data_bitrate": bus["data_bitrate"],
    }
    return data


@pytest.fixture
def rig(write_config: Callable[..., Path]) -> Iterator[CanRig]:
    made = CanRig(write_config(gripper_can()), RuntimeOptions(max_step=0.001))
    try:
        yield made.start()
    finally:
        made.close()


def test_the_gripper_motor_answers_and_moves_the_finger_through_its_transmission(rig: CanRig) -> None:
    runtime, engine = rig.runtime, rig.engine
    twin = runtime.twin
    assert twin is not None
    drives = {j.name: j for j in runtime.joints}
    gripper = drives["gripper"]
    fw = gripper.firmware
    assert isinstance(fw, DamiaoFirmware) and (fw.motor_id, fw.master_id) == (0x07, 0x17)
    assert fw.ranges == MODELS["damiao"]["DM4310"]
    assert (gripper.reduction, gripper.direction) == (pytest.approx(REDUCTION, rel=1e-3), -1)
    assert all(j.firmware.enabled for j in runtime.joints)
    assert twin.mimic_joints == {"gripper_mirror": "gripper"} and twin.free_joints == []

    def drive() -> dict[str, Any]:
        (status,) = [j for j in runtime.status()["joints"] if j["name"] == "gripper"]
        return status

    def finger() -> float:
        return float(twin.data.joint("gripper").qpos[0])

    # Open at the start (the keyframe): the motor stands at −1.0472 rad, and the daemon reads 0.044 m.
    rig.cycle(250)
    g = engine.joints.index("gripper")
    assert drive()["actuator_position"] == pytest.approx(-0.044 * REDUCTION, abs=1e-3)
    assert engine.state.position[g] == pytest.approx(0.044, abs=1e-4)
    assert engine.status()["joints"][g]["mode"] == "hold"

    # 3 cm: the motor turns to −0.714 rad, the finger follows in the model, its mirror with it.
    assert engine.switch(["gripper_position"], []).ok
    for _ in range(400):
        send(engine, "gripper_position", [0.03])
        rig.cycle()
    assert finger() == pytest.approx(0.03, abs=2e-4)
    assert float(twin.data.joint("gripper_mirror").qpos[0]) == pytest.approx(0.03, abs=2e-4)
    assert drive()["actuator_position"] == pytest.approx(-0.03 * REDUCTION, abs=5e-3)
    assert engine.state.position[g] == pytest.approx(finger(), abs=1e-4)  # the daemon sees the same finger

    # Closed on the box: the finger stalls at its half-width, the motor squeezing with the effort limit (60 N on the
    # finger = 2.5 N·m at the motor, positive: the motor closes turning positive).
    for _ in range(500):
        send(engine, "gripper_position", [0.0])
        rig.cycle()
    assert 0.023 < finger() < 0.025
    assert drive()["torque"] == pytest.approx(60.0 / REDUCTION, rel=0.03)
    assert drive()["enabled"] and drive()["fault"] == 0
    assert engine.state.effort[g] == pytest.approx(-60.0, rel=0.03)
    assert all(j["fault"] is None for j in engine.status()["joints"])


def test_the_emulator_starts_the_mimic_finger_at_its_leader(write_config: Callable[..., Path]) -> None:
    """A start position for the driven finger moves its mirror too: the coupling does not snap it on the first step."""
    loaded = load_config(write_config(gripper_can()))
    runtime = build_runtime(loaded, RuntimeOptions(initial_positions={"gripper": 0.035}))
    twin = runtime.twin
    assert twin is not None
    assert float(twin.data.joint("gripper").qpos[0]) == pytest.approx(0.035)
    assert float(twin.data.joint("gripper_mirror").qpos[0]) == pytest.approx(0.035)
    (gripper,) = [i for i, j in enumerate(runtime.joints) if j.name == "gripper"]
    assert runtime.rigs[0].plant.positions[gripper] == pytest.approx(-0.035 * REDUCTION)


def test_a_mimic_coupling_follows_mujocos_polynomial_about_the_reference_pose(tmp_path: Path) -> None:
    """follower − ref₁ = c₀ + c₁·(leader − ref₀) + c₂·(leader − ref₀)², as MuJoCo's joint equality holds it."""
    model = tmp_path / "coupled.xml"
    model.write_text(
        """<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body><joint name="leader" type="hinge" ref="0.1"/><geom size="0.1" mass="1"/></body>
    <body><joint name="follower" type="slide" ref="0.2"/><geom size="0.1" mass="1"/></body>
    <body><joint name="free" type="hinge"/><geom size="0.1" mass="1"/></body>
  </worldbody>
  <equality><joint joint1="follower" joint2="leader" polycoef="0.01 -2 0.5 0 0"/></equality>
</mujoco>"""
    )
    plant = TwinPlant(model, ["leader"], initial_positions={"leader": 0.5}, gravity=False)
    assert plant.mimic_joints == {"follower": "leader"} and plant.free_joints == ["free"]
    dx = 0.5 - 0.1
    assert float(plant.data.joint("follower").qpos[0]) == pytest.approx(0.2 + 0.01 - 2 * dx + 0.5 * dx**2)
    plant.step(np.zeros(1), 0.001)
    assert np.abs(plant.data.efc_pos[plant.data.efc_type == 0]).max(initial=0.0) < 1e-9  # nothing to correct
