"""The Python client: what a script, a notebook or ``hild ctl`` uses to talk to a running daemon.

    from hild.api.client import HildClient

    with HildClient() as hild:                  # the one robot alive on tcp/127.0.0.1:7447
        hild.switch(activate=["fwd"])
        hild.send("fwd", [0.1, 0.2, 0.3])
        print(hild.status()["mode"])

Calls block for at most ``timeout`` seconds. A service that answers ``ok: false`` raises :class:`HildError`; a
daemon that cannot be reached raises :class:`HildUnreachable` (a subclass), so callers can tell "the daemon
said no" from "nobody answered".

Goals are *watched* by default: before its first goal the client declares a liveliness token and names it in each
goal, so if this client goes away (closed, crashed, cut off) the daemon applies the controller's
``on_client_lost`` to its running goals — by default they stop (docs/safety.md). ``send_goal(..., watched=False)``
sends a goal meant to outlive its sender.
"""

from __future__ import annotations

import contextlib
import getpass
import json
import logging
import math
import socket
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from hild.api.codec import encode
from hild.api.goal_senders import client_token_key, new_client_id
from hild.api.keys import ALIVE_ANY, Keys, check_chunk, robot_of_alive_key
from hild.api.session import DEFAULT_CONNECT, client_config, declare_json_publisher, open_session, zenoh_error_text

TEACH_WAIT = 5.0  # s a teach request may take: off brakes each joint to a stop before it holds
# s a record or blackbox request may take: a stop writes the last chunk, fsyncs and writes metadata.yaml. Above the
# daemon's own limit on the recorder (hild/api/record.py, RECORDER_TIMEOUT: 15 s), so the client hears its error.
RECORD_WAIT = 20.0
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
        *,
        zenoh_config: str | Path | None = None,
        zenoh_overrides: Mapping[str, Any] | None = None,
    ) -> None:
        """``zenoh_config``: a Zenoh JSON5 file (TLS certificates, user/password; configs/secure/), applied first;
        ``zenoh_overrides``: dotted Zenoh keys applied last. ``connect`` always names the endpoints."""
        self.connect = list(connect)
        self.timeout = timeout
        self._robot = check_chunk(robot, "robot name") if robot is not None else None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._lock = threading.Lock()  # guards the publisher cache only
        self.client_id = new_client_id()  # named in watched goals; the daemon watches its liveliness token
        self.sender = f"{getpass.getuser()}@{socket.gethostname()}"[:64]  # who loads and tunes, for the events
        self._presence: zenoh.LivelinessToken | None = None
        self._presence_lock = threading.Lock()
        try:
            self.session = open_session(client_config(self.connect, zenoh_config, zenoh_overrides))
        except ConnectionError as exc:
            raise HildUnreachable(f"cannot reach a hild daemon at {', '.join(self.connect)}: {exc}") from None

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    def close(self) -> None:
        self._withdraw_presence()
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
        return self._query(key, service, payload or {}, check, timeout)

    def _query(self, key: str, what: str, payload: Any, check: bool, timeout: float | None) -> dict[str, Any]:
        wait = self.timeout if timeout is None else timeout
        errors: list[str] = []
        asked = time.monotonic()
        try:
            replies = self.session.get(
                key, payload=encode(payload), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=wait
            )
            for reply in replies:
                if reply.ok is not None:
                    data = json.loads(reply.ok.payload.to_bytes())
                    break
                errors.append(reply.err.payload.to_string() if reply.err is not None else "error reply")
            else:
                if errors:
                    raise HildError(f"{what}: {'; '.join(errors)}")
                if time.monotonic() - asked < 0.5 * wait:  # Zenoh ended the query early: nobody may answer us
                    raise HildUnreachable(
                        f"no reply from {key}: nothing serves it, or access control refused this station "
                        "(docs/security.md)"
                    )
                raise HildUnreachable(f"no reply from {key} within {wait:g} s: is the daemon of {self.robot!r} up?")
        except zenoh.ZError as exc:
            raise HildUnreachable(f"{what}: {zenoh_error_text(exc)}") from None
        except json.JSONDecodeError as exc:
            raise HildError(f"{what}: the reply is not JSON ({exc})") from None
        if not isinstance(data, dict):
            raise HildError(f"{what}: the reply is not a JSON object")
        if check and not data.get("ok", False):
            raise HildError(str(data.get("error") or f"{what} failed"))
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

    # ---- controllers while the robot runs -----------------------------------------------------------------------
    def list_controller_types(self) -> list[dict[str, Any]]:
        return list(self.call("list_controller_types")["types"])

    def load_controller(
        self,
        name: str,
        type: str,
        params: dict[str, Any] | None = None,
        fallback_controllers: Iterable[str] = (),
        chain_to: str | None = None,
    ) -> dict[str, Any]:
        """Load a controller (unconfigured) from params checked as the config's are; configure, then switch it.
        ``chain_to``: the chainable controller whose reference interfaces it claims (docs/controllers.md)."""
        request: dict[str, Any] = {"name": name, "type": type, "params": params or {}, "by": self.sender}
        if fallback_controllers:
            request["fallback_controllers"] = list(fallback_controllers)
        if chain_to:
            request["chain_to"] = chain_to
        return self.call("load_controller", request)

    def teach(
        self, on: bool, joints: Iterable[str] = (), *, check: bool = True, timeout: float | None = None
    ) -> dict[str, Any]:
        """Hand-guiding on (``joints`` in teach mode, all by default; the controllers commanding them are deactivated,
        the reply's ``deactivated``) or off (each brakes to a stop and holds where it stopped; the reply comes once
        they hold). The reply's ``teach``: the joints in teach now. Waits at least 5 s: a release brakes first."""
        request = {"on": on, "joints": list(joints), "by": self.sender}
        wait = max(self.timeout, TEACH_WAIT) if timeout is None else timeout
        return self.call("teach", request, check=check, timeout=wait)

    # ---- recording (docs/recording.md) ----------------------------------------------------------------------------
    def record_start(
        self,
        task: str | None = None,
        fps: float | None = None,
        note: str | None = None,
        *,
        check: bool = True,
        timeout: float | None = None,
    ) -> dict[str, Any]:
        """Open an episode: every cycle from now on goes to disk. ``task``: what it shows (the dataset's task);
        ``fps``: the dataset's frame rate for export (default: the config's ``recording.fps``), at most the
        robot's update rate; ``note``: kept in its ``episode.json``. The reply: ``id``, ``directory``,
        ``start_tick``, ``task``, ``fps``. Refused while one is open or when recording is disabled."""
        request: dict[str, Any] = {"action": "start"}
        if task is not None:
            request["task"] = task
        if fps is not None:
            if not math.isfinite(float(fps)):
                raise ValueError("fps must be a finite number")
            request["fps"] = float(fps)
        if note is not None:
            request["note"] = note
        return self._record(request, check, timeout)

    def record_stop(self, *, check: bool = True, timeout: float | None = None) -> dict[str, Any]:
        """Close the open episode; the reply: ``id``, ``directory``, ``files`` (absolute paths, the ``.mcap`` among
        them), ``cycles``, ``duration``, ``dropped`` (rows the recorder lost)."""
        return self._record({"action": "stop"}, check, timeout)

    def record_discard(self, *, check: bool = True, timeout: float | None = None) -> dict[str, Any]:
        """End the open episode and delete its directory; the reply: ``id``, ``discarded``."""
        return self._record({"action": "discard"}, check, timeout)

    def record_status(self, *, check: bool = True, timeout: float | None = None) -> dict[str, Any]:
        """``recording`` (bool), the open episode's ``id``, ``cycles``, ``duration``, and ``dropped``, ``dir``,
        ``recorder`` (``running``, ``stopped`` or ``disabled``)."""
        return self.call("record", {"action": "status"}, check=check, timeout=timeout)

    def blackbox(
        self, seconds: float | None = None, *, check: bool = True, timeout: float | None = None
    ) -> dict[str, Any]:
        """Save the flight recorder's last ``seconds`` (default: all it keeps) of every cycle now; the reply:
        ``file``, ``cycles``, ``seconds``."""
        request: dict[str, Any] = {}
        if seconds is not None:
            if not math.isfinite(float(seconds)):
                raise ValueError("seconds must be a finite number")
            request["seconds"] = float(seconds)
        wait = max(self.timeout, RECORD_WAIT) if timeout is None else timeout
        return self.call("blackbox", request, check=check, timeout=wait)

    def _record(self, request: dict[str, Any], check: bool, timeout: float | None) -> dict[str, Any]:
        wait = max(self.timeout, RECORD_WAIT) if timeout is None else timeout
        return self.call("record", request, check=check, timeout=wait)

    def configure_controller(self, name: str) -> dict[str, Any]:
        return self.call("configure_controller", {"name": name})

    def set_hardware_state(self, name: str, state: str) -> dict[str, Any]:
        """``inactive``: the component's joints held, its command interfaces out of the controllers' reach (the
        controllers claiming them are deactivated); ``active``: available again."""
        return self.call("set_hardware_state", {"name": name, "state": state})

    def cleanup_controller(self, name: str) -> dict[str, Any]:
        """inactive → unconfigured; configure it again before activating it."""
        return self.call("cleanup_controller", {"name": name})

    def unload_controller(self, name: str) -> dict[str, Any]:
        return self.call("unload_controller", {"name": name})

    def list_parameters(self, controller: str) -> list[dict[str, Any]]:
        """Each parameter of ``controller``: ``name`` (a dotted path), ``value``, ``dynamic``, ``description``."""
        return list(self.call("list_parameters", {"controller": controller})["parameters"])

    def get_parameters(self, controller: str, names: Iterable[str] = ()) -> dict[str, Any]:
        return dict(self.call("get_parameters", {"controller": controller, "names": list(names)})["values"])

    def set_parameters(self, controller: str, values: dict[str, Any]) -> dict[str, Any]:
        """Set parameters by dotted path (``{"constraints.goal_time": 0.8}``): dynamic ones while the controller is
        active, any while it is not (it is then rebuilt); all or nothing."""
        return self.call("set_parameters", {"controller": controller, "values": values, "by": self.sender})

    def reload_controller(self, name: str) -> dict[str, Any]:
        """Replace a controller that is not active with one built from the daemon's config file as it is now."""
        return self.call("reload_controller", {"name": name})

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
        return self._subscribe_key(self.keys.topic(check_chunk(topic, "topic")), callback)

    def subscribe_controller(
        self, controller: str, output: str, callback: Callable[[dict[str, Any]], None]
    ) -> Subscription:
        """Like :meth:`subscribe`, for an output published under its controller's name,
        ``hild/<robot>/<controller>/<output>`` (a force_torque_sensor_broadcaster's ``wrench``)."""
        key = self.keys.controller_topic(check_chunk(controller, "controller"), check_chunk(output, "output"))
        return self._subscribe_key(key, callback)

    def next_message(self, topic: str, timeout: float | None = None) -> dict[str, Any]:
        """The next message on a topic (e.g. the current ``joint_states``), waiting at most ``timeout``."""
        box: list[dict[str, Any]] = []
        arrived = threading.Event()

        def keep(message: dict[str, Any]) -> None:
            if not box:
                box.append(message)
                arrived.set()

        wait = self.timeout if timeout is None else timeout
        with self.subscribe(topic, keep):
            if not arrived.wait(wait):
                raise HildUnreachable(f"no message on {self.keys.topic(topic)} within {wait:g} s")
        return box[0]

    # ---- goals ----------------------------------------------------------------------------------------------
    def send_goal(
        self,
        controller: str,
        goal: dict[str, Any],
        feedback: Callable[[dict[str, Any]], None] | None = None,
        *,
        watched: bool = True,
    ) -> GoalHandle:
        """Send a goal (a trajectory or a move_to body) to ``ctrl/<controller>/goal``; raises HildError if refused.

        The result subscription is declared before the goal is sent, so even an instant result is not missed.
        ``watched``: the goal names this client, whose departure the controller's ``on_client_lost`` answers."""
        check_chunk(controller, "controller name")
        if watched and isinstance(goal, dict):
            goal = self._watched(goal)
        handle = GoalHandle(self, controller)
        handle.open(feedback)
        try:
            reply = self._query(self.keys.input(controller, "goal"), "goal", goal, check=False, timeout=None)
        except BaseException:
            handle.close()
            raise
        if not reply.get("ok", False):
            handle.close()
            raise HildError(f"goal rejected: {reply.get('error')}")
        handle.goal_id = str(reply["goal_id"])
        return handle

    def execute_trajectory(
        self,
        controller: str,
        joint_names: Sequence[str],
        points: Sequence[dict[str, Any]],
        *,
        path_tolerance: Sequence[dict[str, Any]] | None = None,
        goal_tolerance: Sequence[dict[str, Any]] | None = None,
        goal_time_tolerance: float | None = None,
        timeout: float | None = None,
        feedback: Callable[[dict[str, Any]], None] | None = None,
    ) -> dict[str, Any]:
        """Run a trajectory and return its result (``status``, ``error_code``, ``error_string``).

        Points without ``time_from_start`` are time-parameterized by the daemon under the joints' limits."""
        goal: dict[str, Any] = {"trajectory": {"joint_names": list(joint_names), "points": list(points)}}
        if path_tolerance is not None:
            goal["path_tolerance"] = list(path_tolerance)
        if goal_tolerance is not None:
            goal["goal_tolerance"] = list(goal_tolerance)
        if goal_time_tolerance is not None:
            goal["goal_time_tolerance"] = goal_time_tolerance
        with self.send_goal(controller, goal, feedback) as handle:
            return handle.wait(timeout)

    def move_to(
        self,
        controller: str,
        positions: Sequence[float],
        *,
        velocities: Sequence[float] | None = None,
        duration: float | None = None,
        joint_names: Sequence[str] | None = None,
        wait: bool = True,
        timeout: float | None = None,
    ) -> dict[str, Any]:
        """A time-optimal jerk-limited move (all joints arrive together; ``duration`` only ever slows it down).

        Returns the result, or ``{"goal_id"}`` at once when ``wait`` is False."""
        goal: dict[str, Any] = {"positions": [float(p) for p in positions]}
        if velocities is not None:
            goal["velocities"] = [float(v) for v in velocities]
        if duration is not None:
            goal["duration"] = float(duration)
        if joint_names is not None:
            goal["joint_names"] = list(joint_names)
        handle = self.send_goal(controller, goal)
        if not wait:
            handle.close()
            return {"goal_id": handle.goal_id}
        with handle:
            return handle.wait(timeout)

    def gripper(
        self,
        controller: str,
        position: float | str,
        *,
        max_effort: float | None = None,
        max_velocity: float | None = None,
        wait: bool = True,
        timeout: float | None = None,
        feedback: Callable[[dict[str, Any]], None] | None = None,
    ) -> dict[str, Any]:
        """Move a parallel_gripper to ``position`` (a number, ``"open"`` or ``"close"``) pressing with at most
        ``max_effort``; the result says ``position``, ``effort``, ``stalled`` (stopped on an object, which it now
        holds) and ``reached_goal``. Returns ``{"goal_id"}`` at once when ``wait`` is False."""
        goal: dict[str, Any] = {"position": position if isinstance(position, str) else float(position)}
        if max_effort is not None:
            goal["max_effort"] = float(max_effort)
        if max_velocity is not None:
            goal["max_velocity"] = float(max_velocity)
        handle = self.send_goal(controller, goal, feedback)
        if not wait:
            handle.close()
            return {"goal_id": handle.goal_id}
        with handle:
            return handle.wait(timeout)

    def cancel(self, controller: str, goal_id: str) -> dict[str, Any]:
        """Ask the controller to stop a goal (decelerating to a stop); the goal's result says when it is done."""
        key = self.keys.input(check_chunk(controller, "controller name"), "cancel")
        return self._query(key, "cancel", {"goal_id": goal_id}, check=True, timeout=None)

    def goal_result(self, controller: str, goal_id: str) -> dict[str, Any]:
        """The result of a finished goal, or ``{"status": "executing"}``."""
        key = self.keys.input(check_chunk(controller, "controller name"), "result")
        reply = self._query(key, "result", {"goal_id": goal_id}, check=False, timeout=None)
        if reply.get("ok") is False:
            raise HildError(str(reply.get("error")))
        return reply

    # ---- presence (goal senders' liveliness, hild/api/goal_senders.py) -----------------------------------------
    def _watched(self, goal: dict[str, Any]) -> dict[str, Any]:
        """``goal`` naming this client, whose liveliness token is declared first (once per client)."""
        key = client_token_key(self.robot, self.client_id)
        with self._presence_lock:
            if self._presence is None:
                try:
                    self._presence = self.session.liveliness().declare_token(key)
                except zenoh.ZError as exc:
                    raise HildUnreachable(f"cannot declare this client's liveliness: {zenoh_error_text(exc)}") from None
        return {**goal, "client": self.client_id}

    def _withdraw_presence(self) -> None:
        with self._presence_lock:
            token, self._presence = self._presence, None
        if token is not None:
            with contextlib.suppress(zenoh.ZError):
                token.undeclare()

    def servo_stream(self, controller: str) -> ServoStream:
        """A sender of streamed targets for a ``servo`` controller (teleop, policies)."""
        return ServoStream(self, controller)

    def _subscribe_key(self, key: str, callback: Callable[[dict[str, Any]], None]) -> Subscription:

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


RESULT_POLL = 0.5  # s: while waiting, ask for the result this often in case the published one was dropped


class GoalHandle:
    """A goal in flight: wait for its result, cancel it. Use as a context manager to release its subscriptions."""

    def __init__(self, client: HildClient, controller: str) -> None:
        self.client = client
        self.controller = controller
        self.goal_id = ""
        self._results: dict[str, dict[str, Any]] = {}
        self._arrived = threading.Condition()
        self._subscriptions: list[Subscription] = []

    def open(self, feedback: Callable[[dict[str, Any]], None] | None) -> None:
        keys = self.client.keys
        self._subscriptions.append(self.client._subscribe_key(keys.input(self.controller, "result"), self._on_result))
        if feedback is not None:

            def mine(message: dict[str, Any]) -> None:
                if message.get("goal_id") == self.goal_id:
                    feedback(message)

            self._subscriptions.append(self.client._subscribe_key(keys.input(self.controller, "feedback"), mine))

    def _on_result(self, message: dict[str, Any]) -> None:
        with self._arrived:
            self._results[str(message.get("goal_id"))] = message
            self._arrived.notify_all()

    def wait(self, timeout: float | None = None) -> dict[str, Any]:
        """Block until the goal has a result and return it; HildError after ``timeout`` seconds (None = forever)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._arrived:
                result = self._results.get(self.goal_id)
                if result is None:
                    left = RESULT_POLL if deadline is None else min(RESULT_POLL, deadline - time.monotonic())
                    if left > 0:
                        self._arrived.wait(left)
                    result = self._results.get(self.goal_id)
            if result is not None:
                return result
            polled = self.client.goal_result(self.controller, self.goal_id)
            if polled.get("status") != "executing":
                return polled
            if deadline is not None and time.monotonic() >= deadline:
                raise HildError(f"goal {self.goal_id} has no result after {timeout:g} s (still executing)")

    def cancel(self) -> dict[str, Any]:
        return self.client.cancel(self.controller, self.goal_id)

    def close(self) -> None:
        for subscription in self._subscriptions:
            subscription.close()
        self._subscriptions.clear()

    def __enter__(self) -> GoalHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ServoStream:
    """Publishes ``{"positions", "velocities"?}`` targets to ``ctrl/<controller>/target`` (fire and forget)."""

    def __init__(self, client: HildClient, controller: str) -> None:
        self.client = client
        self.controller = check_chunk(controller, "controller name")

    def send(self, positions: Sequence[float], velocities: Sequence[float] | None = None) -> None:
        target: dict[str, Any] = {"positions": _finite(positions, "positions")}
        if velocities is not None:
            target["velocities"] = _finite(velocities, "velocities")
        self.client.put(self.controller, target, input="target")


def _finite(values: Sequence[float], what: str) -> list[float]:
    out = [float(v) for v in values]
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be finite numbers")
    return out
