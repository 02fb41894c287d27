"""What every emulated drive shares: the shaft it senses, a thermal model, and run-time fault injection.

A firmware is a pure state machine driven by `handle(msg, now)` and `tick(now)`; it never reads a clock, so an
emulator stepped with sim time is deterministic. Outgoing frames pass through one gate (`_emit`) that applies
the injected transport faults — drop with a seeded RNG, delay, silence — the same way for every vendor.
"""

from __future__ import annotations

import heapq
import math
import random
from dataclasses import dataclass

import can

from drivers.can.protocol.errors import FrameError
from drivers.glitch import ReadingGlitch


@dataclass
class ThermalModel:
    """First-order heating: each temperature relaxes toward ambient + rise·(τ/rated)² with its time constant.

    Crude on purpose: enough for plausible readings and for over-temperature faults under sustained load.
    """

    rated_torque: float
    ambient: float = 25.0
    rotor_rise_at_rated: float = 40.0
    rotor_time_constant: float = 60.0
    mos_rise_at_rated: float = 25.0
    mos_time_constant: float = 20.0

    def step(self, t_rotor: float, t_mos: float, torque: float, dt: float) -> tuple[float, float]:
        load = (torque / self.rated_torque) ** 2
        rotor_target = self.ambient + self.rotor_rise_at_rated * load
        mos_target = self.ambient + self.mos_rise_at_rated * load
        t_rotor += (rotor_target - t_rotor) * -math.expm1(-dt / self.rotor_time_constant)
        t_mos += (mos_target - t_mos) * -math.expm1(-dt / self.mos_time_constant)
        return t_rotor, t_mos


class MotorFirmware:
    """Base of every emulated drive.

    Run-time controls (plain attributes, safe to set from another thread between services):
    `drop_replies` probability of losing each outgoing frame, `reply_delay` seconds before a frame leaves,
    `silent` — the transceiver is cut: nothing is heard or sent (the drive's own watchdog still runs),
    `corrupt_replies` how many of the next outgoing frames leave one byte short (a frame the host must reject),
    `over_temperature` °C at which the drive faults, `glitch` (offset, spike, frozen, sign flip of the position its
    replies report, drivers/glitch.py); plus `inject_fault(code)`, `clear_fault()` and `reboot()`.
    """

    def __init__(self, *, rated_torque: float, seed: int = 0, thermal: ThermalModel | None = None) -> None:
        self.glitch = ReadingGlitch(1)  # corrupts the position its replies report (drivers/glitch.py), never the law
        self.drop_replies = 0.0
        self.reply_delay = 0.0
        self.silent = False
        self.corrupt_replies = 0
        self.over_temperature = 120.0
        self.thermal = thermal if thermal is not None else ThermalModel(rated_torque=rated_torque)
        self.temperature_rotor = self.thermal.ambient
        self.temperature_mos = self.thermal.ambient
        self.position = 0.0
        """Shaft position in the plant's frame (rad), as last observed."""
        self.velocity = 0.0
        self.applied_torque = 0.0
        """Torque the drive produced at the latest control-law evaluation (Nm)."""
        self.counters: dict[str, int] = {
            "handled": 0,
            "garbled": 0,
            "ignored": 0,
            "unheard": 0,
            "dropped": 0,
            "delayed": 0,
            "corrupted": 0,
        }
        self.last_error = ""
        """Reason of the latest garbled frame, for reports."""
        self._rng = random.Random(seed)
        self._pending: list[tuple[float, int, can.Message]] = []
        self._sequence = 0

    # -- to be provided by each vendor -------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        raise NotImplementedError

    @property
    def fault(self) -> int:
        raise NotImplementedError

    def accepts(self, msg: can.Message) -> bool:
        """True when `msg` is addressed to this drive (the emulator routes on it)."""
        raise NotImplementedError

    def torque(self, position: float, velocity: float) -> float:
        """The drive's control law on the plant state, clamped; 0 when not enabled."""
        raise NotImplementedError

    def inject_fault(self, code: int) -> None:
        raise NotImplementedError

    def clear_fault(self) -> None:
        """Operator-side reset (e.g. a power-cycled supply), not a CAN command."""
        raise NotImplementedError

    def reboot(self) -> None:
        """Power cycle: comes back disabled, fault-free, RAM settings lost."""
        raise NotImplementedError

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        """React to one frame; raise FrameError for a frame the firmware cannot parse."""
        raise NotImplementedError

    def _expire(self, now: float) -> None:
        """Run the watchdog up to `now`."""

    def _periodic(self, now: float) -> list[can.Message]:
        """Frames the drive sends on its own at `now`."""
        return []

    def _over_temperature_fault(self, rotor: bool) -> int:
        """The fault code this firmware latches for a hot rotor (True) or hot power stage (False)."""
        raise NotImplementedError

    # -- shared machinery --------------------------------------------------------------------------------------

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        """Process one received frame; returns the frames to send now (delayed ones come out of `tick`)."""
        if self.silent:
            self.counters["unheard"] += 1
            return []
        self._expire(now)
        try:
            replies = self._receive(msg, now)
        except FrameError as exc:
            self.counters["garbled"] += 1
            self.last_error = str(exc)
            return []
        self.counters["handled"] += 1
        return self._emit(replies, now)

    def tick(self, now: float) -> list[can.Message]:
        """Advance timers to `now`: watchdog, cyclic frames, and delayed replies that are due."""
        self._expire(now)
        if self.silent:
            self.counters["dropped"] += len(self._pending)
            self._pending.clear()
            return []
        out = self._emit(self._periodic(now), now)
        while self._pending and self._pending[0][0] <= now:
            out.append(heapq.heappop(self._pending)[2])
        return out

    def observe(self, position: float, velocity: float, dt: float) -> None:
        """The emulator reports the shaft state after advancing the plant by `dt` (heats the drive)."""
        self.position = position
        self.velocity = velocity
        if dt > 0.0:
            self.temperature_rotor, self.temperature_mos = self.thermal.step(
                self.temperature_rotor, self.temperature_mos, self.applied_torque, dt
            )
            if self.fault == 0:
                if self.temperature_rotor > self.over_temperature:
                    self.inject_fault(self._over_temperature_fault(rotor=True))
                elif self.temperature_mos > self.over_temperature:
                    self.inject_fault(self._over_temperature_fault(rotor=False))

    def _emit(self, frames: list[can.Message], now: float) -> list[can.Message]:
        if self.silent:
            return []
        out: list[can.Message] = []
        for frame in frames:
            if self.drop_replies > 0.0 and self._rng.random() < self.drop_replies:
                self.counters["dropped"] += 1
                continue
            if self.corrupt_replies > 0:
                self.corrupt_replies -= 1
                self.counters["corrupted"] += 1
                frame = _cut_short(frame)
            if self.reply_delay > 0.0:
                self.counters["delayed"] += 1
                self._sequence += 1
                heapq.heappush(self._pending, (now + self.reply_delay, self._sequence, frame))
            else:
                out.append(frame)
        return out

    def _ignore(self) -> list[can.Message]:
        """A well-formed frame this firmware does not act on."""
        self.counters["ignored"] += 1
        return []


def _cut_short(frame: can.Message) -> can.Message:
    """The frame with its last data byte lost: what a host sees of a reply mangled on its way (a DLC it rejects)."""
    return can.Message(
        arbitration_id=frame.arbitration_id,
        data=bytes(frame.data[:-1]),
        is_extended_id=frame.is_extended_id,
        is_remote_frame=frame.is_remote_frame,
        is_fd=frame.is_fd,
    )
