"""The CAN bench rig: Damiao motors emulated in-process on python-can ``virtual`` channels, for ``hild bench``.

A ``hild bench`` scenario runs the real daemon in a child process (``hild.bench.host``); for MIT-CAN scenarios
this rig (``hild.bench.rigs.rig_class("mit_can")``) adds to that process what a robot would
have on the wire: n Damiao drives (DM4340 at the base, DM4310 at the wrist, firmware-faithful, ``drivers.can.
emulator``) behind independent motor plants, serviced by one thread every ``EMULATOR_PERIOD`` (bridged: every
``WOKEN_PERIOD``, and at once when a frame arrives — ``drivers.can.emulator.core.serve_on_grid``). The motors are
spread over as many 1 Mbit/s buses as their traffic needs (``hild check`` refuses an over-full bus): 3 per bus
at 1 kHz, 6 at 500 Hz, one ``mit_can`` component per bus, as a real arm would be wired.

For latencies the emulator's bus is wrapped in a :class:`FrameTap`: while listening it keeps the time and bytes
of every command frame the first motor receives (stamped by the virtual bus at the driver's ``send``) and every
reply it sends. No extra bus joins the channel, so listening adds no frame copies to the cycle. Stamps are
``time.time()`` (the virtual bus's clock) converted to ``perf_counter_ns`` (CLOCK_MONOTONIC, system-wide), so the
bench compares them with stamps taken in its own process.

In one process the emulator thread competes with the cycle for the GIL (real drives answer from their own
silicon), so CAN cycle figures are an upper bound; its CPU is reported apart from the daemon's. With the cycle in a
process of its own the rig runs in a process of its own too (:mod:`hild.bench.rigs.can_process`), each bus a
loopback server its loop reads: the frames are then stamped when that loop reads them off the socket, which a
frame's arrival wakes (no poll period between the wire and the stamp).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import can

from drivers.can.bus import BusSpec, frame_bits, open_bus
from drivers.can.emulator import Emulator, MotorFirmware, MotorPlant, Plant
from drivers.can.emulator.core import frame_wakeup, serve_on_grid
from drivers.can.emulator.runtime import build_firmware
from drivers.can.mit_driver import MotorWiring, wire_motors
from drivers.can.params import MitCanParams
from drivers.can.protocol.mit import POSITION_BITS, decode_command, decode_state, special_kind
from hild.config.loader import LoadedConfig

EMULATOR_PERIOD = 0.0002  # s between services: a reply within ~0.2 ms, like a drive's
WOKEN_PERIOD = 0.001  # s between services when a frame wakes the loop (bridged buses): the grid keeps timers going
P = TypeVar("P")
START_POSITIONS = (0.2, -0.3, 0.4, -0.1, 0.3, -0.2)  # rad, where the emulated motors power up
BITRATE = 1_000_000
BUS_LOAD = 0.9  # of the bit time a bus may carry
STALE_FEEDBACK_CYCLES = 50
CLOCK_PAIRS = 9  # (time.time, perf_counter) readings; the tightest pair gives the offset between the clocks


@dataclass(frozen=True)
class MotorKind:
    """A Damiao model and joint settings that fit it (effort below TMAX, gains inside the MIT kp/kd ranges)."""

    model: str
    effort: float
    velocity: float
    acceleration: float
    jerk: float
    kp: float
    kd: float


DM4340 = MotorKind("DM4340", effort=25.0, velocity=3.0, acceleration=8.0, jerk=80.0, kp=60.0, kd=2.5)  # 28 N·m
DM4310 = MotorKind("DM4310", effort=9.0, velocity=4.0, acceleration=12.0, jerk=120.0, kp=30.0, kd=1.0)  # 10 N·m


def motor_kinds(n: int) -> list[MotorKind]:
    """Bigger motors at the base, smaller at the wrist, like a small arm."""
    big = (n + 1) // 2
    return [DM4340] * big + [DM4310] * (n - big)


def motors_per_bus(rate: float, bitrate: int = BITRATE) -> int:
    """How many MIT motors (a command and an 8-byte reply each per cycle) one classic bus carries at ``rate``
    within ``BUS_LOAD`` — 3 at 1 kHz and 6 at 500 Hz on 1 Mbit/s, as on a real arm."""
    return max(1, int(bitrate * BUS_LOAD / (2 * frame_bits(8) * rate)))


def robot_config(motors: int, rate: float) -> dict[str, Any]:
    """A robot of ``motors`` Damiao joints ``j1..jn`` as a config document, the motors spread over as many
    private virtual channels as a 1 Mbit/s bus needs at ``rate`` (components ``bus1``, ``bus2``, …).

    Controllers: ``joint_state_broadcaster`` (100 Hz, autostart), ``joint_trajectory`` (position + velocity) and
    ``forward_position`` (position; the bench's latency probes). No telemetry, default real-time settings.
    """
    if not 1 <= motors <= len(START_POSITIONS):
        raise ValueError(f"1 to {len(START_POSITIONS)} motors, not {motors}")
    names = [f"j{k + 1}" for k in range(motors)]
    kinds = motor_kinds(motors)
    per_bus = motors_per_bus(rate)
    hardware = {}
    for b, first in enumerate(range(0, motors, per_bus)):
        mine = range(first, min(motors, first + per_bus))
        hardware[f"bus{b + 1}"] = {
            "driver": "mit_can",
            "params": {
                "bus": {"interface": "virtual", "channel": f"hild-bench-{uuid.uuid4().hex[:10]}", "bitrate": BITRATE},
                "flavour": "damiao",
                "timeout_ms": 100,
                "reply_timeout_ms": 100,
                "motors": {names[k]: {"id": k + 1, "reply_id": 0x11 + k, "model": kinds[k].model} for k in mine},
            },
            "joints": {names[k]: {} for k in mine},
        }
    joints = {
        name: {
            "limits": {
                "position": {"lower": -3.0, "upper": 3.0},
                "soft_margin": 0.05,
                "velocity": kind.velocity,
                "acceleration": kind.acceleration,
                "jerk": kind.jerk,
                "effort": kind.effort,
            },
            "hold": {"kp": kind.kp, "kd": kind.kd},
        }
        for name, kind in zip(names, kinds, strict=True)
    }
    return {
        "robot": {"name": f"can{motors}"},
        "update_rate": rate,
        "clock": {"source": "wall"},
        "hardware": hardware,
        "joints": joints,
        "controllers": bench_controllers(names, ["position", "velocity"]),
        # The emulated drives share the daemon's GIL: on a loaded 2-core machine their thread can miss 10 ms, which
        # the default (10 cycles) would report as a drive that stopped answering. Real drives do not pause so.
        "safety": {"fault_action": "hold", "estop_action": "hold", "stale_feedback_cycles": STALE_FEEDBACK_CYCLES},
    }


def bench_controllers(names: list[str], trajectory_interfaces: list[str]) -> dict[str, Any]:
    """Every CAN rig's controllers: ``joint_state_broadcaster`` (100 Hz, autostart), ``joint_trajectory`` on
    ``trajectory_interfaces`` (the bench's trajectory) and ``forward_position`` (the latency probes)."""
    return {
        "joint_state_broadcaster": {
            "type": "joint_state_broadcaster",
            "params": {"publish_rate": 100},
            "autostart": True,
        },
        "joint_trajectory": {
            "type": "joint_trajectory",
            "params": {"joints": names, "command_interfaces": trajectory_interfaces},
        },
        "forward_position": {
            "type": "forward_command",
            "params": {"joints": names, "interface": "position", "command_timeout": 0.5},
        },
    }


class FrameTap:
    """The emulator's bus, counting every frame and its worst-case bits (the bus figures), and recording the frames
    of ``watched`` ids while ``recording`` (emulator thread only)."""

    def __init__(self, bus: can.BusABC, watched: set[int]) -> None:
        self.bus = bus
        self.watched = watched
        self.recording = False
        self.frames: list[tuple[float, int, bytes]] = []
        self.frame_count = 0
        self.bits = 0.0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        msg = self.bus.recv(timeout)
        if msg is not None:
            self._count(msg)
            if self.recording and msg.arbitration_id in self.watched:
                self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))
        return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        stamp = time.time()
        self.bus.send(msg, timeout)
        self._count(msg)
        if self.recording and msg.arbitration_id in self.watched:
            self.frames.append((stamp, msg.arbitration_id, bytes(msg.data)))

    def _count(self, msg: can.Message) -> None:
        if not msg.is_error_frame:
            self.frame_count += 1
            self.bits += frame_bits(len(msg.data), fd=msg.is_fd, extended=msg.is_extended_id)

    def shutdown(self) -> None:
        self.bus.shutdown()


class Probe(Protocol):
    """What the bench's latency probes watch on the first drive: its frames' ids, and their positions decoded."""

    joint: str
    ids: set[int]
    lsb: float  # the command's position resolution, rad

    def decode(self, arbitration_id: int, data: bytes) -> tuple[str, float] | None:
        """("command", rad) for a command frame, ("reply", rad) for a reply carrying the position, else None."""
        ...


class MitProbe:
    """A Damiao motor's MIT command and its reply."""

    def __init__(self, wiring: MotorWiring) -> None:
        self.wiring = wiring
        self.joint = wiring.joint
        self.ids = {wiring.command_id, wiring.reply_id}
        self.lsb = 2 * wiring.ranges.p_max / ((1 << POSITION_BITS) - 1)

    def decode(self, arbitration_id: int, data: bytes) -> tuple[str, float] | None:
        w = self.wiring
        if arbitration_id == w.command_id and len(data) == 8 and special_kind(data) is None:
            return "command", decode_command(data, w.ranges).p
        if arbitration_id == w.reply_id and len(data) == 8 and (data[0] & 0xF) == (w.id & 0xF):
            return "reply", decode_state(data[1:6], w.ranges)[0]
        return None


def wall_to_perf_offset_ns() -> int:
    """``time.time_ns() − perf_counter_ns()`` from the tightest of a few back-to-back readings."""
    best: tuple[int, int] | None = None
    for _ in range(CLOCK_PAIRS):
        before = time.perf_counter_ns()
        wall = time.time_ns()
        after = time.perf_counter_ns()
        if best is None or after - before < best[0]:
            best = (after - before, wall - (before + after) // 2)
    assert best is not None
    return best[1]


def components_with_plants(
    loaded: LoadedConfig, kind: type[P], rig: str, driver: str
) -> Iterator[tuple[P, list[str], MotorPlant]]:
    """Each hardware component whose params are a ``kind``: its params, its joints, and a plant for them that powers
    up at ``START_POSITIONS`` (consecutive over the components, so no two motors start alike)."""
    components = [(n, p) for n, p in loaded.driver_params.items() if isinstance(p, kind)]
    if not components:
        raise ValueError(f"{rig} needs a {driver} hardware component")
    first = 0
    for name, params in components:
        joints = list(loaded.config.hardware[name].joints)
        starts = START_POSITIONS[first : first + len(joints)]
        first += len(joints)
        yield params, joints, MotorPlant(len(joints), inertia=0.05, damping=0.05, positions=starts)


class CanBenchRig:
    """The ``mit_can`` rig (a ``hild.bench.rigs.BenchRig``): see the module docstring.

    One emulator per bus, all serviced by one thread (a drive answers the frame it got in the last service).
    ``open_channel`` opens an emulated drive's side of a bus: the config's own (a virtual channel in this process)
    by default; the rig process (:mod:`hild.bench.rigs.can_process`) serves each over loopback instead."""

    trajectory_scale = 0.5  # the standard trajectory moves joints up to 1 rad; half of that suits these motors

    def __init__(self, open_channel: Callable[[BusSpec], Any] = open_bus) -> None:
        self._open_channel = open_channel
        self.emulators: list[Emulator] = []
        self.tap: FrameTap | None = None
        self.taps: list[FrameTap] = []  # every bus, for the bus figures
        self.probe: Probe | None = None
        self.drivers: list[Any] = []
        self._thread: threading.Thread | None = None
        self._thread_id = 0
        self._stop = threading.Event()
        self._priority = 0

    @staticmethod
    def robot_config(joints: int, rate: float) -> dict[str, Any]:
        return robot_config(joints, rate)

    def start(self, loaded: LoadedConfig) -> None:
        """Open the emulated drives on the config's buses and start serving them (before the daemon configures)."""
        try:
            for spec, firmware, plant, probe in self.drives(loaded):
                first = self.tap is None  # the first drive's bus carries the latency probes
                tap = FrameTap(self._open_channel(spec), probe.ids if first else set())
                if first:
                    self.probe, self.tap = probe, tap
                self.taps.append(tap)
                self.emulators.append(Emulator(tap, firmware, plant))
        except BaseException:
            self._close_buses()
            raise
        self._priority = loaded.config.realtime.priority - 1
        self._thread = threading.Thread(target=self._serve, name="hild-bench-emulator", daemon=True)
        self._thread.start()
        while not self._thread_id:
            time.sleep(0.001)

    def drives(self, loaded: LoadedConfig) -> Iterator[tuple[BusSpec, list[MotorFirmware], Plant, Probe]]:
        """Per ``mit_can`` component: its bus, its emulated motors, their plant, and its first motor's probe."""
        for params, joints, plant in components_with_plants(loaded, MitCanParams, "the CAN bench rig", "mit_can"):
            wiring, problems = wire_motors(params, joints)
            if problems:
                raise ValueError("; ".join(problems))
            yield params.bus, build_firmware(params, joints), plant, MitProbe(wiring[0])

    def _serve(self) -> None:
        """``Emulator.run`` for several emulators: one service of each every period, on an absolute grid, and when a
        frame arrives on a bridged bus."""
        self._thread_id = threading.get_native_id()
        if self._priority > 0:  # below a SCHED_FIFO cycle, or the drives starve behind it and their watchdogs fire
            with contextlib.suppress(OSError):  # the daemon's real-time report says whether FIFO is permitted
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._priority))
        emulators = self.emulators

        def service(now: float) -> None:
            for emulator in emulators:
                emulator.service(now)

        wake = frame_wakeup([tap.bus for tap in self.taps])  # across the loopback bridge: a frame wakes the drives
        serve_on_grid(service, EMULATOR_PERIOD if wake is None else WOKEN_PERIOD, self._stop, wake=wake)

    def attach(self, engine: Any) -> None:
        """Keep the daemon's CAN drivers for their frame counters."""
        self.drivers = [s.component for s in engine.hardware if hasattr(s.component, "statistics")]

    def threads(self) -> dict[str, int]:
        return {"emulator": self._thread_id}

    def counters(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for emulator in self.emulators:
            for key, value in emulator.stats().items():
                out[f"emulator {key}"] = out.get(f"emulator {key}", 0) + value
        for driver in self.drivers:
            for key, value in driver.statistics.items():
                out[f"driver {key}"] = out.get(f"driver {key}", 0) + value
        out["bus frames"] = sum(tap.frame_count for tap in self.taps)  # every bus, both ways
        out["bus bits"] = round(sum(tap.bits for tap in self.taps))  # worst case (bit stuffing included)
        return out

    def listen(self, on: bool) -> dict[str, Any]:
        """Start (``on``) or stop recording the first drive's frames. Both return its joint and ``lsb`` (the
        position resolution, rad); stopping also returns the frames decoded: ``command``/``reply`` =
        [[perf_counter_ns, position rad], …]."""
        tap, probe = self.tap, self.probe
        assert tap is not None and probe is not None
        if on:
            tap.frames = []
            tap.recording = True
            return {"joint": probe.joint, "lsb": probe.lsb}
        tap.recording = False
        frames, tap.frames = tap.frames, []
        offset = wall_to_perf_offset_ns()
        decoded: dict[str, list[list[float]]] = {"command": [], "reply": []}
        for stamp, arbitration_id, data in frames:
            seen = probe.decode(arbitration_id, data)
            if seen is not None:
                decoded[seen[0]].append([round(stamp * 1e9) - offset, seen[1]])
        return {"joint": probe.joint, "lsb": probe.lsb, **decoded}

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self._close_buses()

    def _close_buses(self) -> None:
        for emulator in self.emulators:
            emulator.bus.shutdown()
        self.emulators = []
        self.taps = []
