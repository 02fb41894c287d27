"""Latest-value cells in shared memory: the writer replaces, the reader takes the newest once, nobody waits.

Two buffers, each with a sequence word that is odd while it is being written (a seqlock). The writer fills the
buffer the reader was not pointed at, then publishes it. The reader copies the published buffer and keeps the
copy only if the buffer's sequence word was even and unchanged across the copy; a copy torn by a writer that
published twice meanwhile is dropped and the value taken next time. The writer never waits for the reader.

:class:`LatestCell` holds a value of up to a given number of bytes (a pickle); :class:`NumbersCell` a fixed
number of float64s, copied into an array the reader owns, so a streamed input costs the cycle a copy and no
allocation. Both are the one seqlock of :class:`_Seqlock`, which leaves writing and copying a buffer to them.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Generic, TypeVar

import numpy as np

HEADER = 64
_BUFFER_HEADER = 16  # sequence word, length
_LEN = struct.Struct("<q")

V = TypeVar("V")


def latest_bytes(max_value: int) -> int:
    """Cell size for values of at most ``max_value`` bytes."""
    per = _BUFFER_HEADER + (max_value + 63) // 64 * 64
    return HEADER + 2 * per


def numbers_bytes(width: int) -> int:
    """Cell size for records of ``width`` float64s."""
    return latest_bytes(8 * width)


def as_record(values: Sequence[float] | np.ndarray, width: int) -> np.ndarray:
    """A float64 copy of ``values`` (the caller may reuse its own), refused unless they are exactly ``width``."""
    record = np.array(values, dtype=np.float64)
    if record.shape != (width,):
        raise ValueError(f"expected {width} numbers, got shape {record.shape}")
    return record


class _Seqlock(Generic[V]):
    """The protocol of the module docstring; a subclass writes a value into buffer ``k`` and copies one out."""

    def __init__(self, cell: memoryview, writer_lock: threading.Lock | None) -> None:
        per = (len(cell) - HEADER) // 2
        self.max_value = per - _BUFFER_HEADER  # bytes a value may take
        if self.max_value <= 0:
            raise ValueError("a latest-value cell needs room for two buffers")
        self._published = np.frombuffer(cell, dtype=np.int64, count=1)  # values ever published
        self._buffers = [cell[HEADER + k * per : HEADER + (k + 1) * per] for k in (0, 1)]
        self._seqs = [np.frombuffer(b, dtype=np.int64, count=1) for b in self._buffers]
        self._lock: AbstractContextManager[object] = writer_lock or nullcontext()
        self._seen = 0  # the reader's: the last value it took (or cleared)

    def _fill(self, k: int, value: object) -> None:
        raise NotImplementedError

    def _copy(self, k: int) -> V | None:
        """Buffer ``k``'s value (possibly torn: :meth:`take` checks), or None if it is not a value at all."""
        raise NotImplementedError

    # ---- writer -------------------------------------------------------------------------------------------
    def _publish(self, value: object) -> None:
        with self._lock:
            published = self._published.item(0)
            k = (published + 1) % 2
            seq = self._seqs[k]
            writing = seq.item(0) | 1  # odd: being written (even if a writer that died mid-write left it odd)
            seq[0] = writing
            self._fill(k, value)
            seq[0] = writing + 1  # even: complete
            self._published[0] = published + 1

    # ---- reader -------------------------------------------------------------------------------------------
    def take(self) -> V | None:
        """The newest value if it was not taken before; None if there is none or the copy was torn."""
        published = self._published.item(0)
        if published == self._seen:
            return None
        k = published % 2
        seq = self._seqs[k]
        before = seq.item(0)
        if before & 1:
            return None
        value = self._copy(k)
        if value is None or seq.item(0) != before or self._published.item(0) - published > 1:
            return None  # a writer overtook the copy: take the newer value next time
        self._seen = published
        return value

    def clear(self) -> None:
        """Forget what is pending (e.g. a command sent while the consumer was inactive)."""
        self._seen = self._published.item(0)

    def pending(self) -> bool:
        return self._published.item(0) != self._seen


class LatestCell(_Seqlock[bytes]):
    """Values of up to ``max_value`` bytes; each take copies one into a new ``bytes``."""

    def __init__(self, cell: memoryview, *, writer_lock: threading.Lock | None = None) -> None:
        super().__init__(cell, writer_lock)

    def put(self, value: bytes | bytearray | memoryview) -> None:
        n = len(value)
        if n > self.max_value:
            raise ValueError(f"a value of {n} bytes exceeds this cell's {self.max_value}-byte limit")
        self._publish(value)

    def _fill(self, k: int, value: object) -> None:
        assert isinstance(value, bytes | bytearray | memoryview)
        buffer, n = self._buffers[k], len(value)
        _LEN.pack_into(buffer, 8, n)
        buffer[_BUFFER_HEADER : _BUFFER_HEADER + n] = value

    def _copy(self, k: int) -> bytes | None:
        buffer = self._buffers[k]
        n = _LEN.unpack_from(buffer, 8)[0]
        return bytes(buffer[_BUFFER_HEADER : _BUFFER_HEADER + n]) if 0 <= n <= self.max_value else None


class NumbersCell(_Seqlock[np.ndarray]):
    """Records of exactly ``width`` float64s. :meth:`take` copies into :attr:`values` and returns that array:
    the reader owns it, and the next take overwrites it (even one that returns None), so copy what must last."""

    def __init__(self, cell: memoryview, width: int, *, writer_lock: threading.Lock | None = None) -> None:
        super().__init__(cell, writer_lock)
        if not 0 < 8 * width <= self.max_value:
            raise ValueError(f"a cell with room for {self.max_value} bytes cannot hold {width} float64s")
        self.width = width
        self.values = np.zeros(width)
        # Every view made once: a take is a copy between existing arrays.
        self._records = [np.frombuffer(b, dtype=np.float64, count=width, offset=_BUFFER_HEADER) for b in self._buffers]

    def put(self, values: Sequence[float] | np.ndarray) -> None:
        """Publish a copy of ``values`` (exactly ``width`` numbers, else ValueError)."""
        self._publish(as_record(values, self.width))

    def _fill(self, k: int, value: object) -> None:
        self._records[k][...] = value

    def _copy(self, k: int) -> np.ndarray:
        values = self.values
        values[...] = self._records[k]
        return values
