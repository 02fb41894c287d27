"""The emulator loop on the wall clock (drivers/can/emulator/core.py, `serve_on_grid` and `frame_wakeup`).

The finding ([teleop], the command path): across the loopback bridge the emulated drive read a frame only at its
loop's next service — every 0.2 ms in the bench rig, every 1/rate in ``hild emulate`` (0.5 ms at the default rate
beside a 1 kHz daemon) — so up to a period sat between the wire and the drive: in the bench's command → frame
figure, and in every reply. Here a frame wakes the loop. The grid tests drive the loop with a scripted clock and
scripted wakes (no time passes); the bridge tests give the grid a period of an hour, so a reply within seconds can
only come from a frame waking the loop.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import pytest

from drivers.can.emulator import DamiaoFirmware, Emulator, MotorPlant
from drivers.can.emulator.core import frame_wakeup, loop_stats, serve_on_grid
from drivers.can.emulator.remote_host import RemoteServerBus
from drivers.can.emulator.runtime import RuntimeOptions, build_runtime
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.flavours import DAMIAO
from drivers.can.protocol.mit import MitRanges
from hild.config import load_config
from tests.drivers.can.test_emulate_runtime import arm6
from tests.drivers.can.test_remote_host import close

DM4310 = MitRanges(12.5, 30.0, 10.0)
WAIT = 10.0  # s: generous; a reply normally takes a fraction of a millisecond
AN_HOUR = 3600.0  # s: a grid period no test waits out


class Script:
    """A clock that moves only when told, and a wake that says when a frame comes (at a time of the script) or
    lets the whole timeout pass; ``stop`` after ``services`` services."""

    def __init__(self, frames: list[float], services: int, cost: dict[float, float] | None = None) -> None:
        self.now = 0.0
        self.frames = frames
        self.cost = cost or {}
        self.served: list[float] = []
        self.stop = threading.Event()
        self.services = services

    def clock(self) -> float:
        return self.now

    def service(self, now: float) -> None:
        self.served.append(now)
        self.now += self.cost.get(now, 0.0)
        if len(self.served) == self.services:
            self.stop.set()

    def wake(self, timeout: float) -> bool:
        if self.frames and self.frames[0] <= self.now + timeout:
            self.now = max(self.now, self.frames.pop(0))
            return True
        self.now += timeout
        return False


def test_a_frame_between_two_ticks_is_served_at_once_and_the_grid_keeps_its_times() -> None:
    script = Script(frames=[0.4, 2.25], services=6)
    stats = loop_stats()
    serve_on_grid(script.service, 1.0, script.stop, wake=script.wake, stats=stats, clock=script.clock)
    assert script.served == pytest.approx([0.0, 0.4, 1.0, 2.0, 2.25, 3.0])
    assert stats["services"] == 6 and stats["woken"] == 2 and stats["overruns"] == 0
    assert stats["max_late_ms"] == 0.0 and stats["max_gap_ms"] == pytest.approx(1000.0)


def test_a_woken_service_that_runs_into_the_tick_is_followed_by_the_tick_not_counted_an_overrun() -> None:
    script = Script(frames=[0.9], services=4, cost={0.9: 0.2})
    stats = loop_stats()
    serve_on_grid(script.service, 1.0, script.stop, wake=script.wake, stats=stats, clock=script.clock)
    assert script.served == pytest.approx([0.0, 0.9, 1.1, 2.0])
    assert stats["overruns"] == 0 and stats["max_late_ms"] == pytest.approx(100.0)


def test_an_overrun_restarts_the_grid_instead_of_bursting_to_catch_up() -> None:
    script = Script(frames=[], services=4, cost={1.0: 2.5})
    stats = loop_stats()
    serve_on_grid(script.service, 1.0, script.stop, wake=script.wake, stats=stats, clock=script.clock)
    assert script.served == pytest.approx([0.0, 1.0, 3.5, 4.5])
    assert stats["overruns"] == 1 and stats["woken"] == 0


def test_waits_are_cut_short_so_a_stop_is_seen_however_long_the_period() -> None:
    waits: list[float] = []
    stop = threading.Event()

    def wake(timeout: float) -> bool:
        waits.append(timeout)
        if len(waits) == 3:
            stop.set()
        return False

    serve_on_grid(lambda now: None, AN_HOUR, stop, wake=wake)
    assert len(waits) == 3 and max(waits) <= 0.1


def test_a_virtual_bus_has_nothing_to_wait_on_and_its_loop_polls() -> None:
    bus = can.Bus(interface="virtual", channel="wakeup-virtual")
    try:
        assert frame_wakeup([bus]) is None
    finally:
        bus.shutdown()


class FileBus:
    """What frame_wakeup needs of a socketcan bus: its socket's descriptor."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def fileno(self) -> int:
        return self.sock.fileno()


def test_a_bus_with_a_file_wakes_the_loop_when_it_has_something_to_read() -> None:
    wire, drive_end = socket.socketpair()
    with wire, drive_end:
        wake = frame_wakeup([FileBus(drive_end)])
        assert wake is not None
        assert wake(0.0) is False
        wire.send(b"frame")
        assert wake(AN_HOUR) is True


def looping(target: Callable[[], None]) -> threading.Thread:
    thread = threading.Thread(target=target, name="test-emulator-loop", daemon=True)
    thread.start()
    return thread


def stopped(stop: threading.Event, thread: threading.Thread) -> None:
    stop.set()
    thread.join(WAIT)
    assert not thread.is_alive()


def test_across_the_bridge_a_client_and_its_frames_wake_the_loop_between_two_ticks(served: RemoteServerBus) -> None:
    emulator = Emulator(served, [DamiaoFirmware(1, 0x11, DM4310)], MotorPlant(1))
    stop, stats = threading.Event(), loop_stats()
    wake = frame_wakeup([served])
    thread = looping(lambda: serve_on_grid(emulator.service, AN_HOUR, stop, wake=wake, stats=stats))
    host = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{served.address[1]}/")
    try:
        for _ in range(3):
            host.send(DAMIAO.special(1, "enable"))
            reply = host.recv(timeout=WAIT)  # the next tick is an hour away
            assert reply is not None and DAMIAO.decode_reply(reply, DM4310, 1).enabled
    finally:
        stopped(stop, thread)
        close(lambda: emulator.service(time.monotonic()), host)
    assert stats["services"] - stats["woken"] == 1  # the first tick; every other service was woken, at least once
    assert stats["woken"] >= 3  # per command (the first may come with the client's arrival)


def test_hild_emulate_answers_a_remote_frame_at_once_however_low_its_rate(write_config: Callable[..., Path]) -> None:
    config = arm6(bus={"interface": "remote", "channel": "ws://127.0.0.1:54701/"})
    runtime = build_runtime(load_config(write_config(config)), RuntimeOptions(plant="motors"))
    runtime.open(serve_remote=("127.0.0.1", 0))
    try:
        thread = looping(lambda: runtime.run(AN_HOUR))
        assert runtime.remote_address is not None
        daemon = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{runtime.remote_address[1]}/")
        try:
            daemon.send(reg.refresh_request(0x03))  # the elbow's drive, MST_ID 0x13
            reply = daemon.recv(timeout=WAIT)
            assert reply is not None and reply.arbitration_id == 0x13
        finally:
            stopped(runtime.stop_event, thread)
            close(lambda: runtime.service(time.monotonic()), daemon)
        loop = runtime.loop_stats
        assert loop["services"] - loop["woken"] == 1 and loop["woken"] >= 1  # the first tick, then the frame's
    finally:
        runtime.close()
