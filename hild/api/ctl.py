"""``hild ctl``: the operator's command line over :class:`~hild.api.client.HildClient`.

Exit codes: 0 ok, 1 the daemon refused (service error), 2 the daemon cannot be reached. ``--json`` prints the
daemon's reply as one JSON document (errors too, as ``{"ok": false, "error": ...}``) for scripts.
``--zenoh-config FILE`` (or ``HILD_ZENOH_CONFIG``) loads a station's Zenoh file: TLS, credentials and, unless
``--connect`` is given, the endpoint (docs/security.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hild.api import render
from hild.api.client import HildClient, HildError, HildUnreachable
from hild.api.expressions import parse_all
from hild.api.pub import MAX_RATE, MIN_RATE, check_rate, stream
from hild.api.session import DEFAULT_CONNECT, SessionConfigError, file_endpoints
from hild.api.stream_inputs import resolve
from hild.config.documents import DocumentError, load_document

EXIT_OK, EXIT_SERVICE, EXIT_UNREACHABLE = 0, 1, 2
STATES = ("unconfigured", "inactive", "active")
ZENOH_CONFIG_ENV = "HILD_ZENOH_CONFIG"
CLEAR = "\x1b[H\x1b[2J"


def _common() -> argparse.ArgumentParser:
    """Options accepted both before and after the subcommand (SUPPRESS: the later one wins, absent ones vanish)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--robot", default=argparse.SUPPRESS, help="robot name (default: the one alive)")
    common.add_argument(
        "--connect",
        action="append",
        default=argparse.SUPPRESS,
        metavar="ENDPOINT",
        help=f"Zenoh endpoint of the daemon, repeatable (default: {DEFAULT_CONNECT[0]})",
    )
    common.add_argument(
        "--zenoh-config",
        default=argparse.SUPPRESS,
        metavar="FILE",
        help=f"Zenoh JSON5 file with TLS, credentials and the endpoint (default: ${ZENOH_CONFIG_ENV})",
    )
    common.add_argument("--timeout", type=float, default=argparse.SUPPRESS, help="seconds per request (default 2)")
    common.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="machine-readable output")
    return common


def add_ctl_parser(subparsers: Any) -> None:
    """Add ``ctl`` and its subcommands to an argparse subparsers object; dispatch with :func:`run_ctl`."""
    common = _common()
    ctl = subparsers.add_parser(
        "ctl",
        parents=[common],
        help="talk to a running daemon",
        description="Inspect and command a running hild daemon over Zenoh.",
    )
    sub = ctl.add_subparsers(dest="ctl_command", metavar="COMMAND", required=True)
    sub.add_parser("status", parents=[common], help="overall mode, joints, controllers, hardware, loop")
    sub.add_parser("controllers", parents=[common], help="loaded controllers and their claims")
    sub.add_parser("interfaces", parents=[common], help="command interfaces and who claims them")
    sub.add_parser("hardware", parents=[common], help="hardware components")
    hardware_state = sub.add_parser(
        "hardware-state",
        parents=[common],
        help="set a hardware component inactive (its joints held, no controller may command them) or active",
    )
    hardware_state.add_argument("name", help="the component (hild ctl hardware)")
    hardware_state.add_argument("state", choices=("active", "inactive"))
    switch = sub.add_parser("switch", parents=[common], help="activate/deactivate controllers atomically")
    switch.add_argument("--activate", nargs="+", action="extend", default=[], metavar="NAME", help="start these")
    switch.add_argument("--deactivate", nargs="+", action="extend", default=[], metavar="NAME", help="stop these")
    switch.add_argument(
        "--best-effort", action="store_true", help="switch what can be switched instead of refusing the whole switch"
    )
    load = sub.add_parser(
        "load", parents=[common], help="load a controller while the robot runs (then configure it; --state)"
    )
    load.add_argument("name", help="the new controller's name")
    load.add_argument("--type", required=True, help="its type (hild ctl list-types)")
    load.add_argument("--params", metavar="FILE", help="YAML/JSON mapping of its params (as under params: in a config)")
    load.add_argument("--fallback", nargs="+", default=[], metavar="NAME", help="fallback_controllers")
    load.add_argument(
        "--chain-to",
        metavar="NAME",
        help="chain_to: claim that (chainable) controller's reference interfaces instead of the hardware's",
    )
    load.add_argument(
        "--state",
        choices=STATES,
        default="inactive",
        help="leave it unconfigured, configured (inactive, the default) or switched on (active)",
    )
    for verb, what in (
        ("configure", "configure a loaded controller (an inactive one is cleaned up and configured again)"),
        ("cleanup", "clean up an inactive controller: unconfigured, loaded (configure it again to use it)"),
        ("unload", "unload a controller that is not active"),
        ("reload", "replace a controller that is not active with one from the daemon's config file as it is now"),
    ):
        sub.add_parser(verb, parents=[common], help=what).add_argument("name")
    sub.add_parser("list-types", parents=[common], help="controller types this daemon can load")
    param = sub.add_parser("param", parents=[common], help="a controller's parameters: list, get, set")
    verbs = param.add_subparsers(dest="param_command", metavar="VERB", required=True)
    verbs.add_parser("list", parents=[common], help="every parameter, its value and whether it may change while active")
    verbs.add_parser("get", parents=[common], help="values by dotted name").add_argument(
        "names", nargs="*", metavar="NAME", help="default: all"
    )
    setter = verbs.add_parser("set", parents=[common], help="set NAME VALUE pairs, all or nothing")
    setter.add_argument("pairs", nargs="+", metavar="NAME VALUE", help="VALUE is JSON (0.8, true, [1, 2]) or text")
    for verb in verbs.choices.values():
        verb.add_argument("controller", help="the controller's name")
        verb._actions.insert(1, verb._actions.pop())  # the controller first in the usage line
    params = sub.add_parser("params", parents=[common], help="every parameter at once: save")
    saves = params.add_subparsers(dest="params_command", metavar="VERB", required=True)
    save = saves.add_parser(
        "save", parents=[common], help="write the daemon's config file with the values as they are now, comments kept"
    )
    save.add_argument("file", nargs="?", help="where (default: <config name>.tuned.yaml here)")
    save.add_argument("--force", action="store_true", help="replace the file if it exists")
    sub.add_parser("estop", parents=[common], help="engage the e-stop (only reset leaves it)")
    sub.add_parser("reset", parents=[common], help="clear latched faults and the e-stop")
    enable = sub.add_parser("enable", parents=[common], help="enable drives a fault disabled (after reset)")
    enable.add_argument("joints", nargs="*", metavar="JOINT", help="default: every joint")
    teach = sub.add_parser(
        "teach",
        parents=[common],
        help="hand-guiding: on puts joints in teach mode (limp, weightless), off brakes them and holds them there",
    )
    teach.add_argument("state", choices=("on", "off"))
    teach.add_argument("joints", nargs="*", metavar="JOINT", help="default: every joint (off: every joint in teach)")
    record = sub.add_parser(
        "record", parents=[common], help="episodes: every cycle on disk (start, stop, discard, status)"
    )
    actions = record.add_subparsers(dest="record_command", metavar="ACTION", required=True)
    start = actions.add_parser("start", parents=[common], help="open an episode under the config's recording.dir")
    start.add_argument("--task", metavar="TEXT", help="what the episode shows (the dataset's task)")
    start.add_argument(
        "--fps", type=float, metavar="F", help="the dataset's frame rate for export (default: recording.fps)"
    )
    start.add_argument("--note", metavar="TEXT", help="the operator's note, kept in episode.json")
    actions.add_parser("stop", parents=[common], help="close the episode: prints its id, duration and files")
    actions.add_parser("discard", parents=[common], help="end the episode and delete its files")
    actions.add_parser("status", parents=[common], help="the open episode, if any, and the recorder")
    blackbox = sub.add_parser(
        "blackbox", parents=[common], help="save the flight recorder's last seconds of every cycle now"
    )
    blackbox.add_argument(
        "--seconds", type=float, metavar="S", help="how far back (default: all it keeps, recording.blackbox_seconds)"
    )
    zero = sub.add_parser("set-zero", parents=[common], help="make a held joint's current position its drive zero")
    zero.add_argument("joint")
    zero.add_argument("--confirm", action="store_true", help="required: the joint's position origin moves")
    home = sub.add_parser(
        "home",
        parents=[common],
        help="run the drive's own homing of a held joint and wait for its end (exit 0: attained)",
        description=HOME_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    home.add_argument("joint")
    home.add_argument("--no-wait", action="store_true", help="return once it has started (hild ctl status: its end)")
    home.add_argument(
        "--wait", type=float, default=HOME_WAIT, metavar="S", help=f"give up waiting after S s (default {HOME_WAIT:g})"
    )
    goal = argparse.ArgumentParser(add_help=False)
    goal.add_argument("--controller", help="default: the robot's only joint_trajectory controller")
    goal.add_argument("--no-wait", action="store_true", help="print the goal id and return once it is accepted")
    goal.add_argument("--wait", type=float, default=None, metavar="S", help="give up waiting after S seconds")
    move = sub.add_parser("move-to", parents=[common, goal], help="time-optimal jerk-limited move to positions")
    move.add_argument("positions", nargs="+", type=float, metavar="RAD", help="target per joint (controller order)")
    move.add_argument("--joints", nargs="+", metavar="NAME", help="joints the positions are for (partial goals)")
    move.add_argument("--velocities", nargs="+", type=float, metavar="RAD_S", help="velocity at the target")
    move.add_argument("--duration", type=float, help="take at least this long (s); never faster than the limits")
    trajectory = sub.add_parser("trajectory", parents=[common, goal], help="execute a trajectory from a YAML file")
    trajectory.add_argument("file", help='YAML/JSON: a goal {"trajectory": {joint_names, points}, ...}')
    gripper = sub.add_parser(
        "gripper",
        parents=[common],
        help="open, close or move a parallel gripper; closing on an object stalls on it and holds it",
    )
    gripper.add_argument("position", help='"open", "close", or a position (m or rad)')
    gripper.add_argument("--effort", type=float, metavar="N", help="press with at most this (default: its max_effort)")
    gripper.add_argument(
        "--velocity", type=float, metavar="V", help="move at most this fast (default: its max_velocity)"
    )
    gripper.add_argument("--controller", help="default: the robot's only parallel_gripper controller")
    gripper.add_argument("--no-wait", action="store_true", help="print the goal id and return once it is accepted")
    gripper.add_argument("--wait", type=float, default=None, metavar="S", help="give up waiting after S seconds")
    cancel = sub.add_parser("cancel", parents=[common], help="stop a running goal (decelerates, then holds)")
    cancel.add_argument("goal_id")
    cancel.add_argument("--controller", help="default: the robot's only joint_trajectory controller")
    pub = sub.add_parser(
        "pub",
        parents=[common],
        help="stream values or expressions of t to a controller input (Ctrl-C stops; the joints then hold)",
        description=PUB_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    pub.add_argument("controller", help="a forward_command or servo controller, active")
    pub.add_argument("values", nargs="+", metavar="VALUE", help="one per joint (controller order): number or f(t)")
    pub.add_argument("--rate", type=float, default=50.0, help=f"samples per second, {MIN_RATE:g}–{MAX_RATE:g} (50)")
    pub.add_argument("--input", metavar="NAME", help="the controller's input (default: its only streamed one)")
    pub.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: at Ctrl-C)")
    deadman = sub.add_parser(
        "deadman",
        parents=[common],
        help="hold a follow controller's dead-man: enable until Ctrl-C (or --duration), then release",
    )
    deadman.add_argument("controller", help="a follow controller, active")
    deadman.add_argument("--rate", type=float, default=10.0, help="refreshes per second (default 10)")
    deadman.add_argument("--duration", type=float, metavar="S", help="release after S seconds (default: at Ctrl-C)")
    watch = sub.add_parser("watch", parents=[common], help="live joint table (Ctrl-C to leave)")
    watch.add_argument("--once", action="store_true", help="print one table and exit")
    watch.add_argument("--rate", type=float, default=10.0, help="redraws per second (default 10)")


HOME_WAIT = 120.0  # s: homing methods that search for a switch at creep speed take minutes on long axes
HOME_POLL = 0.1  # s between two looks at the status while waiting
HOME_DESCRIPTION = """\
Start the drive's own homing of JOINT (a CiA 402 drive: homing mode, the method its config names) and wait for
its end. The drive moves the joint by itself: the joint must be held and still (no controller claims it, no
fault, no e-stop), no controller may claim it until the homing ends, and the daemon's hold follows it wherever
the drive takes it. An e-stop, a fault of the joint or of its hardware, or stopping the daemon stop the homing:
it ends failed where the drive halted. Once attained the joint's position origin may have moved; hold latches
the new reading.

Exit code 0 when the drive reports it attained its home; 1 when it failed, was refused, or is still homing after
--wait (the homing goes on; Ctrl-C stops the waiting, not the homing: e-stop stops it). docs/operations.md,
"Homing".
"""

PUB_DESCRIPTION = """\
Stream one sample per period to a controller's input: forward_command's commands ({"values": [...]}) or
servo's target ({"positions": [...]}), one VALUE per joint in the controller's order. A VALUE is a number or an
expression of t, the seconds since the first sample: numbers, t, pi, tau, e, + - * / // % **, < <= > >=,
'a if cond else b', and sin cos tan asin acos atan atan2 sinh cosh tanh exp log log10 log2 sqrt hypot floor
ceil fmod copysign degrees radians abs min max sign. Every value is checked at t = 0 before anything is sent.
Put -- before the values if one starts with '-' and is not a plain number.

Stopping (Ctrl-C or --duration) sends nothing more: after the controller's command_timeout (0.5 s by default,
cycle clock) forward_command's joints return to hold at the position they had then, and servo brakes to a stop
and holds. pub stops early, exit code 1, if the daemon reports that it dropped a sample (outside the limits,
controller deactivated) or a value fails later (1/(t-2) at t = 2).

  hild ctl pub forward_position '0.3*sin(2*pi*0.5*t)' 1.0 -1.6 -0.97 1.57 0 --duration 10
  hild ctl pub fwd -- '-0.2*(t > 1)' 0 0 --rate 100
"""


def run_ctl(args: argparse.Namespace) -> int:
    as_json = bool(getattr(args, "json", False))
    zenoh_config = getattr(args, "zenoh_config", None) or os.environ.get(ZENOH_CONFIG_ENV) or None
    try:
        connect = getattr(args, "connect", None) or (zenoh_config and file_endpoints(zenoh_config)) or DEFAULT_CONNECT
        client = HildClient(
            getattr(args, "robot", None), list(connect), getattr(args, "timeout", 2.0), zenoh_config=zenoh_config
        )
    except (HildUnreachable, SessionConfigError) as exc:
        return _fail(exc, as_json, EXIT_UNREACHABLE)
    try:
        return COMMANDS[args.ctl_command](client, args, as_json)
    except HildUnreachable as exc:
        if zenoh_config and "no reply from" in str(exc) and "access control" not in str(exc):
            exc = HildUnreachable(f"{exc} (or access control refused this station: docs/security.md)")
        return _fail(exc, as_json, EXIT_UNREACHABLE)
    except HildError as exc:
        return _fail(exc, as_json, EXIT_SERVICE)
    except KeyboardInterrupt:
        return EXIT_OK
    finally:
        with contextlib.suppress(KeyboardInterrupt):  # a second Ctrl-C while closing
            client.close()


def _fail(exc: Exception, as_json: bool, code: int) -> int:
    if as_json:
        print(json.dumps({"ok": False, "error": str(exc)}))
    else:
        print(f"hild ctl: {exc}", file=sys.stderr)
    return code


def _service(
    service: str, text: Callable[[dict[str, Any]], str], request: Callable[[argparse.Namespace], dict[str, Any]]
) -> Callable[[HildClient, argparse.Namespace, bool], int]:
    def command(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
        return _print_reply(service, client.call(service, request(args), check=False), text, as_json)

    return command


def _no_request(args: argparse.Namespace) -> dict[str, Any]:
    return {}


def _enable_request(args: argparse.Namespace) -> dict[str, Any]:
    return {"joints": args.joints}


def _hardware_state_request(args: argparse.Namespace) -> dict[str, Any]:
    return {"name": args.name, "state": args.state}


def _hardware_state_text(reply: dict[str, Any]) -> str:
    held = f"; deactivated {', '.join(reply['deactivated'])}, their joints held" if reply.get("deactivated") else ""
    return f"{reply['name']}: {reply['state']}{held}"


def _teach(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    return _print_reply("teach", client.teach(args.state == "on", args.joints, check=False), _teach_text, as_json)


def _teach_text(reply: dict[str, Any]) -> str:
    """What the switch did: the joints in teach now, who gave them up, who was handed to hold."""
    parts = [f"in teach: {', '.join(reply.get('teach') or []) or 'none'}"]
    if reply.get("released"):
        parts.append(f"held where released: {', '.join(reply['released'])}")
    if reply.get("deactivated"):
        parts.append(f"deactivated {', '.join(reply['deactivated'])}")
    return "; ".join(parts)


RECORD_TEXT: dict[str, Callable[[dict[str, Any]], str]] = {
    "start": render.record_started_text,
    "stop": render.record_stopped_text,
    "discard": render.record_discarded_text,
    "status": render.record_status_text,
}


def _record(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """``record start|stop|discard|status``: one call of the ``record`` service each."""
    verb = args.record_command
    if verb == "start":
        if (wrong := _not_positive("record start: --fps", args.fps)) is not None:
            return _fail(wrong, as_json, EXIT_SERVICE)
        reply = client.record_start(args.task, args.fps, args.note, check=False)
    else:
        reply = {"stop": client.record_stop, "discard": client.record_discard, "status": client.record_status}[verb](
            check=False
        )
    return _print_reply(f"record {verb}", reply, RECORD_TEXT[verb], as_json)


def _blackbox(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    if (wrong := _not_positive("blackbox: --seconds", args.seconds)) is not None:
        return _fail(wrong, as_json, EXIT_SERVICE)
    return _print_reply("blackbox", client.blackbox(args.seconds, check=False), render.blackbox_text, as_json)


def _not_positive(option: str, value: float | None) -> HildError | None:
    """Why an option's number cannot be sent (NaN would go out as null), or None."""
    if value is None or (math.isfinite(value) and value > 0):
        return None
    return HildError(f"{option} must be a finite number > 0, not {value:g}")


def _print_reply(what: str, reply: dict[str, Any], text: Callable[[dict[str, Any]], str], as_json: bool) -> int:
    if as_json:
        print(json.dumps(reply, indent=2))
    elif reply.get("ok"):
        print(text(reply))
    else:
        print(f"hild ctl: {what}: {reply.get('error')}", file=sys.stderr)
    return EXIT_OK if reply.get("ok") else EXIT_SERVICE


def _switch_request(args: argparse.Namespace) -> dict[str, Any]:
    return {"activate": args.activate, "deactivate": args.deactivate, "strict": not args.best_effort}


def _watch(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    latest: dict[str, dict[str, Any]] = {"status": client.status()}
    latest["status"].pop("ok", None)
    latest["status"].pop("error", None)
    received = {"status": time.monotonic()}
    got_state = threading.Event()

    def keep(topic: str) -> Callable[[dict[str, Any]], None]:
        def on_message(message: dict[str, Any]) -> None:
            latest[topic] = message
            received[topic] = time.monotonic()
            if topic == "joint_states":
                got_state.set()

        return on_message

    with client.subscribe("status", keep("status")), client.subscribe("joint_states", keep("joint_states")):
        if args.once:
            got_state.wait(client.timeout)
            if as_json:
                print(json.dumps({"status": latest["status"], "joint_states": latest.get("joint_states")}, indent=2))
            else:
                print(render.watch_text(latest["status"], latest.get("joint_states")))
            return EXIT_OK
        period = 1.0 / max(args.rate, 0.1)
        while True:
            age = time.monotonic() - received["status"]
            note = f"(no status for {age:.1f} s: is the daemon still running?)" if age > 2.0 else ""
            sys.stdout.write(CLEAR + render.watch_text(latest["status"], latest.get("joint_states"), note) + "\n")
            sys.stdout.flush()
            time.sleep(period)


def _set_zero(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    if not args.confirm:
        return _fail(HildError(f"set-zero moves {args.joint}'s position origin: add --confirm"), as_json, EXIT_SERVICE)
    reply = client.call("set_zero", {"joint": args.joint, "confirm": True}, check=False)
    if as_json:
        print(json.dumps(reply, indent=2))
    elif reply.get("ok"):
        print(f"{args.joint}: its current position is now the drive's zero")
    else:
        print(f"hild ctl: set-zero: {reply.get('error')}", file=sys.stderr)
    return EXIT_OK if reply.get("ok") else EXIT_SERVICE


def _home(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """Start the homing, then wait for the status to show its end; exit 0 only when attained."""
    reply = client.call("home", {"joint": args.joint}, check=False)
    if not reply.get("ok"):
        return _fail(HildError(f"home: {reply.get('error')}"), as_json, EXIT_SERVICE)
    attempt = reply["attempt"]
    if args.no_wait:
        started = f"{args.joint}: homing started (attempt {attempt}); hild ctl status shows its end, e-stop stops it"
        print(json.dumps(reply) if as_json else started)
        return EXIT_OK
    if not as_json:
        print(
            f"{args.joint}: homing (attempt {attempt}); Ctrl-C stops waiting, e-stop stops the homing", file=sys.stderr
        )
    try:
        entry = _homing_end(client, args.joint, attempt, args.wait)
    except KeyboardInterrupt:
        entry = None
    if entry is None:
        waiting = f"home: {args.joint} is still homing: it goes on (hild ctl status shows it; e-stop stops it)"
        return _fail(HildError(waiting), as_json, EXIT_SERVICE)
    attained = entry["state"] == "attained"
    if as_json:
        print(json.dumps({"ok": attained, "error": None if attained else entry["detail"], **entry}, indent=2))
    elif attained:
        print(f"{args.joint}: homed; it reads {entry['position']:+.4f} rad at its home")
    else:
        print(f"hild ctl: home: {args.joint} failed: {entry['detail']}", file=sys.stderr)
    return EXIT_OK if attained else EXIT_SERVICE


def _homing_end(client: HildClient, joint: str, attempt: int, wait: float) -> dict[str, Any] | None:
    """The status's ``homing`` entry of ``joint`` once ``attempt`` has ended; None after ``wait`` s."""
    deadline = time.monotonic() + wait
    while True:
        entry = next((h for h in client.status().get("homing", []) if h.get("joint") == joint), None)
        if entry is not None and entry.get("attempt") == attempt and entry.get("state") != "running":
            return dict(entry)
        if entry is not None and int(entry.get("attempt", 0)) > attempt:  # another homing followed it unseen
            later = f"attempt {attempt} ended unseen: attempt {entry['attempt']} replaced it"
            return {**entry, "attempt": attempt, "state": "failed", "detail": later, "position": None}
        if time.monotonic() >= deadline:
            return None
        time.sleep(HOME_POLL)


def _move_to(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    goal: dict[str, Any] = {"positions": args.positions}
    if args.joints:
        goal["joint_names"] = args.joints
    if args.velocities:
        goal["velocities"] = args.velocities
    if args.duration is not None:
        goal["duration"] = args.duration
    return _run_goal(client, args, as_json, goal)


def _trajectory(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    try:
        goal = load_document(args.file)
    except DocumentError as exc:
        return _fail(exc, as_json, EXIT_SERVICE)
    if isinstance(goal, dict) and "points" in goal and "trajectory" not in goal:
        goal = {"trajectory": goal}  # a bare {joint_names, points} is accepted too
    return _run_goal(client, args, as_json, goal)


def _gripper(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    try:
        position: float | str = float(args.position)
    except ValueError:
        position = args.position  # "open", "close", or a word the controller refuses with its reason
    goal: dict[str, Any] = {"position": position}
    if args.effort is not None:
        goal["max_effort"] = args.effort
    if args.velocity is not None:
        goal["max_velocity"] = args.velocity
    return _run_goal(client, args, as_json, goal, GRIPPER)


@dataclass(frozen=True)
class GoalKind:
    """A controller type that takes goals, as ``ctl`` names it when it chooses the controller."""

    type: str
    words: str


TRAJECTORY = GoalKind("joint_trajectory", "trajectory controller")  # move-to and trajectory goals
GRIPPER = GoalKind("parallel_gripper", "gripper controller")


def _goal_controller(client: HildClient, asked: str | None, kind: GoalKind = TRAJECTORY) -> str:
    """The controller a goal goes to: the one asked for, or the robot's only controller of ``kind``."""
    if asked is not None:
        return asked
    controllers = client.list_controllers()
    found = [c["name"] for c in controllers if c.get("type") == kind.type]
    if len(found) == 1:
        return str(found[0])
    if found:
        raise HildError(
            f"robot {client.robot!r} has {len(found)} {kind.words}s: {', '.join(found)}; choose one with --controller"
        )
    listed = ", ".join(f"{c['name']} ({c.get('type')})" for c in controllers) or "none"
    raise HildError(f"robot {client.robot!r} has no {kind.words} (controllers: {listed})")


def _no_such_goal_controller(
    client: HildClient, name: str, unreachable: HildUnreachable, kind: GoalKind = TRAJECTORY
) -> HildError:
    """Why a goal key got no reply, when the daemon is there: the controller is missing or takes no goals."""
    try:
        controllers = client.list_controllers()
    except HildError:
        return unreachable  # the daemon itself does not answer: say that
    of_kind = ", ".join(c["name"] for c in controllers if c.get("type") == kind.type) or "none"
    found = next((c.get("type") for c in controllers if c["name"] == name), None)
    if found is None:
        reason = f"robot {client.robot!r} has no controller {name!r}"
    elif found != kind.type:
        reason = f"controller {name!r} ({found}) takes no goals"
    else:
        return unreachable
    return HildError(f"{reason} ({kind.words}s: {of_kind}); {unreachable}")


def _run_goal(
    client: HildClient, args: argparse.Namespace, as_json: bool, goal: dict[str, Any], kind: GoalKind = TRAJECTORY
) -> int:
    """Send a goal, then wait for its result (Ctrl-C cancels it); exit 0 only if it succeeded."""
    controller = _goal_controller(client, args.controller, kind)
    # --no-wait: nobody stays to watch the goal, so it must not be stopped when this command exits
    try:
        handle = client.send_goal(controller, goal, watched=not args.no_wait)
    except HildUnreachable as exc:
        raise _no_such_goal_controller(client, controller, exc, kind) from None
    with handle:
        if args.no_wait:
            print(json.dumps({"ok": True, "goal_id": handle.goal_id}) if as_json else handle.goal_id)
            return EXIT_OK
        if not as_json:
            print(f"goal {handle.goal_id} accepted; waiting (Ctrl-C cancels it)", file=sys.stderr)
        try:
            result = handle.wait(args.wait)
        except KeyboardInterrupt:
            handle.cancel()
            result = handle.wait(5.0)
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        print(render.result_text(result))
    return EXIT_OK if result.get("status") == "succeeded" else EXIT_SERVICE


def _load(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """``load_controller``, then ``configure_controller`` and ``switch_controllers`` up to ``--state``, as
    ``ros2 control load_controller --set-state`` does; the first refusal ends it (what was done stays)."""
    try:
        params = load_document(args.params) if args.params else {}
    except DocumentError as exc:
        return _fail(exc, as_json, EXIT_SERVICE)
    if not isinstance(params, dict):
        return _fail(
            ValueError(f"{args.params}: expected a mapping of params, found {type(params).__name__}"), as_json, 1
        )
    steps: list[tuple[str, dict[str, Any], str]] = [
        (
            "load_controller",
            {
                "name": args.name,
                "type": args.type,
                "params": params,
                "fallback_controllers": args.fallback,
                **({"chain_to": args.chain_to} if args.chain_to else {}),
                "by": client.sender,
            },
            "loaded",
        ),
    ]
    if STATES.index(args.state) >= 1:
        steps.append(("configure_controller", {"name": args.name}, "configured"))
    if args.state == "active":
        steps.append(("switch_controllers", {"activate": [args.name]}, "activated"))
    replies = []
    for service, request, done in steps:
        reply = client.call(service, request, check=False)
        replies.append(reply)
        if not reply.get("ok"):
            if as_json:
                print(json.dumps(replies, indent=2))
            else:
                print(f"hild ctl: {service}: {reply.get('error')}", file=sys.stderr)
            return EXIT_SERVICE
        if not as_json:
            print(f"{args.name}: {done}")
    if as_json:
        print(json.dumps(replies, indent=2))
    return EXIT_OK


def _param(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """``param list|get|set``: one service each, printed as ``_service`` prints."""
    if args.param_command == "set":
        if len(args.pairs) % 2:
            return _fail(ValueError("param set takes NAME VALUE pairs"), as_json, EXIT_SERVICE)
        values = {name: _value(raw) for name, raw in zip(args.pairs[::2], args.pairs[1::2], strict=True)}
        request: dict[str, Any] = {"controller": args.controller, "values": values, "by": client.sender}
    elif args.param_command == "get":
        request = {"controller": args.controller, "names": args.names}
    else:
        request = {"controller": args.controller}
    service, text = PARAM_VERBS[args.param_command]
    return _service(service, text, lambda _: request)(client, args, as_json)


def _params_save(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """The daemon's tuned copy of its config (``tuned_config``), written here: never over a file unless --force."""
    reply = client.call("tuned_config", check=False)
    if not reply.get("ok"):
        return _fail(HildError(f"params save: {reply.get('error')}"), as_json, EXIT_SERVICE)
    target = Path(args.file or f"{Path(reply['path']).stem}.tuned.yaml")
    try:
        with open(target, "w" if args.force else "x", encoding="utf-8") as out:
            out.write(reply["yaml"])
    except OSError as exc:
        hint = " (--force replaces it)" if isinstance(exc, FileExistsError) else ""
        return _fail(OSError(f"params save: {target}: {exc.strerror}{hint}"), as_json, EXIT_SERVICE)
    if as_json:
        print(json.dumps({"ok": True, "error": None, "file": str(target), "changed": reply["changed"]}))
    else:
        changed = ", ".join(reply["changed"]) or "nothing: every value is as the file says"
        print(f"{target}: {reply['path']} with {changed}")
    return EXIT_OK


def _set_text(reply: dict[str, Any]) -> str:
    return "\n".join([*reply["changed"], f"{reply['controller']}: {reply['applied']}"])


def _values_text(reply: dict[str, Any]) -> str:
    return "\n".join(f"{name}: {json.dumps(value)}" for name, value in reply["values"].items())


PARAM_VERBS: dict[str, tuple[str, Callable[[dict[str, Any]], str]]] = {
    "list": ("list_parameters", lambda reply: render.parameters_text(reply["parameters"])),
    "get": ("get_parameters", _values_text),
    "set": ("set_parameters", _set_text),
}


def _value(raw: str) -> Any:
    """A value as JSON (``0.8``, ``true``, ``[1, 2]``), else the text itself (``stop``)."""
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return raw


def _named(args: argparse.Namespace) -> dict[str, Any]:
    return {"name": args.name}


def _pub(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """Check everything that would make the daemon drop the samples, then stream (hild/api/pub.py)."""
    try:
        check_rate(args.rate, args.duration)
        expressions = parse_all(args.values)
        target = resolve(client.list_controllers(), args.controller, args.input, len(expressions))
    except ValueError as exc:  # ExpressionError, StreamInputError and the rate's reason
        return _fail(HildError(f"pub: {exc}"), as_json, EXIT_SERVICE)
    key = client.keys.input(target.controller, target.input)
    if not as_json:
        until = f"for {args.duration:g} s" if args.duration is not None else "until Ctrl-C"
        print(f"streaming to {key} at {args.rate:g} Hz {until}", file=sys.stderr)
    result = stream(client, target, expressions, args.rate, args.duration)
    if as_json:
        print(json.dumps({"controller": target.controller, "input": target.input, **result.as_dict()}))
    else:
        print(
            f"sent {result.sent} samples in {result.seconds:.2f} s ({result.stopped}"
            f"{f', {result.skipped} skipped: late' if result.skipped else ''}); {target.controller}'s joints hold "
            "after its command_timeout"
        )
        if result.error:
            print(f"hild ctl: pub: {result.error}", file=sys.stderr)
    return EXIT_OK if result.error is None else EXIT_SERVICE


def _deadman(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    """``{"enable": true}`` on ``ctrl/<follow>/enable`` every 1/rate s, then ``{"enable": false}``: the follower
    moves only while this runs (docs/controllers.md, "follow")."""
    entry = next((c for c in client.list_controllers() if c.get("name") == args.controller), None)
    problem = (
        f"no controller {args.controller!r}"
        if entry is None
        else f"{args.controller!r} is a {entry.get('type')}, not a follow controller"
        if entry.get("type") != "follow"
        else f"{args.controller!r} is {entry.get('state')}: hild ctl switch --activate {args.controller}"
        if entry.get("state") != "active"
        else None
    )
    if problem is not None or not 0.5 <= args.rate <= 1000.0:
        return _fail(HildError(f"deadman: {problem or 'rate must be within 0.5–1000 Hz'}"), as_json, EXIT_SERVICE)
    if not as_json:
        until = f"for {args.duration:g} s" if args.duration is not None else "until Ctrl-C"
        print(f"dead-man held on {args.controller} {until}", file=sys.stderr)
    started, sent = time.monotonic(), 0
    try:
        while args.duration is None or time.monotonic() - started < args.duration:
            client.put(args.controller, {"enable": True}, input="enable")
            sent += 1
            time.sleep(1.0 / args.rate)
    except KeyboardInterrupt:
        pass
    finally:
        client.put(args.controller, {"enable": False}, input="enable")
    seconds = time.monotonic() - started
    print(json.dumps({"sent": sent, "seconds": round(seconds, 3)}) if as_json else f"released after {seconds:.1f} s")
    return EXIT_OK


def _cancel(client: HildClient, args: argparse.Namespace, as_json: bool) -> int:
    controller = _goal_controller(client, args.controller)
    try:
        reply = client.cancel(controller, args.goal_id)
    except HildUnreachable as exc:
        raise _no_such_goal_controller(client, controller, exc) from None
    print(json.dumps(reply) if as_json else f"cancel requested for {args.goal_id}")
    return EXIT_OK


COMMANDS: dict[str, Callable[[HildClient, argparse.Namespace, bool], int]] = {
    "status": _service("status", render.status_text, _no_request),
    "controllers": _service("list_controllers", lambda r: render.controllers_text(r["controllers"]), _no_request),
    "interfaces": _service("list_interfaces", lambda r: render.interfaces_text(r["interfaces"]), _no_request),
    "hardware": _service("list_hardware", lambda r: render.hardware_text(r["hardware"]), _no_request),
    "switch": _service("switch_controllers", render.switch_text, _switch_request),
    "estop": _service("estop", lambda r: f"e-stop engaged; deactivated {r.get('deactivated') or []}", _no_request),
    "reset": _service("reset", lambda r: f"reset; cleared {r.get('cleared') or []}", _no_request),
    "watch": _watch,
    "move-to": _move_to,
    "gripper": _gripper,
    "trajectory": _trajectory,
    "cancel": _cancel,
    "pub": _pub,
    "deadman": _deadman,
    "set-zero": _set_zero,
    "home": _home,
    "enable": _service(
        "enable", lambda r: f"enabled {r.get('enabled') or []}; each holds once its drive confirms", _enable_request
    ),
    "load": _load,
    "teach": _teach,
    "record": _record,
    "blackbox": _blackbox,
    "param": _param,
    "params": _params_save,
    "configure": _service("configure_controller", lambda r: f"{r['name']}: {r['state']}", _named),
    "hardware-state": _service("set_hardware_state", _hardware_state_text, _hardware_state_request),
    "cleanup": _service("cleanup_controller", lambda r: f"{r['name']}: {r['state']}", _named),
    "unload": _service("unload_controller", lambda r: f"{r['name']}: unloaded", _named),
    "reload": _service("reload_controller", lambda r: f"{r['name']}: reloaded ({r['state']})", _named),
    "list-types": _service("list_controller_types", lambda r: render.types_text(r["types"]), _no_request),
}
