"""Lockstep rigs for fault injection: the engine and its hardware advanced one cycle at a time, deterministically.

* :class:`CanRig` — a robot of emulated CAN drives (any MIT flavour, or ODrive) on a private python-can ``virtual``
  channel. A cycle is ``engine.step`` (read → supervise → controllers → write) then ``emulator.service`` at the
  cycle's end time, so a drive answers the command of cycle k before cycle k+1 reads: one cycle of transport, as
  on a real bus. Lifecycle hooks that wait for replies service the emulator through the driver's
  ``serve_while_waiting``.
* :class:`TwinRig` — a shipped MuJoCo twin config on the sim clock.
* :class:`ApiRig` — a twin rig with the daemon's Zenoh API on its own asyncio thread, reached by real clients over
  loopback. Only the API runs on its own; the cycles are still stepped here, one at a time.

Every cycle of either rig runs under the jump guard (``tests.test_engine.JumpGuard``'s bound: a stiff joint's
commanded position never moves by more than ``velocity_limit · dt``), and every event is recorded with the cycle
that produced it. Operator requests (``reset``, ``enable``) go through ``engine.submit`` like the API's do, so they
land between two cycles.
"""

from __future__ import annotations

import asyncio
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np
import yaml

from drivers.can.emulator import Emulator, MotorPlant
from drivers.can.emulator.base import MotorFirmware
from drivers.can.emulator.runtime import BrakedPlant, build_firmware
from drivers.can.params import MitCanParams, ODriveCanParams
from hild.action import GoalResult
from hild.api.client import HildClient
from hild.api.goals import GoalEndpoint
from hild.api.server import ApiServer
from hild.config import load_config
from hild.config.loader import LoadedConfig
from hild.config.model import ZenohSection
from hild.controllers.joint_trajectory import JointTrajectoryController
from hild.crossing.events import Event
from hild.cycle.engine import MAX_STEP_PERIODS, Engine
from hild.modes import MODE_NAMES
from tests.conftest import CONFIGS
from tests.helpers import free_endpoint, rig_joint
from tests.test_engine import JumpGuard

JTC = "joint_trajectory"
START = (0.2, -0.3, 0.4, -0.1)  # rad, where the emulated motors power up
MOTORS = {  # per flavour: the driver, and one motor entry per joint index k
    "damiao": ("mit_can", lambda k: {"id": k + 1, "reply_id": 0x11 + k, "model": "DM4310"}),
    "tmotor": ("mit_can", lambda k: {"id": k + 1, "model": "AK80-9"}),
    "myactuator": ("mit_can", lambda k: {"id": k + 1, "model": "motion_mode"}),
    "odrive": ("odrive_can", lambda k: {"node_id": k + 1}),
}


class Guard(JumpGuard):
    """The jump guard, checked after a cycle somebody else ran; remembers the largest step it saw."""

    def __init__(self, engine: Engine) -> None:
        super().__init__(engine)
        self.worst = 0.0  # largest step seen, as a fraction of the bound

    def check(self, late: bool = False) -> None:
        """``late``: the cycle came after a stall; its bound is the engine's clamp (MAX_STEP_PERIODS periods)."""
        final = self.engine.final
        origin = np.where(self.prev_stiff, self.prev, self.engine.state.position)
        step = np.abs(final.position - origin) * (final.kp > 0.0)
        bound = self.max_step * (MAX_STEP_PERIODS if late else 1.0)
        assert (step <= bound).all(), f"command stepped by {step} at t={self.engine.t}"
        self.worst = max(self.worst, float((step / bound).max()))
        self.prev[:] = final.position
        self.prev_stiff[:] = final.kp > 0.0


class Lockstep:
    """What every rig shares: cycles under the guard, events by cycle, operator requests, trajectory goals."""

    engine: Engine

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.guard = Guard(engine)
        self.cycles = 0
        self.events: list[tuple[int, Event]] = []
        self.collect_events()

    # ---- cycles -------------------------------------------------------------------------------------------------
    def step(self) -> None:
        self.engine.run_cycles(1)

    def cycle(self, count: int = 1) -> None:
        for _ in range(count):
            self.step()
            self.cycles += 1
            self.guard.check()
            self.collect_events()

    def seconds(self, duration: float) -> None:
        self.cycle(round(duration * self.engine.update_rate))

    def stall(self, duration: float) -> None:
        """No cycle for ``duration`` s (a page fault, a hung call, a debugger, SIGSTOP), then the late one. The
        world goes on meanwhile (``_meanwhile``); the guard's bound for the late cycle is the engine's clamp."""
        self._meanwhile(duration)
        engine = self.engine
        dt = duration + engine.period
        engine.step(round(engine.t + dt, 12), dt)
        self._meanwhile(engine.period)  # the cycle's frames reach the hardware, which answers
        self.cycles += 1
        self.guard.check(late=True)
        self.collect_events()

    def _meanwhile(self, duration: float) -> None:
        """What the hardware does while no cycle runs (a twin's physics waits for the next write)."""

    def until(self, condition: Callable[[], bool], limit: float, what: str) -> int:
        """Run cycles until ``condition()``; returns how many it took (raises after ``limit`` seconds)."""
        for k in range(1, round(limit * self.engine.update_rate) + 1):
            self.cycle()
            if condition():
                return k
        raise AssertionError(f"no {what} within {limit:g} s")

    def collect_events(self) -> list[Event]:
        drained = self.engine.events.drain()
        self.events += [(self.cycles, e) for e in drained]
        return drained

    def events_since(self, cycle: int, levels: tuple[str, ...] = ("error", "warning")) -> list[tuple[int, Event]]:
        return [(k, e) for k, e in self.events if k >= cycle and e.level in levels]

    # ---- reading back -------------------------------------------------------------------------------------------
    @property
    def joints(self) -> tuple[str, ...]:
        return self.engine.joints

    def modes(self) -> list[str]:
        return [MODE_NAMES[int(m)] for m in self.engine.supervisor.mode]

    def faulted(self) -> list[str]:
        return [j for j, m in zip(self.joints, self.modes(), strict=True) if m == "fault"]

    def any_fault(self) -> bool:
        return bool(self.engine.supervisor.fault.any())

    # ---- operator requests (through the request queue, like the API) ---------------------------------------------
    def request(self, action: Callable[[], Any]) -> Any:
        """Submit ``action`` and run cycles until it is answered (a reset waits for the drives' confirmation)."""
        future = self.engine.submit(action)
        for _ in range(round(self.engine.update_rate)):
            self.cycle()
            if future.done():
                return future.result(timeout=0)
        raise AssertionError("the request was not answered within 1 s")

    def reset(self) -> dict[str, Any]:
        return dict(self.request(self.engine.reset))

    def enable(self) -> dict[str, Any]:
        return dict(self.request(self.engine.enable))

    def switch(self, activate: list[str], deactivate: list[str] | None = None) -> None:
        result = self.request(lambda: self.engine.switch(activate, deactivate or []))
        assert result.ok, result.error

    # ---- trajectory goals ---------------------------------------------------------------------------------------
    @property
    def jtc(self) -> JointTrajectoryController:
        instance = self.engine.manager.records[JTC].instance
        assert isinstance(instance, JointTrajectoryController)
        return instance

    def move(self, offset: float | list[float], **goal: Any) -> str:
        """A move_to goal ``offset`` (rad) away from where the joints are now; returns its id."""
        target = self.engine.state.position + np.asarray(offset, dtype=float)
        reply = GoalEndpoint.of(self.jtc.action).submit({"positions": target.tolist(), **goal})
        assert reply["ok"], reply["error"]
        return str(reply["goal_id"])

    def result(self, goal_id: str) -> GoalResult | None:
        """The goal's result if it has one (results are kept: asking twice is fine)."""
        GoalEndpoint.of(self.jtc.action).collect()
        reply = GoalEndpoint.of(self.jtc.action).result({"goal_id": goal_id})
        if reply.get("status") in (None, "executing"):
            return None
        return GoalResult(goal_id, reply["status"], reply["error_code"], reply["error_string"])

    def finish(self, goal_id: str, limit: float = 10.0) -> GoalResult:
        self.until(lambda: self.result(goal_id) is not None, limit, f"result of goal {goal_id}")
        result = self.result(goal_id)
        assert result is not None
        return result

    def close(self) -> None:
        self.engine.stop()


class EmulatedBusRig(Lockstep):
    """The real engine and CAN driver against emulated drives on one private virtual bus, in lockstep: the drives are
    serviced after every cycle, and every 0.1 ms of their own clock while a lifecycle hook waits for them."""

    def _workspace(self, prefix: str) -> Path:
        """A temporary directory for the config and a private channel name (``self.channel``)."""
        self._dir = tempfile.TemporaryDirectory(prefix=f"hild-{prefix}-")
        self.channel = f"{prefix}-{uuid.uuid4().hex[:10]}"
        return Path(self._dir.name)

    def _start(self, loaded: LoadedConfig, firmwares: list[MotorFirmware], plant: Any) -> None:
        """Serve ``firmwares`` with ``plant`` behind them on the channel, then build and start the engine."""
        self.bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.emulator = Emulator(self.bus, firmwares, plant)
        self.now = 0.0
        try:
            engine = Engine(loaded)
            self.driver: Any = engine.hardware[0].component
            self.driver.serve_while_waiting = self.serve_while_waiting
            engine.start()
        except BaseException:
            self.bus.shutdown()
            self._dir.cleanup()
            raise
        super().__init__(engine)

    def serve_while_waiting(self) -> None:
        self.now += 1e-4
        self.emulator.service(self.now)

    def step(self) -> None:
        self.engine.run_cycles(1)
        self.now += self.engine.period
        self.emulator.service(self.now)

    def close(self) -> None:
        try:
            super().close()
        finally:
            self.bus.shutdown()
            self._dir.cleanup()


class CanRig(EmulatedBusRig):
    """``n`` emulated drives of one flavour on one virtual bus, driven by the real CAN driver in the engine.

    With ``brakes`` (the default, as in ``hild emulate``) a joint whose drive is off stays where it is; without,
    it coasts."""

    def __init__(
        self,
        flavour: str = "damiao",
        n: int = 3,
        *,
        rate: float = 1000.0,
        params: dict[str, Any] | None = None,
        safety: dict[str, Any] | None = None,
        brakes: bool = True,
    ) -> None:
        path = self._workspace("faults") / "robot.yaml"
        path.write_text(yaml.safe_dump(can_robot(flavour, n, self.channel, rate, params, safety), sort_keys=False))
        loaded = load_config(path)
        driver_params = loaded.driver_params["arm"]
        assert isinstance(driver_params, MitCanParams | ODriveCanParams)
        self.flavour = flavour
        self.firmwares: list[MotorFirmware] = build_firmware(driver_params, list(loaded.config.hardware["arm"].joints))
        inertia = 0.002 if flavour == "odrive" else 0.05  # ODrive: its own gains (pos_gain 20, vel_gain 0.16) fit this
        self.motors = MotorPlant(n, inertia=inertia, damping=inertia, positions=START[:n])
        self.plant = BrakedPlant(self.motors, self.firmwares) if brakes else self.motors
        self._start(loaded, self.firmwares, self.plant)

    def _meanwhile(self, duration: float) -> None:
        """The drives run on alone, serviced every 0.1 ms: their watchdogs fire, their replies queue on the bus."""
        for _ in range(round(duration / 1e-4)):
            self.now += 1e-4
            self.emulator.service(self.now)

    def firmware(self, joint: str) -> MotorFirmware:
        return self.firmwares[self.joints.index(joint)]

    def drives_enabled(self) -> list[bool]:
        return [fw.enabled for fw in self.firmwares]


class MockRig(Lockstep):
    """Joints ``j1..jn`` (the CAN rigs' limits and gains) on the mock driver at 1 kHz: a drive with a first-order
    lag and no physics, the simplest hardware behind the same engine."""

    def __init__(self, n: int = 3) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="hild-faults-")
        doc = can_robot("damiao", n, "unused", 1000.0)
        names = list(doc["joints"])
        doc["robot"]["name"] = "faults_mock"
        params = {"initial_positions": dict(zip(names, START, strict=False)), "dynamics": "first_order"}
        doc["hardware"] = {"arm": {"driver": "mock", "params": params, "joints": {j: {} for j in names}}}
        path = Path(self._dir.name) / "robot.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        engine = Engine(load_config(path))
        engine.start()
        super().__init__(engine)

    def close(self) -> None:
        try:
            super().close()
        finally:
            self._dir.cleanup()


class TwinRig(Lockstep):
    """A shipped MuJoCo twin config (default arm6) on the sim clock; ``controllers`` patches controller params.

    With ``start=False`` the caller starts the engine (and drives it some other way: the guard assumes a start)."""

    def __init__(
        self,
        config: str = "arm6_twin.yaml",
        *,
        safety: dict[str, Any] | None = None,
        controllers: dict[str, dict[str, Any]] | None = None,
        start: bool = True,
    ) -> None:
        engine = Engine(twin_config(config, safety, controllers))
        if start:
            engine.start()
        super().__init__(engine)


def twin_config(
    config: str, safety: dict[str, Any] | None = None, controllers: dict[str, dict[str, Any]] | None = None
) -> LoadedConfig:
    """A shipped config on the sim clock (lockstep), with safety settings and controller params patched."""
    loaded = load_config(CONFIGS / config)
    cfg = loaded.config
    update: dict[str, Any] = {"clock": cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})}
    if safety:
        update["safety"] = cfg.safety.model_copy(update=safety)
    loaded.config = cfg.model_copy(update=update)
    for name, patch in (controllers or {}).items():
        loaded.controller_params[name] = loaded.controller_params[name].model_copy(update=patch)
    return loaded


def can_robot(
    flavour: str,
    n: int,
    channel: str,
    rate: float,
    params: dict[str, Any] | None = None,
    safety: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The config document of a CAN rig: joints ``j1..jn`` that fit every emulated model (limits, gains, efforts)."""
    driver, motor = MOTORS[flavour]
    names = [f"j{k + 1}" for k in range(n)]
    hardware_params: dict[str, Any] = {
        "bus": {"interface": "virtual", "channel": channel, "bitrate": 1_000_000},
        "reply_timeout_ms": 50,
    }
    if driver == "mit_can":
        hardware_params |= {"flavour": flavour, "motors": {j: motor(k) for k, j in enumerate(names)}}
        if flavour == "damiao":
            hardware_params["timeout_ms"] = 50
    else:
        hardware_params |= {"axes": {j: motor(k) for k, j in enumerate(names)}}
    hardware_params |= params or {}
    return {
        "robot": {"name": f"faults_{flavour}"},
        "update_rate": rate,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {"arm": {"driver": driver, "params": hardware_params, "joints": {j: {} for j in names}}},
        "joints": {j: rig_joint() for j in names},
        "controllers": {
            JTC: {
                "type": "joint_trajectory",
                "params": {
                    "joints": names,
                    "constraints": {
                        "stopped_velocity_tolerance": 0.05,
                        "joints": {j: {"goal": 0.01} for j in names},  # a goal succeeds only where it arrived
                    },
                },
            },
            "forward_position": {
                "type": "forward_command",
                "params": {"joints": names, "interface": "position", "command_timeout": 0.1},
            },
        },
        "safety": {"fault_action": "hold", "estop_action": "hold", "stale_feedback_cycles": 10, **(safety or {})},
    }


class ApiRig(TwinRig):
    """A twin rig behind the daemon's Zenoh API (``ApiServer``) on a private loopback port.

    The API runs on an asyncio loop in a thread, as in the daemon; cycles are stepped by the test. After each cycle
    the events it produced and the wake-ups (feedback, results) are handed to the API, as the daemon's wake-up
    does, so clients see what they would see from a daemon.
    """

    def __init__(self, controllers: dict[str, dict[str, Any]] | None = None) -> None:
        super().__init__(controllers=controllers)
        self.endpoint = free_endpoint()
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="faults-api", daemon=True)
        self._thread.start()
        self.server = ApiServer(self.engine, ZenohSection(), [self.endpoint], request_timeout=2.0)
        self._rang = False
        self.engine.wake_client = self._ring
        asyncio.run_coroutine_threadsafe(self.server.start(), self.loop).result(10.0)

    def _ring(self) -> None:
        self._rang = True

    def collect_events(self) -> list[Event]:
        drained = super().collect_events()
        if getattr(self, "server", None) is not None and (drained or self._rang):
            self._rang = False
            self.loop.call_soon_threadsafe(self.server.publish, drained)
        return drained

    def client(self) -> HildClient:
        return HildClient(self.engine.robot, connect=[self.endpoint], timeout=5.0)

    def wait(self, condition: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
        """Wait (wall clock, no cycles) for something the API does on its own thread."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
            time.sleep(0.002)

    def close(self) -> None:
        try:
            asyncio.run_coroutine_threadsafe(self.server.close(), self.loop).result(10.0)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(10.0)
            self.loop.close()
            super().close()
