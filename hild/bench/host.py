"""What runs inside a scenario's process: hild's real ``Daemon`` plus a small control channel for the bench.

    python -m hild.bench.host CONFIG --listen tcp/127.0.0.1:PORT [--rig mit_can] [--can-bridge]

The process layout is the daemon's own — asyncio main thread with Zenoh, the cycle (a process of its own with
``realtime.cycle_process``, else a thread of this one), the telemetry recorder child — and, with ``--rig``,
whatever the rig adds (the CAN rig: emulated drives serviced by a thread of this process; :mod:`hild.bench.rigs`).
A python-can ``virtual`` channel does not leave its process, so with the cycle elsewhere ``--can-bridge`` serves
each of the rig's channels to the daemon's drivers over loopback (:mod:`hild.bench.rigs.can_bridge`).

The bench (the parent) talks to the daemon over Zenoh like any client, and to this host over stdin/stdout, one
JSON object per line (stdout is moved to a private descriptor first, so nothing else can write into the
channel). Requests, answered in order:

* ``{"op": "window"}`` — open a measurement window: note the loop statistics' counts (read-only, the cycle is
  not asked for anything: :mod:`hild.bench.window`), start copying what it records every ``DRAIN_S``; snapshot
  CPU ticks and the rig's counters.
* ``{"op": "collect"}`` — close it: copy the last slots, then return the window's cycle durations and period
  errors raw (ns) with CPU use (% of one core per process and thread group) and counter deltas.
* ``{"op": "clock"}`` — where the cycle clock's zero is in ``perf_counter_ns`` (``t`` = wake − start), and how
  far behind it the control clock that samples are stamped with had fallen, over time. In one process a request
  runs on the cycle thread right after the wake, so start ≈ min(now − t) over a few cycles. With the cycle
  elsewhere the shared clock cell is polled: it is written after the cycle's work, so start ≈ min(now − t) − the
  shortest recent cycle duration (a few tens of µs late at most). The lag (the stalls the control clock skipped)
  is summed from every period error since the cycle began, every ``LAG_EVERY_S``
  (:class:`hild.bench.window.ClockLag`), in either mode.
* ``{"op": "listen", "on": bool}`` — the rig's frame recording (latencies).
* ``{"op": "stop"}`` — stop the daemon as SIGTERM would, and exit.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from hild.bench.report import cpu_groups, cpu_percent
from hild.bench.rigs import BenchRig, rig_class
from hild.bench.window import DRAIN_S, ClockLag, StatsWindow, window_note
from hild.cli import setup_logging
from hild.config import ConfigError, load_config
from hild.cycle.engine import MAX_STEP_PERIODS
from hild.cycle.realtime import thaw_heap
from hild.daemon.daemon import Daemon
from hild.daemon.local import LocalCycle
from hild.daemon.remote import RemoteCycle

CLOCK_SAMPLES = 20
CLOCK_POLL_S = 0.1  # s of polling the shared clock cell (the cycle in a process of its own)
LAG_EVERY_S = 1.0  # s between two looks at the control clock's lag: often enough that no cycle is overwritten
LAG_LISTENING_S = 0.02  # … while latencies are probed: its history then maps a sample's stamp to its lag
LAG_HISTORY = 20_000  # entries kept (~7 min)
CLOCK_POLL_GAP_NS = 20_000  # a change seen more than this after the previous look is not used
READY_TIMEOUT = 60.0  # s from the daemon's start to its READY

log = logging.getLogger("hild.bench.host")


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
    def __init__(self, daemon: Daemon, rig: BenchRig | None, out: IO[str], bridge: Any = None) -> None:
        self.daemon = daemon
        self.link = daemon.link  # a LocalCycle (one process) or a SpawnedCycle: both keep LoopStats and status
        self.rig = rig
        self.bridge = bridge
        self.out = out
        self.tick_hz = os.sysconf("SC_CLK_TCK")
        self.window = StatsWindow(self.link.stats)
        self._draining: asyncio.Task[None] | None = None
        self.lag: ClockLag | None = None  # the control clock's lag behind the cycle clock
        self._lagging: asyncio.Task[None] | None = None
        self._lag_every = LAG_EVERY_S
        self._window_start = 0.0
        self._cpu_before: dict[str, int] = {}
        self._counters_before: dict[str, int] = {}

    def send(self, message: dict[str, Any]) -> None:
        self.out.write(json.dumps(message) + "\n")
        self.out.flush()

    @property
    def cycle_pid(self) -> int | None:
        process = self.link.process if isinstance(self.link, RemoteCycle) else None
        return process.pid if process is not None else None

    def threads(self) -> dict[str, list[int]]:
        """This process's threads by group (the cycle thread only when the cycle runs here)."""
        ids = {"asyncio": [os.getpid()]}
        thread = self.link.thread if isinstance(self.link, LocalCycle) else None
        if thread is not None and thread.native_id is not None:
            ids["cycle"] = [thread.native_id]
        if self.rig is not None:
            ids.update({name: [tid] for name, tid in self.rig.threads().items()})
        if self.bridge is not None:
            ids["bridge"] = self.bridge.threads()
        return ids

    def rig_processes(self) -> dict[str, int]:
        """Processes of the rig's own (not this one's threads): their CPU is reported apart, never subtracted."""
        processes = getattr(self.rig, "processes", None)
        return dict(processes()) if processes is not None else {}

    def side_groups(self) -> list[str]:
        """Thread groups of this process that are the bench's, not the daemon's (emulated drives, the bridge)."""
        return [*(self.rig.threads() if self.rig else {}), *(["bridge"] if self.bridge else [])]

    def cpu_snapshot(self) -> dict[str, int]:
        pid = os.getpid()
        snap = {"process": proc_ticks(f"/proc/{pid}/stat")}
        for name, tids in self.threads().items():
            snap[name] = sum(proc_ticks(f"/proc/{pid}/task/{tid}/stat") for tid in tids)
        for name, pid in self.rig_processes().items():  # the rig's own process (the bridged CAN rig)
            snap[name] = proc_ticks(f"/proc/{pid}/stat")
        if self.cycle_pid is not None:
            snap["cycle"] = proc_ticks(f"/proc/{self.cycle_pid}/stat")
        telemetry = self.daemon.telemetry
        if telemetry is not None and telemetry.pid:
            snap["telemetry"] = proc_ticks(f"/proc/{telemetry.pid}/stat")
        return snap

    def cpu_use(self, seconds: float) -> dict[str, float]:
        use = cpu_percent(self._cpu_before, self.cpu_snapshot(), seconds, self.tick_hz)
        return cpu_groups(use, self.side_groups(), cycle_process=self.cycle_pid is not None)

    # ---- requests --------------------------------------------------------------------------------------------
    async def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request.get("op")
        if op == "window":
            await self._stop_draining()
            self.window.open()
            self._draining = asyncio.create_task(self._drain(), name="bench-window")
            self._window_start = time.monotonic()
            self._cpu_before = self.cpu_snapshot()
            self._counters_before = self.rig.counters() if self.rig else {}
            return {"ok": True}
        if op == "collect":
            return await self.collect()
        if op == "clock":
            return await self.clock()
        if op == "listen":
            if self.rig is None:
                return {"ok": False, "error": "no rig in this scenario"}
            on = bool(request.get("on"))
            self._lag_every = LAG_LISTENING_S if on else LAG_EVERY_S
            frames = await asyncio.to_thread(self.rig.listen, on)
            return {"ok": True, **frames}
        if op == "stop":
            await self._stop_draining()
            self.daemon.request_stop()
            return {"ok": True}
        return {"ok": False, "error": f"unknown op {op!r}"}

    async def _drain(self) -> None:
        while True:
            await asyncio.sleep(DRAIN_S)
            self.window.take()

    async def _stop_draining(self) -> None:
        task, self._draining = self._draining, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    def follow_lag(self) -> None:
        """Start summing the control clock's lag from the period errors (``ClockLag``), read-only, in either
        mode, and keep when it moved: a sample's stamp is the control clock of its cycle."""
        if self.loaded_clock != "wall":
            return
        period_ns = round(1e9 / self.link.update_rate)
        self.lag = ClockLag(self.link.stats, period_ns, MAX_STEP_PERIODS)
        self._lagging = asyncio.create_task(self._follow_lag(), name="bench-clock-lag")

    @property
    def loaded_clock(self) -> str:
        return str(self.link.loaded.config.clock.source)

    def cycle_t(self) -> float:
        return float(self.link.t)

    async def _follow_lag(self) -> None:
        lag = self.lag
        assert lag is not None
        while True:
            lag.take(round(self.cycle_t() * 1e9))  # t read first: of the last cycle the take sees, or a little older
            del lag.history[:-LAG_HISTORY]
            await asyncio.sleep(self._lag_every)

    async def clock(self) -> dict[str, Any]:
        """Where the control clock's zero is in ``perf_counter_ns``: what a sample's stamp counts from."""
        engine = self.link.engine if isinstance(self.link, LocalCycle) else None
        if engine is not None:
            offsets = []
            for _ in range(CLOCK_SAMPLES):
                future = engine.submit(lambda: (engine.t, time.perf_counter_ns()))
                t, now = await asyncio.wrap_future(future)
                offsets.append(now - round(t * 1e9))
            return self._clock_reply(min(offsets), max(offsets) - min(offsets), "cycle")
        remote = self.link
        assert isinstance(remote, RemoteCycle)
        offsets = await asyncio.to_thread(poll_clock, lambda: remote.t, CLOCK_POLL_S)
        if not offsets:
            return {"ok": False, "error": "the shared cycle clock did not move"}
        stats = remote.stats
        shortest = int(stats.duration.values[: min(stats.duration.count, len(stats.duration.values))].min())
        return self._clock_reply(min(offsets) - shortest, max(offsets) - min(offsets), "polled")

    def _clock_reply(self, start: int, spread: int, method: str) -> dict[str, Any]:
        """The cycle clock's zero (``start_ns``) and the control clock's lag history: a sample stamped s woke at
        start + s + lag_at(history, s)."""
        lag = self.lag
        if lag is not None and not lag.certain:
            method += " (lag uncertain: cycles overwritten unread)"
        history = [[round(when, 6), value] for when, value in (lag.history if lag is not None else [])]
        return {"ok": True, "start_ns": start, "spread_ns": spread, "method": method, "lag_history": history}

    async def collect(self) -> dict[str, Any]:
        await self._stop_draining()
        window = self.window.close()
        seconds = time.monotonic() - self._window_start
        status = self.link.status()
        telemetry = self.daemon.telemetry
        note = window_note(window["cycles"], window["lost"], window["restarted"])
        return {
            "ok": True,
            "seconds": round(seconds, 3),
            "cycles": int(window["cycles"]),
            "overruns": int(window["overruns"]),
            "lost": int(window["lost"]),
            "window_notes": [note] if note else [],
            "duration_ns": [int(v) for v in window["duration_ns"]],
            "period_error_ns": [int(v) for v in window["period_error_ns"]],
            "cpu": self.cpu_use(seconds),
            "counters": counter_delta(self.rig.counters(), self._counters_before) if self.rig else {},
            "mode": status["mode"],
            "faults": [f"{j['name']}: {j['fault']}" for j in status["joints"] if j["fault"]],
            "realtime": status["realtime"],
            "cycle_process": self.cycle_pid is not None,
            "cycle_python_threads": self.link.python_threads if isinstance(self.link, RemoteCycle) else None,
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
        self.follow_lag()
        if self.rig is not None and isinstance(self.link, LocalCycle):
            self.rig.attach(self.link.engine)  # its drivers' counters; with the cycle elsewhere they stay there
        ready = {"event": "ready", "pid": os.getpid(), "robot": self.link.robot, "cycle_pid": self.cycle_pid}
        self.send({**ready, "threads": self.threads()})
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
        await self._stop_draining()
        if self._lagging is not None:
            self._lagging.cancel()
        code = await running
        self.send({"event": "stopped", "exit": code})
        return code


def _failure(task: asyncio.Task[int]) -> str:
    exc = task.exception()
    return f"{type(exc).__name__}: {exc}" if exc is not None else f"the daemon ended with exit {task.result()}"


def poll_clock(read_t: Callable[[], float], seconds: float) -> list[int]:
    """now − t (ns) each time the shared cycle clock ``read_t()`` is seen to change right after a look that saw the
    old value (a change seen late says nothing about when it happened)."""
    offsets: list[int] = []
    last = read_t()
    before = time.perf_counter_ns()
    deadline = before + round(seconds * 1e9)
    while before < deadline:
        t = read_t()
        now = time.perf_counter_ns()
        if t != last:
            if now - before < CLOCK_POLL_GAP_NS:
                offsets.append(now - round(t * 1e9))
            last = t
        before = now
    return offsets


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="A hild bench scenario's daemon process (run by hild bench).")
    parser.add_argument("config")
    parser.add_argument("--listen", required=True, action="append")
    parser.add_argument("--rig", help="a rig from hild.bench.rigs (mit_can, cia402)")
    parser.add_argument(
        "--can-bridge",
        action="store_true",
        help="serve the rig's virtual CAN channels to the daemon over loopback, the emulated drives in a process of "
        "their own (hild.bench.rigs.can_process)",
    )
    parser.add_argument(
        "--stock-bridge",
        action="store_true",
        help="with --can-bridge: as before the [teleop] fix, the drives in this process behind python-can-remote's "
        "stock server (hild.bench.rigs.can_bridge), for before/after figures",
    )
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
    rig: BenchRig | None = rig_class(args.rig)() if args.rig else None
    bridge = None
    try:
        if rig is not None and args.can_bridge and not args.stock_bridge:
            from hild.bench.rigs.can_process import CanRigProcess

            rig = CanRigProcess(args.rig)  # the drives and their loopback servers in a process of their own
            loaded = load_config(rig.serve(Path(args.config)))  # the same robot, its buses served over loopback
        elif rig is not None:
            rig.start(loaded)  # the drives must be there before the daemon configures them
        if args.can_bridge and args.stock_bridge:
            from hild.bench.rigs.can_bridge import CanBridge

            bridge = CanBridge()
            loaded = load_config(bridge.serve(Path(args.config)))  # the same robot, its buses served over loopback
        daemon = Daemon(loaded, args.listen)
        code = asyncio.run(Host(daemon, rig, out, bridge).serve())
    except Exception as exc:
        out.write(json.dumps({"event": "failed", "error": f"{type(exc).__name__}: {exc}"}) + "\n")
        return 1
    finally:
        if bridge is not None:
            bridge.close()
        if rig is not None:
            rig.stop()
    thaw_heap()
    return code


if __name__ == "__main__":
    sys.exit(main())
