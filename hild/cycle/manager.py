"""The controller manager: lifecycle, exclusive claims, atomic switches, failure handling.

Every method that changes which controllers run is called on the cycle, between two cycles (the engine
applies queued requests at the start of a cycle), so a switch is atomic: no cycle ever sees half of it.
A switch is validated in full before anything changes; in strict mode any problem refuses the whole switch,
in best-effort mode the failing controllers are dropped. If an ``on_activate`` raises mid-switch, everything the
switch did is rolled back (strict) or that controller alone is dropped (best effort).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import Controller, ControllerState
from hild.crossing.events import EventLog
from hild.interfaces import ClaimError, ClaimMasks, build_masks, check_claims, parse_interface


@dataclass
class ControllerRecord:
    slot: int
    name: str
    type: str
    instance: Controller
    claims: tuple[str, ...]
    fallbacks: tuple[str, ...]
    reads: tuple[str, ...] = ()  # the state interfaces it reads
    gravity: tuple[str, ...] = ()  # joints whose effort command gets the gravity torque on top (gravity_joints)
    state: ControllerState = ControllerState.UNCONFIGURED
    error: str = ""
    joint_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))


@dataclass(frozen=True)
class ControllerInfo:
    """An immutable view of one controller, safe to read from any thread."""

    slot: int
    name: str
    type: str
    state: str
    claimed: tuple[str, ...]
    error: str
    reads: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "type": self.type,
            "state": self.state,
            "claimed": list(self.claimed),
            "error": self.error,
            "state_interfaces": list(self.reads),
        }


@dataclass
class SwitchResult:
    ok: bool
    error: str = ""
    activated: list[str] = field(default_factory=list)
    deactivated: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return {
            "ok": self.ok,
            "error": self.error or None,
            "activated": self.activated,
            "deactivated": self.deactivated,
        }


class SwitchError(ValueError):
    pass


class ControllerManager:
    def __init__(self, joints: Sequence[str], available: Iterable[str], events: EventLog) -> None:
        self.joints = tuple(joints)
        self._joint_index = {j: i for i, j in enumerate(self.joints)}
        self.available = set(available)
        self.events = events
        self.records: dict[str, ControllerRecord] = {}
        self._slots = 0
        self.active: list[ControllerRecord] = []  # in load order: the update order
        self.masks = ClaimMasks.empty(len(self.joints))
        self.snapshot: tuple[ControllerInfo, ...] = ()
        self.change_seq = 0
        self.unavailable: dict[str, str] = {}  # interface → the inactive hardware component it belongs to
        self.on_claims: Callable[[ClaimMasks], None] = lambda masks: None  # the supervisor listens here

    # ---- lifecycle ------------------------------------------------------------------------------------------
    def load(self, name: str, type_name: str, controller: Controller, fallbacks: Sequence[str] = ()) -> None:
        if name in self.records:
            raise SwitchError(f"controller {name!r} is already loaded")
        self.records[name] = self._record(self._slots, name, type_name, controller, fallbacks)
        self._slots += 1
        self._changed()

    def configure(self, name: str) -> None:
        """unconfigured → inactive. An inactive (or failed) controller is cleaned up and configured again, as
        ros2_control does; an ``on_configure`` that raises leaves it unconfigured and says why."""
        rec = self._get(name)
        if rec.state is ControllerState.ACTIVE:
            raise SwitchError(f"controller {name!r} is active; deactivate it first")
        if rec.state is not ControllerState.UNCONFIGURED:
            self._cleanup(rec)
            rec.state = ControllerState.UNCONFIGURED
        try:
            rec.instance.on_configure()
        except Exception as exc:  # a plugin's bug must not take the daemon down
            self._changed()
            raise SwitchError(
                f"{name}: on_configure raised {type(exc).__name__}: {exc}; it stays unconfigured"
            ) from None
        rec.state = ControllerState.INACTIVE
        rec.error = ""
        self._changed()

    def cleanup(self, name: str) -> None:
        """inactive → unconfigured, as ros2_control's ``cleanup_controller``: only from inactive (an active one is
        deactivated first; an unconfigured one has nothing to clean up). It stays loaded, to be configured again."""
        rec = self._get(name)
        if rec.state is not ControllerState.INACTIVE:
            hint = "deactivate it first" if rec.state is ControllerState.ACTIVE else "only an inactive one can be"
            raise SwitchError(f"controller {name!r} is {rec.state}: it cannot be cleaned up ({hint})")
        self._cleanup(rec)
        rec.state = ControllerState.UNCONFIGURED
        self._changed()

    def unload(self, name: str) -> None:
        """Forget a controller that is not active (cleaned up first if it was configured). A controller that is
        another's fallback stays: the fallback is what takes over when that one fails."""
        rec = self._get(name)
        if rec.state is ControllerState.ACTIVE:
            raise SwitchError(f"controller {name!r} is active; deactivate it first")
        needing = [r.name for r in self.records.values() if name in r.fallbacks and r.name != name]
        if needing:
            raise SwitchError(f"controller {name!r} is the fallback of {needing}; unload those first")
        if rec.state is not ControllerState.UNCONFIGURED:
            self._cleanup(rec)
        del self.records[name]
        self._changed()

    def replace(self, name: str, type_name: str, controller: Controller, fallbacks: Sequence[str] = ()) -> str:
        """Swap a loaded controller that is not active for a new instance (a reload), keeping its place in the
        update order. The new one is configured if the old one was; if that fails, the old one stays as it was.
        Returns the new one's state."""
        old = self._get(name)
        if old.state is ControllerState.ACTIVE:
            raise SwitchError(f"controller {name!r} is active; deactivate it before reloading it")
        record = self._record(old.slot, name, type_name, controller, fallbacks)
        configured = old.state is not ControllerState.UNCONFIGURED
        if configured:
            try:
                controller.on_configure()
            except Exception as exc:
                raise SwitchError(
                    f"{name}: the new instance's on_configure raised {type(exc).__name__}: {exc}; the loaded one stays"
                ) from None
            self._cleanup(old)
        record.state = ControllerState.INACTIVE if configured else ControllerState.UNCONFIGURED
        self.records[name] = record
        self._changed()
        return str(record.state)

    def _record(
        self, slot: int, name: str, type_name: str, controller: Controller, fallbacks: Sequence[str]
    ) -> ControllerRecord:
        """A record for ``controller``, unconfigured; ClaimError if it claims what the drives do not offer."""
        claims = tuple(controller.claims())
        check_claims(name, claims, self.available)
        gravity = tuple(controller.gravity_joints())
        if stray := [j for j in gravity if f"{j}/effort" not in claims]:
            raise ClaimError(
                f"{name}: gravity on top of its effort asked for on {stray}, whose effort it does not claim"
            )
        return ControllerRecord(
            slot=slot,
            name=name,
            type=type_name,
            instance=controller,
            claims=claims,
            fallbacks=tuple(fallbacks),
            reads=tuple(controller.state_interfaces()),
            gravity=gravity,
            joint_index=self._joints_of(claims),
        )

    def _cleanup(self, rec: ControllerRecord) -> None:
        try:
            rec.instance.on_cleanup()
        except Exception as exc:
            self.events.emit(
                "error", "controller_manager", f"{rec.name}: on_cleanup raised {type(exc).__name__}: {exc}"
            )

    def _joints_of(self, claims: Sequence[str]) -> np.ndarray:
        return np.array(sorted({self._joint_index[parse_interface(c)[0]] for c in claims}), dtype=np.intp)

    # ---- switching --------------------------------------------------------------------------------------------
    def switch(
        self,
        activate: Sequence[str],
        deactivate: Sequence[str],
        strict: bool,
        state: JointState,
        last_command: ServoCommand,
        refuse_activation: str = "",
    ) -> SwitchResult:
        """Deactivate then activate, atomically between two cycles; see the module docstring for the rules."""
        try:
            to_stop, to_start = self._plan(list(activate), list(deactivate), strict, refuse_activation)
        except SwitchError as exc:
            return SwitchResult(False, str(exc))
        dropped = [n for n in activate if n not in {r.name for r in to_start}]
        dropped += [n for n in deactivate if n not in {r.name for r in to_stop}]

        for rec in to_stop:
            self._deactivate(rec)
        started: list[ControllerRecord] = []
        for rec in to_start:
            try:
                rec.instance.on_activate(state, last_command)
            except Exception as exc:  # a plugin's bug must not take the daemon down
                reason = f"{rec.name}: on_activate raised {type(exc).__name__}: {exc}"
                self.events.emit("error", "controller_manager", reason)
                if strict:
                    for done in started:
                        self._deactivate(done)
                    for back in to_stop:
                        self._reactivate(back, state, last_command)
                    self._apply_claims()
                    return SwitchResult(False, reason + "; switch rolled back")
                dropped.append(rec.name)
                continue
            rec.state = ControllerState.ACTIVE
            rec.error = ""
            rec.instance.set_active(True)
            started.append(rec)
            self.active.append(rec)
        self.active.sort(key=lambda r: r.slot)
        self._apply_claims()
        result = SwitchResult(
            ok=bool(started or to_stop) or not (activate or deactivate),
            error=f"not switched: {', '.join(dropped)}" if dropped else "",
            activated=[r.name for r in started],
            deactivated=[r.name for r in to_stop],
        )
        if started or to_stop:
            self.events.emit(
                "info",
                "controller_manager",
                f"switch: activated {result.activated or '[]'}, deactivated {result.deactivated or '[]'}",
            )
        return result

    def _plan(
        self, activate: list[str], deactivate: list[str], strict: bool, refuse_activation: str
    ) -> tuple[list[ControllerRecord], list[ControllerRecord]]:
        problems: list[str] = []
        to_stop: list[ControllerRecord] = []
        for name in deactivate:
            rec = self.records.get(name)
            if rec is None:
                problems.append(f"unknown controller {name!r}")
            elif rec.state is not ControllerState.ACTIVE:
                problems.append(f"{name} is not active ({rec.state})")
            else:
                to_stop.append(rec)
        candidates: list[ControllerRecord] = []
        for name in activate:
            rec = self.records.get(name)
            if rec is None:
                problems.append(f"unknown controller {name!r}")
            elif refuse_activation and rec.claims:
                problems.append(f"{name}: {refuse_activation}")
            elif rec.state is ControllerState.ACTIVE and rec not in to_stop:
                problems.append(f"{name} is already active")
            elif rec.state is ControllerState.UNCONFIGURED:
                problems.append(f"{name} is not configured")
            elif blocked := [c for c in rec.claims if c in self.unavailable]:
                owners = sorted({self.unavailable[c] for c in blocked})
                problems.append(f"{name} claims {blocked}, of inactive hardware {owners} (set it active first)")
            else:
                candidates.append(rec)
        if strict and problems:
            raise SwitchError("; ".join(problems))

        remaining = [r for r in self.active if r not in to_stop]
        to_start: list[ControllerRecord] = []
        for rec in candidates:
            trial = remaining + to_start + [rec]
            try:
                build_masks(
                    self._joint_index,
                    {r.slot: r.claims for r in trial},
                    {r.slot: r.name for r in trial},
                    {r.slot: r.gravity for r in trial},
                )
            except ClaimError as exc:
                if strict:
                    raise SwitchError(str(exc)) from None
                continue
            to_start.append(rec)
        if not strict and not to_start and not to_stop and (activate or deactivate):
            raise SwitchError("nothing to switch: " + ("; ".join(problems) or "claims conflict"))
        return to_stop, to_start

    def _deactivate(self, rec: ControllerRecord, new_state: ControllerState = ControllerState.INACTIVE) -> None:
        rec.instance.set_active(False)  # first: the API half refuses inputs from now on
        try:
            rec.instance.on_deactivate()
        except Exception as exc:
            self.events.emit("error", "controller_manager", f"{rec.name}: on_deactivate raised {exc!r}")
        rec.state = new_state
        if rec in self.active:
            self.active.remove(rec)

    def _reactivate(self, rec: ControllerRecord, state: JointState, last_command: ServoCommand) -> None:
        try:
            rec.instance.on_activate(state, last_command)
        except Exception as exc:
            self.events.emit("error", "controller_manager", f"{rec.name}: rollback re-activation raised {exc!r}")
            return
        rec.state = ControllerState.ACTIVE
        rec.instance.set_active(True)
        self.active.append(rec)
        self.active.sort(key=lambda r: r.slot)

    def deactivate_commanding(self, reason: str) -> list[str]:
        """Stop every active controller that claims command interfaces (e-stop); broadcasters keep running."""
        stopped = self._deactivate_each([r for r in self.active if r.claims])
        if stopped:
            self.events.emit("warning", "controller_manager", f"{reason}: deactivated {stopped}")
        return stopped

    def make_unavailable(self, interfaces: Sequence[str], component: str) -> list[str]:
        """``component``'s command interfaces leave the controllers' reach: the active controllers claiming any of
        them are deactivated (their joints held where they are) and none may claim them until it is active again."""
        self.unavailable.update(dict.fromkeys(interfaces, component))
        stopped = self._deactivate_each([r for r in self.active if any(c in self.unavailable for c in r.claims)])
        self._changed()
        return stopped

    def _deactivate_each(self, records: list[ControllerRecord]) -> list[str]:
        """Deactivate ``records`` (their joints to hold) and recompute the claims once; their names."""
        for rec in records:
            self._deactivate(rec)
        if records:
            self._apply_claims()
        return [r.name for r in records]

    def make_available(self, interfaces: Sequence[str]) -> None:
        for interface in interfaces:
            self.unavailable.pop(interface, None)
        self._changed()

    def deactivate_all(self, reason: str) -> None:
        stopped = list(self.active)
        for rec in stopped:
            self._deactivate(rec)
        self._apply_claims()
        if stopped:
            self.events.emit("info", "controller_manager", f"{reason}: deactivated {[r.name for r in stopped]}")

    # ---- the cycle ---------------------------------------------------------------------------------------------
    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        command.written.fill(False)
        command.hold_effort.fill(0.0)
        failed: list[tuple[ControllerRecord, BaseException]] | None = None
        for rec in self.active:
            try:
                rec.instance.update(t, dt, state, command)
            except Exception as exc:
                failed = failed or []
                failed.append((rec, exc))
                command.written[rec.joint_index] = False  # nothing it wrote this cycle is used
                command.hold_effort[rec.joint_index] = 0.0
        if failed:
            for rec, exc in failed:
                self.fail(rec, f"update raised {type(exc).__name__}: {exc}", state, command)

    def fail_slots(self, slots: Sequence[int], reason: str, state: JointState, command: ServoCommand) -> None:
        for rec in [r for r in self.active if r.slot in slots]:
            self.fail(rec, reason, state, command)

    def fail(self, rec: ControllerRecord, reason: str, state: JointState, command: ServoCommand) -> None:
        """Deactivate a failed controller, hold its joints (they go unwritten), then start its fallbacks."""
        self._deactivate(rec, ControllerState.FAILED)
        rec.error = reason
        self._apply_claims()
        joints = [self.joints[i] for i in rec.joint_index]
        self.events.emit("error", rec.name, f"{reason}; deactivated, joints {joints} held")
        if rec.fallbacks:
            result = self.switch(list(rec.fallbacks), [], True, state, command)
            level = "info" if result.ok and not result.error else "error"
            self.events.emit(
                level,
                "controller_manager",
                f"fallbacks of {rec.name} {rec.fallbacks}: " + (result.error or "activated"),
            )

    # ---- bookkeeping -------------------------------------------------------------------------------------------
    def _apply_claims(self) -> None:
        self.masks = build_masks(
            self._joint_index,
            {r.slot: r.claims for r in self.active},
            {r.slot: r.name for r in self.active},
            {r.slot: r.gravity for r in self.active},
        )
        self.on_claims(self.masks)
        self._changed()

    def _changed(self) -> None:
        self.snapshot = tuple(
            ControllerInfo(r.slot, r.name, r.type, str(r.state), r.claims, r.error, r.reads)
            for r in self.records.values()
        )
        self.change_seq += 1

    def _get(self, name: str) -> ControllerRecord:
        try:
            return self.records[name]
        except KeyError:
            known = ", ".join(self.records) or "none"
            raise SwitchError(f"unknown controller {name!r} (loaded: {known})") from None
