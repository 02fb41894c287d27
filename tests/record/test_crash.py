"""Crash-proof files: an episode cut at any byte (a power cut: the file as far as the disk had it) or left by a
killed process reads back as a prefix of its rows, whole chunks only, and ``recover`` closes it."""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import signal
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from hild.record import mcap_files, topics
from hild.record.mcap_files import EpisodeWriter, read_episode, recover
from hild.record.model import EPISODE_JSON, ROSBAG_METADATA, EpisodeMeta, RecordError, mcap_name
from tests.record.conftest import CHUNKS, ROWS_PER_CHUNK, Written, write_episode
from tests.record.rows import CODES, assert_rows_equal, make_meta, make_rows

NAME = mcap_name(make_meta().id)


@dataclass(frozen=True)
class Original:
    written: Written
    data: bytes
    chunk_ends: list[int]  # where each chunk record ends, in file order
    chunk_starts: list[int]

    def whole_chunks(self, cut: int) -> int:
        return sum(end <= cut for end in self.chunk_ends)


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> Original:
    written = write_episode(tmp_path_factory.mktemp("original") / make_meta().id)
    path = written.directory / NAME
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    starts = [c.chunk_start_offset for c in indexes]
    return Original(written, path.read_bytes(), [c.chunk_start_offset + c.chunk_length for c in indexes], starts)


def cut_copy(original: Original, cut: int, directory: Path, tail: bytes = b"") -> Path:
    """The episode as a power cut at byte ``cut`` leaves it: episode.json as written at start, no metadata.yaml."""
    directory.mkdir(parents=True)
    meta = EpisodeMeta.read(original.written.directory)
    meta.state, meta.cycles, meta.stop_tick, meta.stopped_wall, meta.dropped = "recording", 0, None, None, 0
    (directory / EPISODE_JSON).write_text(meta.to_json())
    (directory / NAME).write_bytes(original.data[:cut] + tail)
    return directory


def expect_prefix(original: Original, directory: Path, cut: int) -> int:
    """read_episode gives exactly the rows and events of the chunks wholly before ``cut``; their count."""
    whole = original.whole_chunks(cut)
    episode = read_episode(directory)
    assert_rows_equal(episode.rows, original.written.rows.select(slice(0, whole * ROWS_PER_CHUNK)))
    assert episode.events == original.written.events[:whole]
    return whole * ROWS_PER_CHUNK


def interesting_cuts(original: Original) -> list[int]:
    cuts = {0, 1, 7, 8, 9, 20, len(original.data) - 1}
    for start, end in zip(original.chunk_starts, original.chunk_ends, strict=True):
        cuts |= {start - 1, start, start + 1, (start + end) // 2, end - 1, end, end + 1}
    return sorted(c for c in cuts if 0 <= c < len(original.data))


def test_a_cut_at_any_interesting_byte_reads_as_the_whole_chunks_before_it(original: Original, tmp_path: Path) -> None:
    for cut in interesting_cuts(original):
        expect_prefix(original, cut_copy(original, cut, tmp_path / str(cut)), cut)


def test_garbage_after_the_cut_is_damage_too(original: Original, tmp_path: Path) -> None:
    cut = (original.chunk_starts[5] + original.chunk_ends[5]) // 2
    for name, tail in (("zeros", bytes(4096)), ("noise", os.urandom(4096))):
        expect_prefix(original, cut_copy(original, cut, tmp_path / name, tail), cut)


def test_a_flipped_byte_in_a_chunk_stops_reading_there(original: Original, tmp_path: Path) -> None:
    data = bytearray(original.data)
    data[original.chunk_ends[4] - 20] ^= 0x40  # inside chunk 4's compressed records
    directory = cut_copy(original, len(data), tmp_path / "flip")
    (directory / NAME).write_bytes(bytes(data))
    episode = read_episode(directory)
    assert_rows_equal(episode.rows, original.written.rows.select(slice(0, 4 * ROWS_PER_CHUNK)))
    report = recover(directory)
    assert report["cycles"] == 4 * ROWS_PER_CHUNK and report["damage"]


def check_recovered(original: Original, directory: Path, cut: int) -> None:
    rows = expect_prefix(original, directory, cut)
    report = recover(directory)
    assert report["changed"] and report["cycles"] == rows
    assert report["events"] == original.whole_chunks(cut)
    assert 0 <= report["lost_bytes"] <= cut - (original.chunk_ends[rows // ROWS_PER_CHUNK - 1] if rows else 0)
    meta = EpisodeMeta.read(directory)
    assert (meta.state, meta.cycles) == ("recovered", rows)
    if rows:
        assert meta.stop_tick == int(original.written.rows.tick[rows - 1]) == report["stop_tick"]
        assert meta.stopped_wall == float(original.written.rows.wall[rows - 1]) == report["last_wall"]
    with (directory / NAME).open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics.chunk_count == original.whole_chunks(cut)
    with Reader(directory) as reader:
        assert {c.topic: c.msgcount for c in reader.connections}[topics.CYCLE] == rows
    after = read_episode(directory)
    assert_rows_equal(after.rows, original.written.rows.select(slice(0, rows)))
    assert not list(directory.glob("*" + mcap_files.RECOVERING_SUFFIX)) and not list(directory.glob("*.tmp"))


def test_recover_closes_a_cut_episode_losing_at_most_the_chunk_it_cut(original: Original, tmp_path: Path) -> None:
    cuts = [c for i, c in enumerate(interesting_cuts(original)) if i % 3 == 0]
    for cut in cuts:
        check_recovered(original, cut_copy(original, cut, tmp_path / str(cut)), cut)


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_recover_after_a_cut_anywhere(original: Original, data: st.DataObject) -> None:
    cut = data.draw(st.integers(0, len(original.data)))
    with tempfile.TemporaryDirectory() as tmp:
        check_recovered(original, cut_copy(original, cut, Path(tmp) / "ep"), cut)


def digest(directory: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


def test_recover_twice_changes_nothing(original: Original, tmp_path: Path) -> None:
    directory = cut_copy(original, original.chunk_ends[7] + 3, tmp_path / "ep")
    first = recover(directory)
    files = digest(directory)
    second = recover(directory)
    assert second == {**first, "changed": False}
    assert digest(directory) == files


def test_a_crash_between_finishing_the_file_and_episode_json_recovers_everything(
    original: Original, tmp_path: Path
) -> None:
    directory = cut_copy(original, len(original.data), tmp_path / "ep")  # the MCAP finished, episode.json not yet
    report = recover(directory)
    assert (report["cycles"], report["lost_bytes"], report["damage"]) == (len(original.written.rows), 0, None)
    assert_rows_equal(read_episode(directory).rows, original.written.rows)


def test_recover_refuses_a_complete_episode(original: Original) -> None:
    before = digest(original.written.directory)
    with pytest.raises(RecordError, match="complete"):
        recover(original.written.directory)
    assert digest(original.written.directory) == before


def test_a_cut_inside_the_header_or_a_missing_file_recovers_as_an_empty_bag(original: Original, tmp_path: Path) -> None:
    for name, cut in (("header", 12), ("missing", None)):
        directory = cut_copy(original, cut or 0, tmp_path / name)
        if cut is None:
            (directory / NAME).unlink()
        report = recover(directory)
        assert (report["cycles"], report["events"], report["last_wall"]) == (0, 0, None)
        assert (directory / ROSBAG_METADATA).exists()
        with Reader(directory) as reader:
            assert reader.message_count == 0 and {c.topic for c in reader.connections} == set(topics.TOPIC_TYPES)


def test_a_file_left_open_at_a_chunk_end_loses_nothing(tmp_path: Path) -> None:
    rows = make_rows(3 * ROWS_PER_CHUNK)
    writer = EpisodeWriter(tmp_path / "ep", make_meta(), fsync=False)
    for c in range(3):
        writer.write_rows(rows.select(slice(c * ROWS_PER_CHUNK, (c + 1) * ROWS_PER_CHUNK)), CODES)
        writer.end_chunk()
    writer.abandon()  # as a killed process leaves it
    report = recover(tmp_path / "ep")
    assert (report["cycles"], report["lost_bytes"], report["damage"]) == (len(rows), 0, None)
    assert_rows_equal(read_episode(tmp_path / "ep").rows, rows)


def _record_until_killed(directory: str, ready: Any) -> None:
    """The recorder's loop: a chunk, fsync'ed, then tell the parent how many are on disk; forever."""
    rows = make_rows(ROWS_PER_CHUNK * 1000)
    writer = EpisodeWriter(Path(directory), make_meta(), fsync=True)
    for c in range(1000):
        writer.write_rows(rows.select(slice(c * ROWS_PER_CHUNK, (c + 1) * ROWS_PER_CHUNK)), CODES)
        writer.end_chunk()
        ready.send(c + 1)


def test_sigkill_while_recording_keeps_every_chunk_ended_before_it(tmp_path: Path) -> None:
    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe(duplex=False)
    process = context.Process(target=_record_until_killed, args=(str(tmp_path / "ep"), child))
    process.start()
    try:
        assert parent.poll(60), "the recording process never ended a chunk"
        done = 0
        while done < CHUNKS:
            done = parent.recv()
        os.kill(process.pid, signal.SIGKILL)
        process.join(10)
        while parent.poll():  # chunks it ended between our last read and the kill
            done = parent.recv()
    finally:
        if process.is_alive():
            process.kill()
            process.join()
    report = recover(tmp_path / "ep")
    assert done * ROWS_PER_CHUNK <= report["cycles"] <= (done + 1) * ROWS_PER_CHUNK
    assert_rows_equal(
        read_episode(tmp_path / "ep").rows, make_rows(ROWS_PER_CHUNK * 1000).select(slice(0, report["cycles"]))
    )
