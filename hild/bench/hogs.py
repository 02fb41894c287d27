"""Busy processes beside a measurement: the everyday load a rig must stand (an IDE, a compiler, a second test run).

Each hog is ``python -c`` spinning at normal priority. It ends by itself after its time bound and dies with the
process that started it (``PR_SET_PDEATHSIG``), so an interrupted measurement never leaves one running.
"""

from __future__ import annotations

import contextlib
import ctypes
import signal
import subprocess
import sys
from collections.abc import Iterator

PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the child: SIGKILL when the parent dies, however it dies."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def start_hogs(count: int, seconds: float) -> list[subprocess.Popen[bytes]]:
    """``count`` busy processes that end by themselves after ``seconds`` (and with this process)."""
    code = f"import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass"
    return [subprocess.Popen([sys.executable, "-c", code], preexec_fn=_die_with_parent) for _ in range(count)]


@contextlib.contextmanager
def hogs(count: int, seconds: float) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``start_hogs`` for the ``with`` block; every hog is killed and reaped on leaving it."""
    busy = start_hogs(count, seconds)
    try:
        yield busy
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
