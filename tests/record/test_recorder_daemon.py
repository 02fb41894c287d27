"""The recorder in the daemon: built at start, fed every event and request, black boxes on its triggers, closed at
the stop; and across processes, a client domain killed mid-episode whose successor recovers it.

The in-process tests run the real ``hild.daemon.daemon.Daemon`` on this thread's loop with the cycle on a thread of
its own (``realtime.cycle_process: false``), the mock robot's sim clock paced at real time, clients over loopback
Zenoh. The last test runs ``hild run`` (main process, client domain, cycle process).
"""

from __future__ import annotations

import asyncio
import os
import signal
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.mock import MockHardware
from hild.api.client import HildClient
from hild.bench.daemon import child_pids
from hild.config import load_config
from hild.daemon.daemon import Daemon
from hild.daemon.local import LocalCycle
from hild.record.mcap_files import read_blackbox, read_episode
from hild.record.model import EpisodeMeta
from hild.record.recorder import Recorder
from tests.conftest import merge, mock_robot
from tests.helpers import HildRun, component, free_endpoint, serve, until

WAIT = 20.0
IN_PROCESS = {"realtime": {"cycle_process": False}, "clock": {"source": "sim", "real_time_factor": 1.0}}
RECORDING = {"recording": {"chunk_period": 0.05, "fsync": False, "min_free_mb": 0, "blackbox_seconds": 2}}


def run_daemon(
    write_config: Callable[..., Path],
    scenario: Callable[[Daemon, HildClient], Awaitable[None]],
    patch: dict[str, Any] | None = None,
) -> Daemon:
    endpoint = free_endpoint()
    daemon = Daemon(load_config(write_config(merge(merge(mock_robot(), merge(IN_PROCESS, RECORDING)), patch or {}))))
    daemon.listen = [endpoint]

    assert asyncio.run(serve(daemon, endpoint, scenario)) == 0
    return daemon


def recordings(config_dir: Path) -> Path:
    return config_dir / "recordings"


def test_an_episode_through_the_api_holds_its_cycles_requests_and_events(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    seen: dict[str, Any] = {}

    async def scenario(daemon: Daemon, client: HildClient) -> None:
        assert isinstance(daemon.recorder, Recorder) and daemon.recorder.alive
        assert isinstance(daemon.link, LocalCycle)
        status = await asyncio.to_thread(client.record_status)
        assert status["recorder"] == "running" and status["recording"] is False
        assert status["dir"] == str(recordings(tmp_path))
        seen["start"] = await asyncio.to_thread(client.record_start, "reach", 50.0, "a note")
        await asyncio.to_thread(client.switch, ["fwd"], [])
        await asyncio.to_thread(client.call, "switch_controllers", {"activate": ["nope"]}, check=False)
        for _ in range(20):
            client.send("fwd", [0.3, -0.2, 0.1])
            await asyncio.sleep(0.01)
        deadline = time.monotonic() + WAIT
        while (await asyncio.to_thread(client.record_status))["cycles"] == 0:  # written, as the recorder reports
            assert time.monotonic() < deadline, "the recorder reported no cycles written"
            await asyncio.sleep(0.01)
        seen["stop"] = await asyncio.to_thread(client.record_stop)
        seen["status"] = await asyncio.to_thread(client.record_status)

    run_daemon(write_config, scenario)
    start, stop = seen["start"], seen["stop"]
    assert start["task"] == "reach" and start["fps"] == 50.0
    assert stop["id"] == start["id"] and Path(stop["directory"]).parent == recordings(tmp_path)
    assert any(f.endswith(".mcap") and Path(f).is_file() for f in stop["files"])
    assert seen["status"]["recording"] is False and seen["status"]["last"]["id"] == start["id"]
    episode = read_episode(Path(stop["directory"]))
    rows = episode.rows
    assert rows.tick[0] == start["start_tick"] and len(rows) == stop["cycles"] and stop["dropped"] == 0
    assert np.all(np.diff(rows.tick) == 1)  # every cycle from start to stop, none twice
    assert episode.meta.state == "complete" and episode.meta.note == "a note"
    assert episode.meta.stop_tick == rows.tick[-1]
    code = {name: c for c, name in episode.meta.controller_codes.items()}["fwd"]
    assert (rows.owner == code).any()  # fwd's cycles carry its code
    requests = [e.data for e in episode.events if e.kind == "request"]
    assert {"request": "Switch", "fields": {"activate": ["fwd"], "deactivate": [], "strict": True}} in requests
    assert {"reply": "Switch", "ok": True} in requests
    refused = [r for r in requests if r.get("reply") == "Switch" and not r["ok"]]
    assert not refused  # the unknown controller was refused by the API: it never reached the cycle
    messages = [e.data.get("message", "") for e in episode.events if e.kind == "event"]
    assert any("recording started" in m for m in messages)
    assert any("fwd" in m for m in messages)  # the engine's own event of the switch
    markers = [e.data["marker"] for e in episode.events if e.kind == "marker"]
    assert markers == ["episode_start", "task", "episode_stop"]


def test_a_fault_writes_one_black_box_and_an_open_episode_is_closed_at_the_stop(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    seen: dict[str, Any] = {}

    async def scenario(daemon: Daemon, client: HildClient) -> None:
        assert isinstance(daemon.link, LocalCycle) and daemon.triggers is not None
        seen["episode"] = await asyncio.to_thread(client.record_start)
        await until(lambda: daemon.link.cycle > 2.5 * 500, "the flight recorder's 2 s and more of cycles")
        mock = component(daemon.link.engine, MockHardware)
        mock.fault_codes[:] = 3  # every joint's drive faults: one burst
        box = recordings(tmp_path) / "blackbox"
        await until(lambda: box.is_dir() and list(box.glob("*-fault.mcap")), "the black box")
        seen["files"] = sorted(box.glob("*.mcap"))
        # the file is on disk before the recorder's reply reaches the client domain's status: ask until it says so
        deadline = time.monotonic() + 30.0
        while "blackbox" not in (status := await asyncio.to_thread(client.record_status)):
            assert time.monotonic() < deadline, f"record status never named the black box: {status}"
            await asyncio.sleep(0.05)
        seen["status"] = status
        seen["manual"] = await asyncio.to_thread(client.blackbox, 0.2)
        seen["cycle"] = daemon.link.cycle
        seen["written"] = list(daemon.triggers.written)

    daemon = run_daemon(write_config, scenario)
    assert daemon.recorder is None  # closed at the stop
    assert [p.name.endswith("-fault.mcap") for p in seen["files"]] == [True]
    assert seen["written"] == ["fault"]  # three joints faulted: one burst, one file
    rows, events, info = read_blackbox(seen["files"][0])
    assert info["reason"] == "fault"
    assert rows.fault.any() and not rows.fault[0].any()  # before the fault, and after it
    assert len(rows) == pytest.approx(2 * 500, abs=2)
    assert any("drive" in e.data.get("message", "").lower() for e in events if e.kind == "event")
    assert seen["status"]["blackbox"]["file"] == str(seen["files"][0])
    assert seen["manual"]["cycles"] == 100 and seen["manual"]["file"].endswith("-manual.mcap")
    directory = Path(seen["episode"]["directory"])
    meta = EpisodeMeta.read(directory)
    assert meta.state == "complete" and meta.start_tick == seen["episode"]["start_tick"]
    assert meta.stop_tick is not None and meta.stop_tick >= seen["cycle"]  # to the daemon's stop
    assert read_episode(directory).events[-1].data["marker"] == "episode_stop"


def test_recording_disabled_starts_no_recorder(write_config: Callable[..., Path]) -> None:
    async def scenario(daemon: Daemon, client: HildClient) -> None:
        assert daemon.recorder is None and daemon.link.cycle_log() is None
        status = await asyncio.to_thread(client.record_status)
        assert status["recorder"] == "disabled"

    run_daemon(write_config, scenario, {"recording": {"enabled": False}})


# ---- across processes ------------------------------------------------------------------------------------------
def recorder_pid(client_domain: int) -> int:
    """The client domain's recorder process (its spawned child that is not the resource tracker)."""

    def command(pid: int) -> bytes:
        try:
            return Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            return b""

    found = [p for p in child_pids(client_domain) if b"spawn_main" in command(p)]
    assert len(found) == 1, found
    return found[0]


def test_a_killed_client_domain_takes_its_recorder_along_and_the_next_one_recovers_the_episode(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    config = merge(merge(mock_robot(), RECORDING), {"clock": {"source": "sim", "real_time_factor": 1.0}})
    with HildRun(write_config(config), free_endpoint(), "mock3") as run, run.client() as client:
        started = client.record_start(task="crash")
        first = run.client_process()
        worker = recorder_pid(first)
        run.wait(lambda: client.record_status()["cycles"] > 500, "a second of the episode on disk")
        written = client.record_status()["cycles"]  # rows the recorder had flushed to the file
        os.kill(first, signal.SIGKILL)
        run.wait(lambda: not Path(f"/proc/{worker}").exists(), "the recorder to die with its client domain")
        run.wait_log("the client domain ended unexpectedly (exit code -9)")
        status = run.wait(lambda: _recovered(client), "the next client domain to recover the episode")
        assert status["recorder"] == "running" and status["recording"] is False
        assert run.client_process() != first
        run.wait_log(f"recovered episode {started['id']}")
        assert run.stop() == 0
    directory = Path(started["directory"])
    episode = read_episode(directory)
    assert episode.meta.state == "recovered" and episode.meta.task == "crash"
    rows = episode.rows
    assert rows.tick[0] == started["start_tick"] and np.all(np.diff(rows.tick) == 1)
    # Every row the recorder had reported written survived the kill (it reports a chunk once it is flushed).
    assert len(rows) >= written and episode.meta.cycles == len(rows)


def _recovered(client: HildClient) -> dict[str, Any] | None:
    try:
        status = client.record_status(timeout=1.0)
    except Exception:
        return None
    return status if status.get("recovered") else None
