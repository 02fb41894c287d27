"""Replace a directory tree all at once: build the new tree beside it, then swap the two.

A dataset is many files that must agree (the episode index, the stats, the data). Rewriting them one by one leaves a
dataset that disagrees with itself if the process dies halfway. So a writer builds the whole new tree in a staging
directory beside the target (unchanged files hard-linked from the old tree: no copy, and a hard link is never
written through, see ``write_new``), then ``replace_tree`` swaps it in with one ``renameat2(RENAME_EXCHANGE)``:
a reader, or a crash, sees either the old tree or the new one. Where the kernel or the filesystem cannot exchange,
it falls back to two renames, and a crash between them leaves the old tree under ``.<name>.old-<random>`` beside
the target.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
import uuid
from pathlib import Path

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def staging_dir(target: Path) -> Path:
    """A new, empty directory beside ``target`` (same filesystem, so it can be renamed onto it)."""
    stage = target.parent / f".{target.name}.partial-{uuid.uuid4().hex[:8]}"
    stage.mkdir(parents=True)
    return stage


def link_tree(source: Path, stage: Path) -> None:
    """Hard-link every file of ``source`` into ``stage`` (copying where the filesystem cannot link)."""
    for root, dirs, files in os.walk(source):
        into = stage / Path(root).relative_to(source)
        for d in dirs:
            (into / d).mkdir(exist_ok=True)
        for f in files:
            try:
                os.link(Path(root) / f, into / f)
            except OSError:
                shutil.copy2(Path(root) / f, into / f)


def write_new(path: Path, data: bytes) -> None:
    """Write ``data`` to a fresh file at ``path``, synced. An existing file (a hard link into the old tree) is
    unlinked first: writing through it would change the old tree too."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    with open(path, "xb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def sync_tree(root: Path) -> None:
    """fsync every file and directory under ``root`` (what the swap makes visible must be on disk first)."""
    for here, _, files in os.walk(root):
        for name in files:
            fd = os.open(Path(here) / name, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        _sync_dir(Path(here))


def _sync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically; False where renameat2 or RENAME_EXCHANGE is not supported here."""
    libc = ctypes.CDLL(None, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, f"cannot swap {a} and {b}: {os.strerror(err)}")


def replace_tree(stage: Path, target: Path) -> None:
    """Make ``stage`` the tree at ``target`` in one step; the old tree is removed afterwards."""
    sync_tree(stage)
    if not target.exists():
        os.rename(stage, target)
    elif _exchange(stage, target):
        shutil.rmtree(stage)  # now the old tree
    else:
        old = target.parent / f".{target.name}.old-{uuid.uuid4().hex[:8]}"
        os.rename(target, old)
        os.rename(stage, target)
        shutil.rmtree(old)
    _sync_dir(target.parent)
