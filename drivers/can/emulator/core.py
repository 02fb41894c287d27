"""The emulator loop: one bus, several drives, one plant, advanced in sim or wall time.

`service(now)` is the whole cycle and never blocks: advance the plant from the previous call to `now` under the
drives' control laws (sub-stepped, since real drives close their loops far faster than a host cycle), drain the
bus and hand every frame to the drives it addresses (every one that listens: CANopen's NMT and SYNC are
broadcasts), run the drives' timers, send what they answer. Called with sim time it is deterministic, so
lockstep tests can interleave host writes, `service(t)` and host reads.
`bus_off(now, duration)` takes the bus down for a while (fault injection): an error frame of the bus-off class to
every node, then no frame passes either way until it is back, when an error frame of the restarted class follows.
`serve_on_grid` runs services on the wall clock: on a fixed grid, and — on buses with a file to wait on (socketcan,
`RemoteServerBus`; `frame_wakeup`) — also the moment a frame arrives, so a reply leaves when the command is on the
wire, not up to a grid period later.
"""

from __future__ import annotations

import math
import select
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import can
import numpy as np

from drivers.can.bus import ERR_BUS_OFF, ERR_RESTARTED
from drivers.can.emulator.base import MotorFirmware
from drivers.can.emulator.plant import Plant


class Emulator:
    """Drives `motors[i]` act on joint i of `plant`.

    `max_step` bounds the plant's sub-step (s); `max_catch_up` bounds how much time one call simulates, so a
    stalled wall-clock loop resumes instead of grinding through the backlog (the plant simply loses that time).
    `counters`: received, unknown (no drive addressed), error_frames, sent, send_errors; drive-level counts
    (garbled, ignored, dropped, delayed, …) are summed in `stats()`.
    """

    def __init__(
        self,
        bus: can.BusABC,
        motors: Sequence[MotorFirmware],
        plant: Plant,
        *,
        max_step: float = 0.0005,
        max_catch_up: float = 1.0,
    ) -> None:
        if len(plant.positions) != len(motors):
            raise ValueError(f"plant has {len(plant.positions)} joints for {len(motors)} motors")
        if max_step <= 0.0 or max_catch_up <= 0.0:
            raise ValueError("max_step and max_catch_up must be positive")
        self.bus = bus
        self.motors = list(motors)
        self.plant = plant
        self.max_step = max_step
        self.max_catch_up = max_catch_up
        self.counters: dict[str, int] = {
            "received": 0,
            "unknown": 0,
            "error_frames": 0,
            "sent": 0,
            "send_errors": 0,
            "lost_bus_off": 0,
        }
        self.last_send_error = ""
        self.time: float | None = None
        """Sim/wall time of the latest service, None before the first."""
        self.down_until: float | None = None
        """While the bus is off (`bus_off`): the time it comes back."""
        self._torques = np.zeros(len(self.motors))
        for i, motor in enumerate(self.motors):
            motor.observe(float(plant.positions[i]), float(plant.velocities[i]), 0.0)

    def service(self, now: float) -> None:
        self._advance(now)
        if self.down_until is not None:
            if now < self.down_until:
                self._serve_dead_bus(now)
                return
            self.down_until = None
            self._send([_error_frame(ERR_RESTARTED)])
        recv = self.bus.recv
        while (msg := recv(timeout=0)) is not None:
            self.counters["received"] += 1
            if msg.is_error_frame:
                self.counters["error_frames"] += 1
                continue
            heard = False
            for motor in self.motors:  # every drive that listens: CANopen's NMT and SYNC are broadcasts
                if motor.accepts(msg):
                    heard = True
                    self._send(motor.handle(msg, now))
            if not heard:
                self.counters["unknown"] += 1
        for motor in self.motors:
            self._send(motor.tick(now))

    def bus_off(self, now: float, duration: float) -> None:
        """Fault injection: the bus goes off at `now` for `duration` s (see the module docstring)."""
        if duration <= 0.0:
            raise ValueError("a bus-off lasts a positive time")
        self._send([_error_frame(ERR_BUS_OFF)])
        self.down_until = now + duration

    def _serve_dead_bus(self, now: float) -> None:
        """No frame gets through: what the host sent is lost, the drives hear nothing (their watchdogs run)."""
        while self.bus.recv(timeout=0) is not None:
            self.counters["lost_bus_off"] += 1
        for motor in self.motors:
            self.counters["lost_bus_off"] += len(motor.tick(now))

    def run(self, stop: threading.Event, period: float, clock: Callable[[], float] = time.monotonic) -> None:
        """Serve on the wall clock every `period` s, and whenever a frame arrives, until `stop` is set."""
        serve_on_grid(self.service, period, stop, wake=frame_wakeup([self.bus]), clock=clock)

    def stats(self) -> dict[str, int]:
        """Emulator counters plus the drives' counters summed."""
        total = dict(self.counters)
        for motor in self.motors:
            for key, value in motor.counters.items():
                total[key] = total.get(key, 0) + value
        return total

    def _advance(self, now: float) -> None:
        last, self.time = self.time, now if self.time is None else max(self.time, now)
        if last is None or now <= last:
            return
        span = min(now - last, self.max_catch_up)
        steps = math.ceil(span / self.max_step - 1e-9)
        h = span / steps
        positions, velocities, torques = self.plant.positions, self.plant.velocities, self._torques
        motors = self.motors
        for _ in range(steps):
            for i, motor in enumerate(motors):
                torques[i] = motor.torque(float(positions[i]), float(velocities[i]))
            self.plant.step(torques, h)
        for i, motor in enumerate(motors):
            motor.observe(float(positions[i]), float(velocities[i]), span)

    def _send(self, frames: list[can.Message]) -> None:
        for frame in frames:
            try:
                self.bus.send(frame)
            except (can.CanError, OSError) as exc:
                self.counters["send_errors"] += 1
                self.last_send_error = str(exc)
            else:
                self.counters["sent"] += 1


STOP_POLL = 0.1  # s: the longest wait between two looks at the stop event, however long the grid's period


def serve_on_grid(
    service: Callable[[float], None],
    period: float,
    stop: threading.Event,
    *,
    wake: Callable[[float], bool] | None = None,
    stats: dict[str, float] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Call ``service(now)`` every ``period`` s on an absolute grid of ``clock`` until ``stop`` is set.

    With ``wake`` (from `frame_wakeup`: ``wake(timeout)`` is True once a frame may wait on a bus, False after the
    timeout) the loop also serves the moment a frame arrives between two ticks, so a drive answers a frame when it
    is on the wire, as a drive does, rather than when the grid comes round (up to a period later); the ticks keep
    the drives' timers and the plant going. Without it the loop sleeps to each tick (python-can's ``virtual`` bus
    has no file to wait on). An overrun restarts the grid rather than bursting to catch up. ``stats``, when given,
    counts ``services``, ``woken`` (of them, on a frame) and ``overruns``, and keeps ``max_late_ms`` (a tick's
    lateness) and ``max_gap_ms`` (the longest time between two services: a service that ran long shows there).
    """
    wait = stop.wait if wake is None else wake
    deadline = last = clock()
    while not stop.is_set():
        now = clock()
        tick = now >= deadline
        if stats is not None:
            stats["services"] += 1
            if not tick:
                stats["woken"] += 1
            elif now - deadline > stats["max_late_ms"] / 1000.0:
                stats["max_late_ms"] = (now - deadline) * 1000.0
            if now - last > stats["max_gap_ms"] / 1000.0:
                stats["max_gap_ms"] = (now - last) * 1000.0
        last = now
        service(now)
        if tick:
            deadline += period
            if deadline <= clock():  # overran: restart the grid instead of bursting to catch up
                if stats is not None:
                    stats["overruns"] += 1
                deadline = clock()
                continue
        while (delay := deadline - clock()) > 0.0:  # a woken service that reached the deadline: the tick follows
            if wait(min(delay, STOP_POLL)) or stop.is_set():
                break


def loop_stats() -> dict[str, float]:
    """Fresh counters for `serve_on_grid`."""
    return {"services": 0, "woken": 0, "overruns": 0, "max_late_ms": 0.0, "max_gap_ms": 0.0}


class Waitable(Protocol):
    """A bus whose files change while it runs (`RemoteServerBus`: a socket per client, and its arrivals)."""

    def waitables(self) -> tuple[list[Any], list[Any]]:
        """What to wait on now: the files that may bring a frame, and those with output waiting for room."""
        ...


def frame_wakeup(buses: Sequence[Any]) -> Callable[[float], bool] | None:
    """``wake(timeout)`` for `serve_on_grid` over ``buses``: True as soon as any of them may hold a frame (or has
    room for what waits to go out), False after ``timeout`` s. None when one of them has no file to wait on
    (python-can's ``virtual``): then the loop polls on its grid."""
    fixed: list[int] = []
    served: list[Waitable] = []
    for bus in buses:
        if hasattr(bus, "waitables"):
            served.append(bus)
            continue
        try:
            fd = bus.fileno()  # socketcan: its socket
        except (NotImplementedError, AttributeError, OSError):
            return None
        if not isinstance(fd, int) or fd < 0:
            return None
        fixed.append(fd)

    def wake(timeout: float) -> bool:
        readable: list[Any] = list(fixed)
        writable: list[Any] = []
        for bus in served:
            more, room = bus.waitables()
            readable += more
            writable += room
        try:
            ready = select.select(readable, writable, (), timeout)  # to the µs: poll and epoll round up to a ms
            return bool(ready[0] or ready[1])
        except ValueError:  # a descriptor past FD_SETSIZE: wait with poll, to the millisecond
            poller = select.poll()
            for file in {*readable, *writable}:
                poller.register(
                    file, (select.POLLIN if file in readable else 0) | (select.POLLOUT if file in writable else 0)
                )
            return bool(poller.poll(timeout * 1000.0))

    return wake


def _error_frame(error_class: int) -> can.Message:
    """An error frame as SocketCAN delivers it: the class bits in the id, 8 data bytes of detail."""
    return can.Message(arbitration_id=error_class, data=bytes(8), is_error_frame=True, is_extended_id=False)
