"""Latencies across processes: a Zenoh command → the first CAN frame carrying it; a CAN reply → its joint_states.

Both ends are stamped on ``perf_counter_ns`` (CLOCK_MONOTONIC, one clock for the whole machine), the client's in
this process, the frames' by the bench rig: in the daemon's process on the virtual bus, or in the rig's own process
when the loop serving the loopback bridge reads them (``hild.bench.rigs.can_process``). ``hop_latencies`` splits the
way into its hops (tools/command_hops.py).

**Command → frame.** With ``forward_position`` active, the bench publishes targets whose first joint alternates
between two positions ``delta`` apart (a few position LSBs, below one cycle's slew limit); the others hold. Each
publish is stamped just before the put. Its latency is the time to the first command frame for that motor whose
decoded position is within ``tol`` of the value. A probe whose value the frames already carried at publish time
would be ambiguous and is skipped; probes are spaced several cycles apart at random, so they do not lock to the
cycle's phase.

**Reply → sample.** Every ``joint_states`` sample carries the control clock of the cycle that read it: the cycle
time ``t`` less the stalls the control clock skipped (``lag``, known from the period errors); with the cycle
clock's zero in ``perf_counter_ns`` (``start``), that cycle woke at ``start + stamp + lag``. The reply it
reflects is the motor's last reply sent before that wake (or one sent in the few µs between wake and read, when
only that one carries the sample's value). Latency = arrival at the subscriber − that reply's send. It excludes
the wait for the broadcaster's next sample (uniform in 0 … 1/publish_rate).
"""

from __future__ import annotations

import bisect
import itertools
import random
import time
from collections.abc import Sequence
from typing import Any

from hild.api.client import HildClient
from hild.bench.window import lag_at

WARMUP_COMMANDS = 5
HOPS = ("put → accept", "accept → adopt", "adopt → send", "send → frame", "put → frame")
READ_AFTER_WAKE_NS = 100_000  # a reply this soon after the wake may still be the one the read took


def send_probes(
    client: HildClient,
    controller: str,
    base: Sequence[float],
    delta: float,
    count: int,
    gap: tuple[float, float],
    rng: random.Random,
) -> list[tuple[int, float]]:
    """Publish ``count`` alternating targets (first joint ``base[0] + delta``, then ``base[0]``, …) ``gap`` s
    apart (uniform in the range); returns (publish perf_counter_ns, first joint's value) for each."""
    values = [float(v) for v in base]
    for _ in range(WARMUP_COMMANDS):  # the controller starts from base, so frames carry base before probe 0
        client.send(controller, values)
        time.sleep(gap[0])
    probes = []
    for k in range(count):
        values[0] = float(base[0]) + (delta if k % 2 == 0 else 0.0)
        stamp = time.perf_counter_ns()
        client.send(controller, values)
        probes.append((stamp, values[0]))
        time.sleep(rng.uniform(*gap))
    return probes


def match_commands(
    probes: Sequence[tuple[int, float]], frames: Sequence[Sequence[float]], tol: float
) -> tuple[list[int], int]:
    """Latency (ns) of each probe to the first frame carrying its value; also how many were ambiguous."""
    times = [int(f[0]) for f in frames]
    latencies: list[int] = []
    ambiguous = 0
    for stamp, value in probes:
        i = bisect.bisect_left(times, stamp)
        if i > 0 and abs(frames[i - 1][1] - value) <= tol:
            ambiguous += 1
            continue
        for t, position in frames[i:]:
            if abs(position - value) <= tol:
                latencies.append(int(t) - stamp)
                break
    return latencies, ambiguous


def first_carrying(
    stamps: Sequence[tuple[int, float]], times: Sequence[int], after: int, value: float, tol: float
) -> int | None:
    """The time of the first stamp at or after ``after`` whose value is within ``tol`` of ``value``."""
    for t, v in stamps[bisect.bisect_left(times, after) :]:
        if abs(v - value) <= tol:
            return t
    return None


def value_edges(stamps: Sequence[tuple[int, float]], tol: float) -> list[tuple[int, float]]:
    """The stamps of a stream sent every cycle (frames) where its value changes: where a new command shows."""
    out: list[tuple[int, float]] = []
    for t, v in stamps:
        if not out or abs(v - out[-1][1]) > tol:
            out.append((t, v))
    return out


def hop_latencies(
    probes: Sequence[tuple[int, float]],
    chain: Sequence[Sequence[tuple[int, float]]],
    tol: float,
    every_cycle: Sequence[bool] = (False, False, True, True),
) -> tuple[dict[str, list[int]], int]:
    """Per hop (``HOPS``) the latencies (ns) of the probes that reached every stamp of ``chain`` (accept, adopt,
    send, frame: each a time-ordered [(perf_counter_ns, first joint's value)]); also how many did not.

    A probe's stamp at a hop is the first one carrying its value at or after its stamp at the hop before, and
    after the previous matched probe's stamp at that hop (each hop is first in, first out). Streams stamped
    ``every_cycle`` (the sends, the frames) count only where their value changes, so a frame still carrying the
    probe before last does not pass for this one. Probes alternate between two values: a stamp later than the put
    of the probe after next could be either's, so such a probe counts as not matched, and the last two probes
    (no probe after next to bound them) are not judged (tools/command_hops.py)."""
    streams = [value_edges(s, tol) if edge else list(s) for s, edge in zip(chain, every_cycle, strict=True)]
    times = [[t for t, _ in stamps] for stamps in streams]
    out: dict[str, list[int]] = {hop: [] for hop in HOPS}
    last = [-1] * len(streams)
    lost = 0
    for k, (put, value) in enumerate(probes[:-2]):
        bound = probes[k + 2][0]
        at = [put]
        for i, (stamps, ts) in enumerate(zip(streams, times, strict=True)):
            t = first_carrying(stamps, ts, max(at[-1], last[i] + 1), value, tol)
            if t is None or t >= bound:
                break
            at.append(t)
        if len(at) < len(streams) + 1:
            lost += 1
            continue
        last = at[1:]
        for hop, (a, b) in zip(HOPS, itertools.pairwise(at), strict=False):  # the last hop is the whole way
            out[hop].append(b - a)
        out["put → frame"].append(at[-1] - at[0])
    return out, lost


def match_replies(
    samples: Sequence[tuple[int, float, float]],
    replies: Sequence[Sequence[float]],
    start_ns: int,
    tol: float,
    lag_history: Sequence[Sequence[float]] = (),
) -> tuple[list[int], int]:
    """Latency (ns) from the reply each sample reflects to the sample's arrival; also how many found no reply
    carrying their value (samples = (arrival ns, control-clock stamp s, first joint's position)). The stamp is the
    control clock, which lags the cycle clock by the stalls it skipped: ``lag_history`` [(control time, lag ns) …]
    (``hild.bench.window.lag_at``)."""
    times = [int(r[0]) for r in replies]
    history = [(float(when), int(value)) for when, value in lag_history]
    latencies: list[int] = []
    unmatched = 0
    for arrived, stamp, position in samples:
        wake = start_ns + round(stamp * 1e9) + lag_at(history, stamp)
        i = bisect.bisect_left(times, wake) - 1
        candidates = [j for j in (i, i + 1) if 0 <= j < len(times) and times[j] < wake + READ_AFTER_WAKE_NS]
        chosen = next((j for j in candidates if abs(replies[j][1] - position) <= tol), None)
        if chosen is None or times[chosen] > arrived:
            unmatched += 1
            continue
        latencies.append(arrived - times[chosen])
    return latencies, unmatched


class SampleLog:
    """A joint_states subscription callback keeping (arrival perf_counter_ns, stamp, first joint's position)."""

    def __init__(self) -> None:
        self.samples: list[tuple[int, float, float]] = []

    def __call__(self, message: dict[str, Any]) -> None:
        self.samples.append((time.perf_counter_ns(), float(message["stamp"]), float(message["position"][0])))
