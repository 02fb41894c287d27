"""systemd notification: the NOTIFY_SOCKET client, the earned-watchdog rule, and the daemon speaking both.

A fake NOTIFY_SOCKET is a unix datagram socket the test binds itself; the daemon (in-process or a subprocess) sends
to it exactly as it would to systemd.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import socket
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

from hild.config import load_config
from hild.cycle.engine import Engine
from hild.daemon.daemon import Daemon
from hild.main.notify import (
    READY_AFTER_CYCLES,
    SystemdNotifier,
    WatchdogGate,
    socket_address,
    status_line,
    watchdog_interval,
)
from tests.conftest import CONFIGS, Systemd, merge, mock_robot, receive
from tests.helpers import HildRun, free_endpoint, free_port


# ---- the client -------------------------------------------------------------------------------------------------
def test_socket_address_forms() -> None:
    assert socket_address("@hild/notify") == b"\0hild/notify"
    assert socket_address("/run/systemd/notify") == "/run/systemd/notify"
    for bad in ("relative/path", "@", "vsock:2:1234"):
        with pytest.raises(ValueError):
            socket_address(bad)


def test_unset_notify_socket_is_a_quiet_no_op() -> None:
    notifier = SystemdNotifier(environ={"WATCHDOG_USEC": "200000"})
    assert not notifier.enabled
    assert notifier.watchdog_interval is None  # no socket to ping: the watchdog cannot be on
    assert notifier.ping_period is None
    assert notifier.ready("x") is False
    assert notifier.watchdog() is False
    assert (notifier.sent, notifier.errors) == (0, 0)


def test_abstract_socket_receives_ready_with_one_status_line() -> None:
    name = f"hild-test-{uuid.uuid4().hex}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(b"\0" + name.encode())
        notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": "@" + name})
        assert notifier.enabled
        assert notifier.ready("hold at 500 Hz\nsecond line") is True
        assert receive(sock) == "READY=1\nSTATUS=hold at 500 Hz second line"
        notifier.close()


def test_path_socket_receives_watchdog_status_and_stopping(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": path})
    assert notifier.watchdog() and notifier.status("fault") and notifier.stopping("bye")
    assert [receive(sock), receive(sock), receive(sock)] == ["WATCHDOG=1", "STATUS=fault", "STOPPING=1\nSTATUS=bye"]
    assert (notifier.sent, notifier.errors) == (3, 0)
    notifier.close()


def test_send_errors_are_swallowed_counted_and_logged_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": str(tmp_path / "nobody-listens.sock")})
    with caplog.at_level(logging.WARNING, logger="hild.notify"):
        assert notifier.ready("x") is False
        assert notifier.watchdog() is False
        assert notifier.stopping("y") is False
    assert notifier.errors == 3 and notifier.sent == 0
    assert "nobody-listens.sock" in notifier.last_error
    assert len([r for r in caplog.records if r.name == "hild.notify"]) == 1


def test_unsupported_notify_socket_is_counted_not_raised() -> None:
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": "vsock:2:1234", "WATCHDOG_USEC": "1000000"})
    assert not notifier.enabled and notifier.errors == 1 and "vsock" in notifier.last_error
    assert notifier.watchdog() is False


def test_watchdog_interval_honours_usec_and_pid() -> None:
    assert watchdog_interval({"WATCHDOG_USEC": "200000"}, pid=42) == pytest.approx(0.2)
    assert watchdog_interval({"WATCHDOG_USEC": "200000", "WATCHDOG_PID": "42"}, pid=42) == pytest.approx(0.2)
    assert watchdog_interval({"WATCHDOG_USEC": "200000", "WATCHDOG_PID": "43"}, pid=42) is None  # someone else's
    assert watchdog_interval({"WATCHDOG_USEC": "0"}, pid=42) is None
    assert watchdog_interval({"WATCHDOG_USEC": "soon"}, pid=42) is None
    assert watchdog_interval({}, pid=42) is None
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "2000000"}, pid=7)
    assert notifier.ping_period == pytest.approx(0.5)  # WatchdogSec/4, within sd_watchdog_enabled's "at least /2"


# ---- the earned-watchdog rule -------------------------------------------------------------------------------------
def test_gate_pings_only_while_the_cycle_advances() -> None:
    gate = WatchdogGate(max_consecutive_overruns=20, cycle=100)
    assert gate.earned(150, 0, True)
    assert not gate.earned(150, 0, True)
    assert gate.reason == "the cycle is stalled at cycle 150"
    assert not gate.earned(150, 0, True)
    assert gate.earned(151, 0, True) and gate.reason == ""


def test_gate_withholds_on_runaway_overruns_and_a_dead_thread() -> None:
    gate = WatchdogGate(max_consecutive_overruns=20)
    assert gate.earned(10, 19, True)
    assert not gate.earned(20, 20, True) and "20 consecutive overruns" in gate.reason
    assert gate.earned(30, 0, True)
    assert not gate.earned(40, 0, False) and "ended" in gate.reason
    unlimited = WatchdogGate(max_consecutive_overruns=0)  # 0 disables the overrun check, as for the supervisor
    assert unlimited.earned(1, 10_000, True)


def test_gate_against_a_lockstep_engine_whose_cycle_stops(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    gate = WatchdogGate(engine.max_consecutive_overruns)
    gate.reset(engine.cycle)
    decisions = []
    for cycles in (5, 0, 0, 1, 0, 3):  # cycles run between two ping decisions
        engine.run_cycles(cycles)
        decisions.append(gate.earned(engine.cycle, engine.stats.consecutive_overruns, True))
    assert decisions == [True, False, False, True, False, True]
    for _ in range(engine.max_consecutive_overruns):  # the loop misses its deadline run after run
        engine.stats.record(10_000_000, 0, True)
    engine.run_cycles(1)
    assert not gate.earned(engine.cycle, engine.stats.consecutive_overruns, True)


def test_status_line_has_mode_and_loop_figures(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    engine.stats.record(120_000, 3_000, False)
    engine.stats.record(130_000, 4_000, True)
    line = status_line(engine.overall_mode(), engine.update_rate, engine.stats.summary())
    assert line.startswith("hold at 500 Hz; cycle p99 ")
    assert "µs, period error p99 " in line and line.endswith("1 overruns in 2 cycles")


# ---- the daemon in-process: pings stop while the real cycle thread is stalled ---------------------------------------
def test_daemon_withholds_pings_while_its_cycle_stalls(
    systemd: tuple[Systemd, str],
    write_config: Callable[..., Path],
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    fake, path = systemd
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "200000")  # ping period 50 ms
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    # Wall clock at 500 Hz; keep the test process's GC and GIL switch interval as they are.
    # The cycle as a thread of this process (tests/processes has the same with the cycle in its own process).
    realtime = {"gc_freeze": False, "switch_interval": sys.getswitchinterval(), "cycle_process": False}
    patch = {"clock": {"source": "wall"}, "realtime": realtime}
    daemon = Daemon(load_config(write_config(merge(mock_robot(), patch))), [f"tcp/127.0.0.1:{free_port()}"])
    wedged, release, unwedged = threading.Event(), threading.Event(), threading.Event()
    marks: dict[str, float] = {}

    def wedge() -> None:  # runs on the cycle thread at the start of a cycle: the cycle stops advancing
        wedged.set()
        release.wait(10.0)

    async def scenario() -> int:
        task = asyncio.create_task(daemon.run())
        deadline = time.monotonic() + 30.0
        while not daemon.ready:
            assert not task.done() and time.monotonic() < deadline, "the daemon never became ready"
            await asyncio.sleep(0.01)
        assert daemon.link.engine.started and daemon.link.engine.cycle > READY_AFTER_CYCLES
        marks["ready"] = time.monotonic()
        await asyncio.sleep(0.5)
        daemon.link.engine.submit(wedge)
        daemon.link.engine.submit(unwedged.set)  # applied only once the wedge is over
        assert await asyncio.to_thread(wedged.wait, 5.0)
        marks["stalled"] = time.monotonic()
        marks["stall_cycle"] = daemon.link.engine.cycle
        await asyncio.sleep(0.6)
        marks["released"] = time.monotonic()
        assert daemon.link.engine.cycle == marks["stall_cycle"]
        release.set()
        assert await asyncio.to_thread(unwedged.wait, 5.0)
        await asyncio.sleep(0.5)
        marks["end"] = time.monotonic()
        daemon.request_stop()
        return await task

    with caplog.at_level(logging.INFO):
        exit_code = asyncio.run(scenario())
    assert exit_code == 0
    running = fake.between(marks["ready"], marks["stalled"]).count("WATCHDOG=1")
    # One decision may still see the last cycles before the wedge (≤ 1 ping period after it began).
    stalled = fake.between(marks["stalled"] + 0.1, marks["released"]).count("WATCHDOG=1")
    resumed = fake.between(marks["released"], marks["end"]).count("WATCHDOG=1")
    assert 5 <= running <= 15, running  # 0.5 s at one ping per 50 ms
    assert stalled == 0
    assert resumed >= 4, resumed
    assert "withholding the systemd watchdog ping: the cycle is stalled at cycle" in caplog.text
    assert "systemd watchdog pings resumed" in caplog.text
    assert fake.between(marks["end"])[-1] == "STATUS=stopped: hardware released"


# ---- end to end: `hild run` under a fake systemd ------------------------------------------------------------------
JOURNAL_LINE = re.compile(r"^<[0-7]>[a-z_.]+: \S")
TIMESTAMP = re.compile(r"\d{4}-\d\d-\d\d|\d\d:\d\d:\d\d")


def test_hild_run_under_a_fake_systemd(systemd: tuple[Systemd, str], tmp_path: Path) -> None:
    fake, path = systemd
    log_path = tmp_path / "daemon.log"
    env = {k: v for k, v in os.environ.items() if k not in ("WATCHDOG_PID", "NOTIFY_SOCKET")}
    # JOURNAL_STREAM makes the daemon log as under systemd (the value only has to be present).
    env.update(NOTIFY_SOCKET=path, WATCHDOG_USEC="200000", JOURNAL_STREAM="8:12345")
    run = HildRun(CONFIGS / "rrbot_twin.yaml", free_endpoint(), "rrbot", log=log_path, cwd=tmp_path, env=env)
    try:
        ready_at, ready = fake.wait_for("READY=1", 60.0, alive=lambda: run.process.poll() is None)
        # READY=1 came only after the drives went live: the engine's start event is already in the log.
        assert "held where they are" in run.log
        assert "WATCHDOG=1" not in fake.between(0.0, ready_at)
        assert re.fullmatch(r"READY=1\nSTATUS=hold at 500 Hz; cycle p99 .*", ready), ready

        window = 2.5  # covers one STATUS_PERIOD (2 s) of periodic status
        time.sleep(window)
        running = fake.between(ready_at, ready_at + window)
        pings = running.count("WATCHDOG=1")
        assert 0.6 * window / 0.05 <= pings <= 1.4 * window / 0.05, pings  # one per 50 ms, loosely
        assert any(m.startswith("STATUS=hold at 500 Hz") for m in running), running

        stop_at = time.monotonic()
        assert run.stop(20.0) == 0, run.log
    finally:
        run.close()
    fake.wait_for("STATUS=stopped", 2.0)  # sent before exit; the reader thread may not have stamped it yet
    after = fake.between(stop_at)
    assert any(m.startswith("STOPPING=1\nSTATUS=stopping") for m in after), after
    assert after[-1] == "STATUS=stopped: hardware released"
    log = log_path.read_text()
    assert "[engine] stopped: hardware released" in log
    lines = log.splitlines()
    assert lines, "the daemon logged nothing"
    for line in lines:  # journald adds the time: one prefixed line per event, no timestamps of our own
        assert JOURNAL_LINE.match(line), line
        assert not TIMESTAMP.search(line), line
