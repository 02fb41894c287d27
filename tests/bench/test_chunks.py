"""``hild bench --only chunks`` end to end: the section runs (lockstep twin, deterministic), prints its table and
writes its figures and its targets, group ``teleop``, into the JSON. Lockstep makes the figures the same on any
machine, so the targets are asserted too."""

from __future__ import annotations

from pathlib import Path

from hild.bench.chunks import KINDS, MIN_SECONDS, ChunkSettings
from tests.bench.test_cli import run_bench


def test_bench_only_chunks_reports_the_servo_against_jtc_upsampling(tmp_path: Path) -> None:
    done, report = run_bench(tmp_path, ["chunks"])
    chunks = report["chunks"]
    assert chunks["settings"]["seconds"] == MIN_SECONDS  # --seconds 0.5 raised to the least that has handoffs
    for kind in KINDS:
        assert chunks[kind]["handoffs"] >= 10 and chunks[kind]["cycles"] > 500
    targets = [t for t in report["targets"] if t["group"] == "teleop"]
    assert [t["target"] for t in targets] == [
        "chunks: handoff speed shortfall",
        "chunks: peak jerk / limit",
        "chunks: cycles at rest while moving",
        "chunks: arm RMS / JTC upsampling",
        "chunks disagreeing: handoff speed shortfall",
        "chunks disagreeing: peak jerk / limit",
        "chunks disagreeing: cycles at rest while moving",
        "chunks disagreeing: arm RMS / JTC upsampling",
    ]
    assert all(t["status"] == "PASS" for t in targets), targets
    for variant in (chunks, chunks["disagreeing"]):
        assert variant["servo"]["measured_rms_error_mrad"] < variant["jtc_stamped"]["measured_rms_error_mrad"]
    assert "TARGETS [teleop]" in done.stdout and "CHUNKS: twin6@500 lockstep" in done.stdout


def test_settings_follow_quick_and_seconds() -> None:
    assert ChunkSettings.make(False).seconds == 20.0
    assert ChunkSettings.make(True).seconds == 5.0
    assert ChunkSettings.make(True, 7, 60.0) == ChunkSettings(seconds=60.0, seed=7)
