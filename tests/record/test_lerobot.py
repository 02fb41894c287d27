"""LeRobotDataset v3.0 export (hild/record/lerobot.py): frames resampled by zero-order hold from every cycle, the
layout LeRobot's loader reads (tests/record/lerobot_reader.py mirrors its accesses), stats, appending, atomicity."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hild.modes import Source
from hild.record import lerobot, swap
from hild.record.frames import TIME_SLACK, frame_rows
from hild.record.lerobot import ACTION, SOURCE, STATE, export_lerobot
from hild.record.model import RecordedEvent, RecordError
from tests.record import lerobot_reader
from tests.record.episodes import JOINTS, cycle_rows, episode


def three_episodes() -> list:
    """Different lengths, rates and tasks (two share one), one with a gap of lost rows."""
    gap = cycle_rows(1500, 1000.0, t0=3.0)
    keep = np.ones(len(gap), dtype=bool)
    keep[400:437] = False  # 37 rows the recorder lost
    return [
        episode("e1", 2000, task="pick the cube"),
        episode("e2", rows=gap.select(keep), task="place the cube"),
        episode("e3", 1234, rate=500.0, task="pick the cube"),
    ]


def tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*") if p.is_file()
    }


# ---- resampling ------------------------------------------------------------------------------------------------
def assert_zero_order_hold(t: np.ndarray, fps: float, offsets: np.ndarray, rows: np.ndarray) -> None:
    times = t[0] + offsets
    assert np.all(t[rows] <= times + TIME_SLACK), "a frame holds a cycle after its time"
    following = rows + 1 < len(t)
    assert np.all(t[rows[following] + 1] > times[following] + TIME_SLACK), "a frame skips a newer cycle"
    assert times[-1] <= t[-1] + TIME_SLACK, "a frame past the last cycle"
    # the frame after the last would be past the last cycle: none is missing at the end. (Not a count from
    # ⌊duration·fps⌋: 128.04 − 128.0 is 0.03999…, so ⌊·25⌋ = 0 for two frames, at 0 and at 40 ms.)
    assert t[0] + len(rows) / fps > t[-1] + TIME_SLACK, "a frame missing before the last cycle"
    np.testing.assert_array_equal(offsets, np.arange(len(rows)) / fps)


def test_frames_hold_the_last_cycle_at_or_before_their_time() -> None:
    t = cycle_rows(2000).t
    offsets, rows = frame_rows(t, 30.0)
    assert len(rows) == math.floor(1.999 * 30) + 1 == 60
    assert_zero_order_hold(t, 30.0, offsets, rows)
    assert rows[0] == 0 and rows[1] == 33  # 1/30 s = 33.3 cycles: the 34th cycle is after it


def test_a_frame_that_falls_on_a_cycle_takes_that_cycle() -> None:
    t = cycle_rows(1001).t  # exactly 1 s: frames at 0, 10 ms, …, 1 s fall on cycles (float sums of 1/1000)
    _, rows = frame_rows(t, 100.0)
    assert len(rows) == 101
    np.testing.assert_array_equal(rows, np.arange(0, 1001, 10))


@settings(max_examples=200, deadline=None)
@example(periods=[0.04], fps=25, t0=128.0)  # a frame on the last cycle, the duration a hair under 1/fps in floats
@given(
    periods=st.lists(st.floats(1e-4, 0.05), min_size=1, max_size=300),
    fps=st.integers(1, 240),
    t0=st.floats(0.0, 1e5),
)
def test_any_cycle_timing_resamples_to_a_zero_order_hold(periods: list[float], fps: int, t0: float) -> None:
    t = t0 + np.concatenate(([0.0], np.cumsum(periods)))
    offsets, rows = frame_rows(t, float(fps))
    assert_zero_order_hold(t, fps, offsets, rows)


def test_a_single_cycle_is_one_frame_and_no_cycle_is_refused() -> None:
    offsets, rows = frame_rows(np.array([5.0]), 30.0)
    assert offsets.tolist() == [0.0] and rows.tolist() == [0]
    with pytest.raises(RecordError, match="no cycles"):
        frame_rows(np.zeros(0), 30.0)
    with pytest.raises(RecordError, match="backwards"):
        frame_rows(np.array([0.0, 0.2, 0.1]), 30.0)


# ---- the dataset ---------------------------------------------------------------------------------------------
def test_three_episodes_load_as_lerobot_loads_them(tmp_path: Path) -> None:
    episodes = three_episodes()
    out = tmp_path / "ds"
    report = export_lerobot(episodes, out, 30.0)
    ds = lerobot_reader.load(out)

    info = ds.info
    assert info.codebase_version == "v3.0" and info.fps == 30
    assert info.total_episodes == 3 and info.total_tasks == 2
    assert info.splits == {"train": "0:3"}
    assert info.features[STATE] == {"dtype": "float32", "shape": (3,), "names": list(JOINTS)}
    assert info.features[ACTION]["names"] == list(JOINTS)
    assert info.total_frames == len(ds.data) == sum(e.frames for e in report.episodes)
    # the data files hold exactly the arrow types datasets would cast to (no silent float64 → float32 cast)
    for path in (out / "data").glob("*/*.parquet"):
        schema = pq.read_schema(path)
        assert {f.name: f.type for f in schema} == {
            k: lerobot_reader.hf_arrow_type(ft) for k, ft in info.features.items()
        }
    assert (out / info.data_path.format(chunk_index=0, file_index=0)).exists()
    assert pq.ParquetFile(out / "data/chunk-000/file-000.parquet").num_row_groups == 3  # one per episode

    index = ds.data.column("index").to_numpy()
    np.testing.assert_array_equal(index, np.arange(info.total_frames))  # row position = absolute index
    start = 0
    for ep_idx, (ep, exported) in enumerate(zip(episodes, report.episodes, strict=True)):
        row = ds.episode(ep_idx)
        duration = ep.rows.t[-1] - ep.rows.t[0]
        assert abs(row["length"] - math.floor(duration * 30)) <= 1
        assert row["episode_index"] == ep_idx and row["length"] == exported.frames
        assert (row["dataset_from_index"], row["dataset_to_index"]) == (start, start + row["length"])
        assert ds.get_data_file_path(ep_idx) == Path("data/chunk-000/file-000.parquet")
        assert row["tasks"] == [ep.meta.task]
        frames = ds.data.slice(start, row["length"])
        assert frames.column("episode_index").to_pylist() == [ep_idx] * row["length"]
        assert frames.column("frame_index").to_pylist() == list(range(row["length"]))
        stamps = frames.column("timestamp").to_numpy()
        assert np.all(np.diff(stamps) > 0)
        np.testing.assert_allclose(np.diff(stamps), 1 / 30, atol=1e-4)  # LeRobot's tolerance_s
        np.testing.assert_array_equal(stamps, (np.arange(row["length"]) / 30).astype(np.float32))
        # state and action are the cycle rows at the frame times, exactly (as float32)
        _, rows = frame_rows(ep.rows.t, 30.0)
        state = np.array(frames.column(STATE).to_pylist(), dtype=np.float32)
        action = np.array(frames.column(ACTION).to_pylist(), dtype=np.float32)
        np.testing.assert_array_equal(state, ep.rows.measured_position[rows].astype(np.float32))
        np.testing.assert_array_equal(action, ep.rows.position[rows].astype(np.float32))
        item = ds.get_item(start + 2, delta=[-3, 0, 1])  # delta_timestamps stay in the episode, padded
        assert item["task"] == ep.meta.task and ds.get_task_index(ep.meta.task) == item["task_index"]
        assert item["observation.state_is_pad"] == [True, False, False]
        assert item["observation.state"] == [state[0].tolist(), state[2].tolist(), state[3].tolist()]  # clamped
        start += row["length"]
    assert ds.tasks.index.tolist() == ["pick the cube", "place the cube"]
    assert ds.tasks["task_index"].tolist() == [0, 1]


def test_the_gap_of_lost_rows_is_held_over(tmp_path: Path) -> None:
    ep = three_episodes()[1]
    _, rows = frame_rows(ep.rows.t, 30.0)
    ticks = ep.rows.tick[rows]
    assert np.any(np.diff(ticks) > 40)  # a frame whose successor skipped the gap held the row before it


def test_stats_are_numpys_over_the_frames(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    export_lerobot(three_episodes(), out, 30.0)
    ds = lerobot_reader.load(out)
    for name in lerobot.feature_names():
        column = ds.data.column(name)
        values = np.array(column.to_pylist(), dtype=np.float64).reshape(len(column), -1)
        check_stats(ds.stats[name], values)
        for ep_idx in range(ds.info.total_episodes):  # and each episode's own, in meta/episodes
            row = ds.episode(ep_idx)
            part = values[row["dataset_from_index"] : row["dataset_to_index"]]
            ep_stats = {
                key: np.array(ds.episodes_with_stats.column(f"stats/{name}/{key}")[ep_idx].as_py())
                for key in lerobot.STAT_KEYS
            }
            check_stats(ep_stats, part)


def check_stats(stats: dict[str, np.ndarray], values: np.ndarray) -> None:
    assert set(stats) == set(lerobot.STAT_KEYS)
    assert stats["count"].tolist() == [len(values)]
    np.testing.assert_array_equal(stats["min"], values.min(axis=0))
    np.testing.assert_array_equal(stats["max"], values.max(axis=0))
    np.testing.assert_allclose(stats["mean"], values.mean(axis=0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(stats["std"], values.std(axis=0), rtol=1e-9, atol=1e-12)
    for key, q in lerobot.QUANTILES.items():
        np.testing.assert_allclose(stats[key], np.quantile(values, q, axis=0), rtol=1e-12, atol=1e-12)


def test_appending_continues_the_indices_and_keeps_the_old_files(tmp_path: Path) -> None:
    first, second, third = three_episodes()
    out = tmp_path / "ds"
    export_lerobot([first, second], out, 30.0)
    before = tree_digest(out)
    new_task = replace(third, meta=replace(third.meta, task="stack the cubes"))
    report = export_lerobot([new_task], out, None)  # fps: the episode's own (30)
    ds = lerobot_reader.load(out)

    assert report.episodes[0].episode_index == 2
    assert ds.info.total_episodes == 3 and ds.info.splits == {"train": "0:3"}
    assert ds.tasks.index.tolist() == ["pick the cube", "place the cube", "stack the cubes"]
    row = ds.episode(2)
    assert row["dataset_from_index"] == ds.episode(1)["dataset_to_index"]
    assert row["dataset_to_index"] == ds.info.total_frames == len(ds.data)
    assert ds.get_data_file_path(2) == Path("data/chunk-000/file-001.parquet")  # a new file, as LeRobot resumes
    assert row["meta/episodes/file_index"] == 1
    np.testing.assert_array_equal(ds.data.column("index").to_numpy(), np.arange(ds.info.total_frames))
    assert set(ds.data.slice(row["dataset_from_index"]).column("task_index").to_pylist()) == {2}
    after = tree_digest(out)
    for unchanged in ("data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet"):
        assert after[unchanged] == before[unchanged]
    # the dataset's stats cover the old frames and the new ones
    state = np.array(ds.data.column(STATE).to_pylist(), dtype=np.float64)
    check_stats(ds.stats[STATE], state)


def test_an_interrupted_export_leaves_the_previous_dataset_as_it_was(tmp_path: Path, monkeypatch) -> None:
    first, second, third = three_episodes()
    out = tmp_path / "ds"
    export_lerobot([first, second], out, 30.0)
    before = tree_digest(out)

    def killed(stage: Path, target: Path) -> None:
        raise KeyboardInterrupt  # the process stopped after writing the new tree, before the swap

    monkeypatch.setattr(lerobot, "replace_tree", killed)
    with pytest.raises(KeyboardInterrupt):
        export_lerobot([third], out, 30.0)
    assert tree_digest(out) == before  # hard links into the old tree were never written through
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # the staging directory is gone
    lerobot_reader.load(out)


@pytest.mark.parametrize("exchange", [True, False])
def test_replace_tree_swaps_whole_trees(tmp_path: Path, monkeypatch, exchange: bool) -> None:
    if not exchange:
        monkeypatch.setattr(swap, "_exchange", lambda a, b: False)  # kernels or filesystems without it
    target = tmp_path / "ds"
    target.mkdir()
    (target / "old.txt").write_text("old")
    (target / "same.txt").write_text("same")
    stage = swap.staging_dir(target)
    swap.link_tree(target, stage)
    swap.write_new(stage / "old.txt", b"new")
    (stage / "only-new.txt").write_text("x")
    assert (target / "old.txt").read_text() == "old"
    swap.replace_tree(stage, target)
    assert sorted(p.name for p in target.iterdir()) == ["old.txt", "only-new.txt", "same.txt"]
    assert (target / "old.txt").read_text() == "new" and (target / "same.txt").read_text() == "same"
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_task_markers_change_the_frames_task(tmp_path: Path) -> None:
    ep = episode("e1", 3001, task="reach")
    rows = ep.rows
    marker = RecordedEvent(float(rows.wall[1500]), float(rows.t[1500]), "marker", {"task": "grasp"})
    by_wall = RecordedEvent(float(rows.wall[2405]), math.nan, "marker", {"task": "lift"})  # no cycle time known
    other = RecordedEvent(float(rows.wall[100]), float(rows.t[100]), "event", {"task": "ignored"})
    ep = replace(ep, events=[marker, by_wall, other])
    export_lerobot([ep], tmp_path / "ds", 10.0)
    ds = lerobot_reader.load(tmp_path / "ds")
    tasks = [ds.tasks.iloc[i].name for i in ds.data.column("task_index").to_pylist()]
    assert tasks == ["reach"] * 15 + ["grasp"] * 10 + ["lift"] * 6  # frames at 0 … 3.0 s, every 0.1 s
    assert ds.episode(0)["tasks"] == ["reach", "grasp", "lift"]


def test_an_episode_without_a_task_gets_the_default(tmp_path: Path) -> None:
    export_lerobot([episode("e1", 500, task=None)], tmp_path / "a", 30.0)
    assert lerobot_reader.load(tmp_path / "a").tasks.index.tolist() == [lerobot.DEFAULT_TASK]
    export_lerobot([episode("e1", 500, task=None)], tmp_path / "b", 30.0, default_task="wave")
    assert lerobot_reader.load(tmp_path / "b").tasks.index.tolist() == ["wave"]


def test_refusals_say_why_and_touch_nothing(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    export_lerobot([episode("e1", 500)], out, 30.0)
    before = tree_digest(out)
    cases = [
        ([episode("e2", 500)], 15.0, "at 30 fps"),
        ([episode("e2", 500, joints=("x", "y", "z"))], 30.0, "other features"),
        ([episode("e2", 500)], 29.97, "whole number"),
        ([episode("e2", 500)], -1.0, "positive"),
        ([episode("e2", 500), episode("e3", 500, joints=("a", "b", "c"))], 30.0, "has joints"),
        ([], 30.0, "no episodes"),
        ([episode("e2", rows=cycle_rows(0))], 30.0, "no cycles"),
    ]
    for episodes, fps, reason in cases:
        with pytest.raises(RecordError, match=reason):
            export_lerobot(episodes, out, fps)
    with pytest.raises(RecordError, match="different frame rates"):
        export_lerobot([episode("e2", 500, fps=30.0), episode("e3", 500, fps=10.0)], tmp_path / "new", None)
    assert tree_digest(out) == before
    other = tmp_path / "notes"
    other.mkdir()
    (other / "todo.txt").write_text("x")
    with pytest.raises(RecordError, match="not a LeRobot dataset"):
        export_lerobot([episode("e2", 500)], other, 30.0)


def test_a_dataset_whose_files_disagree_is_not_appended_to(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    export_lerobot([episode("e1", 500)], out, 30.0)
    info = json.loads((out / "meta/info.json").read_text())
    info["total_frames"] += 1
    (out / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(RecordError, match="disagree"):
        export_lerobot([episode("e2", 500)], out, 30.0)


def test_a_full_data_file_rolls_over_to_the_next(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(lerobot, "DATA_FILES_SIZE_IN_MB", 0.002)  # ~2 kB: one 30-frame episode per file
    export_lerobot([episode(f"e{i}", 1000) for i in range(3)], tmp_path / "ds", 30.0)
    ds = lerobot_reader.load(tmp_path / "ds")
    assert [str(ds.get_data_file_path(i)) for i in range(3)] == [f"data/chunk-000/file-00{i}.parquet" for i in range(3)]
    assert ds.info.data_files_size_in_mb == 0.002
    np.testing.assert_array_equal(ds.data.column("index").to_numpy(), np.arange(ds.info.total_frames))


def test_tasks_parquet_reads_back_with_pandas_index(tmp_path: Path) -> None:
    export_lerobot(three_episodes(), tmp_path / "ds", 30.0)
    table = pq.read_table(tmp_path / "ds/meta/tasks.parquet")
    assert table.schema.field("task").type == pa.string()
    df = table.to_pandas()
    assert df.index.name == "task" and df.loc["place the cube"].task_index == 1


def test_source_says_who_moved_each_joint_and_filters_the_export(tmp_path: Path) -> None:
    """0–0.6 s a trajectory on every joint, 0.6–1.5 s a leader arm on j1 and j2 with j3 held, then a policy: every
    frame's ``source`` is its cycle's; ``sources={leader, hold}`` keeps the teleoperated run alone, as an episode of
    its own, renumbered from 0; a filter nothing passes is refused."""
    rows = cycle_rows(2000)
    t = rows.t - rows.t[0]
    rows.source[:] = np.where(t < 0.6, Source.TRAJECTORY, np.where(t < 1.5, Source.LEADER, Source.POLICY))[:, None]
    rows.source[(t >= 0.6) & (t < 1.5), 2] = Source.HOLD
    ep = episode(rows=rows)
    everything = export_lerobot([ep], tmp_path / "all", 30.0)
    ds = lerobot_reader.load(tmp_path / "all")
    assert ds.info.features[SOURCE] == {"dtype": "int64", "shape": (3,), "names": list(JOINTS)}
    _, held = frame_rows(rows.t, 30.0)
    np.testing.assert_array_equal(np.array(ds.data.column(SOURCE).to_pylist()), rows.source[held])
    assert everything.total_frames == len(held)

    teleop = export_lerobot([ep], tmp_path / "teleop", 30.0, sources={Source.LEADER, Source.HOLD})
    ds = lerobot_reader.load(tmp_path / "teleop")
    assert [e.frames for e in teleop.episodes] == [ds.info.total_frames]
    kept = np.array(ds.data.column(SOURCE).to_pylist())
    assert kept.tolist() == [[Source.LEADER, Source.LEADER, Source.HOLD]] * len(kept)
    assert abs(len(kept) - 0.9 * 30) <= 1 and abs(teleop.episodes[0].duration - (len(kept) - 1) / 30) < 2e-3
    assert ds.data.column("frame_index").to_pylist() == list(range(len(kept)))
    np.testing.assert_array_equal(ds.data.column("timestamp").to_numpy(), (np.arange(len(kept)) / 30).astype("f4"))
    first = int(np.flatnonzero(rows.source[held, 0] == Source.LEADER)[0])  # the frames are the held cycles'
    np.testing.assert_array_equal(
        np.array(ds.data.column(STATE).to_pylist(), dtype=np.float32),
        rows.measured_position[held[first : first + len(kept)]].astype(np.float32),
    )
    with pytest.raises(RecordError, match="no frame"):
        export_lerobot([ep], tmp_path / "none", 30.0, sources={Source.HAND})
    assert not (tmp_path / "none").exists()
