#!/usr/bin/env python3
"""Where the contact check's microseconds go: each stage of the observer and the force at the tool, timed inside
real cycles (caches as the cycle leaves them) and in a tight loop (hot), on the contact bench's rig (emulated Damiao
arm6, configs/arm6_can.yaml with ``safety.contact`` on as shipped, seeded random moves).

    python tools/contact_stages.py [--cycles 5000] [--runs 3]
    python tools/contact_stages.py --durations [--cycles 20000]   # off / on / on alone: wall and CPU time


In-cycle: each stage's method is wrapped in a timer (a wrapper adds ~0.1 µs to each figure); the table gives the
median and p99 per call, ns, over ``--cycles`` cycles after a warm-up. Tight loop: the same calls repeated on one
reading, best of ``--runs`` — the floor with hot caches. Compare two checkouts on the same machine
(``PYTHONPATH=<checkout>``); what it measures is wall time, so a loaded machine moves the figures.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hild.bench.contact import goal_done, sample_pose
from hild.bench.contact_adapters import ContactAdapters
from hild.bench.contact_rig import JTC, ContactRig, RigSpec


class Timed:
    """A method replaced by a wrapper that records the wall time of each call (ns)."""

    def __init__(self, owner: Any, name: str) -> None:
        self.owner, self.name, self.samples = owner, name, []
        inner: Callable[..., Any] = getattr(owner, name)
        samples, clock = self.samples, time.perf_counter_ns

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = clock()
            out = inner(*args, **kwargs)
            samples.append(clock() - start)
            return out

        setattr(owner, name, timed)


def stages(rig: ContactRig) -> dict[str, Timed]:
    engine = rig.engine
    assert engine is not None and engine.contact is not None
    contact = engine.contact
    picks: dict[str, tuple[Any, str]] = {
        "observe (whole, before the write)": (engine, "_observe_contact"),
        "  observer.update": (contact.observer, "update"),
        "  motor torque": (contact, "_motor_torque"),
        "  joint thresholds": (contact, "_classify"),
        "  quiet screen": (contact, "_quiet"),
        "  force at the tool (bound or judge)": (contact, "_classify_force"),
        "    its judgement (either side)": (contact.tool_force, "judge"),
        "gravity feed-forward (shared)": (engine.supervisor, "gravity"),
        "after_write (G for the next cycle)": (contact, "after_write"),
    }
    out = {}
    for label, (owner, name) in picks.items():
        if owner is not None and hasattr(owner, name):
            out[label] = Timed(owner, name)
    return out


def in_cycle(cycles: int, seed: int) -> None:
    rig = ContactRig(RigSpec(safety=ContactAdapters().observer_safety(True)))
    try:
        rng = np.random.default_rng(seed)
        rig.activate(JTC)
        goal: str | None = None

        def run(count: int, durations: list[int] | None) -> None:
            nonlocal goal
            for _ in range(count):
                if goal is None or goal_done(rig, goal):
                    goal = rig.move(sample_pose(rng))
                duration = rig.timed_cycle()[0]
                if durations is not None:
                    durations.append(duration)

        run(500, None)
        timers = stages(rig)
        durations: list[int] = []
        run(cycles, durations)
    finally:
        rig.close()
    print(f"in-cycle, {cycles} cycles (ns per call: median / p99)")
    label = "cycle duration (start → writes done)"
    print(f"  {label:40s} {np.median(durations):8.0f} / {np.percentile(durations, 99):8.0f}")
    for label, timer in timers.items():
        if timer.samples:
            s = np.array(timer.samples)
            print(f"  {label:40s} {np.median(s):8.0f} / {np.percentile(s, 99):8.0f}   ({len(s)} calls)")


def tight(runs: int, calls: int) -> None:
    rig = ContactRig(RigSpec(safety=ContactAdapters().observer_safety(True)))
    try:
        rig.activate(JTC)
        rig.move(sample_pose(np.random.default_rng(3)))
        rig.cycle(300)
        engine = rig.engine
        assert engine is not None and engine.contact is not None
        contact, state, final = engine.contact, engine.state, engine.final
        obs, tf = contact.observer, contact.tool_force
        q, qd, dt = state.position.copy(), state.velocity.copy(), engine.period
        tau = state.effort.copy()

        def best(fn: Callable[[], object]) -> float:
            times = []
            for _ in range(runs):
                start = time.perf_counter_ns()
                for _ in range(calls):
                    fn()
                times.append((time.perf_counter_ns() - start) / calls)
            return min(times)

        figures = {
            "observer.update": best(lambda: obs.update(q, qd, tau, dt)),
            "contact.observe (trusted, whole)": best(lambda: contact.observe(state, final, True, dt)),
        }
        if tf is not None:
            margin = np.zeros(len(q))
            r = obs.residual.copy()
            figures["force judge"] = best(lambda: tf.judge(q, r, margin, dt))
            figures["force refresh (after the write)"] = best(lambda: tf.refresh(q, margin))
        g = np.zeros(len(q))
        if engine.supervisor.gravity is not None:
            figures["gravity feed-forward (shared)"] = best(lambda: engine.supervisor.gravity(state.position, g))
    finally:
        rig.close()
    print(f"tight loop, best of {runs} × {calls} calls (ns per call)")
    for label, ns in figures.items():
        print(f"  {label:40s} {ns:8.0f}")


def cpu_durations(cycles: int, seed: int) -> None:
    """The cycle's duration (start → writes done) in wall time and in the cycle thread's CPU time, observer off, on
    (as shipped) and on alone, three rigs interleaved in chunks of 200 as ``measure_cost`` runs them. CPU time leaves
    out the time other processes held the core, so on a loaded machine it shows the work the observer adds."""
    adapters = ContactAdapters()
    on = adapters.observer_safety(True)
    configs = {"off": adapters.observer_safety(False), "on": on, "only": {"contact": {**on["contact"], "force": None}}}
    rigs = {mode: ContactRig(RigSpec(safety=safety)) for mode, safety in configs.items()}
    wall: dict[str, list[int]] = {mode: [] for mode in rigs}
    cpu: dict[str, list[int]] = {mode: [] for mode in rigs}
    try:
        marks: dict[str, int] = {}
        for mode, rig in rigs.items():
            engine = rig.engine
            assert engine is not None
            write = engine._write

            def timed_write(t: float, dt: float, write: Callable[..., None] = write, mode: str = mode) -> None:
                write(t, dt)
                marks[mode] = time.thread_time_ns()

            engine._write = timed_write  # type: ignore[method-assign]
            rig.activate(JTC)
        rngs = {mode: np.random.default_rng(seed) for mode in rigs}
        goals: dict[str, str | None] = dict.fromkeys(rigs)
        while len(wall["off"]) < cycles:
            for mode, rig in rigs.items():
                for _ in range(200):
                    goal = goals[mode]
                    if goal is None or goal_done(rig, goal):
                        goals[mode] = rig.move(sample_pose(rngs[mode]))
                    start = time.thread_time_ns()
                    wall[mode].append(rig.timed_cycle()[0])
                    cpu[mode].append(marks[mode] - start)
    finally:
        for rig in rigs.values():
            rig.close()
    print(f"cycle duration, {cycles} cycles per rig (µs: p50 / p99; rise of p99 over off)")
    base = {k: float(np.percentile(v, 99)) for k, v in (("wall", wall["off"]), ("cpu", cpu["off"]))}
    for mode in rigs:
        row = []
        for kind, values in (("wall", wall[mode]), ("cpu", cpu[mode])):
            p50, p99 = np.percentile(values, 50) / 1e3, np.percentile(values, 99) / 1e3
            row.append(f"{kind} {p50:6.1f} / {p99:6.1f} ({100 * (p99 * 1e3 / base[kind] - 1):+5.1f} %)")
        print(f"  {mode:5s} " + "   ".join(row))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=5000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=6)
    parser.add_argument("--durations", action="store_true", help="only the wall/CPU durations, off vs on")
    args = parser.parse_args()
    if args.durations:
        cpu_durations(args.cycles, args.seed)
        return
    in_cycle(args.cycles, args.seed)
    tight(args.runs, 5000)


if __name__ == "__main__":
    main()
