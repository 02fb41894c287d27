"""The fault-injection scenarios behind docs/safety.md's table (issue 7, item 1).

Each scenario injects one fault, measures how many cycles pass until hild reacts, watches what the joints do,
records the event that reports it, recovers the way an operator would (``reset``, ``enable``, a drive power
cycle where the firmware needs one) and checks that the arm then holds where it is and follows a new goal. Every
cycle runs under the jump guard (tests/faults/rigs.py); on MIT drives the firmware also checks, on its side of the
bus, that no command it executed stepped further than ``velocity_limit · dt`` (``command_step``), which covers the
first command after a drive is enabled again.

A scenario asserts what must hold and returns its table row, built only from what it observed: the suite
(tests/faults/test_faults.py) runs them, ``tools/fault_table.py`` writes the table, and a test checks the committed
table is the generated one. Lockstep rigs make every number deterministic. The daemon-restart scenario runs real
processes on the wall clock, so its row states checked bounds, never measured times.
"""

from __future__ import annotations

import math
import os
import re
import signal
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.can.emulator.mit_firmware import MitFirmware
from drivers.can.protocol.flavours import DAMIAO, TMOTOR
from drivers.can.protocol.models import MODELS
from drivers.can.protocol.odrive import ODriveError
from hild.api.client import HildError
from hild.api.goals import GoalEndpoint
from hild.arrays import JointState, ServoCommand
from hild.bench.daemon import CanProcesses
from hild.config import load_config
from hild.controllers.joint_trajectory import JointTrajectoryController
from hild.controllers.servo import Phase
from hild.cycle.process import PARENT_CHECK
from tests.faults.rigs import JTC, ApiRig, CanRig, Lockstep, MockRig, TwinRig
from tests.helpers import running

MOVE = 0.6  # rad: CAN scenarios inject mid-way through a move_to of this size on every joint…
TWIN_MOVE = 0.3  # rad: …twin ones through this one (arm6's twin gains settle a 0.6 rad move of every joint too late)
INTO_MOVE = 0.2  # s: …this long after it started (every joint near full speed)
OBSERVE = 1.0  # s watched after detection
OPERATOR_PAUSE = 0.5  # s between reset and enable, as an operator takes at least
EVENT_CHARS = 110


@dataclass(frozen=True)
class Row:
    fault: str
    injected: str
    detected: str
    joints: str
    event: str
    recovery: str


@dataclass(frozen=True)
class Scenario:
    key: str
    fault: str
    injected: str
    run: Callable[[], tuple[str, str, str, str]]  # → detected, joints, event, recovery

    def row(self) -> Row:
        return Row(self.fault, self.injected, *self.run())


SCENARIOS: list[Scenario] = []


def scenario(key: str, fault: str, injected: str) -> Callable[[Callable[[], tuple[str, str, str, str]]], None]:
    def register(run: Callable[[], tuple[str, str, str, str]]) -> None:
        SCENARIOS.append(Scenario(key, fault, injected, run))

    return register


# ---- observing ------------------------------------------------------------------------------------------------------
def clean(text: str) -> str:
    """Event text for the table: goal and client ids (random) replaced, clipped, safe in a Markdown cell."""
    text = re.sub(r"\b[0-9a-f]{32}\b", "‹id›", text)
    if len(text) > EVENT_CHARS:
        text = text[: EVENT_CHARS - 1] + "…"
    return text.replace("|", "\\|")


def first_event(rig: Lockstep, since: int, words: str = "") -> str:
    """The first error event since cycle ``since`` (containing ``words``), else the first warning."""
    for level in ("error", "warning"):
        for _, event in rig.events_since(since, (level,)):
            if words in event.message:
                return clean(f"{level} `{event.source}`: {event.message}")
    return "none"


def drive_note(rig: Lockstep, i: int) -> str:
    if not isinstance(rig, CanRig):
        return ""
    fw = rig.firmwares[i]
    if fw.enabled:
        return ""
    note = f"drive off, fault {fw.fault:#x}" if fw.fault else "drive off"
    locked = getattr(rig.plant, "locked", None)
    return f"{note}, braked" if locked is not None and locked[i] else note


def joints_text(rig: Lockstep, moved: float | None, goal: str | None = None) -> str:
    """What the joints do now, grouped: mode (and the drive's state on CAN), the goal's fate, motion since."""
    groups: dict[str, list[str]] = {}
    for i, (joint, mode) in enumerate(zip(rig.joints, rig.modes(), strict=True)):
        note = drive_note(rig, i)
        groups.setdefault(f"{mode} ({note})" if note else mode, []).append(joint)
    names = len(rig.joints)
    parts = [f"{'all' if len(js) == names else ', '.join(js)}: {state}" for state, js in groups.items()]
    if goal is not None:
        result = rig.result(goal)
        assert result is not None, "the running goal has no result"
        parts.append(f"goal {result.status}")
    if moved is not None:
        parts.append(f"moved ≤ {moved * 1000:.0f} mrad once caught")
    return "; ".join(parts)


def watch(rig: Lockstep, seconds: float, start: np.ndarray | None = None) -> float:
    """Run ``seconds`` and return the largest distance any joint moved from ``start`` (default: where it is)."""
    start = rig.engine.state.position.copy() if start is None else start
    moved = float(np.abs(rig.engine.state.position - start).max())
    for _ in range(round(seconds * rig.engine.update_rate)):
        rig.cycle()
        moved = max(moved, float(np.abs(rig.engine.state.position - start).max()))
    return moved


def assert_drive_steps(rig: CanRig, lost_cycles: int = 0) -> None:
    """No command an MIT drive executed moved further than the velocity limit allows (plus ``lost_cycles`` of
    frames the bus dropped, and two LSBs of the wire format), measured by the firmware itself."""
    for joint, fw in zip(rig.joints, rig.firmwares, strict=True):
        if not isinstance(fw, MitFirmware):
            continue
        lsb = 2.0 * fw.ranges.p_max / 65535
        bound = (1 + lost_cycles) * float(rig.engine.limits.velocity[rig.joints.index(joint)]) * rig.engine.period
        assert fw.command_step <= bound + 2 * lsb, f"{joint}: the drive's command stepped {fw.command_step:.4g} rad"


# ---- recovery -------------------------------------------------------------------------------------------------------
@dataclass
class Step:
    text: str
    action: Callable[[], None]


def recover(
    rig: Lockstep, before: Sequence[Step] = (), enable: bool | None = None, reset: bool = True, settle: float = 0.0
) -> str:
    """Fix the cause (``before``), ``reset``; ``enable`` when a fault remains (or when told); after ``settle`` s
    (a damped arm may still be moving when the hold catches it) check the arm holds where it is, then that a new
    goal succeeds. Returns what was done, as the table says it."""
    done = []
    for step in before:
        step.action()
        done.append(step.text)
    rig.cycle(5)
    if reset:
        reply = rig.reset()
        assert "error" not in reply, reply
        done.append("`reset`")
        rig.seconds(OPERATOR_PAUSE)
    if enable or (enable is None and rig.any_fault()):
        assert "error" not in (reply := rig.enable()), reply
        done.append("`enable`")
        rig.seconds(0.2)
    assert not rig.any_fault(), f"still faulted after {done}: {rig.faulted()}"
    caught = watch(rig, settle) if settle else 0.0
    moved = watch(rig, 0.3)
    assert moved < 2e-3, f"the arm moved {moved:.4g} rad while holding after recovery"
    outcome = f"caught within {caught * 1000:.0f} mrad, then holds" if settle else "holds where it is"
    if rig.engine.manager.records[JTC].state != "active":
        rig.switch([JTC])
    result = rig.finish(rig.move(-0.3))
    assert result.status == "succeeded", result
    return ", ".join(done or ["nothing"]) + f" → {outcome}; next goal succeeds"


# ---- CAN scenarios ------------------------------------------------------------------------------------------------
class MidMove:
    """A CAN rig with a move_to running on every joint, ``INTO_MOVE`` s in: where CAN faults are injected."""

    def __init__(self, flavour: str = "damiao", n: int = 3, **options: Any) -> None:
        self.rig = CanRig(flavour, n, **options)
        self.rig.switch([JTC])
        self.goal = self.rig.move(MOVE)
        self.rig.seconds(INTO_MOVE)
        self.injected_at = 0

    def inject(self, action: Callable[[], None]) -> None:
        action()
        self.injected_at = self.rig.cycles

    def detect(self, condition: Callable[[], bool] | None = None, limit: float = 1.0) -> int:
        return self.rig.until(condition or self.rig.any_fault, limit, "reaction to the fault")

    def observe(self, tolerated: bool = False) -> str:
        moved = watch(self.rig, OBSERVE)
        return joints_text(self.rig, None if tolerated else moved, self.goal)

    def event(self, words: str = "") -> str:
        return first_event(self.rig, self.injected_at, words)

    def __enter__(self) -> MidMove:
        return self

    def __exit__(self, *exc: object) -> None:
        self.rig.close()


def set_all(rig: CanRig, **values: Any) -> None:
    for fw in rig.firmwares:
        for key, value in values.items():
            setattr(fw, key, value)


@scenario("silent_one", "one servo silent", "j2's transceiver cut (`silent`)")
def _silent_one() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: setattr(rig.firmware("j2"), "silent", True))
        detected = case.detect()
        assert rig.faulted() == ["j2"]
        joints = case.observe()
        assert not rig.firmware("j2").enabled  # deaf to the host: its own CAN watchdog disabled it
        recovery = recover(rig, [Step("transceiver back", lambda: setattr(rig.firmware("j2"), "silent", False))])
        assert_drive_steps(rig)
        return str(detected), joints, case.event(), recovery


@scenario("silent_all", "all servos silent", "every transceiver cut")
def _silent_all() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: set_all(rig, silent=True))
        detected = case.detect()
        assert rig.faulted() == list(rig.joints)
        joints = case.observe()
        recovery = recover(rig, [Step("transceivers back", lambda: set_all(rig, silent=False))])
        assert_drive_steps(rig)
        return str(detected), joints, case.event(), recovery


@scenario("delayed_short", "delayed replies, 5 ms", "every reply 5 ms late (`reply_delay`)")
def _delayed_short() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: set_all(rig, reply_delay=0.005))
        joints = case.observe(tolerated=True)
        result = rig.result(case.goal)
        assert not rig.any_fault() and result is not None and result.status == "succeeded", result
        recovery = recover(rig, [Step("delay off", lambda: set_all(rig, reply_delay=0.0))])
        assert_drive_steps(rig)
        detected = f"— (below `stale_feedback_cycles` {rig.engine.supervisor.safety.stale_feedback_cycles})"
        return detected, joints, case.event(), recovery


@scenario("delayed_long", "delayed replies, 20 ms", "every reply 20 ms late")
def _delayed_long() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: set_all(rig, reply_delay=0.02))
        detected = case.detect()
        joints = case.observe()
        assert all(rig.drives_enabled())  # the drives still hear the host: they hold what it commands
        recovery = recover(rig, [Step("delay off", lambda: set_all(rig, reply_delay=0.0))])
        assert_drive_steps(rig)
        return str(detected), joints, case.event(), recovery


@scenario("corrupt_burst", "corrupted frames, burst of 5", "j2's next 5 replies one byte short")
def _corrupt_burst() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: setattr(rig.firmware("j2"), "corrupt_replies", 5))
        joints = case.observe(tolerated=True)
        result = rig.result(case.goal)
        assert not rig.any_fault() and result is not None and result.status == "succeeded", result
        assert rig.driver.statistics["ignored wrong length"] == 5
        recovery = recover(rig)
        detected = "— (5 < `stale_feedback_cycles`; counted, reported)"
        return detected, joints, case.event("ignored CAN frames"), recovery


@scenario("corrupt_long", "corrupted frames, 50 in a row", "j2's next 50 replies one byte short")
def _corrupt_long() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: setattr(rig.firmware("j2"), "corrupt_replies", 50))
        detected = case.detect()
        assert rig.faulted() == ["j2"]
        joints = case.observe()
        recovery = recover(rig)
        assert_drive_steps(rig)
        return str(detected), joints, case.event(), recovery


def _drive_error(code: int) -> Callable[[], tuple[str, str, str, str]]:
    def run() -> tuple[str, str, str, str]:
        with MidMove() as case:
            rig = case.rig
            case.inject(lambda: rig.firmware("j2").inject_fault(code))
            detected = case.detect()
            assert rig.faulted() == ["j2"]
            joints = case.observe()
            recovery = recover(rig)  # reset sends clear-error: the drive comes back disabled, enable brings it on
            assert_drive_steps(rig)
            return str(detected), joints, case.event(), recovery

    return run


for _code, _name in DAMIAO.fault_names.items():
    scenario(f"damiao_{_code:#x}", f"Damiao error 0x{_code:X} ({_name})", f"`inject_fault({_code:#x})` on j2")(
        _drive_error(_code)
    )


@scenario("tmotor_error", f"T-Motor error 2 ({TMOTOR.fault_names[2]})", "`inject_fault(2)` on j2")
def _tmotor_error() -> tuple[str, str, str, str]:
    with MidMove("tmotor") as case:
        rig = case.rig
        case.inject(lambda: rig.firmware("j2").inject_fault(2))
        detected = case.detect()
        joints = case.observe()
        rig.reset()
        rig.cycle(5)
        assert rig.faulted() == ["j2"]  # no clear-error frame: the drive keeps reporting it
        power_cycle = Step("power-cycle j2's drive", rig.firmware("j2").reboot)
        # Its replies do not say whether it is enabled, so the host cannot see it came back off: enable explicitly.
        recovery = recover(rig, [power_cycle], enable=True)
        assert_drive_steps(rig)
        return str(detected), joints, case.event(), "`reset` alone: fault again (no clear frame); " + recovery


@scenario("myactuator_error", "MyActuator error flags 0x0008 (over-voltage)", "`inject_fault(0x8)` on j2")
def _myactuator_error() -> tuple[str, str, str, str]:
    with MidMove("myactuator") as case:
        rig = case.rig
        case.inject(lambda: rig.firmware("j2").inject_fault(0x8))
        detected = case.detect(limit=0.5)
        joints = case.observe()
        rig.reset()
        rig.seconds(0.2)  # the next status poll reports it again
        assert rig.faulted() == ["j2"]
        # A motion frame runs a rebooted drive at once: no enable, and none is needed.
        recovery = recover(rig, [Step("power-cycle j2's drive", rig.firmware("j2").reboot)])
        assert_drive_steps(rig)
        text = "`reset` alone: fault again at the next status poll; " + recovery
        return f"{detected} (`status_poll_ms`)", joints, case.event(), text


@scenario("odrive_error", "ODrive axis error DC_BUS_OVER_VOLTAGE", "`inject_fault(0x100)` on j2's axis")
def _odrive_error() -> tuple[str, str, str, str]:
    with MidMove("odrive", 2) as case:
        rig = case.rig
        case.inject(lambda: rig.firmware("j2").inject_fault(int(ODriveError.DC_BUS_OVER_VOLTAGE)))
        detected = case.detect(limit=0.5)
        joints = case.observe()
        recovery = recover(rig)  # Clear_Errors, then the axis must be re-armed: enable
        return f"{detected} (heartbeat)", joints, case.event(), recovery


@scenario("reboot", "motor reboot mid-trajectory", "power cycle of j2's Damiao drive (`reboot()`)")
def _reboot() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(rig.firmware("j2").reboot)
        detected = case.detect()
        joints = case.observe()
        recovery = recover(rig)
        assert_drive_steps(rig)
        watchdog = [round(fw.timeout * 1000) for fw in rig.firmwares if hasattr(fw, "timeout")]
        note = f"; j2's CAN watchdog afterwards: {watchdog[1]} ms (others {watchdog[0]} ms)"
        return str(detected), joints, case.event(), recovery + note


BUS_OFF = 0.005  # s


@scenario("bus_off", "bus-off and recovery", f"bus-off error frame, then the bus down {BUS_OFF * 1000:g} ms")
def _bus_off() -> tuple[str, str, str, str]:
    with MidMove() as case:
        rig = case.rig
        case.inject(lambda: rig.emulator.bus_off(rig.now, BUS_OFF))
        detected = case.detect()
        assert rig.faulted() == list(rig.joints)
        assert all(rig.drives_enabled())  # shorter than their watchdog
        joints = case.observe()
        recovery = recover(rig)
        lost = round(BUS_OFF * rig.engine.update_rate)
        assert_drive_steps(rig, lost_cycles=lost)
        return f"{detected} (health poll, 20 Hz)", joints, case.event(), recovery


# ---- twin scenarios -------------------------------------------------------------------------------------------------
class RaisingTrajectory(JointTrajectoryController):
    """joint_trajectory with a bug: once ``armed``, every ``update`` raises."""

    armed = False

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        super().update(t, dt, state, command)
        if self.armed:
            raise RuntimeError("plugin bug")


@scenario("controller_exception", "controller exception", "a joint_trajectory whose `update` raises mid-goal")
def _controller_exception() -> tuple[str, str, str, str]:
    rig = TwinRig()
    try:
        engine = rig.engine
        jtc = engine.manager.records[JTC]
        faulty = RaisingTrajectory(engine.controller_context("faulty"), jtc.instance.params)
        engine.add_controller("faulty", "joint_trajectory", faulty, [JTC])
        rig.switch(["faulty"])
        reply = GoalEndpoint.of(faulty.action).submit({"positions": (engine.state.position + 0.3).tolist()})
        assert reply["ok"], reply
        rig.seconds(0.3)
        since = rig.cycles
        faulty.armed = True
        detected = rig.until(lambda: engine.manager.records["faulty"].state == "failed", 0.1, "failure")
        assert engine.manager.records[JTC].state == "active"  # the fallback
        moved = watch(rig, OBSERVE)
        GoalEndpoint.of(faulty.action).collect()
        result = GoalEndpoint.of(faulty.action).result({"goal_id": reply["goal_id"]})
        joints = f"all: hold, then `{JTC}` (fallback) holds them; its goal {result['status']}"
        joints += f"; moved ≤ {moved * 1000:.0f} mrad once caught"
        assert not rig.any_fault()  # a controller's bug is not a fault of the joints: nothing to reset
        return str(detected), joints, first_event(rig, since), recover(rig, reset=False)
    finally:
        rig.close()


def _stream_then_stop(
    controller: str, words: str, send: Callable[[Any, np.ndarray, np.ndarray], None], stopped: Callable[[Any], bool]
) -> tuple[str, str, str, str]:
    """Stream a moving target (position, velocity) to ``controller`` for 0.4 s, then stop: cycles to its timeout,
    then to ``stopped``; the commanded speed is read when the timeout fires."""
    rig = TwinRig()
    try:
        engine = rig.engine
        rig.switch([controller])
        instance = engine.manager.records[controller].instance
        start = engine.state.position.copy()
        for k in range(round(0.4 * engine.update_rate)):
            t = k / engine.update_rate
            send(
                instance,
                start + 0.3 * math.sin(math.pi * t),
                np.full_like(start, 0.3 * math.pi * math.cos(math.pi * t)),
            )
            rig.cycle()
        since = rig.cycles
        detected = rig.until(lambda: any(words in e.message for _, e in rig.events_since(since)), 2.0, words)
        speed, there = float(np.abs(engine.final.velocity).max()), engine.state.position.copy()
        settle = rig.until(lambda: stopped(instance), 2.0, "the stop") if not stopped(instance) else 0
        moved = watch(rig, OBSERVE, there)
        modes = sorted(set(rig.modes()))
        joints = f"all: {', '.join(modes)}"
        joints += f"; from {speed:.2f} rad/s to rest in {settle} cycles (jerk-limited)" if settle else ""
        joints += f"; moved ≤ {moved * 1000:.0f} mrad after the timeout"
        send(instance, engine.state.position.copy(), np.zeros_like(start))
        rig.cycle(5)
        assert rig.modes() == ["controlled"] * len(rig.joints)
        recovery = "nothing: the next command resumes from where the arm is"
        return f"{detected} (`command_timeout`)", joints, first_event(rig, since), recovery
    finally:
        rig.close()


@scenario("timeout_forward", "controller input timeout: forward_command", "the position stream stops")
def _timeout_forward() -> tuple[str, str, str, str]:
    def send(instance: Any, positions: np.ndarray, velocities: np.ndarray) -> None:
        instance.accept({"values": positions.tolist()})  # position only: the joints reach the last one and stay

    return _stream_then_stop("forward_position", "no command for", send, lambda _: True)


@scenario("timeout_servo", "controller input timeout: servo", "the target stream (with velocities) stops")
def _timeout_servo() -> tuple[str, str, str, str]:
    def send(instance: Any, positions: np.ndarray, velocities: np.ndarray) -> None:
        instance.accept({"positions": positions.tolist(), "velocities": velocities.tolist()})  # keeps cruising

    # servo brakes jerk-limited itself, then holds where it stopped (it stays the joints' controller)
    return _stream_then_stop("servo", "no target for", send, lambda servo: servo.phase == Phase.HOLD)


OVERRUN_BURST = 25


@scenario("overruns", "burst of overruns", f"{OVERRUN_BURST} cycles in a row recorded late")
def _overruns() -> tuple[str, str, str, str]:
    rig = TwinRig()
    try:
        engine = rig.engine
        rig.switch([JTC])
        goal = rig.move(0.3)
        rig.seconds(0.2)
        since = rig.cycles
        late = 2 * round(engine.period * 1e9)
        detected = 0
        for k in range(1, OVERRUN_BURST + 1):
            engine.stats.record(late, late, True)  # what the cycle thread records for a cycle that ended late
            rig.cycle()
            if not detected and rig.any_fault():
                detected = k
        engine.stats.record(0, 0, False)  # the burst ends
        assert detected
        assert rig.faulted() == list(rig.joints)
        joints = joints_text(rig, watch(rig, OBSERVE), goal)
        limit = engine.max_consecutive_overruns
        return f"{detected} (`max_consecutive_overruns` {limit})", joints, first_event(rig, since), recover(rig)
    finally:
        rig.close()


# ---- glitching sensors (issue [trust]): the commanded position never moves toward a bad reading ----------------------
GLITCH_JOINT = 1  # the joint whose readings lie: on arm6 the shoulder_lift, which carries the arm's weight


@dataclass(frozen=True)
class Glitch:
    key: str
    fault: str
    injected: str
    persistent: bool  # it stays until the sensor is fixed: the joint must fault (a short one must not)
    moving: bool = False  # injected mid-move (a frozen encoder only shows while the joint moves)


GLITCHES = (
    Glitch("short", "encoder glitch, short", "3 readings of +7 rad (beyond the hard limit)", False),
    Glitch("jump", "encoder glitch, persistent jump", "every reading +0.5 rad from now on", True),
    Glitch("spike", "encoder glitch, persistent spike beyond limits", "every reading +7 rad", True),
    Glitch("frozen", "frozen encoder", "position frozen mid-move, velocity still reported", True, moving=True),
    Glitch("flip", "encoder sign flip", "every reading −q (the joint away from 0)", True),
)


def inject_glitch(component: Any, i: int, kind: str, q: float) -> float:
    """Corrupt joint ``i``'s readings on a simulated driver (drivers/glitch.py); returns the bad reading."""
    glitch = component.glitch
    if kind == "short":
        glitch.set(i, value=7.0, replies=3)
        return 7.0
    if kind == "jump":
        glitch.set(i, offset=0.5)
        return q + 0.5
    if kind == "spike":
        glitch.set(i, value=7.0)
        return 7.0
    if kind == "frozen":
        glitch.freeze(i)
        return q
    glitch.flip(i)
    return -q


def glitch_run(rig: Lockstep, glitch: Glitch, component: Any) -> tuple[str, str, str, str]:
    """Inject ``glitch`` on GLITCH_JOINT (held, or mid-move), watch the commanded position for 1 s, recover."""
    engine, i = rig.engine, GLITCH_JOINT
    joint = rig.joints[i]
    goal = None
    if glitch.moving:
        rig.switch([JTC])
        goal = rig.move(MOVE)
        rig.seconds(INTO_MOVE)
    p0, q = float(engine.final.position[i]), float(engine.state.position[i])
    since = rig.cycles
    bad = inject_glitch(component, i, glitch.key, q)
    direction = math.copysign(1.0, bad - p0) if bad != p0 else 0.0
    toward = 0.0
    detected = -1
    for k in range(round(OBSERVE * engine.update_rate)):
        rig.cycle()
        if direction:  # how far the command went toward the bad reading; a move's own progress counts too
            toward = max(toward, (float(engine.final.position[i]) - p0) * direction)
        if detected < 0 and engine.supervisor.fault[i]:
            detected = k + 1
    faulted = rig.faulted()
    if glitch.persistent:
        assert faulted == [joint], (glitch.key, faulted)
        assert engine.final.kp[i] == 0.0  # no position to trust: damping only, never a spring
        assert engine.supervisor.latched[i] != bad
    else:
        assert not faulted and detected < 0, faulted
    if goal is None:
        assert toward == 0.0, f"the command moved {toward:.4g} rad toward the bad reading"
    text = "; ".join(
        part
        for part in (
            joints_text(rig, None, goal),
            f"{joint} damped, gravity at its last accepted pose" if glitch.persistent else "",
            f"command moved {toward * 1000:.0f} mrad toward the reading" if goal is None else "",
        )
        if part
    )
    component.glitch.clear()
    recovery = "nothing: readings plausible again"
    if glitch.persistent:  # the sensor fixed, its readings agree again: reset takes them (re-anchored if they moved)
        recovery = recover(rig, [Step("sensor fixed", lambda: rig.seconds(0.05))], settle=0.5 if glitch.moving else 0.0)
    stale = engine.supervisor.safety.stale_feedback_cycles
    shown = str(detected) if detected > 0 else f"— (3 readings rejected, < {stale}; reported)"
    return shown, text, first_event(rig, since, "reading rejected"), recovery


CAN_FLAVOURS = (("damiao", "Damiao"), ("tmotor", "T-Motor"), ("myactuator", "MyActuator"), ("odrive", "ODrive"))


class DriveGlitches:
    """A CAN rig's emulated drives' glitch controls, addressed by joint index like a simulated driver's (each
    firmware corrupts the position field of the replies it sends; its own law keeps the true shaft)."""

    def __init__(self, rig: CanRig) -> None:
        self.firmwares = rig.firmwares

    def set(self, i: int, **corruption: Any) -> None:
        self.firmwares[i].glitch.set(0, **corruption)

    def freeze(self, i: int, on: bool = True) -> None:
        self.firmwares[i].glitch.freeze(0, on)

    def flip(self, i: int, on: bool = True) -> None:
        self.firmwares[i].glitch.flip(0, on)

    def clear(self) -> None:
        for fw in self.firmwares:
            fw.glitch.clear()


@dataclass
class EmulatedDrives:
    glitch: DriveGlitches


Outcome = tuple[str, str, str, str]


def on_rig(make: Callable[[], Lockstep], body: Callable[[Lockstep], Outcome]) -> Callable[[], Outcome]:
    """A scenario's run: build its rig, run ``body`` on it, always close it."""

    def run() -> Outcome:
        rig = make()
        try:
            return body(rig)
        finally:
            rig.close()

    return run


def _simulated_glitch(glitch: Glitch) -> Callable[[Lockstep], Outcome]:
    return lambda rig: glitch_run(rig, glitch, rig.engine.hardware[0].component)


def _drive_glitch(glitch: Glitch) -> Callable[[Lockstep], Outcome]:
    return lambda rig: glitch_run(rig, glitch, EmulatedDrives(DriveGlitches(rig)))


for _glitch in GLITCHES:
    scenario(f"twin_glitch_{_glitch.key}", f"{_glitch.fault} (twin)", _glitch.injected)(
        on_rig(TwinRig, _simulated_glitch(_glitch))
    )
    scenario(f"mock_glitch_{_glitch.key}", f"{_glitch.fault} (mock)", _glitch.injected)(
        on_rig(MockRig, _simulated_glitch(_glitch))
    )
    for _flavour, _name in CAN_FLAVOURS:
        scenario(f"{_flavour}_glitch_{_glitch.key}", f"{_glitch.fault} ({_name})", _glitch.injected)(
            on_rig(lambda flavour=_flavour: CanRig(flavour), _drive_glitch(_glitch))
        )


# ---- a stalled cycle (issue [trust], finding 8): it resumes where it was, never catches up in one step -------------
def stall_run(rig: Lockstep, seconds: float, move: float = MOVE) -> tuple[str, str, str, str]:
    """A move on every joint, the cycle stalled ``seconds`` mid-way, then watched; the late cycle's command step
    is bounded by the guard (MAX_STEP_PERIODS periods of the velocity limit)."""
    engine = rig.engine
    rig.switch([JTC])
    goal = rig.move(move)
    rig.seconds(INTO_MOVE)
    since = rig.cycles
    before = engine.final.position.copy()
    planned = float(np.abs(engine.final.velocity).max()) * engine.period  # the plan's step per cycle, before
    rig.stall(seconds)
    step = float(np.abs(engine.final.position - before).max())
    stalled = bool(engine.supervisor.fault.any())  # past max_cycle_gap: the late cycle itself faults
    detected = "1 (the late cycle faults)"
    if not stalled:
        k = rig.until(lambda: rig.result(goal) is not None or rig.any_fault(), 5.0, "the goal's end")
        detected = f"{1 + k} (the drives' watchdogs)" if rig.any_fault() else "1 (an event at the late cycle)"
    joints = joints_text(rig, None, goal) + f"; command step {step * 1000:.2f} mrad (plan {planned * 1000:.2f}/cycle)"
    event = first_event(rig, since, "stalled" if stalled else "cycle gap")
    result = rig.result(goal)
    if rig.any_fault():  # the hold caught a moving arm: let it settle before checking that it holds
        recovery = recover(rig, settle=0.5)
    else:
        assert result is not None and result.status == "succeeded", result
        assert rig.finish(rig.move(-move / 2)).status == "succeeded"
        recovery = "nothing: the goal ran on, re-timed by the gap, and succeeded; next goal succeeds"
    return detected, joints, event, recovery


for _seconds in (0.3, 2.0):
    _what = f"no cycle for {_seconds:g} s mid-move (SIGSTOP, a debugger, a page storm)"
    scenario(f"stall_twin_{_seconds:g}", f"stalled cycle, {_seconds:g} s (twin)", _what)(
        on_rig(TwinRig, lambda rig, seconds=_seconds: stall_run(rig, seconds, TWIN_MOVE))
    )
    scenario(f"stall_damiao_{_seconds:g}", f"stalled cycle, {_seconds:g} s (Damiao, 50 ms watchdog)", _what)(
        on_rig(CanRig, lambda rig, seconds=_seconds: stall_run(rig, seconds))
    )


# ---- the goal's client disappears (Zenoh liveliness) -------------------------------------------------------------
def _client_lost(setting: str) -> tuple[str, str, str, str]:
    """Client A sends a goal and goes away mid-goal; client B watches. Cycles are paused while Zenoh carries the
    token's withdrawal to the daemon, so the count starts when the daemon knows."""
    rig = ApiRig(controllers={JTC: {"on_client_lost": setting}})
    try:
        engine = rig.engine
        rig.switch([JTC])
        with rig.client() as watcher:
            sender = rig.client()
            target = (engine.state.position + 0.4).tolist()
            handle = sender.send_goal(JTC, {"positions": target})
            goal = handle.goal_id
            rig.seconds(0.3)
            assert rig.result(goal) is None  # still moving
            since = rig.cycles
            sender.close()  # its session, and with it its liveliness token, goes away
            rig.wait(lambda: len(rig.jtc.action.requests) > 0, "the client-lost notice to reach the controller")
            words = "runs on" if setting == "continue" else "decelerating"
            detected = rig.until(lambda: any(words in e.message for _, e in rig.events_since(since)), 0.1, words)
            if setting == "stop":
                assert rig.result(goal) is not None
                speed, there = float(np.abs(rig.jtc.vd).max()), engine.state.position.copy()
                stopped = rig.until(lambda: not rig.jtc.vd.any(), 2.0, "the stop")
                rig.seconds(OBSERVE)
                moved = float(np.abs(engine.state.position - there).max())
                joints = f"all: controlled; from {speed:.2f} rad/s to rest in {stopped} cycles (jerk-limited), held"
                joints += f"; stopped {moved * 1000:.0f} mrad on"
            else:
                result = rig.finish(goal)
                assert result.status == "succeeded", result
                joints = "all: controlled; the goal runs to its end"
            result = watcher.goal_result(JTC, goal)  # what any other client reads
            joints += f"; goal {result['status']}"
            expected = "aborted" if setting == "stop" else "succeeded"
            assert result["status"] == expected, result
            if setting == "stop":
                assert "is gone" in result["error_string"], result
            mine = watcher.send_goal(JTC, {"positions": (engine.state.position - 0.2).tolist()})
            assert rig.finish(mine.goal_id).status == "succeeded"
            mine.close()
        recovery = "nothing: the goal's fate is the controller's `on_client_lost`; another client's goal succeeds"
        event = first_event(rig, since, "the client that sent it")
        return f"{detected} (after the token's withdrawal)", joints, event, recovery
    finally:
        rig.close()


@scenario(
    "client_lost_stop", "the goal's client disappears (`on_client_lost: stop`, default)", "client closed mid-goal"
)
def _client_lost_stop() -> tuple[str, str, str, str]:
    return _client_lost("stop")


@scenario("client_lost_continue", "the goal's client disappears (`on_client_lost: continue`)", "client closed mid-goal")
def _client_lost_continue() -> tuple[str, str, str, str]:
    return _client_lost("continue")


# ---- the daemon is killed and started again ----------------------------------------------------------------------
RESTART_OFFSETS = (0.4, -0.3, 0.3, 0.4, 0.4, 0.4)  # rad: the move the daemon is killed in
STILL = 2e-3  # rad: "where it was", through a kill, two daemons and an enable (1 feedback LSB is 0.38 mrad)
# After enable the brakes let go and hold takes the load: its gravity feed-forward crosses the bus quantized (12-bit
# torque) and the hold spring settles the rest, a static sag of a few mrad on the shoulder. Until the drive confirms
# the enable, hold follows the reading with damping and gravity only (no spring: its first commands must be where
# the shaft is), so the sag grows with how long the confirmation takes: 0.6-6 mrad on an idle machine, up to 11 mrad
# with a CPU hog beside the three processes (measured). Not a jump: the jump guard below checks every command step
# the drives execute. Known gap: a loaded machine sags more after enable (docs/safety.md).
HOLD_SETTLE = 15e-3


@scenario(
    "sigkill",
    "cycle process SIGKILL and restart",
    "`kill -9` of the cycle process mid-trajectory (CAN emulator in its own process), then the same config started "
    "again",
)
def _sigkill() -> tuple[str, str, str, str]:
    return _with_processes(_kill_and_restart)


@scenario(
    "daemon_sigkill",
    "daemon SIGKILL and restart",
    "`kill -9` of `hild run` (the daemon's main process) mid-trajectory, then the same config started again",
)
def _daemon_sigkill() -> tuple[str, str, str, str]:
    return _with_processes(_kill_daemon_and_restart)


@scenario(
    "client_sigkill",
    "client domain SIGKILL",
    "`kill -9` of the client domain (Zenoh, the API) mid-trajectory; `hild run` starts another",
)
def _client_sigkill() -> tuple[str, str, str, str]:
    return _with_processes(_kill_client_domain)


def _with_processes(run: Callable[[CanProcesses], tuple[str, str, str, str]]) -> tuple[str, str, str, str]:
    """``run`` on a CAN emulator process and daemons started by it; a failure carries every process's log."""
    with tempfile.TemporaryDirectory(prefix="hild-faults-") as tmp:
        rigs = CanProcesses(Path(tmp))
        try:
            return run(rigs)
        except AssertionError:
            raise AssertionError(f"{traceback.format_exc()}\n{rigs.logs()}") from None
        finally:
            rigs.close()


def _kill_daemon_and_restart(rigs: CanProcesses) -> tuple[str, str, str, str]:
    with rigs.start_daemon() as arm:
        arm.switch(activate=[JTC])
        home = rigs.positions()
        arm.send_goal(JTC, {"positions": (home + RESTART_OFFSETS).tolist()}, watched=False).close()
        rigs.wait(lambda: np.abs(rigs.positions() - home).max() > 0.1, "the arm to move")
        cycle = rigs.cycle_process()
        rigs.kill_daemon()
    rigs.wait(lambda: not running(cycle), "the orphaned cycle process to stop")
    log = rigs.daemon_log()
    assert "the daemon that started the cycle process is gone: stopping" in log, log
    assert "stopped: hardware released" in log, log
    drives = rigs.drives()
    assert all(not d["enabled"] and d["fault"] == 0 for d in drives), drives  # disabled by the release, not lost
    stopped = rigs.positions()

    with rigs.start_daemon() as arm:
        rigs.wait(lambda: arm.status()["mode"] == "hold", "the new daemon to hold every joint")
        for _ in range(25):  # half a second: the arm stays where the cycle process left it
            moved = rigs.positions() - stopped
            assert np.abs(moved).max() < HOLD_SETTLE, f"the arm moved by {moved} after the restart"
            time.sleep(0.02)
        arm.switch(activate=[JTC])
        goal = {"positions": (stopped + 0.1).tolist(), "duration": 2.0, "goal_time_tolerance": 2.0}
        with arm.send_goal(JTC, goal) as handle:
            result = handle.wait(30.0)
        assert result["status"] == "succeeded", result
    detected = f"the cycle process: its parent is gone (checked every {PARENT_CHECK * 1000:g} ms)"
    held = "held by the cycle process for a final cycle, then every drive disabled (released), no fault"
    event = "error `cycle`: the daemon that started the cycle process is gone: stopping (logged by the cycle process)"
    recovery = "start again: every joint holds where the arm stopped; next goal succeeds"
    return detected, held, event, recovery


def _kill_client_domain(rigs: CanProcesses) -> tuple[str, str, str, str]:
    with rigs.start_daemon() as arm:
        arm.switch(activate=[JTC])
        home = rigs.positions()
        handle = arm.send_goal(JTC, {"positions": (home + RESTART_OFFSETS).tolist()}, watched=False)
        goal_id = handle.goal_id
        handle.close()
        rigs.wait(lambda: np.abs(rigs.positions() - home).max() > 0.1, "the arm to move")
        cycle, client = rigs.cycle_process(), rigs.client_process()
        os.kill(client, signal.SIGKILL)
        killed = time.monotonic()
        rigs.wait(lambda: "the client domain was restarted" in rigs.daemon_log(), "another client domain")
        result = _until_answered(rigs, lambda: arm.goal_result(JTC, goal_id))
        answered = time.monotonic() - killed
        assert result["status"] == "aborted" and "the client domain ended" in result["error_string"], result
        assert rigs.cycle_process() == cycle and rigs.client_process() != client
        there = rigs.positions()
        for _ in range(25):  # half a second: jtc stopped the arm and holds it
            time.sleep(0.02)
        moved = np.abs(rigs.positions() - there).max()
        assert moved < HOLD_SETTLE, f"the arm moved by {moved} after the stop"
        drives = rigs.drives()
        assert all(d["enabled"] and d["fault"] == 0 for d in drives), drives  # never released, never lost
        goal = {"positions": home.tolist(), "duration": 2.0, "goal_time_tolerance": 2.0}
        with arm.send_goal(JTC, goal) as follow:
            assert follow.wait(30.0)["status"] == "succeeded"
    detected = "the main process: the client domain's exit (looked at every 50 ms); it tells the cycle process"
    held = (
        "the cycle process ran on: `joint_trajectory` aborted the goal and decelerated to a stop (jerk-limited), "
        "then held; the drives stayed enabled, no fault"
    )
    event = (
        "error `cycle`: the client domain ended: its goals are aborted and the joints hold until it is back; "
        "warning `daemon`: the client domain was restarted (…); clients may reconnect and resend"
    )
    assert answered < RECONNECT_WITHIN, f"the goal's result was answered {answered:.1f} s after the kill"
    recovery = (
        f"automatic: the same client reconnects and reads the goal's result (`aborted`) within {RECONNECT_WITHIN:g} s; "
        "next goal succeeds"
    )
    return detected, held, event, recovery


RECONNECT_WITHIN = 10.0  # s: a new client domain (≈0.5 s) and Zenoh's reconnection (≈1 s), on a loaded machine


@scenario(
    "client_sigstop",
    "client domain stalled",
    "`kill -STOP` of the client domain for 1 s mid-trajectory (a debugger, a page storm, a long GC), then `-CONT`",
)
def _client_sigstop() -> tuple[str, str, str, str]:
    return _with_processes(_stall_client_domain)


def _stall_client_domain(rigs: CanProcesses) -> tuple[str, str, str, str]:
    with rigs.start_daemon() as arm:
        arm.switch(activate=[JTC])
        home = rigs.positions()
        goal = {"positions": (home + 0.3).tolist(), "duration": 3.0}
        handle = arm.send_goal(JTC, goal, watched=False)
        goal_id = handle.goal_id
        handle.close()
        rigs.wait(lambda: np.abs(rigs.positions() - home).max() > 0.05, "the arm to move")
        client, before = rigs.client_process(), rigs.positions()
        os.kill(client, signal.SIGSTOP)
        try:
            time.sleep(STALL_CLIENT)
            during = rigs.positions()  # the emulator's drives: the arm moved on while nobody answered clients
        finally:
            os.kill(client, signal.SIGCONT)
        assert np.abs(during - before).max() > 0.05, f"the arm stood still during the stall: {during - before}"
        result = _until_answered(rigs, lambda: _finished(arm.goal_result(JTC, goal_id)))
        assert result["status"] == "succeeded", result
        assert rigs.client_process() == client, "a stalled client domain is not restarted"
        assert all(d["enabled"] and d["fault"] == 0 for d in rigs.drives())
        with arm.send_goal(JTC, {"positions": home.tolist(), "duration": 2.0}) as follow:
            assert follow.wait(30.0)["status"] == "succeeded"
    detected = "— (nothing to detect: the cycle does not wait for the client domain)"
    held = (
        "the cycle process ran on: the goal kept executing on the cycle clock and succeeded; drives enabled, no fault"
    )
    event = "none (the client domain's replies and publications resume where they stopped)"
    recovery = (
        "nothing: the client domain answers again when resumed, the goal's result reads `succeeded`; next goal succeeds"
    )
    return detected, held, event, recovery


STALL_CLIENT = 1.0  # s


def _finished(result: dict[str, Any]) -> dict[str, Any]:
    if result.get("status") == "executing":
        raise HildError("still executing")
    return result


def _until_answered(rigs: CanProcesses, ask: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """``ask()`` once the client has reconnected to the new client domain."""
    answer: list[dict[str, Any]] = []

    def answered() -> bool:
        try:
            answer.append(ask())
        except HildError:
            return False
        return True

    rigs.wait(answered, "the client to reconnect")
    return answer[-1]


def _kill_and_restart(rigs: CanProcesses) -> tuple[str, str, str, str]:
    with rigs.start_daemon() as arm:
        arm.switch(activate=[JTC])
        home = rigs.positions()
        arm.send_goal(JTC, {"positions": (home + RESTART_OFFSETS).tolist()}, watched=False).close()
        rigs.wait(lambda: np.abs(rigs.positions() - home).max() > 0.1, "the arm to move")
        rigs.kill_cycle_process()
    log = rigs.daemon_log()
    assert rigs.daemon is not None and rigs.daemon.returncode == 1, log
    assert "the cycle process ended unexpectedly (exit code -9)" in log, log

    def drives_off() -> bool:
        return all(not d["enabled"] and d["fault"] == DAMIAO.LOST_COMM and d["braked"] for d in rigs.drives())

    rigs.wait(drives_off, "every drive's CAN watchdog to disable it")
    stopped = rigs.positions()
    assert np.abs(stopped - home).max() > 0.1, f"killed mid-way, away from home: {stopped - home}"
    cfg = load_config(rigs.config).config
    timeout_ms = cfg.hardware["arm"].params["timeout_ms"]
    lsb = 2 * MODELS["damiao"]["DM8009"].p_max / 65535  # every arm6 motor maps ±12.5 rad on 16 bits
    bound = max(j.limits.velocity for j in cfg.joints.values()) / cfg.update_rate + 2 * lsb

    with rigs.start_daemon() as arm:
        rigs.wait(  # the API answers from just before the first cycle: wait for it
            lambda: all(j["mode"] == "fault" and "0xd" in j["fault"] for j in arm.status()["joints"]),
            "the new daemon to report the drives' faults",
        )
        rigs.wait(  # the log line and the status come from different threads: wait for the line, too
            lambda: "communication lost (CAN timeout) at start-up" in rigs.daemon_log(),
            "the new daemon to log the drives' start-up faults",
        )
        moved = rigs.positions() - stopped
        assert drives_off() and np.abs(moved).max() < STILL, f"nothing was enabled: {rigs.drives()}, moved {moved}"

        _reset_until_cleared(arm, rigs)
        arm.call("enable")
        rigs.wait(lambda: arm.status()["mode"] == "hold", "every joint to hold")
        drives = rigs.drives()
        assert all(d["enabled"] and not d["braked"] for d in drives), drives
        for _ in range(25):  # half a second of drive state: the arm stays where it stopped
            moved = rigs.positions() - stopped
            assert np.abs(moved).max() < HOLD_SETTLE, f"the arm moved by {moved} after enable"
            time.sleep(0.02)
        steps = [d["command_step"] for d in rigs.drives()]
        assert max(steps) < bound, steps  # no command the drives executed jumped, the first included
        found = re.search(r"\[(\w+)\] (\w+: motor reports .* at start-up)", rigs.daemon_log())
        assert found is not None, rigs.daemon_log()
        event = clean(f"error `{found[1]}`: {found[2]}")

        arm.switch(activate=[JTC])
        goal = {"positions": (stopped + 0.1).tolist(), "duration": 2.0, "goal_time_tolerance": 2.0}
        with arm.send_goal(JTC, goal) as handle:
            result = handle.wait(30.0)
        assert result["status"] == "succeeded", result

    detected = f"drives: their CAN watchdog (`timeout_ms` {timeout_ms}); the new daemon: at start-up, before cycle 1"
    held = (
        f"all drives off (0xD), braked: the arm stays where it was (< {STILL * 1000:g} mrad through the restart); "
        "the new daemon starts every joint in fault (hold) and enables nothing"
    )
    recovery = (
        f"`reset` (until the drives report the clear), `enable` → holds where the arm stopped (within "
        f"{HOLD_SETTLE * 1000:g} mrad as hold takes the load; every drive command step < {bound * 1000:.1f} mrad, "
        "the first included); next goal succeeds"
    )
    return detected, held, event, recovery


def _reset_until_cleared(arm: Any, rigs: CanProcesses, attempts: int = 3) -> None:
    """``reset`` until every drive reports its clear (disabled, no error): an operator's loop. ``mit_can`` forgives
    the echoes of a cleared code still in flight (up to 50 replies), so one reset is normally enough; the loop
    keeps this two-process scenario about the restart, not about the loopback bus's latency."""
    for _ in range(attempts):
        arm.reset()
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            faults = [j["fault"] or "" for j in arm.status()["joints"]]
            if all("disabled" in f for f in faults):
                return
            time.sleep(0.05)
    raise AssertionError(f"the drives never reported their clear: {faults}")
