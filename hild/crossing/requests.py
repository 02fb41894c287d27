"""Operator requests to the cycle, as typed records, and the one error type their refusals take.

A request is applied by the engine between two cycles (:meth:`hild.cycle.engine.Engine.apply`), in the daemon's own
process or across the shared region into the cycle process: so each is a small frozen value that pickles, never a
closure. Its answer is a reply dict; a request that is refused raises :class:`Refused`, whichever side it crosses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


class Refused(RuntimeError):
    """The cycle did not do what was asked. ``details`` are the reply's other fields (kept on the wire as before,
    e.g. a refused reset answers ``"cleared": []``)."""

    def __init__(self, reason: str, **details: Any) -> None:
        super().__init__(reason)
        self.details = details


@dataclass(frozen=True, slots=True)
class Switch:
    activate: tuple[str, ...] = ()
    deactivate: tuple[str, ...] = ()
    strict: bool = True


@dataclass(frozen=True, slots=True)
class Estop:
    """Never queued behind other requests: it has its own path to the cycle (``request_estop``)."""


@dataclass(frozen=True, slots=True)
class Reset:
    pass


@dataclass(frozen=True, slots=True)
class Enable:
    joints: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SetZero:
    joint: str


@dataclass(frozen=True, slots=True)
class Home:
    """Start the drive's own homing of a held, still joint (``hild ctl home``). It takes seconds, longer than a
    request may wait for its reply: the reply says it started, the status's ``homing`` and the events how it ends."""

    joint: str


@dataclass(frozen=True, slots=True)
class SetHardwareState:
    """An operator takes a hardware component out of the controllers' reach (``inactive``: still read, its joints
    held by the supervisor, its command interfaces unavailable) or gives it back (``active``)."""

    name: str
    state: str


@dataclass(frozen=True, slots=True)
class Load:
    """Load a controller, unconfigured (ros2_control's ``load_controller``), from params the client domain validated.

    ``doors``: the prefix of its cells in the shared region, chosen by whoever builds its API half (empty: the name,
    as for the controllers the config lists). ``replaces``: swap it for the loaded controller of the same name, which
    must not be active (a reload); the new one is configured if the old one was, and nothing changes if it fails."""

    name: str
    type: str
    params: Any  # the controller type's validated ``Params``
    fallbacks: tuple[str, ...] = ()
    doors: str = ""
    replaces: bool = False
    keeps_fallbacks: bool = False  # a replacement keeps the fallbacks of the one it replaces (new parameters)
    chain_to: str = ""  # the chainable controller whose reference interfaces it claims (config: ``chain_to``)
    source: str = field(default="", compare=False)  # for the event: "from <file>", "by <user@host>"


@dataclass(frozen=True, slots=True)
class Configure:
    """``on_configure``: unconfigured → inactive; an inactive one is cleaned up and configured again."""

    name: str


@dataclass(frozen=True, slots=True)
class Cleanup:
    """``on_cleanup``: inactive → unconfigured (ros2_control's ``cleanup_controller``); it stays loaded."""

    name: str


@dataclass(frozen=True, slots=True)
class Unload:
    """Clean up (if configured) and forget a controller that is not active."""

    name: str


@dataclass(frozen=True, slots=True)
class SetParams:
    """New values of a controller's dynamic parameters, validated by the client domain: set in both halves between
    two cycles. ``changes`` (``path: old → new``) and ``by`` are for the event that records who changed what."""

    name: str
    params: Any  # the controller type's whole, validated ``Params``
    changes: tuple[str, ...] = ()
    by: str = "a client"


# Applied after a cycle's write, one per cycle: a controller's own code never delays a command.
LifecycleRequest = Load | Configure | Cleanup | Unload | SetParams
Request = Switch | Estop | Reset | Enable | SetZero | Home | SetHardwareState | LifecycleRequest
