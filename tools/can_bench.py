#!/usr/bin/env python3
"""Benchmark the CAN path: the cycle at 1 kHz with 3 Damiao motors and at 500 Hz with 6, emulated in-process.

    python tools/can_bench.py                              # both scenarios, 10 s each
    python tools/can_bench.py --scenario 3x1000 --seconds 30 --json can_bench.json
    python tools/can_bench.py --priority 50            # SCHED_FIFO cycle (and emulator one below), if permitted

The engine alone, in this process, with the driver's own read/write times and reply bookkeeping; ``hild bench``
measures the whole daemon (Zenoh, telemetry, latencies) with the same rig. For each scenario the rig's robot
config (``hild.bench.rigs.mit_can.robot_config``) puts ``mit_can`` on a private python-can ``virtual`` channel (Damiao
DM4340/DM4310, ids 1..n, reply ids 0x11..), with a ``joint_state_broadcaster`` at 100 Hz and ``joint_trajectory``
running the standard trajectory (``hild.motion.reference``, scaled down) over and over, so the cycle does real
work. The firmware emulator (``drivers.can.emulator``) services the same channel from a background thread every
``--emulator-period`` s; the engine runs on ``hild.cycle.CycleThread`` on the wall clock with the daemon's
real-time settings. After a 1 s warm-up, the measurement window is opened and closed on the cycle thread itself
(``Engine.submit``), so every counter covers exactly the same cycles.

Reported per scenario: cycle duration and period error (p50/p99/p99.9/max, µs) and overruns per 10k cycles
(``hild.stats``); frames sent and received per cycle (the driver's link counters); missed replies = cycles × motors
in which a motor had no fresh reply at ``read``, per 10k; late replies (a motor's reply arriving together with the
next one, the older one overwritten); ignored frames; the emulator's counters and how regularly its thread got to
run; faults and trajectory goals. For context, the floor: python-can's ``virtual`` bus alone (send on one bus,
recv on another on the same channel, and a request → reply round trip).

The emulator thread competes with the cycle for the GIL (real drives answer from their own silicon), so these
figures are an upper bound on what the CAN path costs the cycle. With ``--priority`` the emulator thread runs
SCHED_FIFO one level below the cycle: left at normal priority it starves behind the cycle on a loaded machine and
the drives' watchdogs fire.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import shlex
import sys
import tempfile
import textwrap
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.can.bus import open_bus
from drivers.can.driver import MitCanDriver
from drivers.can.emulator import Emulator, MotorPlant
from drivers.can.emulator.runtime import build_firmware
from drivers.can.params import MitCanParams
from hild.arrays import JointState, ServoCommand
from hild.bench.probes.can_virtual import virtual_round_trip
from hild.bench.rigs.mit_can import START_POSITIONS, CanBenchRig, motor_kinds, robot_config
from hild.config import load_config
from hild.cycle import CycleThread
from hild.engine import Engine
from hild.motion.reference import standard_trajectory
from hild.realtime import apply_process_settings, freeze_heap
from hild.stats import LoopStats, format_loop_table, percentiles

JTC = "joint_trajectory"
WARMUP_S = 1.0
TRAJECTORY_SCALE = CanBenchRig.trajectory_scale
SUBMIT_TIMEOUT = 5.0  # s to wait for the cycle thread to run a submitted action


@dataclass(frozen=True)
class Scenario:
    name: str
    motors: int
    rate: float


SCENARIOS = {s.name: s for s in (Scenario("3x1000", 3, 1000.0), Scenario("6x500", 6, 500.0))}


class DriverProbe:
    """Wraps the driver's ``read`` and ``write``: their time per cycle, and how many motors had no fresh reply.

    Per cycle: two perf_counter_ns pairs, one count_nonzero and stores into preallocated arrays.
    """

    def __init__(self, driver: MitCanDriver, motors: int, capacity: int) -> None:
        self._read = driver.read
        self._write = driver.write
        self.motors = motors
        self.read_ns = np.zeros(capacity, dtype=np.int64)
        self.write_ns = np.zeros(capacity, dtype=np.int64)
        self.cycles = 0
        self.writes = 0
        self.missed = 0
        self.cycles_with_miss = 0
        driver.read = self.read  # type: ignore[method-assign]
        driver.write = self.write  # type: ignore[method-assign]

    def read(self, t: float, dt: float, state: JointState) -> None:
        start = time.perf_counter_ns()
        self._read(t, dt, state)
        self.read_ns[self.cycles % len(self.read_ns)] = time.perf_counter_ns() - start
        self.cycles += 1
        missing = self.motors - int(np.count_nonzero(state.fresh))
        if missing:
            self.missed += missing
            self.cycles_with_miss += 1

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        start = time.perf_counter_ns()
        self._write(t, dt, command)
        self.write_ns[self.writes % len(self.write_ns)] = time.perf_counter_ns() - start
        self.writes += 1

    def reset(self) -> None:
        self.cycles = self.writes = self.missed = self.cycles_with_miss = 0

    def times_us(self) -> dict[str, dict[str, float]]:
        reads = self.read_ns[: min(self.cycles, len(self.read_ns))]
        writes = self.write_ns[: min(self.writes, len(self.write_ns))]
        return {"read": percentiles(reads, "ns"), "write": percentiles(writes, "ns")}


class ServiceClock:
    """Wraps the emulator's ``service`` to keep the time of every call (emulator thread only)."""

    def __init__(self, service: Callable[[float], None]) -> None:
        self._service = service
        self.times: list[float] = []

    def __call__(self, now: float) -> None:
        self.times.append(now)
        self._service(now)


@dataclass
class Snapshot:
    """Counters taken on the cycle thread at the start of a cycle."""

    now: float
    cycle_t: float
    driver: dict[str, int]
    replies: int
    emulator: dict[str, int]


def snapshot(engine: Engine, driver: MitCanDriver, emulator: Emulator) -> Snapshot:
    # The emulator thread may be inside service(): its counters can be off by the frames of one service.
    return Snapshot(
        time.monotonic(), engine.t, dict(driver.statistics), int(driver.replies.sum()), dict(emulator.stats())
    )


def on_cycle(engine: Engine, action: Callable[[], Any]) -> Any:
    """Run ``action`` on the cycle thread between two cycles and return its result."""
    future: Future[Any] = engine.submit(action)
    return future.result(timeout=SUBMIT_TIMEOUT)


def delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {key: after.get(key, 0) - before.get(key, 0) for key in sorted(set(after) | set(before))}


def measure(scenario: Scenario, seconds: float, emulator_period: float, priority: int, workdir: Path) -> dict[str, Any]:
    path = workdir / f"can_bench_{scenario.name}.yaml"
    path.write_text(json.dumps(robot_config(scenario.motors, scenario.rate), indent=1))  # JSON is YAML
    loaded = load_config(path)
    cfg = loaded.config
    settings = cfg.realtime.model_copy(update={"priority": priority})
    ((component, params),) = loaded.driver_params.items()  # both scenarios fit one 1 Mbit/s bus
    assert isinstance(params, MitCanParams)
    joints = list(cfg.hardware[component].joints)

    bus = open_bus(params.bus)
    plant = MotorPlant(len(joints), inertia=0.05, damping=0.05, positions=START_POSITIONS[: len(joints)])
    emulator = Emulator(bus, build_firmware(params, joints), plant)
    services = ServiceClock(emulator.service)
    emulator.service = services  # type: ignore[method-assign]
    stop_emulator = threading.Event()

    def serve() -> None:
        if priority > 1:  # an emulator left at normal priority would starve behind a SCHED_FIFO cycle
            with contextlib.suppress(OSError):  # the cycle thread's report says whether it is permitted
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority - 1))
        emulator.run(stop_emulator, emulator_period)

    emulator_thread = threading.Thread(target=serve, name="can-bench-emulator", daemon=True)

    engine = Engine(loaded)
    capacity = int(scenario.rate * (seconds + WARMUP_S)) + 1000
    engine.stats = LoopStats(window=capacity)  # every counted cycle, not only the last 10k
    (slot,) = engine.hardware
    driver = slot.component
    assert isinstance(driver, MitCanDriver)
    probe = DriverProbe(driver, len(joints), capacity)

    realtime = apply_process_settings(settings)
    load_before = os.getloadavg()[0]
    emulator_thread.start()
    cycle: CycleThread | None = None
    goals: dict[str, int] = {}
    try:
        realtime["gc"] = freeze_heap(settings)
        engine.start()  # configure reads the registers and positions from the running emulator, then enables
        cycle = CycleThread(engine, "wall", 1.0, settings)
        cycle.start()  # at once: the Damiao watchdog (timeout_ms) expects commands from now on
        switched = on_cycle(engine, lambda: engine.switch([JTC], []))
        if not switched.ok:
            raise SystemExit(f"cannot activate {JTC}: {switched.error}")
        action = engine.manager.records[JTC].instance.action
        home = engine.state.position.copy()
        goal = standard_trajectory(joints, home.tolist(), scale=TRAJECTORY_SCALE)

        def keep_moving() -> None:
            """The asyncio side's part: collect results, send the next trajectory when one ends."""
            finished = action.collect()
            for result in finished:
                goals[str(result.status)] = goals.get(str(result.status), 0) + 1
            if finished or not goals.get("submitted"):
                reply = action.submit(goal)
                key = "submitted" if reply["ok"] else "rejected"
                goals[key] = goals.get(key, 0) + 1

        def run_for(duration: float) -> None:
            end = time.monotonic() + duration
            while (left := end - time.monotonic()) > 0.0:
                keep_moving()
                time.sleep(min(0.05, left))

        run_for(WARMUP_S)

        def open_window() -> Snapshot:
            engine.stats.reset()
            probe.reset()
            return snapshot(engine, driver, emulator)

        before: Snapshot = on_cycle(engine, open_window)
        run_for(seconds)

        def close_window() -> tuple[Snapshot, dict[str, object], int, int, int, dict[str, dict[str, float]]]:
            taken = snapshot(engine, driver, emulator)
            return taken, engine.stats.summary(), probe.cycles, probe.missed, probe.cycles_with_miss, probe.times_us()

        after, loop, cycles, missed, cycles_with_miss, driver_us = on_cycle(engine, close_window)
        status = engine.status()
        mode = engine.overall_mode()
    finally:
        if cycle is not None:
            cycle.stop()
            cycle.join(10.0)  # the cycle thread stops the engine: hold, disable, release the bus
        elif engine.started:
            engine.stop()
        stop_emulator.set()
        emulator_thread.join(5.0)
        bus.shutdown()
    if cycle is not None and cycle.error is not None:
        raise SystemExit(f"the cycle thread crashed: {cycle.error!r}")

    n = len(joints)
    cycles = max(1, cycles)
    driver_delta = delta(after.driver, before.driver)
    replies = after.replies - before.replies
    fresh = cycles * n - missed
    stamps = np.array(services.times)
    in_window = stamps[(stamps >= before.now) & (stamps <= after.now)]
    gaps = np.diff(in_window)
    window_s = after.now - before.now
    events = [e for e in engine.events.drain() if e.level in ("warning", "error")]
    return {
        "scenario": scenario.name,
        "motors": n,
        "models": [k.model for k in motor_kinds(n)],
        "rate_hz": scenario.rate,
        "seconds": round(window_s, 3),
        "load_average_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "window_cycle_clock_s": [round(before.cycle_t, 3), round(after.cycle_t, 3)],
        "mode": mode,
        "realtime": {**realtime, **engine.realtime_report},
        **loop,
        "overruns_per_10k": round(int(loop["overruns"]) * 10_000 / cycles, 2),  # type: ignore[call-overload]
        "counted_cycles": cycles,
        "driver_us": driver_us,
        "frames_sent_per_cycle": round(driver_delta["frames_sent"] / cycles, 3),
        "frames_received_per_cycle": round(driver_delta["frames_received"] / cycles, 3),
        "missed_replies": missed,
        "missed_replies_per_10k": round(missed * 10_000 / (cycles * n), 2),
        "cycles_with_missed_reply": cycles_with_miss,
        "late_replies": max(0, replies - fresh),
        "bad_frames": sum(v for k, v in driver_delta.items() if k.startswith("ignored ")),
        "driver": driver_delta,
        "emulator": delta(after.emulator, before.emulator),
        "emulator_services_per_s": round(len(in_window) / window_s, 1) if window_s > 0 else 0.0,
        "emulator_service_gap_us": percentiles(gaps, "s"),
        "faults": [f"{j['name']}: {j['fault']}" for j in status["joints"] if j["fault"]],
        "hardware": status["hardware"],
        "goals": goals,
        "events": [e.as_dict() for e in events][:20],
    }


# ---- report ---------------------------------------------------------------------------------------------------
def format_report(floor: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    lines = ["Cycle (wall clock, CycleThread, mit_can + Damiao emulator on a python-can virtual bus)"]
    loop_table = format_loop_table(rows).splitlines()
    lines.append(f"{'scenario':>8} " + loop_table[0])
    lines += [f"{r['scenario']:>8} " + line for r, line in zip(rows, loop_table[1:-1], strict=True)]
    lines.append(loop_table[-1])
    lines.append("")
    lines.append("CAN path (per counted cycle; missed = motor without a fresh reply at read)")
    lines.append(
        f"{'scenario':>8} {'motors':>6} {'sent/cyc':>8} {'recv/cyc':>8} {'missed':>7} {'miss/10k':>8} "
        f"{'cyc w/ miss':>11} {'late':>6} {'bad':>5} {'faults':>6}"
    )
    for r in rows:
        lines.append(
            f"{r['scenario']:>8} {r['motors']:>6} {r['frames_sent_per_cycle']:>8} {r['frames_received_per_cycle']:>8} "
            f"{r['missed_replies']:>7} {r['missed_replies_per_10k']:>8} {r['cycles_with_missed_reply']:>11} "
            f"{r['late_replies']:>6} {r['bad_frames']:>5} {len(r['faults']):>6}"
        )
    lines.append("")
    lines.append("mit_can inside the cycle (µs; read = drain replies + decode, write = encode + send n frames)")
    lines.append(
        f"{'scenario':>8} {'read p50':>8} {'p99':>7} {'p99.9':>7} {'max':>8} {'write p50':>9} {'p99':>7} "
        f"{'p99.9':>7} {'max':>8}"
    )
    for r in rows:
        rd, wr = r["driver_us"]["read"], r["driver_us"]["write"]
        lines.append(
            f"{r['scenario']:>8} {rd['p50']:>8} {rd['p99']:>7} {rd['p999']:>7} {rd['max']:>8} {wr['p50']:>9} "
            f"{wr['p99']:>7} {wr['p999']:>7} {wr['max']:>8}"
        )
    lines.append("")
    lines.append("Emulator thread (in-process, same window)")
    for r in rows:
        emu, gap = r["emulator"], r["emulator_service_gap_us"]
        counters = ", ".join(f"{k} {v}" for k, v in emu.items() if v)
        lines.append(f"  {r['scenario']}: {counters or 'no traffic'}")
        lines.append(
            f"  {'':>{len(r['scenario'])}}  services {r['emulator_services_per_s']:g}/s, gap between services µs "
            f"p50 {gap['p50']} p99 {gap['p99']} p99.9 {gap['p999']} max {gap['max']}"
        )
    lines.append("")
    lines.append("Run")
    for r in rows:
        goals = ", ".join(f"{k} {v}" for k, v in sorted(r["goals"].items()))
        w, la = r["window_cycle_clock_s"], r["load_average_1min"]
        lines.append(
            f"  {r['scenario']}: {' + '.join(r['models'])} @ {r['rate_hz']:g} Hz, {r['seconds']:g} s counted "
            f"(cycle clock {w[0]:g}–{w[1]:g} s), load avg {la[0]:g}→{la[1]:g}, "
            f"mode {r['mode']}; trajectories: {goals or 'none'}"
        )
        for fault in r["faults"]:
            lines.append(f"    fault: {fault}")
        for e in r["events"]:
            when = " (warm-up, before the window)" if e["stamp"] < w[0] else ""
            lines.append(f"    event t={e['stamp']:.3f} s{when}: {e['level']} {e['source']}: {e['message']}")
    rt = rows[0]["realtime"] if rows else {}
    lines.append("  real-time: " + ", ".join(f"{k} {v}" for k, v in rt.items()))
    lines.append("")
    ow, rt_ = floor["one_way_us"], floor["round_trip_us"]
    lines.append(f"Floor: python-can virtual bus alone ({floor['frames']} frames, same thread, µs)")
    lines.append(f"  send A → recv B           p50 {ow['p50']:>6} p99 {ow['p99']:>6} max {ow['max']:>8}")
    lines.append(f"  request → reply (A→B→A)   p50 {rt_['p50']:>6} p99 {rt_['p99']:>6} max {rt_['max']:>8}")
    for r in rows:
        frames = r["frames_sent_per_cycle"] + r["frames_received_per_cycle"]
        driver = r["driver_us"]["read"]["p50"] + r["driver_us"]["write"]["p50"]
        lines.append(
            f"  {r['scenario']}: {frames:g} frames/cycle × {ow['p50']} µs ≈ {frames * ow['p50']:.0f} µs of the "
            f"driver's {driver:.0f} µs (read + write p50) is the virtual bus itself"
        )
    lines.append("")
    note = (
        "Note: the emulated drives run in a thread of this process and compete with the cycle for the GIL (real "
        "drives answer from their own hardware), so these cycle figures are an upper bound on what the CAN path "
        "costs. Missed and late replies here mostly measure whether the emulator thread got the GIL between a "
        "cycle's write and the next read; on a real bus they measure the drives and the wire."
    )
    lines.append(textwrap.fill(note, 116))
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), nargs="+", default=list(SCENARIOS))
    parser.add_argument("--seconds", type=float, default=10.0, help="counted seconds per scenario (after 1 s warm-up)")
    parser.add_argument("--emulator-period", type=float, default=0.0002, help="s between emulator services")
    parser.add_argument(
        "--priority", type=int, default=0, help="SCHED_FIFO priority of the cycle thread (0 = normal, the default)"
    )
    parser.add_argument("--floor-frames", type=int, default=20_000, help="frames for the virtual-bus floor")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args()
    if args.seconds <= 0.0 or args.emulator_period <= 0.0 or args.floor_frames < 1:
        parser.error("--seconds, --emulator-period and --floor-frames must be positive")
    if not 0 <= args.priority <= 99:
        parser.error("--priority must be 0..99")

    floor = virtual_round_trip(args.floor_frames)
    rows = []
    with tempfile.TemporaryDirectory(prefix="hild-can-bench-") as tmp:
        for name in args.scenario:
            rows.append(measure(SCENARIOS[name], args.seconds, args.emulator_period, args.priority, Path(tmp)))
    print(format_report(floor, rows))
    if args.json:
        report = {
            "command": shlex.join(["python", "tools/can_bench.py", *sys.argv[1:]]),
            "host": {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()},
            "emulator_period_s": args.emulator_period,
            "floor": floor,
            "scenarios": rows,
        }
        args.json.write_text(json.dumps(report, indent=2))
        print(f"\n(JSON written to {args.json})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
