"""``hild bench``: run the floor and every scenario in one run, print the table, optionally write JSON.

    hild bench                          # everything, ~4 min on 2 cores
    hild bench --quick                  # everything, short windows (~1 min; indicative only)
    hild bench --only floor 'twin6*' --seconds 5 --json bench.json

Order: machine facts and load average; the floor (empty thread, Zenoh, python-can, mj_step); the scenarios one
after the other (never two daemons at once); the interference windows; targets from all of it. Names for
``--only`` (shell-style patterns): ``floor``, ``interference``, ``mock6@500`` … ``can6@1000`` and
``twin6@500-nospin``, ``can6@500-nospin``, ``can6@1000-virtual`` (or a base name such as ``can6`` for all of its).
Every scenario runs with the cycle in a process of its own (the emulated CAN drives in a process of theirs, reached
over loopback; ``--stock-can-bridge``: beside the daemon as before [teleop]) but ``can6@1000-virtual`` (the cycle a
thread of the daemon, the drives on its in-process virtual bus); ``--one-process`` runs them all as before, the
cycle a thread of the daemon.
Two sections run only when named, after the rest: ``motion`` (tracking on the lockstep twin, goal acceptance and
servo latency over Zenoh: ``hild.bench.motion``) and ``soak`` (``hild run`` on the twin at 1 kHz under random
goals, servo streams and faults for 3 min, ``--quick`` 20 s, or ``--seconds``: ``hild.bench.soak``), and
``contact`` (the [contact] targets on the emulated Damiao arm6 in lockstep, group ``contact`` in the targets:
``hild.bench.contact``; ``--quick`` a smoke run, ``--seconds`` the no-false-positive run's sim time), and ``record``
(what recording costs the cycle: twin6@1000 with recording off and with an episode open, ``hild.bench.record``),
``teleop`` (leader–follower between two twin daemons through a delaying, dropping relay, group ``teleop``:
``hild.bench.teleop``), and ``chunks`` (a synthetic policy's action chunks into the servo vs JTC-style upsampling on
the lockstep twin, group ``teleop`` in the targets: ``hild.bench.chunks``; ``--quick`` 5 s of chunks, ``--seconds``
the sim time).
See docs/performance.md for what each figure means.
"""

from __future__ import annotations

import argparse
import datetime as dt
import fnmatch
import importlib
import os
import platform
import shlex
import sys
import tempfile
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from hild.bench.floor import measure_empty_threads, run_probe
from hild.bench.report import busy, evaluate_targets, format_report, write_json
from hild.bench.scenarios import (
    ARM6,
    INTERFERENCE,
    SCENARIOS,
    Settings,
    other_cpus,
    run_interference,
    run_scenario,
)
from hild.config.model import RealtimeSection

PACKAGES = ("hild", "numpy", "eclipse-zenoh", "python-can", "mujoco", "ruckig", "rerun-sdk", "pydantic")
FLOOR_RATES = (500.0, 1000.0)
SECTIONS = ("floor", *(s.name for s in SCENARIOS), "interference")
NAMED_ONLY = ("motion", "soak", "contact", "record", "teleop", "chunks")  # not in a whole run: motion, endurance, …
SOAK_SECONDS = 180.0
SOAK_QUICK_SECONDS = 20.0


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bench",
        help="measure the real-time cycle against this machine's floor (table + JSON)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--quick", action="store_true", help="short windows: a smoke run, not numbers to quote")
    parser.add_argument("--seconds", type=float, help="counted seconds per scenario window (default 10, quick 1.5)")
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="NAME",
        help=f"run only these ({', '.join(SECTIONS)}; and, only when named, {', '.join(NAMED_ONLY)})",
    )
    parser.add_argument("--json", type=Path, metavar="OUT.json", help="also write the whole report as JSON")
    parser.add_argument(
        "--priority", type=int, help="SCHED_FIFO priority for every cycle thread (default: the config's, i.e. off)"
    )
    parser.add_argument(
        "--spin-us",
        type=int,
        metavar="US",
        help="realtime.spin_us for every cycle thread, floor included (default: the config's, 200)",
    )
    parser.add_argument(
        "--cpu-dma-latency",
        type=int,
        metavar="US",
        help="realtime.cpu_dma_latency_us for the daemon and the floor (default: the config's, off)",
    )
    parser.add_argument(
        "--one-process",
        action="store_true",
        help="run every scenario with the cycle as a thread of the daemon (before [rt-split]), not in its own process",
    )
    parser.add_argument(
        "--can-remote",
        action="store_true",
        help="with --one-process: serve the emulated CAN channels over loopback as the cycle-process mode must "
        "(same bus medium in both modes)",
    )
    parser.add_argument(
        "--stock-can-bridge",
        action="store_true",
        help="bridged CAN scenarios as before [teleop]: the emulated drives in the daemon's process behind "
        "python-can-remote's stock server (its per-client threads share the daemon's GIL), for before/after figures",
    )
    parser.add_argument(
        "--cycle-cpu",
        type=int,
        metavar="CPU",
        help="give the cycle (and the floor's empty thread) this CPU and keep the daemon's client domain and the "
        "bench's own load off it (realtime.cpu_affinity / client_cpu_affinity), as on a robot PC",
    )
    parser.add_argument(
        "--keep", type=Path, metavar="DIR", help="keep each scenario's config, daemon log and recording in DIR"
    )
    parser.set_defaults(func=run)


def selected(only: list[str] | None) -> list[str]:
    """The sections ``--only`` names (all but ``NAMED_ONLY`` by default); a pattern matches a name or a scenario's
    base name, a ``NAMED_ONLY`` section only its exact name."""
    if not only:
        return list(SECTIONS)
    chosen = []
    for name in SECTIONS:
        base = name.split("@")[0]
        if any(fnmatch.fnmatch(name, p) or fnmatch.fnmatch(base, p) for p in only):
            chosen.append(name)
    return chosen + [name for name in NAMED_ONLY if name in only]


def machine_info() -> dict[str, Any]:
    model = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    packages = {}
    for name in PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            packages[name] = None
    return {
        "cpu_count": os.cpu_count(),
        "cpu_model": model,
        "kernel": platform.release(),
        "preempt_rt": "PREEMPT_RT" in platform.version() or Path("/sys/kernel/realtime").exists(),
        "python": platform.python_version(),
        "packages": packages,
        "load_average": {"before": round(os.getloadavg()[0], 2)},
    }


def measure_floor(settings: Settings) -> dict[str, Any]:
    realtime = RealtimeSection(**settings.realtime())
    floor: dict[str, Any] = {}
    try:
        floor["empty_thread"] = measure_empty_threads(list(FLOOR_RATES), settings.floor_seconds, realtime)
    except Exception as exc:
        floor["empty_thread"] = []
        floor["empty_thread_error"] = f"{type(exc).__name__}: {exc}"
    floor["zenoh"] = run_probe("zenoh", count=settings.zenoh_pings, puts=settings.zenoh_puts)
    floor["can_virtual"] = run_probe("can_virtual", count=settings.can_frames)
    floor["mj_step"] = run_probe("mj_step", count=settings.mj_steps, config=str(ARM6))
    return floor


def progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def bench(settings: Settings, sections: list[str], workdir: Path) -> dict[str, Any]:
    started = time.monotonic()
    report: dict[str, Any] = {
        "bench": {
            "command": shlex.join(["hild", *sys.argv[1:]]),
            "started": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%SZ"),
            "quick": settings.quick,
            "sections": sections,
            "settings": {k: v for k, v in vars(settings).items()},
        },
        "machine": machine_info(),
        "floor": {},
        "scenarios": [],
        "latency": [],
        "cpu": [],
        "interference": {},
        "targets": [],
    }
    if "floor" in sections:
        progress("floor: empty thread, Zenoh, python-can, mj_step …")
        report["floor"] = measure_floor(settings)
    for scenario in SCENARIOS:
        if scenario.name not in sections:
            continue
        progress(f"{scenario.name} …")
        try:
            row, latency = run_scenario(scenario, workdir, settings)
        except Exception as exc:
            report["scenarios"].append(
                {"name": scenario.name, "base": scenario.base, "rate_hz": scenario.rate, "error": str(exc)}
            )
            continue
        report["scenarios"].append(row)
        report["machine"].setdefault("realtime", row["realtime"])
        report["cpu"].append({"scenario": scenario.name, "rate_hz": scenario.rate, **row["cpu"]})
        if latency is not None:
            report["latency"].append(latency)
    if "interference" in sections:
        progress(f"interference ({INTERFERENCE.name}) …")
        try:
            report["interference"] = run_interference(workdir, settings)
        except Exception as exc:
            report["interference"] = {"scenario": INTERFERENCE.name, "error": str(exc)}
    for name in NAMED_ONLY:
        if name in sections:
            progress(f"{name} …")
            try:
                report[name] = run_named(name, settings)
            except Exception as exc:
                report[name] = {"error": f"{type(exc).__name__}: {exc}"}
    report["machine"]["load_average"]["after"] = round(os.getloadavg()[0], 2)
    report["machine"]["busy"] = busy(report["machine"])
    report["bench"]["seconds_total"] = round(time.monotonic() - started, 1)
    report["targets"] = evaluate_targets(report) if set(sections) & set(SECTIONS) else []  # none for motion, soak
    for name in ("contact", "record", "teleop", "chunks"):  # their own groups of targets
        report["targets"] += report.get(name, {}).get("targets", [])
    return report


def run_named(name: str, settings: Settings) -> dict[str, Any]:
    """A ``NAMED_ONLY`` section's report (imported here: ``hild`` starts without them)."""
    if name == "motion":
        from hild.bench.motion import MotionSettings, run_motion

        return run_motion(MotionSettings.quick() if settings.quick else MotionSettings())
    if name == "contact":
        from hild.bench.contact import ContactSettings, run_contact

        return run_contact(ContactSettings.make(settings.quick, settings.seed, settings.soak_seconds))
    if name == "record":
        from hild.bench.record import run_record

        return run_record(settings)
    if name == "teleop":
        from hild.bench.teleop import TeleopSettings, run_teleop

        return run_teleop(TeleopSettings.make(settings.quick, settings.seed))
    if name == "chunks":
        from hild.bench.chunks import ChunkSettings, run_chunks

        return run_chunks(ChunkSettings.make(settings.quick, settings.seed, settings.soak_seconds))
    from hild.bench.soak import run_soak

    seconds = settings.soak_seconds or (SOAK_QUICK_SECONDS if settings.quick else SOAK_SECONDS)
    return run_soak(seconds).as_dict()


# Each named section's formatter (module, function), in the order they print; imported only when it ran.
NAMED_FORMATTERS = {
    "motion": ("hild.bench.motion", "format_motion"),
    "contact": ("hild.bench.contact", "format_contact"),
    "record": ("hild.bench.record", "format_record"),
    "teleop": ("hild.bench.teleop", "format_teleop"),
    "chunks": ("hild.bench.chunks", "format_chunks"),
}


def format_named(report: dict[str, Any]) -> list[str]:
    """The ``NAMED_ONLY`` sections' text, one entry each that ran."""
    texts = []
    for name, (module, function) in NAMED_FORMATTERS.items():
        if name not in report:
            continue
        section = report[name]
        if "error" in section:
            texts.append(f"{name.upper()} error: {section['error']}")
        else:
            texts.append(getattr(importlib.import_module(module), function)(section))
    if "soak" in report:
        from hild.bench.soak import Report

        soak = report["soak"]
        texts.append(f"SOAK error: {soak['error']}" if "error" in soak else Report.from_dict(soak).text())
    return texts


def run(args: argparse.Namespace) -> int:
    if args.seconds is not None and args.seconds <= 0:
        print("--seconds must be positive", file=sys.stderr)
        return 2
    if args.priority is not None and not 0 <= args.priority <= 99:
        print("--priority must be 0..99", file=sys.stderr)
        return 2
    sections = selected(args.only)
    if not sections:
        print(f"--only matches nothing (names: {', '.join(SECTIONS)})", file=sys.stderr)
        return 2
    if args.spin_us is not None and not 0 <= args.spin_us <= 10_000:
        print("--spin-us must be 0..10000", file=sys.stderr)
        return 2
    if args.cpu_dma_latency is not None and args.cpu_dma_latency < 0:
        print("--cpu-dma-latency must be 0 or more", file=sys.stderr)
        return 2
    if args.cycle_cpu is not None:
        cpus = os.sched_getaffinity(0)
        if args.cycle_cpu not in cpus or len(cpus) < 2:
            print(f"--cycle-cpu must be one of this process's CPUs {sorted(cpus)}, with another left", file=sys.stderr)
            return 2
        os.sched_setaffinity(0, other_cpus(args.cycle_cpu))  # the bench's clients and processes inherit it
    settings = Settings.make(
        args.quick,
        args.seconds,
        args.priority,
        args.spin_us,
        args.cpu_dma_latency,
        cycle_process=not args.one_process,
        can_remote=args.can_remote,
        cycle_cpu=args.cycle_cpu,
        stock_bridge=args.stock_can_bridge,
    )
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        report = bench(settings, sections, args.keep.resolve())
    else:
        with tempfile.TemporaryDirectory(prefix="hild-bench-") as tmp:
            report = bench(settings, sections, Path(tmp))
    print("\n\n".join([format_report(report), *format_named(report)]))
    if args.json:
        write_json(report, args.json)
        print(f"\n(JSON written to {args.json})")
    failed = [r["name"] for r in report["scenarios"] if r.get("error")]
    if "error" in report["interference"]:
        failed.append("interference")
    failed += [name for name in NAMED_ONLY if "error" in report.get(name, {})]
    if "soak" in report and not report["soak"].get("passed", False):
        failed.append("soak")
    return 1 if failed else 0
