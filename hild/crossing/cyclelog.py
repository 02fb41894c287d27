"""The cycle log: every cycle's full record, in a ring the recorder and the flight recorder read (docs/recording.md).

The cycle writes one row per cycle after its write (``CycleLogTap.record``, one in-place numpy copy, no
allocation); the row holds everything a recording needs to be cycle-exact: the cycle's clock and wall time, the
accepted reading, the final command (all five servo fields), each joint's mode, owner, plausibility and fault, the
external torque estimate and who moved it (``hild.modes.Source``: a leader arm, a policy, a trajectory, hold). The
ring keeps at least ``recording.blackbox_seconds`` of cycles, so it *is* the flight recorder's memory: nothing extra
is kept on the cycle for it. It lives in the shared region (a cell carved by the region's creator), so it outlives a
client domain that dies; single producer, any number of readers, each with its own position (a slow reader skips
and counts, never slows the cycle).

``CycleRows`` is what a reader copies out, and what the episode files are written from and read back into.

Layout (``cycle_log_bytes``): a 64-byte header of int64 cells (rows ever committed, a magic number, the joints, the
capacity, the row's width), then ``capacity`` rows of float64, each one contiguous run: ``tick, t, wall, period,
duration``, then per joint side by side ``measured_position, measured_velocity, measured_effort, fresh, fault,
position, velocity, effort, kp, kd, mode, owner, tau_ext, source`` (small integers are exact in float64). The row's
``owner`` is the code of the controller that *claims* the joint and ``source`` that controller's source; a reader's
``CycleRows.owner`` and ``.source`` keep them only where the joint's mode is ``controlled`` (``OWNER_NONE`` and
``Source.HOLD`` elsewhere: the cycle never spends a multiply on what a reader can mask).

Protocol, as the telemetry ring's (``hild.crossing.telemetry``): the producer fills row ``head % capacity``, then
publishes it by storing ``head + 1`` (an aligned 8-byte store; x86-64 keeps stores in order). A reader copies the
rows up to the ``head`` it read, re-reads ``head`` and drops every row the producer may have reached meanwhile, so
it never returns a torn row; what it missed is counted in its own ``lost``. Readers write nothing in the ring:
they map it read-only, and any number of them read at once.
"""

from __future__ import annotations

import contextlib
import math
import mmap
import os
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Protocol

import numpy as np

from hild.crossing.stats import LoopStats
from hild.modes import JointMode, Source

if TYPE_CHECKING:
    from hild.config.model import RobotConfig  # only a type: the crossing imports no config library

OWNER_NONE = 0  # the owner code of a joint no controller commands (held, faulted, e-stopped)

SCALARS = ("tick", "t", "wall", "period", "duration")  # the first cells of a row
PER_JOINT = (  # then these, each ``joints`` wide, side by side
    "measured_position",
    "measured_velocity",
    "measured_effort",
    "fresh",
    "fault",
    "position",
    "velocity",
    "effort",
    "kp",
    "kd",
    "mode",
    "owner",
    "tau_ext",
    "source",
)
_HEAD, _MAGIC, _JOINTS, _CAPACITY, _WIDTH = 0, 1, 2, 3, 4  # int64 header cells
HEADER_BYTES = 64  # a cache line: the rows start on one of their own
MAGIC = 0x68696C64634C0002  # "hildcL" + layout version
MIN_SECONDS = 2.0  # the ring keeps at least this many seconds of cycles, black box or not
MARGIN_SECONDS = 2.0  # beyond the black box's seconds: its copy and a recorder's late take never lose rows
MAX_BYTES = 1 << 30  # the shared region is 2 GiB (virtual); the ring takes at most half of it
_INTEGERS = {
    "tick": np.int64,
    "fresh": np.bool_,
    "fault": np.int16,
    "mode": np.int8,
    "owner": np.int16,
    "source": np.int8,
}


class CycleLogError(RuntimeError):
    """The ring is not what its place says (other code or config on the other side)."""


@dataclass(frozen=True)
class CycleRows:
    """Rows of the cycle log, oldest first; every array owns its memory. ``k`` rows, ``n`` joints (robot order)."""

    tick: np.ndarray  # int64 (k,): the engine's cycle count
    t: np.ndarray  # float64 (k,): the cycle clock, s
    wall: np.ndarray  # float64 (k,): CLOCK_REALTIME at the cycle's read, s since the epoch
    period: np.ndarray  # float64 (k,): the cycle's dt, s
    duration: np.ndarray  # float64 (k,): the previous completed cycle's duration (wake → write done), s
    measured_position: np.ndarray  # float64 (k, n): the accepted reading (after the plausibility check)
    measured_velocity: np.ndarray
    measured_effort: np.ndarray
    fresh: np.ndarray  # bool (k, n): a new reading was accepted this cycle (False: silent or rejected)
    fault: np.ndarray  # int16 (k, n): the joint's latched fault (hild.cycle.supervisor.Fault; 0 = none)
    position: np.ndarray  # float64 (k, n): the final command, the supervisor's (joint space)
    velocity: np.ndarray
    effort: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    mode: np.ndarray  # int8 (k, n): hild.modes.JointMode
    owner: np.ndarray  # int16 (k, n): the commanding controller's code (OWNER_NONE: none); Snapshot.controller_codes
    tau_ext: np.ndarray  # float64 (k, n): the external torque estimate, NaN while no observer runs
    source: np.ndarray  # int8 (k, n): who moved the joint (hild.modes.Source; HOLD where no controller commands it)

    def __len__(self) -> int:
        return len(self.tick)

    def select(self, keep: np.ndarray | slice) -> CycleRows:
        """The rows ``keep`` picks (a boolean mask, indices or a slice), as a new ``CycleRows``."""
        return CycleRows(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    @classmethod
    def concat(cls, parts: list[CycleRows], joints: int) -> CycleRows:
        """Parts joined in order (an empty list gives zero rows of ``joints`` joints)."""
        if not parts:
            return cls.empty(joints)
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    @classmethod
    def empty(cls, joints: int) -> CycleRows:
        scalar = {"tick": np.int64}
        out = {}
        for f in fields(cls):
            if f.name in ("tick", "t", "wall", "period", "duration"):
                out[f.name] = np.zeros(0, dtype=scalar.get(f.name, np.float64))
            else:
                out[f.name] = np.zeros((0, joints), dtype=_INTEGERS.get(f.name, np.float64))
        return cls(**out)


# ---- the layout ---------------------------------------------------------------------------------------------------


def row_width(joints: int) -> int:
    """float64 cells per row."""
    return len(SCALARS) + len(PER_JOINT) * joints


def cycle_log_bytes(joints: int, capacity: int) -> int:
    return HEADER_BYTES + 8 * capacity * row_width(joints)


def cycle_log_capacity(update_rate: float, blackbox_seconds: float) -> int:
    """Rows for ``max(blackbox_seconds, MIN_SECONDS) + MARGIN_SECONDS`` of cycles at ``update_rate``."""
    return math.ceil((max(blackbox_seconds, MIN_SECONDS) + MARGIN_SECONDS) * update_rate)


def capacity_of(config: RobotConfig) -> int:
    """The ring's capacity for this config, the same on every side that carves or finds it; 0 when recording is
    off (then there is no ring, and the engine writes none)."""
    recording = config.recording
    return cycle_log_capacity(config.update_rate, recording.blackbox_seconds) if recording.enabled else 0


@dataclass(frozen=True)
class CycleLogPlace:
    """Where the ring is in a memfd, for another process to map it (the fd itself crosses apart:
    ``multiprocessing.reduction.send_handle``)."""

    size: int  # the memfd's total size (checked: a different file is refused)
    offset: int  # where the ring starts in it
    nbytes: int  # the ring's length: ``cycle_log_bytes(joints, capacity)``
    joints: int
    capacity: int


# ---- the ring and its readers ---------------------------------------------------------------------------------------


class CycleLog:
    """The ring over a buffer of ``cycle_log_bytes(joints, capacity)`` bytes: its head, its readers, its newest rows.

    ``create``: lay the header down (the ring's creator, on zeroed memory); otherwise it is checked."""

    def __init__(self, buffer: memoryview | np.ndarray, joints: int, capacity: int, *, create: bool = False) -> None:
        if capacity < 2:
            raise ValueError("a cycle log holds at least 2 rows")
        self.joints = joints
        self.capacity = capacity
        self.width = row_width(joints)
        raw = np.frombuffer(buffer, dtype=np.uint8, count=cycle_log_bytes(joints, capacity))
        self._raw = raw
        self._header = raw[:HEADER_BYTES].view(np.int64)
        self._rows = raw[HEADER_BYTES:].view(np.float64).reshape(capacity, self.width)
        self._mapping: mmap.mmap | None = None
        expected = (MAGIC, joints, capacity, self.width)
        if create:
            self._header[_MAGIC : _WIDTH + 1] = expected
        found = tuple(int(v) for v in self._header[_MAGIC : _WIDTH + 1])
        if found != expected:
            raise CycleLogError(
                f"the cycle log holds (magic, joints, capacity, width) {found}; this side expects {expected}"
            )

    @classmethod
    def private(cls, joints: int, capacity: int) -> CycleLog:
        """A ring in this process's memory (lockstep tests, tools): nobody else maps it."""
        return cls(np.zeros(cycle_log_bytes(joints, capacity), dtype=np.uint8), joints, capacity, create=True)

    @classmethod
    def memfd(cls, joints: int, capacity: int) -> tuple[CycleLog, int, CycleLogPlace]:
        """A ring in a memfd of its own (``LocalCycle``), mapped here for the writer; the caller owns the fd and
        hands it with the place to the process that reads it."""
        nbytes = cycle_log_bytes(joints, capacity)
        fd = os.memfd_create("hild-cycle-log", os.MFD_CLOEXEC)
        try:
            os.ftruncate(fd, nbytes)
            mapping = mmap.mmap(fd, nbytes)
            log = cls(memoryview(mapping), joints, capacity, create=True)
        except BaseException:
            os.close(fd)
            raise
        log._mapping = mapping
        return log, fd, CycleLogPlace(nbytes, 0, nbytes, joints, capacity)

    @classmethod
    def attach(cls, fd: int, place: CycleLogPlace) -> CycleLog:
        """Map the ring another process writes, read-only (a reader can never disturb the cycle's rows). The fd
        may be closed afterwards: the mapping keeps the memory."""
        size = os.fstat(fd).st_size
        if size != place.size:
            raise CycleLogError(f"the cycle log's file is {size} bytes; its place says {place.size}")
        if place.nbytes != cycle_log_bytes(place.joints, place.capacity):
            raise CycleLogError(f"the cycle log's place is inconsistent: {place}")
        start = place.offset - place.offset % mmap.PAGESIZE  # mmap maps whole pages
        mapping = mmap.mmap(fd, place.offset - start + place.nbytes, mmap.MAP_SHARED, mmap.PROT_READ, offset=start)
        log = cls(memoryview(mapping)[place.offset - start :], place.joints, place.capacity)
        log._mapping = mapping
        return log

    @property
    def head(self) -> int:
        """Rows ever committed."""
        return int(self._header[_HEAD])

    def reader(self, start_tick: int | None = None) -> CycleLogReader:
        """A reader with a position of its own: from the next row committed (None), or from the row of cycle
        ``start_tick`` on (rows of it the ring no longer holds are counted lost; a future tick is waited for)."""
        return CycleLogReader(self, start_tick)

    def last(self, count: int) -> CycleRows:
        """The newest ``count`` rows (at most ``capacity - 1``: the producer may be filling the last slot), oldest
        first; rows the producer overwrote while they were copied are dropped (the flight recorder's copy)."""
        head = self.head
        count = max(0, min(count, self.capacity - 1, head))
        rows, _ = self._copy(head - count, head)
        return rows

    def prefault(self) -> None:
        """Touch every page of the ring for writing, rewriting what is there (the writer, before its first cycle):
        no ``record`` ever takes a first-touch page fault, and a reader meanwhile sees nothing change."""
        page = mmap.PAGESIZE
        self._raw[::page] = self._raw[::page].copy()
        self._raw[-1:] = self._raw[-1:].copy()

    def close(self) -> None:
        """Unmap a ring this object mapped (``attach``, ``memfd``); readers of it must not be used afterwards."""
        mapping, self._mapping = self._mapping, None
        if mapping is None:
            return
        del self._raw, self._header, self._rows
        with contextlib.suppress(BufferError):  # a view of it is still held somewhere: unmapped when that goes
            mapping.close()

    # ---- copying out ----------------------------------------------------------------------------------------------
    def _gather(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start … stop - 1`` (sequence numbers), copied."""
        return self._rows.take(np.arange(start, stop) % self.capacity, axis=0)

    def _copy(self, start: int, stop: int) -> tuple[CycleRows, int]:
        """Rows ``start … stop - 1`` as ``CycleRows``, without those the producer may have reached while they were
        copied (always the oldest ones); and how many those were."""
        block = self._gather(start, stop)
        valid_from = self.head - self.capacity + 1  # re-read: anything before it may be torn
        torn = max(0, min(valid_from, stop) - start)
        return self._unpack(block[torn:]), torn

    def _unpack(self, block: np.ndarray) -> CycleRows:
        out: dict[str, np.ndarray] = {}
        for k, name in enumerate(SCALARS):
            out[name] = block[:, k].astype(_INTEGERS.get(name, np.float64))
        n, first = self.joints, len(SCALARS)
        for k, name in enumerate(PER_JOINT):
            out[name] = block[:, first + k * n : first + (k + 1) * n].astype(_INTEGERS.get(name, np.float64))
        uncontrolled = out["mode"] != JointMode.CONTROLLED  # the ring holds the claim: see above
        out["owner"][uncontrolled] = OWNER_NONE
        out["source"][uncontrolled] = Source.HOLD
        return CycleRows(**out)


class CycleLogReader:
    """One reader's position in a ``CycleLog``: ``take`` copies what was committed since its last take."""

    def __init__(self, log: CycleLog, start_tick: int | None = None) -> None:
        self.log = log
        self.lost = 0  # rows this reader missed: overwritten before it took them, or torn while it copied
        head = log.head
        self._next = head
        self._from_tick = start_tick  # rows of earlier cycles are skipped until one of this cycle or later is seen
        if start_tick is None:
            return
        oldest = max(0, head - log.capacity + 1)
        if oldest == head:
            return
        ticks = log._gather(oldest, head)[:, 0]
        found = int(np.searchsorted(ticks, start_tick))
        if found < len(ticks):
            self._next = oldest + found
            if found == 0:  # the cycle asked for is older than the ring: what came between is lost
                self.lost += max(0, min(int(ticks[0]) - start_tick, oldest))

    def take(self) -> CycleRows:
        log = self.log
        head = log.head
        start = max(self._next, head - log.capacity + 1)  # one row of margin: the producer may be filling it
        rows, torn = log._copy(start, head)
        self.lost += start - self._next + torn
        self._next = head
        if self._from_tick is not None and len(rows):
            keep = rows.tick >= self._from_tick
            if keep.any():
                self._from_tick = None
            if not keep.all():
                rows = rows.select(keep)
        return rows


# ---- the writer (on the cycle) ---------------------------------------------------------------------------------------


class CycleRow:
    """The engine's row buffer: one float64 array laid out as a ring's row, whose per-joint views *are* the engine's
    float arrays (the accepted reading, the final command, the owner codes, the contact observer's estimate).

    The engine builds its ``JointState`` and final ``ServoCommand`` on these views, so the cycle updates the row as it
    works and a record is one contiguous copy into the ring instead of thirteen (``np.concatenate`` of thirteen
    arrays: 1.8 µs for six joints; one copy: 0.3 µs). The fields of other types (``fresh``, ``fault``, ``mode``) are
    mirrored by the tap every cycle."""

    def __init__(self, joints: int) -> None:
        self.joints = joints
        self.buffer = np.zeros(row_width(joints))
        self.stage = self.buffer[: len(SCALARS)]  # tick, t, wall, period, duration
        per_joint = self.buffer[len(SCALARS) :].reshape(len(PER_JOINT), joints)
        self._fields = {name: per_joint[k] for k, name in enumerate(PER_JOINT)}
        self._fields["tau_ext"].fill(np.nan)  # no observer: NaN (one that runs writes its estimate here)

    def field(self, name: str) -> np.ndarray:
        """The row's view of one per-joint field (``PER_JOINT``): write it in place, never rebind it."""
        return self._fields[name]


MIRRORED = ("fresh", "fault", "mode")  # fields the tap copies into the row (their sources are not float64)


class Changes(Protocol):
    """What tells the tap that faults or modes changed: the supervisor's ``change_seq``, bumped with every change."""

    change_seq: int


class CycleLogTap:
    """The cycle's side: ``record`` copies one cycle into the ring, with no allocation that outlives the call.

    ``row``: the engine's ``CycleRow``, whose views are the engine's own arrays (see there); ``fresh``, ``fault`` and
    ``mode``: the sources the row mirrors (the accepted reading's flags, every cycle; the supervisor's latched faults
    and modes, whenever ``changes.change_seq`` moved: they change with it and only with it, and copying them every
    cycle would cost more than the rest of the row). ``stats``: the engine's loop statistics, read for the last
    completed cycle's duration (the current one's is known only after the step). Binding prefaults the ring: the
    cycle never takes a first-touch page fault in it."""

    def __init__(
        self,
        log: CycleLog,
        *,
        row: CycleRow,
        fresh: np.ndarray,
        fault: np.ndarray,
        mode: np.ndarray,
        changes: Changes,
        stats: LoopStats | None = None,
    ) -> None:
        if row.joints != log.joints:
            raise ValueError(f"the cycle log has {log.joints} joints; the engine's row has {row.joints}")
        sources = {"fresh": fresh, "fault": fault, "mode": mode}
        widths = {len(a) for a in sources.values()}
        if widths != {log.joints}:
            raise ValueError(f"the cycle log has {log.joints} joints; its sources have {sorted(widths)}")
        self.log = log
        self._buffer = row.buffer
        self._stage = row.stage
        self._fresh, self._fault, self._mode = (row.field(name) for name in MIRRORED)
        self._fresh_source, self._fault_source, self._mode_source = fresh, fault, mode
        self._changes = changes
        self._mirrored = -1  # changes.change_seq when faults and modes were last mirrored (-1: never)
        self._rows = log._rows
        self._header = log._header
        self._capacity = log.capacity
        self._written = log.head  # the producer's count (it alone advances head)
        # The loop statistics' duration window: its count cell and its values, read directly (one call less per
        # cycle than the window's properties; the window lives in this package).
        window = stats.duration if stats is not None else None
        self._duration_count = window._head if window is not None else None
        self._duration_values = window.values if window is not None else None
        log.prefault()

    def record(self, tick: int, t: float, wall: float, period: float) -> None:
        """Copy this cycle into the ring and publish it (on the cycle, after its write)."""
        stage = self._stage
        stage[0] = tick
        stage[1] = t
        stage[2] = wall
        stage[3] = period
        counted = self._duration_count
        if counted is not None and (count := counted.item(0)):
            values = self._duration_values
            stage[4] = values.item((count - 1) % values.shape[0]) * 1e-9
        np.copyto(self._fresh, self._fresh_source)
        if (seq := self._changes.change_seq) != self._mirrored:
            self._mirrored = seq
            np.copyto(self._fault, self._fault_source)
            np.copyto(self._mode, self._mode_source)
        written = self._written
        self._rows[written % self._capacity] = self._buffer  # the whole row: one contiguous copy
        self._written = written + 1
        self._header[_HEAD] = written + 1  # publish: the row is complete before a reader can see it
