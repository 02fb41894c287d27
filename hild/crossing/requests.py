"""Operator requests to the cycle, as typed records, and the one error type their refusals take.

A request is applied by the engine between two cycles (:meth:`hild.cycle.engine.Engine.apply`), in the daemon's own
process or across the shared region into the cycle process: so each is a small frozen value that pickles, never a
closure. Its answer is a reply dict; a request that is refused raises :class:`Refused`, whichever side it crosses.
"""

from __future__ import annotations

from dataclasses import dataclass
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


Request = Switch | Estop | Reset | Enable | SetZero
