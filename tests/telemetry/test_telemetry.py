"""rerun telemetry: the tap, the recording it produces, sinks and rotation, config errors, shutdown.

Everything runs the arm6 twin in lockstep (sim clock): each test steps the engine and calls the tap exactly as
``Engine.step`` does (after the supervisor's command), then asks the recorder process to flush (and waits for its
acknowledgement) instead of waiting on its timer.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import signal
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hild.arrays import JointState, ServoCommand
from hild.config import ConfigError, load_config
from hild.crossing.events import Event
from hild.crossing.telemetry import SHM_PREFIX, TelemetryTap
from hild.cycle.engine import Engine
from hild.modes import JointMode
from hild.telemetry import Telemetry, TelemetryError, layout
from hild.telemetry.recorder import EVENT_QUEUE
from hild.telemetry.replay import entity_row_counts, load_scalars, tracking
from hild.telemetry.worker import NICE
from tests.conftest import CONFIGS, merge
from tests.helpers import free_port, wait_for

# s a test waits for the recorder to acknowledge a flush. It runs at nice 19 by design: beside busy processes it
# gets the CPU last, so its acknowledgement may come seconds late (the daemon never waits for it; tests and tools do).
FLUSH_WAIT = 60.0
# A close's timeout where the file must be complete: a file sink closes first and may take all of it, but a
# nice-19 recorder beside busy processes needed more than the half second a 1 s timeout gives the sinks.
CLOSE_BUDGET = 10.0

ARM6_BODIES = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")


def arm6(telemetry: dict[str, Any]) -> dict[str, Any]:
    data = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    return merge(data, {"clock": {"source": "sim", "real_time_factor": 0}, "telemetry": telemetry})


def file_telemetry(path: Path, **extra: Any) -> dict[str, Any]:
    return {"enabled": True, "sinks": [{"kind": "file", "path": str(path)}], **extra}


class Rig:
    """A lockstep engine with telemetry; ``run`` steps and taps like the integrated ``Engine.step``."""

    def __init__(self, config: Path) -> None:
        loaded = load_config(config)
        self.engine = Engine(loaded)
        telemetry = Telemetry.from_config(loaded, self.engine.stats)
        assert telemetry is not None
        self.telemetry = telemetry
        self.engine.start()

    def run(self, cycles: int, flush_every: int = 50) -> None:
        e, tap = self.engine, self.telemetry.tap
        for k in range(cycles):
            e.run_cycles(1)
            tap.record(e.t, e.cycle, e.state, e.final, e.supervisor.mode, e.period)
            if (k + 1) % flush_every == 0:
                self.telemetry.log_events(e.events.drain())
                self.telemetry.flush(timeout=FLUSH_WAIT)


@pytest.fixture
def rig(write_config: Callable[..., Path], tmp_path: Path) -> Iterator[Callable[..., Rig]]:
    made: list[Rig] = []

    def make(telemetry: dict[str, Any]) -> Rig:
        made.append(Rig(write_config(arm6(telemetry))))
        return made[-1]

    yield make
    for r in made:  # a failed test must not leave a recorder process or a segment behind
        r.telemetry.close(timeout=1.0)


def test_recording_holds_every_cycle_joint_series_events_and_timing(rig: Callable[..., Rig], tmp_path: Path) -> None:
    r = rig(file_telemetry(tmp_path / "rec" / "arm6.rrd"))
    r.run(150)
    r.engine.estop()  # a mode change half-way: hold → estop
    r.run(150)
    r.telemetry.close(timeout=FLUSH_WAIT)  # its files are read next: let it finish them
    (path,) = r.telemetry.files
    assert path == tmp_path / "rec" / "arm6.rrd"
    counts = entity_row_counts(path)
    for q in layout.QUANTITIES:
        assert counts["/" + layout.joint_path(q, layout.MEASURED)] == 300
        assert counts["/" + layout.joint_path(q, layout.COMMANDED)] == 300
    for entity in (layout.TRACKING_ERROR, layout.MODE, layout.LOOP_PERIOD, layout.LOOP_DURATION):
        assert counts["/" + entity] == 300
    assert counts["/events"] >= 2  # "started" and the e-stop
    cmd, meas = tracking(path)
    assert meas.names == r.engine.joints
    np.testing.assert_allclose(cmd.column("elbow"), cmd.values[:, r.engine.joints.index("elbow")])
    assert list(meas.tick) == list(range(1, 301))
    np.testing.assert_allclose(meas.t, np.arange(1, 301) * 0.002)
    np.testing.assert_allclose(meas.values[-1], r.engine.state.position)
    np.testing.assert_allclose(cmd.values[-1], r.engine.final.position)
    error = load_scalars(path, layout.TRACKING_ERROR)
    np.testing.assert_allclose(error.values, cmd.values - meas.values, atol=1e-12)
    modes = load_scalars(path, layout.MODE)
    assert set(modes.values[149]) == {float(JointMode.HOLD)}
    assert set(modes.values[-1]) == {float(JointMode.ESTOP)}
    period = load_scalars(path, layout.LOOP_PERIOD)
    np.testing.assert_allclose(period.values, 2000.0)  # µs


def test_pose_is_decimated_to_pose_rate(rig: Callable[..., Rig], tmp_path: Path) -> None:
    r = rig(file_telemetry(tmp_path / "a.rrd", pose_rate=25))
    r.run(500, flush_every=37)  # 1 s of cycle time, flushes that do not line up with pose slots
    r.telemetry.close(timeout=FLUSH_WAIT)
    counts = entity_row_counts(r.telemetry.files[0])
    for body in ARM6_BODIES:
        assert 25 <= counts[f"/arm/{body}"] <= 26  # t ∈ (0, 1] spans 26 slots of 40 ms when t = 0 is excluded
    assert counts["/" + layout.joint_path("position", layout.MEASURED)] == 500


def test_scalar_rate_decimates_the_tap(rig: Callable[..., Rig], tmp_path: Path) -> None:
    r = rig(file_telemetry(tmp_path / "a.rrd", scalar_rate=100))
    r.run(500)
    r.telemetry.close(timeout=FLUSH_WAIT)
    series = load_scalars(r.telemetry.files[0], layout.joint_path("position", layout.MEASURED))
    assert len(series.tick) == 100
    assert set(np.diff(series.tick)) == {5}


def test_rotation_by_size_starts_a_second_timestamped_file(rig: Callable[..., Rig], tmp_path: Path) -> None:
    spec = {"enabled": True, "sinks": [{"kind": "file", "path": str(tmp_path / "arm6.rrd"), "rotate_mb": 0.05}]}
    r = rig(spec)
    r.run(
        1000, flush_every=250
    )  # four flushes, each a rotation check: ~3 files of 50 kB (fewer, on a starved recorder)
    r.telemetry.close(timeout=FLUSH_WAIT)
    files = r.telemetry.files
    assert len(files) >= 2
    for f in files:
        assert re.fullmatch(r"arm6-\d{8}T\d{6}Z(-\d+)?\.rrd", f.name)
        assert f.stat().st_size > 0
    total = sum(len(load_scalars(f, layout.joint_path("position", layout.MEASURED)).tick) for f in files)
    assert total == 1000  # nothing lost or duplicated across the rotation
    # every file stands alone: the static series names are in each
    assert load_scalars(files[-1], layout.joint_path("position", layout.MEASURED)).names == r.engine.joints


def _listening(port: int) -> set[str]:
    """Local addresses listening on ``port`` (IPv4 and IPv6, from /proc/net)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                addr, p = local.split(":")
                if state == "0A" and int(p, 16) == port:
                    found.add(addr)
    return found


def test_serve_binds_loopback_by_default(rig: Callable[..., Rig]) -> None:
    port = free_port()
    r = rig({"enabled": True, "sinks": [{"kind": "serve", "port": port}]})
    try:
        assert _listening(port) == {"0100007F"}  # 127.0.0.1, and nothing on 0.0.0.0 or ::
        r.run(50)
    finally:
        r.telemetry.close()


def test_close_with_an_unreachable_viewer_returns_promptly(rig: Callable[..., Rig], tmp_path: Path) -> None:
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"  # nobody listens there
    r = rig({"enabled": True, "sinks": [{"kind": "connect", "url": url}, {"kind": "file", "path": "x.rrd"}]})
    r.run(200)
    start = time.monotonic()
    r.telemetry.close(timeout=CLOSE_BUDGET)  # the viewer's flush can never finish: it takes what the file left …
    assert time.monotonic() - start < CLOSE_BUDGET + 2.0  # … and close still keeps to its timeout
    assert entity_row_counts(r.telemetry.files[0])["/joints/position/measured"] == 200  # the file still got it all


def test_disabled_telemetry_builds_nothing(write_config: Callable[..., Path]) -> None:
    loaded = load_config(write_config(arm6({"enabled": False})))
    assert Telemetry.from_config(loaded) is None


@pytest.mark.parametrize(
    ("telemetry", "expected"),
    [
        ({"enabled": True}, "telemetry: expected: telemetry is enabled but has no sinks"),
        ({"enabled": True, "sinks": [{"kind": "ftp"}]}, "telemetry.sinks[0]: expected: input tag 'ftp'"),
        ({"enabled": True, "sinks": [{"kind": "file", "path": "a.txt"}]}, "ending in .rrd"),
        ({"enabled": True, "sinks": [{"kind": "connect", "url": "http://x:1"}]}, "telemetry.sinks[0].connect.url"),
        ({"enabled": True, "sinks": [{"kind": "file", "path": "a.rrd", "rotate_mb": 0}]}, "rotate_mb"),
        ({"enabled": True, "sinks": [{"kind": "file", "path": "a.rrd"}], "pose_rate": 0}, "pose_rate"),
        ({"enabled": True, "sinks": [{"kind": "serve"}, {"kind": "serve", "port": 9877}]}, "at most one serve"),
    ],
)
def test_bad_telemetry_config_is_a_clear_error(
    write_config: Callable[..., Path], telemetry: dict[str, Any], expected: str
) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(write_config(arm6(telemetry)))
    text = str(info.value)
    assert expected in text, text


# ---- the tap alone ------------------------------------------------------------------------------------------------
def _filled(n: int) -> tuple[JointState, ServoCommand, np.ndarray]:
    state, command = JointState.zeros(n), ServoCommand.zeros(n)
    state.position[:] = np.arange(n)
    command.position[:] = np.arange(n) + 0.5
    return state, command, np.zeros(n, dtype=np.int64)


def test_tap_record_does_not_allocate() -> None:
    tap = TelemetryTap(6, 1024)
    state, command, modes = _filled(6)
    for i in range(100):  # warm up (first-call caches)
        tap.record(i * 0.001, i, state, command, modes, 0.001, 1e-4)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        for i in range(100, 10_100):
            tap.record(i * 0.001, i, state, command, modes, 0.001, 1e-4)
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before < 1024  # nothing retained per call (10 000 calls)
    assert peak - before < 4096  # and no array allocated in a call (one 6-float array alone is ~150 B)


def test_tap_reader_that_falls_behind_skips_ahead_and_counts() -> None:
    tap = TelemetryTap(3, 16)
    state, command, modes = _filled(3)
    for i in range(1, 41):
        state.position[0] = i
        tap.record(i * 0.01, i, state, command, modes, 0.01, 0.0)
    rows = tap.take()
    assert list(rows.tick) == list(range(26, 41))  # capacity − 1 newest rows
    assert tap.dropped == 25
    np.testing.assert_allclose(rows.measured_position[:, 0], rows.tick)
    np.testing.assert_allclose(rows.position[-1], [0.5, 1.5, 2.5])
    assert len(tap.take()) == 0


def test_tap_every_records_one_cycle_in_k() -> None:
    tap = TelemetryTap(2, 64, every=4)
    state, command, modes = _filled(2)
    for i in range(1, 21):
        tap.record(i * 0.01, i, state, command, modes, 0.01, 0.0)
    assert list(tap.take().tick) == [4, 8, 12, 16, 20]


def test_tap_reads_the_last_cycle_duration_from_loop_stats() -> None:
    from hild.crossing.stats import LoopStats

    stats = LoopStats()
    tap = TelemetryTap(2, 8, stats=stats)
    state, command, modes = _filled(2)
    tap.record(0.0, 0, state, command, modes, 0.001)
    stats.record(123_000, 0, False)
    tap.record(0.001, 1, state, command, modes, 0.001)
    np.testing.assert_allclose(tap.take().duration, [0.0, 123e-6])


# ---- the recorder process -----------------------------------------------------------------------------------------
def _segment(name: str) -> Path:
    return Path("/dev/shm") / name


def _ours() -> list[Path]:
    """Segments this test process created (other processes may run their own telemetry meanwhile)."""
    return sorted(Path("/dev/shm").glob(f"{SHM_PREFIX}{os.getpid()}-*"))


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"  # a zombie has exited
    except FileNotFoundError:
        return True


def test_recorder_runs_in_a_low_priority_process_and_close_unlinks_the_ring(
    rig: Callable[..., Rig], tmp_path: Path
) -> None:
    r = rig(file_telemetry(tmp_path / "a.rrd"))
    t = r.telemetry
    assert t.pid is not None and t.pid != os.getpid()
    assert os.getpriority(os.PRIO_PROCESS, t.pid) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICE)
    assert _segment(t.shm_name).exists()
    r.run(100)
    assert t.tap.head == 100  # the rows went through the shared ring
    t.close()
    assert not _segment(t.shm_name).exists()
    assert _gone(t.pid)
    assert entity_row_counts(t.files[0])["/joints/position/measured"] == 100
    r.run(10)  # a cycle that still calls the tap after close() writes into private memory, harmlessly
    assert t.flush() == 0
    assert _ours() == []


def test_a_sink_that_cannot_open_fails_start_up_and_leaves_nothing_behind(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    (tmp_path / "blocker").write_text("a file where the recording directory should be")
    loaded = load_config(write_config(arm6(file_telemetry(tmp_path / "blocker" / "x.rrd"))))
    with pytest.raises(TelemetryError, match=r"telemetry file sink: cannot create .*blocker"):
        Telemetry.from_config(loaded)
    assert _ours() == []


def test_recorder_death_is_reported_and_the_daemon_side_keeps_working(
    rig: Callable[..., Rig], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    r = rig(file_telemetry(tmp_path / "a.rrd"))
    t = r.telemetry
    r.run(50)
    pid = t.pid
    assert pid is not None
    os.kill(pid, signal.SIGKILL)
    with caplog.at_level(logging.ERROR, logger="hild.telemetry"):
        asyncio.run(asyncio.wait_for(t.run(), timeout=10.0))  # the watcher notices, reports and returns
    assert "the recorder process died (exit code -9); telemetry is off" in caplog.text
    assert not t.alive
    assert not _segment(t.shm_name).exists()
    start = time.monotonic()
    r.run(100)  # the cycle's tap, log_events and flush keep working, as no-ops for telemetry
    assert time.monotonic() - start < 5.0
    assert t.tap.head == 150
    t.log_events([Event(0.0, "info", "test", "after the recorder died")])
    t.close(timeout=1.0)
    assert _ours() == []


def test_close_with_a_hung_recorder_returns_within_the_timeout(rig: Callable[..., Rig], tmp_path: Path) -> None:
    r = rig(file_telemetry(tmp_path / "a.rrd"))
    t = r.telemetry
    r.run(20)
    assert t.pid is not None
    os.kill(t.pid, signal.SIGSTOP)  # wedged: answers nothing, ignores SIGTERM
    with pytest.raises(TelemetryError, match=r"did not acknowledge a flush within 0\.2 s"):
        t.flush(timeout=0.2)
    events = [Event(0.01 * i, "info", "test", f"event {i}") for i in range(EVENT_QUEUE + 100)]
    start = time.monotonic()
    t.log_events(events)  # the queue fills: the rest are dropped and counted, nothing waits
    assert t.dropped_events == 100
    t.close(timeout=1.0)
    assert time.monotonic() - start < 1.0 + 0.3
    assert not _segment(t.shm_name).exists()
    # SIGKILLed before close returned; a loaded machine may take a moment to schedule its end
    wait_for(lambda: _gone(t.pid), what="the recorder gone")


def test_the_daemon_process_never_loads_rerun() -> None:
    code = "import sys, hild.telemetry, hild.telemetry.recorder; assert 'rerun' not in sys.modules, 'rerun loaded'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


_KILLED_DAEMON = """
import os, signal, sys
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.telemetry import Telemetry
loaded = load_config(sys.argv[1])
engine = Engine(loaded)
t = Telemetry.from_config(loaded, engine.stats)
engine.start()
for _ in range(100):
    engine.run_cycles(1)
    t.tap.record(engine.t, engine.cycle, engine.state, engine.final, engine.supervisor.mode, engine.period)
t.flush()
print(t.pid, t.shm_name, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_daemon_leaves_no_recorder_and_no_segment(write_config: Callable[..., Path], tmp_path: Path) -> None:
    config = write_config(arm6(file_telemetry(tmp_path / "a.rrd")))
    done = subprocess.run(
        [sys.executable, "-c", _KILLED_DAEMON, str(config)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    pid, name = done.stdout.split()
    deadline = time.monotonic() + 10.0  # the recorder sees its pipe close and saves the file; the tracker unlinks
    while time.monotonic() < deadline and not (_gone(int(pid)) and not _segment(name).exists()):
        time.sleep(0.05)
    assert _gone(int(pid))
    assert not _segment(name).exists()
    assert entity_row_counts(tmp_path / "a.rrd")["/joints/position/measured"] == 100
