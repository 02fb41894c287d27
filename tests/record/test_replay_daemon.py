"""``replay`` end to end against a daemon (the mock arm on the sim clock, tests/api/conftest.py): the goal it builds
is one the real joint_trajectory controller accepts and runs to the recorded end pose."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hild.api.client import HildClient
from hild.record.model import RecordError
from hild.record.replay import replay
from tests.api.conftest import ROBOT, engine_with_trajectory, running
from tests.record.episodes import cycle_rows, episode

JOINTS = ("a", "b", "c")


def swing(start: list[float], seconds: float = 1.5) -> object:
    rows = cycle_rows(int(seconds * 500) + 1, 500.0)
    t = rows.t - rows.t[0]
    path = np.array(start) + 0.2 * (1 - np.cos(np.pi * t / seconds))[:, None] * np.array([1.0, -1.0, 0.5])
    return episode("swing", rows=replace(rows, measured_position=path, position=path), joints=JOINTS)


def test_replay_runs_the_recorded_path_on_the_mock_arm(tmp_path: Path) -> None:
    with running(engine_with_trajectory(tmp_path)) as daemon, HildClient(ROBOT, [daemon.endpoint], 5.0) as client:
        client.switch(activate=["traj"])
        at = dict(zip(*(client.next_message("joint_states")[k] for k in ("name", "position")), strict=True))
        start = [at[j] for j in JOINTS]
        ep = swing([s + 0.01 for s in start])  # 1 cm off: within the start tolerance
        result = replay(client, ep, speed=2.0, say=lambda text: None)
        assert result["status"] == "succeeded", result
        end = client.next_message("joint_states")
        np.testing.assert_allclose(end["position"], ep.rows.measured_position[-1], atol=1e-6)  # the mock tracks exactly

        far = swing([s + 0.3 for s in start])
        with pytest.raises(RecordError, match="--move-to-start"):
            replay(client, far, say=lambda text: None)
