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
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from hild import __version__ as hild_version
from hild.api.ros2.types import type_hash
from hild.crossing.cyclelog import CycleRows
from hild.record import topics
from hild.record.bag_metadata import TopicCount, bag_metadata, dump, metadata_yaml
from hild.record.model import (
    EPISODE_JSON,
    ROSBAG_METADATA,
    Episode,
    EpisodeMeta,
    RecordedEvent,
    RecordError,
    mcap_name,
)

MCAP_VERSION = version("mcap")
LIBRARY = f"hild/{hild_version} mcap-python/{MCAP_VERSION}"
# The mcap Writer ends a chunk by itself once it grows past ``chunk_size``, which could split a row between two
# chunks; hild ends every chunk itself, at a row boundary, with ``Writer.flush()`` (public since mcap 1.5: "finishes
# the chunk in progress … and flushes the stream"), so the Writer's own threshold is set out of reach.
_NEVER = 2**62
AUTO_CHUNK_BYTES = 8 << 20  # a caller that never ends a chunk still gets one per 8 MiB of messages (memory bound)
BLACKBOX_CHUNK_SECONDS = 0.1  # a black box is written at once; its chunks span this much cycle time
RECOVERING_SUFFIX = ".recovering"


def _fsync_dir(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_atomic(path: Path, text: str, fsync: bool = True) -> None:
    """``text`` to ``path`` whole or not at all: beside, flushed (and fsync'ed), renamed over."""
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w") as out:
        out.write(text)
        out.flush()
        if fsync:
            os.fsync(out.fileno())
    os.replace(tmp, path)
    if fsync:
        _fsync_dir(path.parent)


class _McapOut:
    """One MCAP being written: hild's topics (registered on first use), counts and times for rosbag2's metadata."""

    def __init__(self, stream: BinaryIO, joints: tuple[str, ...], metadata: dict[str, dict[str, str]]) -> None:
        self.joints = joints
        self._writer = Writer(stream, chunk_size=_NEVER, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=LIBRARY)
        for name, data in metadata.items():
            self._writer.add_metadata(name, data)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.pending = 0  # message bytes in the chunk in progress
        for topic, type_name in topics.TOPIC_TYPES.items():
            self.channel(topic, type_name)

    def channel(self, topic: str, type_name: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if self.types[topic] != type_name:
                raise ValueError(f"{topic} is a {self.types[topic]}, not a {type_name}")
            return known
        schema = self._schemas.get(type_name)
        if schema is None:
            schema = self._schemas[type_name] = self._writer.register_schema(
                type_name, "ros2msg", topics.schema_text(type_name)
            )
        self._channels[topic] = self._writer.register_channel(
            topic, "cdr", schema, dict(topics.channel_metadata(type_name))
        )
        self.types[topic], self.counts[topic] = type_name, 0
        return self._channels[topic]

    def add(self, channel: int, topic: str, log_ns: int, data: bytes, publish_ns: int | None = None) -> None:
        """One message; log time = publish time = the header stamp (rosbag2 writes sequence 0, so does hild)."""
        self._writer.add_message(channel, log_ns, data, log_ns if publish_ns is None else publish_ns)
        self._count(topic, 1, log_ns, log_ns, len(data))

    def _count(self, topic: str, messages: int, first_ns: int, last_ns: int, size: int) -> None:
        self.counts[topic] += messages
        self.first_ns = first_ns if self.first_ns is None else min(self.first_ns, first_ns)
        self.last_ns = last_ns if self.last_ns is None else max(self.last_ns, last_ns)
        self.pending += size

    def write_rows(self, rows: CycleRows, controller_codes: dict[int, str]) -> None:
        """Every topic for every row, row after row (a row's messages are never split between chunks)."""
        encoded = topics.encode_rows(rows, self.joints, controller_codes)
        add = self._writer.add_message
        states = self._channels[topics.JOINT_STATES]
        command = self._channels[topics.COMMAND]
        cycle = self._channels[topics.CYCLE]
        log_times = encoded.log_times.tolist()
        per_row: list[list[tuple[int, bytes]]] = [[] for _ in range(len(rows))]
        for topic, (which, messages) in encoded.controllers.items():
            channel = self.channel(topic, topics.JOINT_STATE)
            for i, data in zip(which.tolist(), messages, strict=True):
                per_row[i].append((channel, data))
            self._count(topic, len(which), log_times[which[0]], log_times[which[-1]], len(messages[0]) * len(which))
        for i, ns in enumerate(log_times):
            add(states, ns, encoded.joint_states[i], ns)
            add(command, ns, encoded.command[i], ns)
            for channel, data in per_row[i]:
                add(channel, ns, data, ns)
            add(cycle, ns, encoded.cycle[i], ns)
        first, last = min(log_times), max(log_times)
        for topic, messages in ((topics.JOINT_STATES, encoded.joint_states), (topics.COMMAND, encoded.command)):
            self._count(topic, len(messages), first, last, len(messages[0]) * len(messages))
        self._count(topics.CYCLE, len(encoded.cycle), first, last, len(encoded.cycle[0]) * len(encoded.cycle))

    def write_event(self, event: RecordedEvent) -> None:
        ns = topics.wall_ns(event.wall)
        self.add(self._channels[topics.EVENTS], topics.EVENTS, ns, topics.encode_event(event))

    def end_chunk(self) -> None:
        self._writer.flush()
        self.pending = 0

    def topic_counts(self) -> list[TopicCount]:
        return [TopicCount(t, self.types[t], type_hash(self.types[t]), n) for t, n in self.counts.items()]

    def finish(self, file_name: str) -> dict:
        """The summary written; rosbag2's metadata returned (and stored in the file, as rosbag2 does)."""
        self._writer.flush()
        information = bag_metadata(file_name, self.topic_counts(), self.first_ns or 0, self.last_ns or 0)
        self._writer.add_metadata("rosbag2", {"serialized_metadata": dump(information)})
        self._writer.finish()
        return information


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
        _write_atomic(self.directory / EPISODE_JSON, meta.to_json(), fsync)
        self._file = self.path.open("xb")
        self._out = _McapOut(self._file, tuple(meta.joints), {"hild": {"episode": meta.to_json()}})
        self._codes = dict(meta.controller_codes)
        self.cycles = 0
        self.first_tick: int | None = None
        self.last_tick: int | None = None
        self.last_wall: float | None = None
        self.closed = False
        self._sync()
        if fsync:
            _fsync_dir(self.directory)

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
        _write_atomic(self.directory / ROSBAG_METADATA, metadata_yaml(information), self.fsync)
        meta = self.meta
        meta.state, meta.cycles, meta.controller_codes = state, self.cycles, dict(self._codes)
        if dropped is not None:
            meta.dropped = dropped
        if self.last_tick is not None:
            meta.stop_tick, meta.stopped_wall = self.last_tick, self.last_wall
        _write_atomic(self.directory / EPISODE_JSON, meta.to_json(), self.fsync)
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


@dataclass
class _Scan:
    """What a sequential read of an MCAP found, up to the end or the first damage."""

    size: int = 0
    intact: int = 0  # bytes from the start through the last record read whole
    chunks: int = 0
    complete: bool = False  # the footer was read: the file was closed
    damage: str | None = None  # why reading stopped before the end
    channels: dict[int, tuple[str, str]] = field(default_factory=dict)  # id → (topic, type)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def lost_bytes(self) -> int:
        return self.size - self.intact


def _scan(path: Path, scan: _Scan) -> Iterator[list[tuple[str, str, Message]]]:
    """Each whole chunk's messages as (topic, type, message), in file order, with the ``mcap`` stream reader;
    stops quietly at the first record that cannot be read whole (a cut, a bad checksum): ``scan`` says where."""
    schemas: dict[int, str] = {}
    if not path.exists():
        scan.damage = "missing"
        return
    with path.open("rb") as stream:
        scan.size = os.fstat(stream.fileno()).st_size
        records = StreamReader(stream, emit_chunks=True, validate_crcs=True).records
        while True:
            try:  # a damaged record raises whatever its parser meets: EndOfFile, a CRC or zstd error, garbage
                record = next(records)
                inner = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
            except StopIteration:
                return
            except Exception as exc:
                scan.damage = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                return
            scan.intact = stream.tell()
            messages = []
            for item in inner:
                if isinstance(item, Schema):
                    schemas[item.id] = item.name
                elif isinstance(item, Channel):
                    scan.channels[item.id] = (item.topic, schemas.get(item.schema_id, ""))
                elif isinstance(item, Message) and item.channel_id in scan.channels:
                    topic, type_name = scan.channels[item.channel_id]
                    messages.append((topic, type_name, item))
            if isinstance(record, Metadata):
                scan.metadata[record.name] = dict(record.metadata)
            elif isinstance(record, Footer):
                scan.complete = True
            if isinstance(record, Chunk):
                scan.chunks += 1
            if messages:
                yield messages


class _Rows:
    """Rows put together from their messages in file order: a row is whole once its /joint_states,
    /hild/command and /hild/cycle messages are all in (each topic's i-th message is the i-th row)."""

    def __init__(self) -> None:
        self.raw: dict[str, list[bytes]] = {topics.JOINT_STATES: [], topics.COMMAND: [], topics.CYCLE: []}
        self.parts: list[CycleRows] = []
        self.names: tuple[str, ...] | None = None

    def add(self, topic: str, data: bytes) -> None:
        if topic in self.raw:
            self.raw[topic].append(data)

    def take(self) -> None:
        whole = min(len(v) for v in self.raw.values())
        if not whole:
            return
        batch = {topic: messages[:whole] for topic, messages in self.raw.items()}
        for messages in self.raw.values():
            del messages[:whole]
        states = topics.decode_joint_states(batch[topics.JOINT_STATES])
        command = topics.decode_joint_states(batch[topics.COMMAND])
        assert states is not None and command is not None
        if command.names != states.names or (self.names is not None and self.names != states.names):
            raise ValueError(f"the joints change within the file: {self.names} vs {states.names}/{command.names}")
        self.names = states.names
        cycle = topics.decode_cycles(batch[topics.CYCLE], len(states.names))
        stamps = topics.stamps_ns(cycle["wall"])
        if not (np.array_equal(stamps, states.stamps) and np.array_equal(stamps, command.stamps)):
            raise ValueError("/joint_states, /hild/command and /hild/cycle are out of step: not a hild recording")
        self.parts.append(
            CycleRows(
                **{name: cycle[name] for name in (*topics.SCALARS, *topics.PER_JOINT)},
                measured_position=states.position,
                measured_velocity=states.velocity,
                measured_effort=states.effort,
                position=command.position,
                velocity=command.velocity,
                effort=command.effort,
            )
        )

    @property
    def torn(self) -> int:
        """Messages of rows that never became whole (none in a file hild wrote: its chunks hold whole rows)."""
        return sum(len(v) for v in self.raw.values())


@dataclass(frozen=True)
class McapContents:
    rows: CycleRows
    events: list[RecordedEvent]
    joints: tuple[str, ...]
    scan: _Scan
    torn: int


def read_mcap(path: Path, joints: int | None = None) -> McapContents:
    """Rows and events of an MCAP hild wrote (an episode's or a black box's), up to any damage."""
    scan, rows, events = _Scan(), _Rows(), []
    for messages in _scan(path, scan):
        for topic, _, msg in messages:
            if topic == topics.EVENTS:
                events += topics.decode_events(msg.data)
            else:
                rows.add(topic, msg.data)
        rows.take()
    names = rows.names or ()
    width = len(names) if rows.names is not None else (joints or 0)
    return McapContents(CycleRows.concat(rows.parts, width), events, names, scan, rows.torn)


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
    scan = _Scan()
    last_cycle: bytes | None = None
    with tmp.open("wb") as stream:
        out = _McapOut(stream, tuple(meta.joints), {"hild": {"episode": meta.to_json()}})
        for messages in _scan(path, scan):
            for topic, type_name, msg in messages:
                out.add(out.channel(topic, type_name), topic, msg.log_time, msg.data, msg.publish_time)
                if topic == topics.CYCLE:
                    last_cycle = msg.data
            out.end_chunk()
        information = out.finish(path.name)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(tmp, path)
    _fsync_dir(directory)
    _write_atomic(directory / ROSBAG_METADATA, metadata_yaml(information))
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
    _write_atomic(directory / EPISODE_JSON, meta.to_json())
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
        out = _McapOut(stream, joints, {"hild": {"blackbox": json.dumps(info, sort_keys=True)}})
        for part in _time_slices(rows.t, BLACKBOX_CHUNK_SECONDS):
            out.write_rows(rows.select(part), codes)
            out.end_chunk()
        for event in events:
            out.write_event(event)
        out.finish(path.name)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(tmp, path)
    _write_atomic(path.with_suffix(".json"), json.dumps(info, indent=2, sort_keys=True))
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
