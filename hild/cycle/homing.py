"""Operator homing (``hild ctl home JOINT``): a drive's own homing procedure, run for one held joint on command.

A homing takes seconds to minutes, far longer than a request waits for its reply, so the ``home`` request answers
at once that it started (with an ``attempt`` number) and the end is told by events and by the status's ``homing``
entry of the joint, which ``hild ctl home`` polls. While a joint homes, its drive moves by itself: the engine lets
no controller claim it (``ControllerManager.reserved``), hold follows the reading every cycle (never a spring back
toward where the homing began) and ``HardwareComponent.homing`` is polled each cycle. An e-stop, a fault of the
joint or of its component, or the daemon stopping call ``stop_homing``: the drive halts by itself and the homing
ends failed. docs/operations.md, "Homing", is the operator's view.

This module keeps the runs and talks to the components; the engine applies what a run means for the supervisor and
the controller manager (hild/cycle/engine.py, ``home``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from hild.hardware import HardwareComponent, Homing

HOME_MAX_SPEED = 0.05  # rad/s: homing starts only on a still joint (as set-zero)
HOMING_SETTLE = 0.5  # s: after the end hold follows the reading this long (the new origin may show late), then latches
STOP_CONFIRM = 1.0  # s: after stop_homing, how long the drive has to report the end before the engine ends it itself
RESERVED = "is being homed (hild ctl home): wait for the homing to end, or e-stop to stop it"


@dataclass(slots=True)
class HomingRun:
    joint: int
    name: str
    hardware: str  # the component's name, for the words
    component: HardwareComponent
    attempt: int
    stopping: str = ""  # why the engine stopped it (e-stop, fault, shutdown); empty while the drive homes
    stop_by: int = 0  # the cycle by which the drive must have reported the stop


class Homings:
    """The homings under way and the last outcome of every joint homed since start (the status's ``homing``)."""

    def __init__(self, joints: tuple[str, ...]) -> None:
        self.joints = joints
        self.runs: dict[int, HomingRun] = {}
        self.entries: dict[int, dict[str, Any]] = {}  # joint → its status entry, kept after the end
        self.attempts = 0
        self.change_seq = 0  # moves with every entry: a new snapshot carries them

    def begin(self, i: int, hardware: str, component: HardwareComponent) -> HomingRun:
        """Start the drive's homing of joint ``i`` (HardwareError when it cannot home) and keep the run."""
        name = self.joints[i]
        component.start_homing(name)
        self.attempts += 1
        run = HomingRun(i, name, hardware, component, self.attempts)
        self.runs[i] = run
        self._enter(run, Homing.RUNNING, None, None)
        return run

    def stop(self, run: HomingRun, cause: str, cycle: int, confirm_cycles: int) -> None:
        """Ask the drive to stop (it halts under its own deceleration); the run ends once it reports the end."""
        run.stopping, run.stop_by = cause, cycle + confirm_cycles
        try:
            run.component.stop_homing(run.name)
        except Exception as exc:  # the driver's code: the stop is still owed, the end is then the engine's
            run.stopping = f"{cause}; stop_homing raised {type(exc).__name__}: {exc}"
            run.stop_by = cycle

    def poll(
        self, cycle: int, position: Sequence[float], cause_to_stop: Callable[[HomingRun], str], confirm_cycles: int
    ) -> tuple[HomingRun, ...]:
        """Once per cycle while any run is under way (after the read): stop the runs that must stop, and return the
        runs that ended, their entries updated with the joint's reading then (in its new frame once attained); the
        engine latches their joints and lets controllers claim them again. Allocates only when one ends."""
        ended: tuple[HomingRun, ...] = ()
        for run in self.runs.values():
            if not run.stopping and (cause := cause_to_stop(run)):
                self.stop(run, cause, cycle, confirm_cycles)
            try:
                state, detail = run.component.homing(run.name)
            except Exception as exc:  # the driver's code must not end the cycle
                state, detail = Homing.FAILED, f"homing() raised {type(exc).__name__}: {exc}"
            if state is Homing.RUNNING:
                if not run.stopping or cycle < run.stop_by:
                    continue
                state, detail = Homing.FAILED, "the drive did not report the stop in time"
            elif state is Homing.IDLE:
                state, detail = Homing.FAILED, "the drive reports no homing under way"
            if state is Homing.FAILED and run.stopping:
                detail = f"{run.stopping}: {detail}" if detail else run.stopping
            self._enter(run, state, detail or None, float(position[run.joint]))
            ended = (*ended, run)
        for run in ended:
            del self.runs[run.joint]
        return ended

    def abandon(self, position: Sequence[float]) -> list[HomingRun]:
        """End every run still under way, failed (the daemon stops and will not wait for the drives' report)."""
        runs = list(self.runs.values())
        self.runs.clear()
        for run in runs:
            why = run.stopping or "the daemon is stopping"
            self._enter(run, Homing.FAILED, f"{why}: the drive had not reported the end", float(position[run.joint]))
        return runs

    def _enter(self, run: HomingRun, state: Homing, detail: str | None, position: float | None) -> None:
        self.entries[run.joint] = {
            "joint": run.name,
            "state": str(state),
            "attempt": run.attempt,
            "detail": detail,
            "position": position,
        }
        self.change_seq += 1

    def status(self) -> tuple[dict[str, Any], ...]:
        """The entries in joint order, as immutable copies (the snapshot crosses into another process)."""
        return tuple(dict(self.entries[i]) for i in sorted(self.entries))
