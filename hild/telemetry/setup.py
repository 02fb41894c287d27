"""What the recorder process is told about the robot: one picklable value, shared by the daemon side and the worker.

In a module of its own so the worker (the recorder process) and the daemon side (``recorder``) both import it
without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hild.config.model import TelemetrySection


@dataclass(frozen=True)
class TelemetrySetup:
    """What telemetry needs to know about the robot (built from the config by ``Telemetry.from_config``)."""

    robot: str
    joints: tuple[str, ...]
    update_rate: float
    section: TelemetrySection
    directory: Path  # relative sink paths start here (the config file's directory)
    model: Path | None = None  # MJCF/URDF for the 3D view
    avoid_cpus: tuple[int, ...] = ()  # the cycle thread's CPUs: the recorder runs elsewhere when it can
    keep_existing: bool = False  # a restarted client domain's: the file its crashed predecessor wrote is kept
