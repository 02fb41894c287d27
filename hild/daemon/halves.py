"""The API halves of a robot's controllers, for a client domain whose cycle runs in another process.

Each controller is built here as in the cycle process, from the same :class:`~hild.crossing.requests.Load` (its
type, validated params and the prefix of its cells), with mailboxes that are cells of the shared region: its
``inputs()`` and action server validate and plan in this process and put the prepared result into the cells, where
the cycle process's instance of the same controller takes it. Nothing here steps a controller: ``update`` and the
lifecycle run only in the cycle process, whose controller manager sets the ``active`` flag both halves read.

Where the loads come from: the config, for the first client domain (its builder carves their cells before the
cycle process starts); the cycle's ``loads`` cell, for one started later (a restart finds the cells, including
those of controllers loaded while the robot ran); a load request, for one loaded now (this process carves).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from hild import plugins
from hild.arrays import MimicJoints, SensorView
from hild.config.loader import LoadedConfig
from hild.controller import Controller, ControllerContext, JointGainArrays, JointLimitArrays
from hild.crossing.mailboxes import Mailboxes, Shared
from hild.crossing.region import RegionError
from hild.crossing.requests import Load
from hild.interfaces import SensorLayout

Emit = Callable[[str, str, str], None]  # (level, source, message)
REUSE_AFTER = 1.0  # s before given-back cells serve another load: the API withdraws what read them within ms


def configured_loads(loaded: LoadedConfig) -> list[Load]:
    """The controllers the config lists, as the loads the cycle process makes of them at start-up."""
    return [
        Load(name, spec.type, loaded.controller_params[name], tuple(spec.fallback_controllers))
        for name, spec in loaded.config.controllers.items()
    ]


def api_half(loaded: LoadedConfig, load: Load, mailboxes: Mailboxes, emit: Emit) -> Controller:
    """One controller built for its API half; ``mailboxes`` carve its cells or find them (``load.doors``)."""
    cfg = loaded.config
    cls = plugins.load(plugins.CONTROLLERS, load.type)
    params = load.params if isinstance(load.params, cls.Params) else cls.Params.model_validate(load.params)
    context = ControllerContext(
        robot=cfg.robot.name,
        name=load.name,
        joints=tuple(cfg.joints),
        limits=JointLimitArrays.of(cfg),
        gains=JointGainArrays.of(cfg),
        update_rate=cfg.update_rate,
        emit_event=lambda level, message, source=load.name: emit(level, source, message),
        notify=lambda: None,  # the API half writes no output: the cycle half does, and rings
        sensors=SensorView(SensorLayout.of(cfg)),  # names and frames; the values live in the cycle half only
        mailboxes=mailboxes.scoped(load.doors or load.name),
        mimic_joints=MimicJoints.of(cfg),
    )
    return cls(context, params)


def api_halves(loaded: LoadedConfig, loads: Iterable[Load], mailboxes: Mailboxes, emit: Emit) -> dict[str, Controller]:
    """Every controller of ``loads``, built for its API half; ``emit`` takes their events."""
    return {load.name: api_half(loaded, load, mailboxes, emit) for load in loads}


class ApiHalves:
    """The client domain's controllers (their API halves) and the prefixes of their cells, kept in step with the
    cycle's loads and unloads: a load's half is built (its cells carved) before the cycle is asked, and kept only
    if the cycle loaded it; an unloaded or replaced controller's half goes, and its cells' pages are given back.
    ``seq`` moves with every change, so the API re-declares its endpoints (``change_seq``).

    Cells given back are used again: the region's directory only grows (8192 cells), and a test rig that loads and
    unloads a controller every second would fill it in hours. A later load of the same type takes a given-back
    prefix whose cells fit its doors (found by name and size, zeros again after ``release``), once the API has had
    ``REUSE_AFTER`` to withdraw the endpoints that read them."""

    def __init__(self, loaded: LoadedConfig, loads: Iterable[Load], doors: Shared, emit: Emit) -> None:
        self.loaded = loaded
        self._doors = doors
        self._emit = emit
        loads = list(loads)
        self._halves = api_halves(loaded, loads, doors, emit)
        self._prefixes = {load.name: load.doors or load.name for load in loads}
        self._types = {load.name: load.type for load in loads}
        self._free: dict[str, list[tuple[float, str]]] = {}  # type → (when given back, prefix)
        self._lock = threading.Lock()  # the loop answers replies; the API's threads read the halves
        self.seq = 0

    def current(self) -> dict[str, Controller]:
        with self._lock:
            return dict(self._halves)

    def prepare(self, load: Load) -> tuple[Load, Controller]:
        """Cells for ``load`` (given back ones that fit, else carved anew) and its API half: the load the cycle is
        to apply (with those cells' prefix), and the half. Raises with the reason if the half cannot be built."""
        reused = self._reuse(load)
        if reused is not None:
            return reused
        region = self._doors.region
        doors = f"{load.name}@{len(region.cells())}"  # never used before: the directory only grows
        load = dataclasses.replace(load, doors=doors)
        try:
            return load, api_half(self.loaded, load, self._doors.carving(), self._emit)
        except Exception:
            self._give_back(load.type, doors)
            raise

    def _reuse(self, load: Load) -> tuple[Load, Controller] | None:
        now = time.monotonic()
        with self._lock:
            free = self._free.get(load.type, [])
            ready = [entry for entry in free if now - entry[0] >= REUSE_AFTER]
        for entry in ready:
            candidate = dataclasses.replace(load, doors=entry[1])
            try:
                half = api_half(self.loaded, candidate, self._doors.finding(), self._emit)
            except RegionError:  # its doors are of other sizes (other params): not these cells
                continue
            with self._lock:
                free.remove(entry)
            return candidate, half
        return None

    def _give_back(self, type_name: str, prefix: str) -> None:
        self._doors.region.release(f"{prefix}/")
        with self._lock:
            self._free.setdefault(type_name, []).append((time.monotonic(), prefix))

    def loaded_one(self, load: Load, half: Controller, future: concurrent.futures.Future[Any]) -> None:
        """The cycle answered ``load``: keep its half (and drop the one it replaced), or give its cells back."""
        if future.cancelled() or future.exception() is not None:
            self._give_back(load.type, load.doors)
            return
        with self._lock:
            replaced = self._prefixes.get(load.name) if load.replaces else None
            replaced_type = self._types.get(load.name, load.type)
            self._halves[load.name] = half
            self._prefixes[load.name] = load.doors
            self._types[load.name] = load.type
            self.seq += 1
        if replaced is not None:
            self._give_back(replaced_type, replaced)

    def params_set(self, name: str, params: Any, future: concurrent.futures.Future[Any]) -> None:
        """The cycle took new parameters for ``name``: its API half takes them too (it plans and validates)."""
        if future.cancelled() or future.exception() is not None:
            return
        with self._lock:
            half = self._halves.get(name)
        if half is not None:
            half.set_params(params)

    def unloaded(self, name: str, future: concurrent.futures.Future[Any]) -> None:
        """The cycle answered an unload of ``name``: if it was unloaded, its half goes and its cells are given back."""
        if future.cancelled() or future.exception() is not None:
            return
        with self._lock:
            self._halves.pop(name, None)
            prefix = self._prefixes.pop(name, None)
            type_name = self._types.pop(name, "")
            self.seq += 1
        if prefix is not None:
            self._give_back(type_name, prefix)
