"""The telemetry tap: what the cycle writes each cycle, and the only telemetry code that runs on the cycle.

``TelemetryTap.record`` copies the cycle's numbers into preallocated rows of a ring (a few in-place numpy
assignments, no rerun, no allocation that outlives the call). The ring can live in shared memory
(``SharedRing``): the cycle writes it (in the cycle process, or on a cycle thread of a single daemon process), the
recorder process reads it with ``take``.

Protocol (single producer, single consumer): the producer fills a row, then publishes it by advancing ``head``
(an int64 cell at the start of the buffer; aligned 8-byte stores are atomic, and x86-64 keeps stores in order).
The reader copies the rows up to ``head``, re-reads ``head`` and drops any row the producer may have overwritten
meanwhile, so a slow reader loses rows (counted in ``dropped``, a second cell the reader writes) but never sees a
torn one and never slows the cycle.

This module imports neither rerun nor mujoco, so the engine can hold a tap without loading either.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.crossing.stats import LoopStats

FIELDS = ("measured_position", "measured_velocity", "measured_effort", "position", "velocity", "effort")
_HEAD, _DROPPED = 0, 1  # int64 header cells: rows ever committed (producer), rows lost (consumer)
_HEADER_CELLS = 4
SHM_PREFIX = "hild-telemetry-"


@dataclass(frozen=True)
class TelemetryRows:
    """Rows copied out of the ring, oldest first (all arrays own their memory)."""

    tick: np.ndarray  # int64 (k,)
    t: np.ndarray  # cycle clock, s (k,)
    period: np.ndarray  # s (k,): dt of the cycle
    duration: np.ndarray  # s (k,): duration of the previous completed cycle (wake → write done)
    measured_position: np.ndarray  # (k, joints)
    measured_velocity: np.ndarray
    measured_effort: np.ndarray
    position: np.ndarray  # commanded: the supervisor's final command
    velocity: np.ndarray
    effort: np.ndarray
    mode: np.ndarray  # int8 (k, joints): hild.modes.JointMode

    def __len__(self) -> int:
        return len(self.tick)


_SCALARS = ("tick", "t", "period", "duration")  # the first cells of a row; then FIELDS side by side, then mode


def _row_cells(joints: int) -> int:
    return len(_SCALARS) + (len(FIELDS) + 1) * joints


def _layout(joints: int, capacity: int) -> list[tuple[str, np.dtype, tuple[int, ...]]]:
    """The header, then one float64 row per cycle holding everything the cycle records, contiguous: a record
    writes one short run of memory (a cache line or a few, one page) instead of a cell in each of several arrays.
    Ticks and modes are small integers, exact in float64."""
    return [
        ("_header", np.dtype(np.int64), (_HEADER_CELLS,)),
        ("_rows", np.dtype(np.float64), (capacity, _row_cells(joints))),
    ]


def ring_bytes(joints: int, capacity: int) -> int:
    return sum(dtype.itemsize * int(np.prod(shape)) for _, dtype, shape in _layout(joints, capacity))


class TelemetryTap:
    """A preallocated ring of per-cycle samples; single producer (the cycle), single consumer (the recorder).

    ``every``: record one cycle in ``every`` (``scalar_rate`` decimation); the other calls return at once.
    ``capacity``: rows kept; size it for a few flush periods so a late reader does not lose data.
    ``stats``: the engine's loop statistics, read for the last cycle's duration when ``record`` is not given one
    (the current cycle's duration is only known after ``step`` returns, so a row carries the previous one).
    ``buffer``: where the ring lives (e.g. a ``SharedMemory.buf`` of ``ring_bytes`` bytes); private memory if None.
    """

    def __init__(
        self,
        joints: int,
        capacity: int,
        every: int = 1,
        stats: LoopStats | None = None,
        buffer: memoryview | None = None,
    ) -> None:
        if capacity < 2:
            raise ValueError("capacity must be at least 2")
        self.joints = joints
        self.capacity = capacity
        self.every = max(1, int(every))
        self.stats = stats
        self._stage = np.zeros(len(_SCALARS))  # tick, t, period, duration of the row being recorded
        self._bind(np.zeros(ring_bytes(joints, capacity), dtype=np.uint8) if buffer is None else buffer)
        if buffer is None:
            self.prefault()
        self._written = self.head  # the producer's count (it alone advances head)
        self._next = self._written  # the reader's position

    def _bind(self, buffer: memoryview | np.ndarray) -> None:
        raw = np.frombuffer(buffer, dtype=np.uint8, count=ring_bytes(self.joints, self.capacity))
        offset = 0
        for name, dtype, shape in _layout(self.joints, self.capacity):
            size = dtype.itemsize * int(np.prod(shape))
            setattr(self, name, raw[offset : offset + size].view(dtype).reshape(shape))
            offset += size
        rows, n, first = self._rows, self.joints, len(_SCALARS)
        for k, name in enumerate(_SCALARS):  # views for readers
            setattr(self, name, rows[:, k])
        for k, name in enumerate(FIELDS):
            setattr(self, name, rows[:, first + k * n : first + (k + 1) * n])
        self.mode = rows[:, first + len(FIELDS) * n :]
        self._raw = raw

    def prefault(self) -> None:
        """Touch every page of the ring now (the creator, before the cycle starts), so no ``record`` pays a page
        fault the first time it reaches a new page."""
        self._raw.fill(0)

    def detach(self) -> None:
        """Move the ring into private memory (a copy), so the shared segment can be unmapped while the cycle
        thread may still call ``record``; its rows then go nowhere, at the same cost."""
        self._bind(self._raw.copy())

    @property
    def head(self) -> int:
        """Rows ever committed."""
        return int(self._header[_HEAD])

    @property
    def dropped(self) -> int:
        """Rows the reader lost because it fell behind."""
        return int(self._header[_DROPPED])

    def record(
        self,
        t: float,
        tick: int,
        state: JointState,
        final: ServoCommand,
        modes: np.ndarray,
        period: float,
        duration: float | None = None,
    ) -> None:
        """Copy one cycle into the ring (on the cycle). ``duration``: the last completed cycle's, in seconds;
        None reads it from ``stats`` (0 when there is none yet)."""
        if tick % self.every:
            return
        if duration is None:
            duration = 0.0
            if self.stats is not None:
                window = self.stats.duration
                if window.count:
                    duration = window.values.item((window.count - 1) % window.values.shape[0]) * 1e-9
        stage = self._stage
        stage[0] = tick
        stage[1] = t
        stage[2] = period
        stage[3] = duration
        np.concatenate(  # the whole row in one call: the cheapest copy numpy offers per cycle
            (stage, state.position, state.velocity, state.effort, final.position, final.velocity, final.effort, modes),
            out=self._rows[self._written % self.capacity],
        )
        self._written += 1
        self._header[_HEAD] = self._written  # publish: the row is complete before the reader can see it

    def take(self) -> TelemetryRows:
        """Copy out every row committed since the last call (reader side)."""
        head = self.head
        start = max(self._next, head - self.capacity + 1)  # one row of margin: the producer may be filling it
        lost = start - self._next
        seqs = np.arange(start, head)
        slots = seqs % self.capacity
        rows = TelemetryRows(
            tick=self.tick[slots].astype(np.int64),
            t=self.t[slots],
            period=self.period[slots],
            duration=self.duration[slots],
            measured_position=self.measured_position[slots],
            measured_velocity=self.measured_velocity[slots],
            measured_effort=self.measured_effort[slots],
            position=self.position[slots],
            velocity=self.velocity[slots],
            effort=self.effort[slots],
            mode=self.mode[slots].astype(np.int8),
        )
        # Rows the producer reached while we copied may be torn: keep only those it cannot have touched.
        valid_from = self.head - self.capacity + 1
        if start < valid_from:
            keep = seqs >= valid_from
            lost += int(np.count_nonzero(~keep))
            rows = TelemetryRows(**{name: getattr(rows, name)[keep] for name in rows.__dataclass_fields__})
        if lost:
            self._header[_DROPPED] += lost
        self._next = head
        return rows


class SharedRing:
    """A ``TelemetryTap`` in POSIX shared memory (``/dev/shm/hild-telemetry-<pid>-<random>``).

    The client domain creates it (``SharedRing.create``, through ``Telemetry``) and owns the name: ``release``
    unlinks it. The recorder process attaches by name (``SharedRing.attach``); the cycle process maps it by name too
    (``hild.cycle.process``). If the client domain is killed outright, multiprocessing's resource tracker unlinks
    the segment.
    """

    def __init__(self, shm: shared_memory.SharedMemory, tap: TelemetryTap, owner: bool) -> None:
        self.shm = shm
        self.tap = tap
        self.owner = owner
        self.name = shm.name

    @classmethod
    def create(cls, joints: int, capacity: int, every: int = 1, stats: LoopStats | None = None) -> SharedRing:
        name = f"{SHM_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
        shm = shared_memory.SharedMemory(name, create=True, size=ring_bytes(joints, capacity))
        try:
            tap = TelemetryTap(joints, capacity, every, stats, shm.buf)
            tap.prefault()
        except BaseException:
            shm.close()
            shm.unlink()
            raise
        return cls(shm, tap, owner=True)

    @classmethod
    def attach(cls, name: str, joints: int, capacity: int, every: int = 1) -> SharedRing:
        shm = shared_memory.SharedMemory(name)
        return cls(shm, TelemetryTap(joints, capacity, every, None, shm.buf), owner=False)

    def release(self) -> None:
        """Unlink the name (owner) and unmap the segment. The tap moves to private memory first, so a cycle that
        still calls ``record`` keeps working. Safe to call twice."""
        self.tap.detach()
        if self.owner:
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()
            self.owner = False
        with contextlib.suppress(BufferError):  # a record() in flight still holds the old view: unmapped at exit
            self.shm.close()


@dataclass(frozen=True)
class TelemetryRing:
    """The telemetry recorder's shared ring (POSIX shared memory the client domain created): the cycle records into
    it."""

    name: str
    joints: int
    capacity: int
    every: int
