"""The daemon with its cycle in a process of its own (``realtime.cycle_process``), driven from outside over Zenoh.

Most tests run the real ``hild.daemon.daemon.Daemon`` on this thread's event loop (it owns the signal handlers) with the
cycle process it starts itself (as the bench and embedding code do); the watchdog test runs ``hild run``'s main
process the same way, and the stall test ``hild run`` itself. Clients use a free loopback port; the cycle process
paces the mock robot on the sim clock at real time.
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from hild.api.client import HildClient
from hild.config import load_config
from hild.crossing.cells import ClientPhase, Phase
from hild.daemon.daemon import Daemon, StartupError
from hild.daemon.remote import SpawnedCycle
from hild.main.process import MainProcess
from tests.conftest import Systemd, merge, mock_robot
from tests.helpers import HildRun, free_endpoint, serve, until

WAIT = 20.0
SPLIT = {"realtime": {"cycle_process": True}, "clock": {"source": "sim", "real_time_factor": 1.0}}


def split_robot(patch: dict[str, Any] | None = None) -> dict[str, Any]:
    return merge(merge(mock_robot(), SPLIT), patch or {})


def run_split(
    write_config: Callable[..., Path],
    scenario: Callable[[Daemon, HildClient], Awaitable[None]],
    patch: dict[str, Any] | None = None,
) -> tuple[Daemon, int]:
    endpoint = free_endpoint()
    daemon = Daemon(load_config(write_config(split_robot(patch))), [endpoint])

    return daemon, asyncio.run(serve(daemon, endpoint, scenario))


def test_a_client_drives_the_arm_through_the_cycle_process(write_config: Callable[..., Path]) -> None:
    seen: dict[str, Any] = {}

    async def scenario(daemon: Daemon, client: HildClient) -> None:
        remote = daemon.link
        assert isinstance(remote, SpawnedCycle) and remote.process is not None
        assert remote.process.pid != os.getpid()
        status = await asyncio.to_thread(client.status)
        assert status["mode"] == "hold" and [j["name"] for j in status["joints"]] == ["a", "b", "c"]
        assert status["loop"]["cycles"] > 0
        reply = await asyncio.to_thread(client.switch, ["fwd"], [])
        assert reply["activated"] == ["fwd"]
        joint_states: list[dict[str, Any]] = []
        client.subscribe("joint_states", joint_states.append)

        def reached() -> bool:
            client.send("fwd", [0.3, -0.4, 0.5])  # streamed: the controller times out without a fresh sample
            return bool(joint_states) and joint_states[-1]["position"] == pytest.approx([0.3, -0.4, 0.5])

        await until(reached, "the streamed command to reach the mock's joints")
        seen["estop"] = await asyncio.to_thread(client.estop)
        seen["estopped"] = await asyncio.to_thread(client.status)
        seen["reset"] = await asyncio.to_thread(client.reset)
        seen["threads"] = await until(lambda: remote.python_threads, "the cycle process to count its threads")
        seen["controllers"] = await asyncio.to_thread(client.list_controllers)
        seen["realtime"] = (await asyncio.to_thread(client.status))["realtime"]
        seen["pid"] = remote.process.pid

    daemon, code = run_split(write_config, scenario)
    assert code == 0
    assert seen["estop"]["deactivated"] == ["fwd"]
    assert seen["estopped"]["mode"] == "estop"
    assert seen["reset"]["cleared"] == ["e-stop"]
    assert seen["threads"] == 1  # steady state: the cycle alone, on the process's main thread
    assert seen["realtime"]["cycle_process"] == f"pid {seen['pid']}, 1 Python thread(s)"
    assert seen["realtime"]["priority"] == "normal (SCHED_OTHER)"  # the cycle's own settings, reported from there
    assert {c["name"]: c["state"] for c in seen["controllers"]} == {"jsb": "active", "fwd": "inactive"}
    assert isinstance(daemon.link, SpawnedCycle) and daemon.link.exit_code == 0
    assert daemon.link.phase is Phase.STOPPED


def test_a_refused_request_answers_as_before(write_config: Callable[..., Path]) -> None:
    """The one error type crosses with its details: a refused switch, enable, set-zero and reset keep their wire
    replies."""
    replies: dict[str, Any] = {}

    async def scenario(daemon: Daemon, client: HildClient) -> None:
        replies["switch"] = await asyncio.to_thread(
            client.call, "switch_controllers", {"activate": ["nope"]}, check=False
        )
        replies["set_zero"] = await asyncio.to_thread(
            client.call, "set_zero", {"joint": "a", "confirm": True}
        )  # the mock's a is held and still: allowed
        await asyncio.to_thread(client.estop)
        replies["enable"] = await asyncio.to_thread(client.call, "enable", {}, check=False)

    run_split(write_config, scenario)
    assert replies["switch"]["ok"] is False and "unknown controller" in replies["switch"]["error"]
    assert replies["set_zero"]["ok"] is True and replies["set_zero"]["joint"] == "a"
    assert replies["enable"] == {"ok": False, "error": "the e-stop is engaged: reset first"}


def test_a_cycle_process_that_cannot_build_its_hardware_is_a_start_up_error(
    write_config: Callable[..., Path],
) -> None:
    patch = {"hardware": {"bus": {"params": {"initial_positions": {"nope": 1.0}}}}}
    daemon = Daemon(load_config(write_config(split_robot(patch))), [free_endpoint()])
    with pytest.raises(StartupError, match="initial_positions names unknown joints"):
        asyncio.run(daemon.run())
    assert isinstance(daemon.link, SpawnedCycle) and daemon.link.exit_code == 1


def test_a_killed_cycle_process_ends_the_daemon_with_the_reason(
    write_config: Callable[..., Path], caplog: pytest.LogCaptureFixture
) -> None:
    async def scenario(daemon: Daemon, client: HildClient) -> None:
        assert isinstance(daemon.link, SpawnedCycle) and daemon.link.process is not None
        daemon.link.process.send_signal(signal.SIGKILL)
        await until(lambda: not daemon.link.alive(), "the cycle process to die")  # type: ignore[union-attr]
        await asyncio.sleep(0.5)  # the daemon's next housekeeping tick sees it

    _, code = run_split(write_config, scenario)
    assert code == 1
    assert "the cycle process ended unexpectedly (exit code -9)" in caplog.text


def test_the_watchdog_follows_the_cycle_process_not_the_client_domain(
    systemd: tuple[Systemd, str],
    write_config: Callable[..., Path],
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """``hild run``'s main process speaks for the unit. The cycle process stopped (SIGSTOP): systemd's pings stop;
    they resume when it runs again (they are earned by the cycle's own counter in shared memory). The client domain
    killed: the pings go on while another one starts, and READY=1 is not sent again."""
    fake, path = systemd
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "200000")  # ping period 50 ms
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    marks: dict[str, float] = {}
    main = MainProcess(load_config(write_config(split_robot({"clock": {"source": "wall"}}))), [free_endpoint()])

    async def scenario() -> int:
        task = asyncio.create_task(main.run())
        await until(lambda: main.ready or task.done(), "the daemon to be ready")
        assert main.cycle_process is not None and main.client is not None
        pid, client = main.cycle_process.pid, main.client.pid
        marks["ready"] = time.monotonic()
        await asyncio.sleep(0.5)
        os.kill(pid, signal.SIGSTOP)
        marks["stalled"] = time.monotonic()
        await asyncio.sleep(0.6)
        marks["released"] = time.monotonic()
        os.kill(pid, signal.SIGCONT)
        await asyncio.sleep(0.5)
        marks["end"] = time.monotonic()
        os.kill(client, signal.SIGKILL)
        await until(lambda: main.client is not None and main.client.pid != client, "another client domain")
        await until(lambda: main.client_phase is ClientPhase.SERVING, "the new client domain to serve")
        marks["restarted"] = time.monotonic()
        main.request_stop()
        return await task

    with caplog.at_level(logging.INFO):
        code = asyncio.run(scenario())
    assert code == 0
    running = fake.between(marks["ready"], marks["stalled"]).count("WATCHDOG=1")
    stalled = fake.between(marks["stalled"] + 0.1, marks["released"]).count("WATCHDOG=1")
    resumed = fake.between(marks["released"], marks["end"]).count("WATCHDOG=1")
    restarting = fake.between(marks["end"], marks["restarted"]).count("WATCHDOG=1")
    assert running >= 5, running
    assert stalled == 0
    assert resumed >= 4, resumed
    assert restarting >= 1, restarting  # the client domain's restart is not the unit's failure
    assert fake.between(marks["ready"], time.monotonic()).count("READY=1") == 0
    assert "withholding the systemd watchdog ping: the cycle is stalled at cycle" in caplog.text
    _, last = fake.wait_for("STATUS=stopped", WAIT)  # the reader may not have taken the last datagram yet
    assert last == "STATUS=stopped: hardware released"


def test_a_stalled_client_domain_leaves_the_cycle_holding(write_config: Callable[..., Path]) -> None:
    """The client domain stopped (SIGSTOP) while a client streams commands: the cycle process runs on, the stream
    times out on the cycle clock and the joints return to hold; resumed, the client domain reports what happened
    meanwhile. A stalled client domain is not restarted: it is alive."""
    with HildRun(write_config(split_robot()), free_endpoint(), "mock3") as run, run.client() as client:
        client.switch(["fwd"], [])
        for _ in range(50):  # 0.5 s of a stream: fwd owns the joints
            client.send("fwd", [0.3, -0.4, 0.5])
            time.sleep(0.01)
        before = client.status()
        assert [j["owner"] for j in before["joints"]] == ["fwd"] * 3, before
        stalled = run.client_process()
        os.kill(stalled, signal.SIGSTOP)
        try:
            time.sleep(1.0)  # the client domain stalled for 1 s (≥ 5 × fwd's command_timeout of 0.2 s)
        finally:
            os.kill(stalled, signal.SIGCONT)
        after = client.status()
        # The cycle ran on through the stall (in one process it would have stopped with the daemon): at 500 Hz on
        # the sim clock paced at real time, a second is 500 cycles; half of them is proof enough on a busy machine.
        assert after["loop"]["cycles"] - before["loop"]["cycles"] >= 250
        assert [j["mode"] for j in after["joints"]] == ["hold"] * 3, after["joints"]
        run.wait_log("no command for 0.2 s: joints return to hold")
        assert run.client_process() == stalled
        assert run.stop() == 0
    assert "stopped: hardware released" in run.log


def test_a_client_domain_lost_once_the_cycle_is_live_is_replaced_even_before_it_said_it_serves(
    write_config: Callable[..., Path], caplog: pytest.LogCaptureFixture
) -> None:
    """The cycle went live (the client domain told it to): from then on the arm is driven, and a client domain that
    dies, even in the few ms before it says it serves, is replaced like any later one. It used to end the unit as a
    failed start-up (seen under load: a test killed the client domain as soon as its API answered)."""
    main = MainProcess(load_config(write_config(split_robot())), [free_endpoint()])

    async def scenario() -> tuple[int | None, int]:
        task = asyncio.create_task(main.run())
        while main.cycle.phase is not Phase.LIVE:  # as early as possible: before the main process saw it serve
            assert not task.done(), "the daemon ended before its cycle went live"
            await asyncio.sleep(0)
        assert main.client is not None
        first = main.client.pid
        os.kill(first, signal.SIGKILL)
        await until(lambda: (main.client is not None and main.client.pid != first) or task.done(), "another domain")
        await until(lambda: main.client_phase is ClientPhase.SERVING or task.done(), "the new client domain to serve")
        code = task.result() if task.done() else None
        main.request_stop()
        return code, await task

    with caplog.at_level(logging.INFO):
        during, code = asyncio.run(scenario())
    assert (during, code) == (None, 0), caplog.text
    assert "start-up failed" not in caplog.text
