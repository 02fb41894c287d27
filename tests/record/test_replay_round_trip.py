"""Replay's round trip on the twin, through ``hild run``: record a trajectory, replay the episode as a
joint_trajectory goal while recording again — the second path is the first within the controller's tracking error
(the issue's "record → replay → record gives the same path within tracking error")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hild.bench.children import free_endpoint
from hild.bench.daemon import HildRun
from hild.bench.scenarios import JTC, arm6_config
from hild.crossing.cyclelog import CycleRows
from hild.record.mcap_files import read_episode
from hild.record.replay import replay

RATE = 500.0


def _moving(rows: CycleRows) -> int:
    """The first row whose measured velocity shows motion (where a path begins)."""
    speed = np.abs(rows.measured_velocity).max(axis=1)
    return int(np.argmax(speed > 0.02))


def test_a_replayed_episode_records_the_same_path_within_tracking_error(tmp_path: Path) -> None:
    data = arm6_config("twin", RATE)
    data["recording"] = {"dir": str(tmp_path / "recordings")}
    config = tmp_path / "arm6.yaml"
    config.write_text(json.dumps(data))
    with HildRun(config, free_endpoint(), "arm6", cwd=tmp_path) as run, run.connected() as client:
        client.switch(activate=[JTC])
        state = client.next_message("joint_states", timeout=5.0)
        home = list(state["position"])
        goal = {
            "trajectory": {
                "joint_names": list(state["name"]),
                "points": [
                    {"positions": [p + 0.2 * (-1) ** k for k, p in enumerate(home)], "time_from_start": 1.0},
                    {"positions": home, "time_from_start": 2.0},
                ],
            }
        }
        client.record_start(task="original")
        assert client.send_goal(JTC, goal).wait(10.0)["status"] == "succeeded"
        first = read_episode(Path(client.record_stop()["directory"]))

        client.record_start(task="replayed")
        result = replay(client, first, speed=1.0, say=lambda text: None)
        assert result["status"] == "succeeded", result
        second = read_episode(Path(client.record_stop()["directory"]))

    a, b = first.rows, second.rows
    path_a = a.measured_position[_moving(a) :]  # the original motion, from its first moving cycle to the stop
    assert len(path_a) > 1.8 * RATE, "the original holds the whole motion"
    # The replay starts whenever its goal is accepted: the best time offset (whole cycles) lines the two paths up.
    errors = [
        float(np.abs(b.measured_position[shift : shift + len(path_a)] - path_a).max())
        for shift in range(len(b) - len(path_a) + 1)
    ]
    assert errors, "the replayed episode holds the whole path"
    tracking = float(np.abs(a.position - a.measured_position).max())  # the controller's own error, first run
    error = min(errors)
    assert error <= 2 * tracking + 0.005, f"replayed path off by {error:.4f} rad (tracking error {tracking:.4f} rad)"
    np.testing.assert_allclose(b.measured_position[-1], a.measured_position[-1], atol=0.01)
