"""The MuJoCo digital twin: a simulated arm behind the same hardware contract as the CAN servos.

Each joint behaves like an MIT-mode servo drive (docs/architecture.md, "The servo command"). The drive law
``τ = kp·(position − q) + kd·(velocity − q̇) + effort`` is evaluated inside the physics, once per physics step
(``substeps`` per cycle), from the simulated ``q, q̇`` of that step — as a real drive runs its own inner loop faster
than the bus. The torque is saturated to the joint's torque limit and applied as a generalized force on the joint's
degree of freedom (``qfrc_applied``); the model needs no ``<actuator>`` elements.

Timing: ``write`` advances the physics by exactly one cycle period (``substeps`` steps of ``period / substeps``), so
the simulation time is locked to the cycle clock whatever paces the cycle (wall clock for a real-time twin, the sim
clock for lockstep tests; docs/architecture.md, "Clocks"). ``read`` returns the state at the end of the last ``write``.

Lifecycle: like a real drive, the twin applies zero torque until ``on_activate`` and again after ``on_deactivate``; the
physics keeps running (the arm falls under gravity while disabled, as a real unbraked arm would).

Latency: with ``command_latency_cycles = N`` the command written in cycle k is applied during the physics of cycle
k + N (a preallocated ring of N + 1 commands). The ring starts empty (zero torque) at every ``on_activate``, so an
enabled drive applies zero torque for its first N cycles, as a drive that has not yet received a command.

Sensors (``force_torque``, ``imu``; docs/drivers.md, "The twin's sensors"): each reads MuJoCo sensors at a site —
a ``force``/``torque`` pair, or ``framequat``/``gyro``/``accelerometer`` — the model's own when it has them at that
site, else added (with a site at the origin of the ``frame_id`` body when the sensor names none) before the model
is compiled. Each value gets seeded Gaussian noise, so sim and real publish the same kind of signal and the frozen
check stays meaningful.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import mujoco
import numpy as np

from drivers.glitch import ReadingGlitch
from hild.arrays import JointState, SensorValues, ServoCommand, contiguous_slice
from hild.config.params import Field, Params, model_validator
from hild.dynamics.model import (
    SCALAR_JOINT_TYPES,
    SceneObject,
    SensorMount,
    couple_joints,
    joint_couplings,
    joint_names,
    linear_coupling,
    load_model,
    scalar_joint_addresses,
    site_sensor_addresses,
    stiffen_couplings,
)
from hild.hardware import ALL_COMMAND_FIELDS, HardwareComponent, HardwareContext, HardwareError
from hild.interfaces import FORCE_TORQUE, IMU, SensorSpec

__all__ = ["MujocoTwin", "MujocoTwinParams", "MujocoTwinSensorParams"]

_COMMAND_FIELDS = ("position", "velocity", "effort", "kp", "kd")
_BAD_QACC = int(mujoco.mjtWarning.mjWARN_BADQACC)

NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class TwinObject(Params):
    """A primitive the twin adds to the world: something to grasp, or a table to put it on."""

    name: str = Field(min_length=1, description="Body (and geom) name; must not be one of the model's.")
    shape: Literal["box", "sphere", "cylinder"] = "box"
    size: list[Positive] = Field(
        min_length=1, max_length=3, description="Half-sizes (m): box [x, y, z], sphere [r], cylinder [r, half-height]."
    )
    pos: tuple[Finite, Finite, Finite] = Field(description="Position in the world (m) at start.")
    quat: tuple[Finite, Finite, Finite, Finite] = (1.0, 0.0, 0.0, 0.0)
    mass: Positive = Field(default=0.1, description="kg (a fixed object's mass does not matter).")
    friction: Positive = Field(default=1.0, description="Sliding friction coefficient.")
    fixed: bool = Field(default=False, description="Welded to the world (a table) instead of free (a box).")

    @model_validator(mode="after")
    def _sized(self) -> TwinObject:
        needed = {"box": 3, "sphere": 1, "cylinder": 2}[self.shape]
        if len(self.size) != needed:
            raise ValueError(f"a {self.shape} takes {needed} half-size(s), got {len(self.size)}")
        return self

    def scene_object(self) -> SceneObject:
        return SceneObject(
            self.name, self.shape, tuple(self.size), self.pos, self.quat, self.mass, self.friction, self.fixed
        )


class MujocoTwinParams(Params):
    model: str = Field(description="MJCF (.xml) or URDF (.urdf) of the arm, relative to the config file.")
    substeps: int = Field(
        default=1, ge=1, le=1000, description="Physics steps per cycle; the timestep is set to period / substeps."
    )
    command_latency_cycles: int = Field(
        default=0, ge=0, le=1000, description="A command takes effect this many cycles after it is written."
    )
    keyframe: str | None = Field(default=None, description="Model keyframe for the start pose (default: qpos0).")
    initial_positions: dict[str, Finite] = Field(
        default_factory=dict, description="Start position per joint (rad or m), overriding qpos0 / the keyframe."
    )
    torque_limits: dict[str, Positive] = Field(
        default_factory=dict,
        description="Drive torque limit per joint (N·m or N, symmetric). Default: the joint's actuatorfrcrange.",
    )
    friction: dict[str, NonNegative] = Field(
        default_factory=dict, description="Coulomb friction per joint (MuJoCo frictionloss), overriding the model."
    )
    armature: dict[str, NonNegative] = Field(
        default_factory=dict, description="Reflected rotor inertia per joint (kg·m²), overriding the model."
    )
    damping: dict[str, NonNegative] = Field(
        default_factory=dict, description="Viscous joint damping (N·m·s/rad), overriding the model."
    )
    gravity: bool = Field(default=True, description="False disables gravity in the simulation.")
    exclude_contacts: list[tuple[str, str]] = Field(
        default_factory=list,
        description="Body pairs whose contacts the simulation ignores (MuJoCo <contact><exclude>): links of the arm "
        "that touch by construction, e.g. collision meshes overlapping at the start pose.",
    )
    objects: list[TwinObject] = Field(
        default_factory=list, description="Primitives added to the world: boxes to grasp, tables (docs/drivers.md)."
    )
    friction_cone: Literal["pyramidal", "elliptic"] | None = Field(
        default=None,
        description="MuJoCo's friction cone (default: the model's). Grasping: elliptic, with impratio ~10, keeps a "
        "held object from creeping out of the fingers.",
    )
    impratio: Positive | None = Field(
        default=None, description="MuJoCo's frictional-to-normal impedance ratio (default: the model's)."
    )


class MujocoTwinSensorParams(Params):
    """A twin sensor's ``params`` (``hardware.<twin>.sensors.<name>.params``)."""

    site: str | None = Field(
        default=None,
        description="The model's site the sensor sits at; default: a site added at the origin of the frame_id body.",
    )
    force_noise: NonNegative = Field(default=0.05, description="N: std dev of the noise on each force component.")
    torque_noise: NonNegative = Field(default=0.002, description="N·m: std dev on each torque component.")
    orientation_noise: NonNegative = Field(default=0.0, description="Std dev on each quaternion component.")
    gyro_noise: NonNegative = Field(default=0.003, description="rad/s: std dev on each angular velocity component.")
    accel_noise: NonNegative = Field(default=0.02, description="m/s²: std dev on each acceleration component.")
    seed: int = Field(default=0, description="Seed of this sensor's noise (the sensor's index is added).")

    def scales(self, kind: str) -> list[float]:
        """Noise per value, in the order of the sensor type's interfaces."""
        if kind == FORCE_TORQUE:
            return [self.force_noise] * 3 + [self.torque_noise] * 3
        return [self.orientation_noise] * 4 + [self.gyro_noise] * 3 + [self.accel_noise] * 3


class TwinSensor:
    """One sensor's way from ``sensordata`` to hild's values: addresses (hild's order), noise, preallocated."""

    def __init__(self, spec: SensorSpec, params: MujocoTwinSensorParams, addresses: list[int], seed: int) -> None:
        self.part = spec.part
        if spec.type == IMU:  # framequat is (w, x, y, z); hild's orientation is x, y, z, w as ROS's
            quat, gyro, accel = addresses
            index = [quat + 1, quat + 2, quat + 3, quat, *range(gyro, gyro + 3), *range(accel, accel + 3)]
        else:
            force, torque = addresses
            index = [*range(force, force + 3), *range(torque, torque + 3)]
        self.index = np.array(index, dtype=np.intp)
        self.scale = np.array(params.scales(spec.type))
        self.rng = np.random.default_rng(seed)
        self.noise = np.zeros(spec.width)
        self.exact = np.zeros(spec.width)  # MuJoCo's own values, before the noise


class MujocoTwin(HardwareComponent):
    """A MuJoCo simulation of the arm that speaks the servo command of every hild backend.

    Joints are matched to model joints by name (hinge or slide joints). Actuator space is the model's joint space:
    give the twin's joints identity transmissions unless the model itself is built in actuator coordinates.
    """

    Params = MujocoTwinParams

    COMMAND_FIELDS = ALL_COMMAND_FIELDS
    SIMULATED = True
    SENSOR_TYPES = frozenset({FORCE_TORQUE, IMU})
    SensorParams = MujocoTwinSensorParams

    @classmethod
    def files(cls, params: Params) -> dict[str, str]:
        assert isinstance(params, MujocoTwinParams)
        return {"model": params.model}

    def __init__(self, context: HardwareContext, params: MujocoTwinParams) -> None:
        super().__init__(context, params)
        self.glitch = ReadingGlitch(len(context.joints))  # test hook: corrupts reported positions only
        self.params: MujocoTwinParams = params
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._active = False
        self._ring: dict[str, np.ndarray] = {}  # allocated at configure
        self._sensors: list[TwinSensor] = []  # bound at configure

    # ------------------------------------------------------------------ lifecycle (non real-time)

    def on_configure(self) -> None:
        """Load the model, bind the configured joints to it, apply the params' physics; refuse a bad start."""
        p = self.params
        path = self.context.config_dir / p.model
        try:
            objects = [o.scene_object() for o in p.objects]
            model = load_model(path, p.exclude_contacts, sensors=self._mounts(), objects=objects)
        except ValueError as exc:
            raise HardwareError(f"{self.context.name}: {exc}") from None
        self._check_names()
        try:
            jid, qposadr, dofadr = scalar_joint_addresses(model, self.joints)
        except ValueError as exc:
            raise HardwareError(
                f"{self.context.name}: joints do not match the model {path.name}: {exc}; "
                f"configured joints: {', '.join(self.joints)}"
            ) from None
        self._check_mimic_joints(model, path.name)
        self._warn_about_unused_parts(model, jid)
        for values, field in (
            (p.friction, model.dof_frictionloss),
            (p.armature, model.dof_armature),
            (p.damping, model.dof_damping),
        ):
            for name, value in values.items():
                field[dofadr[self.joints.index(name)]] = value
        self._tau_lo, self._tau_hi = self._torque_limits(model, jid)
        self._tau_lo_list, self._tau_hi_list = self._tau_lo.tolist(), self._tau_hi.tolist()

        if p.friction_cone is not None:
            model.opt.cone = int(getattr(mujoco.mjtCone, f"mjCONE_{p.friction_cone.upper()}"))
        if p.impratio is not None:
            model.opt.impratio = p.impratio
        model.opt.timestep = self.context.period / p.substeps
        if path.suffix.lower() == ".urdf":  # a URDF cannot give its <mimic> couplings a stiffness: make them rigid
            stiffen_couplings(model, model.opt.timestep)
        if not p.gravity:
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
        self._keyframe = self._check_start(model, jid, path.name)

        self.model, self.data = model, mujoco.MjData(model)
        self._qposadr, self._dofadr = qposadr, dofadr
        self._bind_sensors(model)
        self._allocate()
        self.reset()

    def _check_mimic_joints(self, model: mujoco.MjModel, model_name: str) -> None:
        """The config's mimic joints are reported as ``multiplier·q + offset``: the model must couple each of them
        that way (a joint equality, as MuJoCo makes of URDF ``<mimic>``), or joint_states would say one thing and
        the simulation do another."""
        for mimic in self.context.mimic_joints:
            wanted = f"{mimic.joint!r} × {mimic.multiplier:g} + {mimic.offset:g}"
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, mimic.name) < 0:
                raise HardwareError(
                    f"{self.context.name}: mimic joint {mimic.name!r} (follows {wanted}) is not a joint of the "
                    f"model {model_name}"
                )
            found = linear_coupling(model, mimic.name)
            if found is None:
                raise HardwareError(
                    f"{self.context.name}: mimic joint {mimic.name!r} follows {wanted} in the config, but the model "
                    f"{model_name} does not couple it linearly to any joint: add <mimic joint={mimic.joint!r} "
                    f'multiplier="{mimic.multiplier:g}" offset="{mimic.offset:g}"/> to it (URDF) or a joint '
                    "equality (MJCF)"
                )
            leader, multiplier, offset = found
            if leader != mimic.joint or not (
                math.isclose(multiplier, mimic.multiplier, abs_tol=1e-9)
                and math.isclose(offset, mimic.offset, abs_tol=1e-9)
            ):
                raise HardwareError(
                    f"{self.context.name}: mimic joint {mimic.name!r} follows {wanted} in the config, but the model "
                    f"{model_name} couples it as {leader!r} × {multiplier:g} + {offset:g}: make them agree"
                )

    def _warn_about_unused_parts(self, model: mujoco.MjModel, jid: np.ndarray) -> None:
        """Model joints nobody drives, and actuators the twin never sets, surprise users: say so at configure.
        A joint a joint equality couples to another (a mimic joint) is not free: it follows."""
        coupled = {c.follower for c in joint_couplings(model)}
        passive = [
            name
            for i, name in enumerate(joint_names(model))
            if int(model.jnt_type[i]) in SCALAR_JOINT_TYPES and i not in jid and i not in coupled
        ]
        if passive:
            self.context.emit_event(
                "warning", f"{self.context.name}: model joints not driven by this component move freely: {passive}"
            )
        if model.nu:
            self.context.emit_event(
                "warning",
                f"{self.context.name}: the model's {model.nu} <actuator> elements are not used by the twin and stay "
                "at ctrl = 0 (a position actuator then pulls its joint towards 0): remove them from the model",
            )

    def _check_start(self, model: mujoco.MjModel, jid: np.ndarray, model_name: str) -> int:
        """The keyframe's index (-1: none); a missing keyframe or an initial position out of range is refused."""
        p, keyframe = self.params, -1
        if p.keyframe is not None:
            keyframe = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, p.keyframe)
            if keyframe < 0:
                keys = [model.key(i).name for i in range(model.nkey)]
                raise HardwareError(f"{self.context.name}: model {model_name} has no keyframe {p.keyframe!r} ({keys})")
        for name, value in p.initial_positions.items():
            j = jid[self.joints.index(name)]
            if model.jnt_limited[j] and not model.jnt_range[j, 0] <= value <= model.jnt_range[j, 1]:
                lo, hi = model.jnt_range[j]
                raise HardwareError(
                    f"{self.context.name}: initial position {value} of {name} is outside its range [{lo}, {hi}]"
                )
        return keyframe

    def on_activate(self) -> None:
        self._clear_commands()
        self._active = True

    def on_deactivate(self) -> None:
        self._active = False
        if self.data is None or not self._ring:  # configure failed or cleanup ran: nothing is driven
            return
        self._clear_commands()
        self._tau.fill(0.0)
        self._frc_all.fill(0.0)

    def on_cleanup(self) -> None:
        self._active = False
        self.model = self.data = None
        self._q = self._qd = self._frc = self._qpos_all = self._qvel_all = self._frc_all = None  # views on the data

    def reset(self) -> None:
        """Put the twin back to its start pose at rest, sim time 0, no pending commands (non real-time): the keyframe
        or qpos0, then initial_positions, then every joint a joint equality couples (mimic joints) from its leader."""
        m, d = self.model, self.data
        if m is None or d is None:
            raise HardwareError(f"{self.context.name}: reset() before configure()")
        if self._keyframe >= 0:
            mujoco.mj_resetDataKeyframe(m, d, self._keyframe)
        else:
            mujoco.mj_resetData(m, d)
        for name, value in self.params.initial_positions.items():
            d.qpos[self._qposadr[self.joints.index(name)]] = value
        d.qvel[:] = 0.0
        couple_joints(m, d)  # mimic joints where their leaders put them, or the couplings snap at the first step
        d.time = 0.0
        self._clear_commands()
        self._tau.fill(0.0)
        mujoco.mj_forward(m, d)

    @property
    def sim_time(self) -> float:
        """Simulation time in seconds: advances by one cycle period per ``write``."""
        return 0.0 if self.data is None else float(self.data.time)

    def health(self) -> str | None:
        if self.data is not None and self.data.warning[_BAD_QACC].number > 0:
            return (
                f"simulation diverged (bad acceleration, {self.data.warning[_BAD_QACC].number}×) and MuJoCo reset "
                "its state: lower the gains or raise substeps, then reset() the twin"
            )
        return None

    # ------------------------------------------------------------------ cycle (real time)

    def read(self, t: float, dt: float, state: JointState) -> None:
        """Position and velocity from the simulation, effort = the torque applied in the last physics step."""
        if self._gather:
            np.take(self._qpos_all, self._qposadr, out=state.position)
            np.take(self._qvel_all, self._dofadr, out=state.velocity)
        else:
            np.copyto(state.position, self._q)
            np.copyto(state.velocity, self._qd)
        np.copyto(state.effort, self._tau)
        state.temperature.fill(math.nan)
        state.fault.fill(0)
        state.fresh.fill(True)
        if self.glitch.active:
            self.glitch.apply(state.position, state.fresh)

    def read_sensors(self, t: float, dt: float, values: SensorValues) -> None:
        """Each sensor's MuJoCo values (computed in the last physics step) plus its noise."""
        data = self.data.sensordata
        out = values.values
        for k, sensor in enumerate(self._sensors):
            np.take(data, sensor.index, out=sensor.exact)
            sensor.rng.standard_normal(out=sensor.noise)
            sensor.noise *= sensor.scale
            np.add(sensor.exact, sensor.noise, out=out[sensor.part])
            values.fresh[k] = True

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        """Queue ``command`` and advance the physics by one cycle, running the drive law in every substep."""
        m, d = self.model, self.data
        if not self._active:
            self._tau.fill(0.0)
            self._frc_all.fill(0.0)
            mujoco.mj_step(m, d, self.params.substeps)
            return

        # The drive applies the command written command_latency_cycles ago. Commands wait in a ring of
        # latency + 1 slots: the one due now is the slot the next write will overwrite. Without latency the
        # command is used directly.
        slots = self._slots
        if slots:
            head = self._head
            pos, vel, eff, kp, kd = slots[head]
            np.copyto(pos, command.position)
            np.copyto(vel, command.velocity)
            np.copyto(eff, command.effort)
            np.copyto(kp, command.kp)
            np.copyto(kd, command.kd)
            head += 1
            self._head = head = 0 if head == len(slots) else head
            pos, vel, eff, kp, kd = slots[head]
        else:
            pos, vel, eff, kp, kd = command.position, command.velocity, command.effort, command.kp, command.kd

        # τ = kp·(position − q) + kd·(velocity − q̇) + effort, saturated to the drive's limits, on plain floats:
        # for a handful of joints that is several times cheaper than a chain of numpy calls.
        p_cmd, v_cmd, ff_cmd, kp_cmd, kd_cmd = pos.tolist(), vel.tolist(), eff.tolist(), kp.tolist(), kd.tolist()
        lo, hi, joints = self._tau_lo_list, self._tau_hi_list, range(len(p_cmd))
        q, qd, tau = self._q, self._qd, self._tau
        for _ in range(self.params.substeps):
            if self._gather:
                np.take(self._qpos_all, self._qposadr, out=q)
                np.take(self._qvel_all, self._dofadr, out=qd)
            q_now, qd_now, torques = q.tolist(), qd.tolist(), []
            for i in joints:
                torque = kp_cmd[i] * (p_cmd[i] - q_now[i]) + kd_cmd[i] * (v_cmd[i] - qd_now[i]) + ff_cmd[i]
                if torque != torque:  # NaN (e.g. 0·inf in a bad command): a drive rejects it, applies nothing
                    torque = 0.0
                elif torque > hi[i]:
                    torque = hi[i]
                elif torque < lo[i]:
                    torque = lo[i]
                torques.append(torque)
            tau[:] = torques
            if self._gather:
                np.put(self._frc_all, self._dofadr, tau)
            else:
                np.copyto(self._frc, tau)
            mujoco.mj_step(m, d)

    # ------------------------------------------------------------------ helpers

    def _mounts(self) -> list[SensorMount]:
        mounts = []
        for spec in self.context.sensors:
            params = self._sensor_params(spec.name)
            mounts.append(SensorMount(spec.name, spec.type, spec.frame_id, params.site))
        return mounts

    def _sensor_params(self, name: str) -> MujocoTwinSensorParams:
        params = self.context.sensor_params.get(name)
        return params if isinstance(params, MujocoTwinSensorParams) else MujocoTwinSensorParams()

    def _bind_sensors(self, model: mujoco.MjModel) -> None:
        self._sensors = []
        for k, (spec, mount) in enumerate(zip(self.context.sensors, self._mounts(), strict=True)):
            params = self._sensor_params(spec.name)
            try:
                addresses = site_sensor_addresses(model, mount)
            except ValueError as exc:
                raise HardwareError(f"{self.context.name}: {exc}") from None
            self._sensors.append(TwinSensor(spec, params, addresses, params.seed + k))

    def _check_names(self) -> None:
        known = set(self.joints)
        p = self.params
        for label, table in (
            ("initial_positions", p.initial_positions),
            ("torque_limits", p.torque_limits),
            ("friction", p.friction),
            ("armature", p.armature),
            ("damping", p.damping),
        ):
            unknown = sorted(set(table) - known)
            if unknown:
                raise HardwareError(
                    f"{self.context.name}: params.{label} names unknown joints {unknown} "
                    f"(this component drives: {', '.join(self.joints)})"
                )

    def _torque_limits(self, model: mujoco.MjModel, jid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.joints)
        lo, hi = np.empty(n), np.empty(n)
        for i, name in enumerate(self.joints):
            if name in self.params.torque_limits:
                limit = self.params.torque_limits[name]
                lo[i], hi[i] = -limit, limit
                continue
            j = jid[i]
            if not model.jnt_actfrclimited[j]:
                raise HardwareError(
                    f"{self.context.name}: no torque limit for joint {name}: set params.torque_limits.{name} or "
                    'actuatorfrcrange (with actuatorfrclimited="true") on the joint in the model '
                    "(URDF: <limit effort=...>)"
                )
            lo[i], hi[i] = model.jnt_actfrcrange[j]
            if not lo[i] <= 0.0 <= hi[i] or lo[i] == hi[i]:
                raise HardwareError(
                    f"{self.context.name}: actuatorfrcrange [{lo[i]}, {hi[i]}] of joint {name} must contain 0"
                )
        return lo, hi

    def _allocate(self) -> None:
        """Preallocate every buffer and view the cycle uses (views on MjData stay valid for its lifetime)."""
        d, n = self.data, len(self.joints)
        self._qpos_all, self._qvel_all, self._frc_all = d.qpos, d.qvel, d.qfrc_applied
        self._frc_all.fill(0.0)
        self._tau = np.zeros(n)
        qb, db = contiguous_slice(self._qposadr), contiguous_slice(self._dofadr)
        # The usual case: the joints are one contiguous block in model order, so work on views directly.
        self._gather = qb is None or db is None
        if self._gather:
            self._q, self._qd, self._frc = np.zeros(n), np.zeros(n), None
        else:
            self._q, self._qd, self._frc = d.qpos[qb], d.qvel[db], d.qfrc_applied[db]
        latency = self.params.command_latency_cycles
        ring = latency + 1 if latency else 0
        self._ring = {name: np.zeros((ring, n)) for name in _COMMAND_FIELDS}
        self._slots = [tuple(self._ring[name][k] for name in _COMMAND_FIELDS) for k in range(ring)]
        self._head = 0

    def _clear_commands(self) -> None:
        """Forget queued commands: the drive applies zero torque until the new ones come through."""
        for buf in self._ring.values():
            buf.fill(0.0)
        self._head = 0
