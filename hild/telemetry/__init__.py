"""rerun telemetry (DESIGN.md §1): the cycle writes a ring in shared memory, a recorder process sends it to rerun.

rerun-sdk is imported only in this package, and only in the recorder process (``worker``, ``outlets``, ``arm3d``,
``layout``, ``replay``). ``tap``, ``recorder`` and ``errors`` import no rerun, so the daemon never loads it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hild.telemetry.errors import TelemetryError
from hild.telemetry.tap import SharedRing, TelemetryRows, TelemetryTap

if TYPE_CHECKING:
    from hild.telemetry.recorder import Telemetry, TelemetrySetup

__all__ = ["SharedRing", "Telemetry", "TelemetryError", "TelemetryRows", "TelemetrySetup", "TelemetryTap"]


def __getattr__(name: str) -> Any:
    if name in ("Telemetry", "TelemetrySetup"):
        from hild.telemetry import recorder

        return getattr(recorder, name)
    raise AttributeError(name)
