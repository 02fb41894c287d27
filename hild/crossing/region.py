"""One block of shared memory every hild process maps, carved into named cells.

The block is an anonymous ``memfd``: the main process (embedded, the client domain's link) creates it and hands the
file descriptor to the processes it starts, so there is no name in ``/dev/shm`` to collide with another daemon or
to leak when a process dies.
A memfd reads as zeros until written, and zero is every cell's empty state, so nothing needs initialising; pages
are only backed once touched, so the region can be sized generously.

Its creator carves every cell (:meth:`Region.carve`) before the cycle process starts; the cycle process and a
client domain find them by name (:meth:`Region.find`), and a size that differs between the two (different code or
config on each side) is refused at start-up, never discovered as a torn record later.
"""

from __future__ import annotations

import mmap
import os
import struct

import numpy as np

ALIGN = 64  # a cache line: two cells never share one, so their writers do not contend
NAME_BYTES = 112
_ENTRY = struct.Struct(f"<{NAME_BYTES}sQQ")  # name, offset, size: 128 bytes
MAX_CELLS = 512
_DIRECTORY = ALIGN + MAX_CELLS * _ENTRY.size  # a count, then the entries
_MAGIC = 0x68696C6478310001  # "hildx1" + layout version


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
        self._next = _DIRECTORY if created else self._end()

    @classmethod
    def attach(cls, fd: int, size: int) -> Region:
        """Map a region another process created (the cycle process or a client domain, from the fd it was handed)."""
        return cls(size, fd)

    def carve(self, name: str, nbytes: int) -> memoryview:
        """A new zeroed cell of ``nbytes`` (the region's creator, before the cycle process starts)."""
        encoded = name.encode()
        if len(encoded) > NAME_BYTES:
            raise RegionError(f"cell name {name!r} is longer than {NAME_BYTES} bytes")
        count = int(self._header[1])
        if count >= MAX_CELLS:
            raise RegionError(f"the shared region holds at most {MAX_CELLS} cells")
        if any(entry[0] == name for entry in self.cells()):
            raise RegionError(f"cell {name!r} is carved twice")
        offset = self._next
        if offset + nbytes > self.size:
            raise RegionError(f"the shared region ({self.size} bytes) has no room for {name!r} ({nbytes} bytes)")
        _ENTRY.pack_into(self.buffer, ALIGN + count * _ENTRY.size, encoded, offset, nbytes)
        self._header[1] = count + 1
        self._next = _align(offset + nbytes)
        return self.buffer[offset : offset + nbytes]

    def find(self, name: str, nbytes: int) -> memoryview:
        """The cell the region's creator carved as ``name``; its size must be ``nbytes``."""
        for cell, offset, size in self.cells():
            if cell == name:
                if size != nbytes:
                    raise RegionError(f"cell {name!r} is {size} bytes in the shared region; this side expects {nbytes}")
                return self.buffer[offset : offset + size]
        raise RegionError(f"no cell {name!r} in the shared region (the other domain did not carve it)")

    def cells(self) -> list[tuple[str, int, int]]:
        out = []
        for k in range(int(self._header[1])):
            raw, offset, size = _ENTRY.unpack_from(self.buffer, ALIGN + k * _ENTRY.size)
            out.append((raw.rstrip(b"\0").decode(), offset, size))
        return out

    def _end(self) -> int:
        cells = self.cells()
        return max((_align(offset + size) for _, offset, size in cells), default=_DIRECTORY)
