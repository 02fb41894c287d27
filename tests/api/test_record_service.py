"""The ``record`` and ``blackbox`` services, ``hild ctl record|blackbox`` and the client's record methods, against a
fake recorder with ``Recorder``'s interface, over a real ApiServer on loopback Zenoh: the replies, every
refusal of a bad request (before the recorder is asked), a recorder's refusal (``RecordError``) as the client's
error with the daemon answering on, a recorder that fails or hangs, and a daemon with recording disabled."""

from __future__ import annotations

import asyncio
import json
import math
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import hild.api.record as record_module
from hild.api.aio import AsyncHildClient
from hild.api.client import HildClient, HildError
from hild.api.ctl import EXIT_OK, EXIT_SERVICE, EXIT_UNREACHABLE, run_ctl
from hild.api.record import BLACKBOX_REASON, DISABLED, MAX_NOTE_CHARS, MAX_TASK_CHARS
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.daemon.daemon import Daemon as DaemonProcess
from hild.record.mcap_files import read_episode
from hild.record.model import EPISODE_JSON, ROSBAG_METADATA, RecordedEvent, RecordError, mcap_name
from tests.api.conftest import ROBOT, Daemon, engine_from, robot_config, running
from tests.api.test_ctl import ctl, parse
from tests.api.test_services import raw_call
from tests.controllers.test_teach import CONFIGS
from tests.helpers import free_endpoint

UPDATE_RATE = 500  # robot_config()'s


class FakeRecorder:
    """``Recorder``'s interface (hild/record/recorder.py), in memory: episodes are directories with empty files,
    cycles are the engine's. ``fail``: raised by the next call; ``hold``: start/stop/discard/blackbox wait for it."""

    def __init__(self, root: Path, engine: Engine) -> None:
        self.root = root
        self.engine = engine
        self.calls: list[tuple[Any, ...]] = []
        self.logged: list[RecordedEvent] = []
        self.fail: Exception | None = None
        self.hold: asyncio.Event | None = None
        self.episode: dict[str, Any] | None = None
        self.last: dict[str, Any] | None = None  # the last stop's reply
        self.count = 0

    async def _enter(self, *call: Any) -> None:
        self.calls.append(call)
        if self.hold is not None:
            await self.hold.wait()
        if self.fail is not None:
            fail, self.fail = self.fail, None
            raise fail

    async def start(self, task: str | None, fps: float | None, note: str | None) -> dict[str, Any]:
        await self._enter("start", task, fps, note)
        if self.episode is not None:
            raise RecordError(f"episode {self.episode['id']} is open: stop or discard it first")
        self.count += 1
        episode_id = f"20250101-120000-{ROBOT}" + (f"-{self.count}" if self.count > 1 else "")
        directory = self.root / episode_id
        directory.mkdir(parents=True)
        self.episode = {"id": episode_id, "directory": str(directory), "start_tick": self.engine.cycle}
        self.episode.update(task=task, fps=30.0 if fps is None else fps, note=note)
        return {k: self.episode[k] for k in ("id", "directory", "start_tick", "task", "fps")}

    def _open(self) -> dict[str, Any]:
        if self.episode is None:
            raise RecordError("no episode is open: hild ctl record start")
        return self.episode

    def _cycles(self) -> int:
        return self.engine.cycle - self._open()["start_tick"]

    async def stop(self) -> dict[str, Any]:
        await self._enter("stop")
        episode, cycles = self._open(), self._cycles()
        directory = Path(episode["directory"])
        files = [directory / mcap_name(episode["id"]), directory / ROSBAG_METADATA, directory / EPISODE_JSON]
        for file in files:
            file.write_text("")
        self.episode = None
        self.last = {
            "id": episode["id"],
            "directory": str(directory),
            "files": [str(f) for f in files],
            "cycles": cycles,
            "duration": cycles / UPDATE_RATE,
            "dropped": 0,
        }
        return dict(self.last)

    async def discard(self) -> dict[str, Any]:
        await self._enter("discard")
        episode = self._open()
        Path(episode["directory"]).rmdir()
        self.episode = None
        return {"id": episode["id"], "discarded": True}

    def status(self) -> dict[str, Any]:
        self.calls.append(("status",))
        if self.fail is not None:
            fail, self.fail = self.fail, None
            raise fail
        reply: dict[str, Any] = {"recording": self.episode is not None, "dropped": 0, "dir": str(self.root)}
        reply["recorder"] = "running"
        if self.episode is not None:
            reply.update(id=self.episode["id"], cycles=self._cycles(), duration=self._cycles() / UPDATE_RATE)
        if self.last is not None:
            reply["last"] = dict(self.last)
        return reply

    async def blackbox(self, reason: str, seconds: float | None = None) -> dict[str, Any]:
        await self._enter("blackbox", reason, seconds)
        kept = 10.0 if seconds is None else seconds
        file = self.root / "blackbox" / f"20250101-120000-{reason}.mcap"
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text("")
        return {"file": str(file), "cycles": round(kept * UPDATE_RATE), "seconds": kept}

    def log(self, event: RecordedEvent) -> None:
        self.logged.append(event)


@pytest.fixture
def recorder(engine: Engine, tmp_path: Path) -> FakeRecorder:
    return FakeRecorder(tmp_path / "recordings", engine)


@pytest.fixture
def daemon(engine: Engine, recorder: FakeRecorder) -> Iterator[Daemon]:
    with running(engine, recorder=recorder) as d:
        yield d


def wait_cycles(client: HildClient, count: int) -> None:
    """Until the open episode has ``count`` cycles (the stepper runs about one a millisecond)."""
    end = time.monotonic() + 10.0
    while client.record_status()["cycles"] < count:
        assert time.monotonic() < end, "the episode gained no cycles: is the stepper running?"
        time.sleep(0.005)


# ---- the services through the client --------------------------------------------------------------------------
def test_start_status_stop(client: HildClient, recorder: FakeRecorder) -> None:
    assert client.record_status() == {
        "ok": True,
        "error": None,
        "recording": False,
        "dropped": 0,
        "dir": str(recorder.root),
        "recorder": "running",
    }
    started = client.record_start(task="pick the cube", fps=15, note="first try\nsoft gripper")
    assert recorder.calls[-1] == ("start", "pick the cube", 15.0, "first try\nsoft gripper")
    assert started["ok"] is True and started["task"] == "pick the cube" and started["fps"] == 15.0
    assert started["id"] == f"20250101-120000-{ROBOT}" and Path(started["directory"]).is_dir()
    assert isinstance(started["start_tick"], int)
    wait_cycles(client, 20)
    status = client.record_status()
    assert status["recording"] is True and status["id"] == started["id"] and status["cycles"] >= 20
    stopped = client.record_stop()
    assert stopped["ok"] is True and stopped["id"] == started["id"] and stopped["cycles"] >= status["cycles"]
    assert stopped["duration"] == pytest.approx(stopped["cycles"] / UPDATE_RATE) and stopped["dropped"] == 0
    assert [Path(f).name for f in stopped["files"]] == [mcap_name(started["id"]), ROSBAG_METADATA, EPISODE_JSON]
    assert all(Path(f).is_absolute() and Path(f).exists() for f in stopped["files"])
    assert client.record_status()["recording"] is False


def test_discard(client: HildClient, recorder: FakeRecorder) -> None:
    started = client.record_start()
    assert recorder.calls[-1] == ("start", None, None, None) and started["fps"] == 30.0
    assert client.record_discard() == {"ok": True, "error": None, "id": started["id"], "discarded": True}
    assert not Path(started["directory"]).exists()
    assert client.record_status()["recording"] is False


def test_blackbox_on_demand(client: HildClient, recorder: FakeRecorder) -> None:
    reply = client.blackbox()
    assert recorder.calls[-1] == ("blackbox", BLACKBOX_REASON, None)
    assert reply["ok"] is True and Path(reply["file"]).exists() and reply["seconds"] == 10.0
    reply = client.blackbox(2.5)
    assert recorder.calls[-1] == ("blackbox", BLACKBOX_REASON, 2.5)
    assert reply["cycles"] == 1250 and reply["seconds"] == 2.5


def test_a_refusal_is_the_clients_error_and_the_daemon_answers_on(client: HildClient, recorder: FakeRecorder) -> None:
    with pytest.raises(HildError, match="no episode is open"):
        client.record_stop()
    reply = client.record_discard(check=False)
    assert reply == {"ok": False, "error": "no episode is open: hild ctl record start"}
    first = client.record_start(task="a")
    with pytest.raises(HildError, match=f"episode {first['id']} is open: stop or discard it first"):
        client.record_start(task="b")
    recorder.fail = RecordError("blackbox_seconds is 0: the flight recorder is off")
    assert client.blackbox(check=False)["error"] == "blackbox_seconds is 0: the flight recorder is off"
    assert client.status()["mode"] == "hold"
    assert client.record_stop()["id"] == first["id"]  # the open one was untouched by the refused start


def test_a_recorder_bug_costs_one_reply(client: HildClient, recorder: FakeRecorder) -> None:
    recorder.fail = RuntimeError("pipe closed")
    reply = client.record_start(check=False)
    assert reply["ok"] is False and reply["error"] == "internal error: RuntimeError: pipe closed"
    recorder.fail = OSError("status broke")
    assert client.record_status(check=False)["error"] == "internal error: OSError: status broke"
    assert client.record_start()["ok"] is True and client.record_status()["recording"] is True


def test_a_hanging_recorder_is_answered_in_time_and_its_call_completes(
    daemon: Daemon, client: HildClient, recorder: FakeRecorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    client.record_start()
    monkeypatch.setattr(record_module, "RECORDER_TIMEOUT", 0.3)
    recorder.hold = daemon.run(_event())
    reply = client.record_stop(check=False)
    assert reply["ok"] is False and "the recorder did not answer within 0.3 s; it may still complete" in reply["error"]
    assert client.status()["ok"] is True  # the loop was never blocked
    assert client.record_status()["recording"] is True  # the stop waits, shielded from the timeout
    recorder.hold, hold = None, recorder.hold
    daemon.loop.call_soon_threadsafe(hold.set)
    completed = asyncio.run(_poll(lambda: not client.record_status()["recording"]))
    assert completed, "the shielded stop never completed"


async def _event() -> asyncio.Event:
    return asyncio.Event()


async def _poll(condition: Any, timeout: float = 10.0) -> bool:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not await asyncio.to_thread(condition):
        if loop.time() > end:
            return False
        await asyncio.sleep(0.01)
    return True


def test_a_stop_longer_than_the_clients_timeout_still_answers(daemon: Daemon, recorder: FakeRecorder) -> None:
    with HildClient(ROBOT, connect=[daemon.endpoint], timeout=0.3) as client:
        client.record_start()
        recorder.hold = daemon.run(_event())
        daemon.loop.call_later(1.0, recorder.hold.set)  # longer than the client's 0.3 s; RECORD_WAIT covers it
        assert client.record_stop()["ok"] is True


# ---- validation: refused before the recorder is asked -----------------------------------------------------------
BAD_RECORD = [
    ({}, 'give the action: {"action": ...}'),
    ({"action": "pause"}, "action must be one of start, stop, discard, status, not 'pause'"),
    ({"action": 1}, "action must be one of start, stop, discard, status, not 1"),
    ({"action": "start", "task": 3}, "task must be a non-empty string, not int"),
    ({"action": "start", "task": "  "}, "task must be a non-empty string, not '  '"),
    ({"action": "start", "task": "x" * (MAX_TASK_CHARS + 1)}, f"at most {MAX_TASK_CHARS}"),
    ({"action": "start", "task": "two\nlines"}, "task must be one line of printable characters"),
    ({"action": "start", "note": ["x"]}, "note must be a non-empty string, not list"),
    ({"action": "start", "note": "n" * (MAX_NOTE_CHARS + 1)}, f"at most {MAX_NOTE_CHARS}"),
    ({"action": "start", "note": "bell\x07"}, "note must be printable text"),
    ({"action": "start", "fps": 0}, "fps must be a finite number > 0, not 0"),
    ({"action": "start", "fps": -30}, "fps must be a finite number > 0, not -30"),
    ({"action": "start", "fps": "30"}, "fps must be a number, not '30'"),
    ({"action": "start", "fps": True}, "fps must be a number, not bool"),
    ({"action": "start", "fps": None}, "fps must be a number, not NoneType"),
    ({"action": "start", "fps": 10**400}, "out of range; send finite numbers only"),  # the codec's
    ({"action": "start", "fps": UPDATE_RATE + 0.5}, "fps 500.5 is above the robot's update rate (500 Hz)"),
    ({"action": "stop", "task": "x"}, "task go with start only, not with stop"),
    ({"action": "status", "fps": 30, "note": "x"}, "fps, note go with start only, not with status"),
    ({"action": "start", "by": "me"}, "unknown field(s) 'by' (allowed: action, fps, note, task)"),
]
BAD_BLACKBOX = [
    ({"seconds": 0}, "seconds must be a finite number > 0, not 0"),
    ({"seconds": -1.5}, "seconds must be a finite number > 0, not -1.5"),
    ({"seconds": "5"}, "seconds must be a number, not '5'"),
    ({"reason": "fault"}, "unknown field(s) 'reason' (allowed: seconds)"),
]


@pytest.mark.parametrize(
    ("service", "request_", "reason"), [("record", *b) for b in BAD_RECORD] + [("blackbox", *b) for b in BAD_BLACKBOX]
)
def test_bad_requests(
    client: HildClient, recorder: FakeRecorder, service: str, request_: dict[str, Any], reason: str
) -> None:
    reply = raw_call(client, service, json.dumps(request_).encode())
    assert reply["ok"] is False and reason in reply["error"]
    assert [c for c in recorder.calls if c[0] != "status"] == []
    assert client.record_status()["ok"] is True


def test_fps_at_the_update_rate_is_taken(client: HildClient, recorder: FakeRecorder) -> None:
    assert client.record_start(fps=UPDATE_RATE)["fps"] == UPDATE_RATE


def test_the_client_refuses_non_finite_numbers_before_sending(client: HildClient, recorder: FakeRecorder) -> None:
    with pytest.raises(ValueError, match="fps must be a finite number"):
        client.record_start(fps=math.nan)
    with pytest.raises(ValueError, match="seconds must be a finite number"):
        client.blackbox(math.inf)
    assert recorder.calls == []


# ---- recording disabled ---------------------------------------------------------------------------------------
@pytest.fixture
def disabled(tmp_path: Path) -> Iterator[Daemon]:
    with running(engine_from(robot_config(), tmp_path)) as d:
        yield d


def test_disabled_recording_refuses_in_words(disabled: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    with HildClient(ROBOT, connect=[disabled.endpoint], timeout=5.0) as client:
        assert client.record_status() == {
            "ok": True,
            "error": None,
            "recording": False,
            "recorder": "disabled",
            "dropped": 0,
            "dir": None,
        }
        for call in (client.record_start, client.record_stop, client.record_discard, client.blackbox):
            assert call(check=False) == {"ok": False, "error": DISABLED}
        assert client.status()["ok"] is True
    assert ctl(disabled, "record", "start", "--task", "x") == EXIT_SERVICE
    assert capsys.readouterr().err.strip() == f"hild ctl: record start: {DISABLED}"
    assert ctl(disabled, "record", "status") == EXIT_OK
    assert "recording is disabled on this daemon" in capsys.readouterr().out
    assert ctl(disabled, "blackbox") == EXIT_SERVICE
    assert DISABLED in capsys.readouterr().err


# ---- hild ctl ---------------------------------------------------------------------------------------------------
def test_ctl_record_text(daemon: Daemon, recorder: FakeRecorder, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "record", "status") == EXIT_OK
    assert capsys.readouterr().out.strip() == f"not recording (recorder running, dir {recorder.root})"
    assert ctl(daemon, "record", "start", "--task", "pour", "--fps", "10", "--note", "n") == EXIT_OK
    assert recorder.calls[-1] == ("start", "pour", 10.0, "n")
    out = capsys.readouterr().out
    episode = f"20250101-120000-{ROBOT}"
    assert out.startswith(f"recording {episode} (task 'pour', 10 fps) into {recorder.root / episode}\n")
    assert "hild ctl record stop" in out
    assert ctl(daemon, "record", "status") == EXIT_OK
    assert capsys.readouterr().out.startswith(f"recording {episode}: ")
    assert ctl(daemon, "record", "start") == EXIT_SERVICE
    assert capsys.readouterr().err.strip() == (
        f"hild ctl: record start: episode {episode} is open: stop or discard it first"
    )
    assert ctl(daemon, "record", "stop") == EXIT_OK
    lines = capsys.readouterr().out.splitlines()
    head = lines[0].split()
    assert head[:2] == ["stopped", f"{episode}:"] and head[3:] == ["s,", head[4], "cycles,", "0", "dropped"]
    assert int(head[4]) > 0 and float(head[2]) == pytest.approx(int(head[4]) / UPDATE_RATE, abs=0.005)
    directory = recorder.root / episode
    assert lines[1:] == [f"  {directory / mcap_name(episode)}", f"  {directory / 'metadata.yaml'}",
                         f"  {directory / 'episode.json'}"]  # fmt: skip
    assert ctl(daemon, "record", "discard") == EXIT_SERVICE
    assert "no episode is open" in capsys.readouterr().err
    assert ctl(daemon, "record", "status") == EXIT_OK
    assert capsys.readouterr().out.splitlines() == [
        f"not recording (recorder running, dir {recorder.root})",
        f"last: {episode}: {head[2]} s, {head[4]} cycles, 0 dropped",
    ]


def test_ctl_record_json(daemon: Daemon, recorder: FakeRecorder, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "--json", "record", "start", "--task", "wipe") == EXIT_OK
    started = json.loads(capsys.readouterr().out)
    assert started["ok"] is True and started["task"] == "wipe" and started["fps"] == 30.0
    assert ctl(daemon, "record", "stop", "--json") == EXIT_OK
    stopped = json.loads(capsys.readouterr().out)
    assert stopped["ok"] is True and stopped["id"] == started["id"]
    assert any(f.endswith(".mcap") for f in stopped["files"]) and all(Path(f).exists() for f in stopped["files"])
    assert ctl(daemon, "--json", "record", "stop") == EXIT_SERVICE
    assert json.loads(capsys.readouterr().out) == {"ok": False, "error": "no episode is open: hild ctl record start"}
    assert ctl(daemon, "--json", "record", "discard") == EXIT_SERVICE
    capsys.readouterr()
    assert ctl(daemon, "--json", "record", "status") == EXIT_OK
    assert json.loads(capsys.readouterr().out)["recording"] is False


def test_ctl_discard(daemon: Daemon, recorder: FakeRecorder, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "record", "start") == EXIT_OK
    capsys.readouterr()
    assert ctl(daemon, "record", "discard") == EXIT_OK
    assert capsys.readouterr().out.strip() == f"discarded 20250101-120000-{ROBOT}: its directory is deleted"
    assert recorder.episode is None


def test_ctl_blackbox(daemon: Daemon, recorder: FakeRecorder, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "blackbox", "--seconds", "2") == EXIT_OK
    file = recorder.root / "blackbox" / f"20250101-120000-{BLACKBOX_REASON}.mcap"
    assert capsys.readouterr().out.strip() == f"black box saved: {file} (1000 cycles, 2.00 s)"
    assert ctl(daemon, "--json", "blackbox") == EXIT_OK
    assert json.loads(capsys.readouterr().out) == {
        "ok": True,
        "error": None,
        "file": str(file),
        "cycles": 5000,
        "seconds": 10.0,
    }
    assert recorder.calls == [("blackbox", BLACKBOX_REASON, 2.0), ("blackbox", BLACKBOX_REASON, None)]


@pytest.mark.parametrize(
    ("argv", "reason"),
    [
        (("record", "start", "--fps", "nan"), "record start: --fps must be a finite number > 0, not nan"),
        (("record", "start", "--fps", "0"), "record start: --fps must be a finite number > 0, not 0"),
        (("blackbox", "--seconds", "-1"), "blackbox: --seconds must be a finite number > 0, not -1"),
    ],
)
def test_ctl_refuses_bad_numbers_itself(
    daemon: Daemon, recorder: FakeRecorder, capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], reason: str
) -> None:
    assert ctl(daemon, *argv) == EXIT_SERVICE
    assert capsys.readouterr().err.strip() == f"hild ctl: {reason}"
    assert recorder.calls == []


def test_ctl_record_unreachable(capsys: pytest.CaptureFixture[str]) -> None:
    code = run_ctl(parse("--connect", free_endpoint(), "--robot", ROBOT, "--timeout", "0.3", "record", "status"))
    assert code == EXIT_UNREACHABLE
    assert "hild ctl: " in capsys.readouterr().err


# ---- the asyncio face ------------------------------------------------------------------------------------------
def test_async_client(daemon: Daemon, recorder: FakeRecorder) -> None:
    async def session() -> tuple[dict[str, Any], ...]:
        async with await AsyncHildClient.connect(ROBOT, [daemon.endpoint], timeout=5.0) as hild:
            started = await hild.record_start("stack", 20)
            status = await hild.record_status()
            stopped = await hild.record_stop()
            refused = await hild.record_discard(check=False)
            box = await hild.blackbox(1.0)
            return started, status, stopped, refused, box

    started, status, stopped, refused, box = asyncio.run(session())
    assert started["task"] == "stack" and started["fps"] == 20.0 and status["recording"] is True
    assert stopped["id"] == started["id"] and refused["ok"] is False and box["seconds"] == 1.0


# ---- end to end: the daemon's own recorder on the twin ---------------------------------------------------------
def twin_config(directory: Path) -> dict[str, Any]:
    """arm6 on its MuJoCo twin, paced on the sim clock, the cycle on a thread (LocalCycle), recording into
    ``directory``."""
    config = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    config["clock"] = {"source": "sim", "real_time_factor": 1.0}
    config["realtime"] = {**config.get("realtime", {}), "cycle_process": False}
    config["recording"] = {"dir": str(directory), "fsync": False, "chunk_period": 0.05, "min_free_mb": 1}
    return config


def test_start_a_few_hundred_cycles_stop_on_the_twin_read_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copy(CONFIGS / "arm6.xml", tmp_path)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(twin_config(tmp_path / "recordings"), sort_keys=False))
    endpoint = free_endpoint()
    daemon = DaemonProcess(load_config(path), [endpoint])
    seen: dict[str, Any] = {}

    async def scenario(client: HildClient) -> None:
        seen["started"] = await asyncio.to_thread(client.record_start, "hold still", 25.0, "end to end")
        end = time.monotonic() + 30.0
        while (await asyncio.to_thread(client.record_status))["cycles"] < 300:
            assert time.monotonic() < end, "the episode did not reach 300 cycles"
            await asyncio.sleep(0.02)
        seen["stopped"] = await asyncio.to_thread(client.record_stop)
        seen["status"] = await asyncio.to_thread(client.record_status)
        seen["ctl"] = await asyncio.to_thread(run_ctl, parse("--connect", endpoint, "record", "status"))

    async def main() -> int:
        task = asyncio.create_task(daemon.run())
        end = time.monotonic() + 60.0
        while not (daemon.ready or task.done()):
            assert time.monotonic() < end, "the daemon did not come up"
            await asyncio.sleep(0.01)
        if task.done():
            return task.result()
        client = HildClient("arm6", [endpoint], timeout=5.0)
        try:
            await scenario(client)
        finally:
            client.close()
            daemon.request_stop()
        return await task

    assert asyncio.run(main()) == 0
    started, stopped = seen["started"], seen["stopped"]
    assert started["task"] == "hold still" and started["fps"] == 25.0
    assert stopped["id"] == started["id"] and stopped["cycles"] >= 300 and stopped["dropped"] == 0
    files = [Path(f) for f in stopped["files"]]
    assert all(f.is_absolute() and f.exists() for f in files)
    assert any(f.suffix == ".mcap" for f in files)
    episode = read_episode(Path(stopped["directory"]))
    assert len(episode.rows) == stopped["cycles"]
    assert episode.rows.tick[0] == started["start_tick"]
    assert (episode.rows.tick == started["start_tick"] + np.arange(len(episode.rows))).all()  # every cycle, once
    assert episode.meta.task == "hold still" and episode.meta.note == "end to end" and episode.meta.fps == 25.0
    assert seen["status"]["recording"] is False and seen["status"]["last"]["id"] == stopped["id"]
    assert seen["ctl"] == EXIT_OK
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"not recording (recorder running, dir {tmp_path / 'recordings'})"
    assert out[1] == f"last: {stopped['id']}: {stopped['duration']:.2f} s, {stopped['cycles']} cycles, 0 dropped"
