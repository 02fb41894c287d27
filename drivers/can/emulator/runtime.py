"""`hild emulate`'s engine room: the CAN drives a robot config names, emulated on their buses, with a plant behind.

`build_runtime(loaded, options)` reads the config's CAN hardware sections (drivers ``mit_can``, ``odrive_can`` and
``cia402``) and makes one firmware model per configured motor — flavour, ids, model ranges and range overrides
exactly as the host driver resolves them (``wire_motors``; ``wire_drives`` and the same EDS for CiA 402 drives),
so both ends of the bus scale values identically. Components on the
same bus share one `Emulator`. Behind the drives sits a plant in actuator space:

* ``twin`` — the robot's MuJoCo model (``robot.model``), joint names kept, each joint seen through its
  transmission (`drivers.mujoco.plant.TwinPlant`): the arm's real dynamics behind CAN. One bus only, because
  the physics must see every drive's torque in the same step.
* ``motors`` — an independent `MotorPlant` joint per motor (inertia, damping, gravity-like load).

Holding brakes (default on): a joint whose drive is not enabled stays where it is, so an unpowered twin does not
collapse before a daemon enables it. Without brakes a disabled or faulted drive lets its joint fall, as an
unbraked Damiao arm does.

Run-time control (``--control HOST:PORT``): a TCP socket taking one JSON object per line and answering one per
line, ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``. Requests are applied by the emulator loop
between two services, so a fault lands atomically. ``joint`` is a joint name; where optional, omitting it means
every emulated joint.

* ``{"op": "status"}`` → ``time``, ``plant``, ``buses`` (counters per bus) and ``joints``: name, component, bus,
  ``position``/``velocity`` (joint space, the plant's truth), ``actuator_position``/``actuator_velocity``,
  ``torque`` (actuator space), ``enabled``, ``fault``, ``braked``, ``temperature_rotor``/``temperature_mos``,
  ``command_step`` (MIT drives: the largest step of the commanded position since the drive was enabled, joint
  space; 0 elsewhere), ``longest_command_gap_ms`` (MIT drives: the longest silence their watchdog saw since the
  drive was enabled; 0 elsewhere); CiA 402 drives add ``cia402_state`` (e.g. "OPERATION ENABLED"), ``nmt_state``
  (5 operational, 127 pre-operational, 4 stopped), ``mode`` (0x6061) and ``error_code`` (0x603F).
* ``{"op": "fault", "joint": J, "code": C}`` — latch a drive fault (Damiao 0x5…0xE, T-Motor 1…6, MyActuator
  flags, ODrive axis error bits, CiA 402 EMCY error codes such as 0x2310 overcurrent, 0x3210 DC link
  overvoltage, 0x4310 over-temperature, 0x5530 hardware, 0x8611 following error: the drive goes to FAULT,
  latches 0x603F and sends the EMCY); the drive disables itself like the firmware does.
* ``{"op": "clear", "joint": J?}`` — clear latched faults on the drive side (an operator power-cycling a supply).
* ``{"op": "reboot", "joint": J?}`` — power cycle: back disabled, RAM settings lost.
* ``{"op": "set", "joint": J?, "drop_replies": P, "reply_delay": S, "silent": B, "over_temperature": C,
  "corrupt_replies": N}`` — transport faults: drop each reply with probability P, delay replies by S seconds, cut
  the transceiver, send the next N replies one byte short.
* ``{"op": "bus_off", "duration": S}`` — every emulated bus goes off for S seconds (an error frame of the bus-off
  class first, then no frame either way).
* ``{"op": "push", "force": [FX, FY, FZ], "duration": S?, "ramp": S?, "delay": S?}`` — twin plant only: push the
  tool (N, world frame; `drivers.can.emulator.disturbances.Push`) from ``delay`` s of plant time on, for
  ``duration`` s (default: until cleared), ramped over ``ramp`` s; ``{"op": "push", "clear": true}`` ends every
  push. The twin's status adds ``contact_force`` (N, world: what the obstacles exert on the arm),
  ``peak_contact_force`` and ``push`` (the force applied now).
* ``{"op": "stop"}`` — end the emulator (the process exits 0).

`request(address, payload)` is a small client for it.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import queue
import socket
import socketserver
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import can
import numpy as np

from drivers.can.bus import BusSpec, open_bus
from drivers.can.cia402.wiring import wire_drives
from drivers.can.emulator.base import MotorFirmware
from drivers.can.emulator.cia402_firmware import Cia402Firmware
from drivers.can.emulator.core import Emulator, frame_wakeup, loop_stats, serve_on_grid
from drivers.can.emulator.disturbances import Obstacle, PlantMismatch, Push
from drivers.can.emulator.mit_firmware import DamiaoFirmware, MitFirmware, MyActuatorFirmware, TMotorFirmware
from drivers.can.emulator.odrive_firmware import ODriveFirmware
from drivers.can.emulator.plant import MotorPlant, Plant
from drivers.can.emulator.remote_host import RemoteServerBus
from drivers.can.params import Cia402Params, MitCanParams, ODriveCanParams
from drivers.can.wiring import wire_motors
from hild.config.loader import LoadedConfig

__all__ = [
    "CAN_DRIVERS",
    "BrakedPlant",
    "EmulatedJoint",
    "EmulatorRuntime",
    "RuntimeOptions",
    "build_firmware",
    "build_runtime",
    "describe",
    "request",
]

log = logging.getLogger("hild.emulate")

CAN_DRIVERS = ("mit_can", "odrive_can", "cia402")
PlantKind = Literal["twin", "motors"]


@dataclass(frozen=True)
class EmulatedJoint:
    """One emulated drive and where it sits: its joint, component, bus and the joint's transmission."""

    name: str
    component: str
    bus: str
    firmware: MotorFirmware
    reduction: float = 1.0
    direction: int = 1
    offset: float = 0.0

    def to_joint(self, actuator_position: float) -> float:
        return self.direction * actuator_position / self.reduction + self.offset

    def to_actuator(self, joint_position: float) -> float:
        return self.direction * (joint_position - self.offset) * self.reduction


@dataclass
class RuntimeOptions:
    """What `hild emulate`'s command line can change. ``plant=None``: the twin when the config has robot.model."""

    plant: PlantKind | None = None
    components: Sequence[str] | None = None
    keyframe: str | None = None
    """Twin start pose; None: the model's ``home`` keyframe if it has one, else its qpos0."""
    initial_positions: Mapping[str, float] = field(default_factory=dict)
    """Joint space, by joint name; applied after the keyframe."""
    brakes: bool = True
    inertia: float = 0.05
    damping: float = 0.05
    gravity: float = 0.0
    max_step: float = 0.0005
    """Longest plant step (s): the drives' control law is evaluated at least this often."""
    mismatch: PlantMismatch | None = None
    """Twin plant only: masses and joint friction scaled away from robot.model (hild keeps the file's values)."""
    obstacles: Sequence[Obstacle] = ()
    """Twin plant only: fixed primitives the arm collides with."""
    pushes: Sequence[Push] = ()
    """Twin plant only: scheduled forces at ``force_site``."""
    force_site: str = "tool"
    """The model site pushes act on."""

    def contact_options(self) -> list[str]:
        """The twin-only options this asks for (for the error when the plant is not the twin)."""
        given = {"mismatch": self.mismatch is not None and not self.mismatch.identity}
        given |= {"obstacles": bool(self.obstacles), "pushes": bool(self.pushes)}
        return [name for name, on in given.items() if on]


def build_firmware(
    params: MitCanParams | ODriveCanParams | Cia402Params, joints: Sequence[str], config_dir: Path = Path(".")
) -> list[MotorFirmware]:
    """One firmware per joint (component joint order), configured as the host driver expects to find it.

    ``config_dir`` resolves a CiA 402 component's EDS paths (relative to the config's directory)."""
    if isinstance(params, Cia402Params):
        drives, problems = wire_drives(params, joints, config_dir)
        if problems:
            raise ValueError("; ".join(problems))
        return [Cia402Firmware(drive, seed=k) for k, drive in enumerate(drives)]
    if isinstance(params, ODriveCanParams):
        return [
            ODriveFirmware(
                params.axes[joint].node_id,
                heartbeat_period=params.heartbeat_rate_ms / 1000.0,
                encoder_period=params.encoder_rate_ms / 1000.0,
                seed=k,
            )
            for k, joint in enumerate(joints)
        ]
    wiring, problems = wire_motors(params, joints)
    if problems:
        raise ValueError("; ".join(problems))
    firmware = {cls.flavour.name: cls for cls in (DamiaoFirmware, TMotorFirmware, MyActuatorFirmware)}[params.flavour]
    return [firmware.for_motor(m, seed=k) for k, m in enumerate(wiring)]


class BrakedPlant:
    """Holding brakes around any plant: a joint whose drive is not enabled keeps the position where it locked."""

    def __init__(self, plant: Plant, motors: Sequence[MotorFirmware]) -> None:
        if len(plant.positions) != len(motors):
            raise ValueError(f"plant has {len(plant.positions)} joints for {len(motors)} motors")
        self.plant = plant
        self.motors = list(motors)
        self.locked = np.zeros(len(motors), dtype=bool)
        self._hold = np.array(plant.positions, dtype=float)
        self._update_locks()

    @property
    def positions(self) -> np.ndarray:
        return self.plant.positions

    @property
    def velocities(self) -> np.ndarray:
        return self.plant.velocities

    def step(self, torques: np.ndarray, dt: float) -> None:
        self._update_locks()
        self.plant.step(torques, dt)
        if self.locked.any():
            self.plant.positions[self.locked] = self._hold[self.locked]
            self.plant.velocities[self.locked] = 0.0

    def _update_locks(self) -> None:
        for i, motor in enumerate(self.motors):
            engage = not motor.enabled
            if engage and not self.locked[i]:
                self._hold[i] = self.plant.positions[i]
                self.plant.velocities[i] = 0.0
            self.locked[i] = engage


@dataclass
class BusRig:
    """One bus: its spec, the drives on it (plant order) and, once opened, the bus and its emulator."""

    spec: BusSpec
    joints: list[EmulatedJoint]
    plant: Plant
    bus: can.BusABC | None = None
    emulator: Emulator | None = None


class EmulatorRuntime:
    """Every emulated bus of one config, serviced together on one clock; the control channel's request handler."""

    def __init__(
        self,
        rigs: list[BusRig],
        plant_kind: PlantKind,
        *,
        max_step: float = 0.0005,
        twin: Any | None = None,
    ) -> None:
        self.rigs = rigs
        self.plant_kind = plant_kind
        self.max_step = max_step
        self.twin = twin
        """The TwinPlant when plant_kind is twin (for status and tests)."""
        self.joints = [j for rig in rigs for j in rig.joints]
        self.time: float | None = None
        self._requests: queue.SimpleQueue[tuple[dict[str, Any], Future[dict[str, Any]]]] = queue.SimpleQueue()
        self._remote: RemoteServerBus | None = None
        self._control: socketserver.ThreadingTCPServer | None = None
        self._control_thread: threading.Thread | None = None
        self.stop_event = threading.Event()
        self.loop_stats = loop_stats()
        """Wall-clock loop (`run`): services, of them woken by a frame, periods overrun, worst lateness of a tick
        against its deadline, longest time between the starts of two services."""

    # ---- lifecycle ------------------------------------------------------------------------------------------
    def open(self, serve_remote: tuple[str, int] | None = None) -> None:
        """Open every bus and start its emulator; with ``serve_remote`` also host the remote bus on HOST:PORT.

        The served bus is the one whose components use ``interface: remote``: a python-can-remote server whose
        frames the emulator loop moves itself (`RemoteServerBus`: no thread per client, no GIL hand-over per frame).
        """
        try:
            served = self._served_rig(serve_remote)
            for rig in self.rigs:
                if rig is served and serve_remote is not None:
                    rig.bus = self._remote = RemoteServerBus(*serve_remote)
                else:
                    rig.bus = open_bus(rig.spec)
                rig.emulator = Emulator(rig.bus, [j.firmware for j in rig.joints], rig.plant, max_step=self.max_step)
        except BaseException:
            self.close()
            raise

    def _served_rig(self, serve_remote: tuple[str, int] | None) -> BusRig | None:
        if serve_remote is None:
            return None
        remote = [rig for rig in self.rigs if rig.spec.interface == "remote"]
        if not remote:
            raise ValueError("--serve-remote: no emulated component uses a bus with interface: remote")
        if len(remote) > 1:
            names = ", ".join(rig.spec.name for rig in remote)
            raise ValueError(f"--serve-remote serves one bus, the config has several remote buses ({names})")
        return remote[0]

    @property
    def remote_address(self) -> tuple[str, int] | None:
        """HOST, PORT the remote server listens on (the port is real even when 0 was asked for)."""
        if self._remote is None:
            return None
        host, port = self._remote.address
        return str(host), int(port)

    def start_control(self, address: tuple[str, int]) -> tuple[str, int]:
        """Listen for control requests on HOST:PORT (JSON lines); returns the bound address."""
        runtime = self

        class Handler(socketserver.StreamRequestHandler):
            def handle(self) -> None:
                for line in self.rfile:
                    if not line.strip():
                        continue
                    reply = runtime.call(line)
                    self.wfile.write(json.dumps(reply).encode() + b"\n")
                    self.wfile.flush()

        class Server(socketserver.ThreadingTCPServer):
            allow_reuse_address = True
            daemon_threads = True

        server = Server(address, Handler)
        self._control = server
        self._control_thread = threading.Thread(target=server.serve_forever, name="emulate-control", daemon=True)
        self._control_thread.start()
        host, port = server.server_address[:2]
        return str(host), int(port)

    def close(self) -> None:
        """Stop the servers and release the buses (safe to call twice)."""
        if self._control is not None:
            self._control.shutdown()
            self._control.server_close()
        self._control = self._remote = None  # the remote server is a rig's bus: shut down with it below
        for rig in self.rigs:
            bus, rig.bus = rig.bus, None
            rig.emulator = None
            if bus is not None:
                with contextlib.suppress(can.CanError, OSError):
                    bus.shutdown()

    # ---- running ------------------------------------------------------------------------------------------------
    def service(self, now: float) -> None:
        """Apply pending control requests, then serve every bus at ``now`` (sim or wall seconds)."""
        self._apply_requests()
        self.time = now
        for rig in self.rigs:
            if rig.emulator is not None:
                rig.emulator.service(now)

    def run(self, period: float, clock: Callable[[], float] = time.monotonic) -> None:
        """Serve every ``period`` s on ``clock``, and whenever a frame arrives on a bus that can be waited on (see
        `serve_on_grid`), until `stop_event` is set (a stop request or a signal)."""
        wake = frame_wakeup([rig.bus for rig in self.rigs if rig.bus is not None])
        serve_on_grid(self.service, period, self.stop_event, wake=wake, stats=self.loop_stats, clock=clock)
        self._apply_requests()  # answer whatever arrived with the stop

    # ---- control ------------------------------------------------------------------------------------------------
    def submit(self, payload: dict[str, Any]) -> Future[dict[str, Any]]:
        """Queue a control request for the emulator loop (any thread)."""
        future: Future[dict[str, Any]] = Future()
        self._requests.put((payload, future))
        return future

    def call(self, line: bytes | str, timeout: float = 5.0) -> dict[str, Any]:
        """One JSON request line in, one reply out (what the control socket does per line)."""
        try:
            payload = json.loads(line)
        except ValueError as exc:
            return {"ok": False, "error": f"not JSON: {exc}"}
        if not isinstance(payload, dict):
            return {"ok": False, "error": "a request is a JSON object with an 'op'"}
        try:
            return self.submit(payload).result(timeout)
        except TimeoutError:
            return {"ok": False, "error": f"the emulator loop did not answer within {timeout} s"}

    def _apply_requests(self) -> None:
        while True:
            try:
                payload, future = self._requests.get_nowait()
            except queue.Empty:
                return
            if future.set_running_or_notify_cancel():
                future.set_result(self.handle(payload))

    def handle(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        """Apply one control request now (on the thread that services the emulators)."""
        op = payload.get("op")
        try:
            if op == "status":
                return {"ok": True, **self.status()}
            if op == "stop":
                self.stop_event.set()
                return {"ok": True}
            if op == "fault":
                code = payload.get("code")
                if not isinstance(code, int) or isinstance(code, bool):
                    raise ValueError("fault needs an integer 'code'")
                (joint,) = self._select(payload, required=True)
                joint.firmware.inject_fault(code)
                return {"ok": True, "joints": [joint.name]}
            if op in ("clear", "reboot"):
                chosen = self._select(payload)
                for joint in chosen:
                    if op == "clear":
                        joint.firmware.clear_fault()
                    else:
                        joint.firmware.reboot()
                return {"ok": True, "joints": [j.name for j in chosen]}
            if op == "set":
                return self._set(payload)
            if op == "bus_off":
                return self._bus_off(payload)
            if op == "glitch":
                return self._glitch(payload)
            if op == "push":
                return self._push(payload)
        except (ValueError, TypeError) as exc:
            return {"ok": False, "error": str(exc)}
        ops = "status, fault, clear, reboot, set, glitch, bus_off, push, stop"
        return {"ok": False, "error": f"unknown op {op!r} (ops: {ops})"}

    def _select(self, payload: Mapping[str, Any], *, required: bool = False) -> list[EmulatedJoint]:
        name = payload.get("joint")
        if name is None:
            if required:
                raise ValueError(f"{payload.get('op')} needs a 'joint'")
            return list(self.joints)
        for joint in self.joints:
            if joint.name == name:
                return [joint]
        raise ValueError(f"unknown joint {name!r} (emulated: {', '.join(j.name for j in self.joints)})")

    def _set(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        settings = {k: v for k, v in payload.items() if k not in ("op", "joint")}
        if not settings:
            raise ValueError(
                "set needs at least one of drop_replies, reply_delay, silent, over_temperature, corrupt_replies"
            )
        checked: dict[str, Any] = {}
        for key, value in settings.items():
            if key == "silent":
                if not isinstance(value, bool):
                    raise ValueError("silent must be true or false")
                checked[key] = value
            elif key == "corrupt_replies":
                if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                    raise ValueError("corrupt_replies must be a count ≥ 0")
                checked[key] = value
            elif key in ("drop_replies", "reply_delay", "over_temperature"):
                if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                    raise ValueError(f"{key} must be a number")
                if key == "drop_replies" and not 0.0 <= value <= 1.0:
                    raise ValueError("drop_replies is a probability in [0, 1]")
                if key == "reply_delay" and value < 0.0:
                    raise ValueError("reply_delay must not be negative")
                checked[key] = float(value)
            else:
                raise ValueError(
                    f"unknown setting {key!r} (drop_replies, reply_delay, silent, over_temperature, corrupt_replies)"
                )
        chosen = self._select(payload)
        for joint in chosen:
            for key, value in checked.items():
                setattr(joint.firmware, key, value)
        return {"ok": True, "joints": [j.name for j in chosen], **checked}

    def _glitch(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        """Corrupt the position a drive reports (joint space, like the daemon sees it), never its law:
        ``offset`` (rad) or ``value`` (an absolute position) for the next ``replies`` (-1: until cleared),
        ``frozen`` / ``sign_flip`` true or false, or ``clear``."""
        (joint,) = self._select(payload, required=True)
        glitch = joint.firmware.glitch
        keys = set(payload) - {"op", "joint"}
        unknown = keys - {"offset", "value", "replies", "frozen", "sign_flip", "clear"}
        if unknown or not keys:
            raise ValueError("glitch takes offset, value, replies, frozen, sign_flip or clear")
        for key in keys & {"offset", "value", "replies"}:
            value = payload[key]
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"{key} must be a finite number")
        for key in keys & {"frozen", "sign_flip", "clear"}:
            if not isinstance(payload[key], bool):
                raise ValueError(f"{key} must be true or false")
        if payload.get("clear"):
            glitch.clear()
        if "offset" in keys or "value" in keys:
            replies = int(payload.get("replies", -1))
            offset = float(payload.get("offset", 0.0)) * joint.reduction  # joint → actuator rad
            value = joint.to_actuator(float(payload["value"])) if "value" in keys else math.nan
            glitch.set(0, offset=offset * joint.direction, value=value, replies=replies)
        if "frozen" in keys:
            glitch.freeze(0, payload["frozen"])
        if "sign_flip" in keys:
            glitch.flip(0, payload["sign_flip"])
        return {"ok": True, "joints": [joint.name]}

    def _push(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        """A force on the tool of the twin plant, from now (+ ``delay``) in plant time (see the module docstring)."""
        if self.twin is None:
            raise ValueError("push needs the twin plant (--plant twin)")
        keys = set(payload) - {"op"}
        unknown = keys - {"force", "duration", "ramp", "delay", "clear"}
        if unknown or not keys:
            raise ValueError("push takes force, duration, ramp, delay, or clear")
        if "clear" in keys:
            if payload["clear"] is not True or len(keys) > 1:
                raise ValueError("push clear takes only clear: true")
            self.twin.pushes.clear()
            return {"ok": True, "pushes": 0}
        force = payload.get("force")
        if not isinstance(force, list) or len(force) != 3 or any(isinstance(f, bool) for f in force):
            raise ValueError("push needs 'force': [FX, FY, FZ] in N")
        for key in keys - {"force"}:
            value = payload[key]
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"{key} must be a finite number of seconds")
        start = self.twin.time + float(payload.get("delay", 0.0))
        duration = float(payload.get("duration", math.inf))
        push = Push((float(force[0]), float(force[1]), float(force[2])), start, duration, float(payload.get("ramp", 0)))
        self.twin.pushes.append(push)
        return {"ok": True, "pushes": len(self.twin.pushes), "start": start}

    def _bus_off(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        duration = payload.get("duration")
        if isinstance(duration, bool) or not isinstance(duration, int | float) or not 0.0 < duration < math.inf:
            raise ValueError("bus_off needs a positive 'duration' in seconds")
        now = self.time if self.time is not None else 0.0
        buses = []
        for rig in self.rigs:
            if rig.emulator is not None:
                rig.emulator.bus_off(now, float(duration))
                buses.append(rig.spec.name)
        return {"ok": True, "buses": buses, "duration": float(duration)}

    def status(self) -> dict[str, Any]:
        joints = []
        for rig in self.rigs:
            braked = rig.plant.locked if isinstance(rig.plant, BrakedPlant) else np.zeros(len(rig.joints), bool)
            for i, joint in enumerate(rig.joints):
                fw = joint.firmware
                q, qd = float(rig.plant.positions[i]), float(rig.plant.velocities[i])
                joints.append(
                    {
                        "name": joint.name,
                        "component": joint.component,
                        "bus": rig.spec.name,
                        "position": joint.to_joint(q),
                        "velocity": joint.direction * qd / joint.reduction,
                        "actuator_position": q,
                        "actuator_velocity": qd,
                        "torque": float(fw.applied_torque),
                        "enabled": bool(fw.enabled),
                        "fault": int(fw.fault),
                        "braked": bool(braked[i]),
                        "command_step": float(getattr(fw, "command_step", 0.0)) / joint.reduction,
                        "longest_command_gap_ms": round(1000.0 * float(getattr(fw, "longest_command_gap", 0.0)), 3),
                        "temperature_rotor": round(float(fw.temperature_rotor), 2),
                        "temperature_mos": round(float(fw.temperature_mos), 2),
                        **(_cia402_status(fw) if isinstance(fw, Cia402Firmware) else {}),
                    }
                )
        buses = [
            {"bus": rig.spec.name, "motors": len(rig.joints), **(rig.emulator.stats() if rig.emulator else {})}
            for rig in self.rigs
        ]
        loop = {**self.loop_stats, **{k: round(self.loop_stats[k], 3) for k in ("max_late_ms", "max_gap_ms")}}
        status = {"time": self.time, "plant": self.plant_kind, "loop": loop, "buses": buses, "joints": joints}
        if self.twin is not None:
            status["contact_force"] = [round(float(f), 3) for f in self.twin.contact_force()]
            status["peak_contact_force"] = round(float(self.twin.peak_contact_force), 3)
            status["push"] = [round(float(f), 3) for f in self.twin.push_now]
        return status


def request(address: tuple[str, int], payload: Mapping[str, Any], timeout: float = 5.0) -> dict[str, Any]:
    """Send one control request to a running `hild emulate --control HOST:PORT` and return its reply."""
    with socket.create_connection(address, timeout=timeout) as sock:
        sock.sendall(json.dumps(dict(payload)).encode() + b"\n")
        with sock.makefile("rb") as reader:
            line = reader.readline()
    if not line:
        raise ConnectionError(f"the emulator at {address[0]}:{address[1]} closed the connection without a reply")
    reply: dict[str, Any] = json.loads(line)
    return reply


# ---- building from a config ---------------------------------------------------------------------------------------


def build_runtime(loaded: LoadedConfig, options: RuntimeOptions | None = None) -> EmulatorRuntime:
    """Emulate the CAN components of ``loaded`` (all of them, or ``options.components``); buses are not opened yet.

    Raises ValueError with the reason when there is nothing to emulate or the plant cannot be built.
    """
    opts = options or RuntimeOptions()
    cfg = loaded.config
    wanted = list(opts.components) if opts.components else None
    if wanted is not None:
        unknown = [name for name in wanted if name not in cfg.hardware]
        if unknown:
            raise ValueError(f"no hardware component {unknown} in the config (it has: {', '.join(cfg.hardware)})")
        not_can = [name for name in wanted if cfg.hardware[name].driver not in CAN_DRIVERS]
        if not_can:
            raise ValueError(f"components {not_can} are not CAN drivers ({', '.join(CAN_DRIVERS)})")
    names = wanted or [name for name, hw in cfg.hardware.items() if hw.driver in CAN_DRIVERS]
    if not names:
        raise ValueError(f"the config has no CAN hardware component (drivers {', '.join(CAN_DRIVERS)})")

    by_bus: dict[str, tuple[BusSpec, list[EmulatedJoint]]] = {}
    for name in names:
        hw = cfg.hardware[name]
        params = loaded.driver_params[name]
        assert isinstance(params, MitCanParams | ODriveCanParams | Cia402Params)
        joints = list(hw.joints)
        firmwares = build_firmware(params, joints, loaded.directory)
        spec = params.bus
        entry = by_bus.setdefault(spec.name, (spec, []))
        for joint, fw in zip(joints, firmwares, strict=True):
            tr = hw.joints[joint]
            entry[1].append(EmulatedJoint(joint, name, spec.name, fw, tr.reduction, tr.direction, tr.offset))

    kind: PlantKind = opts.plant or ("twin" if cfg.robot.model else "motors")
    unknown_initial = sorted(set(opts.initial_positions) - {j.name for _, js in by_bus.values() for j in js})
    if unknown_initial:
        raise ValueError(f"initial positions for joints that are not emulated: {unknown_initial}")
    rigs: list[BusRig] = []
    twin = None
    if kind == "twin":
        if cfg.robot.model is None:
            raise ValueError("--plant twin needs robot.model in the config")
        if len(by_bus) > 1:
            raise ValueError(
                f"--plant twin couples one bus to the model, the config has {len(by_bus)} ({', '.join(by_bus)}): "
                "emulate one bus (--component) or use --plant motors"
            )
        ((spec, joints),) = by_bus.values()
        twin = _twin_plant(loaded, joints, opts)
        rigs.append(BusRig(spec, joints, _braked(twin, joints, opts.brakes)))
    else:
        if opts.keyframe is not None:
            raise ValueError("a keyframe is a pose of the twin's model: it needs --plant twin")
        if opts.contact_options():
            raise ValueError(f"{', '.join(opts.contact_options())} act on the twin's model: they need --plant twin")
        for spec, joints in by_bus.values():
            start = [j.to_actuator(opts.initial_positions.get(j.name, j.offset)) for j in joints]
            plant = MotorPlant(
                len(joints), inertia=opts.inertia, damping=opts.damping, gravity=opts.gravity, positions=start
            )
            rigs.append(BusRig(spec, joints, _braked(plant, joints, opts.brakes)))
    return EmulatorRuntime(rigs, kind, max_step=opts.max_step, twin=twin)


def _braked(plant: Plant, joints: Sequence[EmulatedJoint], brakes: bool) -> Plant:
    return BrakedPlant(plant, [j.firmware for j in joints]) if brakes else plant


def _twin_plant(loaded: LoadedConfig, joints: Sequence[EmulatedJoint], opts: RuntimeOptions) -> Any:
    from drivers.mujoco.plant import TwinPlant  # mujoco stays in drivers/mujoco; only the twin plant needs it

    model = loaded.directory / str(loaded.config.robot.model)
    plant = TwinPlant(
        model,
        [j.name for j in joints],
        reduction=[j.reduction for j in joints],
        direction=[j.direction for j in joints],
        offset=[j.offset for j in joints],
        mismatch=opts.mismatch,
        obstacles=opts.obstacles,
        pushes=opts.pushes,
        force_site=opts.force_site,
    )
    keyframe = opts.keyframe
    if keyframe is None and "home" in plant.keyframes:
        keyframe = "home"
    plant.reset(keyframe, opts.initial_positions)
    if plant.free_joints:
        log.warning("model joints without an emulated drive move freely: %s", ", ".join(plant.free_joints))
    if plant.mimic_joints:
        pairs = ", ".join(f"{follower} ← {leader}" for follower, leader in plant.mimic_joints.items())
        log.info("mimic joints follow their driven leader in the model: %s", pairs)
    return plant


def describe(runtime: EmulatorRuntime) -> list[str]:
    """Human-readable lines on what is emulated where (for the start-up log)."""
    lines = []
    for rig in runtime.rigs:
        motors = ", ".join(f"{j.name}={_ident(j.firmware)}" for j in rig.joints)
        lines.append(f"bus {rig.spec.name}: {len(rig.joints)} drives ({motors})")
    plant = runtime.plant_kind
    if runtime.twin is not None:
        plant += f" ({runtime.twin.model_name})"
        mismatch = runtime.twin.mismatch
        if not mismatch.identity:
            plant += f", mass ×{mismatch.mass:g}, friction ×{mismatch.friction:g}"
            plant += f" ±{mismatch.spread:g} (seed {mismatch.seed})" if mismatch.spread else ""
        if runtime.twin.obstacles:
            plant += f", obstacles {', '.join(runtime.twin.obstacles)}"
    brakes = any(isinstance(rig.plant, BrakedPlant) for rig in runtime.rigs)
    lines.append(f"plant: {plant}, holding brakes {'on' if brakes else 'off'}")
    return lines


def _cia402_status(fw: Cia402Firmware) -> dict[str, Any]:
    """A CiA 402 drive's own words: its 402 state, NMT state, mode display and latched error code (0x603F)."""
    return {"cia402_state": fw.state, "nmt_state": int(fw.nmt_state), "mode": int(fw.mode_display),
            "error_code": int(fw.error_code)}  # fmt: skip


def _ident(fw: MotorFirmware) -> str:
    if isinstance(fw, DamiaoFirmware):
        return f"damiao {fw.motor_id:#x}→{fw.master_id:#x}"
    if isinstance(fw, MitFirmware):
        return f"{fw.flavour.name} {fw.motor_id:#x}"
    if isinstance(fw, ODriveFirmware):
        return f"odrive node {fw.node_id}"
    if isinstance(fw, Cia402Firmware):
        return f"cia402 node {fw.node_id}"
    return type(fw).__name__
