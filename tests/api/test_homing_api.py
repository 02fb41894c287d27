"""The ``home`` service and ``hild ctl home`` against the test daemon, on the mock driver's homing simulation.

Joint a homes from 0.1 to its switch at 0.4 over 0.5 s of the sim clock (the stepper's ~1 ms per cycle makes that
about half a second or more), then reads 0.05.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.mock import MockHardware
from hild.api.client import HildClient
from hild.api.ctl import EXIT_OK, EXIT_SERVICE, run_ctl
from hild.hardware import Homing
from tests.api.conftest import ROBOT, WAIT, Daemon, engine_from, robot_config, running
from tests.api.test_ctl import parse
from tests.helpers import wait_for


def homing_config(duration: float = 0.5) -> dict[str, Any]:
    config = robot_config()
    config["hardware"]["bus"]["params"]["homing"] = {"duration": duration, "switch": {"a": 0.4}, "home_offset": 0.05}
    return config


@pytest.fixture
def homing_daemon(tmp_path: Path) -> Iterator[Daemon]:
    with running(engine_from(homing_config(), tmp_path)) as d:
        yield d


def mock(daemon: Daemon) -> MockHardware:
    component = daemon.engine.hardware[0].component
    assert isinstance(component, MockHardware)
    return component


def ctl(daemon: Daemon, *argv: str) -> int:
    return run_ctl(parse("--connect", daemon.endpoint, *argv))


def homing_entry(client: HildClient, joint: str = "a") -> dict[str, Any] | None:
    return next((h for h in client.status()["homing"] if h["joint"] == joint), None)


def test_the_service_starts_it_and_the_status_tells_the_end(homing_daemon: Daemon) -> None:
    with HildClient(ROBOT, connect=[homing_daemon.endpoint], timeout=5.0) as client:
        assert client.status()["homing"] == []
        reply = client.call("home", {"joint": "a"})
        assert reply == {"ok": True, "error": None, "joint": "a", "attempt": 1, "state": "running"}
        wait_for(lambda: (homing_entry(client) or {}).get("state") == "attained", WAIT, "the homing to end", every=0.05)
        entry = homing_entry(client)
        assert entry is not None and entry["attempt"] == 1 and entry["detail"] is None
        assert entry["position"] == pytest.approx(0.05)
    wait_for(lambda: homing_daemon.events_with("homing a: attained"), WAIT, "the attained event")
    assert homing_daemon.events_with("homing a: started (attempt 1)")


def test_the_service_refuses_naming_what_commands_the_joint(homing_daemon: Daemon) -> None:
    with HildClient(ROBOT, connect=[homing_daemon.endpoint], timeout=5.0) as client:
        client.switch(["fwd_a"])
        reply = client.call("home", {"joint": "a"}, check=False)
        assert reply["ok"] is False and "joint a is commanded by controller fwd_a" in reply["error"]
        reply = client.call("home", {}, check=False)
        assert reply["ok"] is False and 'give the joint: {"joint": NAME}' in reply["error"]
        reply = client.call("home", {"joint": "nope"}, check=False)
        assert reply["ok"] is False and "unknown joint 'nope'" in reply["error"]
        assert client.status()["homing"] == []
    assert mock(homing_daemon).homing_started == []


def test_ctl_home_waits_for_the_end_and_says_where_the_joint_is(
    homing_daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(homing_daemon, "home", "a") == EXIT_OK
    captured = capsys.readouterr()
    assert "a: homed; it reads +0.0500 rad at its home" in captured.out
    assert "a: homing (attempt 1)" in captured.err


def test_ctl_home_fails_in_the_drives_words(homing_daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    mock(homing_daemon).homing_failure = "homing error: switch not found"
    assert ctl(homing_daemon, "home", "a") == EXIT_SERVICE
    assert "hild ctl: home: a failed: homing error: switch not found" in capsys.readouterr().err
    assert ctl(homing_daemon, "--json", "home", "a", "--wait", str(WAIT)) == EXIT_SERVICE  # the next attempt too
    reply = json.loads(capsys.readouterr().out)
    assert reply["ok"] is False and reply["state"] == "failed" and reply["attempt"] == 2
    assert reply["error"] == reply["detail"] == "homing error: switch not found"


def test_ctl_home_refused(homing_daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(homing_daemon, "switch", "--activate", "fwd") == EXIT_OK
    capsys.readouterr()
    assert ctl(homing_daemon, "home", "b") == EXIT_SERVICE
    assert "hild ctl: home: joint b is commanded by controller fwd" in capsys.readouterr().err
    assert ctl(homing_daemon, "--json", "home", "b") == EXIT_SERVICE
    reply = json.loads(capsys.readouterr().out)
    assert reply["ok"] is False and "commanded by controller fwd" in reply["error"]


def test_ctl_home_no_wait_returns_once_started(homing_daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(homing_daemon, "home", "a", "--no-wait") == EXIT_OK
    assert "a: homing started (attempt 1)" in capsys.readouterr().out
    with HildClient(ROBOT, connect=[homing_daemon.endpoint], timeout=5.0) as client:
        wait_for(lambda: (homing_entry(client) or {}).get("state") == "attained", WAIT, "the homing to end", every=0.05)


def test_ctl_home_gives_up_waiting_and_the_homing_goes_on(
    homing_daemon: Daemon, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(mock(homing_daemon), "homing", lambda joint: (Homing.RUNNING, ""))  # never ends
    assert ctl(homing_daemon, "home", "a", "--wait", "0.3") == EXIT_SERVICE
    assert "a is still homing: it goes on" in capsys.readouterr().err
    with HildClient(ROBOT, connect=[homing_daemon.endpoint], timeout=5.0) as client:
        assert (homing_entry(client) or {}).get("state") == "running"
    assert ctl(homing_daemon, "status") == EXIT_OK
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.strip()}
    assert "hold (homing)" in rows["a"] and "homing" not in rows["b"]


def test_an_estop_while_ctl_waits_ends_the_homing_failed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A homing of 30 s (sim): the e-stop reaches the cycle while ``hild ctl home`` waits, and stops it."""
    with running(engine_from(homing_config(duration=30.0), tmp_path)) as daemon:
        codes: list[int] = []
        waiter = threading.Thread(target=lambda: codes.append(ctl(daemon, "home", "a", "--wait", str(WAIT))))
        waiter.start()
        wait_for(lambda: mock(daemon).homing_started == ["a"], WAIT, "the homing to start")
        with HildClient(ROBOT, connect=[daemon.endpoint], timeout=5.0) as client:
            client.estop()
        waiter.join(WAIT + 5.0)
        assert codes == [EXIT_SERVICE]
        assert mock(daemon).homing_stopped == ["a"]
    assert "hild ctl: home: a failed: e-stop: stopped" in capsys.readouterr().err
