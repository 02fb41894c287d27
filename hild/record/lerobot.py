"""LeRobotDataset v3.0 export: episodes resampled to a frame rate, written with pyarrow (docs/recording.md).

**Frames.** A recording holds every cycle (1 kHz, say); a policy sees the robot at its own rate (``fps``, 30 by
default). Frame ``k`` of an episode is taken at ``t0 + k/fps`` on the cycle clock (``t0``: the episode's first
cycle), for ``k = 0 … ⌊duration·fps⌋`` (one fewer if that last time lands after the last cycle), and holds the
**last cycle at or before** that time: a zero-order hold, what a policy running at ``fps`` would have read then,
never an interpolation between two cycles that no controller ever saw. Rows the recorder lost (a gap in ticks) are
held over the same way. ``timestamp`` is ``k/fps`` exactly, as LeRobot's own recorder writes it.
``observation.state`` is the accepted measured position, ``action`` the final command's position (the target the
policy would have produced), both float32 in the robot's joint order, the joint names in the features' ``names``.
``source`` (int64 per joint, ``hild.modes.Source``: 0 hold, 1 trajectory, 2 stream, 3 leader, 4 policy, 5 hand; -1
not recorded) says who moved each joint in the frame's cycle, so a dataset can be filtered by it; ``export_lerobot``'s
``sources`` keeps only frames moved by the sources given (each run of such frames becomes an episode of its own).

**Layout.** What LeRobot's v3.0 loader reads (lerobot/datasets: ``utils.py`` for the paths and ``DatasetInfo``,
``dataset_metadata.py`` and ``io_utils.py`` for loading the metadata, ``dataset_writer.py`` for what a recorded
episode looks like, ``compute_stats.py`` for the statistics):

  meta/info.json                               codebase_version "v3.0", fps, features (dtype, shape, names), totals,
                                               chunks_size, file sizes, data_path/video_path templates, splits
  meta/stats.json                              per feature over every frame: min max mean std count q01 q10 q50 q90 q99
  meta/tasks.parquet                           task_index, with the task text as the pandas index LeRobot reads
  meta/episodes/chunk-XXX/file-YYY.parquet     a row per episode: tasks, length, where its frames are, its stats
  data/chunk-XXX/file-YYY.parquet              a row per frame, one row group per episode

Statistics are computed exactly with numpy over the stored (float32) values; LeRobot's recorder estimates the
quantiles from histograms and, across episodes, keeps an envelope of them: ours are the true quantiles.

**Appending.** Exporting into an existing dataset (same joints, same fps) adds episodes after the last one:
episode and frame indices continue, new tasks get the next task indices, and the new frames go to new data files
(as LeRobot does when it resumes a dataset), so no data file is ever rewritten. The dataset's files are replaced
all at once (``hild.record.swap``): an export that fails or is killed leaves the previous dataset as it was.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from hild.record.frames import TIME_SLACK, frame_rows
from hild.record.model import Episode, RecordError
from hild.record.swap import link_tree, replace_tree, staging_dir, write_new

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  # files per chunk directory (LeRobot's DEFAULT_CHUNK_SIZE)
DATA_FILES_SIZE_IN_MB = 100  # a data file is closed once it would grow past this (DEFAULT_DATA_FILE_SIZE_IN_MB)
VIDEO_FILES_SIZE_IN_MB = 200  # written to info.json as LeRobot does; hild writes no video
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"

STATE = "observation.state"
ACTION = "action"
SOURCE = "source"  # not an observation: a policy must not be fed it (who commanded is not what the robot senses)
# LeRobot's DEFAULT_FEATURES (lerobot/utils/constants.py): every dataset has them, after its own features
INDEX_FEATURES = {"frame_index": "int64", "episode_index": "int64", "index": "int64", "task_index": "int64"}
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}  # compute_stats.DEFAULT_QUANTILES
STAT_KEYS = ("min", "max", "mean", "std", "count", *QUANTILES)
DEFAULT_TASK = "unspecified"  # the task of frames whose episode names none


def feature_names() -> tuple[str, ...]:
    """The dataset's features in LeRobot's order: the robot's first, then the index features."""
    return (ACTION, STATE, SOURCE, "timestamp", *INDEX_FEATURES)


def features(joints: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``info.json``'s features for an arm with these joints."""
    vector = {"dtype": "float32", "shape": [len(joints)], "names": list(joints)}
    out: dict[str, dict[str, Any]] = {ACTION: dict(vector), STATE: dict(vector)}
    out[SOURCE] = {**vector, "dtype": "int64"}
    out["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    out.update({name: {"dtype": dtype, "shape": [1], "names": None} for name, dtype in INDEX_FEATURES.items()})
    return out


# ---- resampling ------------------------------------------------------------------------------------------------
def frame_tasks(episode: Episode, offsets: np.ndarray, default: str) -> list[str]:
    """Each frame's task: the episode's, or the latest task marker at or before the frame (a ``marker`` event
    whose data carries ``task``)."""
    rows = episode.rows
    base = episode.meta.task or default
    changes: list[tuple[float, str]] = []
    for event in episode.events:
        task = event.data.get("task") if event.kind == "marker" else None
        if not isinstance(task, str) or not task:
            continue
        when = event.t if math.isfinite(event.t) else float(np.interp(event.wall, rows.wall, rows.t))
        changes.append((when - float(rows.t[0]), task))
    if not changes:
        return [base] * len(offsets)
    changes.sort(key=lambda c: c[0])
    times = np.array([c[0] for c in changes])
    which = np.searchsorted(times, offsets + TIME_SLACK, side="right") - 1
    return [changes[i][1] if i >= 0 else base for i in which]


@dataclass(frozen=True)
class EpisodeFrames:
    """One episode's frames, as the dataset stores them."""

    columns: dict[str, np.ndarray]  # feature → values (vectors: frames × joints)
    tasks: list[str]  # per frame
    rows: np.ndarray  # the cycle row each frame holds (for checks)

    def __len__(self) -> int:
        return len(self.rows)


def resample(episode: Episode, fps: float, default_task: str = DEFAULT_TASK) -> EpisodeFrames:
    """The episode's frames at ``fps`` (indices still to be numbered: ``number`` does it)."""
    offsets, rows = frame_rows(episode.rows.t, fps)
    columns = {
        ACTION: episode.rows.position[rows].astype(np.float32),
        STATE: episode.rows.measured_position[rows].astype(np.float32),
        SOURCE: episode.rows.source[rows].astype(np.int64),
        "timestamp": offsets.astype(np.float32),
        "frame_index": np.arange(len(rows), dtype=np.int64),
    }
    return EpisodeFrames(columns, frame_tasks(episode, offsets, default_task), rows)


def runs_from(frames: EpisodeFrames, sources: Collection[int], fps: float) -> list[EpisodeFrames]:
    """The runs of consecutive frames in which every joint was moved by one of ``sources`` (hild.modes.Source
    values), each renumbered as an episode of its own (``timestamp`` and ``frame_index`` from 0): "only the human
    demonstrations" of an episode in which a trajectory also ran."""
    keep = np.isin(frames.columns[SOURCE], list(sources)).all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    runs = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        columns = {name: values[start:stop] for name, values in frames.columns.items()}
        n = stop - start
        columns["timestamp"] = (np.arange(n) / fps).astype(np.float32)
        columns["frame_index"] = np.arange(n, dtype=np.int64)
        runs.append(EpisodeFrames(columns, frames.tasks[start:stop], frames.rows[start:stop]))
    return runs


# ---- statistics ----------------------------------------------------------------------------------------------
def feature_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's statistics of one feature over frames (``values``: frames, or frames × dims), per dimension."""
    x = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    if len(x) == 0:
        raise RecordError("no frames to compute statistics over")
    stats = {
        "min": x.min(axis=0),
        "max": x.max(axis=0),
        "mean": x.mean(axis=0),
        "std": x.std(axis=0),
        "count": np.array([len(x)], dtype=np.int64),
    }
    for key, q in QUANTILES.items():
        stats[key] = np.quantile(x, q, axis=0)
    return {k: stats[k] for k in STAT_KEYS}


def all_stats(columns: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    return {name: feature_stats(columns[name]) for name in feature_names()}


def _stats_json(stats: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, list[Any]]]:
    return {name: {k: v.tolist() for k, v in s.items()} for name, s in stats.items()}


# ---- the dataset on disk ---------------------------------------------------------------------------------------
def _next_file(chunk: int, file: int) -> tuple[int, int]:
    """LeRobot's ``update_chunk_file_indices``: the file after ``(chunk, file)``."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


def _vector_array(values: np.ndarray, item: pa.DataType) -> pa.FixedSizeListArray:
    flat = pa.array(np.ascontiguousarray(values, dtype=item.to_pandas_dtype()).ravel(), type=item)
    return pa.FixedSizeListArray.from_arrays(flat, values.shape[1])


def data_schema(joints: int) -> pa.Schema:
    """The data files' columns: what ``datasets`` makes of the features (a vector of shape (n,) is a fixed-size
    list of n, a shape (1,) feature a plain value; lerobot/datasets/feature_utils.get_hf_features_from_features)."""
    vector = pa.list_(pa.float32(), joints)
    types = {ACTION: vector, STATE: vector, SOURCE: pa.list_(pa.int64(), joints), "timestamp": pa.float32()}
    types.update({name: pa.int64() for name in INDEX_FEATURES})
    return pa.schema([pa.field(name, types[name]) for name in feature_names()])


def _data_table(columns: dict[str, np.ndarray], schema: pa.Schema) -> pa.Table:
    arrays = [
        _vector_array(columns[f.name], f.type.value_type)
        if pa.types.is_fixed_size_list(f.type)
        else pa.array(columns[f.name], f.type)
        for f in schema
    ]
    return pa.Table.from_arrays(arrays, schema=schema)


def _tasks_table(tasks: Sequence[str]) -> pa.Table:
    """``meta/tasks.parquet`` as pandas writes LeRobot's ``DataFrame({"task_index": …}, index=Index(tasks,
    name="task"))``: LeRobot reads it with ``pd.read_parquet`` and looks tasks up by that index, so the schema
    carries pandas' metadata naming ``task`` the index (pandas 2's form, which pandas 3 reads too)."""
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    schema = pa.schema(
        [pa.field("task_index", pa.int64()), pa.field("task", pa.string())],
        metadata={b"pandas": json.dumps(pandas_meta).encode()},
    )
    return pa.Table.from_arrays(
        [pa.array(range(len(tasks)), pa.int64()), pa.array(list(tasks), pa.string())], schema=schema
    )


def _parquet_bytes(write: Any) -> bytes:
    sink = pa.BufferOutputStream()
    write(sink)
    return sink.getvalue().to_pybytes()


def _write_table(path: Path, table: pa.Table) -> None:
    write_new(path, _parquet_bytes(lambda sink: pq.write_table(table, sink, compression="snappy")))


def _write_data_file(path: Path, episodes: list[pa.Table]) -> None:
    """One row group per episode, as LeRobot writes them (``read_row_group(i)`` is one episode)."""

    def write(sink: Any) -> None:
        with pq.ParquetWriter(sink, episodes[0].schema, compression="snappy") as writer:
            for table in episodes:
                writer.write_table(table)

    write_new(path, _parquet_bytes(write))


@dataclass
class Existing:
    """What an append needs from the dataset already at ``out``."""

    info: dict[str, Any]
    tasks: list[str]  # by task_index
    episodes: pa.Table  # the episodes' index columns (no stats)
    frames: dict[str, np.ndarray]  # every frame's values, for the dataset's statistics

    @property
    def total_episodes(self) -> int:
        return int(self.info["total_episodes"])

    @property
    def total_frames(self) -> int:
        return int(self.info["total_frames"])

    def last(self, prefix: str) -> tuple[int, int] | None:
        """The newest ``(chunk, file)`` of ``data`` or ``meta/episodes`` the episodes name."""
        if self.episodes.num_rows == 0:
            return None
        chunks = self.episodes.column(f"{prefix}/chunk_index").to_pylist()
        files = self.episodes.column(f"{prefix}/file_index").to_pylist()
        return max(zip(chunks, files, strict=True))


_INDEX_COLUMNS = (
    "episode_index",
    "data/chunk_index",
    "data/file_index",
    "dataset_from_index",
    "dataset_to_index",
    "meta/episodes/chunk_index",
    "meta/episodes/file_index",
)


def read_existing(out: Path, joints: Sequence[str], fps: int) -> Existing | None:
    """The dataset at ``out`` if there is one; refuses one an append would not fit (other features, another fps,
    files that disagree with its index)."""
    info_path = out / INFO_PATH
    if not info_path.exists():
        if out.exists() and any(out.iterdir()):
            raise RecordError(f"{out} is not empty and holds no {INFO_PATH}: not a LeRobot dataset, not touching it")
        return None
    info = json.loads(info_path.read_text())
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise RecordError(f"{out} is a LeRobot {info.get('codebase_version')} dataset; hild appends to v3.0 only")
    if info.get("fps") != fps:
        raise RecordError(f"{out} is at {info.get('fps')} fps; exporting at {fps} fps would mix rates (use --fps)")
    want = features(joints)
    have = {k: {**v, "shape": list(v["shape"])} for k, v in info.get("features", {}).items()}
    if have != want:
        raise RecordError(
            f"{out} has other features than this export (joints {list(joints)}): export to a new directory"
        )
    tasks_table = pq.read_table(out / TASKS_PATH, columns=["task", "task_index"])
    order = np.argsort(tasks_table.column("task_index").to_numpy())
    tasks = [tasks_table.column("task").to_pylist()[i] for i in order]
    episode_files = sorted((out / "meta" / "episodes").glob("*/*.parquet"))
    episodes = pa.concat_tables([pq.read_table(p, columns=list(_INDEX_COLUMNS)) for p in episode_files])
    data_files = sorted((out / "data").glob("*/*.parquet"))
    frames = _read_frames(data_files, len(joints))
    named = {
        DATA_PATH.format(chunk_index=c, file_index=f)
        for c, f in zip(
            episodes.column("data/chunk_index").to_pylist(), episodes.column("data/file_index").to_pylist(), strict=True
        )
    }
    on_disk = {str(p.relative_to(out)) for p in data_files}
    consistent = (
        episodes.column("episode_index").to_pylist() == list(range(int(info["total_episodes"])))
        and (episodes.num_rows == 0 or episodes.column("dataset_to_index").to_pylist()[-1] == info["total_frames"])
        and len(frames["index"]) == info["total_frames"]
        and named == on_disk
        and len(tasks) == info.get("total_tasks")
    )
    if not consistent:
        raise RecordError(f"{out}: its index, its data files and info.json disagree; not appending to it")
    return Existing(info, tasks, episodes, frames)


def _read_frames(paths: Sequence[Path], joints: int) -> dict[str, np.ndarray]:
    parts: dict[str, list[np.ndarray]] = {name: [] for name in feature_names()}
    for path in paths:
        table = pq.read_table(path, columns=list(feature_names()))
        for name in feature_names():
            parts[name].append(_column(table, name, joints))
    empty = {
        ACTION: np.zeros((0, joints), np.float32),
        STATE: np.zeros((0, joints), np.float32),
        SOURCE: np.zeros((0, joints), np.int64),
    }
    return {
        name: np.concatenate(chunks) if chunks else empty.get(name, np.zeros(0, np.int64))
        for name, chunks in parts.items()
    }


# ---- export --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ExportedEpisode:
    id: str
    episode_index: int
    frames: int
    duration: float  # s between the episode's first and last cycle


@dataclass
class ExportReport:
    out: Path
    fps: int
    episodes: list[ExportedEpisode] = field(default_factory=list)
    total_episodes: int = 0
    total_frames: int = 0
    files: list[Path] = field(default_factory=list)  # the data and episode files this export added


def resolve_fps(episodes: Sequence[Episode], fps: float | None) -> int:
    """The export's frame rate: ``fps``, else the episodes' own (recorded at start), which must agree. LeRobot's
    ``info.json`` declares an integer rate (``DatasetInfo.fps: int``), so a fractional one is refused."""
    if fps is None:
        rates = sorted({float(e.meta.fps) for e in episodes})
        if len(rates) != 1:
            raise RecordError(f"the episodes were recorded for different frame rates {rates}: choose one with --fps")
        fps = rates[0]
    if not math.isfinite(fps) or fps <= 0:
        raise RecordError(f"fps must be a positive number; found {fps}")
    if abs(fps - round(fps)) > 1e-9:
        raise RecordError(f"LeRobot datasets have a whole number of frames per second; found {fps:g}")
    return round(fps)


def export_lerobot(
    episodes: Sequence[Episode],
    out: Path,
    fps: float | None = None,
    *,
    default_task: str = DEFAULT_TASK,
    robot_type: str | None = None,
    sources: Collection[int] | None = None,
) -> ExportReport:
    """Add ``episodes`` to the LeRobotDataset v3.0 at ``out`` (created if absent), resampled to ``fps`` (default:
    the episodes' own). ``sources``: keep only the frames every joint of which one of these moved (``runs_from``).
    The dataset's files are replaced at once: on any failure the previous dataset stays."""
    if not episodes:
        raise RecordError("no episodes to export")
    out = Path(out).absolute()
    joints = list(episodes[0].meta.joints)
    for e in episodes[1:]:
        if list(e.meta.joints) != joints:
            raise RecordError(f"episode {e.meta.id} has joints {e.meta.joints}, {episodes[0].meta.id} has {joints}")
    rate = resolve_fps(episodes, fps)
    existing = read_existing(out, joints, rate)
    tasks = list(existing.tasks) if existing else []
    episode_index = existing.total_episodes if existing else 0
    frame_index = existing.total_frames if existing else 0
    schema = data_schema(len(joints))

    report = ExportReport(out, rate)
    new_tables: list[pa.Table] = []
    episode_rows: list[dict[str, Any]] = []
    pieces = [(e, f) for e in episodes for f in _pieces(resample(e, rate, default_task), sources, rate)]
    if not pieces:
        raise RecordError(f"no frame of these episodes was moved only by the sources {sorted(sources or ())}")
    for episode, frames in pieces:
        for task in frames.tasks:
            if task not in tasks:
                tasks.append(task)
        n = len(frames)
        columns = dict(frames.columns)
        columns["episode_index"] = np.full(n, episode_index, dtype=np.int64)
        columns["index"] = np.arange(frame_index, frame_index + n, dtype=np.int64)
        columns["task_index"] = np.array([tasks.index(t) for t in frames.tasks], dtype=np.int64)
        new_tables.append(_data_table(columns, schema))
        episode_rows.append(
            {
                "episode_index": episode_index,
                "tasks": list(dict.fromkeys(frames.tasks)),
                "length": n,
                "dataset_from_index": frame_index,
                "dataset_to_index": frame_index + n,
                "stats": all_stats(columns),
            }
        )
        first, last = (0, -1) if sources is None else (frames.rows[0], frames.rows[-1])  # a run: its own span
        duration = float(episode.rows.t[last] - episode.rows.t[first])
        report.episodes.append(ExportedEpisode(episode.meta.id, episode_index, n, duration))
        episode_index += 1
        frame_index += n

    # where the new files go: after the newest the dataset has (LeRobot starts a new file when it resumes)
    last_data = existing.last("data") if existing else None
    data_at = _next_file(*last_data) if last_data else (0, 0)
    last_meta = existing.last("meta/episodes") if existing else None
    meta_at = _next_file(*last_meta) if last_meta else (0, 0)

    data_files: dict[tuple[int, int], list[pa.Table]] = {}
    size = 0
    limit = existing.info.get("data_files_size_in_mb", DATA_FILES_SIZE_IN_MB) if existing else DATA_FILES_SIZE_IN_MB
    for table, row in zip(new_tables, episode_rows, strict=True):
        if size and size + table.nbytes >= limit * 1024**2:
            data_at, size = _next_file(*data_at), 0
        data_files.setdefault(data_at, []).append(table)
        size += table.nbytes
        row["data/chunk_index"], row["data/file_index"] = data_at
        row["meta/episodes/chunk_index"], row["meta/episodes/file_index"] = meta_at

    # the dataset's statistics over every frame, old and new
    new_columns = {
        name: np.concatenate([_column(t, name, len(joints)) for t in new_tables]) for name in feature_names()
    }
    if existing:
        every = {name: np.concatenate([existing.frames[name], new_columns[name]]) for name in feature_names()}
    else:
        every = new_columns
    info = dict(existing.info) if existing else _new_info(rate, joints, robot_type)
    info["total_episodes"] = episode_index
    info["total_frames"] = frame_index
    info["total_tasks"] = len(tasks)
    info["splits"] = {"train": f"0:{episode_index}"}

    stage = staging_dir(out)
    try:
        if existing:
            link_tree(out, stage)
        for (chunk, file), tables in data_files.items():
            path = stage / DATA_PATH.format(chunk_index=chunk, file_index=file)
            _write_data_file(path, tables)
            report.files.append(out / path.relative_to(stage))
        meta_path = stage / EPISODES_PATH.format(chunk_index=meta_at[0], file_index=meta_at[1])
        _write_table(meta_path, _episodes_table(episode_rows))
        report.files.append(out / meta_path.relative_to(stage))
        _write_table(stage / TASKS_PATH, _tasks_table(tasks))
        write_new(stage / STATS_PATH, json.dumps(_stats_json(all_stats(every)), indent=4).encode())
        write_new(stage / INFO_PATH, json.dumps(info, indent=4).encode())
        replace_tree(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    report.total_episodes, report.total_frames = episode_index, frame_index
    return report


def _pieces(frames: EpisodeFrames, sources: Collection[int] | None, fps: float) -> list[EpisodeFrames]:
    return [frames] if sources is None else runs_from(frames, sources, fps)


def _column(table: pa.Table, name: str, joints: int) -> np.ndarray:
    column = table.column(name).combine_chunks()
    if name in (ACTION, STATE, SOURCE):
        return column.flatten().to_numpy(zero_copy_only=False).reshape(-1, joints)
    return column.to_numpy(zero_copy_only=False)


def _new_info(fps: int, joints: Sequence[str], robot_type: str | None) -> dict[str, Any]:
    """``info.json`` of a new dataset, keys as LeRobot's ``create_empty_dataset_info`` writes them."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": 0,
        "total_frames": 0,
        "total_tasks": 0,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": fps,
        "splits": {},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features(joints),
    }


def _episodes_table(rows: list[dict[str, Any]]) -> pa.Table:
    """``meta/episodes`` rows with the columns LeRobot's ``save_episode`` writes, in its order: the episode, where
    its frames are, ``stats/<feature>/<stat>`` (lists: float64, ``count`` int64), where this row is."""
    columns: dict[str, pa.Array] = {
        "episode_index": pa.array([r["episode_index"] for r in rows], pa.int64()),
        "tasks": pa.array([r["tasks"] for r in rows], pa.list_(pa.string())),
        "length": pa.array([r["length"] for r in rows], pa.int64()),
    }
    for name in ("data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index"):
        columns[name] = pa.array([r[name] for r in rows], pa.int64())
    for feature in feature_names():
        for key in STAT_KEYS:
            kind = pa.int64() if key == "count" else pa.float64()
            columns[f"stats/{feature}/{key}"] = pa.array(
                [r["stats"][feature][key].tolist() for r in rows], pa.list_(kind)
            )
    for name in ("meta/episodes/chunk_index", "meta/episodes/file_index"):
        columns[name] = pa.array([r[name] for r in rows], pa.int64())
    return pa.table(columns)
