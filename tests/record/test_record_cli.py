"""``hild record`` (hild/record/cli.py) and replay's plan and safety checks (hild/record/replay.py), offline: episodes
are built from synthetic rows and handed to the command through ``cli.load_episode`` (reading MCAP files back is
``hild.record.mcap_files``' job, tested beside it); replay talks to a fake client that records what it is asked."""

from __future__ import annotations

import json
import math
import sys
import types
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.action import GoalRejected
from hild.cli import main
from hild.controllers.trajectory_goals import MAX_POINTS, GoalContext, parse_goal
from hild.motion.limits import KinematicLimits
from hild.record import cli
from hild.record import replay as replay_mod
from hild.record.frames import frame_rows
from hild.record.model import EPISODE_JSON, Episode, RecordedEvent, RecordError, mcap_name
from hild.record.replay import check_simulated, plan_replay, replay, trajectory_controller
from tests.record import lerobot_reader
from tests.record.episodes import JOINTS, cycle_rows, episode


def write_episode(root: Path, ep: Episode) -> Path:
    directory = root / ep.meta.id
    directory.mkdir(parents=True)
    (directory / EPISODE_JSON).write_text(ep.meta.to_json())
    return directory


@pytest.fixture
def recordings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, dict[str, Episode]]:
    """Three episodes on disk (their episode.json), read back through ``cli.load_episode``."""
    root = tmp_path / "recordings"
    crashed = episode("20250101-120200-arm", 900, task=None, state="recording")
    crashed = replace(crashed, meta=replace(crashed.meta, stopped_wall=None, stop_tick=None))
    episodes = {
        e.meta.id: e
        for e in (
            episode("20250101-120000-arm", 2000, task="pick the cube"),
            episode("20250101-120100-arm", 1500, task="place the cube"),
            crashed,
        )
    }
    for ep in episodes.values():
        write_episode(root, ep)
    monkeypatch.setattr(cli, "load_episode", lambda directory: episodes[Path(directory).name])
    return root, episodes


def test_list_shows_each_episode(recordings, capsys) -> None:
    root, episodes = recordings
    assert main(["record", "list", str(root)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["ID", "STATE", "CYCLES", "DURATION", "TASK"]
    assert lines[1].split() == ["20250101-120000-arm", "complete", "2000", "2.00", "s", "pick", "the", "cube"]
    assert lines[3].split()[:4] == ["20250101-120200-arm", "recording", "900", "0.90"]  # cycles / update_rate
    assert main(["record", "list", str(root), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in listed] == sorted(episodes)
    assert listed[0]["duration"] == pytest.approx(1.999)  # stopped_wall − started_wall
    assert main(["record", "list", str(root / "missing")]) == 1
    assert "no such directory" in capsys.readouterr().err


def test_export_writes_and_appends_a_lerobot_dataset(recordings, tmp_path, capsys) -> None:
    root, episodes = recordings
    ids = sorted(episodes)
    out = tmp_path / "ds"
    assert main(["record", "export", "--lerobot", str(out), "--fps", "30", str(root / ids[0]), str(root / ids[1])]) == 0
    assert "2 episodes" in capsys.readouterr().out
    # appending the crashed episode, recorded without a task: --task names it
    assert main(["record", "export", "--lerobot", str(out), "--task", "wave", "--json", str(root / ids[2])]) == 0
    captured = capsys.readouterr()
    assert f"{ids[2]} was never closed" in captured.err  # the crashed one: said, and exported all the same
    reply = json.loads(captured.out)
    assert reply["ok"] and reply["total_episodes"] == 3 and reply["episodes"][0]["episode_index"] == 2
    ds = lerobot_reader.load(out)
    assert ds.tasks.index.tolist() == ["pick the cube", "place the cube", "wave"]
    for i, ep_id in enumerate(ids):
        rows = episodes[ep_id].rows
        assert ds.episode(i)["length"] == len(frame_rows(rows.t, 30.0)[1])
    assert main(["record", "export", "--lerobot", str(out), "--fps", "10", str(root / ids[0])]) == 1
    assert "30 fps" in capsys.readouterr().err  # refused, with the reason


def test_an_episode_is_named_by_directory_mcap_file_or_id(recordings, monkeypatch) -> None:
    root, episodes = recordings
    ep_id = sorted(episodes)[0]
    (root / ep_id / mcap_name(ep_id)).write_bytes(b"")
    assert cli.resolve_episode(str(root / ep_id)) == root / ep_id
    assert cli.resolve_episode(str(root / ep_id / mcap_name(ep_id))) == root / ep_id
    monkeypatch.chdir(root.parent)
    assert cli.resolve_episode(ep_id) == Path("recordings") / ep_id
    with pytest.raises(RecordError, match="not an episode"):
        cli.resolve_episode("nothing-here")


def test_view_save_writes_an_rrd_rerun_reads_back(recordings, tmp_path, capsys) -> None:
    from hild.telemetry.replay import entity_row_counts, tracking

    root, episodes = recordings
    ep_id = sorted(episodes)[0]
    ep = episodes[ep_id]
    events = [
        RecordedEvent(float(ep.rows.wall[10]), float(ep.rows.t[10]), "marker", {"episode": "start"}),
        RecordedEvent(float(ep.rows.wall[500]), math.nan, "event", {"level": "warning", "message": "limit"}),
    ]
    episodes[ep_id] = replace(ep, events=events)
    path = tmp_path / "ep.rrd"
    assert main(["record", "view", str(root / ep_id), "--save", str(path)]) == 0
    assert f"{len(ep.rows)} cycles written" in capsys.readouterr().out
    commanded, measured = tracking(path)  # rerun's own reader (rerun.chunk.RrdReader)
    np.testing.assert_array_equal(measured.tick, ep.rows.tick)
    np.testing.assert_allclose(measured.t, ep.rows.t, atol=1e-9)
    np.testing.assert_array_equal(measured.values, ep.rows.measured_position)
    np.testing.assert_array_equal(commanded.values, ep.rows.position)
    assert measured.names == JOINTS and commanded.names == tuple(f"{j} cmd" for j in JOINTS)
    counts = entity_row_counts(path)
    assert counts["/joints/effort/commanded"] == counts["/loop/period"] == len(ep.rows)
    assert counts["/events"] == 2


def test_a_long_episode_is_sent_in_batches(tmp_path, monkeypatch) -> None:
    from hild.telemetry import episode_view
    from hild.telemetry.replay import load_scalars

    monkeypatch.setattr(episode_view, "BATCH", 700)
    ep = episode("e1", 2000)
    path = episode_view.save_episode(ep, tmp_path / "ep.rrd")
    series = load_scalars(path, "joints/mode")
    np.testing.assert_array_equal(series.tick, ep.rows.tick)


class FakeRecover:
    """Stands in for ``hild.record.mcap_files`` (another part of the room) until it is merged."""

    def __init__(self) -> None:
        self.recovered: list[str] = []

    def recover(self, directory: Path) -> dict[str, Any]:
        self.recovered.append(Path(directory).name)
        return {"cycles": 900, "lost": 0.1}


def test_recover_closes_open_episodes_and_skips_a_live_one(recordings, monkeypatch, capsys) -> None:
    root, episodes = recordings
    fake = FakeRecover()
    module = types.ModuleType("hild.record.mcap_files")
    module.recover = fake.recover  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "hild.record.mcap_files", module)
    crashed = "20250101-120200-arm"
    assert main(["record", "recover", str(root)]) == 0
    assert fake.recovered == [crashed]  # only the one still marked "recording"
    assert crashed in capsys.readouterr().out
    complete = sorted(episodes)[0]
    assert main(["record", "recover", str(root / complete), "--json"]) == 0  # named: recovered whatever its state
    assert json.loads(capsys.readouterr().out)[0]["report"] == {"cycles": 900, "lost": 0.1}
    (root / crashed / mcap_name(crashed)).write_bytes(b"being written")  # changed just now
    assert main(["record", "recover", str(root)]) == 1
    assert "maybe still recording" in capsys.readouterr().out
    assert main(["record", "recover", str(root), "--force"]) == 0
    assert fake.recovered == [crashed, complete, crashed]


# ---- replay ----------------------------------------------------------------------------------------------------
def moving_episode(seconds: float = 4.0, rate: float = 1000.0) -> Episode:
    """The arm swings each joint through 0.6 rad (sine, 0.5 Hz), starting at rest at its start pose."""
    rows = cycle_rows(int(seconds * rate) + 1, rate)
    t = rows.t - rows.t[0]
    path = 0.3 * (1 - np.cos(2 * np.pi * 0.5 * t))[:, None] * np.array([1.0, -0.5, 0.8]) + np.array([0.1, 0.2, 0.3])
    rows = replace(rows, measured_position=path, position=path + 0.01)
    return episode("e1", rows=rows)


def test_the_plan_is_the_measured_path_at_the_recorded_times() -> None:
    ep = moving_episode()
    plan = plan_replay(ep, ["j3", "j1"], rate=50.0)
    rows = ep.rows
    assert plan.times[0] == 0.0 and np.all(np.diff(plan.times) > 0)
    assert plan.duration == pytest.approx(rows.t[-1] - rows.t[0])
    assert len(plan.times) == 201  # 4 s at 50 Hz, and the last cycle
    picked = np.searchsorted(rows.t - rows.t[0], plan.times - 1e-12)
    np.testing.assert_array_equal(plan.positions, rows.measured_position[picked][:, [2, 0]])  # joints as asked
    np.testing.assert_allclose(plan.velocities[100], [0.8 * 0.3 * np.pi * np.sin(np.pi * 2.0), 0.0], atol=1e-2)
    slow = plan_replay(ep, ["j3", "j1"], rate=50.0, speed=0.5)
    np.testing.assert_allclose(slow.times, plan.times * 2)
    np.testing.assert_allclose(slow.velocities, plan.velocities / 2)
    np.testing.assert_array_equal(slow.positions, plan.positions)


def test_the_plan_is_a_goal_joint_trajectory_accepts() -> None:
    ep = moving_episode()
    plan = plan_replay(ep, list(JOINTS))
    limits = KinematicLimits(np.full(3, 2.0), np.full(3, 10.0), np.full(3, 100.0))
    goal = {"trajectory": {"joint_names": list(JOINTS), "points": plan.points()}}
    prepared = parse_goal(goal, GoalContext.unchecked(JOINTS, 3.0, limits))
    np.testing.assert_array_equal(prepared.plan.times, plan.times)
    with pytest.raises(GoalRejected, match=r"exceeds its limit|above its limit"):  # the daemon says why it refuses
        parse_goal(
            {"trajectory": {"joint_names": list(JOINTS), "points": plan_replay(ep, list(JOINTS), speed=4).points()}},
            GoalContext.unchecked(JOINTS, 3.0, KinematicLimits(np.full(3, 0.3), np.full(3, 10.0), np.full(3, 100.0))),
        )


def test_a_long_episode_is_decimated_under_the_controllers_point_limit() -> None:
    assert MAX_POINTS == replay_mod.MAX_POINTS
    ep = episode("long", rows=cycle_rows(100_001, rate=200.0))  # 500 s
    plan = plan_replay(ep, list(JOINTS))
    assert len(plan.times) <= MAX_POINTS and plan.times[-1] == pytest.approx(500.0)


def test_plans_refuse_what_cannot_be_replayed() -> None:
    with pytest.raises(RecordError, match="no recording of"):
        plan_replay(moving_episode(), ["j1", "elbow"])
    with pytest.raises(RecordError, match="speed"):
        plan_replay(moving_episode(), ["j1"], speed=0.0)
    with pytest.raises(RecordError, match="nothing to replay"):
        plan_replay(episode("one", rows=cycle_rows(1)), ["j1"])


class FakeClient:
    """A daemon as replay sees it; records every call."""

    def __init__(self, drivers=("mujoco",), at=(0.1, 0.2, 0.3), controllers=None) -> None:
        self.drivers = drivers
        self.at = list(at)
        self.controllers = controllers or [
            {"name": "jsb", "type": "joint_state_broadcaster", "state": "active"},
            {"name": "traj", "type": "joint_trajectory", "state": "active"},
        ]
        self.calls: list[tuple[str, Any]] = []

    def list_hardware(self) -> list[dict[str, Any]]:
        return [{"name": f"hw{i}", "driver": d} for i, d in enumerate(self.drivers)]

    def list_controllers(self) -> list[dict[str, Any]]:
        return self.controllers

    def get_parameters(self, controller: str, names=()) -> dict[str, Any]:
        return {"joints": list(JOINTS)}

    def next_message(self, topic: str, timeout=None) -> dict[str, Any]:
        assert topic == "joint_states"
        return {"name": list(JOINTS), "position": self.at}

    def move_to(self, controller: str, positions, **kw) -> dict[str, Any]:
        self.calls.append(("move_to", positions))
        return {"status": "succeeded"}

    def execute_trajectory(self, controller, joint_names, points, **kw) -> dict[str, Any]:
        self.calls.append(("trajectory", points))
        return {"status": "succeeded"}


def run_replay(client: FakeClient, **kw: Any) -> dict[str, Any]:
    return replay(client, moving_episode(), say=lambda text: None, **kw)


def test_replay_on_the_twin_moves_to_the_start_then_sends_the_path() -> None:
    client = FakeClient(at=(0.12, 0.2, 0.31))  # 0.02 rad off: within the tolerance
    assert run_replay(client, speed=0.5)["status"] == "succeeded"
    (kind, start), (kind2, points) = client.calls
    assert kind == "move_to" and start == pytest.approx([0.1, 0.2, 0.3])
    assert kind2 == "trajectory" and points[0]["time_from_start"] == 0.0
    assert points[0]["positions"] == start and points[-1]["time_from_start"] == pytest.approx(8.0)


def test_replay_refuses_real_hardware_unless_confirmed() -> None:
    client = FakeClient(drivers=("mujoco", "mit_can"))
    with pytest.raises(RecordError, match=r"hw1 \(mit_can\).*--yes-on-hardware"):
        run_replay(client)
    assert client.calls == []  # nothing was sent
    assert run_replay(client, on_hardware=True)["status"] == "succeeded"
    check_simulated([{"name": "sim", "driver": "mock"}], confirmed=False)


def test_replay_refuses_an_arm_away_from_the_start_unless_asked_to_move_there() -> None:
    client = FakeClient(at=(0.1, 0.5, 0.3))
    with pytest.raises(RecordError, match=r"0\.3 rad from the episode's start on j2.*--move-to-start"):
        run_replay(client)
    assert client.calls == []
    assert run_replay(client, move_to_start=True)["status"] == "succeeded"
    assert [c[0] for c in client.calls] == ["move_to", "trajectory"]


def test_replay_needs_one_active_trajectory_controller() -> None:
    two = [
        {"name": "a", "type": "joint_trajectory", "state": "active"},
        {"name": "b", "type": "joint_trajectory", "state": "inactive"},
    ]
    with pytest.raises(RecordError, match="--controller"):
        trajectory_controller(two, None)
    assert trajectory_controller(two, "a") == "a"
    with pytest.raises(RecordError, match="activate it first"):
        trajectory_controller(two, "b")
    with pytest.raises(RecordError, match="no joint_trajectory controller named"):
        trajectory_controller(two, "c")


def test_replay_command_refuses_real_hardware_with_its_reason(recordings, monkeypatch, capsys) -> None:
    root, episodes = recordings
    ep_id = sorted(episodes)[0]
    episodes[ep_id] = replace(moving_episode(), meta=replace(moving_episode().meta, id=ep_id))
    client = FakeClient(drivers=("mit_can",))
    client.close = lambda: None  # type: ignore[attr-defined]
    asked: list[str] = []

    def fake_client(robot: str, *a: Any) -> FakeClient:
        asked.append(robot)
        return client

    monkeypatch.setattr(cli, "_client", fake_client)
    assert main(["record", "replay", str(root / ep_id)]) == 1
    assert "--yes-on-hardware" in capsys.readouterr().err and client.calls == []
    assert asked == ["arm"]  # the episode's robot
    assert main(["record", "replay", str(root / ep_id), "--yes-on-hardware", "--robot", "other", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"status": "succeeded"} and asked[-1] == "other"
