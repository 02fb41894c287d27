"""The one telemetry exception, in a module of its own so the client domain can raise it without loading rerun."""

from __future__ import annotations


class TelemetryError(RuntimeError):
    """A sink that cannot open, a recorder process that cannot start, or one that stopped answering."""
