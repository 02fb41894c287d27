"""``hild record``: recorded episodes offline: list, export to LeRobot, view in rerun, recover, replay.

  hild record list [DIR]                                 episodes under a recordings directory
  hild record export --lerobot OUT [--fps F] [--source S]… EPISODE…   add episodes to a LeRobotDataset v3.0
  hild record view EPISODE [--save FILE.rrd]             open an episode in rerun, or save it as .rrd
  hild record recover [EPISODE|DIR …]                    close episodes a crash left open
  hild record replay EPISODE [--yes-on-hardware] [--speed S]   send the recorded path back to the arm

An EPISODE is an episode's directory (or its .mcap file, or its id under ./recordings). DIR defaults to
./recordings, the config's default ``recording.dir`` when hild runs from the config's directory.
Everything but ``replay`` works on files alone; ``replay`` talks to the running daemon (``--robot``, ``--connect``,
``--zenoh-config`` as for ``hild ctl``; the robot defaults to the episode's).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hild.modes import SOURCE_NAMES
from hild.record import locks
from hild.record.model import EPISODE_JSON, Episode, EpisodeMeta, RecordError, mcap_name

DEFAULT_DIR = Path("recordings")
LIVE_SECONDS = 2.0  # an open episode whose file changed this recently may still be written: recover skips it

EXIT_OK, EXIT_FAILED, EXIT_UNREACHABLE = 0, 1, 2


def load_episode(directory: Path) -> Episode:
    """Read an episode back (``hild.record.mcap_files``, imported only when an episode is read)."""
    from hild.record.mcap_files import read_episode

    return read_episode(directory)


def resolve_episode(arg: str) -> Path:
    """An episode's directory from what the user typed: the directory, its .mcap or episode.json, or an id."""
    path = Path(arg)
    if path.is_file():
        path = path.parent
    if not path.exists() and not path.is_absolute() and (DEFAULT_DIR / arg).exists():
        path = DEFAULT_DIR / arg
    if not (path / EPISODE_JSON).is_file():
        raise RecordError(f"{arg}: not an episode (no {EPISODE_JSON} in {path})")
    return path


def episode_dirs(root: Path) -> list[Path]:
    """Episode directories directly under ``root``, oldest first (their ids start with the UTC start time)."""
    if not root.is_dir():
        raise RecordError(f"{root}: no such directory")
    return sorted(p for p in root.iterdir() if (p / EPISODE_JSON).is_file())


def summary(directory: Path) -> dict[str, Any]:
    """What ``list`` shows of an episode, from its ``episode.json`` alone."""
    meta = EpisodeMeta.read(directory)
    if meta.stopped_wall is not None:
        duration: float | None = meta.stopped_wall - meta.started_wall
    elif meta.cycles and meta.update_rate:
        duration = meta.cycles / meta.update_rate
    else:
        duration = None
    return {
        "id": meta.id,
        "state": meta.state,
        "task": meta.task,
        "cycles": meta.cycles,
        "duration": duration,
        "dropped": meta.dropped,
        "directory": str(directory.absolute()),
    }


# ---- verbs ---------------------------------------------------------------------------------------------------
def _list(args: argparse.Namespace) -> int:
    rows = [summary(d) for d in episode_dirs(Path(args.dir))]
    if args.json:
        print(json.dumps(rows, indent=2))
        return EXIT_OK
    if not rows:
        print(f"no episodes in {args.dir}")
        return EXIT_OK
    table = [["ID", "STATE", "CYCLES", "DURATION", "TASK"]]
    for r in rows:
        duration = "?" if r["duration"] is None else f"{r['duration']:.2f} s"
        table.append([r["id"], r["state"], str(r["cycles"]), duration, r["task"] or ""])
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    return EXIT_OK


SOURCE_CODES = {name: code for code, name in SOURCE_NAMES.items()}  # what --source takes: hold, trajectory, …


def _export(args: argparse.Namespace) -> int:
    from hild.record.lerobot import DEFAULT_TASK, export_lerobot

    episodes = [load_episode(resolve_episode(e)) for e in args.episodes]
    for e in episodes:
        if e.meta.state == "recording":
            print(
                f"hild record: {e.meta.id} was never closed (still 'recording'): exporting the {len(e.rows)} cycles "
                "its file holds; `hild record recover` closes it",
                file=sys.stderr,
            )
    sources = [SOURCE_CODES[name] for name in args.source] if args.source else None
    report = export_lerobot(
        episodes, Path(args.lerobot), args.fps, default_task=args.task or DEFAULT_TASK, sources=sources
    )
    if args.json:
        print(
            json.dumps(
                {
                    "ok": True,
                    "out": str(report.out),
                    "fps": report.fps,
                    "episodes": [vars(e) for e in report.episodes],
                    "total_episodes": report.total_episodes,
                    "total_frames": report.total_frames,
                    "files": [str(f) for f in report.files],
                },
                indent=2,
            )
        )
        return EXIT_OK
    for e in report.episodes:
        print(f"{e.id}: episode {e.episode_index}, {e.frames} frames ({e.duration:.2f} s at {report.fps} fps)")
    print(f"{report.out}: {report.total_episodes} episodes, {report.total_frames} frames")
    return EXIT_OK


def _model_of(meta: EpisodeMeta) -> Path | None:
    """The arm model for the 3D view, from the config the episode was recorded with, if it is still there."""
    try:
        from hild.config import load_config

        loaded = load_config(meta.config_path)
    except Exception:
        return None
    model = loaded.config.robot.model
    return loaded.directory / model if model else None


def _view(args: argparse.Namespace) -> int:
    from hild.telemetry.episode_view import save_episode, show_episode

    episode = load_episode(resolve_episode(args.episode))
    model = None if args.no_arm else _model_of(episode.meta)
    if args.save:
        path = save_episode(episode, Path(args.save), model)
        print(f"{episode.meta.id}: {len(episode.rows)} cycles written to {path}")
    else:
        show_episode(episode, model)
        print(f"{episode.meta.id}: {len(episode.rows)} cycles sent to a new rerun viewer")
    return EXIT_OK


def _recover(args: argparse.Namespace) -> int:
    from hild.record.mcap_files import recover

    targets: list[Path] = []
    for arg in args.paths or [str(DEFAULT_DIR)]:
        path = Path(arg)
        if (path / EPISODE_JSON).is_file() or path.is_file():
            targets.append(resolve_episode(arg))  # named: recovered whatever its state
        else:
            targets += [d for d in episode_dirs(path) if EpisodeMeta.read(d).state == "recording"]
    status = EXIT_OK
    reports: list[dict[str, Any]] = []
    for directory in targets:
        if locks.in_use(directory):  # a live recorder holds it: never, not even with --force
            print(f"{directory}: a running recorder is writing it; skipped")
            status = EXIT_FAILED
            continue
        mcap = directory / mcap_name(directory.name)
        if mcap.exists() and time.time() - mcap.stat().st_mtime < LIVE_SECONDS and not args.force:
            print(f"{directory}: written less than {LIVE_SECONDS:g} s ago, maybe still recording; skipped (--force)")
            status = EXIT_FAILED
            continue
        try:
            report = recover(directory)
        except (RecordError, OSError, ValueError) as exc:
            print(f"{directory}: {exc}", file=sys.stderr)
            status = EXIT_FAILED
            continue
        reports.append({"directory": str(directory), "report": _jsonable(report)})
        if not args.json:
            print(f"{directory}: {_jsonable(report)}")
    if args.json:
        print(json.dumps(reports, indent=2, default=str))
    elif not targets:
        print("nothing to recover")
    return status


def _jsonable(report: Any) -> Any:
    if hasattr(report, "__dataclass_fields__"):
        return {k: getattr(report, k) for k in report.__dataclass_fields__}
    return report


def _replay(args: argparse.Namespace) -> int:
    from hild.api.client import HildError, HildUnreachable
    from hild.api.ctl import ZENOH_CONFIG_ENV
    from hild.api.session import DEFAULT_CONNECT, SessionConfigError, file_endpoints
    from hild.record.replay import replay

    episode = load_episode(resolve_episode(args.episode))
    zenoh_config = args.zenoh_config or os.environ.get(ZENOH_CONFIG_ENV) or None
    try:
        connect = args.connect or (zenoh_config and file_endpoints(zenoh_config)) or DEFAULT_CONNECT
        client = _client(args.robot or episode.meta.robot, list(connect), args.timeout, zenoh_config)
    except (HildUnreachable, SessionConfigError) as exc:
        print(f"hild record: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE
    try:
        result = replay(
            client,
            episode,
            speed=args.speed,
            controller=args.controller,
            on_hardware=args.yes_on_hardware,
            start_tolerance=args.start_tolerance,
            move_to_start=args.move_to_start,
            say=lambda text: print(text, file=sys.stderr),
        )
    except HildUnreachable as exc:
        print(f"hild record: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE
    except HildError as exc:
        print(f"hild record: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:  # closing the client withdraws its presence: the controller stops the goal
        print("hild record: replay interrupted; the goal is stopped", file=sys.stderr)
        return EXIT_FAILED
    finally:
        client.close()
    print(json.dumps(result, indent=2) if args.json else f"replay {result.get('status')}: {result}")
    return EXIT_OK if result.get("status") == "succeeded" else EXIT_FAILED


def _client(robot: str, connect: list[str], timeout: float, zenoh_config: str | None) -> Any:
    from hild.api.client import HildClient

    return HildClient(robot, connect, timeout, zenoh_config=zenoh_config)


VERBS: dict[str, Callable[[argparse.Namespace], int]] = {
    "list": _list,
    "export": _export,
    "view": _view,
    "recover": _recover,
    "replay": _replay,
}


def run(args: argparse.Namespace) -> int:
    try:
        return VERBS[args.record_command](args)
    except RecordError as exc:
        if getattr(args, "json", False):
            print(json.dumps({"ok": False, "error": str(exc)}))
        else:
            print(f"hild record: {exc}", file=sys.stderr)
        return EXIT_FAILED


def register(subparsers: Any) -> None:
    """``hild record`` (the ``hild.commands`` entry point)."""
    cmd = subparsers.add_parser(
        "record",
        help="recorded episodes: list, export to LeRobot, view in rerun, recover, replay",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    verbs = cmd.add_subparsers(dest="record_command", metavar="VERB", required=True)
    as_json = argparse.ArgumentParser(add_help=False)
    as_json.add_argument("--json", action="store_true", help="machine-readable output")

    listing = verbs.add_parser("list", parents=[as_json], help="episodes under a recordings directory")
    listing.add_argument("dir", nargs="?", default=str(DEFAULT_DIR), metavar="DIR")

    export = verbs.add_parser("export", parents=[as_json], help="add episodes to a LeRobotDataset v3.0")
    export.add_argument("--lerobot", required=True, metavar="OUT", help="the dataset's directory (created or added to)")
    export.add_argument("--fps", type=float, help="frames per second (default: the fps the episodes were recorded for)")
    export.add_argument("--task", metavar="TEXT", help="the task of episodes recorded without one")
    export.add_argument(
        "--source",
        action="append",
        choices=sorted(SOURCE_CODES),
        help="keep only frames whose every joint this source moved (repeat for several; e.g. --source leader "
        "--source hold: the teleoperated part); each run of such frames becomes an episode",
    )
    export.add_argument("episodes", nargs="+", metavar="EPISODE")

    view = verbs.add_parser("view", help="open an episode in rerun, or save it as an .rrd file")
    view.add_argument("episode", metavar="EPISODE")
    view.add_argument("--save", metavar="FILE.rrd", help="write this file instead of opening a viewer")
    view.add_argument("--no-arm", action="store_true", help="no 3D arm (default: drawn when the config's model loads)")

    recover = verbs.add_parser("recover", parents=[as_json], help="close episodes a crash left open")
    recover.add_argument("paths", nargs="*", metavar="EPISODE|DIR", help=f"default: {DEFAULT_DIR}")
    recover.add_argument("--force", action="store_true", help="also episodes whose file changed in the last 2 s")

    replay = verbs.add_parser("replay", parents=[as_json], help="send an episode's path back as a trajectory goal")
    replay.add_argument("episode", metavar="EPISODE")
    replay.add_argument("--yes-on-hardware", action="store_true", help="required when the daemon drives a real arm")
    replay.add_argument("--speed", type=float, default=1.0, help="time scale: 0.5 takes twice as long (default 1)")
    replay.add_argument("--controller", help="the joint_trajectory controller (default: the only one)")
    replay.add_argument(
        "--start-tolerance",
        type=float,
        default=0.05,
        metavar="RAD",
        help="how far the arm may be from the episode's start pose (default 0.05)",
    )
    replay.add_argument(
        "--move-to-start", action="store_true", help="move there first (jerk-limited move_to) when it is farther"
    )
    replay.add_argument("--robot", help="robot name (default: the episode's)")
    replay.add_argument("--connect", action="append", metavar="ENDPOINT", help="Zenoh endpoint of the daemon")
    replay.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 file (TLS, credentials, endpoint)")
    replay.add_argument("--timeout", type=float, default=2.0, help="seconds per request (default 2)")
    cmd.set_defaults(func=run)
