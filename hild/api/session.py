"""Zenoh configs for the daemon and for its clients.

Defaults keep hild on loopback: the daemon listens where ``zenoh.listen`` says (``tcp/127.0.0.1:7447``), multicast
scouting and gossip are off, so nothing is announced on the robot network until the config says so. The daemon's
session has Zenoh's shared-memory transport off (``zenoh.shared_memory``): its memory is bounded whoever connects.
Order of application: ``config_file`` first, then hild's own keys, then the ``config`` passthrough entries, so the
passthrough always has the last word. Clients take the same two extras, which is where TLS certificates and
credentials go (configs/secure/, docs/security.md).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
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
    settings: ZenohSection,
    listen: Sequence[str] | None = None,
    base_dir: Path | None = None,
    timestamping: bool = False,
) -> zenoh.Config:
    """The daemon's session config; ``listen`` (e.g. from the command line) replaces ``settings.listen``.
    ``timestamping``: samples carry a timestamp, which a publisher that keeps samples for late joiners (the ROS 2
    face's transient-local topics) needs."""
    config = _base_config(settings.config_file, base_dir)
    _insert(config, "mode", settings.mode)
    if settings.mode != "client":  # a client never listens
        _insert(config, "listen/endpoints", list(listen if listen is not None else settings.listen))
    _insert(config, "connect/endpoints", list(settings.connect))
    _insert(config, "scouting/multicast/enabled", settings.multicast_scouting)
    _insert(config, "scouting/gossip/enabled", False)
    # Zenoh maps each sending session's shared-memory pool (16 MiB, for payloads of 3 KB and more) and keeps it
    # after that session has gone: off, a daemon's memory no longer grows with every client that ever sent one.
    _insert(config, "transport/shared_memory/enabled", settings.shared_memory)
    if timestamping:
        _insert(config, "timestamping/enabled", True)
    _apply_overrides(config, settings.config)
    return config


def client_config(
    connect: Sequence[str] = DEFAULT_CONNECT,
    config_file: str | Path | None = None,
    config: Mapping[str, Any] | None = None,
) -> zenoh.Config:
    """A client session: one connection to the daemon, no listening socket, no scouting.

    Client mode fails fast when no endpoint answers, which is what a CLI wants ("cannot reach the daemon").
    ``config_file`` (a Zenoh JSON5 file: TLS, credentials) is applied first, then these keys (``connect`` replaces
    the file's endpoints: see :func:`file_endpoints`), then ``config`` (dotted paths → values), like the daemon's.
    """
    zconfig = _base_config(config_file)
    _insert(zconfig, "mode", "client")
    _insert(zconfig, "connect/endpoints", list(connect))
    _insert(zconfig, "listen/endpoints", [])
    _insert(zconfig, "scouting/multicast/enabled", False)
    _insert(zconfig, "scouting/gossip/enabled", False)
    _apply_overrides(zconfig, config or {})
    return zconfig


def file_endpoints(config_file: str | Path) -> list[str]:
    """The ``connect/endpoints`` a Zenoh config file names for a client ([] when none), so a station's file can
    carry the robot's address and ``hild ctl --zenoh-config FILE`` needs no ``--connect``."""
    try:
        endpoints = json.loads(_base_config(config_file).get_json("connect/endpoints"))
    except (zenoh.ZError, ValueError) as exc:
        raise SessionConfigError(f"zenoh config_file {str(config_file)!r}: {zenoh_error_text(exc)}") from None
    if isinstance(endpoints, dict):  # per-mode form: {"client": [...], "peer": [...]}
        endpoints = endpoints.get("client", [])
    return [str(e) for e in endpoints or []]


def _base_config(config_file: str | Path | None, base_dir: Path | None = None) -> zenoh.Config:
    """A fresh config, or the JSON5 file's (relative to ``base_dir`` when given)."""
    if not config_file:
        return zenoh.Config()
    path = Path(config_file)
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise SessionConfigError(f"zenoh config_file {str(path)!r}: {zenoh_error_text(exc)}") from None


def _apply_overrides(config: zenoh.Config, overrides: Mapping[str, Any]) -> None:
    for dotted, value in overrides.items():
        _insert(config, dotted.replace(".", "/"), value)


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
