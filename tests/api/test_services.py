"""Services over Zenoh: every reply has ok/error, bad input gets a clear error, the daemon keeps answering."""

from __future__ import annotations

import json
from typing import Any

import pytest

from hild.api.client import HildClient, HildError, HildUnreachable
from hild.api.codec import MAX_PAYLOAD
from hild.api.keys import SERVICES
from tests.api.conftest import ROBOT, Daemon
from tests.helpers import wait_for


def raw_call(client: HildClient, service: str, raw: bytes) -> dict[str, Any]:
    """A request with an arbitrary payload, bypassing the client's encoder."""
    replies = list(client.session.get(client.keys.service(service), payload=raw, timeout=5.0))
    assert len(replies) == 1 and replies[0].ok is not None, f"expected one reply from {service}"
    reply = json.loads(replies[0].ok.payload.to_bytes())
    assert set(reply) >= {"ok", "error"}
    return reply


def test_status_reply_has_modes_joints_controllers_hardware_and_loop(client: HildClient) -> None:
    status = client.status()
    assert status["ok"] is True and status["error"] is None
    assert status["robot"] == ROBOT and status["mode"] == "hold"
    assert [j["name"] for j in status["joints"]] == ["a", "b", "c"]
    for joint in status["joints"]:
        assert joint["mode"] == "hold" and joint["owner"] is None and joint["fault"] is None
        assert joint["limits"] == []
    assert {c["name"]: c["state"] for c in status["controllers"]} == {
        "jsb": "active",
        "fwd": "inactive",
        "fwd_a": "inactive",
    }
    assert set(status["controllers"][0]) == {
        "name",
        "type",
        "state",
        "claimed",
        "error",
        "state_interfaces",
        "chain_to",
        "is_chainable",
        "is_chained",
        "reference_interfaces",
        "chain_connections",
    }
    assert status["hardware"] == [{"name": "bus", "driver": "mock", "state": "active", "fault": None}]
    assert {"update_rate", "clock", "cycles", "overruns", "duration_us", "period_error_us"} <= set(status["loop"])


def test_list_services(client: HildClient) -> None:
    controllers = client.list_controllers()
    assert {c["name"] for c in controllers} == {"jsb", "fwd", "fwd_a"}
    fwd = next(c for c in controllers if c["name"] == "fwd")
    assert fwd == {
        "name": "fwd",
        "type": "forward_command",
        "state": "inactive",
        "claimed": ["a/position", "b/position", "c/position"],
        "error": "",
        "state_interfaces": [],  # forward_command reads nothing
        "chain_to": None,  # not chained: it commands the hardware
        "is_chainable": False,
        "is_chained": False,
        "reference_interfaces": [],
        "chain_connections": [],
    }
    jsb = next(c for c in controllers if c["name"] == "jsb")
    assert jsb["state_interfaces"] == [f"{j}/{f}" for j in "abc" for f in ("position", "velocity", "effort")]
    interfaces = {i["name"]: i["claimed_by"] for i in client.list_interfaces()}
    assert interfaces["a/position"] is None and "c/effort" in interfaces
    (bus,) = client.list_hardware()
    assert bus["name"] == "bus" and bus["driver"] == "mock" and bus["joints"] == ["a", "b", "c"]
    assert "position" in bus["command_fields"]


def test_switch_strict_success_claims_the_joints(client: HildClient) -> None:
    reply = client.switch(activate=["fwd"])
    assert reply == {"ok": True, "error": None, "activated": ["fwd"], "deactivated": []}
    status = client.status()
    assert status["mode"] == "active"
    assert {j["owner"] for j in status["joints"]} == {"fwd"}
    assert {i["name"]: i["claimed_by"] for i in client.list_interfaces()}["b/position"] == "fwd"
    reply = client.switch(activate=["fwd_a"], deactivate=["fwd"])
    assert reply["activated"] == ["fwd_a"] and reply["deactivated"] == ["fwd"]


def test_switch_unknown_controller_is_refused_with_the_loaded_names(client: HildClient) -> None:
    with pytest.raises(HildError, match=r"unknown controller\(s\) 'nope' \(loaded: fwd, fwd_a, jsb\)"):
        client.switch(activate=["fwd", "nope"])
    assert client.status()["mode"] == "hold"  # strict: nothing was switched


def test_switch_conflict_is_refused_and_changes_nothing(client: HildClient) -> None:
    with pytest.raises(HildError, match="a/position is claimed by both fwd and fwd_a"):
        client.switch(activate=["fwd", "fwd_a"])
    assert {c["name"]: c["state"] for c in client.list_controllers()}["fwd"] == "inactive"


def test_switch_errors_from_the_manager(client: HildClient) -> None:
    with pytest.raises(HildError, match="fwd is not active"):
        client.switch(deactivate=["fwd"])
    client.switch(activate=["fwd"])
    with pytest.raises(HildError, match="fwd is already active"):
        client.switch(activate=["fwd"])


def test_switch_best_effort_switches_what_it_can(client: HildClient) -> None:
    reply = client.switch(activate=["fwd", "fwd_a"], strict=False)
    assert reply["ok"] is True and reply["activated"] == ["fwd"]
    assert "fwd_a" in reply["error"]


def test_estop_then_reset(client: HildClient) -> None:
    client.switch(activate=["fwd"])
    reply = client.estop()
    assert reply["ok"] is True and reply["deactivated"] == ["fwd"]
    status = client.status()
    assert status["mode"] == "estop" and {j["mode"] for j in status["joints"]} == {"estop"}
    assert {c["name"]: c["state"] for c in status["controllers"]}["jsb"] == "active"  # broadcasters survive
    with pytest.raises(HildError, match="e-stop is engaged; reset first"):
        client.switch(activate=["fwd"])
    reply = client.reset()
    assert reply["ok"] is True and reply["cleared"] == ["e-stop"]
    assert client.status()["mode"] == "hold"
    assert client.switch(activate=["fwd"])["activated"] == ["fwd"]


def test_a_stalled_cycle_gives_a_clear_error_and_read_only_services_keep_answering(
    daemon: Daemon, client: HildClient
) -> None:
    daemon.stepper.running.clear()
    try:
        reply = client.call("switch_controllers", {"activate": ["fwd"]}, check=False)
        assert reply["ok"] is False and reply["error"].startswith("cycle not running")
        assert client.status()["ok"] is True
        assert client.list_controllers()
    finally:
        daemon.stepper.running.set()
    # The withdrawn request never applies, and the next one does.
    assert {c["name"]: c["state"] for c in client.list_controllers()}["fwd"] == "inactive"
    assert client.switch(activate=["fwd"])["activated"] == ["fwd"]


BAD_ANY = [
    (b"{", "malformed JSON"),
    (b"[1, 2]", "request must be a JSON object, not list"),
    (b'"status"', "request must be a JSON object, not str"),
    (b'{"bogus": 1}', "unknown field(s) 'bogus'"),
    (b"\xff\xfe{}", "payload is not UTF-8"),
    (b"NaN", "NaN is not valid JSON"),
]


@pytest.mark.parametrize("service", SERVICES)
@pytest.mark.parametrize(("raw", "reason"), BAD_ANY)
def test_bad_requests_on_every_service(client: HildClient, service: str, raw: bytes, reason: str) -> None:
    reply = raw_call(client, service, raw)
    assert reply["ok"] is False and reason in reply["error"]


BAD_SWITCH = [
    ({"activate": "fwd"}, "activate must be a list of controller names, not str"),
    ({"activate": [1]}, "activate must contain non-empty strings, found 1"),
    ({"activate": [None]}, "activate must contain non-empty strings, found None"),
    ({"activate": [""]}, "activate must contain non-empty strings"),
    ({"deactivate": {"fwd": 1}}, "deactivate must be a list of controller names, not dict"),
    ({"activate": ["fwd", "fwd"]}, "activate lists 'fwd' twice"),
    ({"activate": ["fwd"], "strict": "yes"}, "strict must be true or false"),
    ({"activate": ["fwd"], "strict": 1}, "strict must be true or false"),
    ({"activate": []}, "nothing to switch"),
    ({}, "nothing to switch"),
    ({"activate": ["fwd"], "force": True}, "unknown field(s) 'force' (allowed: activate, deactivate, strict)"),
]


@pytest.mark.parametrize(("request_", "reason"), BAD_SWITCH)
def test_bad_switch_requests(client: HildClient, request_: dict[str, Any], reason: str) -> None:
    reply = raw_call(client, "switch_controllers", json.dumps(request_).encode())
    assert reply["ok"] is False and reason in reply["error"]
    assert client.status()["mode"] == "hold"


def test_empty_payload_is_an_empty_request(client: HildClient) -> None:
    assert raw_call(client, "status", b"")["mode"] == "hold"
    assert raw_call(client, "list_controllers", b"  ")["ok"] is True


def test_oversized_request_is_refused_before_decoding(client: HildClient) -> None:
    reply = raw_call(client, "status", b" " * (MAX_PAYLOAD + 1))
    assert reply["ok"] is False and "exceeds the 1048576-byte limit" in reply["error"]
    assert client.status()["ok"] is True


def test_no_daemon_for_that_robot_is_unreachable(daemon: Daemon) -> None:
    with HildClient("other", connect=[daemon.endpoint], timeout=0.5) as other:
        with pytest.raises(HildUnreachable, match="no reply from hild/other/srv/status"):
            other.status()
        with pytest.raises(HildUnreachable, match="robot 'other' is not alive"):
            other.wait_alive(0.2)


def test_hardware_fault_shows_in_status_and_reset_needs_the_cause_gone(daemon: Daemon, client: HildClient) -> None:
    mock = daemon.engine.hardware[0].component
    mock.health_problem = "overheated"
    status = wait_for(lambda: (s := client.status())["mode"] == "fault" and s, what="the fault in status")
    assert status["hardware"][0]["fault"] == "overheated"
    assert {j["mode"] for j in status["joints"]} == {"fault"}
    assert all("overheated" in j["fault"] for j in status["joints"])
    reply = client.call("reset", check=False)
    assert reply["ok"] is False and reply["error"] == "bus still faulted: overheated"
    mock.health_problem = None
    reply = client.reset()
    assert reply["ok"] is True and reply["error"] is None and len(reply["cleared"]) == 3
    assert client.status()["mode"] == "hold"
