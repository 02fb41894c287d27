"""rerun telemetry: the cycle writes a ring in shared memory, a recorder process sends it to rerun
(docs/architecture.md, "Three processes").

rerun-sdk is imported only in this package, and only in the recorder process (``worker``, ``outlets``, ``arm3d``,
``layout``, ``replay``). The ring and the tap that writes it each cycle are in :mod:`hild.crossing.telemetry`;
``recorder`` (the client domain's side), ``setup`` and ``errors`` import no rerun, so the daemon never loads it.
"""

from __future__ import annotations

from hild.telemetry.errors import TelemetryError
from hild.telemetry.recorder import Telemetry
from hild.telemetry.setup import TelemetrySetup

__all__ = ["Telemetry", "TelemetryError", "TelemetrySetup"]
