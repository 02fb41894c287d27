"""One robot name, one daemon: two daemons answering ``hild/<robot>/...`` would both obey every command.

Every daemon declares a liveliness token ``hild/<robot>/daemon/<zid>`` (its Zenoh session id) and answers a query
on the same key with where it runs (host, pid, listen endpoints). The pid is the one an operator stops: under
``hild run``, the main process's (stopping the client domain that answers only makes the main process start
another, the name still taken). A starting daemon looks for such tokens — and for
an ``hild/<robot>/alive`` token, which older daemons declare alone — *before* it declares anything or enables a
drive, and refuses to start naming the other one. Tokens of one key expression are merged by Zenoh, which is why
each daemon's token carries its own id: a daemon that appears later on the same network is seen by the watch and
reported as an error event (it cannot be stopped from here; the operator must).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from hild.api.keys import Keys

DAEMON = "daemon"
CHECK_TIMEOUT = 1.0  # s a starting daemon waits for other daemons' tokens (and their answer of where they run)


class RobotNameTaken(RuntimeError):
    """Another daemon already runs a robot of this name on this Zenoh network."""


def daemon_key(keys: Keys, zid: str = "*") -> str:
    return f"{keys.root}/{DAEMON}/{zid}"


def describe_other(session: zenoh.Session, keys: Keys, zid: str) -> str:
    """Where the daemon with session id ``zid`` runs, as it answers it (or just its id)."""
    try:
        for reply in session.get(daemon_key(keys, zid), timeout=CHECK_TIMEOUT):
            if reply.ok is not None:
                info = json.loads(reply.ok.payload.to_string())
                listen = ", ".join(info.get("listen") or []) or "no listen endpoint"
                return f"Zenoh id {zid}, {info.get('host')} pid {info.get('pid')}, listening on {listen}"
    except (zenoh.ZError, ValueError, TypeError):
        pass
    return f"Zenoh id {zid}"


def check_unique(session: zenoh.Session, keys: Keys) -> None:
    """Raise RobotNameTaken when another daemon of ``keys.robot`` is alive (call before declaring anything)."""
    own = str(session.zid())
    others = []
    for reply in session.liveliness().get(daemon_key(keys), timeout=CHECK_TIMEOUT):
        if reply.ok is not None:
            zid = str(reply.ok.key_expr).rsplit("/", 1)[-1]
            if zid != own:
                others.append(describe_other(session, keys, zid))
    if not others:
        for reply in session.liveliness().get(keys.alive, timeout=CHECK_TIMEOUT):
            if reply.ok is not None:
                others.append("a daemon that does not say where it runs (an older hild)")
                break
    if others:
        raise RobotNameTaken(
            f"robot {keys.robot!r} already has a daemon on this Zenoh network ({'; '.join(others)}): two daemons of "
            "one robot name would both obey every command. Stop it, or give this robot another robot.name"
        )


class DaemonIdentity:
    """This daemon's token and its answer of where it runs; watches for another daemon of the same robot."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        listen: Sequence[str],
        on_other: Callable[[str], None],
        pid: int | None = None,
    ) -> None:
        """``pid``: the process to stop to stop this daemon (default: this one)."""
        self.zid = str(session.zid())
        own_key = daemon_key(keys, self.zid)
        pid = os.getpid() if pid is None else pid
        where = json.dumps({"zid": self.zid, "host": socket.gethostname(), "pid": pid, "listen": list(listen)})

        def answer(query: zenoh.Query) -> None:
            query.reply(own_key, where)

        def seen(sample: zenoh.Sample) -> None:  # a Zenoh thread
            zid = str(sample.key_expr).rsplit("/", 1)[-1]
            if sample.kind == zenoh.SampleKind.PUT and zid != self.zid:
                on_other(zid)

        self._queryable = session.declare_queryable(own_key, answer)
        self._watch = session.liveliness().declare_subscriber(daemon_key(keys), seen)
        self._token = session.liveliness().declare_token(own_key)

    def close(self) -> None:
        handles: tuple[Any, ...] = (self._token, self._watch, self._queryable)
        for handle in handles:
            with contextlib.suppress(zenoh.ZError):
                handle.undeclare()
