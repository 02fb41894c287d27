"""The recorder process and its handle, on a lockstep engine whose cycle log is a memfd (``LocalCycle``): the test
steps the cycle itself, so every tick an episode holds is known exactly, and a recorder stopped with SIGSTOP shows
what a late recorder does. The disk-full cases run the recorder's loop in this process (``Worker``) with a writer
that fails as a full disk does.
"""

from __future__ import annotations

import asyncio
import errno
import itertools
import json
import os
import queue
import shutil
import signal
import threading
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import replace
from multiprocessing import Pipe
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.cli import main as hild_main
from hild.config import load_config
from hild.crossing.cyclelog import CycleLog, CycleRows
from hild.crossing.events import Event
from hild.crossing.requests import Switch
from hild.daemon.local import LocalCycle
from hild.record import locks, mcap_files
from hild.record import recorder as recorder_module
from hild.record.events import cycle_event, marker, request_event
from hild.record.mcap_files import read_blackbox, read_episode
from hild.record.model import EPISODE_JSON, EpisodeMeta, RecordError, mcap_name
from hild.record.recorder import Recorder
from hild.record.setup import RecorderSetup
from hild.record.worker import Outbox, Worker
from tests.conftest import merge, mock_robot
from tests.record.rows import assert_rows_equal, make_meta

RATE = 500  # Hz: the mock robot's
SECONDS = 2.0  # the black box's: the ring holds (max(2, this) + 2) s = 2000 rows


def recording(tmp_path: Path, **patch: Any) -> dict[str, Any]:
    section = {
        "dir": str(tmp_path / "recordings"),
        "chunk_period": 0.01,
        "fsync": False,
        "min_free_mb": 0,
        "blackbox_seconds": SECONDS,
    }
    return {"recording": {**section, **patch}}


@pytest.fixture
def link(write_config: Callable[..., Path], tmp_path: Path) -> Iterator[LocalCycle]:
    cycle = LocalCycle(load_config(write_config(merge(mock_robot(), recording(tmp_path)))))
    cycle.engine.start()
    try:
        yield cycle
    finally:
        cycle.engine.stop()
        cycle.close()


def ring(link: LocalCycle) -> CycleLog:
    shared = link.cycle_log()
    assert shared is not None
    return CycleLog.attach(*shared)


def rows_between(link: LocalCycle, first: int, last: int) -> CycleRows:
    """The cycle log's rows of ticks ``first … last`` (what an episode of those ticks must hold)."""
    rows = ring(link).last(2000)
    return rows.select((rows.tick >= first) & (rows.tick <= last))


def run(link: LocalCycle, scenario: Callable[[Recorder, list[tuple[str, str]]], Awaitable[Any]]) -> Any:
    """``scenario`` with an open recorder on ``link``; the recorder is closed after it, whatever happens."""
    said: list[tuple[str, str]] = []

    async def main() -> Any:
        recorder = Recorder.from_config(link.loaded, link, lambda level, text: said.append((level, text)))
        assert recorder is not None
        await recorder.open()
        try:
            return await scenario(recorder, said)
        finally:
            await recorder.close()

    return asyncio.run(main())


def test_an_episode_holds_exactly_the_cycles_from_its_start_to_its_stop(link: LocalCycle) -> None:
    link.engine.run_cycles(50)

    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> tuple[dict[str, Any], dict[str, Any]]:
        started = await recorder.start("pick the cube", None, "first try")
        assert started["start_tick"] == link.cycle == 50
        link.engine.run_cycles(300)
        assert recorder.status()["recording"] is True
        stopped = await recorder.stop()
        link.engine.run_cycles(20)  # after the stop: not the episode's
        assert recorder.status()["recording"] is False and recorder.status()["last"]["id"] == started["id"]
        assert ("info", f"recording started: episode {started['id']} at cycle 50, task 'pick the cube'") in said
        return started, stopped

    started, stopped = run(link, scenario)
    directory = Path(stopped["directory"])
    assert started["fps"] == 30.0 and started["task"] == "pick the cube"
    assert stopped["id"] == started["id"] == directory.name and directory.parent == link.loaded.directory / "recordings"
    assert started["id"].endswith("-mock3") and len(started["id"]) == len("20260101-000000-mock3")
    assert stopped["cycles"] == 301 and stopped["dropped"] == 0
    assert stopped["duration"] == pytest.approx(300 / RATE)
    assert sorted(stopped["files"]) == sorted(
        str(directory / name) for name in (mcap_name(started["id"]), "metadata.yaml", EPISODE_JSON)
    )
    assert all(Path(f).is_absolute() and Path(f).is_file() for f in stopped["files"])
    episode = read_episode(directory)
    assert_rows_equal(episode.rows, rows_between(link, 50, 350))
    meta = episode.meta
    assert (meta.state, meta.start_tick, meta.stop_tick, meta.cycles, meta.dropped) == ("complete", 50, 350, 301, 0)
    assert meta.started_wall == episode.rows.wall[0] and meta.stopped_wall == episode.rows.wall[-1]
    assert (meta.robot, meta.joints, meta.task, meta.note, meta.fps, meta.update_rate) == (
        "mock3",
        ["a", "b", "c"],
        "pick the cube",
        "first try",
        30.0,
        500.0,
    )
    assert meta.config_path == str(link.loaded.path.resolve())
    assert len(meta.config_sha256) == 64 and {"hild", "python", "numpy", "mcap"} <= set(meta.versions)


def test_a_recorder_late_by_seconds_still_starts_at_the_start_tick_and_loses_nothing(link: LocalCycle) -> None:
    """Stopped (SIGSTOP) from just after the start for 1.5 s of cycles: the ring holds them."""

    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
        link.engine.run_cycles(10)
        await recorder.start(None, 10.0, None)
        assert recorder.pid is not None
        os.kill(recorder.pid, signal.SIGSTOP)
        try:
            link.engine.run_cycles(int(1.5 * RATE))
        finally:
            os.kill(recorder.pid, signal.SIGCONT)
        return await recorder.stop()

    stopped = run(link, scenario)
    episode = read_episode(Path(stopped["directory"]))
    assert stopped["dropped"] == 0 and episode.meta.fps == 10.0
    assert_rows_equal(episode.rows, rows_between(link, 10, 10 + int(1.5 * RATE)))


def test_rows_a_recorder_finds_overwritten_are_counted_and_reported(link: LocalCycle) -> None:
    capacity = ring(link).capacity

    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
        link.engine.run_cycles(10)
        started = await recorder.start(None, None, None)
        assert recorder.pid is not None
        os.kill(recorder.pid, signal.SIGSTOP)
        link.engine.run_cycles(capacity + 500)
        os.kill(recorder.pid, signal.SIGCONT)
        for _ in range(500):  # its next chunk finds the loss and says so
            if any("cycles lost" in text for _, text in said):
                break
            await asyncio.sleep(0.01)
        stopped = await recorder.stop()
        assert stopped["id"] == started["id"]
        return {**stopped, "start_tick": started["start_tick"]}

    stopped = run(link, scenario)
    episode = read_episode(Path(stopped["directory"]))
    assert stopped["dropped"] > 0 and episode.meta.dropped == stopped["dropped"]
    assert stopped["cycles"] + stopped["dropped"] == capacity + 500 + 1  # ticks 10 … 10 + capacity + 500
    assert episode.rows.tick[-1] == link.cycle
    # The rows counted lost are exactly the ticks missing: at the start (a recorder stopped before its first chunk)
    # or between two chunks (stopped after it).
    gaps = np.diff(episode.rows.tick) - 1
    late_start = int(episode.rows.tick[0]) - stopped["start_tick"]
    assert gaps.min() >= 0 and late_start >= 0 and late_start + gaps.sum() == stopped["dropped"]


def test_events_requests_and_markers_are_recorded_in_time_order(link: LocalCycle) -> None:
    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
        link.engine.run_cycles(5)
        link.take()  # the start-up's events: not the episode's
        recorder.log(cycle_event(Event(link.t, "info", "engine", "before the episode")))
        await recorder.start("wave", None, None)
        switch = Switch(("fwd",), ())
        recorder.log(request_event(switch, link.t))
        future = link.request(switch)
        link.engine.run_cycles(1)  # applied at this cycle's start: its events carry this cycle's time
        assert future.result(1.0)["ok"]
        for event in link.take():
            recorder.log(cycle_event(event, wall=0.0))  # received "late": the recorder puts it at its cycle
        link.engine.run_cycles(100)
        return await recorder.stop()

    stopped = run(link, scenario)
    episode = read_episode(Path(stopped["directory"]))
    kinds = [(e.kind, e.data.get("marker") or e.data.get("request") or e.data.get("source")) for e in episode.events]
    assert kinds[:2] == [("marker", "episode_start"), ("marker", "task")]
    assert ("request", "Switch") in kinds and kinds[-1] == ("marker", "episode_stop")
    assert all(e.data.get("message") != "before the episode" for e in episode.events)
    request = next(e for e in episode.events if e.kind == "request")
    assert request.data["fields"] == {"activate": ["fwd"], "deactivate": [], "strict": True}
    engine = [e for e in episode.events if e.kind == "event"]
    assert engine and all(e.data["source"] for e in engine)
    rows = episode.rows
    for event in engine:  # at the wall time of the row of the cycle that emitted it
        i = int(np.flatnonzero(rows.t == event.t)[0])
        assert event.wall == rows.wall[i]
    walls = [e.wall for e in episode.events]
    assert walls == sorted(walls)
    assert episode.events[0].data == {
        "marker": "episode_start",
        "id": stopped["id"],
        "tick": 5,
        "task": "wave",
        "fps": 30.0,
        "note": None,
    }


def test_one_episode_at_a_time_and_discard_removes_it(link: LocalCycle) -> None:
    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> None:
        with pytest.raises(RecordError, match="no episode is being recorded"):
            await recorder.stop()
        with pytest.raises(RecordError, match="no episode is being recorded"):
            await recorder.discard()
        first = await recorder.start(None, None, None)
        with pytest.raises(RecordError, match=f"episode {first['id']} is being recorded: stop or discard it first"):
            await recorder.start(None, None, None)
        link.engine.run_cycles(20)
        directory = Path(first["directory"])
        assert (directory / EPISODE_JSON).is_file()
        assert await recorder.discard() == {"id": first["id"], "discarded": True}
        assert not directory.exists()
        second = await recorder.start(None, None, None)  # a new episode after a discard
        link.engine.run_cycles(5)
        await recorder.stop()
        taken = await recorder.start(None, None, None)
        assert taken["id"] != second["id"]
        await recorder.stop()

    run(link, scenario)


def test_a_start_the_recorder_answers_too_late_is_undone(link: LocalCycle, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(recorder_module, "COMMAND_TIMEOUT", 0.3)

    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> None:
        link.engine.run_cycles(5)
        assert recorder.pid is not None
        os.kill(recorder.pid, signal.SIGSTOP)
        try:
            with pytest.raises(RecordError, match=r"the recorder did not answer within 0.3 s \(start\)"):
                await recorder.start(None, None, None)
        finally:
            os.kill(recorder.pid, signal.SIGCONT)
        assert recorder.status()["recording"] is False
        monkeypatch.setattr(recorder_module, "COMMAND_TIMEOUT", 10.0)
        started = await recorder.start(None, None, None)  # the late start was discarded there: this one is taken
        link.engine.run_cycles(5)
        stopped = await recorder.stop()
        assert stopped["cycles"] == 6
        assert [p.name for p in Path(started["directory"]).parent.iterdir()] == [started["id"]]

    run(link, scenario)


def test_ids_in_the_same_second_get_suffixes(link: LocalCycle, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("hild.record.recorder.time.time", lambda: 1_767_225_600.5)

    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> list[str]:
        ids = []
        for _ in range(3):
            ids.append((await recorder.start(None, None, None))["id"])
            link.engine.run_cycles(2)
            await recorder.stop()
        return ids

    assert run(link, scenario) == ["20260101-000000-mock3", "20260101-000000-mock3-2", "20260101-000000-mock3-3"]


def test_a_black_box_on_demand_holds_the_last_seconds_and_their_events(link: LocalCycle) -> None:
    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
        link.engine.run_cycles(3 * RATE)
        t = float(ring(link).last(100).t[0])  # a cycle 0.2 s ago emitted it
        recorder.log(cycle_event(Event(t, "error", "engine", "a: drive fault 3")))
        recorder.log(marker("old", link.t, wall=0.0))  # older than the black box's seconds: left out
        reply = await recorder.blackbox("manual", 0.5)
        assert recorder.status()["blackbox"]["file"] == reply["file"]
        again = await recorder.blackbox("manual", 0.5)
        assert again["file"] != reply["file"]  # the same second: a suffix, never overwritten
        return reply

    reply = run(link, scenario)
    path = Path(reply["file"])
    assert path.parent == link.loaded.directory / "recordings" / "blackbox" and path.name.endswith("-manual.mcap")
    assert reply["cycles"] == 250 and reply["seconds"] == pytest.approx(0.5)
    rows, events, info = read_blackbox(path)
    assert_rows_equal(rows, rows_between(link, link.cycle - 249, link.cycle))
    assert [e.data["message"] for e in events] == ["a: drive fault 3"]
    assert events[0].wall == rows.wall[rows.t == events[0].t][0]
    assert info["reason"] == "manual" and info["joints"] == ["a", "b", "c"]


def test_a_black_box_needs_seconds_when_the_flight_recorder_is_off(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    cycle = LocalCycle(load_config(write_config(merge(mock_robot(), recording(tmp_path, blackbox_seconds=0)))))
    cycle.engine.start()
    try:
        cycle.engine.run_cycles(100)

        async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
            with pytest.raises(RecordError, match="the black box is off"):
                await recorder.blackbox("manual")
            return await recorder.blackbox("manual", 0.1)

        assert run(cycle, scenario)["cycles"] == 50
    finally:
        cycle.engine.stop()
        cycle.close()


def test_a_start_is_refused_below_min_free_mb(write_config: Callable[..., Path], tmp_path: Path) -> None:
    cycle = LocalCycle(load_config(write_config(merge(mock_robot(), recording(tmp_path, min_free_mb=1e12)))))
    cycle.engine.start()
    try:

        async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> None:
            with pytest.raises(RecordError, match=r"MiB free in .* below recording.min_free_mb"):
                await recorder.start(None, None, None)
            assert recorder.status()["recording"] is False
            assert list((tmp_path / "recordings").iterdir()) == []  # nothing left behind

        run(cycle, scenario)
    finally:
        cycle.engine.stop()
        cycle.close()


def test_a_dead_recorder_is_reported_and_start_says_why(link: LocalCycle) -> None:
    async def scenario(recorder: Recorder, said: list[tuple[str, str]]) -> None:
        started = await recorder.start(None, None, None)
        link.engine.run_cycles(50)
        assert recorder.pid is not None
        os.kill(recorder.pid, signal.SIGKILL)
        for _ in range(500):
            if not recorder.alive:
                break
            await asyncio.sleep(0.01)
        assert recorder.status()["recorder"] == "stopped" and recorder.status()["recording"] is False
        level, text = said[-1]
        assert level == "error" and "the recorder process died (exit code -9)" in text and started["id"] in text
        with pytest.raises(RecordError, match=r"the recorder is not running \(the recorder process died"):
            await recorder.start(None, None, None)
        assert EpisodeMeta.read(Path(started["directory"])).state == "recording"  # left for recover

    run(link, scenario)


def test_the_next_recorder_recovers_what_a_dead_one_left_open(link: LocalCycle) -> None:
    async def first(recorder: Recorder, said: list[tuple[str, str]]) -> dict[str, Any]:
        link.engine.run_cycles(5)
        started = await recorder.start(None, None, None)
        link.engine.run_cycles(200)
        for _ in range(500):  # written: the recorder's progress report says so
            if recorder.status()["cycles"] >= 201:
                break
            await asyncio.sleep(0.01)
        assert recorder.pid is not None
        os.kill(recorder.pid, signal.SIGKILL)
        for _ in range(500):
            if not recorder.alive:
                break
            await asyncio.sleep(0.01)
        return started

    started = run(link, first)
    directory = Path(started["directory"])
    assert EpisodeMeta.read(directory).state == "recording" and not locks.in_use(directory)

    async def second(recorder: Recorder, said: list[tuple[str, str]]) -> None:
        for _ in range(1000):
            if recorder.recovered:
                break
            await asyncio.sleep(0.01)
        assert [r["id"] for r in recorder.recovered] == [started["id"]]
        assert recorder.status()["recovered"][0]["cycles"] == 201
        assert ("warning", f"recording: recovered episode {started['id']}, left open by a recorder that died") in said

    run(link, second)
    episode = read_episode(directory)
    assert episode.meta.state == "recovered"
    assert_rows_equal(episode.rows, rows_between(link, started["start_tick"], started["start_tick"] + 200))


def test_an_episode_a_live_recorder_holds_is_not_recovered(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    meta = make_meta()
    directory = tmp_path / meta.id
    directory.mkdir()
    fd = locks.hold(directory)  # as the recorder process holds the episode it writes
    try:
        writer = mcap_files.EpisodeWriter(directory, meta, fsync=False)
        assert locks.in_use(directory)
        with pytest.raises(BlockingIOError):
            locks.hold(directory)
        assert hild_main(["record", "recover", str(tmp_path), "--force"]) == 1
        assert "a running recorder is writing it; skipped" in capsys.readouterr().out
        assert EpisodeMeta.read(directory).state == "recording"
        writer.abandon()
    finally:
        locks.release(fd)
    assert not locks.in_use(directory)
    assert hild_main(["record", "recover", str(tmp_path), "--force"]) == 0
    assert EpisodeMeta.read(directory).state == "recovered"


# ---- the recorder's loop in this process: a full disk ---------------------------------------------------------------
class InProcess:
    """A ``Worker`` on the cycle log, its commands called directly, its messages collected."""

    def __init__(self, link: LocalCycle, **setup: Any) -> None:
        self.link = link
        base = RecorderSetup.from_config(link.loaded)
        self.setup = replace(base, **setup)
        self.messages, sender = Pipe(duplex=False)
        commands, self.commands = Pipe()
        self.events: queue.Queue[Any] = queue.Queue()
        self.worker = Worker(self.setup, ring(link), commands, Outbox(sender), self.events, os.getppid())
        self.seq = itertools.count(1)
        self.no = 0
        self.said: list[tuple[Any, ...]] = []
        link.engine.run_cycles(5)  # an episode starts at a cycle that has a row

    def ask(self, kind: str, *args: Any) -> tuple[Any, ...]:
        self.worker.command((kind, next(self.seq), *args))
        return self.received("reply")

    def received(self, kind: str) -> tuple[Any, ...]:
        while self.messages.poll(5.0):
            message = self.messages.recv()
            self.said.append(message)
            if message[0] == kind:
                return message
        raise AssertionError(f"no {kind!r} message; had {self.said}")

    def start(self) -> tuple[Path, tuple[Any, ...]]:
        args = self.start_args()
        return Path(args[2]), self.ask("start", *args)

    def start_args(self) -> tuple[Any, ...]:
        """A new episode's directory made, and the start command's arguments."""
        self.no += 1
        directory = self.setup.directory / f"episode-{self.no}"
        directory.mkdir(parents=True)
        meta = EpisodeMeta(
            id=directory.name,
            robot="mock3",
            joints=["a", "b", "c"],
            state="recording",
            task=None,
            note=None,
            fps=30.0,
            update_rate=RATE,
            config_path="",
            config_sha256="",
            versions={},
            started_wall=0.0,
            start_tick=self.link.cycle,
        )
        return self.no, meta, str(directory), []


def test_a_full_disk_stops_the_episode_cleanly_and_the_recorder_runs_on(
    link: LocalCycle, monkeypatch: pytest.MonkeyPatch
) -> None:
    here = InProcess(link)
    directory, reply = here.start()
    assert reply[2] is True
    writes = 0
    real = mcap_files.EpisodeWriter.write_rows

    def filling(self: Any, rows: CycleRows, codes: dict[int, str]) -> None:
        nonlocal writes
        writes += 1
        if writes == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(self, rows, codes)

    monkeypatch.setattr(mcap_files.EpisodeWriter, "write_rows", filling)
    for _ in range(3):
        link.engine.run_cycles(10)
        here.worker.chunk()
    _, no, ended, why = here.received("ended")
    assert no == 1 and why.startswith("disk full") and "No space left on device" in why
    meta = EpisodeMeta.read(directory)
    assert meta.state == "complete" and meta.cycles == 21 == ended["cycles"]  # ticks 5 … 25: two chunks
    assert meta.extra["stopped_because"] == why
    assert here.worker.episode is None and not locks.in_use(directory)
    assert read_episode(directory).rows.tick.tolist() == list(range(5, 26))
    assert here.ask("stop", 1, link.cycle, 0, [], {}, 0)[2:] == (
        False,
        "no episode is being recorded (the recorder stopped it: see its events)",
    )
    monkeypatch.setattr(mcap_files.EpisodeWriter, "write_rows", real)
    _, reply = here.start()  # the recorder runs on
    assert reply[2] is True
    link.engine.run_cycles(10)
    here.worker.chunk()
    stopped = here.ask("stop", 2, link.cycle, 0, [], {}, 0)
    assert stopped[2] is True and stopped[3]["cycles"] == 11


def test_free_space_falling_below_min_free_mb_stops_the_episode(link: LocalCycle) -> None:
    here = InProcess(link)
    directory, _ = here.start()
    link.engine.run_cycles(10)
    here.worker.chunk()
    here.worker.setup = replace(here.setup, min_free_mb=1e12)
    link.engine.run_cycles(10)
    here.worker.chunk()
    _, _, ended, why = here.received("ended")
    assert why.startswith("free space below recording.min_free_mb") and ended["cycles"] == 21
    assert EpisodeMeta.read(directory).state == "complete"
    assert json.loads((directory / EPISODE_JSON).read_text())["extra"]["stopped_because"] == why


def test_events_that_overtake_their_start_are_kept_for_it(link: LocalCycle) -> None:
    here = InProcess(link)
    event = marker("early", link.t, 1.0)
    here.events.put((1, event.wall, event.t, event.kind, event.data))
    here.events.put((0, event.wall, event.t, event.kind, {"marker": "stale"}))
    here.worker.chunk()  # no episode yet: the first is held for episode 1, the stale one dropped
    directory, _ = here.start()
    link.engine.run_cycles(5)
    stopped = here.ask("stop", 1, link.cycle, 1, [], {}, 0)
    assert stopped[2] is True
    assert [e.data["marker"] for e in read_episode(directory).events] == ["early"]


def test_a_chunk_that_fails_ends_the_episode_and_the_loop_runs_on(link: LocalCycle) -> None:
    here = InProcess(link)
    directory, _ = here.start()
    serving = threading.Thread(target=here.worker.serve, daemon=True)
    serving.start()
    try:
        link.engine.run_cycles(10)
        here.received("progress")
        shutil.rmtree(directory)  # under the recorder's feet
        link.engine.run_cycles(10)
        _, no, ended, why = here.received("ended")
        assert no == 1 and why.startswith("recording failed: FileNotFoundError") and ended["files"] == []
        assert serving.is_alive()
        here.commands.send(("start", 100, *here.start_args()))
        assert here.received("reply")[2] is True  # a new episode starts
    finally:
        here.commands.send(("close", 101))
        serving.join(5.0)
    assert not serving.is_alive()
