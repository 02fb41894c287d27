"""The motion bench's lockstep part (``hild bench --only motion`` without its daemon): the standard trajectory
succeeds on the twin at its rate and at another, and the report prints."""

from __future__ import annotations

from hild.bench.motion import MotionSettings, format_motion, run_motion
from tests.conftest import CONFIGS


def test_tracking_runs_the_standard_trajectory_on_the_lockstep_twin() -> None:
    report = run_motion(MotionSettings(tracking=[CONFIGS / "rrbot_twin.yaml"], rates=[1000.0], daemon_config=None))
    rows = report["tracking"]
    assert [(r["config"], r["rate_hz"], r["status"]) for r in rows] == [
        ("rrbot_twin.yaml", 500.0, "succeeded"),
        ("rrbot_twin.yaml", 1000.0, "succeeded"),
    ]
    assert all(j["max_rad"] < 0.05 and abs(j["settled_rad"]) < 1e-3 for r in rows for j in r["joints"])
    assert "rrbot_twin.yaml @ 1000 Hz: succeeded" in format_motion(report)
