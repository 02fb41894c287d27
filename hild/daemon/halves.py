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
from collections.abc import Callable, Iterable
from typing import Any

from hild import plugins
from hild.config.loader import LoadedConfig
from hild.controller import Controller, ControllerContext, JointLimitArrays
from hild.crossing.mailboxes import Mailboxes, Shared
from hild.crossing.requests import Load

Emit = Callable[[str, str, str], None]  # (level, source, message)


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
        update_rate=cfg.update_rate,
        emit_event=lambda level, message, source=load.name: emit(level, source, message),
        notify=lambda: None,  # the API half writes no output: the cycle half does, and rings
        mailboxes=mailboxes.scoped(load.doors or load.name),
    )
    return cls(context, params)


def api_halves(loaded: LoadedConfig, loads: Iterable[Load], mailboxes: Mailboxes, emit: Emit) -> dict[str, Controller]:
    """Every controller of ``loads``, built for its API half; ``emit`` takes their events."""
    return {load.name: api_half(loaded, load, mailboxes, emit) for load in loads}


class ApiHalves:
    """The client domain's controllers (their API halves) and the prefixes of their cells, kept in step with the
    cycle's loads and unloads: a load's half is built (its cells carved) before the cycle is asked, and kept only
    if the cycle loaded it; an unloaded or replaced controller's half goes, and its cells' pages are given back.
    ``seq`` moves with every change, so the API re-declares its endpoints (``change_seq``)."""

    def __init__(self, loaded: LoadedConfig, loads: Iterable[Load], doors: Shared, emit: Emit) -> None:
        self.loaded = loaded
        self._doors = doors
        self._emit = emit
        loads = list(loads)
        self._halves = api_halves(loaded, loads, doors, emit)
        self._prefixes = {load.name: load.doors or load.name for load in loads}
        self._lock = threading.Lock()  # the loop answers replies; the API's threads read the halves
        self.seq = 0

    def current(self) -> dict[str, Controller]:
        with self._lock:
            return dict(self._halves)

    def prepare(self, load: Load) -> tuple[Load, Controller]:
        """Carve cells of their own for ``load`` and build its API half: the load the cycle is to apply (with
        those cells' prefix), and the half. Raises with the reason if the half cannot be built."""
        region = self._doors.region
        doors = f"{load.name}@{len(region.cells())}"  # never used before: the directory only grows
        load = dataclasses.replace(load, doors=doors)
        try:
            return load, api_half(self.loaded, load, self._doors.carving(), self._emit)
        except Exception:
            region.release(f"{doors}/")
            raise

    def loaded_one(self, load: Load, half: Controller, future: concurrent.futures.Future[Any]) -> None:
        """The cycle answered ``load``: keep its half (and drop the one it replaced), or give its cells back."""
        if future.cancelled() or future.exception() is not None:
            self._doors.region.release(f"{load.doors}/")
            return
        with self._lock:
            replaced = self._prefixes.get(load.name) if load.replaces else None
            self._halves[load.name] = half
            self._prefixes[load.name] = load.doors
            self.seq += 1
        if replaced is not None:
            self._doors.region.release(f"{replaced}/")

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
            self.seq += 1
        if prefix is not None:
            self._doors.region.release(f"{prefix}/")
