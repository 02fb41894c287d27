"""Who sent a goal, and whether they are still there: goal senders' Zenoh liveliness.

A client declares the liveliness token ``hild/<robot>/client/<id>`` before its first goal and names ``<id>`` in
each goal (the body's ``client`` key). The daemon watches ``hild/<robot>/client/*``; when a token goes away (the
client closed its session, crashed, or lost the network for longer than Zenoh's lease), every controller that runs
goals of that client is told through its action server, and applies its ``on_client_lost`` setting
(docs/safety.md). Tokens cost nothing per cycle: Zenoh sends one declaration and one withdrawal.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Any

import zenoh

from hild.api.keys import Keys

CLIENT = "client"


def new_client_id() -> str:
    return uuid.uuid4().hex


def client_token_key(robot: str, client_id: str) -> str:
    return f"{Keys(robot).root}/{CLIENT}/{client_id}"


def client_of_key(robot: str, key: str) -> str | None:
    """``hild/<robot>/client/<id>`` → ``<id>``; None for any other key."""
    prefix = f"{Keys(robot).root}/{CLIENT}/"
    if not key.startswith(prefix):
        return None
    client_id = key[len(prefix) :]
    return client_id if client_id and "/" not in client_id else None


def watch_clients(session: zenoh.Session, robot: str, on_gone: Callable[[str], None]) -> zenoh.Subscriber[Any]:
    """Call ``on_gone(client_id)`` (on a Zenoh thread) whenever a goal sender's token is withdrawn.

    With history, tokens declared before the daemon started watching are known too, so their withdrawal is seen.
    """

    def on_sample(sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        client_id = client_of_key(robot, str(sample.key_expr))
        if client_id is not None:
            on_gone(client_id)

    return session.liveliness().declare_subscriber(f"{Keys(robot).root}/{CLIENT}/*", on_sample, history=True)
