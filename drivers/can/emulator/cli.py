"""``hild emulate CONFIG``: the CAN drives of a robot config, emulated in their own process, for rigs without motors.

Registered through the ``hild.commands`` entry-point group. Typical rigs (docs/drivers.md, "CAN"):

* ``hild emulate configs/arm6_vcan.yaml`` — drives on the kernel's vcan0, a daemon in a second process;
* ``hild emulate configs/arm6_can_loopback.yaml --serve-remote 127.0.0.1:54701`` — no kernel CAN at all: the
  emulator hosts a python-can-remote server on 127.0.0.1 and the daemon's bus is ``interface: remote``.

The run-time control channel (``--control``) is described in :mod:`drivers.can.emulator.runtime`.
"""

from __future__ import annotations

import argparse
import gc
import logging
import math
import os
import signal
import sys
from typing import Any

from drivers.can.emulator.disturbances import Obstacle, PlantMismatch, Push, parse_obstacle, parse_push
from drivers.can.emulator.runtime import EmulatorRuntime, RuntimeOptions, build_runtime, describe
from hild.config import ConfigError, load_config
from hild.hardware import HardwareError

log = logging.getLogger("hild.emulate")


def host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` → (host, port); the port may be 0 (any free port)."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, e.g. 127.0.0.1:54701; got {text!r}")
    return host.strip("[]"), int(port)


def joint_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if sep and name:
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if math.isfinite(number):
            return name, number
    raise argparse.ArgumentTypeError(f"expected JOINT=RADIANS, got {text!r}")


def push_arg(text: str) -> Push:
    try:
        return parse_push(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def obstacle_arg(text: str) -> Obstacle:
    try:
        return parse_obstacle(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(subparsers: Any) -> None:
    """Add ``emulate`` to the ``hild`` command line."""
    p = subparsers.add_parser(
        "emulate",
        help="emulate the CAN drives of a robot config (firmware-faithful, optionally with the MuJoCo twin behind)",
        description="Emulate every CAN motor a robot config names, on the config's own buses, until Ctrl-C.",
    )
    p.add_argument("config", help="robot config file (YAML)")
    p.add_argument(
        "--plant",
        choices=["twin", "motors"],
        help="twin: the robot's MuJoCo model (robot.model) behind the drives; motors: one simple load per motor "
        "(default: twin when the config has robot.model)",
    )
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="emulator service rate (default: twice the config's update_rate): the drives' timers and the plant run "
        "at it, and replies leave within 1/rate; on socketcan and --serve-remote buses a frame also wakes the loop, "
        "so its reply leaves at once",
    )
    p.add_argument(
        "--serve-remote",
        type=host_port,
        metavar="HOST:PORT",
        help="host a python-can-remote server for the config's 'interface: remote' bus (use 127.0.0.1)",
    )
    p.add_argument(
        "--control", type=host_port, metavar="HOST:PORT", help="JSON-lines control socket (status, fault injection)"
    )
    p.add_argument("--component", action="append", metavar="NAME", help="emulate only this hardware component")
    p.add_argument("--keyframe", help="twin start pose (default: the model's 'home' keyframe if any, else qpos0)")
    p.add_argument(
        "--initial", action="append", type=joint_value, default=[], metavar="JOINT=RAD", help="start position"
    )
    p.add_argument(
        "--brakes",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="hold a joint still while its drive is disabled (default on; --no-brakes lets it fall)",
    )
    p.add_argument("--inertia", type=float, default=0.05, help="motors plant: kg·m² per motor (actuator side)")
    p.add_argument("--damping", type=float, default=0.05, help="motors plant: N·m·s/rad per motor")
    p.add_argument("--gravity", type=float, default=0.0, help="motors plant: m·g·l load amplitude per motor (N·m)")
    contact = p.add_argument_group(
        'contact bench (twin plant only; docs/drivers.md, "Model mismatch, pushes and obstacles")'
    )
    contact.add_argument(
        "--mass-scale", type=float, default=1.0, metavar="F", help="plant masses and inertias ×F (robot.model kept)"
    )
    contact.add_argument(
        "--friction-scale", type=float, default=1.0, metavar="F", help="plant joint frictionloss and damping ×F"
    )
    contact.add_argument(
        "--mismatch-spread",
        type=float,
        default=0.0,
        metavar="S",
        help="each body and joint also ×U[1-S, 1+S] (seeded by --mismatch-seed)",
    )
    contact.add_argument("--mismatch-seed", type=int, default=0, metavar="N", help="seed of the per-body factors")
    contact.add_argument(
        "--obstacle",
        action="append",
        type=obstacle_arg,
        default=[],
        metavar="SHAPE:X,Y,Z:SIZES[:K[,B]]",
        help="a fixed box/sphere/cylinder the arm collides with, e.g. box:0.5,0,0.2:0.05,0.2,0.2 (half-sizes, m); "
        "K,B pad it (N/m, N·s/m)",
    )
    contact.add_argument(
        "--push",
        action="append",
        type=push_arg,
        default=[],
        metavar="FX,FY,FZ[@T[+D[~R]]]",
        help="a force on the tool (N, world) from T s for D s ramped over R s, e.g. 0,0,-20@2+0.5~0.02",
    )
    contact.add_argument("--force-site", default="tool", metavar="SITE", help="the model site pushes act on")
    p.add_argument(
        "--priority",
        type=int,
        default=0,
        metavar="N",
        help="SCHED_FIFO priority for the emulator's threads (0 = normal): drives answer from silicon, whatever "
        "else the host runs; an emulator starved by a busy host makes every drive look silent at once",
    )
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    p.set_defaults(func=run)


def apply_priority(priority: int) -> str:
    """SCHED_FIFO for the calling thread and every thread it starts afterwards; the report line either way."""
    if priority == 0:
        return "normal (SCHED_OTHER)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return f"not permitted: {exc.strerror or exc} (needs CAP_SYS_NICE or LimitRTPRIO>={priority})"
    return f"SCHED_FIFO {priority}"


def run(args: argparse.Namespace) -> int:
    """``hild emulate``: check the arguments, build the config's drives, serve them until SIGINT/SIGTERM."""
    from hild.cli import setup_logging

    setup_logging(args.log_level)
    if logging.getLogger().level > logging.DEBUG:  # canopen's SDO server logs a line per transfer at INFO
        logging.getLogger("canopen").setLevel(logging.WARNING)
    sys.setswitchinterval(0.0005)  # the control and handshake threads must not wait 5 ms for the emulator loop
    if args.rate is not None and not args.rate > 0.0:
        print("--rate must be positive", file=sys.stderr)
        return 2
    try:
        loaded = load_config(args.config)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 1
    rate = args.rate or 2.0 * loaded.config.update_rate
    if not 0 <= args.priority <= 99:
        print("--priority must be within 0..99", file=sys.stderr)
        return 2
    priority = apply_priority(args.priority)  # before any thread starts: the server threads inherit it
    try:
        runtime = build_runtime(loaded, _options(args, rate))  # ValueError: a bad mismatch factor too
        runtime.open(args.serve_remote)
    except (ValueError, HardwareError, OSError) as exc:
        print(f"hild emulate: {exc}", file=sys.stderr)
        return 1
    try:
        _announce(runtime, args, priority)
        if rate < 2.0 * loaded.config.update_rate:
            log.warning("--rate %g is below twice the config's update_rate: replies may arrive late", rate)

        def stop(signum: int, frame: Any) -> None:
            runtime.stop_event.set()

        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)
        gc.collect()
        gc.freeze()  # like the daemon: no full collection of the start-up heap stalls the loop for tens of ms
        log.info("emulating at %g Hz; Ctrl-C stops", rate)
        runtime.run(1.0 / rate)
    except OSError as exc:
        print(f"hild emulate: {exc}", file=sys.stderr)
        return 1
    finally:
        runtime.close()
    log.info("stopped")
    return 0


def _options(args: argparse.Namespace, rate: float) -> RuntimeOptions:
    return RuntimeOptions(
        plant=args.plant,
        components=args.component,
        keyframe=args.keyframe,
        initial_positions=dict(args.initial),
        brakes=args.brakes,
        inertia=args.inertia,
        damping=args.damping,
        gravity=args.gravity,
        max_step=min(0.0005, 1.0 / rate),
        mismatch=PlantMismatch(args.mass_scale, args.friction_scale, args.mismatch_spread, args.mismatch_seed),
        obstacles=[
            Obstacle(f"obstacle{k}", o.shape, o.size, o.pos, o.stiffness, o.damping)
            for k, o in enumerate(args.obstacle)
        ],
        pushes=args.push,
        force_site=args.force_site,
    )


def _announce(runtime: EmulatorRuntime, args: argparse.Namespace, priority: str) -> None:
    """Log what is emulated where; start the control socket when asked for."""
    for line in describe(runtime):
        log.info("%s", line)
    log.info("priority: %s", priority)
    if runtime.remote_address is not None:
        host, port = runtime.remote_address
        log.info("remote bus served on ws://%s:%d/ (clients: bus interface remote, that channel)", host, port)
    if args.control is not None:
        host, port = runtime.start_control(args.control)
        log.info('control on %s:%d (JSON lines, e.g. {"op": "status"})', host, port)
