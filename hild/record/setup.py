"""What the recorder process is told: one picklable value, built in the client domain from the config.

In a module of its own so the worker (the recorder process) and its handle (``recorder``) both import it without
importing each other. Nothing here imports ``mcap`` or ``pyarrow``.
"""

from __future__ import annotations

import hashlib
import platform
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from hild.record.model import BLACKBOX_DIR

# On the event queue to the recorder process, an item of this kind is no event: it carries the controllers' owner
# codes as they are now (a controller loaded during an episode gets a code; its commands topic needs the name).
CODES = "_controller_codes"

# Recorded in every episode's metadata, as installed (absent ones are left out).
VERSIONED = ("hild", "numpy", "mujoco", "mcap", "mcap-ros2-support", "rosbags", "pyarrow", "eclipse-zenoh")


def versions() -> dict[str, str]:
    """The versions of Python and of what writes or shapes a recording (read from the installed metadata, so
    nothing is imported for it)."""
    found = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def file_sha256(path: Path) -> str:
    """The SHA-256 of the config file as it is now ('' when it cannot be read)."""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return ""


@dataclass(frozen=True)
class RecorderSetup:
    """The robot and the ``recording:`` section, resolved (``directory`` is absolute)."""

    robot: str
    joints: tuple[str, ...]
    update_rate: float
    directory: Path  # recording.dir, relative paths resolved beside the config file
    chunk_period: float = 0.1  # s: one MCAP chunk per period, flushed
    fsync: bool = True
    min_free_mb: float = 200.0  # MiB: below it an episode stops, and none starts
    blackbox_seconds: float = 10.0
    fps: float = 30.0  # an episode's frame rate unless its start says otherwise
    config_path: str = ""
    config_sha256: str = ""
    versions: dict[str, str] = field(default_factory=dict)
    avoid_cpus: tuple[int, ...] = ()  # the cycle's CPUs: the recorder runs elsewhere when it can

    @classmethod
    def from_config(cls, loaded: Any) -> RecorderSetup:
        cfg = loaded.config
        sec = cfg.recording
        directory = Path(sec.dir).expanduser()
        if not directory.is_absolute():
            directory = loaded.directory / directory
        return cls(
            robot=cfg.robot.name,
            joints=tuple(cfg.joints),
            update_rate=float(cfg.update_rate),
            directory=directory.resolve(),
            chunk_period=float(sec.chunk_period),
            fsync=bool(sec.fsync),
            min_free_mb=float(sec.min_free_mb),
            blackbox_seconds=float(sec.blackbox_seconds),
            fps=float(sec.fps),
            config_path=str(Path(loaded.path).resolve()),
            config_sha256=file_sha256(Path(loaded.path)),
            versions=versions(),
            avoid_cpus=tuple(cfg.realtime.cpu_affinity),
        )

    @property
    def blackbox_directory(self) -> Path:
        return self.directory / BLACKBOX_DIR
