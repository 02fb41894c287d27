"""The ``teach`` service: hand-guiding on and off for named joints (``hild ctl teach on|off [JOINTS]``).

``{"on": true, "joints": [...]}`` puts the joints (all by default) in teach mode: a ``teach`` controller named
``teach`` is loaded for them if none is (with the params of the config's ``teach`` controller, when it has one,
its joints replaced) and switched on in one switch that deactivates the controllers commanding those joints; the
reply names them. Joints the active teach controller already has are turned on through its ``teach`` input; a
wider set replaces it (its joints are released to hold first, then the new one is switched on). Refused under
e-stop and on a faulted joint.

``{"on": false, "joints": [...]}`` releases the joints (all in teach by default): each brakes to a stop, at most the
controller's ``release_time``, and is handed to hold where it stopped; once no joint is left in teach the controller
is switched off. The reply comes when the hand-over is done.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

from hild.api.fields import MAX_NAMES, Reply, RequestError, Service, boolean, required, sender
from hild.api.lifecycle import ControllerLifecycle
from hild.crossing.requests import Configure, Load, Request, Switch
from hild.daemon.link import CycleLink

TEACH = "teach"  # the controller's name and its type
POLL = 0.005  # s between looks at the snapshot while joints are handed to hold
SLACK = 1.0  # s beyond the controller's release_time before the service gives up waiting

OnCycle = Callable[[Request], Awaitable[Any]]


def joint_names(field: str, value: Any) -> list[str]:
    """A list of distinct joint names (checked against the robot by the service)."""
    if not isinstance(value, list) or len(value) > MAX_NAMES:
        raise RequestError(f"{field} must be a list of at most {MAX_NAMES} joint names")
    if not all(isinstance(v, str) and v for v in value):
        raise RequestError(f"{field} must contain non-empty joint names")
    if len(set(value)) != len(value):
        raise RequestError(f"{field} lists a joint twice: {value}")
    return value


def in_teach(snapshot: Any) -> list[str]:
    """The joints a teach controller commands now (released ones are held: not in teach)."""
    types = {c["name"]: c["type"] for c in snapshot.controllers}
    return [j["name"] for j in snapshot.joints if j["mode"] == "controlled" and types.get(j["owner"]) == TEACH]


class TeachService:
    def __init__(self, engine: CycleLink, on_cycle: OnCycle, lifecycle: ControllerLifecycle) -> None:
        self.engine = engine
        self.on_cycle = on_cycle
        self.lifecycle = lifecycle

    def services(self) -> dict[str, Service]:
        return {"teach": Service({"on": boolean, "joints": joint_names, "by": sender}, self._teach)}

    async def _teach(self, request: dict[str, Any]) -> Reply:
        on = required(request, "on")
        joints = request.get("joints") or []
        unknown = [j for j in joints if j not in self.engine.joints]
        if unknown:
            raise RequestError(f"unknown joints {unknown} (robot joints: {list(self.engine.joints)})")
        return await (self._on(joints, request.get("by")) if on else self._off(joints))

    # ---- on ---------------------------------------------------------------------------------------------------------
    async def _on(self, asked: list[str], by: str | None) -> Reply:
        snapshot = self.engine.snapshot()
        if snapshot.mode == "estop":
            raise RequestError("e-stop is engaged: reset first (hild ctl reset)")
        wanted = asked or list(self.engine.joints)
        faulted = [f"{j['name']} ({j['fault']})" for j in snapshot.joints if j["name"] in wanted and j["fault"]]
        if faulted:
            raise RequestError(f"faulted joints cannot be taught: {', '.join(faulted)}; reset first")
        record = self._record(snapshot)
        taught = self._joints_of(record)
        if record is not None and record["state"] == "active" and set(wanted) <= set(taught):
            self._half().set_teach(dict.fromkeys(wanted, True))
            # Through its input: answer once the cycle shows them in teach, so the reply (and whatever the client
            # asks next, e.g. a wider set built from the joints in teach) sees what the arm does.
            return {"teach": await self._taught(wanted), "deactivated": [], "loaded": False}
        joints = self._order(set(wanted) | (set(in_teach(snapshot)) if record is not None else set()))
        released: list[str] = []
        if record is not None and record["state"] == "active":  # a wider set: hand the old one's joints to hold
            released = await self._release(self._joints_of(record))
            await self._switch((), (TEACH,))
        await self._load(joints, replaces=record is not None, by=by)
        snapshot = self.engine.snapshot()
        mine = {f"{j}/" for j in joints}
        conflicting = tuple(
            c["name"]
            for c in snapshot.controllers
            if c["state"] == "active" and c["name"] != TEACH and any(i.startswith(tuple(mine)) for i in c["claimed"])
        )
        await self._switch((TEACH,), conflicting)
        # Once the cycle shows them in teach: a request right after this reply (teach off for one of them) reads the
        # snapshot, and one from before the switch would show none of them in teach.
        taught = await self._taught(joints)
        return {"teach": taught, "deactivated": list(conflicting), "loaded": True, "released": released}

    async def _load(self, joints: list[str], *, replaces: bool, by: str | None) -> None:
        section = self.engine.loaded.config.controllers.get(TEACH)
        params = dict(section.params) if section is not None and section.type == TEACH else {}
        params["joints"] = joints
        loaded = {c["name"] for c in self.engine.snapshot().controllers} - {TEACH}
        checked = self.lifecycle.checked(TEACH, {"type": TEACH, "params": params}, loaded, "teach")
        load = Load(TEACH, TEACH, checked.params, replaces=replaces, source=f"by {by or 'a client'} (teach on)")
        reply = dict(await self.on_cycle(load))
        if reply.get("state") == "unconfigured":
            await self.on_cycle(Configure(TEACH))

    # ---- off --------------------------------------------------------------------------------------------------------
    async def _off(self, asked: list[str]) -> Reply:
        snapshot = self.engine.snapshot()
        record = self._record(snapshot)
        if record is None or record["state"] != "active":
            if asked:
                raise RequestError(f"no joint is in teach (asked to release {asked})")
            return {"teach": [], "released": [], "deactivated": []}
        taught = self._joints_of(record)
        stray = [j for j in asked if j not in taught]
        if stray:
            raise RequestError(f"{stray} are not in teach (teach controller joints: {taught})")
        released = await self._release(asked or taught)
        left = in_teach(self.engine.snapshot())
        deactivated: list[str] = []
        if not left:
            await self._switch((), (TEACH,))
            deactivated = [TEACH]
        return {"teach": left, "released": released, "deactivated": deactivated}

    async def _release(self, joints: list[str]) -> list[str]:
        """Have the teach controller brake ``joints`` to a stop and hand them to hold; return once all are held."""
        half = self._half()
        half.set_teach(dict.fromkeys(joints, False))
        deadline = time.monotonic() + float(half.params.release_time) + SLACK
        while set(joints) & set(in_teach(self.engine.snapshot())):
            if time.monotonic() > deadline:
                raise RequestError(f"{joints} were not handed to hold in time; is the cycle running?")
            await asyncio.sleep(POLL)
        return joints

    async def _taught(self, joints: list[str]) -> list[str]:
        """The joints in teach once ``joints`` are among them (the cycle took the teach controller's input)."""
        deadline = time.monotonic() + SLACK
        while not set(joints) <= set(taught := in_teach(self.engine.snapshot())):
            if time.monotonic() > deadline:
                raise RequestError(f"{joints} did not go into teach in time; is the cycle running?")
            await asyncio.sleep(POLL)
        return taught

    # ---- helpers ----------------------------------------------------------------------------------------------------
    async def _switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        reply = dict(await self.on_cycle(Switch(activate, deactivate, True)))
        if not reply.get("ok", True):
            raise RequestError(f"teach: {reply.get('error')}")

    def _record(self, snapshot: Any) -> dict[str, Any] | None:
        record = next((dict(c) for c in snapshot.controllers if c["name"] == TEACH), None)
        if record is not None and record["type"] != TEACH:
            raise RequestError(f"a controller named {TEACH!r} of type {record['type']} is loaded: unload it first")
        return record

    def _joints_of(self, record: dict[str, Any] | None) -> list[str]:
        if record is None:
            return []
        return self._order({c.split("/")[0] for c in record["claimed"]})

    def _half(self) -> Any:
        half = self.engine.controllers().get(TEACH)
        if half is None or not hasattr(half, "set_teach"):
            raise RequestError("the teach controller is not loaded here")
        return half

    def _order(self, joints: set[str]) -> list[str]:
        return [j for j in self.engine.joints if j in joints]
