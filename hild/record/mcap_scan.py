"""Reading one MCAP hild wrote, sequentially, up to its end or its first damage (docs/recording.md, "Files").

The ``mcap`` library's stream reader, not its seeking one: a file that was never closed has no summary to seek
with, and one cut by a power failure ends in a torn record. Chunk by chunk, each decompressed and its CRC checked,
until a record cannot be read whole; what was read is every chunk before the damage.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from hild.crossing.cyclelog import CycleRows
from hild.record import topics
from hild.record.model import RecordedEvent


@dataclass
class Scan:
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


def scan_chunks(path: Path, scan: Scan) -> Iterator[list[tuple[str, str, Message]]]:
    """Each whole chunk's messages as (topic, type, message), in file order, with the ``mcap`` stream reader;
    stops quietly at the first record that cannot be read whole (a cut, a bad checksum): ``scan`` says where."""
    schemas: dict[int, str] = {}
    if not path.exists():
        scan.damage = "missing"
        return
    with path.open("rb") as stream:
        scan.size = os.fstat(stream.fileno()).st_size
        # chunks whole (emit_chunks), each opened here with breakup_chunk — what the library's own readers call —
        # so that a chunk that fails its CRC or decompression is known as the damage, never half-read
        records = StreamReader(stream, emit_chunks=True, validate_crcs=True).records
        while True:
            try:  # a damaged record raises whatever its parser meets: EndOfFile, a CRC or zstd error, garbage
                record = next(records)
                inner = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
            except StopIteration:  # after the footer, the closing magic was read too
                scan.intact = stream.tell()
                return
            except EndOfFile:
                if scan.intact < scan.size:  # a record cut short (at the file's end, a file never closed: no damage)
                    scan.damage = "a record cut short by the end of the file"
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


class RowAssembler:
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
    scan: Scan
    torn: int


def read_mcap(path: Path, joints: int | None = None) -> McapContents:
    """Rows and events of an MCAP hild wrote (an episode's or a black box's), up to any damage."""
    scan, rows, events = Scan(), RowAssembler(), []
    for messages in scan_chunks(path, scan):
        for topic, _, msg in messages:
            if topic == topics.EVENTS:
                events += topics.decode_events(msg.data)
            else:
                rows.add(topic, msg.data)
        rows.take()
    names = rows.names or ()
    width = len(names) if rows.names is not None else (joints or 0)
    return McapContents(CycleRows.concat(rows.parts, width), events, names, scan, rows.torn)
