"""``hild ctl pub``'s loop: one sample per period to a controller input, until the duration ends, Ctrl-C, or the
daemon reports that it dropped one.

Samples follow an absolute schedule (sample ``k`` is due at ``start + k / rate`` and carries ``t = k / rate``), so
the rate does not drift with the time each send takes; a loop that falls behind (a stall, a loaded machine) skips
to the latest due sample instead of sending a burst of stale ones. Nothing is sent to stop: the controller's
``command_timeout`` (cycle clock) hands its joints back to the supervisor, which holds them (forward_command), or
brakes them to a stop and holds (servo).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

from hild.api.client import HildClient
from hild.api.expressions import Expression, ExpressionError, values_at
from hild.api.stream_inputs import StreamInput

MIN_RATE, MAX_RATE = 5.0, 1000.0  # Hz: below, a 0.5 s command_timeout is too close; above, the sleep is the jitter
Stopped = Literal["duration", "interrupted", "refused", "expression"]


def check_rate(rate: float, duration: float | None) -> None:
    """Refuse rates and durations that make no sense on an arm (ValueError with the reason)."""
    if not MIN_RATE <= rate <= MAX_RATE:  # NaN fails too
        raise ValueError(
            f"--rate {rate:g} Hz is outside {MIN_RATE:g}–{MAX_RATE:g} Hz (the controller returns to hold after its "
            "command_timeout without a sample, 0.5 s by default; the daemon's cycle takes only the newest)"
        )
    if duration is not None and not (0.0 < duration < math.inf):
        raise ValueError(f"--duration {duration:g} must be a positive number of seconds")


@dataclass
class PubResult:
    sent: int = 0
    skipped: int = 0  # due samples not sent because the loop was late
    seconds: float = 0.0
    stopped: Stopped = "duration"
    error: str | None = None  # why it stopped early: the daemon's drop warning or the failing expression

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.error is None, **asdict(self), "seconds": round(self.seconds, 3)}


def stream(
    client: HildClient, target: StreamInput, expressions: Sequence[Expression], rate: float, duration: float | None
) -> PubResult:
    """Stream until ``duration`` (None: until Ctrl-C), a drop warning for this input, or a value that fails."""
    key = client.keys.input(target.controller, target.input)
    refused = threading.Event()
    result = PubResult()

    def on_event(message: dict[str, Any]) -> None:
        text = str(message.get("message", ""))
        if text.startswith(f"dropped command on {key}:") and not refused.is_set():
            result.error = f"the daemon dropped a sample: {text}"
            refused.set()

    total = math.ceil(duration * rate - 1e-9) if duration is not None else None  # samples due before the end
    with client.subscribe("events", on_event):
        start = time.monotonic()
        try:
            k = 0
            while total is None or k < total:
                wait = start + k / rate - time.monotonic()
                if wait > 0:
                    if refused.wait(wait):
                        break
                else:
                    due = int((time.monotonic() - start) * rate)  # the latest sample whose time has come
                    if total is not None:
                        due = min(due, total - 1)
                    if due > k:
                        result.skipped += due - k
                        k = due
                if refused.is_set():
                    break
                client.put(target.controller, target.payload(values_at(expressions, k / rate)), input=target.input)
                result.sent += 1
                k += 1
            else:
                refused.wait(max(0.0, start + k / rate - time.monotonic()))  # the last sample's period
        except KeyboardInterrupt:
            result.stopped = "interrupted"
        except ExpressionError as exc:
            result.stopped, result.error = "expression", str(exc)
        result.seconds = time.monotonic() - start
    if refused.is_set():
        result.stopped = "refused"
    return result
