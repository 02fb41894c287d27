"""The contact bench's plant options: model mismatch, pushes on the tool, obstacles, and their determinism."""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from drivers.can.emulator.cli import _options as emulate_options
from drivers.can.emulator.disturbances import Obstacle, PlantMismatch, Push, parse_obstacle, parse_push, push_force
from drivers.can.emulator.runtime import RuntimeOptions, build_runtime, describe
from drivers.mujoco.plant import TwinPlant
from hild.cli import build_parser
from hild.config import load_config
from tests.conftest import CONFIGS

ARM6 = CONFIGS / "arm6.xml"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
HOME = {"shoulder_lift": 1.0, "elbow": -1.6, "wrist_1": -0.9708, "wrist_2": 1.5708}


def gravity_torque(plant: TwinPlant) -> np.ndarray:
    """The joint torques that hold the plant still where it stands (qfrc_bias at rest)."""
    plant.data.qvel[:] = 0.0
    mujoco.mj_forward(plant.model, plant.data)
    return plant.data.qfrc_bias.copy()


def test_a_mass_scale_changes_the_gravity_torque_the_plant_needs_by_that_factor() -> None:
    nominal = TwinPlant(ARM6, JOINTS, initial_positions=HOME)
    heavy = TwinPlant(ARM6, JOINTS, initial_positions=HOME, mismatch=PlantMismatch(mass=1.1))
    g0, g1 = gravity_torque(nominal), gravity_torque(heavy)
    assert abs(g0[1]) > 10.0  # shoulder_lift carries the arm at home
    np.testing.assert_allclose(g1, 1.1 * g0, rtol=1e-9, atol=1e-9)


def test_a_friction_scale_scales_damping_and_frictionloss_only_in_the_plant() -> None:
    nominal = TwinPlant(ARM6, JOINTS)
    slippery = TwinPlant(ARM6, JOINTS, mismatch=PlantMismatch(friction=0.7))
    np.testing.assert_allclose(slippery.model.dof_damping, 0.7 * nominal.model.dof_damping)
    np.testing.assert_allclose(slippery.model.dof_frictionloss, 0.7 * nominal.model.dof_frictionloss)
    np.testing.assert_allclose(slippery.model.body_mass, nominal.model.body_mass)


def test_a_seeded_spread_is_the_same_for_the_same_seed_and_differs_for_another() -> None:
    a = TwinPlant(ARM6, JOINTS, mismatch=PlantMismatch(mass=1.1, spread=0.05, seed=3))
    b = TwinPlant(ARM6, JOINTS, mismatch=PlantMismatch(mass=1.1, spread=0.05, seed=3))
    c = TwinPlant(ARM6, JOINTS, mismatch=PlantMismatch(mass=1.1, spread=0.05, seed=4))
    nominal = TwinPlant(ARM6, JOINTS).model.body_mass
    ratio = a.model.body_mass[1:] / nominal[1:]
    assert np.all((ratio >= 1.1 * 0.95) & (ratio <= 1.1 * 1.05)) and np.ptp(ratio) > 0.0
    np.testing.assert_array_equal(a.model.body_mass, b.model.body_mass)
    assert not np.array_equal(a.model.body_mass, c.model.body_mass)


def test_a_push_at_the_tool_moves_a_compliant_joint_and_stops_when_it_ends() -> None:
    plant = TwinPlant(ARM6, JOINTS, initial_positions=HOME, gravity=False)
    plant.pushes.append(Push((0.0, 20.0, 0.0), start=0.01, duration=0.2, ramp=0.01))
    zero = np.zeros(6)
    for _ in range(5):
        plant.step(zero, 0.001)
    assert plant.positions[0] == pytest.approx(0.0, abs=1e-12)  # before the push starts nothing moves
    for _ in range(100):
        plant.step(zero, 0.001)
    assert plant.push_now[1] == pytest.approx(20.0)
    assert plant.velocities[0] > 0.01  # +y at the tool, in front of the base: shoulder_pan turns positive
    for _ in range(200):
        plant.step(zero, 0.001)
    assert not plant.push_now.any() and not plant.data.xfrc_applied.any()


def ball_under_the_tool(stiffness: float = 0.0) -> Obstacle:
    """A 2 cm ball 3 cm under the tool flange at home (the tool points down there): clear of the arm at start."""
    tool = TwinPlant(ARM6, JOINTS, initial_positions=HOME, gravity=False).tool_position()
    return Obstacle("ball", "sphere", (0.02,), (float(tool[0]), float(tool[1]), float(tool[2]) - 0.05), stiffness, 50.0)


def test_an_obstacle_in_the_way_pushes_back_with_a_measurable_force() -> None:
    plant = TwinPlant(ARM6, JOINTS, initial_positions=HOME, gravity=False, obstacles=[ball_under_the_tool()])
    free = TwinPlant(ARM6, JOINTS, initial_positions=HOME, gravity=False)
    assert plant.data.ncon == 0  # clear at the start
    push = Push((0.0, 0.0, -40.0), start=0.0, duration=1.0)
    plant.pushes.append(push)
    free.pushes.append(push)
    zero = np.zeros(6)
    for _ in range(300):
        plant.step(zero, 0.001)
        free.step(zero, 0.001)
    force = plant.contact_force()
    assert force[2] > 10.0  # the ball pushes the arm up, against the push
    assert plant.peak_contact_force >= np.linalg.norm(force) > 10.0
    assert plant.tool_position()[2] > free.tool_position()[2] + 0.01  # the free arm went further down
    assert free.peak_contact_force == 0.0
    plant.reset_peak()
    assert plant.peak_contact_force == 0.0


def test_a_padded_obstacle_gives_way_more_than_a_rigid_one() -> None:
    def depth(stiffness: float) -> tuple[float, float]:
        plant = TwinPlant(
            ARM6, JOINTS, initial_positions=HOME, gravity=False, obstacles=[ball_under_the_tool(stiffness)]
        )
        plant.pushes.append(Push((0.0, 0.0, -40.0)))
        deepest = 0.0
        for _ in range(600):
            plant.step(np.zeros(6), 0.001)
            for i in range(plant.data.ncon):
                deepest = max(deepest, -float(plant.data.contact[i].dist))
        assert np.linalg.norm(plant.contact_force()) == pytest.approx(40.0, rel=0.05)  # at rest on it: the push
        return deepest, plant.peak_contact_force

    (rigid, rigid_peak), (padded, padded_peak) = depth(0.0), depth(500.0)
    assert padded > 2.0 * rigid and padded_peak < 0.8 * rigid_peak  # gives way, softens the impact


def test_the_same_disturbances_give_the_same_motion() -> None:
    def run() -> np.ndarray:
        plant = TwinPlant(
            ARM6,
            JOINTS,
            initial_positions=HOME,
            mismatch=PlantMismatch(1.1, 1.3, spread=0.05, seed=7),
            pushes=[Push((5.0, -3.0, 10.0), 0.02, 0.1, 0.01)],
        )
        torque = np.array([0.0, 30.0, -10.0, 0.0, 0.0, 0.0])
        for _ in range(200):
            plant.step(torque, 0.0005)
        return np.concatenate([plant.positions, plant.velocities])

    np.testing.assert_array_equal(run(), run())


def test_push_schedule_ramps_and_sums() -> None:
    pushes = [Push((10.0, 0.0, 0.0), start=1.0, duration=1.0, ramp=0.5), Push((0.0, 0.0, -2.0))]
    out = np.zeros(3)
    np.testing.assert_allclose(push_force(pushes, 0.5, out), [0.0, 0.0, -2.0])
    np.testing.assert_allclose(push_force(pushes, 1.25, out), [5.0, 0.0, -2.0])
    np.testing.assert_allclose(push_force(pushes, 1.5, out), [10.0, 0.0, -2.0])
    np.testing.assert_allclose(push_force(pushes, 1.9, out), [2.0, 0.0, -2.0], atol=1e-9)
    np.testing.assert_allclose(push_force(pushes, 2.0, out), [0.0, 0.0, -2.0])


def test_the_command_line_forms_parse_and_bad_ones_say_why() -> None:
    assert parse_push("0,0,-20@2+0.5~0.02") == Push((0.0, 0.0, -20.0), 2.0, 0.5, 0.02)
    assert parse_push("1,2,3").duration == math.inf
    assert parse_obstacle("box:0.5,0,0.2:0.05,0.2,0.2", 1) == Obstacle(
        "obstacle1", "box", (0.05, 0.2, 0.2), (0.5, 0.0, 0.2)
    )
    assert parse_obstacle("sphere:0,0,1:0.1:5000,80").stiffness == 5000.0
    assert parse_obstacle("sphere:0,0,1:0.1:5000,80").damping == 80.0
    with pytest.raises(ValueError, match="FX,FY,FZ"):
        parse_push("1,2")
    with pytest.raises(ValueError, match="ramp"):
        parse_push("1,2,3@0+0.1~0.1")
    with pytest.raises(ValueError, match="half-size"):
        parse_obstacle("sphere:0,0,0:0.1,0.2")
    with pytest.raises(ValueError, match="positive factor"):
        PlantMismatch(mass=0.0)


# ---- through `hild emulate`'s runtime and command line ----------------------------------------------------------
def arm6_vcan(write_config: Callable[..., Path]) -> Path:
    data = yaml.safe_load((CONFIGS / "arm6_vcan.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    data["hardware"]["arm"]["params"]["bus"] = {"interface": "virtual", "channel": f"dist-{uuid.uuid4().hex[:10]}"}
    return write_config(data)


def test_the_runtime_builds_the_twin_with_the_disturbances_and_pushes_on_request(
    write_config: Callable[..., Path],
) -> None:
    wall = Obstacle("wall", "box", (0.05, 0.05, 0.05), (1.0, 1.0, 1.0))
    options = RuntimeOptions(mismatch=PlantMismatch(mass=0.9), obstacles=[wall], max_step=0.001)
    runtime = build_runtime(load_config(arm6_vcan(write_config)), options)
    twin = runtime.twin
    assert twin is not None and twin.obstacles == ("wall",)
    assert twin.model.body_mass[2] == pytest.approx(0.9 * 8.393)  # upper_arm_link
    assert "mass ×0.9" in describe(runtime)[-1] and "obstacles wall" in describe(runtime)[-1]
    reply = runtime.handle({"op": "push", "force": [0, 0, -20], "duration": 0.5, "ramp": 0.1, "delay": 0.2})
    assert reply["ok"] and twin.pushes == [Push((0.0, 0.0, -20.0), twin.time + 0.2, 0.5, 0.1)]
    status = runtime.status()
    assert status["push"] == [0.0, 0.0, 0.0] and status["contact_force"] == [0.0, 0.0, 0.0]
    assert status["peak_contact_force"] == 0.0
    assert runtime.handle({"op": "push", "clear": True}) == {"ok": True, "pushes": 0} and not twin.pushes
    for bad in ({"op": "push"}, {"op": "push", "force": [1, 2]}, {"op": "push", "force": [1, 2, 3], "ramp": "x"}):
        assert runtime.handle(bad)["ok"] is False


def test_the_motor_plant_refuses_what_needs_the_model(write_config: Callable[..., Path]) -> None:
    loaded = load_config(arm6_vcan(write_config))
    with pytest.raises(ValueError, match=r"mismatch act on the twin.s model: they need --plant twin"):
        build_runtime(loaded, RuntimeOptions(plant="motors", mismatch=PlantMismatch(friction=1.3)))
    runtime = build_runtime(loaded, RuntimeOptions(plant="motors", mismatch=PlantMismatch()))  # identity: fine
    assert runtime.handle({"op": "push", "force": [0, 0, 1]}) == {
        "ok": False,
        "error": "push needs the twin plant (--plant twin)",
    }


def test_the_command_line_carries_the_contact_options() -> None:
    args = build_parser().parse_args(
        [
            "emulate",
            "robot.yaml",
            "--mass-scale", "1.1",
            "--friction-scale", "0.7",
            "--mismatch-spread", "0.05",
            "--mismatch-seed", "9",
            "--obstacle", "sphere:0.4,0,0.3:0.05",
            "--push", "0,0,-20@1+0.5",
        ]
    )  # fmt: skip
    options = emulate_options(args, 1000.0)
    assert options.mismatch == PlantMismatch(1.1, 0.7, 0.05, 9)
    assert options.obstacles == [Obstacle("obstacle0", "sphere", (0.05,), (0.4, 0.0, 0.3))]
    assert options.pushes == [Push((0.0, 0.0, -20.0), 1.0, 0.5)]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["emulate", "robot.yaml", "--push", "1,2"])
