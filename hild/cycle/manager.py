"""The controller manager: lifecycle, exclusive claims, atomic switches, failure handling.

Every method that changes which controllers run is called on the cycle, between two cycles (the engine
applies queued requests at the start of a cycle), so a switch is atomic: no cycle ever sees half of it.
A switch is validated in full before anything changes; in strict mode any problem refuses the whole switch,
in best-effort mode the failing controllers are dropped. If an ``on_activate`` raises mid-switch, everything the
switch did is rolled back (strict) or that controller alone is dropped (best effort).

**Chains** (ros2_control's chainable controllers; docs/controllers.md, "Chained controllers"). A controller loaded
with ``chain_to: F`` claims F's *reference interfaces* ``F/<joint>/<field>`` instead of the hardware's: its update
gets F's reference buffer (``F.references``) as its ``command``, so it needs no code of its own to be chained, and
F reads that buffer in its own update of the same cycle. The rules:

* update order: every controller chained to F runs before F, each cycle (the active list is kept in that order);
* a reference interface is an exclusive claim, like a hardware one, and all fields of one joint go to one claimant;
* a chained controller is activated only if F is active after the switch (already, or activated in the same
  switch, F first); deactivating F while a controller chained to it stays active is refused in strict mode, and
  takes that controller along in best effort; a switch activates and deactivates whole chains or nothing (strict);
* when F fails (or is stopped by an e-stop or an inactive component), the controllers chained to it are deactivated
  too: their joints are F's, and the supervisor holds them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import Controller, ControllerState
from hild.crossing.events import EventLog
from hild.interfaces import ClaimError, ClaimMasks, build_masks, check_claims, parse_interface
from hild.modes import Source


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
    chain_to: str = ""  # the controller whose reference interfaces it claims; "" for the hardware's
    references: tuple[str, ...] = ()  # the reference interfaces it exports, ``<name>/<joint>/<field>``
    state: ControllerState = ControllerState.UNCONFIGURED
    error: str = ""
    joint_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    output: ServoCommand | None = None  # where its update writes while active: its following controller's references
    chained_claims: frozenset[str] = frozenset()  # of its references, what active chained controllers claim
    source: int = -1  # its ``instance.source`` when the joints' sources were last worked out (-1: never)


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
    chain_to: str = ""
    references: tuple[str, ...] = ()  # the reference interfaces it exports (chainable when any)
    chained: bool = False  # an active controller claims some of its references

    def as_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "type": self.type,
            "state": self.state,
            "claimed": list(self.claimed),
            "error": self.error,
            "state_interfaces": list(self.reads),
            "chain_to": self.chain_to or None,
            "is_chainable": bool(self.references),
            "is_chained": self.chained,
            "reference_interfaces": list(self.references),
            "chain_connections": (
                [{"name": self.chain_to, "reference_interfaces": list(self.claimed)}] if self.chain_to else []
            ),
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
        self.active: list[ControllerRecord] = []  # the update order: chained ones before theirs, else load order
        self._chained_references: list[ServoCommand] = []  # the references of active controllers chained to
        self.masks = ClaimMasks.empty(len(self.joints))
        self.snapshot: tuple[ControllerInfo, ...] = ()
        self.change_seq = 0
        self.unavailable: dict[str, str] = {}  # interface → the inactive hardware component it belongs to
        self.reserved: dict[int, str] = {}  # joint → why no controller may claim it now (its drive homes it)
        self.on_claims: Callable[[ClaimMasks], None] = lambda masks: None  # the supervisor listens here
        # Per joint, who moves it (hild.modes.Source, as float64: the engine points this at its cycle-log row's
        # ``source`` view). Worked out at each switch and when an active controller's ``source`` changes.
        self.sources = np.zeros(len(self.joints))

    # ---- lifecycle ------------------------------------------------------------------------------------------
    def load(
        self, name: str, type_name: str, controller: Controller, fallbacks: Sequence[str] = (), chain_to: str = ""
    ) -> None:
        if name in self.records:
            raise SwitchError(f"controller {name!r} is already loaded")
        self.records[name] = self._record(self._slots, name, type_name, controller, fallbacks, chain_to)
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

    def replace(
        self, name: str, type_name: str, controller: Controller, fallbacks: Sequence[str] = (), chain_to: str = ""
    ) -> str:
        """Swap a loaded controller that is not active for a new instance (a reload), keeping its place in the
        update order. The new one is configured if the old one was; if that fails, the old one stays as it was.
        Returns the new one's state."""
        old = self._get(name)
        if old.state is ControllerState.ACTIVE:
            raise SwitchError(f"controller {name!r} is active; deactivate it before reloading it")
        record = self._record(old.slot, name, type_name, controller, fallbacks, chain_to)
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
        self,
        slot: int,
        name: str,
        type_name: str,
        controller: Controller,
        fallbacks: Sequence[str],
        chain_to: str = "",
    ) -> ControllerRecord:
        """A record for ``controller``, unconfigured; ClaimError if it claims what the drives do not offer (chained:
        its claims are ``chain_to``'s references, checked when it is switched on, where that one must be active)."""
        own = tuple(controller.claims())
        gravity = tuple(controller.gravity_joints())
        if stray := [j for j in gravity if f"{j}/effort" not in own]:
            raise ClaimError(
                f"{name}: gravity on top of its effort asked for on {stray}, whose effort it does not claim"
            )
        if chain_to == name:
            raise ClaimError(f"{name}: a controller cannot chain to itself")
        if chain_to:
            for claim in own:
                parse_interface(claim)
            if gravity:
                raise ClaimError(
                    f"{name}: chained to {chain_to}, it asks for gravity on top of its effort on {list(gravity)}; "
                    f"gravity is added to the effort {chain_to} sends (turn it off here)"
                )
            claims = tuple(f"{chain_to}/{c}" for c in own)
        else:
            check_claims(name, own, self.available)
            claims = own
        references = tuple(f"{name}/{r}" for r in controller.reference_interfaces())
        if references:
            buffer = controller.references
            if not isinstance(buffer, ServoCommand) or len(buffer) != len(self.joints):
                raise ClaimError(
                    f"{name}: it exports reference interfaces but its references are not a ServoCommand over the "
                    f"robot's {len(self.joints)} joints"
                )
            for reference in references:
                parse_interface(reference.removeprefix(f"{name}/"))
        return ControllerRecord(
            slot=slot,
            name=name,
            type=type_name,
            instance=controller,
            claims=claims,
            fallbacks=tuple(fallbacks),
            reads=tuple(controller.state_interfaces()),
            gravity=gravity,
            chain_to=chain_to,
            references=references,
            joint_index=self._joints_of(own),
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
            if rec.chain_to and self.records[rec.chain_to].state is not ControllerState.ACTIVE:
                dropped.append(rec.name)  # best effort: the controller it chains to did not start
                continue
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
        self._order()
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
        """What to stop and what to start (following controllers before those chained to them), or SwitchError."""
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
            elif self.reserved and (taken := [i for i in rec.joint_index.tolist() if i in self.reserved]):
                why = "; ".join(f"{self.joints[i]} {self.reserved[i]}" for i in taken)
                problems.append(f"{name} claims joints no controller may command now: {why}")
            elif rec.chain_to and rec.chain_to not in self.records:
                problems.append(f"{name} chains to {rec.chain_to!r}, which is not loaded")
            else:
                candidates.append(rec)
        # A following controller stopped while one chained to it stays active: refused, or taken along.
        for rec in list(to_stop):
            staying = [d for d in self._dependents(rec) if d not in to_stop]
            if staying and strict:
                names = [d.name for d in staying]
                problems.append(f"{rec.name} cannot be deactivated while {names} chain to it (deactivate them too)")
            elif staying:
                to_stop.extend(d for d in staying if d not in to_stop)
        if strict and problems:
            raise SwitchError("; ".join(problems))

        remaining = [r for r in self.active if r not in to_stop]
        to_start: list[ControllerRecord] = []
        for rec in sorted(candidates, key=self._depth):  # following controllers first
            trial = remaining + to_start + [rec]
            problem = self._chain_problem(rec, trial) or self._claims_problem(trial)
            if problem:
                if strict:
                    raise SwitchError(problem)
                continue
            to_start.append(rec)
        if not strict and not to_start and not to_stop and (activate or deactivate):
            raise SwitchError("nothing to switch: " + ("; ".join(problems) or "claims conflict"))
        return to_stop, to_start

    def _chain_problem(self, rec: ControllerRecord, trial: list[ControllerRecord]) -> str:
        """Why ``rec`` cannot run among ``trial`` (the active set after the switch), or "": a chained controller needs
        the one it chains to active, and claims only references that one exports."""
        if not rec.chain_to:
            return ""
        following = self.records[rec.chain_to]
        if following not in trial:
            return (
                f"{rec.name} chains to {following.name}, which would not be active after the switch "
                f"(activate {following.name} in the same switch, or first)"
            )
        if missing := [c for c in rec.claims if c not in following.references]:
            return f"{rec.name} claims {missing}, which {following.name} does not export"
        return ""

    def _claims_problem(self, trial: list[ControllerRecord]) -> str:
        """The first conflict among ``trial``'s claims, or "": hardware interfaces and reference interfaces alike are
        exclusive, and all fields of one joint (of the hardware, or of one controller's references) go to one."""
        try:
            self._hardware_masks(trial)
        except ClaimError as exc:
            return str(exc)
        taken: dict[tuple[str, str], str] = {}  # (following, joint) → the controller chained to it there
        for rec in trial:
            if not rec.chain_to:
                continue
            for claim in rec.claims:
                joint, _ = parse_interface(claim.removeprefix(f"{rec.chain_to}/"))
                other = taken.setdefault((rec.chain_to, joint), rec.name)
                if other != rec.name:
                    return f"{rec.chain_to}'s references of joint {joint} are claimed by both {other} and {rec.name}"
        return ""

    def _hardware_masks(self, records: Sequence[ControllerRecord]) -> ClaimMasks:
        """The hardware claims of ``records`` (chained ones claim references instead) as masks; ClaimError on a
        conflict."""
        direct = [r for r in records if not r.chain_to]
        return build_masks(
            self._joint_index,
            {r.slot: r.claims for r in direct},
            {r.slot: r.name for r in direct},
            {r.slot: r.gravity for r in direct},
        )

    def _dependents(self, rec: ControllerRecord) -> list[ControllerRecord]:
        """The active controllers chained to ``rec``, directly or through others (those nearest it last)."""
        found: list[ControllerRecord] = []
        frontier = [rec.name]
        while frontier:
            name = frontier.pop()
            for other in self.active:
                if other.chain_to == name and other not in found:
                    found.append(other)
                    frontier.append(other.name)
        return found[::-1]

    def _depth(self, rec: ControllerRecord) -> int:
        """How many controllers ``rec`` chains through to reach the hardware: 0 for one that commands it."""
        depth, hop, seen = 0, rec, {rec.name}
        while hop.chain_to and hop.chain_to in self.records and hop.chain_to not in seen:
            seen.add(hop.chain_to)
            hop = self.records[hop.chain_to]
            depth += 1
        return depth

    def _order(self) -> None:
        """The update order: every controller before the one it chains to, otherwise load order."""
        self.active.sort(key=lambda r: (-self._depth(r), r.slot))

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
        self._order()

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
        """Deactivate ``records`` and the controllers chained to them (their joints to hold) and recompute the
        claims once; their names."""
        for rec in list(records):
            records.extend(d for d in self._dependents(rec) if d not in records)
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
        """Every active controller's update, in the order of ``self.active``: a chained one writes into the
        references of the one it chains to (cleared here first), which runs after it in the same cycle."""
        command.written.fill(False)
        command.hold_effort.fill(0.0)
        for references in self._chained_references:
            references.written.fill(False)
        failed: list[tuple[ControllerRecord, BaseException]] | None = None
        sources_moved = False
        for rec in self.active:
            out = command if rec.output is None else rec.output
            try:
                rec.instance.update(t, dt, state, out)
                if rec.instance.source != rec.source:
                    sources_moved = True
            except Exception as exc:
                failed = failed or []
                failed.append((rec, exc))
                out.written[rec.joint_index] = False  # nothing it wrote this cycle is used
                out.hold_effort[rec.joint_index] = 0.0
        if sources_moved:
            self._work_out_sources()
        if failed:
            for rec, exc in failed:
                if rec.state is ControllerState.ACTIVE:  # not already taken along by a failed one it chains to
                    self.fail(rec, f"update raised {type(exc).__name__}: {exc}", state, command)

    def fail_slots(self, slots: Sequence[int], reason: str, state: JointState, command: ServoCommand) -> None:
        for rec in [r for r in self.active if r.slot in slots]:
            self.fail(rec, reason, state, command)

    def fail(self, rec: ControllerRecord, reason: str, state: JointState, command: ServoCommand) -> None:
        """Deactivate a failed controller and the controllers chained to it, hold its joints (they go unwritten), then
        start its fallbacks."""
        dependents = self._dependents(rec)
        self._deactivate(rec, ControllerState.FAILED)
        rec.error = reason
        for dependent in dependents:
            self._deactivate(dependent)
            dependent.error = f"deactivated: {rec.name}, which it chains to, failed ({reason})"
        self._apply_claims()
        joints = [self.joints[i] for i in rec.joint_index]
        along = f"; {[d.name for d in dependents]}, chained to it, deactivated too" if dependents else ""
        self.events.emit("error", rec.name, f"{reason}; deactivated, joints {joints} held{along}")
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
        """After every change of the active set: the supervisor's masks (hardware claims), where each chained
        controller writes, and what each chainable one learns of the controllers chained to it."""
        self.masks = self._hardware_masks(self.active)
        chained: dict[str, list[str]] = {}
        for rec in self.active:
            rec.output = None
            if rec.chain_to:
                following = self.records[rec.chain_to]
                rec.output = following.instance.references
                chained.setdefault(following.name, []).extend(rec.claims)
        self._chained_references = [
            r.instance.references for r in self.active if r.name in chained and r.instance.references is not None
        ]
        for rec in self.records.values():
            claims = frozenset(chained.get(rec.name, ())) if rec.state is ControllerState.ACTIVE else frozenset()
            if claims == rec.chained_claims:
                continue
            rec.chained_claims = claims
            self._tell_chained(rec, claims)
        self._work_out_sources()
        self.on_claims(self.masks)
        self._changed()

    def _work_out_sources(self) -> None:
        """Each joint's source: that of the controller at the head of the chain that moves it (a trajectory chained
        into an impedance controller is a trajectory), ``HOLD`` where no controller claims it. Rare: at a switch,
        or when a controller's source changes."""
        for rec in self.active:
            rec.source = int(rec.instance.source)
        by_slot = {rec.slot: rec for rec in self.active}
        for j, slot in enumerate(self.masks.owner.tolist()):
            rec = by_slot.get(slot)
            self.sources[j] = Source.HOLD if rec is None else self._head(rec, j).source

    def _head(self, rec: ControllerRecord, joint: int) -> ControllerRecord:
        """The controller at the head of the chain through ``rec`` on ``joint``."""
        seen = {rec.name}
        while True:
            up = next(
                (r for r in self.active if r.chain_to == rec.name and r.name not in seen and joint in r.joint_index),
                None,
            )
            if up is None:
                return rec
            rec = up
            seen.add(rec.name)

    def _tell_chained(self, rec: ControllerRecord, claims: frozenset[str]) -> None:
        """``rec.instance.set_chained`` with its claimed references as masks over the robot's joints (None: none)."""
        masks = None
        if claims:
            prefix = f"{rec.name}/"
            masks = build_masks(self._joint_index, {0: [c.removeprefix(prefix) for c in claims]}, {0: rec.name})
        try:
            rec.instance.set_chained(masks)
        except Exception as exc:  # a plugin's bug must not take the daemon down; it shows in its update
            self.events.emit("error", rec.name, f"set_chained raised {type(exc).__name__}: {exc}")

    def _changed(self) -> None:
        self.snapshot = tuple(
            ControllerInfo(
                r.slot,
                r.name,
                r.type,
                str(r.state),
                r.claims,
                r.error,
                r.reads,
                r.chain_to,
                r.references,
                bool(r.chained_claims),
            )
            for r in self.records.values()
        )
        self.change_seq += 1

    def _get(self, name: str) -> ControllerRecord:
        try:
            return self.records[name]
        except KeyError:
            known = ", ".join(self.records) or "none"
            raise SwitchError(f"unknown controller {name!r} (loaded: {known})") from None
