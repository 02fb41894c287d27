"""The engine: one robot's hardware, supervisor and controllers, advanced one cycle per ``step(t, dt)``.

``step`` is the whole real-time cycle (docs/architecture.md, "The cycle"):

    apply queued requests → read → transmissions → supervisor.check → controllers → supervisor.command
    → transmissions → write

It is paced by ``hild.cycle.pacing.CycleThread``, on the cycle process's main thread or on a thread of a single
daemon process, or called directly by tests in lockstep, which makes control tests deterministic. Everything else
reaches the engine through typed requests (``request``, ``request_estop``: applied at the start of the next cycle,
answered through a ``concurrent.futures.Future``) and reads it back through ``snapshot()``, ``status()`` and the
controllers' output rings.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from hild import plugins
from hild.arrays import (
    JointState,
    MimicJoints,
    SensorValues,
    SensorView,
    ServoCommand,
    contiguous_slice,
    gather_command,
    scatter_state,
)
from hild.config.loader import LoadedConfig
from hild.config.tuning import MANAGER, ManagerParams
from hild.controller import ControllerContext, ControllerState, JointGainArrays, JointLimitArrays
from hild.crossing.cyclelog import OWNER_NONE, CycleLog, CycleLogTap, CycleRow
from hild.crossing.events import EventLog
from hild.crossing.inprocess import BoundedQueue
from hild.crossing.mailboxes import InProcess, Mailboxes
from hild.crossing.requests import (
    Cleanup,
    Configure,
    Enable,
    Home,
    LifecycleRequest,
    Load,
    Refused,
    Request,
    Reset,
    SetHardwareState,
    SetParams,
    SetZero,
    Switch,
    Unload,
)
from hild.crossing.snapshot import Snapshot
from hild.crossing.stats import LoopStats
from hild.crossing.status import loop_status, render_status
from hild.cycle.contact import ContactMonitor, ContactSettings
from hild.cycle.contact_force import ToolForce
from hild.cycle.homing import HOME_MAX_SPEED, HOMING_SETTLE, RESERVED, STOP_CONFIRM, HomingRun, Homings
from hild.cycle.manager import ControllerManager, SwitchError, SwitchResult
from hild.cycle.sensor_gate import SensorGate
from hild.cycle.supervisor import Action, Fault, JointGains, SafetySettings, Supervisor, limit_names
from hild.cycle.transmission import Transmissions
from hild.cycle.walls import WallGuard, Walls
from hild.dynamics.friction import FrictionArrays
from hild.hardware import HardwareComponent, HardwareContext, HardwareError, Lifecycle
from hild.interfaces import ClaimError, ClaimMasks, SensorLayout, SensorSpec, interface_name
from hild.modes import MODE_NAMES, JointMode

if TYPE_CHECKING:
    from hild.dynamics.momentum import MomentumObserver  # only a type here: mujoco stays behind the seam

REQUEST_QUEUE = 64
HEALTH_POLL_HZ = 20.0
ENABLE_CONFIRM = 1.0  # s: an operator enable must show in the drive's replies within this
CLEAR_CONFIRM = 0.5  # s: a reset waits at most this long for the drives to confirm clear-error
SET_ZERO_MAX_SPEED = 0.05  # rad/s: set-zero only on a still joint
SET_ZERO_SETTLE = 0.5  # s: hold follows the reading while the drive moves to its new frame (some drop replies ~1 s)
MAX_STEP_PERIODS = 2.0  # a late cycle advances the control clock (and the slew limit) by at most this many periods
RESET_OVERTAKEN = "an e-stop took effect after this reset was sent: reset again to clear it"
HOLD_GAIN_RAMP = 0.5  # s over which new hold gains are ramped in
GAP_EVENT_PERIODS = 10  # a cycle later than this many periods is reported (at most once a second, with a count)


@dataclass
class Deferred:
    """A request's answer that needs more cycles (e.g. a reset waiting for the drives to confirm clear-error):
    ``poll`` runs after each cycle's read until it returns the answer."""

    poll: Callable[[], Any]


@dataclass
class HardwareSlot:
    name: str
    driver: str
    component: HardwareComponent
    index: np.ndarray
    state: JointState
    command: ServoCommand
    in_place: bool  # state and command are views of the engine's actuator arrays: no scatter or gather
    lifecycle: Lifecycle = Lifecycle.UNCONFIGURED
    fault: str = ""
    locked_out: bool = False  # set inactive by an operator: read and held, its command interfaces unavailable
    sensors: SensorValues | None = None  # its sensors' part of the engine's raw sensor values; None: it has none
    sensor_failure: str = ""  # read_sensors raised: why (reported once, until it reads again)

    def command_interfaces(self) -> list[str]:
        return [interface_name(j, f) for j in self.component.joints for f in sorted(self.component.COMMAND_FIELDS)]

    def reported_state(self) -> str:
        """ros2_control's word: an active component an operator set inactive is ``inactive`` (a fault wins)."""
        if self.locked_out and self.lifecycle is Lifecycle.ACTIVE:
            return str(Lifecycle.INACTIVE)
        return str(self.lifecycle)


class Engine:
    def __init__(
        self,
        loaded: LoadedConfig,
        mailboxes: Mailboxes | None = None,
        *,
        stats: LoopStats | None = None,
        wake_client: Callable[[], None] | None = None,
        cycle_log: CycleLog | None = None,
    ) -> None:
        """``mailboxes``: where controllers' doors to their API halves live (in this process by default; cells of
        the shared region when the API half runs in the client domain). ``stats``: where the cycle's loop
        statistics go (a shared cell when another process reads them). ``wake_client``: called, from the cycle, when
        there is something to publish (events, outputs, replies). ``cycle_log``: the ring every cycle is written
        into for the recorder (``hild.crossing.cyclelog``; ``CycleLog.private`` for a lockstep test); None: none.

        Long because it builds the robot in the order each part needs the one before (arrays and transmissions,
        hardware, supervisor, controller manager, controllers), kept in one place so that order is read at once."""
        cfg = loaded.config
        self.mailboxes = mailboxes or InProcess()
        self.loaded = loaded
        self.robot = cfg.robot.name
        self.joints: tuple[str, ...] = tuple(cfg.joints)
        self.update_rate = cfg.update_rate
        self.period = 1.0 / cfg.update_rate
        self.clock_source = cfg.clock.source
        n = len(self.joints)
        index = {j: i for i, j in enumerate(self.joints)}

        self.events = EventLog()
        self.events.now = lambda: self.t
        self.wake_client: Callable[[], None] = wake_client or (lambda: None)
        # Set by the API: takes streamed commands at the start of each cycle, so no other thread takes the GIL
        # per sample (docs/performance.md, "Where the time goes").
        self.take_inputs: Callable[[], None] | None = None
        self.inputs_on_arrival = False  # take_inputs above takes them: one GIL handover per cycle, not per sample
        self.write_done_ns = 0  # perf_counter_ns when the last cycle's hardware writes were done
        self.events.on_emit = self._ring
        self.stats = stats or LoopStats()
        self.t = 0.0  # the cycle clock as given: wall time since start, or the sim clock
        # The control clock: what controllers and the slew limit see. It advances by the cycle's dt, but by at
        # most MAX_STEP_PERIODS periods, so a stalled cycle resumes where it stopped instead of catching up in
        # one step: trajectories and streams are re-timed by the length of the stall. Equal to t in lockstep.
        self.control_t = 0.0
        self._clock_lag = 0.0
        self._gap_report = (-1.0, 0, 0.0)  # (t of the last gap event, gaps not reported since, the longest)
        self.cycle = 0
        self.wall = 0.0  # time.time() at the last cycle's read: the cycle log's wall clock
        self.started = False
        self.realtime_report: dict[str, str] = {}

        self.limits = JointLimitArrays.of(cfg)
        self._position_gains = JointGainArrays.of(cfg)
        self.mimic_joints = MimicJoints.of(cfg)
        # robot.model as a path, or None: gravity, the contact check, the walls and controllers all take it from here
        self._model_path = loaded.directory / cfg.robot.model if cfg.robot.model else None
        self.friction = FrictionArrays.of(cfg)  # joints.<j>.friction: controllers compensate it (teach)
        # The cycle-log row: the accepted reading and the final command live in it (views), so recording a cycle is
        # one contiguous copy (hild/crossing/cyclelog.py, CycleRow); controllers and drivers see plain arrays.
        self.row = CycleRow(n)
        self.state = JointState.zeros(n, over=lambda name: self.row.field(f"measured_{name}"))  # what controllers see
        self.command = ServoCommand.zeros(n)  # controllers' output
        self.final = ServoCommand.zeros(n, over=self.row.field)  # the supervisor's output, joint space
        self.transmissions = self._transmissions(cfg, index)
        if self.transmissions.identity:  # actuator space is joint space: one set of arrays, no conversion
            self._actuator_state, self._actuator_command = self.state, self.final
        else:
            self._actuator_state, self._actuator_command = JointState.zeros(n), ServoCommand.zeros(n)
        self.sensor_layout = SensorLayout.of(cfg)
        self.sensor_gate = SensorGate(
            self.sensor_layout,
            [cfg.hardware[s.hardware].sensors[s.name].frozen_cycles for s in self.sensor_layout.sensors],
            cfg.safety.stale_feedback_cycles,
            self.events.emit,
        )
        self.sensors = SensorView(self.sensor_layout, self.sensor_gate.accepted, self.sensor_gate.fresh)
        self.hardware = self._build_hardware(loaded, index)
        self._has_sensors = bool(self.sensor_layout.sensors)
        self._joint_slot = np.zeros(n, dtype=np.intp)
        for k, slot in enumerate(self.hardware):
            self._joint_slot[slot.index] = k

        self.applies_gains = self._applies_gains()  # per joint; controllers see it in their context
        self.supervisor = self._build_supervisor(loaded)
        self.contact = self._build_contact(loaded)  # None unless safety.contact.enabled
        self._contact_seq = -1  # the supervisor's change_seq when _foreign_fault was last looked at
        self._foreign_fault = False
        self.walls = self._build_walls(loaded)
        s = cfg.safety
        self.max_consecutive_overruns = s.max_consecutive_overruns
        self._max_step = MAX_STEP_PERIODS * self.period
        self.max_cycle_gap = s.max_cycle_gap
        self.stop_descent = s.stop_descent
        # what controllers may claim: only fields the drives really use
        self.available_interfaces = [i for slot in self.hardware for i in slot.command_interfaces()]
        self.manager = ControllerManager(self.joints, self.available_interfaces, self.events)
        self.manager.on_claims = self._claims_changed
        self.manager.sources = self.row.field("source")  # who moves each joint, straight into the cycle log's row
        # Owner codes (the cycle log's owner column): each load gets the next code, never given again, so a row
        # recorded before an unload still names the controller that wrote it. code = the manager's slot + 1.
        self.controller_codes: dict[int, str] = {}
        self.owner_codes = self.row.field("owner")  # per joint: its claiming controller's code (float64, exact)
        self.owner_codes.fill(OWNER_NONE)
        self._requests: BoundedQueue[tuple[Callable[[], Any], concurrent.futures.Future[Any], bool]] = BoundedQueue(
            REQUEST_QUEUE
        )
        # Load, configure, unload: one per cycle, after its write (a controller's constructor and on_configure are
        # its author's code: they must never delay a command, and a burst of them must not stall one cycle).
        self._lifecycle: BoundedQueue[tuple[LifecycleRequest, concurrent.futures.Future[Any]]] = BoundedQueue(
            REQUEST_QUEUE
        )
        self.loads: dict[str, Load] = {}  # how each loaded controller was loaded: a new client domain builds its halves
        self.loads_seq = 0
        self._estop_requested = False
        self.tap: Any = None  # telemetry: an object with record(...) called once per cycle, or None
        self.cycle_log: CycleLogTap | None = None if cycle_log is None else self.cycle_log_tap(cycle_log)
        self._rearm: dict[int, int] = {}  # joint → cycle by which its drive must confirm an operator enable
        self._estop_waiters: deque[concurrent.futures.Future[Any]] = deque(maxlen=256)
        self._deferred: list[tuple[Deferred, concurrent.futures.Future[Any], bool]] = []  # …, clears an e-stop
        self.homings = Homings(self.joints)  # drives homing on an operator's command (hild/cycle/homing.py)
        self._homing_confirm = max(1, round(STOP_CONFIRM * self.update_rate))  # cycles a drive has to confirm a stop
        self._health_every = max(1, round(self.update_rate / HEALTH_POLL_HZ))
        self.tuning = ManagerParams.of(cfg)  # the daemon's own parameters (hold gains): set_parameters changes them
        self.tuning_floor = [j.soft_margin for j in self.tuning.joints.values()]  # the config's soft margins
        for name, spec in cfg.controllers.items():
            self.load_controller(
                name, spec.type, loaded.controller_params[name], spec.fallback_controllers, spec.chain_to or ""
            )

    # ---- construction ---------------------------------------------------------------------------------------
    def _build_supervisor(self, loaded: LoadedConfig) -> Supervisor:
        """The supervisor with the config's safety settings, and gravity feed-forward when the robot has a model."""
        cfg = loaded.config
        gravity = None
        self._gravity_model: Any = None  # hild.dynamics.gravity.GravityModel when the robot has one
        if self._model_path is not None and cfg.safety.gravity_compensation:
            from hild.dynamics.gravity import GravityModel  # mujoco stays behind this seam

            self._gravity_model = GravityModel(self._model_path, self.joints)
            gravity = self._gravity_model.compute
        s = cfg.safety
        return Supervisor(
            self.joints,
            self.limits,
            self._gains(cfg),
            SafetySettings(
                s.stale_feedback_cycles,
                s.overspeed_factor,
                Action[s.fault_action.upper()],
                Action[s.estop_action.upper()],
                stale_feedback_time=s.stale_feedback_time,
                plausibility_margin=s.plausibility.margin,
                plausible_speed_factor=s.plausibility.speed_factor,
                plausible_step_tolerance=s.plausibility.step_tolerance,
                plausible_time_slack=self.period,  # a reply shows the shaft somewhere in the last period
            ),
            self.events,
            gravity=gravity,
            describe_fault=self._describe_fault,
            applies_gains=self.applies_gains,
        )

    def _build_contact(self, loaded: LoadedConfig) -> ContactMonitor | None:
        """The momentum observer and the collision reflex (``safety.contact``; docs/safety.md, "Contact")."""
        cfg = loaded.config
        c = cfg.safety.contact
        if not c.enabled:
            return None
        if self._model_path is None:
            raise ValueError("safety.contact needs robot.model: the observer runs on the arm's dynamics")
        from hild.dynamics.momentum import MomentumObserver  # mujoco stays behind this seam
        from hild.dynamics.tool import ToolPoint

        path = self._model_path
        thresholds = [c.thresholds(j) for j in self.joints]
        settings = ContactSettings(
            gain=c.observer_gain,
            use_reply=c.torque == "reply",
            contact=np.array([t.contact for t in thresholds]),
            collision=np.array([t.collision for t in thresholds]),
            model_margin=c.model_margin,
            retract=c.reflex == "retract",
            reflex_stiffness=c.reflex_stiffness,
            retract_distance=c.retract_distance,
            retract_time=c.retract_time,
            force_contact=c.force.contact if c.force else math.inf,
            force_collision=c.force.collision if c.force else math.inf,
        )
        shares_gravity = self.supervisor.gravity is not None  # one evaluation of the dynamics per cycle serves both
        tau_ext = self.row.field("tau_ext")  # the estimate is written where the cycle log reads it
        observer = MomentumObserver(
            path, self.joints, c.observer_gain, self.period, gravity=shares_gravity, residual=tau_ext
        )
        self.realtime_report["contact_observer"] = observer.implementation  # compiled, or python and why
        if shares_gravity:
            from hild.dynamics.gravity import SharedGravity

            self.supervisor.gravity = SharedGravity(self._gravity_model, observer).compute
        return ContactMonitor(
            self.joints,
            settings,
            observer,
            effort_limit=self.limits.effort,
            applies_gains=self.applies_gains,
            friction=self.friction,
            emit=self.events.emit,
            update_rate=self.update_rate,
            tool=ToolPoint(path, self.joints, site=c.tool_site).position if c.reflex == "retract" else None,
            tool_force=self._build_tool_force(loaded, observer) if c.force else None,
            tau_ext=tau_ext,
        )

    def _build_tool_force(self, loaded: LoadedConfig, observer: MomentumObserver) -> ToolForce:
        """The Cartesian contact check of ``safety.contact.force`` on the tool point (docs/safety.md, "Contact"): its
        Jacobian read off the observer's evaluation of the model at the same reading."""
        from hild.dynamics.tool import ReadingJacobian, ToolPoint  # mujoco stays behind this seam

        c = loaded.config.safety.contact
        f = c.force
        assert f is not None and self._model_path is not None
        if f.bandwidth * self.period >= 1.0:
            raise ValueError(
                f"safety.contact.force.bandwidth {f.bandwidth:g}/s × period {self.period * 1e3:g} ms ≥ 1: use a "
                f"bandwidth below {1.0 / self.period:.0f}/s"
            )
        tool = ToolPoint(self._model_path, self.joints, site=c.tool_site)
        settle = 5.0 / c.observer_gain + 5.0 / f.bandwidth  # both low-passes within 1 % of a step
        return ToolForce(
            ReadingJacobian(tool, observer),
            len(self.joints),
            damping=f.damping,
            bandwidth=f.bandwidth,
            baseline=f.baseline,
            settle=settle,
        )

    def _observe_contact(self, dt: float, dt_control: float) -> None:
        """The external torque estimate, and on a collision the reflex: every joint faults into it and every
        commanding controller is deactivated (as an e-stop does), so nothing pushes on."""
        contact, sup = self.contact, self.supervisor
        assert contact is not None
        if self._contact_seq != sup.change_seq:  # faults change rarely: look at them only when something changed
            self._contact_seq = sup.change_seq
            faults = sup.fault
            # Any fault but a collision's own: the torques are not the model's.
            self._foreign_fault = bool(((faults != Fault.NONE) & (faults != Fault.COLLISION)).any())
        trusted = sup.all_fresh and not (sup.estop or sup.descent_started or self._foreign_fault)
        joint = contact.observe(self.state, self.final, trusted, dt)
        if joint >= 0:
            words = contact.describe(joint) + contact.begin_reflex(self.state.position)
            sup.collide(words, contact.settings.reflex_stiffness)
            self.manager.deactivate_commanding("collision")
        if contact.retracting:
            contact.reflex_step(dt_control, sup.latched)

    def _build_walls(self, loaded: LoadedConfig) -> WallGuard | None:
        """The virtual walls of ``safety.walls`` on the tool point of ``robot.model`` (docs/safety.md)."""
        cfg = loaded.config
        spec = cfg.safety.walls
        if not spec.enabled:
            return None
        if self._model_path is None:
            raise ValueError("safety.walls: virtual walls need the arm's model (robot.model) for the tool point")
        from hild.dynamics.collision import SelfCollision  # mujoco stays behind this seam
        from hild.dynamics.tool import ToolPoint

        model = self._model_path
        tool = ToolPoint(model, self.joints, site=spec.site, body=spec.body, offset=spec.tool_offset)
        return WallGuard(
            tool,
            Walls.of(spec),
            margin=spec.margin,
            deceleration=spec.deceleration,
            lead_time=spec.lead_time,
            limits=self.limits,
            update_rate=self.update_rate,
            emit=self.events.emit,
            collision=SelfCollision(model, self.joints) if spec.self_collision else None,
        )

    @staticmethod
    def _gains(cfg: Any) -> JointGains:
        js = list(cfg.joints.values())
        pos = [j.position_gains or j.hold for j in js]
        return JointGains(
            hold_kp=np.array([j.hold.kp for j in js]),
            hold_kd=np.array([j.hold.kd for j in js]),
            position_kp=np.array([g.kp for g in pos]),
            position_kd=np.array([g.kd for g in pos]),
            velocity_kd=np.array([(j.velocity_gains.kd if j.velocity_gains else j.hold.kd) for j in js]),
        )

    def _applies_gains(self) -> np.ndarray:
        """Per joint: does its drive apply the command's kp/kd (so the supervisor can predict its torque)?"""
        applies = np.ones(len(self.joints), dtype=bool)
        for slot in self.hardware:
            applies[slot.index] = slot.component.gains_applied()
        return applies

    def _transmissions(self, cfg: Any, index: dict[str, int]) -> Transmissions:
        n = len(self.joints)
        reduction, direction, offset = np.ones(n), np.ones(n), np.zeros(n)
        for hw in cfg.hardware.values():
            for joint, tr in hw.joints.items():
                i = index[joint]
                reduction[i], direction[i], offset[i] = tr.reduction, tr.direction, tr.offset
        return Transmissions(reduction, direction, offset)

    def _build_hardware(self, loaded: LoadedConfig, index: dict[str, int]) -> list[HardwareSlot]:
        slots = []
        for name, hw in loaded.config.hardware.items():
            joints = tuple(hw.joints)
            sensors, sensor_values = self._sensors_of(name)
            context = HardwareContext(
                name=name,
                joints=joints,
                config_dir=loaded.directory,
                update_rate=self.update_rate,
                clock_source=self.clock_source,
                emit_event=lambda level, msg, src=name: self.events.emit(level, src, msg),
                mimic_joints=tuple(m for m in self.mimic_joints.joints if m.joint in hw.joints),
                sensors=sensors,
                sensor_params=dict(loaded.sensor_params.get(name, {})),
            )
            component = loaded.driver_classes[name](context, loaded.driver_params[name])
            joint_index = np.array([index[j] for j in joints], dtype=np.intp)
            part = contiguous_slice(joint_index)
            if part is not None:  # the usual case: the component reads into and writes from the engine's arrays
                state, command = self._actuator_state.view(part), self._actuator_command.view(part)
            else:
                state, command = JointState.zeros(len(joints)), ServoCommand.zeros(len(joints))
            slot = HardwareSlot(name, hw.driver, component, joint_index, state, command, part is not None)
            slot.sensors = sensor_values
            slots.append(slot)
        return slots

    def _sensors_of(self, hardware: str) -> tuple[tuple[SensorSpec, ...], SensorValues | None]:
        """Component ``hardware``'s sensors (offsets relative to its own part) and its part of the raw values."""
        mine = [k for k, s in enumerate(self.sensor_layout.sensors) if s.hardware == hardware]
        if not mine:
            return (), None
        specs = [self.sensor_layout.sensors[k] for k in mine]
        start = specs[0].offset
        local = tuple(dataclasses.replace(s, offset=s.offset - start) for s in specs)
        width = sum(s.width for s in specs)
        return local, self.sensor_gate.raw.view(slice(start, start + width), slice(mine[0], mine[-1] + 1))

    def controller_context(self, name: str, doors: str = "") -> ControllerContext:
        """``doors``: the prefix of its cells in the shared region (the name, for those the config lists)."""
        return ControllerContext(
            robot=self.robot,
            name=name,
            joints=self.joints,
            limits=self.limits,
            update_rate=self.update_rate,
            emit_event=lambda level, msg: self.events.emit(level, name, msg),
            notify=self._ring,
            joint_modes=self.supervisor.mode,
            gains=self._position_gains,
            sensors=self.sensors,
            mailboxes=self.mailboxes.scoped(doors or name),
            mimic_joints=self.mimic_joints,
            applies_gains=self.applies_gains,
            external_torque=self.contact.tau_ext if self.contact is not None else None,
            friction=self.friction,
            gravity_torque=self.supervisor.gravity_torque if self.supervisor.gravity is not None else None,
            model_path=self._model_path,
        )

    def cycle_log_tap(self, log: CycleLog) -> CycleLogTap:
        """A writer of ``log`` bound to this engine's row (the ring is prefaulted now, before any cycle)."""
        sup = self.supervisor
        return CycleLogTap(
            log, row=self.row, fresh=self.state.fresh, fault=sup.fault, mode=sup.mode, changes=sup, stats=self.stats
        )

    def _claims_changed(self, masks: ClaimMasks) -> None:
        """At each switch or failure (never per cycle): the supervisor's defaults and each joint's owner code."""
        self.supervisor.set_claims(masks)
        np.add(masks.owner, 1, out=self.owner_codes)  # a slot's code is slot + 1; unclaimed (-1) is OWNER_NONE

    def _coded(self, name: str) -> None:
        """Give the controller just loaded as ``name`` its code (its manager slot's; a reload keeps it)."""
        self.controller_codes[self.manager.records[name].slot + 1] = name

    def controllers(self) -> dict[str, Any]:
        """Each loaded controller by name: the instance whose inputs and action server the API exposes."""
        return {name: record.instance for name, record in list(self.manager.records.items())}

    def load_controller(
        self, name: str, type_name: str, params: Any, fallbacks: Sequence[str] = (), chain_to: str = ""
    ) -> None:
        """Load and configure a controller (before start; at runtime a :class:`Load` request does it)."""
        self._loaded(Load(name, type_name, params, tuple(fallbacks), chain_to=chain_to))
        self.manager.configure(name)

    def add_controller(
        self, name: str, type_name: str, controller: Any, fallbacks: Sequence[str] = (), chain_to: str = ""
    ) -> None:
        """Load and configure an already built controller instance (tests and tools that build their own)."""
        self.manager.load(name, type_name, controller, fallbacks, chain_to)
        self._coded(name)
        self.manager.configure(name)

    def _build(self, load: Load) -> Any:
        cls = plugins.load(plugins.CONTROLLERS, load.type)
        params = load.params if isinstance(load.params, cls.Params) else cls.Params.model_validate(load.params)
        return cls(self.controller_context(load.name, load.doors), params)

    def _loaded(self, load: Load) -> str:
        """Build ``load``'s controller and adopt it (unconfigured, or replacing the loaded one): its state."""
        try:
            controller = self._build(load)
        except Exception as exc:  # the plugin's constructor: its author's code
            raise SwitchError(f"{load.name}: building a {load.type} failed: {type(exc).__name__}: {exc}") from None
        if load.replaces:
            if load.keeps_fallbacks and load.name in self.manager.records:
                kept = self.manager.records[load.name]
                load = dataclasses.replace(load, fallbacks=kept.fallbacks, chain_to=kept.chain_to)
            state = self.manager.replace(load.name, load.type, controller, load.fallbacks, load.chain_to)
        else:
            self.manager.load(load.name, load.type, controller, load.fallbacks, load.chain_to)
            state = "unconfigured"
        self._coded(load.name)
        self.loads[load.name] = load
        self.loads_seq += 1
        return state

    def apply_lifecycle(self, request: LifecycleRequest) -> dict[str, Any]:
        """Load, configure or unload now (between cycles, after a write): the reply, or :class:`Refused`."""
        name = request.name
        try:
            match request:
                case Load():
                    state = self._loaded(request)
                    verb = "reloaded" if request.replaces else "loaded"
                    source = f" {request.source}" if request.source else ""
                    self.events.emit("info", "controller_manager", f"{verb} {name} ({request.type}){source}: {state}")
                    return {"name": name, "type": request.type, "state": state}
                case Configure():
                    self.manager.configure(name)
                    self.events.emit("info", "controller_manager", f"configured {name}: inactive")
                    return {"name": name, "state": "inactive"}
                case Cleanup():
                    self.manager.cleanup(name)
                    self.events.emit("info", "controller_manager", f"cleaned up {name}: unconfigured")
                    return {"name": name, "state": "unconfigured"}
                case SetParams():
                    return self._set_params(request)
                case Unload():
                    self.manager.unload(name)
                    del self.loads[name]
                    self.loads_seq += 1
                    self.events.emit("info", "controller_manager", f"unloaded {name}")
                    return {"name": name}
        except (SwitchError, ClaimError) as exc:
            raise Refused(str(exc)) from None
        raise Refused(f"not a lifecycle request: {request!r}")

    def _describe_fault(self, joint: int, code: int) -> str:
        slot = self.hardware[self._joint_slot[joint]]
        return f"{slot.name}: {slot.component.describe_fault(code)}"

    # ---- lifecycle --------------------------------------------------------------------------------------------
    def start(self) -> None:
        """``bring_up`` then ``go_live``: what tests and tools use; the daemon calls the two apart (see there)."""
        self.bring_up()
        self.go_live()

    def bring_up(self) -> None:
        """Configure hardware and read once so hold starts where the arm is. Drives stay disabled.

        If any component fails to come up, the ones already configured are released again and the error is raised
        with the component's name: a half-started robot is never left behind.
        """
        try:
            for slot in self.hardware:
                slot.lifecycle = Lifecycle.INACTIVE
                self._hook(slot, "configure", slot.component.on_configure)
            self._read(0.0, self.period)
            self.supervisor.start(self.state)
            np.copyto(self.final.position, self.supervisor.latched)  # the "last command" before any cycle: hold
        except HardwareError:
            self._release_hardware()
            raise

    def go_live(self) -> None:
        """Enable the drives and autostart controllers. The first cycle must follow at once: an enabled drive
        waits limp for its first command, and its watchdog (e.g. Damiao's CAN timeout) is already running."""
        try:
            for slot in self.hardware:
                self._hook(slot, "activate", slot.component.on_activate)
                slot.lifecycle = Lifecycle.ACTIVE
        except HardwareError:
            self._release_hardware()
            raise
        autostart = [n for n, s in self.loaded.config.controllers.items() if s.autostart]
        if autostart:
            result = self.manager.switch(autostart, [], True, self.state, self.final)
            if not result.ok:
                self.events.emit("error", "engine", f"autostart failed: {result.error}")
        self.started = True
        self.events.emit("info", "engine", f"{self.robot} started: {len(self.joints)} joints held where they are")

    def release(self) -> None:
        """Leave every configured component in its safe state and release it (start-up failed after bring_up)."""
        self._release_hardware()
        self.events.emit("info", "engine", "stopped: hardware released")

    @staticmethod
    def _hook(slot: HardwareSlot, what: str, hook: Callable[[], None]) -> None:
        try:
            hook()
        except Exception as exc:
            raise HardwareError(f"hardware {slot.name!r} ({slot.driver}): {what} failed: {exc}") from exc

    def begin_stop(self) -> bool:
        """Start stopping: every controller is deactivated; with ``safety.stop_descent`` the damped descent begins.
        Returns True when cycles must go on until ``stopping_done`` (the cycle thread keeps its pace meanwhile)."""
        if not self.started:
            return False
        self.manager.deactivate_all("shutdown")
        self._stop_homing("the daemon is stopping")
        if self.stop_descent > 0.0:
            self.supervisor.begin_descent(self.stop_descent)
            return True
        return False

    @property
    def stopping_done(self) -> bool:
        return not self.supervisor.descending

    def stop(self) -> None:
        """Hold every joint (or, after a stop descent, keep damping), then leave the hardware in its safe state and
        release it.

        Runs on the cycle thread after its last cycle, also after a crash: the hardware is released even when
        the final cycle itself fails. After a descent the final cycle damps with no feed-forward: a hold spring
        would pull the lowered arm back up for one cycle before release.
        """
        if not self.started:
            return
        descended = self.supervisor.descent_started
        self.started = False
        self.manager.deactivate_all("shutdown")
        if not descended:
            try:
                self.step(self.t + self.period, self.period)  # one last cycle: every joint in hold
            except Exception as exc:
                self.events.emit("error", "engine", f"final hold cycle failed: {type(exc).__name__}: {exc}")
        self._stop_homing("the daemon is stopping")
        for run in self.homings.abandon(self.state.position):  # its drive never reported the end: released anyway
            self._homing_ended(run)
        self._release_hardware()
        self.events.emit("info", "engine", "stopped: hardware released")

    def _release_hardware(self) -> None:
        for slot in self.hardware:
            if slot.lifecycle is Lifecycle.UNCONFIGURED:
                continue
            for hook in (slot.component.on_deactivate, slot.component.on_cleanup):
                try:
                    hook()
                except Exception as exc:
                    self.events.emit("error", slot.name, f"{hook.__name__} failed: {exc}")
            slot.lifecycle = Lifecycle.UNCONFIGURED

    # ---- the cycle ----------------------------------------------------------------------------------------------
    def step(self, t: float, dt: float) -> None:
        """One cycle. ``dt`` is the time since the last one as it really passed: drivers and the plausibility
        check use it (the arm moved for that long); controllers and the slew limit get it clamped."""
        self.t = t
        dt_control = dt
        if dt > self._max_step:
            dt_control = self._max_step
            self._clock_lag += dt - dt_control
            self._late_cycle(dt)
        self.control_t = t - self._clock_lag
        self.cycle += 1
        estop_now = self._estop_requested
        answer = self._apply_estop() if estop_now else None
        self._apply_requests(estop_now)
        if answer is not None:  # only now: a reset sent once the e-stop is answered is taken in a later cycle
            self._answer_estop(*answer)
        if self.take_inputs is not None:
            self._take_inputs()
        self.wall = time.time()
        self._read(t, dt)
        sup = self.supervisor
        sup.check(self.state, dt)
        if self._rearm:
            self._confirm_enabled()
        if self.homings.runs:
            self._poll_homing()
        if self._deferred:
            self._poll_deferred()
        if self.cycle % self._health_every == 0:
            self._poll_health()
        if self.max_consecutive_overruns and self.stats.consecutive_overruns >= self.max_consecutive_overruns:
            sup.trip_all(Fault.OVERRUN, f"{self.stats.consecutive_overruns} consecutive overruns")
        if self.contact is not None:
            self._observe_contact(dt, dt_control)
        self.manager.update(self.control_t, dt_control, self.state, self.command)
        if self.walls is not None:  # the tool's commanded point kept inside the virtual walls, before the supervisor
            self.walls.apply(dt_control, self.state, self.command, self.final, self.manager.masks, sup.mode)
        sup.command(dt_control, self.state, self.command, self.final)
        if sup.bad_command_owners:
            self.manager.fail_slots(
                sup.bad_command_owners, "non-finite or negative-gain command", self.state, self.command
            )
        self._write(t, dt)
        self.write_done_ns = time.perf_counter_ns()  # the cycle's duration ends here: what could delay a command
        if self.contact is not None:  # what its next check needs and no command waits for
            self.contact.after_write(self.state.position)
        if self.tap is not None:  # after the write, so recording never delays a command; rerun runs elsewhere
            self.tap.record(t, self.cycle, self.state, self.final, sup.mode, dt)
        if self.cycle_log is not None:  # every cycle, for the recorder and the flight recorder (no allocation)
            self.cycle_log.record(self.cycle, t, self.wall, dt)
        if (lifecycle := self._lifecycle.poll()) is not None:
            self._apply_lifecycle(*lifecycle)

    def _set_params(self, request: SetParams) -> dict[str, Any]:
        """Hand a controller its new parameters; one whose ``on_params`` raises gets its old ones back."""
        if request.name == MANAGER:
            return self._tune(request)
        record = self.manager.records.get(request.name)
        if record is None:
            raise Refused(f"unknown controller {request.name!r}")
        old = record.instance.params
        try:
            record.instance.set_params(request.params)
        except Exception as exc:  # the plugin's code: it must not take the cycle down, nor keep half of a change
            reason = f"{request.name}: on_params raised {type(exc).__name__}: {exc}"
            try:
                record.instance.set_params(old)
            except Exception:  # not even its old parameters take: it cannot be trusted to command anything
                record.instance.params = old
                if record.state is ControllerState.ACTIVE:
                    self.manager.fail(record, f"{reason}, and again with its old parameters", self.state, self.command)
                raise Refused(f"{reason}, and again with its old parameters; it is stopped") from None
            raise Refused(f"{reason}; nothing changed") from None
        self.loads[request.name] = dataclasses.replace(self.loads[request.name], params=request.params)
        self.loads_seq += 1
        self.events.emit("info", request.name, f"parameters set by {request.by}: {'; '.join(request.changes)}")
        return {"name": request.name, "changed": list(request.changes)}

    def _tune(self, request: SetParams) -> dict[str, Any]:
        """The daemon's own parameters: hold gains, ramped in by the supervisor over ``HOLD_GAIN_RAMP``; soft margins
        (never below the config's) and the velocity scale, refused if they would leave a joint outside its range."""
        tuning: ManagerParams = request.params
        if list(tuning.joints) != list(self.joints) or tuning.update_rate != self.update_rate:
            raise Refused("the joints and the update rate are the config's")
        joints = [tuning.joints[j] for j in self.joints]
        margins = [j.soft_margin for j in joints]
        narrower = [n for n, m, c in zip(self.joints, margins, self.tuning_floor, strict=True) if m < c]
        if narrower:  # the margin keeps commands off the hard stops: a client may widen it, never shrink it
            raise Refused(f"soft_margin of {narrower} below the config's: only a wider margin can be set")
        refusal = self.supervisor.set_command_limits(
            (self.limits.lower + margins).tolist(), (self.limits.upper - margins).tolist(), tuning.velocity_scale
        )
        if refusal:
            raise Refused(refusal)
        ramp = max(1, round(HOLD_GAIN_RAMP * self.update_rate))
        self.supervisor.set_hold_gains([j.hold.kp for j in joints], [j.hold.kd for j in joints], ramp)
        self.tuning = tuning
        self.supervisor.change_seq += 1  # a new snapshot carries them
        self.events.emit("info", MANAGER, f"parameters set by {request.by}: {'; '.join(request.changes)}")
        return {"name": MANAGER, "changed": list(request.changes)}

    def _apply_lifecycle(self, request: LifecycleRequest, future: concurrent.futures.Future[Any]) -> None:
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(self.apply_lifecycle(request))
        except Exception as exc:
            future.set_exception(exc)

    def _late_cycle(self, dt: float) -> None:
        """A cycle came ``dt`` after the last: past ``safety.max_cycle_gap`` every joint faults (the arm may have
        been on its drives' own watchdogs); a shorter gap is reported, at most once a second."""
        ms = dt * 1000.0
        if self.max_cycle_gap and dt > self.max_cycle_gap:
            limit = self.max_cycle_gap * 1000.0
            self.supervisor.trip_all(Fault.OVERRUN, f"the cycle stalled for {ms:.0f} ms (max_cycle_gap {limit:g} ms)")
            return
        if dt < GAP_EVENT_PERIODS * self.period:
            return
        last, missed, longest = self._gap_report
        if last >= 0.0 and self.t - last < 1.0:
            self._gap_report = (last, missed + 1, max(longest, dt))
            return
        more = f"; {missed} more since the last report, the longest {longest * 1000:.0f} ms" if missed else ""
        self.events.emit(
            "warning",
            "engine",
            f"cycle gap of {ms:.0f} ms ({dt / self.period:.0f} periods): controllers resume where they were, "
            f"re-timed by the gap{more}",
        )
        self._gap_report = (self.t, 0, 0.0)

    def run_cycles(self, count: int) -> None:
        """Lockstep helper: advance ``count`` cycles of the sim clock (tests, tools)."""
        for _ in range(count):
            self.step(round(self.t + self.period, 12), self.period)

    def _read(self, t: float, dt: float) -> None:
        act = self._actuator_state
        for slot in self.hardware:
            try:
                slot.component.read(t, dt, slot.state)
            except Exception as exc:
                slot.state.fresh.fill(False)
                self._hardware_fault(slot, f"read failed: {type(exc).__name__}: {exc}")
            if slot.sensors is not None:
                self._read_sensors(slot, t, dt)
            if not slot.in_place:
                scatter_state(slot.state, slot.index, act)
        if act is not self.state:
            self.transmissions.to_joint(act, self.state)
        if self._has_sensors:
            self.sensor_gate.filter()

    def _read_sensors(self, slot: HardwareSlot, t: float, dt: float) -> None:
        """The component's sensors, right after its joints; a failure leaves them not fresh (the sensor gate's
        stale rule faults them) and is reported once, never a joint's fault."""
        values = slot.sensors
        assert values is not None
        try:
            slot.component.read_sensors(t, dt, values)
        except Exception as exc:
            values.fresh.fill(False)
            if not slot.sensor_failure:
                slot.sensor_failure = f"{type(exc).__name__}: {exc}"
                self.events.emit("error", slot.name, f"reading its sensors failed: {slot.sensor_failure}")
            return
        if slot.sensor_failure:
            slot.sensor_failure = ""
            self.events.emit("info", slot.name, "reading its sensors works again")

    def _write(self, t: float, dt: float) -> None:
        if self._actuator_command is not self.final:
            self.transmissions.to_actuator(self.final, self._actuator_command)
        for slot in self.hardware:
            if not slot.in_place:
                gather_command(self._actuator_command, slot.index, slot.command)
            try:
                slot.component.write(t, dt, slot.command)
            except Exception as exc:
                self._hardware_fault(slot, f"write failed: {type(exc).__name__}: {exc}")

    def _poll_health(self) -> None:
        for slot in self.hardware:
            problem = slot.component.health()
            if problem:
                self._hardware_fault(slot, problem)

    def _hardware_fault(self, slot: HardwareSlot, text: str) -> None:
        if slot.lifecycle is not Lifecycle.FAULT:
            slot.lifecycle = Lifecycle.FAULT
            slot.fault = text
            self.events.emit("error", slot.name, text)
        for i in slot.index:
            self.supervisor.trip(int(i), Fault.HARDWARE, f"{slot.name}: {text}")

    # ---- requests (asyncio side → cycle) ---------------------------------------------------------------------
    def submit(self, action: Callable[[], Any], *, clears_estop: bool = False) -> concurrent.futures.Future[Any]:
        """Run ``action`` on the cycle thread at the start of the next cycle; refused when the queue is full.
        ``clears_estop``: the action may clear an e-stop (a reset), so it is refused if an e-stop is applied in the
        cycle that would run it: it was sent before that e-stop took effect."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        if not self._requests.offer((action, future, clears_estop)):
            future.set_exception(Refused("too many pending requests; try again"))
        return future

    def request(self, request: Request) -> concurrent.futures.Future[Any]:
        """An operator request (:mod:`hild.crossing.requests`), applied at the start of the next cycle (a lifecycle
        request: after its write). Its future holds the reply dict, or raises
        :class:`~hild.crossing.requests.Refused`; an e-stop takes its own path and is never refused."""
        if isinstance(request, LifecycleRequest):
            future: concurrent.futures.Future[Any] = concurrent.futures.Future()
            if not self._lifecycle.offer((request, future)):
                future.set_exception(Refused("too many pending requests; try again"))
            return future
        if isinstance(request, Switch | Reset | Enable | SetZero | Home | SetHardwareState):
            return self.submit(lambda: self.apply(request), clears_estop=isinstance(request, Reset))
        return self.request_estop()

    def apply(self, request: Request) -> dict[str, Any] | Deferred:
        """Apply one request now (on the cycle thread, between cycles): the reply, or :class:`Refused`."""
        if isinstance(request, LifecycleRequest):
            return self.apply_lifecycle(request)
        match request:
            case Switch(activate, deactivate, strict):
                return self.switch(activate, deactivate, strict).as_dict()  # carries its own ok and error
            case Reset():
                outcome = self.reset()
                if isinstance(outcome, Deferred):
                    return Deferred(lambda: _refused_if_error(outcome.poll()))
                return _refused_if_error(outcome)  # type: ignore[return-value]
            case Enable(joints):
                return _refused_if_error(self.enable(joints))  # type: ignore[return-value]
            case SetZero(joint):
                return _refused_if_error(self.set_zero(joint))  # type: ignore[return-value]
            case Home(joint):
                return _refused_if_error(self.home(joint))  # type: ignore[return-value]
            case SetHardwareState(name, state):
                return _refused_if_error(self.set_hardware_state(name, state))  # type: ignore[return-value]
        return self.estop()

    def _apply_requests(self, estop_now: bool) -> None:
        """Apply every queued request. In a cycle that applied an e-stop, a queued reset is refused, never applied
        after it: an operator's reset sent before the e-stop took effect must not clear it."""
        while (item := self._requests.poll()) is not None:
            action, future, clears_estop = item
            if not future.set_running_or_notify_cancel():
                continue
            if estop_now and clears_estop:
                future.set_exception(Refused(RESET_OVERTAKEN))
                continue
            try:
                result = action()
            except Exception as exc:
                future.set_exception(exc)
                continue
            if isinstance(result, Deferred):
                self._deferred.append((result, future, clears_estop))
            else:
                future.set_result(result)

    def _poll_deferred(self) -> None:
        """Answer the requests that waited for more cycles (after this cycle's read and checks)."""
        for item in list(self._deferred):
            deferred, future, _ = item
            try:
                result = deferred.poll()
            except Exception as exc:
                self._deferred.remove(item)
                future.set_exception(exc)
                continue
            if result is not None:
                self._deferred.remove(item)
                future.set_result(result)

    def _take_inputs(self) -> None:
        """Streamed commands, taken by the cycle itself (``hild.api.ports.ControllerPorts.take_inputs``)."""
        try:
            self.take_inputs()  # type: ignore[misc]
        except Exception as exc:  # a bug there must not end the cycle; without inputs, controllers time out
            self.take_inputs = None
            self.events.emit("error", "api", f"taking the inputs failed, and is off: {type(exc).__name__}: {exc}")

    def client_domain_lost(self, reason: str) -> None:
        """The client domain ended while the cycle runs (cycle thread): what controllers run for its clients ends
        with ``reason``; streams time out on the cycle clock; the arm holds until a new client domain commands."""
        self.events.emit("error", "cycle", f"{reason}: its goals are aborted and the joints hold until it is back")
        for name, record in list(self.manager.records.items()):
            try:
                record.instance.on_client_domain_lost(self.control_t, reason)
            except Exception as exc:  # a controller's bug must not end the cycle
                self.events.emit("error", name, f"on_client_domain_lost failed: {type(exc).__name__}: {exc}")

    def request_estop(self) -> concurrent.futures.Future[Any]:
        """E-stop from any thread. Never refused (it bypasses the request queue); applied at the next cycle."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._estop_waiters.append(future)
        self._estop_requested = True
        return future

    def _apply_estop(self) -> tuple[dict[str, Any], int]:
        """Engage the e-stop; its reply and how many of the waiting requesters it answers (`_answer_estop`, once
        this cycle's queued requests were taken: a reset sent after the answer is never taken for one sent before)."""
        self._estop_requested = False
        result = self.estop()
        for item in [item for item in self._deferred if item[2]]:  # a reset waiting for its drives: not any more
            self._deferred.remove(item)
            item[1].set_exception(Refused(RESET_OVERTAKEN))
        return result, len(self._estop_waiters)

    def _answer_estop(self, result: dict[str, Any], count: int) -> None:
        for _ in range(min(count, len(self._estop_waiters))):
            future = self._estop_waiters.popleft()
            if future.set_running_or_notify_cancel():
                future.set_result(result)

    def switch(self, activate: Sequence[str], deactivate: Sequence[str], strict: bool = True) -> SwitchResult:
        """Switch controllers now (call on the cycle thread, i.e. through ``submit``, or before start)."""
        refuse = "e-stop is engaged; reset first" if self.supervisor.estop else ""
        return self.manager.switch(activate, deactivate, strict, self.state, self.final, refuse)

    def set_hardware_state(self, name: str, state: str) -> dict[str, Any]:
        """Operator request (between cycles), ros2_control's ``set_hardware_component_state`` for ``active`` and
        ``inactive``. Inactive, a component is still read and written every cycle — the supervisor holds its joints
        where they are, so its drives stay enabled and nothing falls — but no controller may command it: those
        that do are deactivated. A faulted component is recovered with reset and enable, never here."""
        slot = next((s for s in self.hardware if s.name == name), None)
        if slot is None:
            return {"error": f"no hardware component {name!r} (components: {[s.name for s in self.hardware]})"}
        if state not in ("active", "inactive"):
            return {"error": f"{name} {state}: hardware can be set active or inactive while the daemon runs"}
        if slot.lifecycle is not Lifecycle.ACTIVE:
            fault = f" ({slot.fault})" if slot.fault else ""
            return {
                "error": f"{name} is {slot.lifecycle}{fault}: recover it as an operator does, with reset (it also "
                "releases the e-stop) then enable for its joints (hild ctl reset; hild ctl enable)"
            }
        deactivated: list[str] = []
        if (state == "inactive") != slot.locked_out:
            slot.locked_out = state == "inactive"
            if slot.locked_out:
                deactivated = self.manager.make_unavailable(slot.command_interfaces(), name)
            else:
                self.manager.make_available(slot.command_interfaces())
            held = f"; deactivated {deactivated}, its joints held" if deactivated else ""
            self.events.emit("info", "controller_manager", f"hardware {name} set {state}{held}")
        return {"name": name, "state": state, "deactivated": deactivated}

    def estop(self) -> dict[str, Any]:
        self.supervisor.engage_estop()
        stopped = self.manager.deactivate_commanding("e-stop")
        return {"deactivated": stopped}

    def reset(self) -> dict[str, Any] | Deferred:
        """Operator reset (between cycles): clear drive errors, then e-stop and latched faults.

        Drives that repeat clear-error until their replies confirm it make the answer wait (``Deferred``, at most
        ``CLEAR_CONFIRM`` s): a drive whose error is still there after every try is named and nothing is cleared.
        """
        refusal = self.supervisor.refusal()
        if refusal:
            return {"cleared": [], "error": refusal}
        cleared = []
        for slot in self.hardware:
            if slot.lifecycle is Lifecycle.FAULT or self.supervisor.fault[slot.index].any():
                slot.component.clear_faults()  # drive errors too; it never re-enables a drive (that is enable)
                cleared.append(slot)
        if any(slot.component.confirming() for slot in cleared):
            deadline = self.cycle + max(1, round(CLEAR_CONFIRM * self.update_rate))

            def finish() -> dict[str, Any] | None:
                if self.cycle < deadline and any(slot.component.confirming() for slot in cleared):
                    return None
                return self._finish_reset(cleared)

            return Deferred(finish)
        return self._finish_reset(cleared)

    def _finish_reset(self, cleared: list[HardwareSlot]) -> dict[str, Any]:
        for slot in cleared:
            stuck = slot.component.persistent_errors()
            if stuck:
                for joint, words in stuck.items():
                    self.supervisor.rename_fault(self.joints.index(joint), f"{slot.name}: {words}")
                named = "; ".join(f"{joint}: {words}" for joint, words in stuck.items())
                return {"cleared": [], "error": f"{slot.name}: {named}"}
            problem = slot.component.health()
            if problem:
                return {"cleared": [], "error": f"{slot.name} still faulted: {problem}"}
            slot.lifecycle, slot.fault = Lifecycle.ACTIVE, ""
        self.stats.consecutive_overruns = 0
        if self.contact is not None:
            self.contact.clear()
        return {"cleared": self.supervisor.reset() + self.sensor_gate.reset()}

    def enable(self, joints: Sequence[str] = ()) -> dict[str, Any]:
        """Operator command (between cycles): enable drives a fault disabled; all when ``joints`` is empty.

        A joint leaves its drive fault once its drive reads back enabled and fault-free (within
        ``ENABLE_CONFIRM`` s), holding where it is then. Never done automatically."""
        if self.supervisor.estop:
            return {"error": "the e-stop is engaged: reset first"}
        unknown = [j for j in joints if j not in self.joints]
        if unknown:
            return {"error": f"unknown joints {unknown} (joints: {', '.join(self.joints)})"}
        wanted = list(joints) or list(self.joints)
        enabled: list[str] = []
        for slot in self.hardware:
            mine = [j for j in wanted if j in slot.component.joints]
            if not mine:
                continue
            try:
                if len(mine) == len(slot.component.joints):
                    enabled += slot.component.enable(None)
                else:
                    for joint in mine:
                        enabled += slot.component.enable(joint)
            except HardwareError as exc:
                return {"error": f"{slot.name}: {exc}", "enabled": enabled}
        cycles = max(1, round(ENABLE_CONFIRM * self.update_rate))
        for joint in enabled:
            i = self.joints.index(joint)
            self._rearm[i] = self.cycle + cycles
            # The drive was off and the arm may have moved (coasted, pushed): until the drive confirms, hold
            # follows the reading, so its first commands are where the shaft is, never where it was.
            self.supervisor.follow_measured(i, cycles)
        return {"enabled": enabled}

    def _confirm_enabled(self) -> None:
        state, sup = self.state, self.supervisor
        for i, deadline in list(self._rearm.items()):
            if state.fresh.item(i) and not state.fault.item(i):
                del self._rearm[i]
                sup.follow_measured(i, 1)  # latch this reading and hold it
                if sup.rearm(i):
                    self.events.emit("info", "engine", f"{self.joints[i]}: drive enabled, holding where it is")
            elif self.cycle >= deadline:
                del self._rearm[i]
                self.events.emit("error", "engine", f"{self.joints[i]}: the drive did not confirm enable")

    def set_zero(self, joint: str) -> dict[str, Any]:
        """Operator command (between cycles): make the drive's current position the joint's zero.

        Only for a held, still joint: a controller or a fault would otherwise act on a position whose origin just
        moved. Hold then follows the measured position for ``SET_ZERO_SETTLE`` s and latches the new reading."""
        if joint not in self.joints:
            return {"error": f"unknown joint {joint!r} (joints: {', '.join(self.joints)})"}
        i = self.joints.index(joint)
        if i in self.homings.runs:
            return {"error": f"joint {joint} {RESERVED}"}
        if self.supervisor.mode[i] != JointMode.HOLD:
            mode = JointMode(self.supervisor.mode[i]).name.lower()
            return {"error": f"joint {joint} is in {mode}: set-zero needs it held (no controller, no fault)"}
        speed = abs(float(self.state.velocity[i]))
        if not speed < SET_ZERO_MAX_SPEED:
            return {"error": f"joint {joint} moves at {speed:.3g} rad/s: set-zero needs it still"}
        slot = self.hardware[self._joint_slot[i]]
        try:
            slot.component.set_zero(joint)
        except HardwareError as exc:
            return {"error": f"{slot.name}: {exc}"}
        self.supervisor.follow_measured(i, max(1, round(SET_ZERO_SETTLE * self.update_rate)), new_frame=True)
        self.events.emit("warning", "engine", f"set-zero: {joint}'s current position is now its drive zero")
        return {"joint": joint}

    def home(self, joint: str) -> dict[str, Any]:
        """Operator command (between cycles): start the drive's own homing of ``joint`` (hild/cycle/homing.py).

        Only for a held, still joint that nothing else commands; the reply says it started, with the attempt number
        the status's ``homing`` entry of the joint carries until it ends (events say the end too)."""
        if joint not in self.joints:
            return {"error": f"unknown joint {joint!r} (joints: {', '.join(self.joints)})"}
        i = self.joints.index(joint)
        refusal = self._home_refusal(i)
        if refusal:
            return {"error": f"joint {joint} {refusal}"}
        slot = self.hardware[self._joint_slot[i]]
        try:
            run = self.homings.begin(i, slot.name, slot.component)
        except HardwareError as exc:
            return {"error": f"{slot.name}: {exc}"}
        self.manager.reserved[i] = RESERVED
        self.supervisor.follow_measured(i, 1, new_frame=True)  # from this cycle: the drive moves it by itself
        self.events.emit(
            "warning", "engine", f"homing {joint}: started (attempt {run.attempt}); its drive moves it, e-stop stops it"
        )
        return {"joint": joint, "attempt": run.attempt, "state": "running"}

    def _home_refusal(self, i: int) -> str:
        """Why joint ``i`` cannot start homing now, naming what commands it; empty when it can."""
        sup = self.supervisor
        if (run := self.homings.runs.get(i)) is not None:
            return f"is already being homed (attempt {run.attempt})"
        if not self.started or sup.descent_started:
            return "cannot be homed: the daemon is stopping"
        if sup.estop:
            return "cannot be homed while the e-stop is engaged: reset first"
        if sup.fault.item(i):
            return f"is in fault ({sup.fault_text[i]}): reset (and enable) first"
        owner = int(self.manager.masks.owner[i])
        if owner >= 0:
            name = next((c.name for c in self.manager.snapshot if c.slot == owner), f"slot {owner}")
            return f"is commanded by controller {name}: deactivate it first (homing needs the joint held)"
        if sup.mode[i] != JointMode.HOLD:
            return f"is in {JointMode(sup.mode[i]).name.lower()}: homing needs it held (no controller, no fault)"
        if i in self._rearm:
            return "waits for its drive to confirm enable: home once it holds"
        slot = self.hardware[self._joint_slot[i]]
        if slot.lifecycle is not Lifecycle.ACTIVE:
            return f"cannot be homed: its hardware {slot.name} is {slot.lifecycle}"
        speed = abs(float(self.state.velocity[i]))
        if not speed < HOME_MAX_SPEED:
            return f"moves at {speed:.3g} rad/s: homing needs it still"
        return ""

    def _poll_homing(self) -> None:
        """Each cycle while a drive homes: hold follows its joint's reading (in a frame the drive may move), and a
        homing that must stop (e-stop, a fault) is stopped; one that ended is latched where it stopped."""
        confirm = self._homing_confirm
        for run in self.homings.poll(self.cycle, self.state.position, self._homing_must_stop, confirm):
            self._homing_ended(run)
        for i in self.homings.runs:
            self.supervisor.follow_measured(i, 1, new_frame=True)

    def _homing_must_stop(self, run: HomingRun) -> str:
        sup = self.supervisor
        if sup.estop:
            return "e-stop"
        if sup.fault.item(run.joint):
            return f"fault: {sup.fault_text[run.joint]}"
        if not self.started:
            return "the daemon is stopping"
        return ""

    def _stop_homing(self, cause: str) -> None:
        for run in list(self.homings.runs.values()):
            if not run.stopping:
                self.homings.stop(run, cause, self.cycle, self._homing_confirm)

    def _homing_ended(self, run: HomingRun) -> None:
        """Controllers may claim the joint again; hold follows the reading a little longer (a drive's new origin
        may show a few replies late), then latches where the joint stopped."""
        i = run.joint
        self.manager.reserved.pop(i, None)
        self.supervisor.follow_measured(i, max(1, round(HOMING_SETTLE * self.update_rate)), new_frame=True)
        entry = self.homings.entries[i]
        if entry["state"] == "attained":
            where = f"{entry['position']:.4g} rad"
            self.events.emit("info", "engine", f"homing {run.name}: attained; it reads {where} at home now")
        else:
            self.events.emit("error", "engine", f"homing {run.name} failed: {entry['detail']}")

    def _ring(self) -> None:
        self.wake_client()

    # ---- reading back (any thread) ----------------------------------------------------------------------------
    @property
    def change_seq(self) -> int:
        walls = self.walls.change_seq if self.walls is not None else 0
        sup, manager, homings = self.supervisor, self.manager, self.homings
        return sup.change_seq + manager.change_seq + self.sensor_gate.change_seq + walls + homings.change_seq

    def overall_mode(self) -> str:
        sup = self.supervisor
        if sup.estop:
            return "estop"
        if sup.fault.any():
            return "fault"
        if any(c.state == "active" and c.claimed for c in self.manager.snapshot):
            return "active"
        return "hold"

    def snapshot(self) -> Snapshot:
        """What changes only when ``change_seq`` does (modes, faults, controllers, hardware states), as one
        immutable value: built from immutable views, so it is safe from any thread, and it pickles to cross."""
        sup = self.supervisor
        controllers = self.manager.snapshot
        owner = self.manager.masks.owner
        names = {c.slot: c.name for c in controllers}
        types = {c.slot: c.type for c in controllers}
        owner_of = {c: info.name for info in controllers if info.state == "active" for c in info.claimed}
        return Snapshot(
            change_seq=self.change_seq,
            mode=self.overall_mode(),
            joints=tuple(
                {
                    "name": name,
                    "mode": MODE_NAMES[int(sup.mode[i])],
                    "owner": names.get(int(owner[i])) if int(owner[i]) >= 0 else None,
                    "fault": sup.fault_text[i] or None,
                    "limits": limit_names(int(sup.limit_flags[i])),
                    "hold_effort": float(sup.hold_effort[i]),
                    # hand-guided now: commanded by a teach controller (a joint it released is held)
                    "teach": int(sup.mode[i]) == JointMode.CONTROLLED and types.get(int(owner[i])) == "teach",
                }
                for i, name in enumerate(self.joints)
            ),
            controllers=tuple(c.as_dict() for c in controllers),
            hardware=tuple(
                {
                    "name": s.name,
                    "driver": s.driver,
                    "state": s.reported_state(),
                    "fault": s.fault or None,
                    "joints": list(s.component.joints),
                    "command_fields": sorted(s.component.COMMAND_FIELDS),
                }
                for s in self.hardware
            ),
            interfaces=tuple(
                {"name": n, "claimed_by": owner_of.get(n), "available": n not in self.manager.unavailable}
                for n in self.available_interfaces
            ),
            realtime=dict(self.realtime_report),
            tuning=self.tuning,
            sensors=tuple(
                {**entry, "fault": self.sensor_gate.fault_text[k] or None, "available": self._sensor_available(k)}
                for k, entry in enumerate(self.sensor_layout.describe())
            ),
            walls=self.walls.status() if self.walls is not None else None,
            controller_codes=dict(self.controller_codes),
            homing=self.homings.status(),
        )

    def _sensor_available(self, k: int) -> bool:
        """ros2_control's word for a state interface: its component is active or inactive (still read)."""
        slot = next(s for s in self.hardware if s.name == self.sensor_layout.sensors[k].hardware)
        return slot.lifecycle in (Lifecycle.ACTIVE, Lifecycle.INACTIVE)

    def status(self) -> dict[str, Any]:
        """The status reply, rendered as the client domain renders it for a cycle in another process."""
        loop = loop_status(self.update_rate, self.clock_source, self.stats)
        return render_status(self.robot, self.snapshot(), self.t, self.supervisor.longest_silence, loop)

    def interfaces(self) -> list[dict[str, Any]]:
        return list(self.snapshot().interfaces)

    def joint_mode(self, name: str) -> JointMode:
        return JointMode(int(self.supervisor.mode[self.joints.index(name)]))


def _refused_if_error(reply: dict[str, Any] | None) -> dict[str, Any] | None:
    """The operator commands answer ``{"error": …}`` when they did nothing: that is a :class:`Refused`."""
    if reply is not None and reply.get("error"):
        details = {k: v for k, v in reply.items() if k != "error"}
        raise Refused(reply["error"], **details)
    return reply
