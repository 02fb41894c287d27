"""hild bench --only teleop judges what [teleop] says: lag ≤ 2 control periods + one-way delay, for the runs that
stream at the control rate; the 100 Hz runs are reported beside them, not judged."""

from __future__ import annotations

from typing import Any

from hild.bench.teleop import teleop_targets


def run(name: str, judged: bool, lag: float, delay: float) -> dict[str, Any]:
    return {
        "run": name,
        "judged": judged,
        "control_period_ms": 2.0,
        "delay_ms": delay,
        "lag_command_worst_ms": lag,
        "jumps": 0,
        "deadman_hold_cycles": 0,
    }


def test_only_the_control_rate_runs_are_judged_against_two_control_periods_plus_the_delay() -> None:
    report = {
        "runs": [
            run("no delay @ 500 Hz", True, 4.0, 0.0),
            run("50 ms @ 500 Hz", True, 55.0, 50.0),
            run("no delay @ 100 Hz", False, 1.0, 0.0),
        ]
    }
    rows = teleop_targets(report)
    lag = [r for r in rows if r["target"] == "joint lag"]
    assert [r["scenario"] for r in lag] == ["no delay @ 500 Hz", "50 ms @ 500 Hz"]
    assert [r["limit"] for r in lag] == [4.0, 54.0]
    assert [r["status"] for r in lag] == ["PASS", "MISS"]
    assert all(r["scenario"].endswith("500 Hz") for r in rows)
