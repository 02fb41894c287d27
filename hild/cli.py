"""The ``hild`` command line: run, check, schema, ctl."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Sequence

from hild import plugins
from hild.config import ConfigError, json_schema, load_config

# sd-daemon(3) priority prefixes: journald reads them from stderr and keeps its own timestamps.
_JOURNAL_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"<{_JOURNAL_PRIORITY.get(record.levelno, 6)}>{record.name}: {record.getMessage()}"


def setup_logging(level: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    if os.environ.get("JOURNAL_STREAM"):  # under systemd: no duplicated timestamps, levels as priorities
        handler.setFormatter(_JournalFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)


def _cmd_run(args: argparse.Namespace) -> int:
    from hild.cycle.realtime import thaw_heap
    from hild.daemon.daemon import run_daemon

    setup_logging(args.log_level)
    try:
        loaded = load_config(args.config)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 1
    code = run_daemon(loaded, args.listen)
    thaw_heap()  # the daemon is gone; free what was frozen for the cycle's sake
    return code


def _cmd_check(args: argparse.Namespace) -> int:
    from hild.config.stop_review import check_with_model

    status = 0
    for path in args.configs:
        try:
            loaded = load_config(path)
            check_with_model(loaded)  # what the daemon would refuse in the model, and a limp stop under gravity
        except ConfigError as exc:
            print(f"{len(exc.issues)} error(s):\n{exc}", file=sys.stderr)
            status = 1
            continue
        print(loaded.summary())
        print("ok")
    return status


def _cmd_schema(args: argparse.Namespace) -> int:
    print(json.dumps(json_schema(), indent=2))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hild", description="Hardware-in-the-loop bridge daemon for robot arms.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run the daemon for one robot config")
    run.add_argument("config", help="robot config file (YAML)")
    run.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh listen endpoint, overrides the config (repeatable), e.g. tcp/127.0.0.1:7447",
    )
    run.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    run.set_defaults(func=_cmd_run)

    check = sub.add_parser("check", help="validate configs; print a summary or every error")
    check.add_argument("configs", nargs="+", metavar="CONFIG")
    check.set_defaults(func=_cmd_check)

    schema = sub.add_parser("schema", help="print the config file's JSON Schema")
    schema.set_defaults(func=_cmd_schema)

    from hild.api.ctl import add_ctl_parser, run_ctl

    add_ctl_parser(sub)
    sub.choices["ctl"].set_defaults(func=run_ctl)
    for register in plugins.commands():  # each calls sub.add_parser(...) and sets its own func
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
