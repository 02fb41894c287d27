"""The measuring room's child processes: one that ignores its stop signal is killed; its log tail names it."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

from hild.bench.children import LoggedChild, wait_for

STUBBORN = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); time.sleep(60)"


def test_a_child_that_ignores_its_signal_is_killed_and_its_log_kept(tmp_path: Path) -> None:
    child = LoggedChild([sys.executable, "-c", STUBBORN], tmp_path / "child.log")
    try:
        wait_for(lambda: "up" in child.log, 10.0, "the child to start")
        assert child.end(0.3) == -signal.SIGKILL
        assert child.log_tail() == ":\n    up"
    finally:
        child.close()
