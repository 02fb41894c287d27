"""A controller's parameters read and changed while the robot runs (issue [runtime], item 2): dynamic ones while
it is active, between two cycles and in both halves; the rest only while it is not (it is then rebuilt); bad input
refused with the reason and nothing changed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hild.api.client import HildClient, HildError
from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.api.goals import GoalEndpoint
from hild.config import load_config
from hild.config.params import describe, flatten, with_values
from hild.config.tuning import MANAGER
from hild.controllers.joint_trajectory import JointTrajectoryParams
from hild.crossing.requests import SetParams
from hild.cycle.engine import HOLD_GAIN_RAMP
from tests.api.conftest import Daemon, engine_from, engine_with_trajectory, robot_config, running
from tests.api.test_ctl import ctl
from tests.api.test_services import raw_call
from tests.conftest import with_trajectory
from tests.helpers import wait_for


def test_every_parameter_is_listed_with_its_value_and_whether_it_may_change_while_active(client: HildClient) -> None:
    listed = {p["name"]: p for p in client.list_parameters("fwd")}
    assert set(listed) == {"joints", "interface", "command_timeout"}
    assert listed["command_timeout"]["value"] == 0.5 and listed["command_timeout"]["dynamic"] is True
    assert "silence" in listed["command_timeout"]["description"]
    assert listed["joints"] == {
        "name": "joints",
        "value": ["a", "b", "c"],
        "dynamic": False,
        "description": "Joints commanded, in the order of the values.",
    }
    assert client.get_parameters("fwd", ["command_timeout"]) == {"command_timeout": 0.5}
    with pytest.raises(HildError, match="fwd has no parameter\\(s\\) 'nope'"):
        client.get_parameters("fwd", ["nope"])
    with pytest.raises(HildError, match="unknown controller 'ghost'"):
        client.list_parameters("ghost")


def test_a_dynamic_parameter_changes_while_active_and_the_event_says_who_what_old_and_new(
    client: HildClient, daemon: Daemon
) -> None:
    client.switch(["fwd"])
    reply = client.set_parameters("fwd", {"command_timeout": 0.05})
    assert reply["changed"] == ["command_timeout: 0.5 → 0.05"] and reply["applied"] == "now"
    assert client.get_parameters("fwd", ["command_timeout"]) == {"command_timeout": 0.05}
    assert daemon.engine.manager.records["fwd"].instance.params.command_timeout == 0.05  # the cycle's
    said = f"parameters set by {client.sender}: command_timeout: 0.5 → 0.05"  # who (user@host), what, old → new
    wait_for(lambda: daemon.events_with(said), what="the event")
    client.send("fwd", [0.2, -0.1, 0.1])  # then silence: the new, shorter timeout hands the joints back to hold
    wait_for(lambda: daemon.events_with("no command for 0.05 s: joints return to hold"), what="the new timeout")
    assert client.set_parameters("fwd", {"command_timeout": 0.05})["applied"] == "unchanged"


def test_a_fixed_parameter_is_refused_while_active_and_rebuilds_the_controller_while_not(client: HildClient) -> None:
    client.switch(["fwd"])
    with pytest.raises(HildError, match="joints of fwd cannot change while it is active"):
        client.set_parameters("fwd", {"joints": ["a"], "command_timeout": 0.3})
    assert client.get_parameters("fwd") == {"joints": ["a", "b", "c"], "interface": "position", "command_timeout": 0.5}
    client.switch([], ["fwd"])
    reply = client.set_parameters("fwd", {"joints": ["c"]})
    assert reply == {
        "ok": True,
        "error": None,
        "controller": "fwd",
        "changed": ['joints: ["a","b","c"] → ["c"]'],
        "applied": "rebuilt (inactive)",
    }
    fwd = next(c for c in client.list_controllers() if c["name"] == "fwd")
    assert fwd["claimed"] == ["c/position"] and fwd["state"] == "inactive"
    client.switch(["fwd"])  # the rebuilt one runs
    assert client.list_controllers()[1]["state"] == "active"


@pytest.mark.parametrize(
    ("values", "reason"),
    [
        ({"command_timeout": -1}, "command_timeout: Input should be greater than 0"),
        ({"command_timeout": "soon"}, "command_timeout: Input should be a valid number"),
        ({"command_timout": 1}, "command_timout: Extra inputs are not permitted"),
        ({"interface": "current"}, "interface: Input should be 'position', 'velocity' or 'effort'"),
        ({"a..b": 1}, "'a..b' is not a parameter path"),
        ({"command_timeout.x": 1}, "'command_timeout' holds a value, not parameters"),
        ({}, "nothing to set"),
        ({f"p{i}": i for i in range(300)}, "300 parameters in one request; at most 256"),
    ],
)
def test_a_bad_value_is_refused_with_the_reason_and_nothing_changes(
    client: HildClient, values: dict[str, object], reason: str
) -> None:
    before = client.get_parameters("fwd")
    reply = client.call("set_parameters", {"controller": "fwd", "values": values}, check=False)
    assert reply["ok"] is False and reason in reply["error"], reply["error"]
    assert client.get_parameters("fwd") == before


def test_a_megabyte_value_is_refused_before_it_is_decoded(client: HildClient) -> None:
    request = {"controller": "fwd", "values": {"interface": "x" * (1 << 20)}}
    reply = raw_call(client, "set_parameters", json.dumps(request).encode())
    assert reply["ok"] is False and "exceeds the" in reply["error"]


def test_trajectory_constraints_change_while_a_goal_runs_and_apply_to_the_next_goal(tmp_path: Path) -> None:
    """``hild ctl param set joint_trajectory constraints.goal_time 0.8`` while it moves: the running goal keeps
    what it was accepted with and succeeds; the API half plans the next one with the new values."""
    with running(engine_with_trajectory(tmp_path)) as daemon, HildClient("mock3", [daemon.endpoint], 5.0) as client:
        client.switch(["traj"])
        with client.send_goal("traj", {"positions": [0.5, -0.5, 0.4]}) as handle:
            reply = client.set_parameters("traj", {"constraints.goal_time": 0.8, "velocity_scale": 0.5})
            assert sorted(reply["changed"]) == ["constraints.goal_time: 1.0 → 0.8", "velocity_scale: 1.0 → 0.5"]
            assert handle.wait(20.0)["status"] == "succeeded"
        controller = daemon.engine.manager.records["traj"].instance
        assert controller.goal_context.goal_time == 0.8
        limits = controller.context.limits
        np.testing.assert_allclose(controller.goal_context.limits.velocity, limits.velocity[:3] * 0.5, rtol=1e-5)


def test_hild_ctl_param_list_get_and_set(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "param", "list", "fwd") == EXIT_OK
    out = capsys.readouterr().out
    assert "command_timeout" in out and "WHILE ACTIVE" in out
    assert ctl(daemon, "param", "set", "fwd", "command_timeout", "0.8") == EXIT_OK
    assert capsys.readouterr().out.splitlines() == ["command_timeout: 0.5 → 0.8", "fwd: now"]
    assert ctl(daemon, "param", "get", "fwd", "command_timeout") == EXIT_OK
    assert capsys.readouterr().out.strip() == "command_timeout: 0.8"
    assert ctl(daemon, "param", "set", "fwd", "interface", "torque") == EXIT_SERVICE
    assert "interface: Input should be" in capsys.readouterr().err
    assert ctl(daemon, "param", "set", "fwd", "command_timeout") == EXIT_SERVICE
    assert "NAME VALUE pairs" in capsys.readouterr().err


# ---- the schema: which fields are dynamic, and paths into it ---------------------------------------------------------
def test_dynamic_is_said_by_the_schema_and_inherited_below_a_dynamic_field() -> None:
    assert describe(JointTrajectoryParams, "constraints.goal_time")[0] is True
    assert describe(JointTrajectoryParams, "constraints.joints.a.goal") == (
        True,
        "Goal position tolerance (rad); 0 = not checked.",
    )
    assert describe(JointTrajectoryParams, "joints")[0] is False
    assert describe(JointTrajectoryParams, "command_interfaces")[0] is False  # claims: not while active
    assert describe(JointTrajectoryParams, "gains.a.p")[0] is True  # ramped in: the effort never steps
    params = JointTrajectoryParams(joints=["a", "b"])
    changed = with_values(params, {"constraints.joints.a.goal": 0.01})
    assert flatten(changed)["constraints.joints.a.goal"] == 0.01 and "constraints.joints.a.goal" not in flatten(params)


# ---- the daemon's own parameters: hold gains ------------------------------------------------------------------------
def test_the_controller_manager_node_has_the_update_rate_and_each_joints_hold_gains(client: HildClient) -> None:
    listed = {p["name"]: p for p in client.list_parameters("controller_manager")}
    assert listed["update_rate"]["value"] == 500 and listed["update_rate"]["dynamic"] is False
    assert listed["joints.a.hold.kp"]["value"] == 100 and listed["joints.a.hold.kp"]["dynamic"] is True
    with pytest.raises(HildError, match="update_rate of controller_manager cannot change while it is active"):
        client.set_parameters("controller_manager", {"update_rate": 1000})
    with pytest.raises(HildError, match=r"unknown joint\(s\) \['z'\]"):
        client.set_parameters("controller_manager", {"joints.z.hold.kp": 1})
    with pytest.raises(HildError, match=r"joints\.a\.hold\.kp: Input should be greater than or equal to 0"):
        client.set_parameters("controller_manager", {"joints.a.hold.kp": -1})
    with pytest.raises(HildError, match="names the daemon's own parameters"):
        client.load_controller("controller_manager", "forward_command", {"joints": ["a"]})
    reply = client.set_parameters("controller_manager", {"joints.a.hold.kp": 300})
    assert reply["changed"] == ["joints.a.hold.kp: 100.0 → 300.0"]
    assert client.get_parameters("controller_manager", ["joints.a.hold.kp"]) == {"joints.a.hold.kp": 300.0}


def test_raising_a_held_joints_stiffness_while_a_goal_runs_ramps_it_in_and_nothing_jumps(tmp_path: Path) -> None:
    """Joint c is held while a goal moves a and b: its hold kp goes 100 → 300 over HOLD_GAIN_RAMP, never in a step,
    its target stays where it was latched, and the goal runs on undisturbed."""
    config = with_trajectory(robot_config(), "traj", joints=("a", "b"))
    engine = engine_from(config, tmp_path)
    engine.start()
    assert engine.switch(["traj"], []).ok
    engine.run_cycles(5)
    goal = engine.manager.records["traj"].instance
    endpoint = GoalEndpoint.of(goal.action)
    accepted = endpoint.submit({"positions": [0.9, -0.9]})
    assert accepted["ok"], accepted
    engine.run_cycles(50)  # the goal is moving
    held = engine.supervisor.latched[2]
    tuning = engine.tuning
    new = with_values(tuning, {"joints.c.hold.kp": 300.0})
    future = engine.request(SetParams(MANAGER, new, ("joints.c.hold.kp: 100.0 → 300.0",)))
    kp, target, moving = [], [], []
    for _ in range(int(0.7 * engine.update_rate)):
        engine.run_cycles(1)
        kp.append(float(engine.final.kp[2]))
        target.append(float(engine.final.position[2]))
        moving.append(goal.goal is not None)
    assert future.result(0)["changed"] == ["joints.c.hold.kp: 100.0 → 300.0"]
    steps = np.diff([100.0, *kp])
    ramp = int(HOLD_GAIN_RAMP * engine.update_rate)
    assert kp[-1] == pytest.approx(300.0) and kp[0] < 101.0  # reached, from where it was
    assert steps.max() <= 200.0 / ramp * 1.01 and steps.min() >= 0.0  # linear, never a step
    np.testing.assert_allclose(target, held)  # the held joint's target never moved
    assert all(moving[:ramp])  # the goal ran throughout the ramp
    engine.stop()


def test_params_save_writes_the_config_with_what_was_tuned_and_keeps_its_comments(
    client: HildClient,
    daemon: Daemon,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = Path(daemon.engine.loaded.path)
    path.write_text("# the bench arm: tuned on the robot\n" + path.read_text())
    client.set_parameters("fwd", {"command_timeout": 0.8})
    client.set_parameters("controller_manager", {"joints.a.hold.kp": 300})
    client.load_controller("late", "forward_command", {"joints": ["b"], "command_timeout": 0.3})
    monkeypatch.chdir(tmp_path)
    assert ctl(daemon, "params", "save") == EXIT_OK
    saved = tmp_path / "robot.tuned.yaml"
    assert capsys.readouterr().out.startswith(f"{saved.name}: {path} with ")
    text = saved.read_text()
    assert text.startswith("# the bench arm: tuned on the robot\n")
    tuned = load_config(saved)
    assert tuned.controller_params["fwd"].command_timeout == 0.8
    assert tuned.config.joints["a"].hold.kp == 300 and tuned.config.joints["b"].hold.kp == 100
    assert tuned.config.controllers["late"].type == "forward_command"
    assert tuned.controller_params["late"].command_timeout == 0.3
    assert ctl(daemon, "params", "save") == EXIT_SERVICE  # never over a file
    assert "--force replaces it" in capsys.readouterr().err
    assert ctl(daemon, "--json", "params", "save", "--force") == EXIT_OK
    assert set(json.loads(capsys.readouterr().out)["changed"]) == {
        "controllers.fwd.params.command_timeout",
        "joints.a.hold.kp",
        "controllers.late",
    }
