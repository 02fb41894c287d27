"""The crossing of one running robot: the shared region with the engine's cells, and the wake-up eventfd.

Carved once by the process that starts the cycle process (:meth:`Crossing.carve`); a client domain started later
(a restart) finds the same cells through an :class:`Attachment`, the numbers it is handed on its standard input.
The controllers' doors are carved from :attr:`Crossing.doors` by whoever builds their API halves.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hild.crossing.cells import REGION_BYTES, EngineCells
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region


@dataclass(frozen=True)
class Attachment:
    """How a client domain started by the daemon's main process finds the crossing it carved."""

    region_fd: int
    region_size: int
    wakeup_fd: int
    parent_pid: int  # the main process: when it is gone, so is the unit
    restarted_after: str | None = None  # why the previous client domain ended; None for the first


class Crossing:
    """``cycle_log``: the cycle log's capacity in rows (``hild.crossing.cyclelog.capacity_of``; 0: none)."""

    def __init__(self, region: Region, wakeup_fd: int, joints: int, *, create: bool, cycle_log: int = 0) -> None:
        self.region = region
        self.wakeup_fd = wakeup_fd
        self.doors = Shared(region, create=create)  # the controllers' doors: carved or found by name
        self.cells = EngineCells(region, joints, create=create, cycle_log=cycle_log)

    @classmethod
    def carve(cls, joints: int, cycle_log: int = 0) -> Crossing:
        wakeup = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        return cls(Region(REGION_BYTES), wakeup, joints, create=True, cycle_log=cycle_log)

    @classmethod
    def attach(cls, joints: int, at: Attachment, cycle_log: int = 0) -> Crossing:
        region = Region.attach(at.region_fd, at.region_size)
        return cls(region, at.wakeup_fd, joints, create=False, cycle_log=cycle_log)

    def attachment(self, parent_pid: int, restarted_after: str | None = None) -> Attachment:
        return Attachment(self.region.fd, self.region.size, self.wakeup_fd, parent_pid, restarted_after)
