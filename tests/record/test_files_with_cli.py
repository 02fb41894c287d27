"""The files as the offline command meets them: ``hild record recover`` closes a cut episode through
``mcap_files.recover``, ``list`` sees it recovered, and ``export --lerobot`` reads it back from the MCAP."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hild.cli import main
from hild.record.cli import LIVE_SECONDS
from hild.record.mcap_files import recover
from hild.record.model import EPISODE_JSON, EpisodeMeta, RecordError, mcap_name
from tests.record.conftest import ROWS_PER_CHUNK, write_episode
from tests.record.rows import make_meta


def cut_episode(root: Path, whole_chunks: int) -> Path:
    """An episode as a power cut leaves it: its file ends mid-chunk, episode.json still says recording."""
    directory = write_episode(root / make_meta().id).directory
    path = directory / mcap_name(make_meta().id)
    data = path.read_bytes()
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    cut = chunks[whole_chunks].chunk_start_offset + chunks[whole_chunks].chunk_length // 2
    path.write_bytes(data[:cut])
    (directory / "metadata.yaml").unlink()
    meta = EpisodeMeta.read(directory)
    meta.state, meta.cycles, meta.stop_tick, meta.stopped_wall = "recording", 0, None, None
    (directory / EPISODE_JSON).write_text(meta.to_json())
    past = time.time() - 2 * LIVE_SECONDS  # not "maybe still recording"
    os.utime(path, (past, past))
    return directory


def test_recover_list_and_export_a_cut_episode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    directory = cut_episode(tmp_path / "recordings", whole_chunks=5)
    assert main(["record", "recover", str(tmp_path / "recordings"), "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)
    assert entry["report"]["cycles"] == 5 * ROWS_PER_CHUNK and entry["report"]["lost_bytes"] > 0
    assert main(["record", "list", str(tmp_path / "recordings"), "--json"]) == 0
    (listed,) = json.loads(capsys.readouterr().out)
    assert (listed["state"], listed["cycles"]) == ("recovered", 5 * ROWS_PER_CHUNK)
    assert main(["record", "export", "--lerobot", str(tmp_path / "dataset"), "--fps", "30", str(directory)]) == 0
    info = json.loads((tmp_path / "dataset" / "meta" / "info.json").read_text())
    duration = (5 * ROWS_PER_CHUNK - 1) / 1000.0
    assert info["total_episodes"] == 1 and abs(info["total_frames"] - (int(duration * 30) + 1)) <= 1


def test_recover_of_a_complete_episode_is_refused_in_words(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    directory = write_episode(tmp_path / "recordings" / make_meta().id).directory
    with pytest.raises(RecordError):
        recover(directory)
    assert main(["record", "recover", str(directory), "--force"]) == 1
    assert "complete: nothing to recover" in capsys.readouterr().err
