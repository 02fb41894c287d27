"""A file outlet rotates without the rows' loop waiting on rerun.

Under load, rerun-sdk 0.41 was seen (py-spy) to block a rotating recorder for over a minute: in
``RecordingStream.flush(timeout_sec=1.0)`` past its timeout, and in the ``__del__`` of the temporary stream
``send_blueprint`` drops. These tests make every such call block, as it did, and check that ``maintain`` — called
by the recorder after every batch of rows — still returns at once, and that the rotation completes once rerun
does, with every row in exactly one file.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from hild.config.model import FileSinkSpec
from hild.telemetry import layout
from hild.telemetry.outlets import FileOutlet
from hild.telemetry.replay import load_scalars
from tests.helpers import wait_for

PATH = "/joints/position"
ROWS = 2000  # rows per batch: ~40 kB on disk, so a 0.05 MB file is full after two batches
STUCK_FOR = 10.0  # s a stuck rerun call blocks unless released (it was over 60 on the loaded machine)


class StuckRerun:
    """Makes rerun's waiting calls block until released, as they did on the loaded machine."""

    def __init__(self) -> None:
        self.released = threading.Event()
        self.blocked_on: set[str] = set()
        self.flush = rr.RecordingStream.flush
        self.drop = rr.RecordingStream.__del__

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        stuck = self

        def flush(rec: rr.RecordingStream, *, timeout_sec: float = 1e38) -> None:
            stuck.blocked_on.add(threading.current_thread().name)
            stuck.released.wait(STUCK_FOR)
            stuck.flush(rec, timeout_sec=timeout_sec)

        def drop(rec: rr.RecordingStream) -> None:
            stuck.blocked_on.add(threading.current_thread().name)
            stuck.released.wait(STUCK_FOR)
            stuck.drop(rec)

        monkeypatch.setattr(rr.RecordingStream, "flush", flush)
        monkeypatch.setattr(rr.RecordingStream, "__del__", drop)


@pytest.fixture
def stuck(monkeypatch: pytest.MonkeyPatch) -> Iterator[StuckRerun]:
    s = StuckRerun()
    yield s
    s.released.set()


def _on_open(rec: rr.RecordingStream) -> None:
    rec.log(PATH, rr.SeriesLines(names=["j"]), static=True)
    rec.send_blueprint(rr.blueprint.Blueprint(rr.blueprint.TimeSeriesView(origin="/joints")))


def _send(outlet: FileOutlet, start: int) -> None:
    ticks = np.arange(start, start + ROWS)
    outlet.rec.send_columns(
        PATH,
        indexes=[rr.TimeColumn(layout.TICK, sequence=ticks), rr.TimeColumn(layout.CYCLE_TIME, duration=ticks * 1e-3)],
        columns=rr.Scalars.columns(scalars=np.sin(ticks * 1e-3)),
    )


def _timed(call: object) -> float:
    start = time.monotonic()
    call()  # type: ignore[operator]
    return time.monotonic() - start


def test_maintain_never_waits_on_a_stuck_rerun_and_rotates_once_it_moves(
    tmp_path: Path, stuck: StuckRerun, monkeypatch: pytest.MonkeyPatch
) -> None:
    outlet = FileOutlet(FileSinkSpec(kind="file", path="arm.rrd", rotate_mb=0.05), tmp_path, "rec-1", "arm", _on_open)
    stuck.install(monkeypatch)
    sent = 0
    for _ in range(6):
        _send(outlet, sent)
        sent += ROWS
        assert _timed(outlet.maintain) < 0.5  # the old maintain flushed here and blocked for as long as rerun did
    wait_for(lambda: stuck.blocked_on, timeout=30)  # the rotation thread is what waits …
    assert "MainThread" not in stuck.blocked_on  # … never the rows' loop
    stuck.released.set()
    deadline = time.monotonic() + 30
    while len(outlet.files) < 2 and time.monotonic() < deadline:
        _send(outlet, sent)
        sent += ROWS
        outlet.maintain()
        time.sleep(0.05)
    outlet.close(timeout=30)
    assert len(outlet.files) >= 2
    ticks = np.concatenate([load_scalars(f, PATH).tick for f in outlet.files])
    assert sorted(ticks.tolist()) == list(range(sent))  # nothing lost or duplicated across rotations
    for f in outlet.files:  # every file stands alone
        assert load_scalars(f, PATH).names == ("j",)


def test_close_waits_for_a_rotation_under_way_and_keeps_its_file(tmp_path: Path) -> None:
    outlet = FileOutlet(FileSinkSpec(kind="file", path="arm.rrd", rotate_mb=0.05), tmp_path, "rec-2", "arm", _on_open)
    _send(outlet, 0)
    _send(outlet, ROWS)
    outlet.maintain()  # the check starts: the file is full, so a new one is opened …
    wait_for(lambda: len(list(tmp_path.glob("*.rrd"))) == 2, timeout=30)
    outlet.close(timeout=30)  # … but not yet adopted when close comes
    assert len(outlet.files) == 2
    assert all(f.exists() for f in outlet.files)
    assert sorted(np.concatenate([load_scalars(f, PATH).tick for f in outlet.files]).tolist()) == list(range(2 * ROWS))
