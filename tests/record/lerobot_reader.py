"""A LeRobotDataset v3.0 reader that makes every access LeRobot's own loader makes, without torch or ``datasets``.

``lerobot`` itself pulls torch, torchvision, diffusers and wandb (several GB), too heavy for this project's test
environment, so its loading path is mirrored here, step by step, from the source (huggingface/lerobot main, and the
0.4.4 release on PyPI where it differs), each step naming the function it mirrors:

- ``lerobot/datasets/io_utils.py``        load_info, load_stats (cast_stats_to_numpy), load_tasks, load_episodes,
                                         load_nested_dataset
- ``lerobot/datasets/utils.py``           DatasetInfo.from_dict / __post_init__, check_version_compatibility,
                                         DEFAULT_DATA_PATH / DEFAULT_EPISODES_PATH, update_chunk_file_indices
- ``lerobot/datasets/feature_utils.py``   get_hf_features_from_features (the arrow type ``datasets`` casts each
                                         data column to)
- ``lerobot/datasets/dataset_metadata.py`` LeRobotDatasetMetadata._load_metadata, get_data_file_path, get_task_index
- ``lerobot/datasets/dataset_reader.py``  DatasetReader._load_hf_dataset, _build_index_mapping, _get_query_indices,
                                         get_item (the task text from ``tasks.iloc[task_index].name``)
- ``lerobot/datasets/compute_stats.py``   _validate_stat_value (``count`` of shape (1,), every stat at least 1-D)
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import packaging.version
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

CODEBASE_VERSION = "v3.0"  # dataset_metadata.CODEBASE_VERSION


@dataclass
class DatasetInfo:
    """utils.DatasetInfo: the fields LeRobot knows (from_dict drops and warns about any other key)."""

    codebase_version: str
    fps: int
    features: dict[str, dict]
    total_episodes: int = 0
    total_frames: int = 0
    total_tasks: int = 0
    chunks_size: int = 1000
    data_files_size_in_mb: int = 100
    video_files_size_in_mb: int = 200
    data_path: str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    video_path: str | None = None
    robot_type: str | None = None
    splits: dict[str, str] | None = None
    tools: list[dict] | None = None

    def __post_init__(self) -> None:
        for ft in self.features.values():  # shapes become tuples
            if isinstance(ft.get("shape"), list):
                ft["shape"] = tuple(ft["shape"])
        for name in ("fps", "chunks_size", "data_files_size_in_mb", "video_files_size_in_mb"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive")


def hf_arrow_type(ft: dict[str, Any]) -> pa.DataType:
    """feature_utils.get_hf_features_from_features, as arrow types: shape (1,) → Value(dtype); (n,) →
    Sequence(length=n, Value(dtype)), which ``datasets`` stores as a fixed-size list."""
    value = pa.from_numpy_dtype(np.dtype(ft["dtype"]))
    if ft["shape"] == (1,):
        return value
    assert len(ft["shape"]) == 1, f"hild writes no image features: {ft}"
    return pa.list_(value, ft["shape"][0])


@dataclass
class Loaded:
    root: Path
    info: DatasetInfo
    tasks: pd.DataFrame
    episodes: pa.Table  # without stats/ columns, as load_episodes selects them
    episodes_with_stats: pa.Table
    stats: dict[str, dict[str, np.ndarray]]
    data: pa.Table  # every data file, in load_nested_dataset's order

    def episode(self, ep_idx: int) -> dict[str, Any]:
        """``meta.episodes[ep_idx]``: a row of the episodes dataset (``datasets`` indexes rows by position)."""
        return {name: self.episodes.column(name)[ep_idx].as_py() for name in self.episodes.column_names}

    def get_data_file_path(self, ep_idx: int) -> Path:
        ep = self.episode(ep_idx)
        return Path(self.info.data_path.format(chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"]))

    def get_task_index(self, task: str) -> int | None:
        """dataset_metadata.get_task_index."""
        return int(self.tasks.loc[task].task_index) if task in self.tasks.index else None

    def get_item(self, idx: int, delta: list[int] | None = None) -> dict[str, Any]:
        """dataset_reader.get_item over all episodes (no episode filter, so ``_absolute_to_relative_idx`` is None
        and absolute indices are row positions); ``delta``: frame offsets for ``observation.state``, as
        delta_timestamps would give them, clamped to the episode and padded (``_get_query_indices``)."""
        item = {name: self.data.column(name)[idx].as_py() for name in self.data.column_names}
        ep_idx, abs_idx = item["episode_index"], item["index"]
        if delta is not None:
            ep = self.episode(ep_idx)
            start, end = ep["dataset_from_index"], ep["dataset_to_index"]
            query = [max(start, min(end - 1, abs_idx + d)) for d in delta]
            item["observation.state"] = [self.data.column("observation.state")[q].as_py() for q in query]
            item["observation.state_is_pad"] = [(abs_idx + d < start) or (abs_idx + d >= end) for d in delta]
        item["task"] = self.tasks.iloc[item["task_index"]].name
        return item


def load(root: Path) -> Loaded:
    """LeRobotDatasetMetadata._load_metadata, then DatasetReader._load_hf_dataset."""
    raw = json.loads((root / "meta/info.json").read_text())  # io_utils.load_info
    known = {f.name for f in fields(DatasetInfo)}
    unknown = sorted(set(raw) - known)
    assert not unknown, f"LeRobot would warn about and drop {unknown}"
    info = DatasetInfo(**raw)
    # utils.check_version_compatibility against CODEBASE_VERSION: same major, minor not newer
    have, want = packaging.version.parse(info.codebase_version), packaging.version.parse(CODEBASE_VERSION)
    assert have.major == want.major and have.minor >= want.minor, info.codebase_version
    # io_utils.load_tasks: pandas, the task text as the index
    tasks = pd.read_parquet(root / "meta/tasks.parquet")
    tasks.index.name = "task"
    # io_utils.load_episodes → load_nested_dataset(meta/episodes): sorted */*.parquet, concatenated
    episode_paths = sorted((root / "meta/episodes").glob("*/*.parquet"))
    assert episode_paths, "load_nested_dataset raises FileNotFoundError on no parquet file"
    with_stats = pa.concat_tables([pq.read_table(p) for p in episode_paths])
    episodes = with_stats.select([n for n in with_stats.column_names if not n.startswith("stats/")])
    # io_utils.load_stats → cast_stats_to_numpy (np.atleast_1d of every value, flattened by "/")
    stats_raw = json.loads((root / "meta/stats.json").read_text())
    stats = {f: {k: np.atleast_1d(np.array(v)) for k, v in s.items()} for f, s in stats_raw.items()}
    for feature, s in stats.items():  # compute_stats._validate_stat_value
        for key, value in s.items():
            assert value.ndim >= 1, (feature, key)
            if key == "count":
                assert value.shape == (1,), (feature, value.shape)
    # dataset_reader._load_hf_dataset: load_nested_dataset(data, features=hf features): the columns must be exactly
    # the features (video ones aside) and cast to their types
    data_paths = sorted((root / "data").glob("*/*.parquet"))
    want_types = {k: hf_arrow_type(ft) for k, ft in info.features.items() if ft["dtype"] != "video"}
    tables = []
    for path in data_paths:
        table = pq.read_table(path)
        assert set(table.column_names) == set(want_types), (path, table.column_names)
        tables.append(table.select(list(want_types)).cast(pa.schema(want_types)))  # the cast datasets does
    data = pa.concat_tables(tables)
    return Loaded(root, info, tasks, episodes, with_stats, stats, data)
