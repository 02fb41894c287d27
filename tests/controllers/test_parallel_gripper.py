"""parallel_gripper on a lockstep MuJoCo rig: a gripper on a vertical lift over a 3 cm box on a table.

Every way a goal ends (reached, stalled on the box, timed out, canceled, preempted), the force bound, the grasp
kept through hold, deactivation and e-stop, and the goals refused before they reach the cycle."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

from hild.action import GoalResult
from hild.api import render
from hild.api.goals import GoalEndpoint
from hild.config import load_config
from hild.controllers.parallel_gripper import ParallelGripperController
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.modes import JointMode
from tests.test_engine import events

RIG = Path(__file__).parent / "gripper" / "rig.xml"
BOX_HALF_WIDTH = 0.015
MAX_EFFORT = 10.0


def rig_config(gripper: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "robot": {"name": "rig", "model": "rig.xml"},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {
            "twin": {
                "driver": "mujoco",
                "params": {"model": "rig.xml", "keyframe": "open", "substeps": 2},
                "joints": {"lift": {}, "finger": {}},
            }
        },
        "joints": {
            "lift": {
                "limits": {
                    "position": {"lower": -0.02, "upper": 0.2},
                    "velocity": 0.3,
                    "effort": 80,
                    "acceleration": 2.0,
                    "jerk": 20.0,
                },
                "hold": {"kp": 4000, "kd": 120},
            },
            "finger": {
                "limits": {"position": {"lower": 0.0, "upper": 0.04}, "velocity": 0.2, "effort": 40},
                "hold": {"kp": 2000, "kd": 20},
            },
        },
        "controllers": {
            "gripper": {
                "type": "parallel_gripper",
                "params": {"joint": "finger", "max_effort": MAX_EFFORT, "allow_stalling": True, **(gripper or {})},
            },
            "lift": {"type": "joint_trajectory", "params": {"joints": ["lift"]}},
        },
    }


def rig_engine(tmp_path: Path, gripper: dict[str, Any] | None = None) -> Engine:
    """The rig's engine on the sim clock, not started."""
    shutil.copy(RIG, tmp_path / "rig.xml")
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(rig_config(gripper), sort_keys=False))
    return Engine(load_config(path))


def rig(tmp_path: Path, gripper: dict[str, Any] | None = None) -> Engine:
    engine = rig_engine(tmp_path, gripper)
    engine.start()
    assert engine.switch(["gripper", "lift"], []).ok
    return engine


def gripper(engine: Engine) -> ParallelGripperController:
    instance = engine.manager.records["gripper"].instance
    assert isinstance(instance, ParallelGripperController)
    return instance


def endpoint(engine: Engine, name: str = "gripper") -> GoalEndpoint[Any]:
    server = engine.manager.records[name].instance.action_server()
    assert server is not None
    return GoalEndpoint.of(server)


def submit(engine: Engine, goal: dict[str, Any], name: str = "gripper") -> str:
    reply = endpoint(engine, name).submit(goal)
    assert reply["ok"], reply["error"]
    return str(reply["goal_id"])


def run_until_result(engine: Engine, goal_id: str, name: str = "gripper", limit_s: float = 10.0) -> GoalResult:
    for _ in range(int(limit_s * engine.update_rate)):
        engine.run_cycles(1)
        for result in endpoint(engine, name).collect():
            if result.goal_id == goal_id:
                return result
    raise AssertionError(f"goal {goal_id} has no result after {limit_s} s")


def finger(engine: Engine) -> int:
    return engine.joints.index("finger")


def box_height(engine: Engine) -> float:
    twin = engine.hardware[0].component
    body = mujoco.mj_name2id(twin.model, mujoco.mjtObj.mjOBJ_BODY, "box")
    return float(twin.data.xpos[body][2])


def grasp(engine: Engine) -> GoalResult:
    result = run_until_result(engine, submit(engine, {"position": "close"}))
    assert result.status == "succeeded", result
    return result


def test_closing_on_the_box_stalls_and_presses_with_the_goals_effort(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    goal_id = submit(engine, {"position": "close"})
    efforts = []
    for _ in range(3000):
        engine.run_cycles(1)
        efforts.append(engine.state.effort[finger(engine)])
        results = {r.goal_id: r for r in endpoint(engine).collect()}
        if goal_id in results:
            break
    result = results[goal_id].as_dict()
    assert result["status"] == "succeeded" and result["stalled"] is True and result["reached_goal"] is False
    assert result["position"] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)  # stopped on the box, not at 0
    # The drive's spring presses with the goal's effort, never with the joint's 40 N limit.
    assert max(-e for e in efforts) < MAX_EFFORT * 1.1
    engine.run_cycles(500)
    assert -engine.state.effort[finger(engine)] == pytest.approx(MAX_EFFORT, rel=0.05)
    assert engine.state.position[finger(engine)] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)


def test_the_held_box_rises_with_the_lift(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    grasp(engine)
    before = box_height(engine)
    lift = engine.joints.index("lift")
    up = float(engine.state.position[lift]) + 0.05
    assert run_until_result(engine, submit(engine, {"positions": [up]}, "lift"), "lift").status == "succeeded"
    engine.run_cycles(500)
    assert box_height(engine) - before == pytest.approx(0.05, abs=0.005)  # lifted off the table, not left behind


def test_opening_reaches_the_goal(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    grasp(engine)
    result = run_until_result(engine, submit(engine, {"position": "open", "max_velocity": 0.05})).as_dict()
    assert result["status"] == "succeeded" and result["reached_goal"] is True and result["stalled"] is False
    assert result["position"] == pytest.approx(0.04, abs=0.01)
    engine.run_cycles(250)
    assert engine.state.position[finger(engine)] == pytest.approx(0.04, abs=0.002)
    assert engine.supervisor.hold_effort[finger(engine)] == 0.0  # no grasp left to keep


def test_a_stall_without_allow_stalling_aborts_but_keeps_the_grasp(tmp_path: Path) -> None:
    engine = rig(tmp_path, {"allow_stalling": False})
    result = run_until_result(engine, submit(engine, {"position": 0.0})).as_dict()
    assert result["status"] == "aborted" and result["stalled"] is True
    engine.run_cycles(250)
    assert -engine.state.effort[finger(engine)] == pytest.approx(MAX_EFFORT, rel=0.05)


def test_a_grasp_is_kept_when_the_gripper_is_deactivated(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    grasp(engine)
    assert engine.switch([], ["gripper"]).ok
    engine.run_cycles(1000)
    i = finger(engine)
    assert engine.supervisor.mode[i] == JointMode.HOLD
    assert -engine.state.effort[i] == pytest.approx(MAX_EFFORT, rel=0.1)
    assert engine.state.position[i] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)
    joint = next(j for j in engine.status()["joints"] if j["name"] == "finger")
    assert joint["hold_effort"] == -MAX_EFFORT  # an operator sees the grasp the hold keeps
    assert "hold (grasp -10)" in render.status_text(engine.status())
    assert any("joint finger holds its grasp" in e for e in events(engine))
    # Activated again, it takes the grasp over instead of letting go.
    assert engine.switch(["gripper"], []).ok
    engine.run_cycles(500)
    assert -engine.state.effort[i] == pytest.approx(MAX_EFFORT, rel=0.1)


def test_an_e_stopped_gripper_holds_what_it_holds(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    grasp(engine)
    lift = engine.joints.index("lift")
    up = float(engine.state.position[lift]) + 0.04
    assert run_until_result(engine, submit(engine, {"positions": [up]}, "lift"), "lift").status == "succeeded"
    height = box_height(engine)
    engine.estop()
    engine.run_cycles(1500)
    i = finger(engine)
    assert engine.supervisor.mode[i] == JointMode.ESTOP
    assert -engine.state.effort[i] == pytest.approx(MAX_EFFORT, rel=0.1)
    assert box_height(engine) == pytest.approx(height, abs=0.003)  # not dropped
    # E-stop deactivated the gripper: nothing can open it until an operator resets and activates it.
    assert not gripper(engine).active
    assert not endpoint(engine).submit({"position": "open"})["ok"]
    engine.reset()
    engine.run_cycles(500)
    assert engine.supervisor.mode[i] == JointMode.HOLD
    assert -engine.state.effort[i] == pytest.approx(MAX_EFFORT, rel=0.1)
    assert box_height(engine) == pytest.approx(height, abs=0.003)


def test_a_fault_aborts_the_goal_and_keeps_the_grasp(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    grasp(engine)
    goal_id = submit(engine, {"position": 0.0, "max_effort": 20.0})  # press harder: still running when it faults
    engine.run_cycles(5)
    i = finger(engine)
    engine.supervisor.trip(i, Fault.DRIVE, "test fault")
    result = run_until_result(engine, goal_id)
    assert result.status == "aborted" and "taken over" in result.error_string
    engine.run_cycles(500)
    assert engine.supervisor.mode[i] == JointMode.FAULT
    assert -engine.state.effort[i] > 5.0  # still pressing: the fault's hold keeps the grasp
    assert engine.state.position[i] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)
    engine.reset()
    engine.run_cycles(500)  # the gripper, still active, takes over where the finger is: the grasp stays
    assert engine.supervisor.mode[i] == JointMode.CONTROLLED
    assert -engine.state.effort[i] > 5.0
    assert engine.state.position[i] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)


def test_a_goal_that_neither_arrives_nor_stalls_times_out(tmp_path: Path) -> None:
    # A zero stall threshold: the finger pressed on the box never counts as stopped, so only the clock ends it.
    engine = rig(tmp_path, {"stall_velocity_threshold": 0.0, "goal_time_margin": 0.5})
    result = run_until_result(engine, submit(engine, {"position": 0.0, "max_velocity": 0.1}))
    assert result.status == "aborted" and "timed out" in result.error_string
    assert result.as_dict()["stalled"] is False


def test_cancel_stops_where_the_finger_is(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    goal_id = submit(engine, {"position": 0.0, "max_velocity": 0.02})
    engine.run_cycles(250)  # 0.5 s at 2 cm/s: on the way, not yet on the box
    assert endpoint(engine).cancel({"goal_id": goal_id})["ok"]
    result = run_until_result(engine, goal_id)
    assert result.status == "canceled"
    stopped = float(engine.state.position[finger(engine)])
    engine.run_cycles(500)
    assert engine.state.position[finger(engine)] == pytest.approx(stopped, abs=0.001)
    assert stopped > BOX_HALF_WIDTH + 0.005


def test_a_new_goal_preempts_the_running_one(tmp_path: Path) -> None:
    engine = rig(tmp_path, {"goal_tolerance": 0.001})
    first = submit(engine, {"position": 0.0, "max_velocity": 0.02})
    engine.run_cycles(100)
    second = submit(engine, {"position": "open"})
    engine.run_cycles(1)
    results = {r.goal_id: r for r in endpoint(engine).collect()}
    assert results[first].status == "preempted"
    assert run_until_result(engine, second).as_dict()["reached_goal"] is True


def test_feedback_reports_the_finger_while_a_goal_runs(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    goal_id = submit(engine, {"position": 0.0, "max_velocity": 0.02})
    engine.run_cycles(200)
    messages = endpoint(engine).feedback_messages()
    assert len(messages) >= 5  # 20 Hz over 0.4 s
    last = messages[-1]
    assert last["goal_id"] == goal_id and last["joint"] == "finger"
    assert last["position"] == pytest.approx(float(engine.state.position[finger(engine)]), abs=0.002)
    assert last["velocity"] < 0.0 and last["stalled"] is False


@pytest.mark.parametrize(
    ("goal", "reason"),
    [
        ({"position": 0.05}, "outside finger's soft range"),
        ({"position": "shut"}, 'a number, "open" or "close"'),
        ({"position": 0.01, "force": 3}, "unknown keys ['force']"),
        ({"max_effort": 3}, 'needs "position"'),
        ({"position": 0.01, "max_effort": 41}, "at most the joint's effort limit 40"),
        ({"position": 0.01, "max_velocity": 0}, "must be above 0"),
        ({"position": float("nan")}, "finite number"),
        ([0.01], "expected an object"),
    ],
)
def test_bad_goals_are_refused_with_the_reason(tmp_path: Path, goal: Any, reason: str) -> None:
    engine = rig(tmp_path)
    reply = endpoint(engine).submit(goal)
    assert not reply["ok"]
    assert reason in reply["error"]


def test_goals_for_an_inactive_gripper_are_refused(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    assert engine.switch([], ["gripper"]).ok
    reply = endpoint(engine).submit({"position": "open"})
    assert not reply["ok"] and "not active" in reply["error"]


def test_config_refuses_a_default_effort_above_the_joints_limit(tmp_path: Path) -> None:
    shutil.copy(RIG, tmp_path / "rig.xml")
    config = rig_config({"max_effort": 55.0})
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    with pytest.raises(Exception, match="max_effort 55 is above joint finger's effort limit 40"):
        load_config(path)


def test_the_twin_rig_starts_still(tmp_path: Path) -> None:
    engine = rig(tmp_path)
    start = engine.state.position.copy()
    engine.run_cycles(500)
    np.testing.assert_allclose(engine.state.position, start, atol=1e-3)
    assert not engine.supervisor.fault.any()
