"""What an episode is on disk, independent of how its files are written (docs/recording.md, "Files").

An episode is a rosbag2 bag directory ``<recording.dir>/<episode id>/``: ``<episode id>_0.mcap`` (every cycle and
event, ROS 2 message encoding), rosbag2's ``metadata.yaml`` (written when the episode is closed or recovered) and
hild's own ``episode.json`` (``EpisodeMeta``: written at start, rewritten at stop or recovery).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hild.crossing.cyclelog import CycleRows

EPISODE_JSON = "episode.json"
ROSBAG_METADATA = "metadata.yaml"
BLACKBOX_DIR = "blackbox"  # under recording.dir: the flight recorder's files
STATES = ("recording", "complete", "recovered")  # an episode.json's state; a discarded episode's directory is removed


class RecordError(Exception):
    """A refusal or failure a client is told about in words (no episode open, recording disabled, disk full …)."""


def mcap_name(episode_id: str) -> str:
    """rosbag2's name for a bag's first (and, here, only) file."""
    return f"{episode_id}_0.mcap"


@dataclass
class EpisodeMeta:
    """hild's per-episode metadata (``episode.json``)."""

    id: str
    robot: str
    joints: list[str]
    state: str  # one of STATES
    task: str | None
    note: str | None  # the operator's note
    fps: float  # the dataset frame rate asked for at start (export resamples to it; --fps overrides)
    update_rate: float  # Hz: the cycle rate
    config_path: str
    config_sha256: str
    versions: dict[str, str]  # hild, python, mujoco, mcap, ... as recorded
    started_wall: float  # s since the epoch: the first cycle's wall time
    start_tick: int  # the first cycle recorded
    stopped_wall: float | None = None
    stop_tick: int | None = None  # the last cycle recorded (inclusive)
    cycles: int = 0  # rows written
    dropped: int = 0  # rows the recorder lost (reported, never silent)
    controller_codes: dict[int, str] = field(default_factory=dict)  # owner code → controller name
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        data = dataclasses.asdict(self)
        data["controller_codes"] = {str(k): v for k, v in self.controller_codes.items()}
        return json.dumps(data, indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> EpisodeMeta:
        data = json.loads(text)
        data["controller_codes"] = {int(k): v for k, v in data.get("controller_codes", {}).items()}
        return cls(**data)

    @classmethod
    def read(cls, directory: Path) -> EpisodeMeta:
        return cls.from_json((directory / EPISODE_JSON).read_text())


@dataclass(frozen=True)
class RecordedEvent:
    """One line of ``/hild/events``: a cycle event, a request, a parameter change or an episode/task marker."""

    wall: float  # s since the epoch
    t: float  # the cycle clock, s (NaN when the client domain stamped it and no cycle time was known)
    kind: str  # "event", "request", "params", "marker"
    data: dict[str, Any]  # JSON-safe


@dataclass(frozen=True)
class Episode:
    """An episode read back from its directory."""

    directory: Path
    meta: EpisodeMeta
    rows: CycleRows
    events: list[RecordedEvent]
