"""A CAN driver and its emulated drives on a private in-process virtual channel, stepped in lockstep.

A cycle is ``write → emulator.service(t + dt) → read``: a drive answers cycle k's command before cycle k+1 reads,
as on a real bus, with no sleep anywhere. Lifecycle hooks that wait for replies serve the emulator through the
driver's ``serve_while_waiting``, a small step of emulator time per wait.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.can.emulator import Emulator, MotorPlant
from drivers.can.emulator.base import MotorFirmware
from hild.arrays import JointState, ServoCommand
from hild.hardware import HardwareContext


class LockstepRig:
    """Subclasses build their driver from :meth:`context` and ``self.channel``, then call :meth:`attach`."""

    def __init__(self, name: str, joints: Sequence[str], rate: float, wait_step: float) -> None:
        self.channel = f"{name}-{uuid.uuid4().hex[:10]}"
        self.events: list[tuple[str, str]] = []
        self.joints = tuple(joints)
        self.dt = 1.0 / rate
        self.wait_step = wait_step
        self.now = 0.0  # the emulator's clock
        self.t = 0.0  # the driver's clock
        self.state = JointState.zeros(len(joints))
        self.command = ServoCommand.zeros(len(joints))
        self._rate = rate

    def context(self, name: str) -> HardwareContext:
        emit: Callable[[str, str], None] = lambda level, msg: self.events.append((level, msg))  # noqa: E731
        return HardwareContext(name, self.joints, Path("."), self._rate, "sim", emit)

    def attach(self, driver: Any, firmwares: list[MotorFirmware], plant: MotorPlant) -> None:
        self.driver = driver
        self.firmwares = firmwares
        self.plant = plant
        self.bus = can.Bus(interface="virtual", channel=self.channel)  # the emulator's end; also for injecting
        self.emulator = Emulator(self.bus, firmwares, plant)
        driver.serve_while_waiting = self.serve_while_waiting

    def serve_while_waiting(self) -> None:
        self.now += self.wait_step
        self.emulator.service(self.now)

    def start(self) -> None:
        self.driver.on_configure()
        self.driver.read(0.0, self.dt, self.state)
        self.driver.on_activate()

    def hold(self, kp: float, kd: float) -> None:
        """Command every motor to hold its measured position."""
        self.command.position[:] = self.state.position
        self.command.velocity[:] = 0.0
        self.command.effort[:] = 0.0
        self.command.kp[:] = kp
        self.command.kd[:] = kd

    def cycle(self, count: int = 1) -> None:
        for _ in range(count):
            self.driver.write(self.t, self.dt, self.command)
            self.now += self.dt
            self.t += self.dt
            self.emulator.service(self.now)
            self.driver.read(self.t, self.dt, self.state)

    def inject(self, msg: can.Message) -> None:
        """A frame from somewhere else on the bus."""
        self.bus.send(msg)


def rig_factory(make: Callable[..., LockstepRig]) -> Callable[[], Iterator[Callable[..., Any]]]:
    """A fixture that makes rigs with ``make`` and cleans every one up (driver first, then its bus)."""

    @pytest.fixture
    def rigs() -> Iterator[Callable[..., Any]]:
        made: list[LockstepRig] = []

        def build(*args: Any, **kwargs: Any) -> LockstepRig:
            made.append(make(*args, **kwargs))
            return made[-1]

        yield build
        for rig in made:
            rig.driver.on_cleanup()
            rig.bus.shutdown()

    return rigs
