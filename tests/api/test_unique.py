"""One robot name, one daemon (issue [trust], finding 9): behind one network, two daemons of one robot name both
answered every switch and one streamed command moved both arms. A second daemon now refuses to start, naming the
first; one that appears later (the first cannot refuse it) is reported by the first as an error event."""

from __future__ import annotations

import asyncio
import logging
import socket
import sys
from pathlib import Path

import pytest
import yaml

from hild.api.unique import RobotNameTaken
from hild.config import load_config
from hild.config.model import ZenohSection
from hild.cycle.engine import Engine
from hild.daemon.daemon import Daemon as DaemonProcess
from hild.daemon.daemon import run_daemon
from hild.hardware import HardwareError
from tests.api.conftest import Daemon, robot_config
from tests.helpers import free_endpoint, wait_for


def another_engine(tmp_path: Path, name: str = "second.yaml") -> Engine:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(robot_config(), sort_keys=False))
    return Engine(load_config(path))


def connected_to(endpoint: str) -> ZenohSection:
    return ZenohSection(connect=[endpoint])


def test_a_second_daemon_of_the_same_robot_refuses_to_start(daemon: Daemon, tmp_path: Path) -> None:
    second = Daemon(another_engine(tmp_path), free_endpoint(), connected_to(daemon.endpoint))
    second.thread.start()
    try:
        second.engine.bring_up()
        with pytest.raises(RobotNameTaken) as refused:
            second.run(second.server.start())
        text = str(refused.value)
        assert text.startswith("robot 'mock3' already has a daemon on this Zenoh network (Zenoh id ")
        assert f"listening on {daemon.endpoint}" in text  # where the other one runs, as it answers it
        assert not second.engine.started  # nothing was enabled
    finally:
        second.loop.call_soon_threadsafe(second.loop.stop)
        second.thread.join(10)
        second.engine.release()
    # The first one is untouched: it still answers.
    assert daemon.events_with("appeared") == []


def test_a_daemon_reports_another_that_appears_later(
    daemon: Daemon, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    import hild.api.server as server

    # The second one starts without looking (an older hild, or both started at the same instant).
    monkeypatch.setattr(server, "check_unique", lambda session, keys: None)
    second = Daemon(another_engine(tmp_path), free_endpoint(), connected_to(daemon.endpoint))
    caplog.set_level(logging.ERROR, logger="hild.api")
    second.start()
    try:
        events = wait_for(lambda: daemon.events_with("another daemon of robot 'mock3' appeared"), what="the report")
        assert events[0]["level"] == "error" and f"listening on {second.endpoint}" in events[0]["message"]
        assert len(daemon.events_with("appeared")) == 1  # once, not per cycle
        logged = [r.getMessage() for r in caplog.records if "appeared" in r.getMessage()]
        assert logged and f"listening on {second.endpoint}" in logged[0]  # the operator's log names it too
    finally:
        second.stop()


def test_a_refused_daemon_never_touches_its_hardware(
    daemon: Daemon, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Refused before ``configure``: a second daemon of the same arm on the same bus must not open it, and its
    release after the refusal must not send the drives a disable (that would drop the first daemon's arm)."""
    data = robot_config()
    # The real daemon's process settings: keep this test process's GIL switch interval and GC as they are; the cycle
    # as a thread of this process, whose driver class the test patches.
    data["realtime"] = {"gc_freeze": False, "switch_interval": sys.getswitchinterval(), "cycle_process": False}
    data["zenoh"] = {"connect": [daemon.endpoint]}
    path = tmp_path / "second.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    loaded = load_config(path)
    touched: list[str] = []
    for hook in ("on_configure", "on_activate", "on_deactivate", "on_cleanup"):
        monkeypatch.setattr(loaded.driver_classes["bus"], hook, lambda self, hook=hook: touched.append(hook))
    with caplog.at_level(logging.ERROR, logger="hild.daemon"):
        code = run_daemon(loaded, [free_endpoint()])
    assert code == 1
    assert touched == []
    assert "robot 'mock3' already has a daemon on this Zenoh network" in caplog.text
    assert f"listening on {daemon.endpoint}" in caplog.text
    assert daemon.engine.started and daemon.events_with("appeared") == []  # the first one runs on, undisturbed


def test_the_session_opened_for_the_check_closes_when_the_hardware_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The session now opens before the hardware comes up: a bus that fails must not leave it listening."""
    import hild.api.server as server

    data = robot_config()
    realtime = {"gc_freeze": False, "switch_interval": sys.getswitchinterval(), "cycle_process": False}
    data["realtime"] = realtime  # the driver class patched below is this process's
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    loaded = load_config(path)

    def fail(self: object) -> None:
        raise HardwareError("bus down")

    monkeypatch.setattr(loaded.driver_classes["bus"], "on_configure", fail)
    opened: list[server.ApiServer] = []  # held here, so a session left open is not closed by the collector
    original_open = server.ApiServer.open

    async def open_and_keep(self: server.ApiServer) -> None:
        opened.append(self)
        await original_open(self)

    monkeypatch.setattr(server.ApiServer, "open", open_and_keep)
    endpoint = free_endpoint()
    with pytest.raises(HardwareError, match="configure failed: bus down"):
        asyncio.run(DaemonProcess(loaded, [endpoint]).run())
    assert len(opened) == 1 and opened[0].session is None
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as s:  # closed, not merely idle: the port can be bound again
        s.bind((host, int(port)))
