"""Who is writing an episode: an advisory lock on its directory, held by the recorder process while it writes.

An episode left ``recording`` on disk is either being written right now (by this daemon's recorder, or another
daemon's sharing ``recording.dir``) or was left by a recorder that died. The lock tells them apart: the kernel drops
it when its holder dies, so ``recover`` closes only what nobody holds (``flock`` on the directory).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path


def hold(directory: Path) -> int:
    """Lock ``directory`` for writing; returns the descriptor that holds the lock (``release`` it, or exit).
    Raises ``BlockingIOError`` if another writer holds it."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BaseException:
        os.close(fd)
        raise
    return fd


def release(fd: int) -> None:
    with contextlib.suppress(OSError):
        os.close(fd)


def in_use(directory: Path) -> bool:
    """Whether a live recorder holds ``directory`` (a missing directory is not in use)."""
    try:
        fd = hold(directory)
    except BlockingIOError:
        return True
    except OSError:
        return False
    release(fd)
    return False
