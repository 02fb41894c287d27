"""Zenoh configs for the daemon and for its clients.

Defaults keep hild on loopback: the daemon listens where ``zenoh.listen`` says (``tcp/127.0.0.1:7447``), multicast
scouting and gossip are off, so nothing is announced on the robot network until the config says so. Order of
application: ``config_file`` first, then hild's own keys, then the ``config`` passthrough entries, so the
passthrough always has the last word.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from hild.config.model import ZenohSection

DEFAULT_CONNECT = ("tcp/127.0.0.1:7447",)


class SessionConfigError(ValueError):
    """A Zenoh setting was refused; the message names the key."""


def zenoh_error_text(exc: BaseException) -> str:
    """A ZError's message without the Rust source location zenoh appends (`` at /root/.cargo/…``)."""
    text = str(exc)
    cut = text.find(" at /")
    return (text[:cut] if cut > 0 else text).strip()


def _insert(config: zenoh.Config, path: str, value: Any) -> None:
    try:
        config.insert_json5(path, json.dumps(value))
    except (zenoh.ZError, TypeError, ValueError) as exc:
        raise SessionConfigError(f"zenoh config {path!r} = {value!r} refused: {zenoh_error_text(exc)}") from None


def server_config(
    settings: ZenohSection, listen: Sequence[str] | None = None, base_dir: Path | None = None
) -> zenoh.Config:
    """The daemon's session config; ``listen`` (e.g. from the command line) replaces ``settings.listen``."""
    if settings.config_file:
        path = Path(settings.config_file)
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        try:
            config = zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise SessionConfigError(f"zenoh config_file {str(path)!r}: {zenoh_error_text(exc)}") from None
    else:
        config = zenoh.Config()
    _insert(config, "mode", settings.mode)
    if settings.mode != "client":  # a client never listens
        _insert(config, "listen/endpoints", list(listen if listen is not None else settings.listen))
    _insert(config, "connect/endpoints", list(settings.connect))
    _insert(config, "scouting/multicast/enabled", settings.multicast_scouting)
    _insert(config, "scouting/gossip/enabled", False)
    for dotted, value in settings.config.items():
        _insert(config, dotted.replace(".", "/"), value)
    return config


def client_config(connect: Sequence[str] = DEFAULT_CONNECT) -> zenoh.Config:
    """A client session: one connection to the daemon, no listening socket, no scouting.

    Client mode fails fast when no endpoint answers, which is what a CLI wants ("cannot reach the daemon").
    """
    config = zenoh.Config()
    _insert(config, "mode", "client")
    _insert(config, "connect/endpoints", list(connect))
    _insert(config, "listen/endpoints", [])
    _insert(config, "scouting/multicast/enabled", False)
    _insert(config, "scouting/gossip/enabled", False)
    return config


def open_session(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open`` with its error turned into a ConnectionError (nothing to connect to, port taken, …)."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise ConnectionError(zenoh_error_text(exc)) from None


def declare_json_publisher(
    session: zenoh.Session, key: str, priority: zenoh.Priority = zenoh.Priority.DATA, express: bool = False
) -> zenoh.Publisher:
    """A JSON publisher that drops under congestion: a slow peer loses samples, it never stalls the sender.

    Every hild publisher is one of these: state, status and events from the daemon, streamed commands from
    clients (the next command replaces a lost one).
    """
    return session.declare_publisher(
        key,
        encoding=zenoh.Encoding.APPLICATION_JSON,
        congestion_control=zenoh.CongestionControl.DROP,
        priority=priority,
        express=express,
    )
