"""The Python client: what a script, a notebook or ``hild ctl`` uses to talk to a running daemon.

    from hild.api.client import HildClient

    with HildClient() as hild:                  # the one robot alive on tcp/127.0.0.1:7447
        hild.switch(activate=["fwd"])
        hild.send("fwd", [0.1, 0.2, 0.3])
        print(hild.status()["mode"])

Calls block for at most ``timeout`` seconds. A service that answers ``ok: false`` raises :class:`HildError`; a
daemon that cannot be reached raises :class:`HildUnreachable` (a subclass), so callers can tell "the daemon
said no" from "nobody answered".
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from types import TracebackType
from typing import Any

import zenoh

from hild.api.codec import encode
from hild.api.keys import ALIVE_ANY, Keys, check_chunk, robot_of_alive_key
from hild.api.session import DEFAULT_CONNECT, client_config, declare_json_publisher, open_session, zenoh_error_text

log = logging.getLogger("hild.api.client")


class HildError(Exception):
    """A service refused the request; the message is the daemon's reason."""


class HildUnreachable(HildError):
    """No daemon answered: not running, wrong endpoint, or wrong robot name."""


class Subscription:
    """A live subscription; ``close()`` (or leaving a ``with`` block) stops the callbacks."""

    def __init__(self, subscriber: zenoh.Subscriber[Any]) -> None:
        self._subscriber = subscriber

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._subscriber.undeclare()

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class HildClient:
    def __init__(
        self,
        robot: str | None = None,
        connect: Sequence[str] = DEFAULT_CONNECT,
        timeout: float = 2.0,
    ) -> None:
        self.connect = list(connect)
        self.timeout = timeout
        self._robot = check_chunk(robot, "robot name") if robot is not None else None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._lock = threading.Lock()  # guards the publisher cache only
        try:
            self.session = open_session(client_config(self.connect))
        except ConnectionError as exc:
            raise HildUnreachable(f"cannot reach a hild daemon at {', '.join(self.connect)}: {exc}") from None

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    def close(self) -> None:
        with self._lock:
            publishers, self._publishers = list(self._publishers.values()), {}
        for publisher in publishers:
            with contextlib.suppress(zenoh.ZError):
                publisher.undeclare()
        with contextlib.suppress(zenoh.ZError):
            self.session.close()

    def __enter__(self) -> HildClient:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ---- discovery ----------------------------------------------------------------------------------------------
    def discover(self) -> list[str]:
        """Names of the robots whose daemon is alive (liveliness tokens ``hild/*/alive``)."""
        robots = set()
        try:
            for reply in self.session.liveliness().get(ALIVE_ANY, timeout=self.timeout):
                if reply.ok is not None:
                    robot = robot_of_alive_key(str(reply.ok.key_expr))
                    if robot:
                        robots.add(robot)
        except zenoh.ZError as exc:
            raise HildUnreachable(f"liveliness query failed: {zenoh_error_text(exc)}") from None
        return sorted(robots)

    @property
    def robot(self) -> str:
        """The robot this client talks to; found by :meth:`discover` when not given."""
        if self._robot is None:
            self._robot = self._pick(self.discover())
        return self._robot

    def _pick(self, alive: list[str]) -> str:
        if len(alive) == 1:
            return alive[0]
        where = ", ".join(self.connect)
        if not alive:
            raise HildUnreachable(f"no hild daemon alive at {where}")
        raise HildError(f"several robots are alive at {where} ({', '.join(alive)}); choose one with robot=...")

    def wait_alive(self, timeout: float | None = None) -> str:
        """Block until the robot's daemon is alive (or, with no robot given, exactly one is); return its name."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            alive = self.discover()
            if self._robot is not None and self._robot in alive:
                return self._robot
            if self._robot is None and alive:
                return self.robot if len(alive) == 1 else self._pick(alive)
            if time.monotonic() >= deadline:
                wanted = f"robot {self._robot!r}" if self._robot else "a hild daemon"
                raise HildUnreachable(f"{wanted} is not alive at {', '.join(self.connect)}")
            time.sleep(0.05)

    @property
    def keys(self) -> Keys:
        return Keys(self.robot)

    # ---- services -----------------------------------------------------------------------------------------------
    def call(
        self, service: str, payload: dict[str, Any] | None = None, *, check: bool = True, timeout: float | None = None
    ) -> dict[str, Any]:
        """Call ``hild/<robot>/srv/<service>``; return the reply, raising HildError on ``ok: false`` if ``check``."""
        key = self.keys.service(check_chunk(service, "service name"))
        wait = self.timeout if timeout is None else timeout
        errors: list[str] = []
        try:
            replies = self.session.get(
                key, payload=encode(payload or {}), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=wait
            )
            for reply in replies:
                if reply.ok is not None:
                    data = json.loads(reply.ok.payload.to_bytes())
                    break
                errors.append(reply.err.payload.to_string() if reply.err is not None else "error reply")
            else:
                if errors:
                    raise HildError(f"{service}: {'; '.join(errors)}")
                raise HildUnreachable(f"no reply from {key} within {wait:g} s: is the daemon of {self.robot!r} up?")
        except zenoh.ZError as exc:
            raise HildUnreachable(f"{service}: {zenoh_error_text(exc)}") from None
        except json.JSONDecodeError as exc:
            raise HildError(f"{service}: the reply is not JSON ({exc})") from None
        if not isinstance(data, dict):
            raise HildError(f"{service}: the reply is not a JSON object")
        if check and not data.get("ok", False):
            raise HildError(str(data.get("error") or f"{service} failed"))
        return data

    def status(self) -> dict[str, Any]:
        return self.call("status")

    def list_controllers(self) -> list[dict[str, Any]]:
        return list(self.call("list_controllers")["controllers"])

    def switch(
        self, activate: Iterable[str] = (), deactivate: Iterable[str] = (), strict: bool = True
    ) -> dict[str, Any]:
        """Switch controllers atomically between two cycles; best effort when ``strict`` is False."""
        request = {"activate": list(activate), "deactivate": list(deactivate), "strict": strict}
        return self.call("switch_controllers", request)

    def list_interfaces(self) -> list[dict[str, Any]]:
        return list(self.call("list_interfaces")["interfaces"])

    def list_hardware(self) -> list[dict[str, Any]]:
        return list(self.call("list_hardware")["hardware"])

    def estop(self) -> dict[str, Any]:
        return self.call("estop")

    def reset(self) -> dict[str, Any]:
        return self.call("reset")

    # ---- streams ------------------------------------------------------------------------------------------------
    def send(self, controller: str, values: Sequence[float], input: str = "commands") -> None:
        """Stream ``{"values": [...]}`` to a controller input (fire and forget; the daemon drops bad samples)."""
        values = [float(v) for v in values]
        if not all(math.isfinite(v) for v in values):
            raise ValueError("values must be finite numbers")
        self.put(controller, {"values": values}, input=input)

    def put(self, controller: str, payload: Any, input: str = "commands") -> None:
        """Send any JSON payload to a controller input."""
        key = self.keys.input(check_chunk(controller, "controller name"), check_chunk(input, "input name"))
        with self._lock:
            publisher = self._publishers.get(key)
            if publisher is None:
                publisher = declare_json_publisher(
                    self.session, key, priority=zenoh.Priority.INTERACTIVE_HIGH, express=True
                )
                self._publishers[key] = publisher
        publisher.put(encode(payload))

    def subscribe(self, topic: str, callback: Callable[[dict[str, Any]], None]) -> Subscription:
        """Call ``callback(message)`` for each message on ``hild/<robot>/<topic>`` (``joint_states``, ``status``,
        ``events``, or any controller output). It runs on a Zenoh thread: keep it short and thread-safe."""
        key = self.keys.topic(check_chunk(topic, "topic"))

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                message = json.loads(sample.payload.to_bytes())
            except ValueError:
                log.warning("undecodable message on %s", key)
                return
            try:
                callback(message)
            except Exception:
                log.exception("subscriber callback for %s raised", key)

        return Subscription(self.session.declare_subscriber(key, on_sample))
