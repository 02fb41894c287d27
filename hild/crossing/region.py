"""One block of shared memory every hild process maps, carved into named cells.

The block is an anonymous ``memfd``: the main process (embedded, the client domain's link) creates it and hands the
file descriptor to the processes it starts, so there is no name in ``/dev/shm`` to collide with another daemon or
to leak when a process dies.
A memfd reads as zeros until written, and zero is every cell's empty state, so nothing needs initialising; pages
are only backed once touched, so the region can be sized generously.

Its creator carves every cell (:meth:`Region.carve`) before the cycle process starts; the cycle process and a
client domain find them by name (:meth:`Region.find`), and a size that differs between the two (different code or
config on each side) is refused at start-up, never discovered as a torn record later. A controller loaded while the
robot runs gets cells the client domain carves then (the only process that carves once the cycle runs, one load
at a time), before the cycle process is asked to find them; an unloaded one's pages are given back
(:meth:`Region.release`). The directory is append-only, so a reader never sees an entry change.
"""

from __future__ import annotations

import mmap
import os
import struct

import numpy as np

ALIGN = 64  # a cache line: two cells never share one, so their writers do not contend
NAME_BYTES = 112
_ENTRY = struct.Struct(f"<{NAME_BYTES}sQQ")  # name, offset, size: 128 bytes
MAX_CELLS = 8192  # a controller takes a few; loads while the robot runs take new ones
_DIRECTORY = ALIGN + MAX_CELLS * _ENTRY.size  # a count, then the entries
_MAGIC = 0x68696C6478310002  # "hildx1" + layout version
PAGE = mmap.PAGESIZE


class RegionError(RuntimeError):
    """Two processes disagree on the region's layout, or it is full."""


def _align(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


class Region:
    """A shared-memory block and its directory of cells (name → offset, size)."""

    def __init__(self, size: int, fd: int | None = None) -> None:
        self.size = _align(size)
        created = fd is None
        if fd is None:
            fd = os.memfd_create("hild-crossing", os.MFD_CLOEXEC)
            os.ftruncate(fd, self.size)
        elif os.fstat(fd).st_size != self.size:
            raise RegionError(f"the shared region is {os.fstat(fd).st_size} bytes; expected {self.size}")
        self.fd = fd
        self._map = mmap.mmap(fd, self.size)
        self.buffer = memoryview(self._map)
        self._header = np.frombuffer(self.buffer, dtype=np.uint64, count=2)  # magic, cells carved
        if created:
            self._header[0] = _MAGIC
        elif int(self._header[0]) != _MAGIC:
            raise RegionError("the shared region was not made by this version of hild")
        self._known: dict[str, tuple[int, int]] = {}  # the directory's entries read so far: name → offset, size
        self._next = _DIRECTORY if created else self._end()

    @classmethod
    def attach(cls, fd: int, size: int) -> Region:
        """Map a region another process created (the cycle process or a client domain, from the fd it was handed)."""
        return cls(size, fd)

    def carve(self, name: str, nbytes: int) -> memoryview:
        """A new zeroed cell of ``nbytes``: by the region's creator before the cycle process starts, and by the
        client domain for a controller loaded later (one carver at a time)."""
        encoded = name.encode()
        if len(encoded) > NAME_BYTES:
            raise RegionError(f"cell name {name!r} is longer than {NAME_BYTES} bytes")
        count = int(self._header[1])
        if count >= MAX_CELLS:
            raise RegionError(f"the shared region holds at most {MAX_CELLS} cells")
        if name in self._directory():
            raise RegionError(f"cell {name!r} is carved twice")
        offset = max(self._next, self._end())
        if offset + nbytes > self.size:
            raise RegionError(f"the shared region ({self.size} bytes) has no room for {name!r} ({nbytes} bytes)")
        _ENTRY.pack_into(self.buffer, ALIGN + count * _ENTRY.size, encoded, offset, nbytes)
        self._header[1] = count + 1  # after the entry: a reader that sees the count finds the entry whole
        self._next = _align(offset + nbytes)
        return self.buffer[offset : offset + nbytes]

    def find(self, name: str, nbytes: int) -> memoryview:
        """The cell the region's creator carved as ``name``; its size must be ``nbytes``."""
        entry = self._directory().get(name)
        if entry is None:
            raise RegionError(f"no cell {name!r} in the shared region (the other domain did not carve it)")
        offset, size = entry
        if size != nbytes:
            raise RegionError(f"cell {name!r} is {size} bytes in the shared region; this side expects {nbytes}")
        return self.buffer[offset : offset + size]

    def release(self, prefix: str) -> int:
        """Zero every cell named ``prefix…`` (an unloaded controller's: nobody uses them any more) and give its
        whole pages back (``MADV_REMOVE``: they cost no memory until written again). Zero is every cell's empty
        state, so the cells can serve another load. Returns the bytes whose pages were given back."""
        released = 0
        for name, (offset, size) in self._directory().items():
            if not name.startswith(prefix):
                continue
            start = -(-offset // PAGE) * PAGE
            end = (offset + size) // PAGE * PAGE
            if end > start:
                self._map.madvise(mmap.MADV_REMOVE, start, end - start)
                released += end - start
            for lo, hi in ((offset, min(start, offset + size)), (max(end, offset), offset + size)):
                if hi > lo:  # the part of a page the cell shares with its neighbours: zeroed by hand
                    self.buffer[lo:hi] = bytes(hi - lo)
        return released

    def cells(self) -> list[tuple[str, int, int]]:
        return [(name, offset, size) for name, (offset, size) in self._directory().items()]

    def _directory(self) -> dict[str, tuple[int, int]]:
        """name → (offset, size), reading only the entries added since the last call (the directory only grows)."""
        known = self._known
        for k in range(len(known), int(self._header[1])):
            raw, offset, size = _ENTRY.unpack_from(self.buffer, ALIGN + k * _ENTRY.size)
            known[raw.rstrip(b"\0").decode()] = (offset, size)
        return known

    def _end(self) -> int:
        return max((_align(offset + size) for offset, size in self._directory().values()), default=_DIRECTORY)
