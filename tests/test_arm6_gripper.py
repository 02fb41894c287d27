"""configs/arm6_gripper_twin.yaml in lockstep: the arm with a wrist F/T sensor and a parallel gripper starts and holds,
closes on the box (the fingers stall at its half-width), lifts it with a short arm motion, and the sensor carries
what hangs below it.

The gripper is driven by the config's `gripper_position` forward_command (streamed openings) and by its `gripper`
controller (parallel_gripper goals); the F/T sensor is read from MuJoCo's sensordata directly (`ft_force`,
`ft_torque` at `ft_site`, in that site's frame: the force and torque the flange exerts on the sensor, z out of the
flange).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from hild.api.goals import GoalEndpoint
from hild.cycle.engine import Engine
from tests.test_engine import JumpGuard, events, modes, send
from tests.test_twin_engine import twin

CONFIG = "arm6_gripper_twin.yaml"
BOX_HALF_WIDTH = 0.025  # m: the 5 cm cube of arm6_gripper.xml
LIFT = 0.15  # rad of shoulder_lift: raises the tool by ~7 cm and tilts it by as much


class Rig:
    """The engine, the twin's MuJoCo model and data, and the names a test reads."""

    def __init__(self) -> None:
        self.engine: Engine = twin(CONFIG)
        component: Any = self.engine.hardware[0].component
        self.model: mujoco.MjModel = component.model
        self.data: mujoco.MjData = component.data
        self.guard = JumpGuard(self.engine)
        self.gripper = self.engine.joints.index("gripper")
        self.arm = [self.engine.joints.index(name) for name in self.engine.joints if name != "gripper"]

    def run(self, cycles: int, gripper: float | None = None, arm: np.ndarray | None = None) -> None:
        """``cycles`` cycles, streaming the gripper's and the arm's position targets when given."""
        for _ in range(cycles):
            if gripper is not None:
                send(self.engine, "gripper_position", [gripper])
            if arm is not None:
                send(self.engine, "forward_position", arm.tolist())
            self.guard.run(1)

    def qpos(self, joint: str) -> float:
        return float(self.data.joint(joint).qpos[0])

    def box(self) -> np.ndarray:
        return np.array(self.data.body("box").xpos)

    def wrench(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.data.sensor("ft_force").data), np.array(self.data.sensor("ft_torque").data)

    def hild_wrench(self) -> np.ndarray:
        """What hild's sensor wrist_ft reads (accepted values: MuJoCo's plus the twin's noise)."""
        view = self.engine.sensors
        return view.values[view.index_of([f"wrist_ft/{p}.{a}" for p in ("force", "torque") for a in "xyz"])]

    def expected_wrench(self, masses: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """At rest, the sensor holds up the weight of ``masses`` (body → mass, each at its subtree's centre of mass):
        force m·g upwards and the torque of that weight about ft_site, both in the site's frame."""
        g = -float(self.model.opt.gravity[2])
        site = self.data.site("ft_site")
        rotation = np.array(site.xmat).reshape(3, 3)
        total = sum(masses.values())
        centre = sum(m * np.array(self.data.subtree_com[self.model.body(b).id]) for b, m in masses.items()) / total
        force = np.array([0.0, 0.0, total * g])
        return rotation.T @ force, rotation.T @ np.cross(centre - np.array(site.xpos), force)

    def hand_mass(self) -> float:
        return float(self.model.body_subtreemass[self.model.body("ft_sensor_link").id])

    def close_on_the_box(self) -> None:
        assert self.engine.switch(["gripper_position"], []).ok
        self.run(750, gripper=0.0)  # 0.44 s of travel at 0.1 m/s, then a second squeezing

    def lift(self, gripper: float | None) -> np.ndarray:
        """Raise shoulder_lift by LIFT and settle there; returns the arm's target."""
        assert self.engine.switch(["forward_position"], []).ok
        target = self.engine.state.position[self.arm].copy()
        target[1] += LIFT  # shoulder_lift
        self.run(1500, gripper=gripper, arm=target)  # 0.05 s of slew, then settling
        return target


def healthy(engine: Engine) -> bool:
    """No joint and no hardware component reports a fault."""
    status = engine.status()
    return all(j["fault"] is None for j in status["joints"]) and all(h["fault"] is None for h in status["hardware"])


def test_starts_and_holds_with_no_fault() -> None:
    rig = Rig()
    start = rig.engine.state.position.copy()
    box = rig.box()
    assert start[rig.gripper] == 0.044  # open, from the keyframe
    assert rig.qpos("gripper_mirror") == 0.044
    worst = 0.0
    for _ in range(250):  # 5 s, checked every 10 cycles
        rig.run(10)
        worst = max(worst, float(np.abs(rig.engine.state.position - start).max()))
    assert worst < 1e-3
    assert abs(rig.qpos("gripper_mirror") - rig.qpos("gripper")) < 1e-4  # the mimic finger stays with its leader
    assert np.abs(rig.box() - box).max() < 1e-3  # the box rests on the stand, untouched
    assert modes(rig.engine) == ["hold"] * 7
    assert healthy(rig.engine)
    assert not [e for e in events(rig.engine) if e.startswith("error")]


def test_closing_on_the_box_stalls_at_its_half_width_and_the_arm_lifts_it() -> None:
    rig = Rig()
    box_start = rig.box()
    rig.close_on_the_box()
    # Stalled on the box, not at the closed end: squeezing with the effort limit, no longer moving.
    finger = rig.engine.state.position[rig.gripper]
    assert BOX_HALF_WIDTH - 0.002 < finger < BOX_HALF_WIDTH, finger  # pads pressed ~1 mm into the box
    assert abs(rig.engine.state.velocity[rig.gripper]) < 1e-3
    assert abs(rig.qpos("gripper_mirror") - BOX_HALF_WIDTH) < 0.002  # the mirrored finger touches the other side
    assert rig.engine.state.effort[rig.gripper] < -50.0  # closing force (N) on the driven finger, limit 60
    rig.run(250, gripper=0.0)
    assert abs(rig.engine.state.position[rig.gripper] - finger) < 1e-4  # stays stalled

    target = rig.lift(gripper=0.0)
    tcp = np.array(rig.data.site("tcp").xpos)
    assert rig.box()[2] - box_start[2] > 0.05  # lifted with the arm…
    assert np.linalg.norm(rig.box() - tcp) < 0.005  # …and still centred between the pads
    assert abs(rig.engine.state.position[rig.gripper] - finger) < 5e-4
    lifted = rig.box()
    rig.run(1000, gripper=0.0, arm=target)
    assert np.abs(rig.box() - lifted).max() < 2e-4  # held for 2 s more, not slipping
    assert healthy(rig.engine)


def test_without_a_grasp_the_same_lift_leaves_the_box_on_the_stand() -> None:
    rig = Rig()
    box_start = rig.box()
    rig.lift(gripper=None)  # the fingers stay open, held by the supervisor
    assert rig.engine.state.position[rig.gripper] > 0.043
    assert np.abs(rig.box() - box_start).max() < 2e-3


def test_the_ft_sensor_carries_the_weight_below_it() -> None:
    rig = Rig()
    rig.run(250)
    hand = {"ft_sensor_link": rig.hand_mass()}
    assert abs(rig.hand_mass() - 0.9) < 1e-9  # sensor 0.25, hand 0.55, fingers 2 × 0.05 kg
    force, torque = rig.wrench()
    expected_force, expected_torque = rig.expected_wrench(hand)
    np.testing.assert_allclose(force, expected_force, atol=0.02)
    assert force[2] < -8.8  # the tool points down: the flange holds the hand up, against the sensor's z
    np.testing.assert_allclose(torque, expected_torque, atol=2e-3)
    assert np.abs(torque).max() < 2e-3  # hanging straight down: no moment at the flange
    np.testing.assert_allclose(rig.hild_wrench(), np.concatenate([force, torque]), atol=0.25)  # within 5σ of noise

    rig.close_on_the_box()
    rig.lift(gripper=0.0)
    held = {**hand, "box": float(rig.model.body("box").mass[0])}
    force, torque = rig.wrench()
    expected_force, expected_torque = rig.expected_wrench(held)
    np.testing.assert_allclose(force, expected_force, atol=0.05)  # the box's 0.2 kg is there, tilted by the lift
    np.testing.assert_allclose(torque, expected_torque, atol=5e-3)
    assert np.linalg.norm(force) > (0.9 + 0.2) * 9.81 - 0.05
    assert (
        abs(np.linalg.norm(rig.hild_wrench()[:3]) - np.linalg.norm(force)) < 0.25
    )  # hild's sensor sees the box's weight too
    assert np.abs(torque).max() > 0.05  # tilted: the weight now has a lever arm about the flange


def test_the_gripper_controller_grasps_the_box_and_the_arm_carries_it() -> None:
    """`hild ctl gripper close` as the cycle sees it: parallel_gripper stalls on the box with its max_effort (20 N,
    not the joint's 60), reports `stalled`, and the grasp holds through a trajectory and an e-stop."""
    rig = Rig()
    assert rig.engine.switch(["gripper", "joint_trajectory"], []).ok
    goals = GoalEndpoint.of(rig.engine.manager.records["gripper"].instance.action_server())
    reply = goals.submit({"position": "close"})
    assert reply["ok"], reply
    result = None
    for _ in range(1500):
        rig.run(1)
        result = next((r for r in goals.collect() if r.goal_id == reply["goal_id"]), result)
        if result is not None:
            break
    assert result is not None
    fields = result.as_dict()
    assert fields["status"] == "succeeded" and fields["stalled"] is True
    assert BOX_HALF_WIDTH - 0.002 < fields["position"] < BOX_HALF_WIDTH
    rig.run(250)
    assert abs(rig.engine.state.effort[rig.gripper] + 20.0) < 1.0  # the goal's force, not the 60 N limit
    box_start = rig.box()
    trajectory = GoalEndpoint.of(rig.engine.manager.records["joint_trajectory"].instance.action_server())
    target = rig.engine.state.position[rig.arm].copy()
    target[1] += LIFT
    assert trajectory.submit({"positions": target.tolist()})["ok"]
    rig.run(1500)
    assert rig.box()[2] - box_start[2] > 0.05  # carried
    rig.engine.estop()
    lifted = rig.box()
    rig.run(1000)
    assert np.abs(rig.box() - lifted).max() < 2e-3  # e-stopped: the gripper holds what it holds
