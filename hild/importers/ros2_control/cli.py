"""``hild import ros2-control``: registered through the ``hild.commands`` entry-point group.

``hild import`` is a group so other sources (MJCF-only robots, other frameworks) can join it later.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from hild.importers.ros2_control.packages import parse_package_root


def _package_root(text: str) -> tuple[str, Path]:
    try:
        return parse_package_root(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _xacro_arg(text: str) -> tuple[str, str]:
    name, sep, value = text.partition(":=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME:=VALUE, got {text!r}")
    return name, value


def _launch_arg(text: str) -> tuple[str, str]:
    """``NAME=VALUE`` (or ROS's own ``NAME:=VALUE``); the value may be empty (an empty prefix)."""
    name, sep, value = text.partition(":=") if ":=" in text else text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), value


def register(subparsers: Any) -> None:
    """Add ``import`` (with its ``ros2-control`` source) to the ``hild`` command line."""
    group = subparsers.add_parser("import", help="make a hild config from another framework's robot description")
    sources = group.add_subparsers(dest="source", required=True)
    p = sources.add_parser(
        "ros2-control",
        help="URDF/xacro with <ros2_control> + controller_manager YAML → hild config on the MuJoCo twin",
        description="Import a ros2_control robot: writes the hild config (-o) and the twin's URDF beside it, and "
        "prints what was mapped, approximated and not supported, with file:line. On any error nothing is written.",
    )
    p.add_argument("--urdf", required=True, type=Path, help="the robot's URDF or xacro file")
    p.add_argument(
        "--controllers",
        required=True,
        type=Path,
        nargs="+",
        action="extend",
        metavar="FILE",
        help="controller_manager YAML; several files (or the option repeated) are merged in order, as ROS does",
    )
    p.add_argument("-o", "--output", required=True, type=Path, help="hild config to write (ROBOT.yaml)")
    p.add_argument(
        "--package-root",
        action="append",
        type=_package_root,
        default=[],
        metavar="NAME=DIR",
        help="where ROS package NAME lives, for $(find NAME) and package://NAME/ (repeatable)",
    )
    p.add_argument(
        "--arg",
        action="append",
        type=_launch_arg,
        default=[],
        metavar="NAME=VALUE",
        help="a launch argument: a xacro argument and the value of $(var NAME) in the YAML (repeatable)",
    )
    p.add_argument(
        "--xacro-arg", action="append", type=_xacro_arg, default=[], metavar="NAME:=VALUE", help="xacro argument"
    )
    p.add_argument(
        "--allow-partial",
        action="store_true",
        help="import even when controllers or joints given cannot be mapped (they are listed and left out)",
    )
    p.add_argument(
        "--keep-self-contacts",
        action="store_true",
        help="let the twin collide robot links that overlap at the start pose (adjacent links never collide)",
    )
    p.add_argument(
        "--no-tracking-check",
        dest="tracking_check",
        action="store_false",
        help="skip the short lockstep run of a full-speed goal of each trajectory controller on the twin",
    )
    p.add_argument("--robot-name", help="hild robot name (default: the URDF's <robot name>)")
    p.add_argument(
        "--namespace",
        metavar="NAME",
        help="the robot whose nodes to read when the controller files give several (/leader/…, /follower/…); "
        "default: the first, said in the report",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hild.importers.ros2_control.importer import ImportRequest, import_ros2_control  # mujoco, xacro: on use
    from hild.importers.ros2_control.report import ImportFailure

    request = ImportRequest(
        urdf=args.urdf,
        controllers=args.controllers,
        output=args.output,
        package_roots=dict(args.package_root),
        xacro_args=dict(args.xacro_arg),
        args=dict(args.arg),
        robot_name=args.robot_name,
        namespace=args.namespace,
        force=args.force,
        allow_partial=args.allow_partial,
        keep_self_contacts=args.keep_self_contacts,
        tracking_check=args.tracking_check,
    )
    try:
        result = import_ros2_control(request)
    except ImportFailure as exc:
        print(f"hild import ros2-control: {exc}\nnothing was written", file=sys.stderr)
        return 1
    print(result.report.format())
    return 0
