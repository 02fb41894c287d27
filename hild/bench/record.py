"""``hild bench --only record``: what recording costs the cycle ([record]: p99 rise ≤ 5 % with it on).

The twin6@1000 scenario (``hild.bench.scenarios``: the arm6 twin at 1 kHz, the cycle in a process of its own, a
joint_trajectory goal on every joint, the joint_state_broadcaster at 100 Hz, telemetry to a file), run as fresh
daemons in two conditions, alternated round by round so a drift of the machine hits both alike:

* ``off`` — ``recording.enabled: false``: no cycle log on the cycle, no recorder process;
* ``on``  — recording as shipped, with an episode open through the whole window (``hild ctl record start``): the
  cycle writes its row into the cycle log, the recorder process writes every cycle to MCAP (chunks every
  ``recording.chunk_period``, fsync'ed).

Figures are pooled over the rounds per condition. The rise compares the cycle duration's p99 (wake → writes done,
as the loop statistics count it); the period error's p99 and the overruns are reported beside it, since the
cycle log's row is written after the writes (it counts toward overruns only) and the recorder process competes for
the machine's cores. Each ``on`` window's episode is read back: its cycles against the cycles the window saw, and
rows the recorder lost.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from hild.bench.report import loop_figures, target_row
from hild.bench.scenarios import JTC, Scenario, Settings, open_session

SCENARIO = Scenario("twin6", "twin", 6, 1000.0)
GROUP = "record"
RISE_PCT = 5.0
ROUNDS, QUICK_ROUNDS = 3, 1


def run_record(settings: Settings, workdir: Path | None = None) -> dict[str, Any]:
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="hild-bench-record-") as tmp:
            return run_record(settings, Path(tmp))
    rounds = QUICK_ROUNDS if settings.quick else ROUNDS
    windows: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
    episodes: list[dict[str, Any]] = []
    for k in range(rounds):
        for condition in ("off", "on") if k % 2 == 0 else ("on", "off"):
            window, episode = _measure(condition, workdir / f"{condition}{k}", settings)
            windows[condition].append(window)
            if episode is not None:
                episodes.append(episode)
    report: dict[str, Any] = {"scenario": SCENARIO.name, "rounds": rounds, "seconds": settings.seconds}
    for condition, parts in windows.items():
        report[condition] = _pooled(parts)
    off, on = report["off"]["duration_us"]["p99"], report["on"]["duration_us"]["p99"]
    report["p99_rise_pct"] = round((on / off - 1.0) * 100.0, 1) if off else None
    perr_off, perr_on = report["off"]["period_error_us"]["p99"], report["on"]["period_error_us"]["p99"]
    report["period_error_p99_rise_pct"] = round((perr_on / perr_off - 1.0) * 100.0, 1) if perr_off else None
    report["episodes"] = episodes
    report["targets"] = record_targets(report)
    return report


def _measure(condition: str, workdir: Path, settings: Settings) -> tuple[dict[str, Any], dict[str, Any] | None]:
    workdir.mkdir(parents=True, exist_ok=True)
    recording = {"enabled": condition == "on", "dir": str(workdir / "recordings")}
    with open_session(SCENARIO, workdir, settings, overrides={"recording": recording}) as s:
        s.client.switch(activate=[JTC])
        keeper = s.keeper(JTC, s.joints, s.home)
        started = s.client.record_start(task="bench") if condition == "on" else None
        time.sleep(settings.warmup)
        window = s.window(settings.seconds)
        episode = None
        if started is not None:
            stopped = s.client.record_stop()
            episode = {
                "id": stopped["id"],
                "cycles": stopped["cycles"],
                "dropped": stopped["dropped"],
                "duration_s": stopped["duration"],
                "window_cycles": window["cycles"],
                "files": stopped["files"],
            }
        keeper.stop()
    return window, episode


def _pooled(windows: list[dict[str, Any]]) -> dict[str, Any]:
    figures = loop_figures(
        sum(w["cycles"] for w in windows),
        sum(w["overruns"] for w in windows),
        np.concatenate([np.asarray(w["duration_ns"], dtype=np.int64) for w in windows]),
        np.concatenate([np.asarray(w["period_error_ns"], dtype=np.int64) for w in windows]),
    )
    figures["windows"] = len(windows)
    figures["lost"] = sum(w["lost"] for w in windows)
    return figures


def record_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    off, on = report["off"], report["on"]
    episodes = report.get("episodes", [])
    return [
        target_row(
            "cycle p99 rise with recording on",
            report.get("p99_rise_pct"),
            RISE_PCT,
            "%",
            f"cycle duration p99 {off['duration_us']['p99']} → {on['duration_us']['p99']} µs (wake → writes done), "
            f"{report['rounds']} × {report['seconds']:g} s per condition, an episode open; period error p99 "
            f"{off['period_error_us']['p99']} → {on['period_error_us']['p99']} µs; overruns/10k "
            f"{off['overruns_per_10k']} → {on['overruns_per_10k']}",
            scenario=SCENARIO.name,
            group=GROUP,
        ),
        target_row(
            "rows the recorder lost",
            float(sum(e["dropped"] for e in episodes)) if episodes else None,
            0.0,
            "",
            f"{len(episodes)} episodes, {sum(e['cycles'] for e in episodes)} cycles written",
            scenario=SCENARIO.name,
            group=GROUP,
        ),
    ]


def format_record(report: dict[str, Any]) -> str:
    lines = [f"RECORD ({report['scenario']}, {report['rounds']} rounds × {report['seconds']:g} s per condition)"]
    for condition in ("off", "on"):
        r = report[condition]
        d, p = r["duration_us"], r["period_error_us"]
        lines.append(
            f"  {condition:<4} cycles {r['cycles']:>7}  duration p50 {d['p50']} p99 {d['p99']} max {d['max']} µs  "
            f"period error p99 {p['p99']} µs  overruns/10k {r['overruns_per_10k']}"
        )
    lines.append(
        f"  p99 rise: duration {report['p99_rise_pct']} %, period error {report['period_error_p99_rise_pct']} %"
    )
    for e in report.get("episodes", []):
        lines.append(
            f"  episode {e['id']}: {e['cycles']} cycles in {e['duration_s']:.2f} s, {e['dropped']} dropped "
            f"(window saw {e['window_cycles']})"
        )
    return "\n".join(lines)
