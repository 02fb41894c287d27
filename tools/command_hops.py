#!/usr/bin/env python3
"""Where a Zenoh command's time goes on its way to the CAN wire, hop by hop (docs/performance.md, "The command
path: the 195 ms finding").

    python tools/command_hops.py                        # both layouts, 300 probes each
    python tools/command_hops.py --layout split --stock-bridge   # the bridge as before the fix
    python tools/command_hops.py --gil                  # also the bridge alone, beside busy Python threads or not

Runs the bench's can6@1000 scenario (``hild.bench.scenarios``) with ``forward_position`` active and publishes the
bench's latency probes (``hild.bench.latency.send_probes``), every process tapped by ``hild.bench.command_taps``
(a ``sitecustomize`` on ``PYTHONPATH``; hild itself unchanged). Hops, each stamped on ``perf_counter_ns``
(CLOCK_MONOTONIC, one clock for the machine), each the first stamp after the previous one that carries the
probe's value:

  put     the bench's ``client.send`` (this process)
  accept  forward_command's input callback in the daemon's client domain
  adopt   the cycle's ``LatestNumbers.take`` (the crossing; the cycle process, or the cycle thread)
  send    the cycle's ``CanLink.send`` of the first motor's command frame
  frame   the emulated drive reads it off its bus (the rig: its own process across the loopback bridge, or the
          daemon's process on the virtual bus)

Layouts: ``split`` — the cycle in a process of its own, the drives across the loopback bridge (can6@1000);
``virtual`` — the cycle a thread of the daemon, the drives on its in-process virtual bus (can6@1000-virtual).
``--gil``: frames at 1 kHz through each loopback server alone (``hild.bench.rigs.bridge_stall``), with 0 and 3
CPU-bound Python threads beside it: the mechanism, without hild.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.bench.command_taps import ENV, SITECUSTOMIZE, read_stamps
from hild.bench.floor import run_probe
from hild.bench.latency import hop_latencies, send_probes
from hild.bench.report import summarize_ns
from hild.bench.scenarios import FORWARD, PROBE_DELTA_LSB, PROBE_TOL_LSB, Scenario, Settings, open_session

LAYOUTS = {
    "split": Scenario("can6", "can", 6, 1000.0),
    "virtual": Scenario("can6", "can", 6, 1000.0, virtual_bus=True),
}
WARMUP_S = 1.0
ZENOH_PINGS = 1000  # the floor's Zenoh probe before each layout: put → accept less this is the daemon's share
LINGER_S = 0.6  # s after the last probe: the taps flush every 0.25 s


def decoder(joints: int) -> Any:
    """Decode the first motor's 8-byte command to its position, as the rig does (its wiring and ranges)."""
    from drivers.can.params import MitCanParams
    from drivers.can.protocol.mit import decode_command
    from drivers.can.wiring import wire_motors
    from hild.bench.rigs.mit_can import robot_config

    bus1 = robot_config(joints, 1000.0)["hardware"]["bus1"]
    wiring, problems = wire_motors(MitCanParams.model_validate(bus1["params"]), list(bus1["joints"]))
    assert not problems, problems
    ranges = wiring[0].ranges
    return lambda hexed: float(decode_command(bytes.fromhex(hexed), ranges).p)


def measure(layout: str, probes: int, stock: bool, seed: int) -> dict[str, Any]:
    scenario = LAYOUTS[layout]
    settings = Settings.make(False, None, None, stock_bridge=stock)
    settings.latency_probes = probes
    with tempfile.TemporaryDirectory(prefix="hild-hops-") as tmp:
        work, taps, site = Path(tmp), Path(tmp) / "stamps", Path(tmp) / "site"
        taps.mkdir()
        site.mkdir()
        (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
        saved = {k: os.environ.get(k) for k in (ENV, "PYTHONPATH")}
        os.environ[ENV] = str(taps)
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), saved["PYTHONPATH"]) if p)
        try:
            with open_session(scenario, work, settings) as s:
                s.client.switch(activate=[FORWARD])
                time.sleep(WARMUP_S)
                base = list(s.client.next_message("joint_states", timeout=5.0)["position"])
                lsb = float(s.host.request("listen", on=True)["lsb"])
                sent = send_probes(
                    s.client, FORWARD, base, PROBE_DELTA_LSB * lsb, probes, settings.probe_gap, random.Random(seed)
                )
                time.sleep(LINGER_S)
                frames = s.host.request("listen", on=False, timeout=120.0)
                bus = s.host.bridged and ("stock server" if s.host.stock_bridge else "rig process")
        finally:
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
        stamps = read_stamps(taps)
    decode = decoder(scenario.joints)
    chain = [
        stamps["accept"],
        stamps["adopt"],
        [(t, decode(data)) for t, data in stamps["send"]],
        [(int(t), float(p)) for t, p in frames["command"]],
    ]
    hops, lost = hop_latencies(sent, chain, PROBE_TOL_LSB * lsb)
    return {
        "layout": layout,
        "scenario": scenario.name,
        "bus": f"loopback bridge ({bus})" if bus else "virtual (in-process)",
        "probes": len(sent),
        "judged": max(0, len(sent) - 2),  # hild.bench.latency.hop_latencies: the last two are not
        "unmatched": lost,
        "hops_us": {hop: summarize_ns(v) for hop, v in hops.items()},
    }


def gil_rows(frames: int) -> list[str]:
    from hild.bench.rigs.bridge_stall import run_bridge

    rows = [f"{'server':<40} {'busy':>4} {'≤5 ms':>7} {'p50 µs':>9} {'p99 µs':>10} {'max µs':>10}"]
    for kind, busy in (("stock", 0), ("stock", 3), ("loop", 0), ("loop", 3)):
        run = run_bridge(kind, busy, frames)
        figures = summarize_ns([d for d in run.delays_ns if d is not None])
        name = "python-can-remote RemoteServer" if kind == "stock" else "RemoteServerBus in the drives' loop"
        rows.append(
            f"{name:<40} {busy:>4} {run.within(0.005):>4}/{frames} {figures['p50']:>9.0f} {figures['p99']:>10.0f}"
            f" {figures['max']:>10.0f}"
        )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--layout", choices=[*LAYOUTS, "both"], default="both")
    parser.add_argument("--probes", type=int, default=300)
    parser.add_argument("--stock-bridge", action="store_true", help="split: the bridge as before the fix")
    parser.add_argument("--gil", action="store_true", help="also the loopback servers alone, with busy threads")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    layouts = list(LAYOUTS) if args.layout == "both" else [args.layout]
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs")
    for layout in layouts:
        floor = run_probe("zenoh", count=ZENOH_PINGS, puts=ZENOH_PINGS)
        if "error" not in floor:
            f = floor["put_to_subscriber_us"]
            print(f"\nZenoh floor just before (put → subscriber): p50 {f['p50']:.0f} µs, p99 {f['p99']:.0f} µs")
        result = measure(layout, args.probes, args.stock_bridge, args.seed)
        print(
            f"\n{result['scenario']} — {result['bus']}: {result['probes']} probes, {result['judged']} judged, "
            f"{result['unmatched']} unmatched (a stamp missing, or later than the put of the probe after next)"
        )
        print(f"{'hop':<16} {'p50 µs':>9} {'p99 µs':>10} {'max µs':>10} {'n':>5}")
        for hop, f in result["hops_us"].items():
            print(f"{hop:<16} {f['p50']:>9.0f} {f['p99']:>10.0f} {f['max']:>10.0f} {f['n']:>5}")
    if args.gil:
        print("\nthe loopback server alone, 1000 frames at 1 kHz (delay = client send → the drive loop has it)")
        with contextlib.suppress(KeyboardInterrupt):
            print("\n".join(gil_rows(1000)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
