"""Pub/sub: liveliness, status, events and joint states out; controller commands in, bad ones dropped."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh

from hild.api.client import HildClient, HildUnreachable
from hild.api.codec import MAX_PAYLOAD
from hild.cycle.engine import Engine
from tests.api.conftest import ROBOT, Daemon
from tests.helpers import free_endpoint, wait_for

FWD_KEY = f"hild/{ROBOT}/ctrl/fwd/commands"


class Inbox:
    """Collects messages from a subscription callback (a Zenoh thread)."""

    def __init__(self) -> None:
        self.messages: list[dict[str, Any]] = []
        self._lock = threading.Lock()

    def __call__(self, message: dict[str, Any]) -> None:
        with self._lock:
            self.messages.append(message)

    def snapshot(self) -> list[dict[str, Any]]:
        with self._lock:
            return list(self.messages)

    def matching(self, text: str) -> list[dict[str, Any]]:
        return [m for m in self.snapshot() if text in m.get("message", "")]


def mock_position(engine: Engine) -> np.ndarray:
    return engine.hardware[0].component.position.copy()


def test_liveliness_token_and_discovery(daemon: Daemon) -> None:
    with HildClient(connect=[daemon.endpoint]) as anyone:
        assert anyone.discover() == [ROBOT]
        assert anyone.wait_alive(5.0) == ROBOT
        assert anyone.robot == ROBOT
        assert anyone.status()["robot"] == ROBOT


def test_token_goes_away_when_the_server_closes(engine: Engine) -> None:
    daemon = Daemon(engine, free_endpoint())
    daemon.start()
    watcher = HildClient(connect=[daemon.endpoint], timeout=1.0)
    try:
        assert watcher.discover() == [ROBOT]
        daemon.stop()
        wait_for(lambda: _discover_or_empty(watcher) == [], what="the token to go")
    finally:
        watcher.close()


def _discover_or_empty(client: HildClient) -> list[str]:
    try:
        return client.discover()
    except HildUnreachable:
        return []


def test_unreachable_daemon_fails_fast() -> None:
    with pytest.raises(HildUnreachable, match=r"cannot reach a hild daemon at tcp/127\.0\.0\.1:"):
        HildClient(connect=[free_endpoint()])


def test_status_is_published_periodically_and_on_change(client: HildClient) -> None:
    inbox = Inbox()
    with client.subscribe("status", inbox):
        wait_for(lambda: len(inbox.snapshot()) >= 2, what="two periodic status messages")
        assert inbox.snapshot()[-1]["mode"] == "hold" and "ok" not in inbox.snapshot()[-1]
        client.switch(activate=["fwd"])
        wait_for(lambda: any(m["mode"] == "active" for m in inbox.snapshot()), what="status after the switch")


def test_joint_states_samples(client: HildClient) -> None:
    inbox = Inbox()
    with client.subscribe("joint_states", inbox):
        wait_for(lambda: len(inbox.snapshot()) >= 5, what="joint states")
    samples = inbox.snapshot()
    first = samples[0]
    assert set(first) == {"stamp", "seq", "name", "position", "velocity", "effort", "fresh", "tau_ext"}
    assert first["name"] == ["a", "b", "c"]
    assert first["tau_ext"] == [None, None, None]  # no contact observer on this robot (safety.contact)
    assert first["fresh"] == [1.0, 1.0, 1.0]
    assert all(len(first[f]) == 3 for f in ("position", "velocity", "effort"))
    assert first["position"] == pytest.approx([0.1, -0.1, 0.0])  # initial actuator -0.2 on b, reduction 2
    seqs = [s["seq"] for s in samples]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert samples[-1]["stamp"] > first["stamp"]


def test_events_are_published(client: HildClient) -> None:
    inbox = Inbox()
    with client.subscribe("events", inbox):
        client.switch(activate=["fwd"])
        event = wait_for(lambda: inbox.matching("switch: activated"), what="the switch event")[0]
    assert set(event) == {"stamp", "level", "source", "message"}
    assert event["level"] == "info" and event["source"] == "controller_manager"


def test_forward_commands_move_the_mock_joints(daemon: Daemon, client: HildClient) -> None:
    client.switch(activate=["fwd"])
    target = [0.3, 0.2, -0.1]
    inbox = Inbox()

    def reached() -> bool:
        client.send("fwd", target)  # keep streaming: the controller times out after 0.5 s of silence
        samples = inbox.snapshot()
        return bool(samples) and np.allclose(samples[-1]["position"], target, atol=1e-6)

    with client.subscribe("joint_states", inbox):
        wait_for(reached, what="the joints to reach the target")
    # Joint space → actuator space: b has reduction 2, c has direction -1.
    assert mock_position(daemon.engine) == pytest.approx([0.3, 0.4, 0.1])
    assert daemon.server.counters.accepted > 0


BAD_COMMANDS = [
    (b"{", "malformed JSON"),
    (b"[0, 0, 0]", 'expected an object {"values": [...]}'),
    (b'{"values": [0.1, 0.2]}', "expected 3 values for ['a', 'b', 'c']; found 2 values"),
    (b'{"values": [NaN, 0, 0]}', "NaN is not valid JSON"),
    (b'{"values": [1e999, 0, 0]}', "values must be finite"),
    (b'{"values": [null, 0, 0]}', "values must be numbers"),
    (b'{"values": ["0.1", 0, 0]}', "values must be numbers"),
    (b'{"values": [0, 0, 0], "speed": 1}', 'expected an object {"values": [...]}'),
    (b'{"values": [5, 0, 0]}', "position 5 for a is outside [-1, 1]"),
]


def test_bad_commands_are_dropped_with_an_event_and_nothing_moves(daemon: Daemon, client: HildClient) -> None:
    client.switch(activate=["fwd"])
    before = mock_position(daemon.engine)
    inbox = Inbox()
    with client.subscribe("events", inbox):
        for raw, reason in BAD_COMMANDS:
            client.session.put(FWD_KEY, raw)
            event = wait_for(lambda r=reason: inbox.matching(r), what=f"the drop event for {raw!r}")[0]
            assert event["level"] == "warning" and event["source"] == "fwd"
            assert event["message"].startswith(f"dropped command on {FWD_KEY}: ")
    assert daemon.server.counters.dropped == len(BAD_COMMANDS)
    assert daemon.server.counters.accepted == 0
    assert mock_position(daemon.engine) == pytest.approx(before)
    assert client.status()["mode"] == "active"  # still answering, fwd still in charge
    client.send("fwd", [0.0, 0.0, 0.0])
    wait_for(lambda: daemon.server.counters.accepted == 1, what="a good command after the bad ones")


def test_commands_to_an_inactive_controller_are_dropped(daemon: Daemon, client: HildClient) -> None:
    inbox = Inbox()
    with client.subscribe("events", inbox):
        client.send("fwd_a", [0.5])
        wait_for(lambda: inbox.matching("controller fwd_a is not active"), what="the drop event")
    assert daemon.engine.joint_mode("a").name == "HOLD"


def test_oversized_command_is_dropped(daemon: Daemon, client: HildClient) -> None:
    client.switch(activate=["fwd"])
    inbox = Inbox()
    with client.subscribe("events", inbox):
        client.session.put(FWD_KEY, b" " * (MAX_PAYLOAD + 1))
        wait_for(lambda: inbox.matching("exceeds the 1048576-byte limit"), what="the drop event")


def test_a_flood_of_garbage_is_rate_limited_and_the_daemon_keeps_answering(daemon: Daemon, client: HildClient) -> None:
    client.switch(activate=["fwd"])
    # One publisher that blocks rather than drops: every sample leaves, in order (a client's own drop sheds
    # samples under load before they reach the daemon, which would test Zenoh, not hild). Paced over many
    # cycles, so take_inputs takes (and rejects) garbage again and again, not just the newest of one burst.
    publisher = client.session.declare_publisher(FWD_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    counters = daemon.server.counters
    for _ in range(300):
        publisher.put(b"garbage")
        time.sleep(0.0005)
    wait_for(lambda: counters.rejected >= 1, what=f"garbage to be taken ({counters})")
    publisher.put(b'{"values": [0.0, 0.0, 0.0]}')
    publisher.undeclare()
    wait_for(lambda: counters.accepted == 1, what=f"the good command after the flood ({counters})")
    # Every sample take_inputs took is accounted for once (Zenoh drops the oldest beyond an input's ring, uncounted)
    assert counters.accepted + counters.dropped == counters.commands <= 301
    assert client.status()["ok"] is True
    reports = daemon.events_with(f"dropped command on {FWD_KEY}")
    assert 0 < len(reports) <= min(20, counters.rejected)  # about ten per second, not one per rejected sample


def test_close_answers_pending_requests(engine: Engine) -> None:
    daemon = Daemon(engine, free_endpoint())
    daemon.start()
    replies: list[dict[str, Any]] = []
    with HildClient(ROBOT, connect=[daemon.endpoint], timeout=5.0) as client:
        daemon.stepper.running.clear()
        daemon.server.services.timeout = 30.0  # the request stays pending until the server closes
        caller = threading.Thread(
            target=lambda: replies.append(client.call("switch_controllers", {"activate": ["fwd"]}, check=False))
        )
        caller.start()
        wait_for(lambda: daemon.server._requests, what="the request to be in flight")
        daemon.stop()
        caller.join(10.0)
    assert replies == [{"ok": False, "error": "the daemon is shutting down"}]
