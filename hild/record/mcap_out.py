"""Writing one MCAP the way hild's episode and black-box files are written (docs/recording.md, "Files").

Profile ``ros2``; a ``ros2msg`` schema with the full definition text per type, a ``cdr`` channel per topic with
the metadata rosbag2 Jazzy's MCAP storage writes (``offered_qos_profiles``, ``topic_type_hash``); each message's
log time = publish time = its header stamp, sequence 0 (as rosbag2). Chunks are zstd-compressed and carry a CRC:
a cut or damaged chunk is recognised as such, never read as rows.
"""

from __future__ import annotations

import os
from importlib.metadata import version
from pathlib import Path
from typing import BinaryIO

from mcap.writer import CompressionType, Writer

from hild import __version__ as hild_version
from hild.api.ros2.types import type_hash
from hild.crossing.cyclelog import CycleRows
from hild.record import topics
from hild.record.bag_metadata import TopicCount, bag_metadata, dump
from hild.record.model import RecordedEvent

MCAP_VERSION = version("mcap")
LIBRARY = f"hild/{hild_version} mcap-python/{MCAP_VERSION}"
# The mcap Writer ends a chunk by itself once it grows past ``chunk_size``, which could split a row between two
# chunks; hild ends every chunk itself, at a row boundary, with ``Writer.flush()`` (public since mcap 1.5: "finishes
# the chunk in progress … and flushes the stream"), so the Writer's own threshold is set out of reach.
_NEVER = 2**62


def fsync_dir(directory: Path) -> None:
    """A directory's entries on disk (a file created or renamed survives a power cut only with this)."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, text: str, fsync: bool = True) -> None:
    """``text`` to ``path`` whole or not at all: beside, flushed (and fsync'ed), renamed over."""
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w") as out:
        out.write(text)
        out.flush()
        if fsync:
            os.fsync(out.fileno())
    os.replace(tmp, path)
    if fsync:
        fsync_dir(path.parent)


class McapOut:
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
        if not len(rows):
            return
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
