"""The bench's statistics, ratios and targets on synthetic data: no daemon, no timing."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.bench.report import (
    busy,
    cpu_percent,
    evaluate_targets,
    format_report,
    loop_figures,
    per_10k,
    rise_pct,
    summarize_ns,
)


def test_summarize_ns_gives_microsecond_percentiles_of_every_sample() -> None:
    values = np.arange(1, 1001) * 1000  # 1 … 1000 µs
    s = summarize_ns(values)
    assert s["n"] == 1000
    assert s["p50"] == pytest.approx(500.5)
    assert s["p99"] == pytest.approx(990.0, abs=0.1)
    assert s["p999"] == pytest.approx(999.0, abs=0.1)
    assert s["max"] == 1000.0
    assert s["mean"] == pytest.approx(500.5)


def test_summarize_ns_of_nothing_is_zeros() -> None:
    assert summarize_ns([]) == {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0, "mean": 0.0, "n": 0}


def test_ratios() -> None:
    assert per_10k(3, 30_000) == 1.0
    assert per_10k(1, 0) == 0.0
    assert rise_pct(110.0, 100.0) == 10.0
    assert rise_pct(90.0, 100.0) == -10.0
    assert cpu_percent({"process": 100, "cycle": 50}, {"process": 400, "cycle": 150}, 10.0, 100) == {
        "process": 30.0,
        "cycle": 10.0,
    }


def test_loop_figures_counts_overruns_per_10k_cycles() -> None:
    f = loop_figures(20_000, 4, [100_000] * 10, [5_000] * 10)
    assert f["overruns_per_10k"] == 2.0
    assert f["duration_us"]["p99"] == 100.0
    assert f["period_error_us"]["max"] == 5.0


def _us(p99: float) -> dict[str, float]:
    return {"p50": p99 / 2, "p99": p99, "p999": p99, "max": p99, "mean": p99 / 2, "n": 100}


def _scenario(base: str, rate: float, dur_p99: float, perr_p99: float, ovr: float, cpu: float) -> dict[str, Any]:
    return {
        "name": f"{base}@{rate:g}",
        "base": base,
        "rate_hz": rate,
        "cycles": 10_000,
        "duration_us": _us(dur_p99),
        "period_error_us": _us(perr_p99),
        "overruns_per_10k": ovr,
        "cpu": {"daemon": cpu},
    }


def _report() -> dict[str, Any]:
    return {
        "floor": {
            "empty_thread": [
                {
                    "rate_hz": 1000.0,
                    "period_error_us": _us(20.0),
                    "lateness_us": _us(5.0),
                    "cycles": 5000,
                    "overruns_per_10k": 0.0,
                }
            ],
            "zenoh": {"one_way_us": _us(150.0), "put_to_subscriber_us": _us(160.0), "pings": 10, "puts": 10},
        },
        "scenarios": [
            _scenario("twin6", 1000.0, 240.0, 39.0, 0.5, 50.0),  # passes the cycle targets
            _scenario("can6", 1000.0, 300.0, 41.0, 2.0, 60.0),  # misses all three
            _scenario("twin6", 500.0, 100.0, 10.0, 0.0, 30.0),
            _scenario("can6", 500.0, 100.0, 10.0, 0.0, 40.0),
        ],
        "latency": [
            {
                "scenario": "can6@1000",
                "base": "can6",
                "rate_hz": 1000.0,
                "probes": 100,
                "samples": 50,
                "command_to_frame_us": _us(1250.0),
                "reply_to_joint_states_us": _us(900.0),
            }
        ],
        "interference": {
            "scenario": "twin6@1000",
            "setup": "trajectory on 3 joints + servo on 3",
            "rounds": 2,
            "conditions": [
                {"name": "baseline", **loop_figures(10_000, 0, [80_000] * 100, [2_000] * 100), "p99_rise_pct": 0.0},
                {"name": "polling", **loop_figures(10_000, 1, [90_000] * 100, [2_000] * 100), "p99_rise_pct": 12.5},
            ],
        },
    }


def test_targets_pass_or_miss_against_limits_derived_from_the_same_runs_floor() -> None:
    targets = {(t["target"], t["scenario"]): t for t in evaluate_targets(_report())}
    assert targets[("cycle duration p99", "twin6@1000")]["status"] == "PASS"
    assert targets[("cycle duration p99", "can6@1000")]["status"] == "MISS"
    perr = targets[("period error p99", "twin6@1000")]
    assert perr["limit"] == 40.0 and perr["status"] == "PASS"  # 2 × the empty thread's 20 µs
    assert targets[("period error p99", "can6@1000")]["status"] == "MISS"
    assert targets[("overruns", "twin6@1000")]["status"] == "PASS"
    assert targets[("overruns", "can6@1000")]["status"] == "MISS"
    zenoh = targets[("Zenoh command → CAN frame p99", "can6@1000")]
    assert zenoh["limit"] == 1300.0 and zenoh["status"] == "PASS"  # 2 × 150 µs + one 1 ms cycle
    assert targets[("daemon CPU at 500 Hz", "twin6@500")]["status"] == "PASS"
    assert targets[("daemon CPU at 500 Hz", "can6@500")]["status"] == "MISS"
    assert targets[("polling raises cycle p99 by", "twin6@1000")]["status"] == "MISS"


def test_targets_without_their_measurement_are_not_applicable() -> None:
    targets = evaluate_targets({"floor": {}, "scenarios": [], "latency": [], "interference": {}})
    assert targets and all(t["status"] == "n/a" for t in targets)
    by_name = {(t["target"], t["scenario"]): t for t in targets}
    assert by_name[("cycle duration p99", "mock6@1000")]["limit"] == 250.0  # fixed limits are still stated


def test_a_failed_scenario_is_not_used_for_a_target() -> None:
    report = _report()
    report["scenarios"][0] = {"name": "twin6@1000", "base": "twin6", "rate_hz": 1000.0, "error": "did not start"}
    targets = {(t["target"], t["scenario"]): t for t in evaluate_targets(report)}
    assert targets[("cycle duration p99", "twin6@1000")]["status"] == "n/a"


def test_the_table_shows_every_section_and_each_targets_status() -> None:
    report = _report()
    report["targets"] = evaluate_targets(report)
    report["cpu"] = [{"scenario": "twin6@500", "rate_hz": 500.0, "process": 30.0, "daemon": 30.0}]
    text = format_report(report)
    for heading in ("FLOOR", "CYCLE", "LATENCY", "CPU", "INTERFERENCE", "TARGETS"):
        assert heading in text
    assert "MISS" in text and "PASS" in text
    assert "can6@1000" in text


def test_a_busy_machine_is_flagged_in_the_table() -> None:
    idle = {"cpu_count": 2, "load_average": {"before": 0.1, "after": 1.2}}  # after: the bench's own load
    loaded = {"cpu_count": 2, "load_average": {"before": 1.5, "after": 1.9}}
    assert not busy(idle) and busy(loaded)
    assert "WARNING" not in format_report({"machine": idle})
    assert "WARNING: the machine was busy" in format_report({"machine": loaded})
