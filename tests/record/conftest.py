"""An episode written the way the recorder writes one: rows in chunk-period batches, events between them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from hild.crossing.cyclelog import CycleRows
from hild.record.mcap_files import EpisodeWriter
from hild.record.model import RecordedEvent
from tests.record.rows import CODES, make_event, make_meta, make_rows

ROWS_PER_CHUNK = 50  # a 0.05 s chunk period at 1 kHz
CHUNKS = 12


@dataclass(frozen=True)
class Written:
    directory: Path
    rows: CycleRows
    events: list[RecordedEvent]
    paths: list[Path]


def write_episode(directory: Path, *, chunks: int = CHUNKS, rows_per_chunk: int = ROWS_PER_CHUNK) -> Written:
    rows = make_rows(chunks * rows_per_chunk)
    writer = EpisodeWriter(directory, make_meta(), fsync=False)
    events = []
    for c in range(chunks):
        part = rows.select(slice(c * rows_per_chunk, (c + 1) * rows_per_chunk))
        writer.write_rows(part, CODES)
        event = make_event(float(part.wall[-1]), kind="marker" if c % 4 == 0 else "event", chunk=c, text='x,\n"y"')
        writer.write_event(event)
        events.append(event)
        writer.end_chunk()
    paths = writer.close(dropped=3)
    return Written(directory, rows, events, paths)


@pytest.fixture
def episode(tmp_path: Path) -> Written:
    return write_episode(tmp_path / "recordings" / make_meta().id)
