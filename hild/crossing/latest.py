"""A latest-value cell in shared memory: the writer replaces, the reader takes the newest once, nobody waits.

Two buffers, each with a sequence word that is odd while it is being written (a seqlock). The writer fills the
buffer the reader was not pointed at, then publishes it. The reader copies the published buffer and keeps the
copy only if the buffer's sequence word was even and unchanged across the copy; a copy torn by a writer that
published twice meanwhile is dropped and the value taken next time. The writer never waits for the reader.
"""

from __future__ import annotations

import struct
import threading
from contextlib import nullcontext

import numpy as np

HEADER = 64
_BUFFER_HEADER = 16  # sequence word, length
_LEN = struct.Struct("<q")


def latest_bytes(max_value: int) -> int:
    """Cell size for values of at most ``max_value`` bytes."""
    per = _BUFFER_HEADER + (max_value + 63) // 64 * 64
    return HEADER + 2 * per


class LatestCell:
    def __init__(self, cell: memoryview, *, writer_lock: threading.Lock | None = None) -> None:
        per = (len(cell) - HEADER) // 2
        self.max_value = per - _BUFFER_HEADER
        if self.max_value <= 0:
            raise ValueError("a latest-value cell needs room for two buffers")
        self._published = np.frombuffer(cell, dtype=np.int64, count=1)  # values ever published
        self._buffers = [cell[HEADER + k * per : HEADER + (k + 1) * per] for k in (0, 1)]
        self._seqs = [np.frombuffer(b, dtype=np.int64, count=1) for b in self._buffers]
        self._lock = writer_lock or nullcontext()
        self._seen = 0  # the reader's: the last value it took (or cleared)

    # ---- writer -------------------------------------------------------------------------------------------
    def put(self, value: bytes | bytearray | memoryview) -> None:
        n = len(value)
        if n > self.max_value:
            raise ValueError(f"a value of {n} bytes exceeds this cell's {self.max_value}-byte limit")
        with self._lock:
            published = int(self._published[0])
            k = (published + 1) % 2
            buffer, seq = self._buffers[k], self._seqs[k]
            writing = int(seq[0]) | 1  # odd: being written (even if a writer that died mid-write left it odd)
            seq[0] = writing
            _LEN.pack_into(buffer, 8, n)
            buffer[_BUFFER_HEADER : _BUFFER_HEADER + n] = value
            seq[0] = writing + 1  # even: complete
            self._published[0] = published + 1

    # ---- reader -------------------------------------------------------------------------------------------
    def take(self) -> bytes | None:
        """The newest value if it was not taken before; None if there is none or the copy was torn."""
        published = int(self._published[0])
        if published == self._seen:
            return None
        k = published % 2
        buffer, seq = self._buffers[k], self._seqs[k]
        before = int(seq[0])
        if before & 1:
            return None
        n = _LEN.unpack_from(buffer, 8)[0]
        value = bytes(buffer[_BUFFER_HEADER : _BUFFER_HEADER + n]) if 0 <= n <= self.max_value else None
        if value is None or int(seq[0]) != before or int(self._published[0]) - published > 1:
            return None  # a writer overtook the copy: take the newer value next time
        self._seen = published
        return value

    def clear(self) -> None:
        """Forget what is pending (e.g. a command sent while the consumer was inactive)."""
        self._seen = int(self._published[0])

    def pending(self) -> bool:
        return int(self._published[0]) != self._seen
