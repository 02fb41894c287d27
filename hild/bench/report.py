"""Statistics, targets and the two outputs of a bench run: a readable table and JSON.

Everything here is pure (numbers in, numbers or text out), so tests check it on synthetic data. Percentiles are
numpy's linear interpolation over every counted sample; "per 10k" is per 10 000 cycles. A target compares a hild
figure with a limit derived, where the issue says so, from the floor of the same run; its status is PASS, MISS,
or n/a when the run did not measure what it needs (e.g. ``--only`` left it out).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

CYCLE_P99_LIMIT_US = 250.0
PERIOD_ERROR_FLOOR_FACTOR = 2.0
OVERRUNS_PER_10K_LIMIT = 1.0
ZENOH_FACTOR = 2.0
CPU_LIMIT_PCT = 35.0
POLLING_RISE_LIMIT_PCT = 10.0
TARGET_RATE = 1000.0
CPU_RATE = 500.0
CYCLE_TARGET_SCENARIOS = ("mock6", "twin6", "can6")
CPU_TARGET_SCENARIOS = ("twin6", "can6")
LATENCY_TARGET_SCENARIO = "can6"


def summarize_ns(values_ns: Sequence[int] | np.ndarray) -> dict[str, float]:
    """p50/p99/p99.9/max/mean of nanosecond samples, in µs rounded to 0.1 (zeros for no samples)."""
    values = np.asarray(values_ns, dtype=float)
    if values.size == 0:
        return {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0, "mean": 0.0, "n": 0}
    p50, p99, p999 = (float(v) / 1e3 for v in np.percentile(values, [50, 99, 99.9]))
    return {
        "p50": round(p50, 1),
        "p99": round(p99, 1),
        "p999": round(p999, 1),
        "max": round(float(values.max()) / 1e3, 1),
        "mean": round(float(values.mean()) / 1e3, 1),
        "n": int(values.size),
    }


def per_10k(events: int, cycles: int) -> float:
    return round(events * 10_000 / cycles, 2) if cycles > 0 else 0.0


def rise_pct(loaded: float, baseline: float) -> float:
    """How much ``loaded`` exceeds ``baseline``, in % of the baseline (negative when it is below)."""
    return round(100.0 * (loaded - baseline) / baseline, 1) if baseline > 0 else 0.0


def loop_figures(
    cycles: int, overruns: int, duration_ns: Sequence[int] | np.ndarray, period_error_ns: Sequence[int] | np.ndarray
) -> dict[str, Any]:
    """The cycle figures of one window: duration, period error, overruns per 10k cycles."""
    return {
        "cycles": int(cycles),
        "overruns": int(overruns),
        "overruns_per_10k": per_10k(int(overruns), int(cycles)),
        "duration_us": summarize_ns(duration_ns),
        "period_error_us": summarize_ns(period_error_ns),
    }


def cpu_percent(before: dict[str, int], after: dict[str, int], seconds: float, tick_hz: int) -> dict[str, float]:
    """% of one core per accounted entity between two snapshots of clock ticks (utime + stime)."""
    if seconds <= 0:
        return {}
    return {
        key: round(100.0 * (after[key] - before.get(key, 0)) / tick_hz / seconds, 1) for key in after if key in before
    }


# ---- targets ----------------------------------------------------------------------------------------------------
def _scenario(report: dict[str, Any], base: str, rate: float) -> dict[str, Any] | None:
    for row in report.get("scenarios", []):
        if row.get("base") == base and row.get("rate_hz") == rate and not row.get("error"):
            return dict(row)
    return None


def _floor_row(report: dict[str, Any], rate: float) -> dict[str, Any] | None:
    for row in report.get("floor", {}).get("empty_thread", []):
        if row.get("rate_hz") == rate:
            return dict(row)
    return None


def _target(
    name: str, scenario: str, measured: float | None, limit: float | None, unit: str, basis: str
) -> dict[str, Any]:
    status = "n/a" if measured is None or limit is None else "PASS" if measured <= limit else "MISS"
    return {
        "target": name,
        "scenario": scenario,
        "measured": None if measured is None else round(measured, 1),
        "limit": None if limit is None else round(limit, 1),
        "unit": unit,
        "basis": basis,
        "status": status,
    }


def evaluate_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The issue's targets, each with PASS/MISS/n-a, from a report's floor and hild sections."""
    rate = TARGET_RATE
    tag = f"@{rate:g}"
    targets = []
    floor = _floor_row(report, rate)
    floor_perr = floor["period_error_us"]["p99"] if floor else None
    for base in CYCLE_TARGET_SCENARIOS:
        row = _scenario(report, base, rate)
        d = row["duration_us"]["p99"] if row else None
        p = row["period_error_us"]["p99"] if row else None
        o = row["overruns_per_10k"] if row else None
        targets.append(_target("cycle duration p99", base + tag, d, CYCLE_P99_LIMIT_US, "µs", "fixed 250 µs"))
        limit = PERIOD_ERROR_FLOOR_FACTOR * floor_perr if floor_perr is not None else None
        basis = f"2 × empty thread p99 ({floor_perr} µs)" if floor_perr is not None else "2 × empty thread p99"
        targets.append(_target("period error p99", base + tag, p, limit, "µs", basis))
        targets.append(_target("overruns", base + tag, o, OVERRUNS_PER_10K_LIMIT, "/10k", "fixed 1 per 10k cycles"))
    zenoh = report.get("floor", {}).get("zenoh", {})
    one_way = zenoh.get("one_way_us", {}).get("p99") if "error" not in zenoh else None
    latency = next(
        (r for r in report.get("latency", []) if r.get("base") == LATENCY_TARGET_SCENARIO and r.get("rate_hz") == rate),
        None,
    )
    measured = latency["command_to_frame_us"]["p99"] if latency and latency["command_to_frame_us"]["n"] else None
    period_us = 1e6 / rate
    limit = ZENOH_FACTOR * one_way + period_us if one_way is not None else None
    basis = f"2 × Zenoh one-way p99 ({one_way} µs) + one cycle ({period_us:g} µs)"
    targets.append(
        _target("Zenoh command → CAN frame p99", LATENCY_TARGET_SCENARIO + tag, measured, limit, "µs", basis)
    )
    for base in CPU_TARGET_SCENARIOS:
        row = _scenario(report, base, CPU_RATE)
        cpu = row["cpu"].get("daemon") if row and row.get("cpu") else None
        targets.append(
            _target(
                f"daemon CPU at {CPU_RATE:g} Hz", f"{base}@{CPU_RATE:g}", cpu, CPU_LIMIT_PCT, "% core", "fixed 35 %"
            )
        )
    interference = report.get("interference", {})
    rises = {c.get("name"): c.get("p99_rise_pct") for c in interference.get("conditions", [])}
    rise, decoy = rises.get("polling"), rises.get("decoy polling")
    scenario = str(interference.get("scenario", "twin6@1000"))
    targets.append(
        _target(
            "polling raises cycle p99 by",
            scenario,
            rise,
            POLLING_RISE_LIMIT_PCT,
            "%",
            "fixed 10 % over the interleaved baseline",
        )
    )
    hild_part = round(rise - decoy, 1) if rise is not None and decoy is not None else None
    targets.append(
        _target(
            "… of which serving it (vs decoy)",
            scenario,
            hild_part,
            POLLING_RISE_LIMIT_PCT,
            "%",
            "the same clients polling a decoy daemon load the machine alike; the difference is hild's",
        )
    )
    return targets


def busy(machine: dict[str, Any]) -> bool:
    """True when the 1-minute load average before the run exceeded a quarter of the CPUs (after the run it
    always includes the bench's own load: a daemon, its clients and, for CAN, the emulated drives)."""
    cpus = machine.get("cpu_count") or 1
    return bool(machine.get("load_average", {}).get("before", 0.0) > cpus / 4)


# ---- the table --------------------------------------------------------------------------------------------------
def _p(d: dict[str, Any] | None, *keys: str) -> str:
    if not d:
        return "  ".join("—" for _ in keys)
    return "  ".join(f"{d.get(k, '—')}" for k in keys)


def _row(cells: Sequence[Any], widths: Sequence[int]) -> str:
    return " ".join(f"{c!s:>{w}}" if i else f"{c!s:<{w}}" for i, (c, w) in enumerate(zip(cells, widths, strict=True)))


def format_report(report: dict[str, Any]) -> str:
    """The whole run as fixed-width text (µs unless a column says otherwise)."""
    lines: list[str] = []
    m = report.get("machine", {})
    bench = report.get("bench", {})
    lines.append(
        f"hild bench — {bench.get('started', '?')}, {m.get('cpu_model', '?')} × {m.get('cpu_count', '?')}, "
        f"Linux {m.get('kernel', '?')}{' PREEMPT_RT' if m.get('preempt_rt') else ''}, Python {m.get('python', '?')}"
    )
    load = m.get("load_average", {})
    lines.append(
        f"load average (1 min) {load.get('before', '?')} → {load.get('after', '?')}; "
        f"{bench.get('seconds_total', '?')} s; window {bench.get('settings', {}).get('seconds', '?')} s per scenario"
    )
    if busy(m):
        lines.append(
            "WARNING: the machine was busy (load average above a quarter of its CPUs): these figures measure what "
            "else ran as much as hild; rerun on an idle machine before quoting them"
        )
    rt = m.get("realtime", {})
    if rt:
        lines.append("real-time: " + ", ".join(f"{k} {v}" for k, v in rt.items()))
    lines.append("")

    floor = report.get("floor", {})
    if floor:
        lines += _floor_lines(floor)
    return "\n".join(lines + _hild_lines(report))


def _floor_lines(floor: dict[str, Any]) -> list[str]:
    lines = ["FLOOR (same run)"]
    w = (26, 6, 7, 8, 7, 7, 8, 8, 7, 8, 8)
    lines.append(
        _row(
            [
                "empty sleep+spin thread",
                "rate",
                "cycles",
                "perr p50",
                "p99",
                "p99.9",
                "max",
                "late p50",
                "p99",
                "max",
                "ovr/10k",
            ],
            w,
        )
    )
    for r in floor.get("empty_thread", []):
        pe, la = r["period_error_us"], r["lateness_us"]
        lines.append(
            _row(
                [
                    "",
                    f"{r['rate_hz']:g}",
                    r["cycles"],
                    pe["p50"],
                    pe["p99"],
                    pe["p999"],
                    pe["max"],
                    la["p50"],
                    la["p99"],
                    la["max"],
                    r["overruns_per_10k"],
                ],
                w,
            )
        )
    z = floor.get("zenoh")
    if z:
        if "error" in z:
            lines.append(f"Zenoh ping-pong: {z['error']}")
        else:
            ow, ps = z["one_way_us"], z["put_to_subscriber_us"]
            lines.append(
                f"Zenoh loopback, client → peer: one-way (RTT/2) p50 {ow['p50']} p99 {ow['p99']} max {ow['max']}; "
                f"put → subscriber p50 {ps['p50']} p99 {ps['p99']} max {ps['max']} "
                f"({z['pings']} pings, {z['puts']} puts)"
            )
    c = floor.get("can_virtual")
    if c:
        if "error" in c:
            lines.append(f"python-can virtual: {c['error']}")
        else:
            ow, rt_ = c["one_way_us"], c["round_trip_us"]
            lines.append(
                f"python-can virtual, one thread: send → recv p50 {ow['p50']} p99 {ow['p99']}; "
                f"request → reply p50 {rt_['p50']} p99 {rt_['p99']} max {rt_['max']} ({c['frames']} frames)"
            )
    s = floor.get("mj_step")
    if s:
        if "error" in s:
            lines.append(f"mj_step: {s['error']}")
        else:
            st = s["step_us"]
            lines.append(
                f"mj_step ({s['model']}, {s['timestep_ms']} ms): p50 {st['p50']} p99 {st['p99']} max {st['max']} "
                f"mean {st['mean']} ({s['steps']} steps)"
            )
    if "empty_thread_error" in floor:
        lines.append(f"empty thread: {floor['empty_thread_error']}")
    lines.append("")
    return lines


def _hild_lines(report: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    scenarios = report.get("scenarios", [])
    if scenarios:
        lines.append("CYCLE (the daemon in its own process; trajectory, broadcaster 100 Hz, telemetry to a file)")
        w = (12, 6, 7, 7, 6, 6, 7, 8, 6, 6, 7, 8, 7, 7)
        lines.append(
            _row(
                [
                    "scenario",
                    "rate",
                    "cycles",
                    "dur p50",
                    "p99",
                    "p99.9",
                    "max",
                    "perr p50",
                    "p99",
                    "p99.9",
                    "max",
                    "ovr/10k",
                    "cpu %",
                    "goals",
                ],
                w,
            )
        )
        for r in scenarios:
            if r.get("error"):
                lines.append(f"{r['name']:<12} error: {r['error']}")
                continue
            d, p = r["duration_us"], r["period_error_us"]
            goals = r.get("goals", {})
            ok = goals.get("succeeded", 0)
            lines.append(
                _row(
                    [
                        r["name"],
                        f"{r['rate_hz']:g}",
                        r["cycles"],
                        d["p50"],
                        d["p99"],
                        d["p999"],
                        d["max"],
                        p["p50"],
                        p["p99"],
                        p["p999"],
                        p["max"],
                        r["overruns_per_10k"],
                        r.get("cpu", {}).get("daemon", "—"),
                        f"{ok}/{goals.get('sent', 0)}",
                    ],
                    w,
                )
            )
            for note in r.get("notes", []):
                lines.append(f"{'':<12} note: {note}")
        lines.append(
            "(duration = wake → write done; perr = period error |Δwake − T|; cpu = daemon process, % of one core)"
        )
        lines.append("")

    latency = report.get("latency", [])
    if latency:
        lines.append("LATENCY (cross-process, CLOCK_MONOTONIC; n = matched / sent)")
        w = (12, 6, 9, 7, 8, 9, 14, 7, 8, 9)
        lines.append(_row(["scenario", "rate", "cmd→frame", "p99", "max", "n", "reply→sample", "p99", "max", "n"], w))
        for r in latency:
            a, b = r["command_to_frame_us"], r["reply_to_joint_states_us"]
            lines.append(
                _row(
                    [
                        r["scenario"],
                        f"{r['rate_hz']:g}",
                        a["p50"],
                        a["p99"],
                        a["max"],
                        f"{a['n']}/{r['probes']}",
                        b["p50"],
                        b["p99"],
                        b["max"],
                        f"{b['n']}/{r['samples']}",
                    ],
                    w,
                )
            )
        lines.append(
            "(cmd→frame: client publish → the first CAN frame carrying the value; reply→sample: the reply a "
            "joint_states sample reflects → its arrival at a Zenoh subscriber; at 100 Hz a reply also waits "
            "0–10 ms, 5 ms on average, for the broadcaster's next sample)"
        )
        lines.append("")

    cpu = report.get("cpu", [])
    if cpu:
        lines.append("CPU (% of one core over the window; daemon = process minus the emulator thread)")
        w = (12, 6, 8, 7, 6, 8, 7, 9, 10)
        lines.append(
            _row(["scenario", "rate", "process", "daemon", "cycle", "asyncio", "other", "emulator", "telemetry"], w)
        )
        for r in cpu:
            lines.append(
                _row(
                    [
                        r["scenario"],
                        f"{r['rate_hz']:g}",
                        r.get("process", "—"),
                        r.get("daemon", "—"),
                        r.get("cycle", "—"),
                        r.get("asyncio", "—"),
                        r.get("other", "—"),
                        r.get("emulator", "—"),
                        r.get("telemetry", "—"),
                    ],
                    w,
                )
            )
        lines.append("")

    inter = report.get("interference", {})
    if inter.get("conditions"):
        lines.append(f"INTERFERENCE ({inter['scenario']}, {inter['setup']}; {inter['rounds']} interleaved round(s))")
        w = (19, 7, 7, 6, 6, 7, 8, 8, 9, 24)
        lines.append(
            _row(
                ["condition", "cycles", "dur p50", "p99", "p99.9", "max", "perr p99", "ovr/10k", "p99 rise", "clients"],
                w,
            )
        )
        for r in inter["conditions"]:
            d, p = r["duration_us"], r["period_error_us"]
            lines.append(
                _row(
                    [
                        r["name"],
                        r["cycles"],
                        d["p50"],
                        d["p99"],
                        d["p999"],
                        d["max"],
                        p["p99"],
                        r["overruns_per_10k"],
                        f"{r.get('p99_rise_pct', 0.0)} %",
                        r.get("clients", ""),
                    ],
                    w,
                )
            )
        lines.append("")

    targets = report.get("targets", [])
    if targets:
        lines.append("TARGETS (1 kHz, 6 joints, trajectory, broadcaster, telemetry; limits from this run's floor)")
        w = (32, 12, 9, 9, 6, 6)
        lines.append(_row(["target", "scenario", "measured", "limit", "unit", ""], w))
        for t in targets:
            measured = "—" if t["measured"] is None else t["measured"]
            limit = "—" if t["limit"] is None else t["limit"]
            lines.append(_row([t["target"], t["scenario"], measured, limit, t["unit"], t["status"]], w))
    return lines


def write_json(report: dict[str, Any], path: Path) -> None:
    path.write_text(json.dumps(report, indent=2, ensure_ascii=False) + "\n")
