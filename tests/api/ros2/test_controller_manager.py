"""``list_controllers`` and ``switch_controller`` as ros2_control 4.46 (Jazzy) fills them, against a bare Zenoh peer:
claimed interfaces only while active, required interfaces from each controller's configuration, the cycle's
rate, and a switch's strictness, ``activate_asap``, ``timeout`` and ``message``."""

from __future__ import annotations

import time
from typing import Any

import pytest
import zenoh

from hild.api.ros2 import types
from tests.api.conftest import Daemon
from tests.api.ros2.conftest import call, request
from tests.helpers import wait_for

LIST = "controller_manager_msgs/srv/ListControllers"
SWITCH = "controller_manager_msgs/srv/SwitchController"
SERVICE_TIMEOUT = 0.5  # the test daemon's request_timeout (tests/api/conftest.py)
FWD = ["a/position", "b/position", "c/position"]


def listed(peer: zenoh.Session) -> dict[str, Any]:
    reply = call(peer, "/controller_manager/list_controllers", LIST, request(LIST))
    assert reply.ok is not None
    return {c.name: c for c in types.decode(reply.ok.payload.to_bytes(), f"{LIST}_Response").controller}


def switched(
    peer: zenoh.Session,
    activate: list[str],
    strictness: int = 2,
    *,
    activate_asap: bool = False,
    timeout: float = 0.0,
) -> Any:
    """The decoded SwitchController response."""
    sec = int(timeout // 1)
    payload = request(
        SWITCH,
        activate_controllers=activate,
        deactivate_controllers=[],
        strictness=strictness,
        activate_asap=activate_asap,
        timeout=types.message("builtin_interfaces/msg/Duration", sec=sec, nanosec=round((timeout - sec) * 1e9)),
    )
    reply = call(peer, "/controller_manager/switch_controller", SWITCH, payload)
    assert reply.ok is not None
    return types.decode(reply.ok.payload.to_bytes(), f"{SWITCH}_Response")


def active(daemon: Daemon) -> set[str]:
    return {c["name"] for c in daemon.engine.snapshot().controllers if c["state"] == "active"}


def test_claimed_interfaces_only_while_active_required_ones_always(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    before = listed(peer)
    assert before["fwd"].state == "inactive"
    assert (list(before["fwd"].claimed_interfaces), list(before["fwd"].required_command_interfaces)) == ([], FWD)
    assert switched(peer, ["fwd"]).ok
    after = listed(peer)
    assert (list(after["fwd"].claimed_interfaces), list(after["fwd"].required_command_interfaces)) == (FWD, FWD)
    assert list(after["fwd_a"].claimed_interfaces) == [] and list(after["fwd_a"].required_command_interfaces) == [
        "a/position"
    ]


def test_required_state_interfaces_are_what_each_controller_reads(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    states = listed(peer)
    jsb = states["jsb"]
    assert jsb.state == "active" and list(jsb.claimed_interfaces) == [] == list(jsb.required_command_interfaces)
    assert list(jsb.required_state_interfaces) == [
        f"{j}/{f}" for j in "abc" for f in ("position", "velocity", "effort")
    ]
    assert list(states["traj"].required_state_interfaces) == [
        f"{j}/{f}" for j in "abc" for f in ("position", "velocity")
    ]
    assert list(states["fwd"].required_state_interfaces) == []  # forward_command reads nothing, as ros2_controllers'


def test_every_controller_runs_synchronously_at_the_cycle_rate(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    states = listed(peer)
    assert {(c.is_async, c.update_rate) for c in states.values()} == {(False, 500)}  # robot_config: update_rate 500


@pytest.mark.parametrize("activate_asap", [False, True])
def test_a_switch_says_what_it_did_whatever_activate_asap(
    ros_daemon: Daemon, peer: zenoh.Session, activate_asap: bool
) -> None:
    response = switched(peer, ["fwd"], activate_asap=activate_asap)
    assert response.ok
    assert response.message == "switched controllers: activated fwd; deactivated none"
    assert "fwd" in active(ros_daemon)


def test_a_best_effort_switch_names_what_it_dropped(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    response = switched(peer, ["fwd", "nope"], strictness=1)
    assert response.ok and "fwd" in active(ros_daemon)
    assert response.message == "switched controllers: activated fwd; deactivated none (not switched: nope)"


def test_a_refused_switch_carries_hilds_reason(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    response = switched(peer, ["nope"])
    assert not response.ok
    assert "unknown controller(s) 'nope'" in response.message
    wait_for(lambda: ros_daemon.events_with("refused ROS request on /controller_manager/switch_controller"))


@pytest.mark.parametrize(
    ("strictness", "reason"),
    [
        (3, "strictness AUTO (3) is not supported: hild activates no chain by itself"),
        (4, "strictness FORCE_AUTO (4) is not supported: hild deactivates only the controllers named"),
        (7, "unknown strictness 7"),
        (-1, "unknown strictness -1"),
    ],
)
def test_auto_force_auto_and_unknown_strictness_are_refused_unswitched(
    ros_daemon: Daemon, peer: zenoh.Session, strictness: int, reason: str
) -> None:
    response = switched(peer, ["fwd"], strictness=strictness)
    assert not response.ok and response.message.startswith(reason), response.message
    wait_for(lambda: ros_daemon.events_with(reason), what="the refusal event")
    t = ros_daemon.engine.t
    wait_for(lambda: ros_daemon.engine.t > t + 0.05, what="more cycles")  # nothing was queued for them to apply
    assert active(ros_daemon) == {"jsb"}


def test_strictness_zero_is_ros2_controls_default_best_effort(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    response = switched(peer, ["fwd", "nope"], strictness=0)
    assert response.ok and "fwd" in active(ros_daemon) and "nope" in response.message


def test_a_negative_timeout_is_refused(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    payload = request(
        SWITCH,
        activate_controllers=["fwd"],
        deactivate_controllers=[],
        strictness=2,
        activate_asap=False,
        timeout=types.message("builtin_interfaces/msg/Duration", sec=-1, nanosec=0),
    )
    reply = call(peer, "/controller_manager/switch_controller", SWITCH, payload)
    assert reply.ok is not None
    response = types.decode(reply.ok.payload.to_bytes(), f"{SWITCH}_Response")
    assert not response.ok and response.message == "timeout must not be negative, not -1 s"


@pytest.mark.parametrize(
    ("timeout", "waited"),
    [(0.1, 0.1), (0.0, SERVICE_TIMEOUT), (30.0, SERVICE_TIMEOUT)],  # zero: hild's own; longer: capped at it
)
def test_the_timeout_bounds_the_wait_for_a_stopped_cycle(
    ros_daemon: Daemon, peer: zenoh.Session, timeout: float, waited: float
) -> None:
    """With the cycle stopped the switch cannot apply: the reply comes after the request's timeout (at most the
    services' own), says so, and the withdrawn switch never applies once the cycle runs again."""
    ros_daemon.stepper.running.clear()
    try:
        start = time.monotonic()
        response = switched(peer, ["fwd"], timeout=timeout)
        elapsed = time.monotonic() - start
    finally:
        ros_daemon.stepper.running.set()
    assert not response.ok
    assert response.message == f"cycle not running: the request was not applied within {waited:g} s and was withdrawn"
    assert waited <= elapsed < waited + 0.3
    t = ros_daemon.engine.t
    wait_for(lambda: ros_daemon.engine.t > t + 0.05, what="the cycle running again")
    assert "fwd" not in active(ros_daemon)
