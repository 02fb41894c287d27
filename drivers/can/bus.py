"""One CAN bus as a host driver sees it: opened from config, used without blocking, and budgeted in bit times.

* ``BusSpec`` / ``open_bus``: any python-can interface (socketcan incl. vcan, pcan, slcan, gs_usb, kvaser, virtual,
  remote, …) with bitrate, CAN-FD and extra interface options from the config.
* ``CanLink``: the cycle-side handle. ``send`` never waits (``timeout=0``) and counts failures instead of raising;
  ``poll`` is ``recv(timeout=0)``, which on fd-based buses (socketcan) is a zero-timeout ``select`` plus one read, so
  draining happens inside the cycle with no thread hop (``receive`` is the same in a loop, for the cycle). Bus
  errors (error frames, bus-off, a dead interface, a send queue that stays full) latch a ``problem`` that the driver
  reports through ``health()``.
* ``BadFrames``: counts frames a driver could not use, by kind, and turns them into at most one event per interval.
* ``frame_bits``: worst-case frame length (bit stuffing included), for ``hild check``'s bus-load figure.
"""

from __future__ import annotations

import contextlib
import errno
import time
from collections.abc import Callable, Sequence
from typing import Any

import can

from hild.config.params import Field, Params, model_validator
from hild.hardware import HardwareError

# Linux can/error.h: class bits in the arbitration id of an error frame, controller detail in data[1].
ERR_TX_TIMEOUT = 0x001
ERR_LOST_ARBITRATION = 0x002
ERR_CONTROLLER = 0x004
ERR_PROTOCOL = 0x008
ERR_TRANSCEIVER = 0x010
ERR_NO_ACK = 0x020
ERR_BUS_OFF = 0x040
ERR_BUS_ERROR = 0x080
ERR_RESTARTED = 0x100
_CTRL_PASSIVE = 0x10 | 0x20
_CTRL_OVERFLOW = 0x01 | 0x02

_RESERVED_OPTIONS = frozenset({"interface", "channel", "bitrate", "fd", "data_bitrate", "receive_own_messages"})


class BusSpec(Params):
    """How to open one bus. ``options`` go to ``can.Bus`` unchanged (e.g. pcan's ``f_clock_mhz``, gs_usb's index)."""

    interface: str = Field(default="socketcan", description="python-can interface name (socketcan, pcan, virtual, …).")
    channel: str | int = Field(description="Interface channel, e.g. can0, vcan0, PCAN_USBBUS1.")
    bitrate: int = Field(default=1_000_000, gt=0, le=1_000_000, description="Nominal (arbitration) bitrate, bit/s.")
    fd: bool = Field(default=False, description="CAN-FD frames (commands are sent as FD frames).")
    data_bitrate: int | None = Field(
        default=None, gt=0, le=12_000_000, description="CAN-FD data-phase bitrate with bit-rate switch; FD only."
    )
    options: dict[str, Any] = Field(default_factory=dict, description="Extra keyword arguments for can.Bus.")

    @model_validator(mode="after")
    def _consistent(self) -> BusSpec:
        if self.data_bitrate is not None and not self.fd:
            raise ValueError("data_bitrate needs fd: true")
        if self.data_bitrate is not None and self.data_bitrate < self.bitrate:
            raise ValueError(f"data_bitrate {self.data_bitrate} is below the nominal bitrate {self.bitrate}")
        clash = sorted(_RESERVED_OPTIONS & set(self.options))
        if clash:
            raise ValueError(f"options may not repeat {', '.join(clash)}: use the bus keys of the same name")
        return self

    @property
    def name(self) -> str:
        """A stable name of the medium, so ``hild check`` can add up the components sharing it."""
        return f"{self.interface}:{self.channel}"


def open_bus(spec: BusSpec) -> can.BusABC:
    """Open the bus; any failure becomes a HardwareError that names the interface and channel."""
    kwargs: dict[str, Any] = {"bitrate": spec.bitrate, "receive_own_messages": False, **spec.options}
    if spec.fd:
        kwargs["fd"] = True
        if spec.data_bitrate is not None:
            kwargs["data_bitrate"] = spec.data_bitrate
    try:
        return can.Bus(interface=spec.interface, channel=spec.channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError, TypeError) as exc:
        raise HardwareError(f"cannot open CAN bus {spec.name}: {type(exc).__name__}: {exc}") from exc


# ---- bit budget -------------------------------------------------------------------------------------------------

_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def frame_bits(payload: int, *, fd: bool = False, brs_ratio: float = 1.0, extended: bool = False) -> float:
    """Worst-case length of one data frame in nominal bit times, bit stuffing and the 3-bit intermission included.

    Classic CAN: 47 + 8n + ⌊(34 + 8n − 1)/4⌋ for 11-bit ids (135 for 8 bytes), 67 + 8n + ⌊(54 + 8n − 1)/4⌋ for
    29-bit ids. CAN-FD: the arbitration phase (SOF … BRS, ≤ 1 stuff bit per 4) and the tail (CRC delimiter, ACK,
    EOF, intermission) run at the nominal rate; ESI, DLC, data with worst-case dynamic stuffing, stuff count, CRC-17
    (CRC-21 above 16 bytes) and its fixed stuff bits run at the data rate, i.e. count ``1 / brs_ratio`` each.
    """
    if not fd:
        if payload > 8:
            raise ValueError(f"a classic CAN frame carries at most 8 bytes, not {payload}")
        if extended:
            return 67 + 8 * payload + (54 + 8 * payload - 1) // 4
        return 47 + 8 * payload + (34 + 8 * payload - 1) // 4
    n = next((size for size in _FD_LENGTHS if size >= payload), None)
    if n is None:
        raise ValueError(f"a CAN-FD frame carries at most 64 bytes, not {payload}")
    head = (1 + 29 + 1 + 1 + 1 + 1 + 1 + 1) if extended else (1 + 11 + 1 + 1 + 1 + 1 + 1)  # SOF … BRS
    head += (head - 1) // 4
    tail = 1 + 2 + 7 + 3
    crc = 17 if n <= 16 else 21
    data = 1 + 4 + 8 * n
    data += (data - 1) // 4 + 4 + crc + (crc + 4 + 3) // 4
    return head + tail + data / brs_ratio


def bits_per_second(spec: BusSpec, frames: Sequence[tuple[int, float]], *, extended: bool = False) -> float:
    """Nominal-rate bit times per second for ``frames`` = [(payload bytes, frames per second), …] on ``spec``."""
    ratio = spec.data_bitrate / spec.bitrate if spec.fd and spec.data_bitrate else 1.0
    return sum(rate * frame_bits(size, fd=spec.fd, brs_ratio=ratio, extended=extended) for size, rate in frames)


def rtr_bits(*, extended: bool = False) -> float:
    """A classic remote (RTR) frame carries no data: the 0-byte length."""
    return frame_bits(0, extended=extended)


# ---- the cycle-side handle ----------------------------------------------------------------------------------------


class CanLink:
    """One open bus plus its error bookkeeping. Cycle methods (``send``, ``poll``, ``end_cycle``) never block.

    ``serve_while_waiting``: an optional callable run while a lifecycle hook waits for replies. In-process
    emulators (tests, benchmarks) service their motors from it; on real hardware it stays None and the wait is a
    short ``recv``.
    """

    def __init__(self, spec: BusSpec, send_failure_cycles: int = 3) -> None:
        self.spec = spec
        self.send_failure_cycles = send_failure_cycles
        self.bus: can.BusABC | None = None
        self.serve_while_waiting: Callable[[], None] | None = None
        self.problem: str | None = None  # latched until clear()
        self.frames_sent = 0
        self.frames_received = 0
        self.send_failures = 0
        self.error_frames = 0
        self.passive_reports = 0
        self._cycle_failed = False
        self._failed_cycles = 0
        self._last_send_error = ""

    # lifecycle
    def open(self) -> None:
        self.bus = open_bus(self.spec)

    def close(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            with contextlib.suppress(can.CanError, OSError):
                bus.shutdown()

    def reopen(self) -> None:
        """Close and open the bus again (operator reset after bus-off with ``bus_recovery: reopen``)."""
        self.close()
        self.open()
        self.clear()

    def clear(self) -> None:
        self.problem = None
        self._failed_cycles = 0
        self._cycle_failed = False

    def make_message(self, arbitration_id: int, data: bytes = b"", *, rtr: bool = False) -> can.Message:
        """A frame with this bus's FD flags (remote frames are always classic)."""
        fd = self.spec.fd and not rtr
        return can.Message(
            arbitration_id=arbitration_id,
            data=bytearray(data),
            dlc=len(data),
            is_extended_id=False,
            is_remote_frame=rtr,
            is_fd=fd,
            bitrate_switch=fd and self.spec.data_bitrate is not None,
        )

    # cycle
    def send(self, msg: can.Message) -> bool:
        """Queue one frame without waiting; a failure is counted (and latched if it persists), never raised."""
        bus = self.bus
        if bus is None:
            self._fail("bus closed")
            return False
        try:
            bus.send(msg, timeout=0)
        except can.CanError as exc:
            code = getattr(exc, "error_code", None)
            if code == errno.ENOBUFS or "buffer" in str(exc).lower():
                self._fail("send buffer full")
            else:
                self._fail(f"send failed: {exc}")
                self.latch(f"bus error: send failed: {exc}")
            return False
        self.frames_sent += 1
        return True

    def _fail(self, reason: str) -> None:
        self.send_failures += 1
        self._cycle_failed = True
        self._last_send_error = reason

    def end_cycle(self) -> None:
        """Call once after a cycle's sends: a send queue full for ``send_failure_cycles`` cycles in a row latches."""
        if self._cycle_failed:
            self._cycle_failed = False
            self._failed_cycles += 1
            if self._failed_cycles >= self.send_failure_cycles:
                self.latch(
                    f"{self._last_send_error} for {self._failed_cycles} cycles ({self.send_failures} frames lost)"
                )
        else:
            self._failed_cycles = 0

    def poll(self) -> can.Message | None:
        """The next received data frame, or None when nothing is waiting. Error frames are consumed here."""
        bus = self.bus
        if bus is None:
            return None
        while True:
            try:
                msg = bus.recv(timeout=0)
            except (can.CanError, OSError, ValueError) as exc:
                self.latch(f"bus error: receive failed: {exc}")
                return None
            if msg is None:
                return None
            if msg.is_error_frame:
                self._error_frame(msg)
                continue
            self.frames_received += 1
            return msg

    def receive(self, accept: Callable[[can.Message], None], budget: int) -> None:
        """Feed up to ``budget`` waiting data frames to ``accept`` without blocking; error frames are consumed here.

        ``poll`` in a loop, without a call and a closed-bus check per frame: this is the cycle's receive path.
        """
        bus = self.bus
        if bus is None:
            return
        recv = bus.recv
        taken = 0
        try:
            while taken < budget:
                try:
                    msg = recv(timeout=0)
                except (can.CanError, OSError, ValueError) as exc:
                    self.latch(f"bus error: receive failed: {exc}")
                    return
                if msg is None:
                    return
                if msg.is_error_frame:
                    self._error_frame(msg)
                    continue
                taken += 1
                accept(msg)
        finally:
            self.frames_received += taken

    def _error_frame(self, msg: can.Message) -> None:
        self.error_frames += 1
        cls = msg.arbitration_id
        if cls & ERR_BUS_OFF:
            self.latch("bus off")
        elif cls & ERR_CONTROLLER and len(msg.data) > 1 and msg.data[1] & _CTRL_PASSIVE:
            self.passive_reports += 1

    def latch(self, problem: str) -> None:
        if self.problem is None:
            self.problem = problem

    def check_state(self) -> str | None:
        """The latched problem, after asking backends that track it (pcan, kvaser, …) for their bus state."""
        bus = self.bus
        if self.problem is None and bus is not None:
            try:
                state = bus.state
            except (can.CanError, OSError, NotImplementedError):
                state = can.BusState.ACTIVE
            if state is can.BusState.ERROR:
                self.latch("bus off")
        return self.problem

    # lifecycle waits (non real-time)
    def send_wait(self, msg: can.Message, timeout: float = 0.1) -> None:
        """Send outside the cycle, retrying while the transmit queue is full (socketcan's txqueuelen is 10)."""
        bus = self.bus
        if bus is None:
            raise HardwareError(f"CAN bus {self.spec.name} is not open")
        deadline = time.monotonic() + timeout
        while True:
            try:
                bus.send(msg, timeout=0)
            except can.CanError as exc:
                full = getattr(exc, "error_code", None) == errno.ENOBUFS or "buffer" in str(exc).lower()
                if not full or time.monotonic() >= deadline:
                    raise HardwareError(f"CAN bus {self.spec.name}: send failed: {exc}") from exc
                time.sleep(0.0005)
                continue
            self.frames_sent += 1
            return

    def collect(self, handle: Callable[[can.Message], None], done: Callable[[], bool], timeout: float) -> bool:
        """Feed received frames to ``handle`` until ``done()`` or ``timeout`` seconds pass; True when done."""
        deadline = time.monotonic() + timeout
        while not done():
            if self.serve_while_waiting is not None:
                self.serve_while_waiting()
            msg = self.poll()
            if msg is not None:
                handle(msg)
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return done()
            if self.serve_while_waiting is None and self.bus is not None:
                try:
                    msg = self.bus.recv(timeout=min(remaining, 0.005))
                except (can.CanError, OSError, ValueError) as exc:
                    raise HardwareError(f"CAN bus {self.spec.name}: receive failed: {exc}") from exc
                if msg is not None:
                    if msg.is_error_frame:
                        self._error_frame(msg)
                    else:
                        self.frames_received += 1
                        handle(msg)
        return True

    def drain(self) -> int:
        """Drop whatever is queued (frames from before we started listening); returns how many."""
        count = 0
        while self.poll() is not None:
            count += 1
        return count


class BadFrames:
    """Frames a driver could not use, counted per kind and reported as one summarising event per interval.

    ``note`` runs on the cycle thread and only increments counters; ``report`` emits at most one event per
    ``interval`` seconds of the cycle clock, so garbage on the bus can never flood the event log.
    """

    def __init__(self, emit: Callable[[str, str], None], source: str, interval: float = 1.0) -> None:
        self.emit = emit
        self.source = source
        self.interval = interval
        self.totals: dict[str, int] = {}
        self._pending: dict[str, int] = {}
        self._last_id: dict[str, int] = {}
        self._next_report = 0.0

    def note(self, kind: str, arbitration_id: int) -> None:
        self.totals[kind] = self.totals.get(kind, 0) + 1
        self._pending[kind] = self._pending.get(kind, 0) + 1
        self._last_id[kind] = arbitration_id

    @property
    def total(self) -> int:
        return sum(self.totals.values())

    def report(self, t: float) -> None:
        if not self._pending or t < self._next_report:
            return
        parts = [f"{n} {kind} (last id {self._last_id[kind]:#x})" for kind, n in sorted(self._pending.items())]
        self._pending.clear()
        self._next_report = t + self.interval
        self.emit("warning", f"ignored CAN frames: {'; '.join(parts)}")  # the event names the source
