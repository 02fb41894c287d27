"""The mock driver: a drive without physics, for tests and for trying configs without a model.

It mirrors the servo command into the state (optionally through a first-order lag) and reports the torque the
drive law would produce. Fault-injection hooks make the supervisor's fault paths testable: silence a servo,
raise a drive fault code, fail reads, report a component-level problem, or corrupt readings (``glitch``).

Homing (``params.homing``): like a drive's own homing, the joint travels at constant speed to its home switch
(``switch``, in the frame it had at start) over ``duration`` s, ignoring the servo command, and then reads
``home_offset`` there (its origin moved); ``stop_homing`` ends it FAILED where it is; a test makes the next one
fail with the drive's words by setting ``homing_failure``.

Sensors (``force_torque``, ``imu``): each reads ``sensor_values[name]`` (settable; from its params at start) plus
seeded Gaussian noise of ``noise`` (orientation excepted), so the frozen check has something to see; tests set
values, silence a sensor (``sensor_silent``) or make ``read_sensors`` raise (``sensor_error``).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from drivers.glitch import ReadingGlitch
from hild.arrays import JointState, SensorValues, ServoCommand
from hild.config.params import Field, Params
from hild.hardware import HardwareComponent, HardwareContext, HardwareError, Homing
from hild.interfaces import FORCE_TORQUE, IMU


class MockHomingParams(Params):
    duration: float = Field(default=1.0, gt=0.0, description="Seconds a homing takes, at constant speed.")
    switch: dict[str, float] = Field(
        default_factory=dict, description="Per joint, where its home switch is (rad, in its frame at start); default 0."
    )
    home_offset: float = Field(default=0.0, description="What a joint reads at its switch once homed (rad).")


class MockParams(Params):
    initial_positions: dict[str, float] = Field(default_factory=dict, description="Start pose (rad); default 0.")
    dynamics: Literal["mirror", "first_order"] = Field(
        default="mirror", description="mirror: state = command. first_order: state follows with time_constant."
    )
    time_constant: float = Field(default=0.02, gt=0.0, description="Seconds, for first_order dynamics.")
    homing: MockHomingParams | None = Field(
        default=None, description="Simulate a drive's own homing (hild ctl home); none: the mock cannot home."
    )


class MockSensorParams(Params):
    values: list[float] | None = Field(
        default=None,
        description="The sensor's values in interface order; default zeros (an IMU: orientation w 1, linear "
        "acceleration z 9.81).",
    )
    noise: float = Field(default=0.01, ge=0.0, description="Std dev of the Gaussian noise added to each value.")
    seed: int = Field(default=0, description="Seed of the noise (the sensor's index is added).")


def _rest_values(kind: str, width: int) -> np.ndarray:
    values = np.zeros(width)
    if kind == IMU:
        values[3], values[9] = 1.0, 9.81  # orientation.w, linear_acceleration.z
    return values


class MockHardware(HardwareComponent):
    Params = MockParams
    SIMULATED = True
    SENSOR_TYPES = frozenset({FORCE_TORQUE, IMU})
    SensorParams = MockSensorParams

    def __init__(self, context: HardwareContext, params: MockParams) -> None:
        super().__init__(context, params)
        unknown = set(params.initial_positions) - set(context.joints)
        if unknown:
            raise HardwareError(f"initial_positions names unknown joints {sorted(unknown)}")
        n = len(context.joints)
        self.position = np.array([params.initial_positions.get(j, 0.0) for j in context.joints])
        self.velocity = np.zeros(n)
        self.effort = np.zeros(n)
        self.enabled = False
        self.last_command = ServoCommand.zeros(n)
        # Fault injection (set from tests; plain attribute writes are atomic under the GIL).
        self.silent = np.zeros(n, dtype=bool)
        self.fault_codes = np.zeros(n, dtype=np.int64)
        self.read_error: str | None = None
        self.write_error: str | None = None
        self.health_problem: str | None = None
        self.glitch = ReadingGlitch(n)  # corrupts reported positions only (drivers/glitch.py)
        self.homing_failure: str | None = None  # set: a running homing fails with these words at the next write
        self.homing_started: list[str] = []  # the joints start_homing was called for, in order (tests read it)
        self.homing_stopped: list[str] = []  # and stop_homing
        self._homing: dict[int, list[float]] = {}  # joint → [switch position (frame at start), seconds left]
        self._homing_end: dict[int, tuple[Homing, str]] = {}  # joint → its outcome, until `homing` reports it
        self.sensor_values: dict[str, np.ndarray] = {}
        self.sensor_silent: set[str] = set()
        self.sensor_error: str | None = None
        self._sensor_noise: list[tuple[slice, np.ndarray, np.random.Generator, np.ndarray]] = []
        for k, spec in enumerate(context.sensors):
            sp = context.sensor_params.get(spec.name)
            p = sp if isinstance(sp, MockSensorParams) else MockSensorParams()
            base = _rest_values(spec.type, spec.width) if p.values is None else np.array(p.values, dtype=float)
            if len(base) != spec.width:
                raise HardwareError(f"sensor {spec.name}: {len(base)} values, a {spec.type} sensor has {spec.width}")
            self.sensor_values[spec.name] = base
            mask = np.array([0.0 if v.startswith("orientation") else 1.0 for v in spec.values])
            rng = np.random.default_rng(p.seed + k)  # two sensors never share a noise stream
            self._sensor_noise.append((spec.part, mask * p.noise, rng, np.zeros(spec.width)))

    def on_activate(self) -> None:
        self.enabled = True

    def set_zero(self, joint: str) -> None:
        """Like a drive's set-zero: the current position reads 0 from now on (the arm itself does not move)."""
        self.position[self.joints.index(joint)] = 0.0

    def start_homing(self, joint: str) -> None:
        h = self.params.homing
        if h is None:
            raise HardwareError("mock: no homing configured (params.homing)")
        i = self.joints.index(joint)
        unknown = set(h.switch) - set(self.joints)
        if unknown:
            raise HardwareError(f"mock: homing.switch names unknown joints {sorted(unknown)}")
        self.homing_started.append(joint)
        self._homing_end.pop(i, None)
        self._homing[i] = [h.switch.get(joint, 0.0), h.duration]

    def stop_homing(self, joint: str) -> None:
        i = self.joints.index(joint)
        self.homing_stopped.append(joint)
        if self._homing.pop(i, None) is not None:
            self.velocity[i] = 0.0
            self._homing_end[i] = (Homing.FAILED, "stopped")

    def homing(self, joint: str) -> tuple[Homing, str]:
        i = self.joints.index(joint)
        if i in self._homing:
            return Homing.RUNNING, ""
        return self._homing_end.pop(i, (Homing.IDLE, ""))

    def _home(self, dt: float, q_all: list[float]) -> None:
        """Advance the running homings by ``dt`` from the positions before this write (``q_all``): each joint
        moves on toward its switch by itself, whatever it was commanded."""
        assert self.params.homing is not None
        for i, run in list(self._homing.items()):
            if self.homing_failure:
                del self._homing[i]
                self.position[i], self.velocity[i] = q_all[i], 0.0
                self._homing_end[i] = (Homing.FAILED, self.homing_failure)
                continue
            switch, left = run
            q = q_all[i]
            step = (switch - q) * min(1.0, dt / left)
            self.position[i] = q + step
            self.velocity[i] = step / dt
            run[1] = left - dt
            if run[1] <= 1e-9:  # at the switch: the drive's origin moves so that it reads home_offset here
                del self._homing[i]
                self.position[i], self.velocity[i] = self.params.homing.home_offset, 0.0
                self._homing_end[i] = (Homing.ATTAINED, "")

    def on_deactivate(self) -> None:
        self.enabled = False

    def read(self, t: float, dt: float, state: JointState) -> None:
        if self.read_error:
            raise HardwareError(self.read_error)
        fresh = ~self.silent
        np.copyto(state.position, self.position, where=fresh)
        np.copyto(state.velocity, self.velocity, where=fresh)
        np.copyto(state.effort, self.effort, where=fresh)
        np.copyto(state.fresh, fresh)
        np.copyto(state.fault, self.fault_codes)
        if self.glitch.active:
            self.glitch.apply(state.position, fresh)

    def read_sensors(self, t: float, dt: float, values: SensorValues) -> None:
        if self.sensor_error:
            raise HardwareError(self.sensor_error)
        for k, spec in enumerate(self.context.sensors):
            part, scale, rng, buf = self._sensor_noise[k]
            if spec.name in self.sensor_silent:
                values.fresh[k] = False
                continue
            rng.standard_normal(out=buf)
            np.multiply(buf, scale, out=buf)
            np.add(self.sensor_values[spec.name], buf, out=values.values[part])
            values.fresh[k] = True

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        if self.write_error:
            raise HardwareError(self.write_error)
        self.last_command.copy_from(command)
        if not self.enabled or dt <= 0.0:
            return
        # Plain floats: a mock stands in for a drive in benchmarks too, so it should not cost more than one.
        q_all, qd_all = self.position.tolist(), self.velocity.tolist()
        p_cmd, v_cmd, ff_cmd = command.position.tolist(), command.velocity.tolist(), command.effort.tolist()
        kp_cmd, kd_cmd = command.kp.tolist(), command.kd.tolist()
        first_order = self.params.dynamics == "first_order"
        alpha = 1.0 - math.exp(-dt / self.params.time_constant) if first_order else 1.0
        positions, velocities, torques = [], [], []
        for i, q in enumerate(q_all):
            qd, kp, kd = qd_all[i], kp_cmd[i], kd_cmd[i]
            torques.append(kp * (p_cmd[i] - q) + kd * (v_cmd[i] - qd) + ff_cmd[i])
            # stiff: goes to the commanded position; otherwise moves at the commanded (damped) or current velocity
            target = p_cmd[i] if kp > 0.0 else q + (v_cmd[i] if kd > 0.0 else qd) * dt
            if first_order:
                target = q + alpha * (target - q)
            positions.append(target)
            velocities.append((target - q) / dt)
        self.velocity[:] = velocities
        self.position[:] = positions
        self.effort[:] = torques
        if self._homing:  # a homing joint ignores the command: the drive moves by itself
            self._home(dt, q_all)

    def health(self) -> str | None:
        return self.health_problem

    def clear_faults(self) -> None:
        """Drive fault codes clear on request; an injected health problem persists until the test lifts it."""
        self.fault_codes[:] = 0
