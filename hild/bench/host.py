"""What runs inside a scenario's process: hild's real ``Daemon`` plus a small control channel for the bench.

    python -m hild.bench.host CONFIG --listen tcp/127.0.0.1:PORT [--rig mit_can] [--capacity N]

The process layout is the daemon's own — asyncio main thread with Zenoh, the cycle thread, the telemetry
recorder child — and, with ``--rig``, whatever the rig adds (the CAN rig: emulated drives serviced by a thread).
Rigs come from drivers through the entry-point group ``hild.bench_rigs``; hild never imports them directly.

The bench (the parent) talks to the daemon over Zenoh like any client, and to this host over stdin/stdout, one
JSON object per line (stdout is moved to a private descriptor first, so nothing else can write into the
channel). Requests, answered in order:

* ``{"op": "window"}`` — open a measurement window: on the cycle thread, between two cycles, reset the loop
  statistics; then snapshot CPU ticks and the rig's counters.
* ``{"op": "collect"}`` — close it: copy the window's cycle durations and period errors on the cycle thread,
  then return them raw (ns) with CPU use (% of one core per thread group) and counter deltas.
* ``{"op": "clock"}`` — when the cycle clock's zero was, in ``perf_counter_ns``: the wall clock's ``t`` is
  wake − start, and a request runs right after the wake, so start ≈ min(now − t) over a few cycles.
* ``{"op": "listen", "on": bool}`` — the rig's frame recording (latencies).
* ``{"op": "stop"}`` — stop the daemon as SIGTERM would, and exit.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import IO, Any, Protocol

from hild.bench.report import cpu_percent
from hild.cli import setup_logging
from hild.config import ConfigError, load_config
from hild.config.loader import LoadedConfig
from hild.daemon import Daemon
from hild.realtime import thaw_heap
from hild.stats import LoopStats

RIGS = "hild.bench_rigs"
CLOCK_SAMPLES = 20
READY_TIMEOUT = 60.0  # s from the daemon's start to its READY

log = logging.getLogger("hild.bench.host")


class BenchRig(Protocol):
    """What a rig offers the bench (see drivers/can/bench_rig.py for the one hild ships)."""

    trajectory_scale: float

    @staticmethod
    def robot_config(joints: int, rate: float) -> dict[str, Any]: ...

    def start(self, loaded: LoadedConfig) -> None: ...

    def attach(self, engine: Any) -> None: ...

    def threads(self) -> dict[str, int]: ...

    def counters(self) -> dict[str, int]: ...

    def listen(self, on: bool) -> dict[str, Any]: ...

    def stop(self) -> None: ...


def rig_class(name: str) -> Callable[[], BenchRig]:
    """The rig registered as ``name`` in ``hild.bench_rigs``."""
    for ep in entry_points(group=RIGS):
        if ep.name == name:
            loaded: Callable[[], BenchRig] = ep.load()
            return loaded
    known = ", ".join(sorted(ep.name for ep in entry_points(group=RIGS))) or "none installed"
    raise LookupError(f"no bench rig {name!r} in {RIGS} (known: {known})")


def proc_ticks(path: str) -> int:
    """utime + stime (clock ticks) from a /proc/<pid>/stat or /proc/<pid>/task/<tid>/stat file; 0 if gone."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        return 0
    fields = text[text.rindex(")") + 2 :].split()  # the command name may hold spaces and parentheses
    return int(fields[11]) + int(fields[12])  # fields 14 and 15 of proc(5), counted from the state (field 3)


def counter_delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {k: after[k] - before.get(k, 0) for k in after if after[k] - before.get(k, 0)}


class Host:
    def __init__(self, daemon: Daemon, rig: BenchRig | None, out: IO[str]) -> None:
        self.daemon = daemon
        self.engine = daemon.engine
        self.rig = rig
        self.out = out
        self.tick_hz = os.sysconf("SC_CLK_TCK")
        self._window_start = 0.0
        self._cpu_before: dict[str, int] = {}
        self._counters_before: dict[str, int] = {}

    def send(self, message: dict[str, Any]) -> None:
        self.out.write(json.dumps(message) + "\n")
        self.out.flush()

    async def on_cycle(self, action: Callable[[], Any]) -> Any:
        """Run ``action`` on the cycle thread at the start of the next cycle."""
        return await asyncio.wrap_future(self.engine.submit(action))

    def threads(self) -> dict[str, int]:
        ids = {"asyncio": os.getpid()}
        if self.daemon.cycle is not None and self.daemon.cycle.native_id is not None:
            ids["cycle"] = self.daemon.cycle.native_id
        if self.rig is not None:
            ids.update(self.rig.threads())
        return ids

    def cpu_snapshot(self) -> dict[str, int]:
        pid = os.getpid()
        snap = {"process": proc_ticks(f"/proc/{pid}/stat")}
        for name, tid in self.threads().items():
            snap[name] = proc_ticks(f"/proc/{pid}/task/{tid}/stat")
        telemetry = self.daemon.telemetry
        if telemetry is not None and telemetry.pid:
            snap["telemetry"] = proc_ticks(f"/proc/{telemetry.pid}/stat")
        return snap

    def cpu_use(self, seconds: float) -> dict[str, float]:
        use = cpu_percent(self._cpu_before, self.cpu_snapshot(), seconds, self.tick_hz)
        rig_threads = sum(use.get(name, 0.0) for name in (self.rig.threads() if self.rig else {}))
        use["daemon"] = round(use["process"] - rig_threads, 1)
        # Zenoh's threads and the rest; ticks are 1/SC_CLK_TCK s per thread, so rounding can go a little negative
        use["other"] = max(0.0, round(use["daemon"] - use.get("cycle", 0.0) - use.get("asyncio", 0.0), 1))
        return use

    # ---- requests --------------------------------------------------------------------------------------------
    async def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request.get("op")
        if op == "window":
            stats = self.engine.stats
            await self.on_cycle(stats.reset)
            self._window_start = time.monotonic()
            self._cpu_before = self.cpu_snapshot()
            self._counters_before = self.rig.counters() if self.rig else {}
            return {"ok": True}
        if op == "collect":
            return await self.collect()
        if op == "clock":
            engine = self.engine
            offsets = []
            for _ in range(CLOCK_SAMPLES):
                t, now = await self.on_cycle(lambda: (engine.t, time.perf_counter_ns()))
                offsets.append(now - round(t * 1e9))
            return {"ok": True, "start_ns": min(offsets), "spread_ns": max(offsets) - min(offsets)}
        if op == "listen":
            if self.rig is None:
                return {"ok": False, "error": "no rig in this scenario"}
            frames = await asyncio.to_thread(self.rig.listen, bool(request.get("on")))
            return {"ok": True, **frames}
        if op == "stop":
            self.daemon.request_stop()
            return {"ok": True}
        return {"ok": False, "error": f"unknown op {op!r}"}

    async def collect(self) -> dict[str, Any]:
        stats = self.engine.stats

        def copy_window() -> tuple[int, int, list[int], list[int]]:
            n = min(stats.cycles, len(stats.duration.values))
            return stats.cycles, stats.overruns, stats.duration.values[:n].copy(), stats.period_error.values[:n].copy()

        cycles, overruns, duration, period_error = await self.on_cycle(copy_window)
        seconds = time.monotonic() - self._window_start
        status = self.engine.status()
        telemetry = self.daemon.telemetry
        return {
            "ok": True,
            "seconds": round(seconds, 3),
            "cycles": int(cycles),
            "overruns": int(overruns),
            "duration_ns": [int(v) for v in duration],
            "period_error_ns": [int(v) for v in period_error],
            "cpu": self.cpu_use(seconds),
            "counters": counter_delta(self.rig.counters(), self._counters_before) if self.rig else {},
            "mode": status["mode"],
            "faults": [f"{j['name']}: {j['fault']}" for j in status["joints"] if j["fault"]],
            "realtime": status["realtime"],
            "telemetry_dropped_rows": getattr(getattr(telemetry, "tap", None), "dropped", None),
        }

    # ---- the process ---------------------------------------------------------------------------------------
    async def serve(self) -> int:
        running = asyncio.create_task(self.daemon.run(), name="hild-daemon")
        deadline = time.monotonic() + READY_TIMEOUT
        while not self.daemon.ready:
            if running.done():
                self.send({"event": "failed", "error": _failure(running)})
                await self.daemon.close_telemetry()  # as run_daemon does after a failed start
                return 1
            if time.monotonic() > deadline:
                self.send({"event": "failed", "error": f"not ready within {READY_TIMEOUT:g} s"})
                self.daemon.request_stop()
                await running
                return 1
            await asyncio.sleep(0.01)
        if self.rig is not None:
            self.rig.attach(self.engine)
        self.send({"event": "ready", "pid": os.getpid(), "robot": self.engine.robot, "threads": self.threads()})
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
        while not running.done():
            line_task = asyncio.ensure_future(reader.readline())
            await asyncio.wait({line_task, running}, return_when=asyncio.FIRST_COMPLETED)
            if not line_task.done():
                line_task.cancel()
                break
            line = line_task.result()
            if not line:  # the bench went away: stop like on SIGTERM
                self.daemon.request_stop()
                break
            try:
                request = json.loads(line)
                reply = await self.handle(request)
            except Exception as exc:  # a bad request is answered, never fatal
                reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            self.send(reply)
        code = await running
        self.send({"event": "stopped", "exit": code})
        return code


def _failure(task: asyncio.Task[int]) -> str:
    exc = task.exception()
    return f"{type(exc).__name__}: {exc}" if exc is not None else f"the daemon ended with exit {task.result()}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="A hild bench scenario's daemon process (run by hild bench).")
    parser.add_argument("config")
    parser.add_argument("--listen", required=True, action="append")
    parser.add_argument("--rig", help="a rig from the hild.bench_rigs entry-point group")
    parser.add_argument("--capacity", type=int, default=10_000, help="cycles the loop statistics keep")
    parser.add_argument("--log-level", default="warning")
    args = parser.parse_args(argv)
    out = os.fdopen(os.dup(1), "w", buffering=1)  # the control channel
    os.dup2(2, 1)  # anything else printed goes to the log
    setup_logging(args.log_level)
    try:
        loaded = load_config(args.config)
    except ConfigError as exc:
        out.write(json.dumps({"event": "failed", "error": str(exc)}) + "\n")
        return 1
    # The bench's windows and CPU accounting reach into the cycle thread: one process, until it measures the cycle
    # process too.
    realtime = loaded.config.realtime.model_copy(update={"cycle_process": False})
    loaded.config = loaded.config.model_copy(update={"realtime": realtime})
    rig = rig_class(args.rig)() if args.rig else None
    try:
        if rig is not None:
            rig.start(loaded)  # the drives must be there before the daemon configures them
        daemon = Daemon(loaded, args.listen)
        assert daemon.engine is not None
        daemon.engine.stats = LoopStats(window=max(10_000, args.capacity))  # every cycle of a window, not the last 10k
        code = asyncio.run(Host(daemon, rig, out).serve())
    except Exception as exc:
        out.write(json.dumps({"event": "failed", "error": f"{type(exc).__name__}: {exc}"}) + "\n")
        return 1
    finally:
        if rig is not None:
            rig.stop()
    thaw_heap()
    return code


if __name__ == "__main__":
    sys.exit(main())
