"""A parallel gripper described the usual way — one actuated knuckle, five ``<mimic>`` joints — imports, starts
closed where its initial_value says and holds: every mimic joint at multiplier·q + offset from the first step, the
start-pose contact check posed the same way, joint_states reporting the mimic joints as ros2_control does."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from drivers.mujoco.plant import TwinPlant
from hild.config import load_config
from hild.dynamics.kinematics import Kinematics
from hild.dynamics.model import couple_joints, linear_coupling, load_model
from hild.hardware import HardwareError
from hild.importers.ros2_control.importer import ImportResult
from tests.importers.helpers import ROBOTS, import_robot, lockstep

GRIPPER = ROBOTS / "gripper"
START = 0.79  # finger_joint's initial_value
# mimic joint → (followed joint, multiplier, offset), as gripper.urdf's <mimic> elements say
MIMICS = {
    "right_outer_knuckle_joint": ("finger_joint", -1.0, 0.0),
    "left_inner_knuckle_joint": ("finger_joint", 1.0, 0.0),
    "right_inner_knuckle_joint": ("finger_joint", -1.0, 0.0),
    "left_inner_finger_joint": ("finger_joint", -1.0, 0.05),
    "right_inner_finger_joint": ("finger_joint", 1.0, -0.05),
}


def imported(tmp_path: Path) -> ImportResult:
    return import_robot(GRIPPER / "gripper.urdf", GRIPPER / "gripper_controllers.yaml", tmp_path / "gripper.yaml")


def test_the_gripper_holds_closed_at_start_with_every_mimic_joint_where_its_leader_puts_it(tmp_path: Path) -> None:
    engine = lockstep(imported(tmp_path).config)
    twin = engine.hardware[0].component
    finger = engine.joints.index("finger_joint")

    def coupling_errors() -> list[float]:
        q = engine.state.position[finger]
        return [
            twin.data.qpos[twin.model.joint(name).qposadr[0]] - (multiplier * q + offset)
            for name, (_, multiplier, offset) in MIMICS.items()
        ]

    np.testing.assert_allclose(coupling_errors(), 0.0, atol=1e-9)  # the start pose itself: every coupling holds
    for _ in range(400):
        engine.run_cycles(1)
        assert engine.status()["mode"] != "fault", engine.status()["joints"]
        # MuJoCo's joint equality is a soft constraint carrying the linkage's weight: millradians, never 0.79 rad
        np.testing.assert_allclose(coupling_errors(), 0.0, atol=0.015)
    assert engine.state.position[finger] == pytest.approx(START, abs=0.015)
    np.testing.assert_allclose(engine.state.velocity, 0.0, atol=0.02)


def test_the_start_pose_contact_check_poses_the_mimic_joints(tmp_path: Path) -> None:
    result = imported(tmp_path)
    exclude = {
        frozenset(pair) for pair in load_config(result.config).config.hardware["twin"].params["exclude_contacts"]
    }
    assert frozenset(("left_inner_finger", "right_inner_finger")) in exclude  # the pads touch when closed
    assert frozenset(("left_outer_knuckle", "left_inner_knuckle")) not in exclude  # they only meet at a wrong pose


def test_mimic_joints_are_mapped_to_the_configs_mimic_joints(tmp_path: Path) -> None:
    result = imported(tmp_path)
    cfg = load_config(result.config).config
    assert list(cfg.joints) == ["wrist", "finger_joint"]
    found = {name: (m.joint, m.multiplier, m.offset) for name, m in cfg.mimic_joints.items()}
    assert found == MIMICS
    mapped = [f.text for f in result.report.of("mapped") if f.text.startswith("mimic joint")]
    assert len(mapped) == len(MIMICS)
    assert not [f for f in result.report.of("unsupported") if "mimic" in f.text]
    assert not result.report.partial


def test_the_twin_refuses_a_config_whose_mimic_joint_the_model_couples_otherwise(tmp_path: Path) -> None:
    result = imported(tmp_path)
    text = result.config.read_text()
    wrong = text.replace(
        "left_inner_finger_joint: {joint: finger_joint, multiplier: -1, offset: 0.05}",
        "left_inner_finger_joint: {joint: finger_joint, multiplier: -1, offset: 0.1}",
    )
    assert wrong != text
    result.config.write_text(wrong)
    with pytest.raises(HardwareError, match=r"left_inner_finger_joint.*couples it as 'finger_joint' × -1 \+ 0\.05"):
        lockstep(result.config)


CHAIN = """<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body><joint name="j1" type="hinge" ref="0.1"/><geom size="0.1" mass="1"/>
      <body><joint name="j2" type="hinge"/><geom size="0.1" mass="1"/>
        <body><joint name="j3" type="slide"/><geom size="0.1" mass="1"/>
          <body><joint name="j4" type="hinge"/><geom size="0.1" mass="1"/></body>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint joint1="j3" joint2="j2" polycoef="0.2 -2 0 0 0"/>
    <joint joint1="j2" joint2="j1" polycoef="0.1 0.5 0 0 0"/>
    <joint joint1="j4" joint2="j1" polycoef="0 1 3 0 0"/>
  </equality>
</mujoco>
"""


def test_couplings_are_applied_leader_first_through_a_chain_and_composed(tmp_path: Path) -> None:
    path = tmp_path / "chain.xml"
    path.write_text(CHAIN)
    model = load_model(path)
    data = mujoco.MjData(model)
    data.qpos[model.joint("j1").qposadr[0]] = 0.5
    data.qvel[model.joint("j1").dofadr[0]] = 2.0
    couple_joints(model, data)
    x = 0.5 - 0.1  # j1 from its reference position
    j2 = 0.1 + 0.5 * x
    assert data.qpos[model.joint("j2").qposadr[0]] == pytest.approx(j2)
    assert data.qpos[model.joint("j3").qposadr[0]] == pytest.approx(0.2 - 2 * j2)
    assert data.qpos[model.joint("j4").qposadr[0]] == pytest.approx(x + 3 * x**2)
    assert data.qvel[model.joint("j3").dofadr[0]] == pytest.approx(-2 * 0.5 * 2.0)
    assert data.qvel[model.joint("j4").dofadr[0]] == pytest.approx((1 + 6 * x) * 2.0)
    # j3 = 0.2 − 2·(0.1 + 0.5·(j1 − 0.1)) = −j1 + 0.1
    leader, multiplier, offset = linear_coupling(model, "j3")
    assert (leader, multiplier, offset) == ("j1", pytest.approx(-1.0), pytest.approx(0.1))
    assert linear_coupling(model, "j4") is None  # quadratic: no multiplier and offset say it
    assert linear_coupling(model, "j1") is None


def test_the_emulators_twin_plant_starts_the_mimic_joints_where_their_leader_puts_them() -> None:
    plant = TwinPlant(GRIPPER / "gripper.urdf", ["wrist", "finger_joint"], initial_positions={"finger_joint": START})
    for name, (_, multiplier, offset) in MIMICS.items():
        assert plant.data.qpos[plant.model.joint(name).qposadr[0]] == pytest.approx(multiplier * START + offset)
    assert plant.free_joints == []  # coupled joints follow; none moves freely


def test_the_3d_pose_draws_the_mimic_joints_where_their_leader_puts_them() -> None:
    kinematics = Kinematics(GRIPPER / "gripper.urdf", ["wrist", "finger_joint"])
    xyz, _ = kinematics.body_poses(np.array([[0.0, START]]))
    pads = [kinematics.body_names.index(b) for b in ("left_inner_finger", "right_inner_finger")]
    left, right = xyz[0, pads]
    assert left[0] == pytest.approx(-right[0], abs=1e-9)  # the linkage closes symmetrically
    assert left[0] == pytest.approx(0.045 - 0.05 * np.sin(START), abs=1e-9)  # the pad sits on its knuckle's tip
