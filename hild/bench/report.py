"""Statistics, targets and the two outputs of a bench run: a readable table and JSON.

Everything here is pure (numbers in, numbers or text out), so tests check it on synthetic data. Percentiles are
numpy's linear interpolation over every counted sample; "per 10k" is per 10 000 cycles. A target compares a hild
figure with a limit derived, where the issue says so, from the floor of the same run; its status is PASS, MISS,
or n/a when the run did not measure what it needs (e.g. ``--only`` left it out).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hild.crossing.stats import percentiles

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
    """``percentiles`` of nanosecond samples in µs, with their mean and count (zeros for no samples)."""
    values = np.asarray(values_ns, dtype=float)
    mean = round(float(values.mean()) / 1e3, 1) if values.size else 0.0
    return {**percentiles(values, "ns"), "mean": mean, "n": int(values.size)}


def per_10k(events: int, cycles: int) -> float:
    return round(events * 10_000 / cycles, 2) if cycles > 0 else 0.0


def rise_pct(loaded: float, baseline: float) -> float:
    """How much ``loaded`` exceeds ``baseline``, in % of the baseline (negative when it is below)."""
    return round(100.0 * (loaded - baseline) / baseline, 1) if baseline > 0 else 0.0


def target_row(
    name: str,
    measured: float | None,
    limit: float,
    unit: str,
    basis: str,
    *,
    scenario: str,
    group: str,
    error: str | None = None,
) -> dict[str, Any]:
    """One target row of a named section (lower is better): PASS/MISS on the measured figure, MISS "error: …" when
    its measurement failed (also when nothing could be measured: never n/a, never a PASS by default)."""
    if error is not None:
        status, detail, measured = "MISS", f"error: {error}", None
    elif measured is None or not math.isfinite(measured):
        status, detail = "MISS", f"{name}: nothing measured ({basis})"
        measured = None
    elif measured <= limit:
        status, detail = "PASS", ""
    else:
        status, detail = "MISS", f"{name} {measured:g} {unit} > limit {limit:g} {unit} ({basis})"
    return {
        "target": name,
        "scenario": scenario,
        "measured": None if measured is None else round(float(measured), 2),
        "limit": limit,
        "unit": unit,
        "basis": basis,
        "status": status,
        "group": group,
        "detail": detail,
    }


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


def format_loop_table(rows: list[dict[str, object]]) -> str:
    """A fixed-width table of loop figures (``LoopStats.summary()`` or ``loop_figures`` rows, each with ``rate_hz``)."""
    lines = [
        f"{'rate':>6} {'cycles':>7} {'dur p50':>8} {'p99':>7} {'p99.9':>7} {'max':>8} "
        f"{'perr p50':>8} {'p99':>7} {'p99.9':>7} {'max':>8} {'ovr/10k':>8}"
    ]
    for r in rows:
        d, p = r["duration_us"], r["period_error_us"]
        assert isinstance(d, dict) and isinstance(p, dict)
        cycles = int(r["cycles"])  # type: ignore[call-overload]
        per_10k = round(int(r["overruns"]) * 10_000 / max(1, cycles), 1)  # type: ignore[call-overload]
        lines.append(
            f"{r['rate_hz']:>6g} {cycles:>7} {d['p50']:>8} {d['p99']:>7} {d['p999']:>7} {d['max']:>8} "
            f"{p['p50']:>8} {p['p99']:>7} {p['p999']:>7} {p['max']:>8} {per_10k:>8}"
        )
    lines.append("(µs; duration = wake → write done; period error = |Δwake − T|)")
    return "\n".join(lines)


def cpu_percent(before: dict[str, int], after: dict[str, int], seconds: float, tick_hz: int) -> dict[str, float]:
    """% of one core per accounted entity between two snapshots of clock ticks (utime + stime)."""
    if seconds <= 0:
        return {}
    return {
        key: round(100.0 * (after[key] - before.get(key, 0)) / tick_hz / seconds, 1) for key in after if key in before
    }


def cpu_groups(use: dict[str, float], side: Sequence[str], *, cycle_process: bool) -> dict[str, float]:
    """Derived CPU figures from the measured ones (% of one core).

    Measured: ``process`` (the daemon's process), its thread groups (``asyncio``; ``cycle`` when the cycle is a
    thread of it; the bench's ``side`` groups: emulated drives, the CAN bridge), ``cycle`` (the cycle process when
    there is one) and ``telemetry`` (the recorder process). Derived: ``daemon`` = the process minus the side
    groups; ``other`` = the daemon's threads that are neither asyncio nor the cycle (Zenoh's, the goal planner);
    ``hild`` = the daemon plus the cycle process (with a cycle thread the daemon already holds it): the figure the
    one-process bench called daemon; ``whole`` = hild plus the telemetry recorder: every process hild runs.
    Clock ticks are 1/SC_CLK_TCK s per thread, so a difference can round a little below zero: clipped at zero."""
    out = dict(use)
    if "process" not in use:
        return out
    daemon = use["process"] - sum(use.get(name, 0.0) for name in side)
    out["daemon"] = round(max(0.0, daemon), 1)
    in_process_cycle = 0.0 if cycle_process else use.get("cycle", 0.0)
    out["other"] = round(max(0.0, out["daemon"] - in_process_cycle - use.get("asyncio", 0.0)), 1)
    out["hild"] = round(out["daemon"] + (use.get("cycle", 0.0) if cycle_process else 0.0), 1)
    out["whole"] = round(out["hild"] + use.get("telemetry", 0.0), 1)
    return out


# ---- targets ----------------------------------------------------------------------------------------------------
def _scenario(report: dict[str, Any], name: str) -> dict[str, Any] | None:
    for row in report.get("scenarios", []):
        if row.get("name") == name and not row.get("error"):
            return dict(row)
    return None


def _floor_row(report: dict[str, Any], rate: float) -> dict[str, Any] | None:
    for row in report.get("floor", {}).get("empty_thread", []):
        if row.get("rate_hz") == rate:
            return dict(row)
    return None


def judge(measured: float | None, limit: float | None) -> str:
    """PASS when ``measured ≤ limit``, MISS when above, n/a when either is unknown."""
    if measured is None or limit is None:
        return "n/a"
    return "PASS" if measured <= limit else "MISS"


def _fmt(value: float | None) -> str:
    return "—" if value is None else f"{value:g}"


def _target(
    name: str,
    scenario: str,
    measured: float | None,
    limit: float | None,
    unit: str,
    basis: str,
    group: str = "earlier",
) -> dict[str, Any]:
    """One row: the status, and for a MISS or n/a a sentence naming the numbers it was decided on."""
    status = judge(measured, limit)
    measured_r = None if measured is None else round(measured, 1)
    limit_r = None if limit is None else round(limit, 1)
    if status == "MISS":
        detail = f"{scenario}: {name} {_fmt(measured_r)} {unit} > limit {_fmt(limit_r)} {unit} ({basis})"
    elif status == "n/a":
        missing = "the measurement" if measured is None else "the limit's basis"
        detail = f"{scenario}: {name}: not measured in this run ({missing}; {basis})"
    else:
        detail = ""
    return {
        "target": name,
        "scenario": scenario,
        "measured": measured_r,
        "limit": limit_r,
        "unit": unit,
        "basis": basis,
        "status": status,
        "group": group,
        "detail": detail,
    }


# The [rt-split] targets: 1 kHz, 6 joints, trajectory + broadcaster + telemetry, on the twin and on can6; every
# limit that names the floor takes it from the same run's empty thread.
RT = "rt-split"
RT_SCENARIOS = ("twin6", "can6")
RT_PERIOD_ERROR_FACTOR = 3.0
RT_SMALL_FLOOR_US = 10.0  # below this floor p99, the limit is floor + a margin instead of a multiple
RT_SMALL_FLOOR_MARGIN_US = 20.0
RT_OVERRUN_MARGIN_PER_10K = 1.0
RT_RISE_LIMIT_PCT = 10.0
RT_GOAL_ACCEPT_LIMIT_MS = 50.0
RT_LATENCY_MARGIN_US = 50.0
RT_CPU_LIMIT_PCT = 35.0
RT_CPU_SCENARIO_SUFFIX = "-nospin"


def period_error_limit(floor_p99_us: float) -> float:
    """≤ 3 × the floor's p99, or ≤ floor + 20 µs when the floor is below 10 µs."""
    if floor_p99_us < RT_SMALL_FLOOR_US:
        return floor_p99_us + RT_SMALL_FLOOR_MARGIN_US
    return RT_PERIOD_ERROR_FACTOR * floor_p99_us


def period_error_basis(floor_p99_us: float) -> str:
    if floor_p99_us < RT_SMALL_FLOOR_US:
        return f"empty thread p99 {floor_p99_us:g} µs + {RT_SMALL_FLOOR_MARGIN_US:g} µs (floor below 10 µs)"
    return f"{RT_PERIOD_ERROR_FACTOR:g} × empty thread p99 {floor_p99_us:g} µs"


def overrun_limit(floor_per_10k: float) -> float:
    """≤ the floor's own overruns + 1 per 10 000 cycles."""
    return floor_per_10k + RT_OVERRUN_MARGIN_PER_10K


def command_to_frame_limit(one_way_p99_us: float, rate_hz: float, cycle_p99_us: float) -> float:
    """≤ one-way Zenoh p99 + one period + the cycle's p99 + 50 µs."""
    return one_way_p99_us + 1e6 / rate_hz + cycle_p99_us + RT_LATENCY_MARGIN_US


# The command path, once per medium: can6@1000 (the cycle process, the drives across the loopback bridge, or the
# virtual bus with --one-process) and can6@1000-virtual (the cycle a thread of the daemon, the in-process virtual
# bus). Each against its own scenario's cycle p99; an unambiguous probe that found no frame is a MISS.
COMMAND_PATH_SUFFIXES = ("", "-virtual")


def probe_counts(latency: dict[str, Any]) -> tuple[int, int, int, int]:
    """(sent, matched, ambiguous, unmatched) of a scenario's command → frame probes."""
    sent = int(latency.get("probes", 0))
    matched = int(latency["command_to_frame_us"].get("n", 0))
    ambiguous = int(latency.get("ambiguous_probes", 0))
    return sent, matched, ambiguous, max(0, sent - matched - ambiguous)


def command_to_frame_target(report: dict[str, Any], where: str, one_way: float | None, rate: float) -> dict[str, Any]:
    """The command → frame p99 target of scenario ``where``, with its probes counted beside it."""
    latency = next((r for r in report.get("latency", []) if r.get("scenario") == where), None)
    measured = latency["command_to_frame_us"]["p99"] if latency and latency["command_to_frame_us"]["n"] else None
    can = _scenario(report, where)
    cycle_p99 = can["duration_us"]["p99"] if can else None
    limit = command_to_frame_limit(one_way, rate, cycle_p99) if one_way is not None and cycle_p99 is not None else None
    basis = (
        f"Zenoh one-way p99 {_fmt(one_way)} + period {1e6 / rate:g} + cycle p99 {_fmt(cycle_p99)} "
        f"+ {RT_LATENCY_MARGIN_US:g} µs"
    )
    if latency is None:
        return _target("Zenoh command → CAN frame p99", where, None, limit, "µs", basis, RT)
    sent, matched, ambiguous, unmatched = probe_counts(latency)
    bus = str(latency.get("can_bus", "?")) + (f", {latency['can_bridge']}" if latency.get("can_bridge") else "")
    basis += f"; {bus}; probes {sent}: matched {matched}, ambiguous {ambiguous}, unmatched {unmatched}"
    row = _target("Zenoh command → CAN frame p99", where, measured, limit, "µs", basis, RT)
    if unmatched:  # a command that never reached the wire is the worst latency of all, even with no other matched
        row["status"] = "MISS"
        row["detail"] = f"{where}: {unmatched} of {sent} probes never matched a frame ({basis})"
    return row


def _condition(interference: dict[str, Any], name: str) -> dict[str, Any] | None:
    return next((c for c in interference.get("conditions", []) if c.get("name") == name), None)


def _servo_stream_rise(interference: dict[str, Any], where: str, baseline: dict[str, Any] | None) -> dict[str, Any]:
    """The servo stream alone at 1 kHz (a new target every cycle, no pollers): what following it costs the cycle."""
    alone, decoy = _condition(interference, "servo"), _condition(interference, "decoy servo")
    rise = alone.get("p99_rise_pct") if alone and baseline else None
    basis = "interleaved baseline windows"
    if alone and baseline:
        basis = f"cycle p99 {alone['duration_us']['p99']:g} µs vs baseline {baseline['duration_us']['p99']:g} µs"
        if decoy and decoy.get("p99_rise_pct") is not None:
            basis += f"; the same stream to a decoy {decoy['p99_rise_pct']:+g} %"
    return _target("servo stream 1 kHz: p99 rise", where, rise, RT_RISE_LIMIT_PCT, "%", basis, RT)


def _target_floor(report: dict[str, Any]) -> tuple[float, str, dict[str, Any] | None, float | None]:
    """The targets' rate, its scenario suffix, the floor's row at that rate and its period error p99."""
    floor = _floor_row(report, TARGET_RATE)
    return TARGET_RATE, f"@{TARGET_RATE:g}", floor, floor["period_error_us"]["p99"] if floor else None


def rt_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The [rt-split] targets, each PASS/MISS/n-a with the numbers it was decided on."""
    rate, tag, floor, floor_perr = _target_floor(report)
    out = []
    floor_ovr = floor["overruns_per_10k"] if floor else None
    for base in RT_SCENARIOS:
        row = _scenario(report, base + tag)
        perr = row["period_error_us"]["p99"] if row else None
        limit = period_error_limit(floor_perr) if floor_perr is not None else None
        basis = period_error_basis(floor_perr) if floor_perr is not None else "from the empty thread at 1 kHz"
        out.append(_target("period error p99", base + tag, perr, limit, "µs", basis, RT))
        ovr = row["overruns_per_10k"] if row else None
        limit = overrun_limit(floor_ovr) if floor_ovr is not None else None
        basis = f"empty thread {_fmt(floor_ovr)} /10k + {RT_OVERRUN_MARGIN_PER_10K:g} /10k"
        out.append(_target("overruns", base + tag, ovr, limit, "/10k", basis, RT))

    interference = report.get("interference", {})
    where = str(interference.get("scenario", "twin6@1000"))
    baseline = _condition(interference, "baseline")
    both = _condition(interference, "polling+servo")
    rise = both.get("p99_rise_pct") if both and baseline else None
    basis = (
        f"cycle p99 {both['duration_us']['p99']:g} µs vs baseline {baseline['duration_us']['p99']:g} µs"
        if both and baseline
        else "interleaved baseline windows"
    )
    out.append(_target("polling 200/s + servo 1 kHz: p99 rise", where, rise, RT_RISE_LIMIT_PCT, "%", basis, RT))
    out.append(_servo_stream_rise(interference, where, baseline))

    flood = _condition(interference, "flood")
    rise = flood.get("p99_rise_pct") if flood and baseline else None
    basis = (
        f"cycle p99 {flood['duration_us']['p99']:g} µs vs baseline {baseline['duration_us']['p99']:g} µs; "
        f"{flood.get('clients', '')}"
        if flood and baseline
        else "1 MiB queries, as fast as they are answered"
    )
    out.append(_target("1 MiB flood: p99 rise", where, rise, RT_RISE_LIMIT_PCT, "%", basis, RT))
    ovr = flood["overruns_per_10k"] if flood and baseline else None
    limit = overrun_limit(baseline["overruns_per_10k"]) if flood and baseline else None
    basis = (
        f"{flood['overruns']} in {flood['cycles']} cycles; baseline {baseline['overruns_per_10k']:g} /10k + "
        f"{RT_OVERRUN_MARGIN_PER_10K:g} /10k"
        if flood and baseline
        else "baseline + 1 per 10k"
    )
    out.append(_target("1 MiB flood: overruns (no burst)", where, ovr, limit, "/10k", basis, RT))
    accept = flood.get("goal_accept_ms") if flood else None
    slowest = accept["max"] if accept and accept.get("n") else None
    basis = (
        f"slowest of {accept['n']} trajectory goals sent during the flood (p50 {accept['p50']:g} ms)"
        if slowest is not None
        else "no trajectory goal was sent during the flood windows"
    )
    out.append(_target("1 MiB flood: operator goal accepted", where, slowest, RT_GOAL_ACCEPT_LIMIT_MS, "ms", basis, RT))

    zenoh = report.get("floor", {}).get("zenoh", {})
    one_way = zenoh.get("one_way_us", {}).get("p99") if "error" not in zenoh else None
    for suffix in COMMAND_PATH_SUFFIXES:
        out.append(command_to_frame_target(report, LATENCY_TARGET_SCENARIO + tag + suffix, one_way, rate))

    for base in CPU_TARGET_SCENARIOS:
        name = f"{base}@{CPU_RATE:g}{RT_CPU_SCENARIO_SUFFIX}"
        row = _scenario(report, name)
        cpu = row.get("cpu", {}) if row else {}
        whole = cpu.get("whole")
        basis = (
            f"daemon {_fmt(cpu.get('daemon'))} + cycle {_fmt(cpu.get('cycle'))}"
            + (" (process)" if row and row.get("cycle_process") else " (thread, in daemon)")
            + f" + telemetry {_fmt(cpu.get('telemetry'))} %, spin_us 0"
            if whole is not None
            else "every process hild runs, spin_us 0"
        )
        out.append(_target(f"whole daemon CPU at {CPU_RATE:g} Hz", name, whole, RT_CPU_LIMIT_PCT, "% core", basis, RT))
    return out


def evaluate_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every target, each with PASS/MISS/n-a: the [rt-split] ones first, then the earlier ones (docs/performance.md,
    "Targets"), which the earlier figures are quoted against."""
    return rt_targets(report) + earlier_targets(report)


def earlier_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The targets before [rt-split] (docs/performance.md, "Targets"), from a report's floor and hild sections."""
    rate, tag, _, floor_perr = _target_floor(report)
    targets = []
    for base in CYCLE_TARGET_SCENARIOS:
        row = _scenario(report, base + tag)
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
        (r for r in report.get("latency", []) if r.get("scenario") == LATENCY_TARGET_SCENARIO + tag),
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
        row = _scenario(report, f"{base}@{CPU_RATE:g}")
        cpu = row.get("cpu", {}) if row else {}
        measured = cpu.get("hild", cpu.get("daemon"))  # hild: the daemon with its cycle, wherever that runs
        targets.append(
            _target(
                f"daemon CPU at {CPU_RATE:g} Hz",
                f"{base}@{CPU_RATE:g}",
                measured,
                CPU_LIMIT_PCT,
                "% core",
                "fixed 35 %; daemon and cycle, telemetry apart",
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
    settings = bench.get("settings", {})
    if "cycle_process" in settings:
        where = (
            "the cycle in a process of its own (realtime.cycle_process)"
            if settings["cycle_process"]
            else "one process: the cycle a thread of the daemon (--one-process)"
        )
        if settings.get("cycle_cpu") is not None:
            where += f"; the cycle on CPU {settings['cycle_cpu']}, everything else off it (--cycle-cpu)"
        lines.append(f"mode: {where}")
    rt = m.get("realtime", {})
    if rt:
        lines.append("real-time: " + ", ".join(f"{k} {v}" for k, v in rt.items()))
    lines.append("")

    floor = report.get("floor", {})
    if floor:
        lines += _floor_lines(floor)
    return "\n".join(lines + _hild_lines(report))


def _zenoh_line(z: dict[str, Any]) -> str:
    ow, ps = z["one_way_us"], z["put_to_subscriber_us"]
    return (
        f"Zenoh loopback, client → peer: one-way (RTT/2) p50 {ow['p50']} p99 {ow['p99']} max {ow['max']}; "
        f"put → subscriber p50 {ps['p50']} p99 {ps['p99']} max {ps['max']} ({z['pings']} pings, {z['puts']} puts)"
    )


def _can_virtual_line(c: dict[str, Any]) -> str:
    ow, rt = c["one_way_us"], c["round_trip_us"]
    return (
        f"python-can virtual, one thread: send → recv p50 {ow['p50']} p99 {ow['p99']}; "
        f"request → reply p50 {rt['p50']} p99 {rt['p99']} max {rt['max']} ({c['frames']} frames)"
    )


def _mj_step_line(s: dict[str, Any]) -> str:
    st = s["step_us"]
    return (
        f"mj_step ({s['model']}, {s['timestep_ms']} ms): p50 {st['p50']} p99 {st['p99']} max {st['max']} "
        f"mean {st['mean']} ({s['steps']} steps)"
    )


PROBE_LINES = (  # the floor section's probe, its label when it failed, its line when it ran
    ("zenoh", "Zenoh ping-pong", _zenoh_line),
    ("can_virtual", "python-can virtual", _can_virtual_line),
    ("mj_step", "mj_step", _mj_step_line),
)


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
    for key, label, line in PROBE_LINES:
        probe = floor.get(key)
        if probe:
            lines.append(f"{label}: {probe['error']}" if "error" in probe else line(probe))
    if "empty_thread_error" in floor:
        lines.append(f"empty thread: {floor['empty_thread_error']}")
    lines.append("")
    return lines


def _hild_lines(report: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    scenarios = report.get("scenarios", [])
    if scenarios:
        lines.append("CYCLE (the real daemon per scenario; trajectory, broadcaster 100 Hz, telemetry to a file)")
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
                        r.get("cpu", {}).get("hild", r.get("cpu", {}).get("daemon", "—")),
                        f"{ok}/{goals.get('sent', 0)}",
                    ],
                    w,
                )
            )
            for note in r.get("notes", []):
                lines.append(f"{'':<12} note: {note}")
        lines.append(
            "(duration = wake → write done; perr = period error |Δwake − T|; cpu = hild: daemon and cycle, "
            "% of one core)"
        )
        lines.append("")

    buses = [r for r in scenarios if r.get("bus")]
    if buses:
        lines.append("CAN BUS (% of the buses' bitrate; check = hild check's worst case from the drivers' layouts)")
        w = (12, 6, 9, 10, 10, 12)
        lines.append(_row(["scenario", "rate", "bitrate", "check %", "crossed %", "frames/s"], w))
        for r in buses:
            b = r["bus"]
            cells = [r["name"], f"{r['rate_hz']:g}", f"{b['buses_bitrate'] / 1e6:g} M", b["check_load_pct"]]
            lines.append(_row([*cells, b["measured_load_pct"], b["frames_per_s"]], w))
        lines.append(
            "(crossed = every frame on the emulated buses in the window, both ways, in the same worst-case bits: "
            "RPDOs/commands, SYNC, TPDOs/replies, heartbeats)"
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
        lines.append(
            "CPU (% of one core over the window; daemon = its process minus the bench's threads (emulator, bridge); "
            "cycle = the cycle process, or the cycle thread inside daemon; hild = daemon + cycle process; "
            "whole = hild + telemetry recorder)"
        )
        w = (17, 6, 8, 7, 6, 8, 7, 9, 7, 10, 6, 6)
        keys = ("process", "daemon", "cycle", "asyncio", "other", "emulator", "bridge", "telemetry", "hild", "whole")
        lines.append(_row(["scenario", "rate", *keys], w))
        for r in cpu:
            lines.append(_row([r["scenario"], f"{r['rate_hz']:g}", *(r.get(k, "—") for k in keys)], w))
        lines.append("")

    inter = report.get("interference", {})
    if inter.get("conditions"):
        lines.append(f"INTERFERENCE ({inter['scenario']}, {inter['setup']}; {inter['rounds']} interleaved round(s))")
        w = (19, 7, 7, 6, 6, 7, 8, 8, 9, 10, 24)
        lines.append(
            _row(
                [
                    "condition",
                    "cycles",
                    "dur p50",
                    "p99",
                    "p99.9",
                    "max",
                    "perr p99",
                    "ovr/10k",
                    "p99 rise",
                    "goal ms",
                    "clients",
                ],
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
                        _accept(r.get("goal_accept_ms")),
                        r.get("clients", ""),
                    ],
                    w,
                )
            )
        lines.append("(goal ms: slowest acceptance of the trajectory goals sent during the condition's windows)")
        lines.append("")

    targets = report.get("targets", [])
    if targets:
        groups = (
            (RT, "TARGETS [rt-split] (1 kHz, 6 joints, trajectory, broadcaster, telemetry; floor from this run)"),
            ("earlier", "EARLIER TARGETS (docs/performance.md, Targets)"),
            ("contact", "TARGETS [contact] (emulated Damiao arm6, 1 kHz, mass ×1.1, friction ×1.3; lockstep)"),
            ("record", "TARGETS [record] (twin6@1000, the cycle in its own process; recording off vs an episode open)"),
            (
                "teleop",
                "TARGETS [teleop] (follow: two arm6 twins on loopback, the relay between them; chunks: the arm6 twin "
                "in lockstep, a synthetic policy; docs/performance.md)",
            ),
        )
        for group, heading in groups:
            mine = [t for t in targets if t.get("group", "earlier") == group]
            if not mine:
                continue
            w = (max(36, *(len(t["target"]) for t in mine)), 17, 9, 9, 6, 6)  # the group's longest name fits
            lines.append(heading)
            lines.append(_row(["target", "scenario", "measured", "limit", "unit", ""], w))
            for t in mine:
                measured = "—" if t["measured"] is None else t["measured"]
                limit = "—" if t["limit"] is None else t["limit"]
                lines.append(_row([t["target"], t["scenario"], measured, limit, t["unit"], t["status"]], w))
                if t["status"] == "MISS" or (t["status"] == "PASS" and group == RT):
                    lines.append(f"{'':<4}{'MISS: ' + t['detail'] if t['status'] == 'MISS' else t['basis']}")
            lines.append("")
    return lines


def _accept(figures: dict[str, Any] | None) -> str:
    if not figures or not figures.get("n"):
        return "—"
    return f"{figures['max']:g} ({figures['n']})"


def write_json(report: dict[str, Any], path: Path) -> None:
    path.write_text(json.dumps(report, indent=2, ensure_ascii=False) + "\n")
