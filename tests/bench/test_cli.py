"""``hild bench`` end to end at the shortest windows: the real daemon processes, the clients, the JSON report.

Only the shape and the internal consistency of the figures are checked, never a timing target: on a shared
machine the numbers are whatever they are, and the report says so itself.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from hild.bench.cli import SECTIONS, selected

SECTION_KEYS = ("bench", "machine", "floor", "scenarios", "latency", "cpu", "interference", "targets")


def test_only_takes_names_and_base_names_as_patterns() -> None:
    assert selected(None) == list(SECTIONS)
    assert selected(["can6"]) == ["can6@500", "can6@1000", "can6@500-nospin", "can6@1000-virtual"]
    assert selected(["can6@1000"]) == ["can6@1000"]  # the virtual-bus row is named apart
    assert selected(["can6@1000*"]) == ["can6@1000", "can6@1000-virtual"]
    assert selected(["*nospin"]) == ["twin6@500-nospin", "can6@500-nospin"]
    assert selected(["floor", "*@1000"]) == ["floor", "mock6@1000", "twin6@1000", "can3@1000", "can6@1000"]
    assert selected(["nothing"]) == []
    assert selected(["*"]) == list(SECTIONS)  # motion and soak run only when named
    assert selected(["soak", "motion", "floor"]) == ["floor", "motion", "soak"]


def ordered(p: dict[str, float]) -> bool:
    return p["n"] > 0 and 0.0 <= p["p50"] <= p["p99"] <= p["p999"] <= p["max"]


def run_bench(tmp_path: Path, only: list[str], *options: str) -> tuple[subprocess.CompletedProcess[str], Any]:
    out = tmp_path / "bench.json"
    command = [sys.executable, "-m", "hild.cli", "bench", "--quick", "--seconds", "0.5", "--json", str(out)]
    done = subprocess.run(
        [*command, *options, "--only", *only],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return done, json.loads(out.read_text())


def test_a_quick_run_writes_every_section(tmp_path: Path) -> None:
    only = ["floor", "can3@1000", "interference"]
    done, report = run_bench(tmp_path, only)
    assert "TARGETS" in done.stdout and "can3@1000" in done.stdout
    assert "mode: the cycle in a process of its own" in done.stdout
    assert set(SECTION_KEYS) <= set(report)
    assert report["bench"]["settings"]["cycle_process"] is True
    assert report["bench"]["sections"] == only and report["bench"]["quick"] is True
    assert report["machine"]["cpu_count"] >= 1 and report["machine"]["packages"]["eclipse-zenoh"]
    assert {"before", "after"} <= set(report["machine"]["load_average"])
    assert "switch_interval" in report["machine"]["realtime"]

    floor = report["floor"]
    assert [r["rate_hz"] for r in floor["empty_thread"]] == [500.0, 1000.0]
    assert all(ordered(r["period_error_us"]) for r in floor["empty_thread"])
    for probe in ("zenoh", "can_virtual", "mj_step"):
        assert "error" not in floor[probe], floor[probe]

    (scenario,) = report["scenarios"]
    assert scenario["name"] == "can3@1000" and "error" not in scenario
    assert scenario["cycles"] > 0 and ordered(scenario["duration_us"]) and ordered(scenario["period_error_us"])
    assert scenario["cycle_process"] is True and scenario["can_bus"] == "remote (loopback bridge)"
    assert scenario["can_bridge"] == "rig process"  # the drives in a process of their own (the [teleop] fix)
    assert scenario["counters"]["emulator handled"] > 0  # the drives answered the cycle process over the bridge
    assert scenario["goals"]["sent"] >= 1

    (latency,) = report["latency"]
    assert latency["probes"] > 0 and ordered(latency["command_to_frame_us"])
    assert latency["samples"] > 0 and ordered(latency["reply_to_joint_states_us"])

    (cpu,) = report["cpu"]
    assert cpu["process"] > 0 and cpu["daemon"] <= cpu["process"] and cpu["emulator"] >= 0
    assert cpu["cycle"] > 0 and cpu["hild"] == round(cpu["daemon"] + cpu["cycle"], 1)  # the cycle process counted
    assert cpu["whole"] >= cpu["hild"] and cpu["emulator"] > 0  # the rig process: drives and their servers

    conditions = report["interference"]["conditions"]
    names = ["baseline", "polling", "polling+servo", "servo", "decoy polling", "decoy polling+servo", "decoy servo"]
    names.append("flood")
    assert [c["name"] for c in conditions] == names
    assert all(c["cycles"] > 0 and ordered(c["duration_us"]) for c in conditions)
    decoy = {c["name"]: c["clients"] for c in conditions}["decoy polling+servo"]
    assert "poll-status" in decoy and "servo-servo_wrist" in decoy and "failures" not in decoy  # the decoy answered
    assert conditions[0]["p99_rise_pct"] == 0.0

    flood = conditions[-1]
    assert "flood-status" in flood["clients"] and "goal_accept_ms" in flood

    statuses = {(t["target"], t["scenario"]): t["status"] for t in report["targets"]}
    assert statuses[("polling 200/s + servo 1 kHz: p99 rise", "twin6@1000")] in ("PASS", "MISS")
    assert statuses[("servo stream 1 kHz: p99 rise", "twin6@1000")] in ("PASS", "MISS")
    assert statuses[("1 MiB flood: p99 rise", "twin6@1000")] in ("PASS", "MISS")
    assert statuses[("polling raises cycle p99 by", "twin6@1000")] in ("PASS", "MISS")  # measured, so decided
    assert statuses[("… of which serving it (vs decoy)", "twin6@1000")] in ("PASS", "MISS")
    assert statuses[("cycle duration p99", "twin6@1000")] == "n/a"  # not run


def test_one_process_mode_stays_selectable(tmp_path: Path) -> None:
    done, report = run_bench(tmp_path, ["can3@1000"], "--one-process")
    assert "mode: one process" in done.stdout
    (scenario,) = report["scenarios"]
    assert scenario["cycle_process"] is False and scenario["can_bus"] == "virtual"
    assert scenario["counters"]["driver frames_sent"] > 0  # the drivers are in this process: their counters too
    assert scenario["cycles"] > 0 and ordered(scenario["duration_us"])
    (cpu,) = report["cpu"]
    assert cpu["cycle"] > 0 and cpu["hild"] == cpu["daemon"]  # the cycle thread is inside the daemon
