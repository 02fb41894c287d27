"""Episodes and black boxes as MCAP with ROS 2 message encoding: writing in chunks, reading back, recovering.

An episode is a rosbag2 directory (``hild.record.model``): ``<id>_0.mcap`` written with the ``mcap`` library's
``Writer`` (profile ``ros2``, ``ros2msg`` schemas, ``cdr`` messages, channel metadata as rosbag2 Jazzy writes it),
``metadata.yaml`` once it is closed or recovered, and ``episode.json``. The recorder writes the rows it took every
``chunk_period`` and then ends the chunk (``EpisodeWriter.end_chunk``): a chunk is compressed and checksummed on
its own and always holds whole rows, so a file cut anywhere (a killed process, a power cut) keeps every chunk before
the cut. ``read_episode`` reads such a file up to the damage; ``recover`` rewrites it whole (docs/recording.md).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from hild.crossing.cyclelog import CycleRows
from hild.record import topics
from hild.record.bag_metadata import metadata_yaml
from hild.record.mcap_out import MCAP_VERSION, McapOut, fsync_dir, write_atomic
from hild.record.mcap_scan import Scan, read_mcap, scan_chunks
from hild.record.model import (
    EPISODE_JSON,
    ROSBAG_METADATA,
    Episode,
    EpisodeMeta,
    RecordedEvent,
    RecordError,
    mcap_name,
)

AUTO_CHUNK_BYTES = 8 << 20  # a caller that never ends a chunk still gets one per 8 MiB of messages (memory bound)
BLACKBOX_CHUNK_SECONDS = 0.1  # a black box is written at once; its chunks span this much cycle time
RECOVERING_SUFFIX = ".recovering"


class EpisodeWriter:
    """An episode being recorded: ``episode.json`` (state ``recording``) at once, then rows and events into the
    MCAP, a chunk ended (and, with ``fsync``, on disk) at each ``end_chunk``; ``close`` finishes it."""

    def __init__(self, directory: Path, meta: EpisodeMeta, *, fsync: bool = True) -> None:
        self.directory = Path(directory).absolute()
        self.meta = meta
        self.fsync = fsync
        self.path = self.directory / mcap_name(meta.id)
        self.directory.mkdir(parents=True, exist_ok=True)
        if (self.directory / EPISODE_JSON).exists() or self.path.exists():
            raise FileExistsError(f"{self.directory} already holds an episode")
        meta.state = "recording"
        meta.versions.setdefault("mcap", MCAP_VERSION)
        write_atomic(self.directory / EPISODE_JSON, meta.to_json(), fsync)
        self._file = self.path.open("xb")
        self._out = McapOut(self._file, tuple(meta.joints), {"hild": {"episode": meta.to_json()}})
        self._codes = dict(meta.controller_codes)
        self.cycles = 0
        self.first_tick: int | None = None
        self.last_tick: int | None = None
        self.last_wall: float | None = None
        self.closed = False
        self._sync()
        if fsync:
            fsync_dir(self.directory)

    def write_rows(self, rows: CycleRows, controller_codes: dict[int, str]) -> None:
        """Every topic of every row (``controller_codes``: the owner codes' names, as the Snapshot has them)."""
        self._check_open()
        if not len(rows):
            return
        self._codes.update(controller_codes)
        self._out.write_rows(rows, self._codes)
        self.cycles += len(rows)
        if self.first_tick is None:
            self.first_tick = int(rows.tick[0])
        self.last_tick, self.last_wall = int(rows.tick[-1]), float(rows.wall[-1])
        if self._out.pending > AUTO_CHUNK_BYTES:
            self.end_chunk()

    @property
    def messages(self) -> int:
        """Messages written so far, every topic."""
        return sum(self._out.counts.values())

    def write_event(self, event: RecordedEvent) -> None:
        self._check_open()
        self._out.write_event(event)

    def end_chunk(self) -> None:
        """End the chunk in progress now and flush the file (fsync'ed when asked): what is written survives a
        killed process (and, fsync'ed, a power cut) whole."""
        self._check_open()
        self._out.end_chunk()
        self._sync()

    def close(self, state: str = "complete", *, dropped: int | None = None) -> list[Path]:
        """Finish the MCAP (summary, indexes), write ``metadata.yaml`` and the final ``episode.json``; the paths
        written. ``dropped``: rows the recorder lost (kept in ``episode.json``)."""
        self._check_open()
        information = self._out.finish(self.path.name)
        self._sync()
        self._file.close()
        self.closed = True
        write_atomic(self.directory / ROSBAG_METADATA, metadata_yaml(information), self.fsync)
        meta = self.meta
        meta.state, meta.cycles, meta.controller_codes = state, self.cycles, dict(self._codes)
        if dropped is not None:
            meta.dropped = dropped
        if self.last_tick is not None:
            meta.stop_tick, meta.stopped_wall = self.last_tick, self.last_wall
        write_atomic(self.directory / EPISODE_JSON, meta.to_json(), self.fsync)
        return [self.path, self.directory / ROSBAG_METADATA, self.directory / EPISODE_JSON]

    def abandon(self) -> None:
        """Close the file as it is (a discarded episode: the caller removes the directory)."""
        if not self.closed:
            self._file.close()
            self.closed = True

    def _sync(self) -> None:
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def _check_open(self) -> None:
        if self.closed:
            raise RecordError(f"episode {self.meta.id} is closed")


def read_episode(directory: Path) -> Episode:
    """The episode in ``directory``: its metadata, every row (bit-exact) and event; a file that was never closed
    (or was cut) is read through its last whole chunk."""
    directory = Path(directory)
    meta = EpisodeMeta.read(directory)
    contents = read_mcap(directory / mcap_name(meta.id), len(meta.joints))
    if contents.joints and list(contents.joints) != list(meta.joints):
        raise ValueError(f"{directory}: the file's joints {contents.joints} are not episode.json's {meta.joints}")
    return Episode(directory, meta, contents.rows, contents.events)


def recover(directory: Path) -> dict:
    """Close an episode left ``recording`` (its process killed, the power cut): every whole chunk copied into a
    complete MCAP (written beside, fsync'ed, renamed over), ``metadata.yaml`` written, ``episode.json`` set
    ``recovered`` with the counts. What was recovered is returned (and kept in episode.json's ``extra``); a
    recovered episode answers that again and changes nothing; a complete one is refused."""
    directory = Path(directory).absolute()
    meta = EpisodeMeta.read(directory)
    if meta.state == "complete":
        raise RecordError(f"episode {meta.id} is complete: nothing to recover")
    if meta.state == "recovered":
        return {**meta.extra.get("recovery", {}), "changed": False}
    path = directory / mcap_name(meta.id)
    tmp = path.with_name(path.name + RECOVERING_SUFFIX)
    scan = Scan()
    last_cycle: bytes | None = None
    with tmp.open("wb") as stream:
        out = McapOut(stream, tuple(meta.joints), {"hild": {"episode": meta.to_json()}})
        for messages in scan_chunks(path, scan):
            for topic, type_name, msg in messages:
                out.add(out.channel(topic, type_name), topic, msg.log_time, msg.data, msg.publish_time)
                if topic == topics.CYCLE:
                    last_cycle = msg.data
            out.end_chunk()
        information = out.finish(path.name)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(tmp, path)
    fsync_dir(directory)
    write_atomic(directory / ROSBAG_METADATA, metadata_yaml(information))
    last = None if last_cycle is None else topics.decode_cycles([last_cycle], len(meta.joints))
    cycles = min(out.counts[t] for t in (topics.JOINT_STATES, topics.COMMAND, topics.CYCLE))
    report = {
        "id": meta.id,
        "directory": str(directory),
        "file": str(path),
        "cycles": cycles,
        "events": out.counts[topics.EVENTS],
        "chunks": scan.chunks,
        "lost_bytes": scan.lost_bytes,
        "last_wall": None if last is None else float(last["wall"][0]),
        "stop_tick": None if last is None else int(last["tick"][0]),
        "damage": scan.damage,
        "changed": True,
    }
    meta.state, meta.cycles = "recovered", cycles
    if last is not None:
        meta.stop_tick, meta.stopped_wall = report["stop_tick"], report["last_wall"]
    meta.extra["recovery"] = {k: v for k, v in report.items() if k != "changed"}
    write_atomic(directory / EPISODE_JSON, meta.to_json())
    return report


def write_blackbox(path: Path, rows: CycleRows, events: list[RecordedEvent], meta: dict) -> Path:
    """The flight recorder's file: ``rows`` and ``events`` as one MCAP (the episode's topics) at ``path``, written
    beside and renamed, and a ``.json`` beside it with ``meta`` (reason, robot, ``joints``, ``controller_codes``)
    and the time range and counts. ``meta["joints"]`` names the rows' joints."""
    path = Path(path).absolute()
    path.parent.mkdir(parents=True, exist_ok=True)
    joints = tuple(meta["joints"])
    codes = {int(k): str(v) for k, v in meta.get("controller_codes", {}).items()}
    info = {
        **meta,
        "controller_codes": {str(k): v for k, v in codes.items()},
        "file": path.name,
        "cycles": len(rows),
        "events": len(events),
        "first_tick": int(rows.tick[0]) if len(rows) else None,
        "last_tick": int(rows.tick[-1]) if len(rows) else None,
        "start_wall": float(rows.wall[0]) if len(rows) else None,
        "stop_wall": float(rows.wall[-1]) if len(rows) else None,
        "seconds": float(rows.wall[-1] - rows.wall[0]) if len(rows) else 0.0,
    }
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as stream:
        out = McapOut(stream, joints, {"hild": {"blackbox": json.dumps(info, sort_keys=True)}})
        for part in _time_slices(rows.t, BLACKBOX_CHUNK_SECONDS):
            out.write_rows(rows.select(part), codes)
            out.end_chunk()
        for event in events:
            out.write_event(event)
        out.finish(path.name)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(tmp, path)
    write_atomic(path.with_suffix(".json"), json.dumps(info, indent=2, sort_keys=True))
    return path


def _time_slices(t: np.ndarray, seconds: float) -> list[slice]:
    """Consecutive rows, each slice spanning at most ``seconds`` of cycle time from its first row."""
    out, start = [], 0
    while start < len(t):
        stop = int(np.searchsorted(t, t[start] + seconds, side="left"))
        stop = max(stop, start + 1)
        out.append(slice(start, stop))
        start = stop
    return out


def read_blackbox(path: Path) -> tuple[CycleRows, list[RecordedEvent], dict]:
    """A black box's rows, events and its ``.json``."""
    path = Path(path)
    info = json.loads(path.with_suffix(".json").read_text())
    contents = read_mcap(path, len(info.get("joints", ())))
    return contents.rows, contents.events, info
