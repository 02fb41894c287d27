"""What every CAN host driver shares: one bus link, bad-frame accounting, the non-blocking drain, counters."""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence

import can

from drivers.can.bus import BadFrames, CanLink
from drivers.can.params import CanDriverParams
from hild.config.params import Params
from hild.hardware import HardwareComponent, HardwareContext, HardwareError


def coverage_problems(drive: str, drives: str, configured: Collection[str], joints: Sequence[str]) -> list[str]:
    """Joints without a configured drive, and drives configured for joints this component does not drive."""
    problems = []
    missing = [j for j in joints if j not in configured]
    if missing:
        problems.append(f"no {drive} configured for joints {missing}")
    extra = [j for j in configured if j not in joints]
    if extra:
        problems.append(f"{drives} configured for joints this component does not drive: {extra}")
    return problems


class FeedForwardClamp:
    """Feed-forward checked against the drive's own frame field before encoding (never silently saturated).

    A value beyond ``±limit`` is clamped to it, counted per motor, and reported once when an episode of clamping
    starts and once when it ends: events on change only, never per cycle.
    """

    def __init__(self, emit: Callable[[str, str], None], joints: list[str], limits: list[float], field: str) -> None:
        self.emit = emit
        self.joints = joints
        self.limits = limits
        self.field = field
        self.clamped = [0] * len(joints)  # frames whose feed-forward was clamped, per motor
        self._active = [False] * len(joints)

    def __call__(self, k: int, ff: float) -> float:
        limit = self.limits[k]
        if -limit <= ff <= limit:
            if self._active[k]:
                self._active[k] = False
                self.emit("info", f"{self.joints[k]}: feed-forward back inside the drive's {self.field}")
            return ff
        clamped = limit if ff > 0.0 else -limit if ff < 0.0 else 0.0  # NaN: no torque at all
        self.clamped[k] += 1
        if not self._active[k]:
            self._active[k] = True
            self.emit(
                "warning",
                f"{self.joints[k]}: feed-forward {ff:.4g} N·m beyond the drive's {self.field} (±{limit:g} N·m): "
                f"clamped to {clamped:g}",
            )
        return clamped


class CanComponent(HardwareComponent):
    """Base of ``mit_can`` and ``odrive_can``: one component owns one bus."""

    def __init__(self, context: HardwareContext, params: CanDriverParams, drives: int) -> None:
        super().__init__(context, params)
        self.link = CanLink(params.bus, params.send_failure_cycles)
        self.bad_frames = BadFrames(context.emit_event, context.name, params.event_interval)
        self._frame_budget = 8 * drives + 64  # frames drained per read at most; the rest waits for the next cycle

    @property
    def serve_while_waiting(self) -> Callable[[], None] | None:
        """Called while lifecycle hooks wait for replies: in-process emulators service their drives from it."""
        return self.link.serve_while_waiting

    @serve_while_waiting.setter
    def serve_while_waiting(self, fn: Callable[[], None] | None) -> None:
        self.link.serve_while_waiting = fn

    @classmethod
    def holds_at_stop(cls, params: Params) -> bool:
        """Both CAN drivers leave their drives holding on deactivate only with ``on_deactivate: hold`` (each
        names its limp choice its own way: ``disable``, ``idle``)."""
        return getattr(params, "on_deactivate", None) == "hold"

    def on_cleanup(self) -> None:
        self.link.close()

    def _stopping_limp(self, held: str) -> bool:
        """deactivate's question: should the drives be stopped? Not with the bus closed, nor with
        ``on_deactivate: hold`` (reported with `held`, what stays as it was)."""
        if self.link.bus is None:
            return False
        if self.params.on_deactivate == "hold":
            self.context.emit_event("info", f"{held} (on_deactivate: hold)")
            return False
        return True

    def _joint_indices(self, joint: str | None) -> list[int]:
        """Every drive for None, else the one of `joint`; an operator command naming another joint is refused."""
        if joint is None:
            return list(range(len(self.joints)))
        if joint not in self.joints:
            raise HardwareError(f"{self.context.name} drives no joint {joint!r} (joints: {', '.join(self.joints)})")
        return [self.joints.index(joint)]

    def drain(self, accept: Callable[[can.Message], None]) -> None:
        """Take every frame waiting (up to the budget) without blocking: the cycle never waits on the bus."""
        self.link.receive(accept, self._frame_budget)

    def recover_bus(self, accept: Callable[[can.Message], None]) -> None:
        """First step of an operator reset: recover a bus in trouble per ``bus_recovery``, then take in the frames
        already received, so replies sent before the clear cannot re-report what the reset is about to clear."""
        if self.link.problem is not None:
            if self.params.bus_recovery == "reopen":
                try:
                    self.link.reopen()
                except HardwareError as exc:
                    self.link.latch(str(exc))
            else:
                self.link.clear()
        self.drain(accept)

    def health(self) -> str | None:
        return self.link.check_state()

    @property
    def statistics(self) -> dict[str, int]:
        """Counters for tools and tests: frames, send failures, error frames, ignored frames by kind."""
        link = self.link
        return {
            "frames_sent": link.frames_sent,
            "frames_received": link.frames_received,
            "send_failures": link.send_failures,
            "error_frames": link.error_frames,
            "error_passive_reports": link.passive_reports,
            **{f"ignored {kind}": n for kind, n in self.bad_frames.totals.items()},
        }
