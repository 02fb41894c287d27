"""The daemon's ROS 2 face: what a ros2_control node offers, under the same names, on rmw_zenoh's wire protocol.

It shares the API's Zenoh session and reaches the robot only through what the JSON API uses: the broadcaster's
output ring (``/joint_states``), a forward_command controller's ``inputs()`` callable (``<controller>/commands``:
the same validation, the same refusals), a force_torque_sensor_broadcaster's ``wrench`` ring
(``<controller>/wrench``), the services layer (the controller manager's services and every node's
parameters) and a joint_trajectory controller's action server (``action``). This module is the plumbing they share:
the node's tokens, publishers, subscriptions and service queryables, and one more node per loaded controller
(``/<controller>``, with its parameter services), as ros2_control's controllers are nodes. Anything a ROS peer
sends that is wrong is dropped or refused with a warning event; nothing it sends reaches the cycle unvalidated.

Threads: samples and queries arrive on Zenoh threads. A command is validated there and handed over (as the JSON
API does when the cycle runs in its own process); a query hops to the asyncio loop, which answers it. ``flush``
runs on the loop when the cycle wakes the client domain.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
import weakref
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext

from hild.api.codec import FAST_DECODE, MAX_PAYLOAD
from hild.api.ports import DropReporter
from hild.api.queries import clip, drop
from hild.api.ros2 import types
from hild.api.ros2.actions import RosAction
from hild.api.ros2.clock import CLOCK, CLOCK_TOPIC, RosClock, ros_time
from hild.api.ros2.controller_manager import ControllerManager
from hild.api.ros2.follow_joint_trajectory import TrajectoryAction
from hild.api.ros2.gripper_command import GripperAction
from hild.api.ros2.hardware import HardwareServices
from hild.api.ros2.lifecycle import LifecycleServices
from hild.api.ros2.manager_parameters import ManagerParameters, PendingLoads
from hild.api.ros2.node import NodeHost, Writer
from hild.api.ros2.parameters import ControllerParameters, ParameterServer
from hild.api.ros2.wire import (
    DEFAULT_QOS,
    LATCHED_QOS,
    PUBLISHER,
    SERVICE,
    SUBSCRIPTION,
    NodeInfo,
    Qos,
    attachment,
    data_key,
    gid_of,
    parse_attachment,
    qualify,
)
from hild.api.services import Services
from hild.config.model import Ros2Section
from hild.controller import ShapedOutput
from hild.crossing.ring import RingReader
from hild.daemon.link import CycleLink

log = logging.getLogger("hild.api.ros2")

JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"  # rosbags' Jazzy store holds it; its hash is Jazzy's
WRENCH_BROADCASTER = "force_torque_sensor_broadcaster"
SOURCE = "ros2"  # the source of hild events this face emits
# joint_state_broadcaster's frame_id parameter defaults to this (ros2_controllers 4.42.1, jazzy); rviz needs a frame
# to show the joints' efforts
JOINT_STATES_FRAME = "base_link"


@dataclass
class JointStatesOut:
    writer: Writer
    reader: RingReader
    names: list[str]
    # <broadcaster>/external_joint_torques: the contact observer's tau_ext in ``effort`` (safety.contact on)
    external: Writer | None = None


@dataclass
class WrenchOut:
    """A force_torque_sensor_broadcaster's ``wrench`` ring, published as WrenchStamped in ``frame_id``."""

    writer: Writer
    reader: RingReader
    frame_id: str


def _undeclare(entities: list[Any]) -> None:
    for entity in entities:
        with contextlib.suppress(zenoh.ZError):
            entity.undeclare()


@dataclass
class Declared:
    """What one controller put on ROS 2: withdrawn together when it is unloaded."""

    instance: Any
    tokens: list[Any] = field(default_factory=list)
    entities: list[Any] = field(default_factory=list)
    joint_states: JointStatesOut | None = None
    wrench: WrenchOut | None = None
    action: RosAction | None = None


@dataclass
class Inlet:
    """One subscription whose messages are handled on the loop: one at a time, the newest waiting (a flood
    costs a replaced payload, never a pile of tasks)."""

    controller: str
    name: str
    type_name: str
    handle: Callable[[Any], Awaitable[None]]
    busy: bool = False
    waiting: bytes | None = None


@dataclass
class SubNode:
    """A node of the face's session besides the daemon's (:meth:`RosFace.declare_node`): its token and services,
    withdrawn together by :meth:`close`."""

    face: RosFace
    info: NodeInfo
    tokens: list[Any] = field(default_factory=list)
    entities: list[Any] = field(default_factory=list)

    def declare_service(self, relative: str, type_name: str, serve: Callable[[Any], Any]) -> None:
        with self.face._declaring_into(self.tokens, self.entities):
            self.face._declare_service(self.info, relative, type_name, serve)

    def close(self) -> None:
        """The services' tokens, then the node's (declared first), then the queryables."""
        _undeclare([*reversed(self.tokens), *self.entities])
        self.tokens.clear()
        self.entities.clear()


@dataclass
class RosFace:
    """Declared by :meth:`start` on the API's session; :meth:`flush` publishes, :meth:`close` withdraws."""

    session: zenoh.Session
    engine: CycleLink
    services: Services
    settings: Ros2Section
    loop: asyncio.AbstractEventLoop
    _node: NodeInfo | None = None
    _next_id: int = 0
    _tokens: list[Any] = field(default_factory=list)  # where declarations go: the node's, or a controller's
    _entities: list[Any] = field(default_factory=list)
    _controllers: dict[str, Declared] = field(default_factory=dict)
    _controller_nodes: dict[str, NodeHost | None] = field(default_factory=dict)  # by name: a rebuild keeps its node
    _tasks: set[asyncio.Task[None]] = field(default_factory=set)
    _drops: DropReporter | None = None
    _clock: RosClock | None = None
    closing: bool = False

    # ---- declaration --------------------------------------------------------------------------------------------
    def start(self) -> None:
        """The node's token, then each controller's topics, services and action, the description, the manager."""
        self._drops = DropReporter(self.engine.events.emit)
        zid = str(self.session.info.zid())
        self._node = NodeInfo(self.settings.domain_id, zid, self.settings.namespace, self.settings.node)
        self._tokens.append(self.session.liveliness().declare_token(self._node.node_token()))
        sim = self.engine.loaded.config.clock.source == "sim"
        self._clock = RosClock(self.engine, self.writer(CLOCK_TOPIC, CLOCK) if sim else None)
        self._sync(self._loaded_controllers())
        self._declare_description()
        # ros2_control's services live under its node, its parameters too (what a spawner sets before a load)
        node, rate = self.settings.node, self.engine.loaded.config.update_rate
        pending = PendingLoads()
        ControllerManager(self, self.services, node, rate)
        LifecycleServices(self, self.services, node, pending)
        HardwareServices(self, self.services, node, rate)
        ParameterServer(self, node, ManagerParameters(rate, pending), self)

    def _loaded_controllers(self) -> dict[str, Any]:
        """The loaded controllers; the copy is retried when the records change while it is taken (start-up)."""
        for _ in range(99):
            try:
                return self.engine.controllers()
            except RuntimeError:
                time.sleep(0.001)
        return self.engine.controllers()

    def sync(self) -> None:
        """Controllers loaded or unloaded since: declare what the new ones offer, withdraw what the gone ones did
        (asyncio thread; the API calls it when the controllers change, as it syncs its own endpoints)."""
        try:
            current = self.engine.controllers()
        except RuntimeError:  # the records changed while copied; the next change brings us back here
            return
        self._sync(current)

    def _sync(self, current: dict[str, Any]) -> None:
        self._sync_controller_nodes(current)
        stale = [n for n, d in self._controllers.items() if current.get(n) is not d.instance]
        for name in stale:
            self._withdraw(self._controllers.pop(name))
        new = [n for n in current if n not in self._controllers]
        if not new:
            return
        kinds = {c["name"]: c["type"] for c in self.engine.snapshot().controllers}
        for name in new:
            if name in kinds:  # not yet in the snapshot: the next sync declares it
                self._controllers[name] = self._declare_controller(name, current[name], kinds[name])

    def _sync_controller_nodes(self, current: dict[str, Any]) -> None:
        """A node ``/<controller>`` with the six parameter services for each loaded controller, as ros2_control's
        controllers are nodes; it follows the name, not the instance (a parameter change that rebuilds the
        controller keeps its node, so the call that rebuilt it is answered on it)."""
        for name in [n for n in self._controller_nodes if n not in current]:
            node = self._controller_nodes.pop(name)
            if node is not None:
                node.close()
        for name in [n for n in current if n not in self._controller_nodes]:
            self._controller_nodes[name] = self._controller_node(name)

    def _controller_node(self, controller: str) -> NodeHost | None:
        if controller == self.settings.node:
            self.engine.events.emit(
                "error", SOURCE, f"controller {controller}: no parameter node: it has the controller manager's name"
            )
            return None
        node = self.declare_node(controller)
        try:
            ParameterServer(node, controller, ControllerParameters(self.services, controller), self)
        except Exception as exc:  # a node that cannot be offered costs its own services, not the face
            node.close()
            self.engine.events.emit("error", SOURCE, f"controller {controller}: no parameter node on ROS 2: {exc}")
            return None
        return node

    def _withdraw(self, declared: Declared) -> None:
        """An unloaded controller's tokens first (ROS graph tools see its endpoints go), then its entities."""
        if declared.action is not None:
            declared.action.close()
        _undeclare([*declared.tokens, *declared.entities])

    @contextlib.contextmanager
    def _declaring_for(self, declared: Declared) -> Iterator[None]:
        """Tokens and entities declared inside go to ``declared`` (the writer, service and subscription helpers
        are shared with the node's own declarations)."""
        with self._declaring_into(declared.tokens, declared.entities):
            yield

    @contextlib.contextmanager
    def _declaring_into(self, tokens: list[Any], entities: list[Any]) -> Iterator[None]:
        saved = self._tokens, self._entities
        self._tokens, self._entities = tokens, entities
        try:
            yield
        finally:
            self._tokens, self._entities = saved

    def now_ns(self) -> int:
        """ROS time: the wall clock, or the sim clock when the cycle runs on it (``hild.api.ros2.clock``)."""
        assert self._clock is not None
        return self._clock.now_ns()

    def name(self, relative: str) -> str:
        return qualify(self.settings.namespace, relative)

    def _key(self, name: str, type_name: str) -> str:
        return data_key(self.settings.domain_id, name, type_name, self.settings.distro)

    def _token(
        self, kind: str, name: str, type_name: str, qos: Qos = DEFAULT_QOS, node: NodeInfo | None = None
    ) -> bytes:
        """Declare the entity's liveliness token (of the daemon's node unless ``node``); its GID (rmw_zenoh's: a
        hash of the token key)."""
        node = node or self._node
        assert node is not None
        self._next_id += 1
        token = node.entity_token(self._next_id, kind, name, type_name, qos, self.settings.distro)
        self._tokens.append(self.session.liveliness().declare_token(token))
        return gid_of(token)

    def writer(self, name: str, type_name: str, *, latched: bool = False) -> Writer:
        """A ROS publisher. ``latched``: transient local, depth 1 — an AdvancedPublisher whose cache keeps the last
        sample, which rmw_zenoh's transient-local subscriptions (AdvancedSubscriber with history and late-publisher
        detection) ask for when they appear."""
        key = self._key(name, type_name)
        if latched:
            publisher = zenoh.ext.declare_advanced_publisher(
                self.session, key, cache=zenoh.ext.CacheConfig(max_samples=1), publisher_detection=True
            )
        else:
            publisher = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
        self._entities.append(publisher)
        return Writer(publisher, self._token(PUBLISHER, name, type_name, LATCHED_QOS if latched else DEFAULT_QOS))

    def _declare_controller(self, controller: str, instance: Any, kind: str) -> Declared:
        declared = Declared(instance)
        try:
            with self._declaring_for(declared):
                self._declare_endpoints(declared, controller, kind)
        except Exception as exc:  # a controller that cannot be exposed costs its own endpoints, not the face
            self.engine.events.emit("error", SOURCE, f"controller {controller}: not exposed on ROS 2: {exc}")
        return declared

    def _declare_endpoints(self, declared: Declared, controller: str, kind: str) -> None:
        instance = declared.instance
        outputs = dict(instance.outputs())
        inputs = dict(instance.inputs())
        ring = outputs.get("joint_states")
        if ring is not None:
            names = list(getattr(ring, "names", None) or self.engine.joints)
            writer = self.writer(self.name("joint_states"), JOINT_STATE)
            external = None
            if self.engine.loaded.config.safety.contact.enabled and "tau_ext" in getattr(ring, "fields", ()):
                external = self.writer(self.name(f"{controller}/external_joint_torques"), JOINT_STATE)
            declared.joint_states = JointStatesOut(writer, RingReader(ring), names, external)
        wrench = outputs.get("wrench")
        if isinstance(wrench, ShapedOutput) and kind == WRENCH_BROADCASTER:
            writer = self.writer(self.name(f"{controller}/wrench"), WRENCH_STAMPED)
            declared.wrench = WrenchOut(writer, RingReader(wrench.ring), str(instance.frame_id))
        server = instance.action_server() if kind in ("joint_trajectory", "parallel_gripper") else None
        if server is not None and kind == "joint_trajectory":
            declared.action = TrajectoryAction(self, controller, server)
        elif server is not None:
            declared.action = GripperAction(self, controller, server, instance.params.ros_action)
        accept = inputs.get("commands")
        if accept is not None and kind == "forward_command":
            name = self.name(f"{controller}/commands")
            handler = self._commands_handler(controller, name, accept)
            self._entities.append(self.session.declare_subscriber(self._key(name, FLOAT64_ARRAY), handler))
            self._token(SUBSCRIPTION, name, FLOAT64_ARRAY)

    def _declare_description(self) -> None:
        """``/robot_description``, kept for late joiners (a latched writer): the URDF ``ros2.robot_description``
        names, else ``robot.model`` when that is a URDF (an MJCF twin names a URDF of the same arm for ROS)."""
        model = self.settings.robot_description or self.engine.loaded.config.robot.model
        if model is None or (self.settings.robot_description is None and not model.lower().endswith(".urdf")):
            return
        path = Path(model)
        if not path.is_absolute():
            path = self.engine.loaded.path.parent / path
        try:
            text = path.read_text()
        except OSError as exc:
            self.engine.events.emit("error", SOURCE, f"/robot_description not offered: {exc}")
            return
        writer = self.writer(self.name("robot_description"), STRING, latched=True)
        writer.put(types.encode(types.message(STRING, data=text), STRING))

    def declare_service(self, relative: str, type_name: str, serve: Callable[[Any], Any]) -> None:
        assert self._node is not None
        self._declare_service(self._node, relative, type_name, serve)

    def _declare_service(self, node: NodeInfo, relative: str, type_name: str, serve: Callable[[Any], Any]) -> None:
        name = self.name(relative)
        self._token(SERVICE, name, type_name, node=node)
        handler = self._query_handler(name, type_name, serve)
        self._entities.append(self.session.declare_queryable(self._key(name, type_name), handler, complete=True))

    def declare_node(self, name: str) -> SubNode:
        """Another node in the ROS graph, ``<namespace>/<name>``: its own token (node ids share the entity
        counter, as in rmw_zenoh's context), for ``ros2 node list`` and ``ros2 param``, which look the node up
        before calling it."""
        assert self._node is not None
        self._next_id += 1
        info = NodeInfo(self._node.domain_id, self._node.zid, self._node.namespace, name, node_id=self._next_id)
        node = SubNode(self, info)
        node.tokens.append(self.session.liveliness().declare_token(info.node_token()))
        return node

    def close(self) -> None:
        """Tokens first (ROS graph tools see the node go), then the entities."""
        self.closing = True
        for task in list(self._tasks):
            task.cancel()
        for node in self._controller_nodes.values():
            if node is not None:
                node.close()
        self._controller_nodes.clear()
        declared = list(self._controllers.values())
        tokens = [*self._tokens, *(t for d in declared for t in d.tokens)]
        _undeclare([*tokens, *self._entities, *(e for d in declared for e in d.entities)])
        self._tokens.clear()
        self._entities.clear()
        self._controllers.clear()

    # ---- out (asyncio thread) -----------------------------------------------------------------------------------
    def flush(self) -> None:
        """``/clock`` on the sim clock, then every joint-state sample the broadcaster wrote since the last flush,
        stamped in ROS time: the wall clock when published, or the sample's own sim time."""
        assert self._clock is not None
        with contextlib.suppress(zenoh.ZError):
            self._clock.tick()
        declared = list(self._controllers.values())
        for out in (d.joint_states for d in declared if d.joint_states is not None):
            for _seq, stamp, fields in out.reader.read():
                msg = types.message(
                    JOINT_STATE,
                    header=types.message(
                        "std_msgs/msg/Header",
                        stamp=ros_time(self._clock.sample_ns(stamp)),
                        frame_id=JOINT_STATES_FRAME,
                    ),
                    name=out.names,
                    position=np.asarray(fields["position"], dtype=np.float64),
                    velocity=np.asarray(fields["velocity"], dtype=np.float64),
                    effort=np.asarray(fields["effort"], dtype=np.float64),
                )
                with contextlib.suppress(zenoh.ZError):
                    out.writer.put(types.encode(msg, JOINT_STATE))
                if out.external is not None:
                    self._flush_external(out.external, msg, fields)
        for wrench in (d.wrench for d in declared if d.wrench is not None):
            self._flush_wrench(wrench)
        for action in (d.action for d in declared if d.action is not None):
            try:
                action.flush()
            except Exception:  # a bug costs this flush of one action, not the daemon's publishing
                log.exception("ROS action %s: flush failed", action.name)

    @staticmethod
    def _flush_external(writer: Writer, joint_state: Any, fields: dict[str, list[float]]) -> None:
        """The same sample's external torque estimate as a JointState whose ``effort`` is ``tau_ext`` (position and
        velocity empty), as franka_ros2's ``external_joint_torques``; NaN while the observer cannot run."""
        msg = types.message(
            JOINT_STATE,
            header=joint_state.header,
            name=joint_state.name,
            position=np.zeros(0),
            velocity=np.zeros(0),
            effort=np.asarray(fields["tau_ext"], dtype=np.float64),
        )
        with contextlib.suppress(zenoh.ZError):
            writer.put(types.encode(msg, JOINT_STATE))

    def _flush_wrench(self, out: WrenchOut) -> None:
        """Each fresh wrench sample as WrenchStamped; a sample whose sensor had no accepted reading is not sent
        (ROS has no ``fresh``: the topic goes quiet while the sensor is stale, as the JSON's ``fresh`` says false)."""
        assert self._clock is not None
        for _seq, stamp, fields in out.reader.read():
            if not fields["fresh"][0]:
                continue
            force, torque = fields["force"], fields["torque"]
            msg = types.message(
                WRENCH_STAMPED,
                header=types.message(
                    "std_msgs/msg/Header", stamp=ros_time(self._clock.sample_ns(stamp)), frame_id=out.frame_id
                ),
                wrench=types.message(
                    "geometry_msgs/msg/Wrench",
                    force=types.message("geometry_msgs/msg/Vector3", x=force[0], y=force[1], z=force[2]),
                    torque=types.message("geometry_msgs/msg/Vector3", x=torque[0], y=torque[1], z=torque[2]),
                ),
            )
            with contextlib.suppress(zenoh.ZError):
                out.writer.put(types.encode(msg, WRENCH_STAMPED))

    # ---- commands (a Zenoh thread) ------------------------------------------------------------------------------
    def _commands_handler(self, controller: str, name: str, accept: Callable[[Any], None]) -> Callable[[Any], None]:
        owner = weakref.ref(self)
        lock = threading.Lock()  # one input's samples one at a time, so a later one is never overtaken

        def on_sample(sample: zenoh.Sample) -> None:
            me = owner()
            if me is None or me.closing:
                return
            with lock:
                try:
                    size = len(sample.payload)
                    if size > MAX_PAYLOAD:
                        raise ValueError(f"payload of {size} bytes exceeds the {MAX_PAYLOAD}-byte limit")
                    msg = types.decode(sample.payload.to_bytes(), FLOAT64_ARRAY)
                    accept({"values": [float(v) for v in msg.data]})  # the JSON input's validation
                except Exception as exc:
                    reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
                    assert me._drops is not None
                    me._drops.report(controller, name, reason)

        return on_sample

    # ---- subscriptions handled on the loop (trajectories) -------------------------------------------------------
    def subscribe(self, controller: str, name: str, type_name: str, handle: Callable[[Any], Awaitable[None]]) -> None:
        """Messages on ``name`` decoded and given to ``handle`` on the loop; what it raises is a dropped-command
        event, as for the JSON API's inputs."""
        inlet = Inlet(controller, name, type_name, handle)
        owner = weakref.ref(self)

        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: copy out (bounded) and hop to the loop
            me = owner()
            if me is None or me.closing:
                return
            raw = sample.payload.to_bytes() if len(sample.payload) <= MAX_PAYLOAD else b""
            with contextlib.suppress(RuntimeError):  # the loop is closed
                me.loop.call_soon_threadsafe(me._arrived, inlet, raw)

        self._entities.append(self.session.declare_subscriber(self._key(name, type_name), on_sample))
        self._token(SUBSCRIPTION, name, type_name)

    def _arrived(self, inlet: Inlet, raw: bytes) -> None:
        if inlet.busy:
            inlet.waiting = raw  # replaces the one waiting, undecoded
            return
        inlet.busy = True
        self._spawn(self._deliver(inlet, raw))

    def _spawn(self, work: Coroutine[Any, Any, None]) -> None:
        """Run ``work`` on the loop, kept until done (``close`` cancels what is left)."""
        task = self.loop.create_task(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _deliver(self, inlet: Inlet, raw: bytes | None) -> None:
        while raw is not None and not self.closing:
            try:
                if not raw:
                    raise ValueError(f"payload empty or larger than {MAX_PAYLOAD} bytes")
                if len(raw) > FAST_DECODE:
                    msg = await asyncio.to_thread(types.decode, raw, inlet.type_name)
                else:
                    msg = types.decode(raw, inlet.type_name)
                await inlet.handle(msg)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
                assert self._drops is not None
                self._drops.report(inlet.controller, inlet.name, reason)
            raw, inlet.waiting = inlet.waiting, None
        inlet.busy = False

    # ---- services (a Zenoh thread, then the loop) ---------------------------------------------------------------
    def _query_handler(self, name: str, type_name: str, serve: Callable[[Any], Any]) -> Callable[[zenoh.Query], None]:
        owner = weakref.ref(self)

        def on_query(query: zenoh.Query) -> None:
            me = owner()
            if me is None or me.closing:
                drop(query)
                return
            payload = query.payload
            raw = b"" if payload is None else payload.to_bytes() if len(payload) <= MAX_PAYLOAD else None
            raw_attachment = None if query.attachment is None else query.attachment.to_bytes()
            answer = functools.partial(me._answer, name, type_name, serve, query, raw, raw_attachment)
            try:
                me.loop.call_soon_threadsafe(lambda: me._spawn(answer()))
            except RuntimeError:  # the loop is closed
                drop(query)

        return on_query

    async def _answer(
        self,
        name: str,
        type_name: str,
        serve: Callable[[Any], Any],
        query: zenoh.Query,
        raw: bytes | None,
        raw_attachment: bytes | None,
    ) -> None:
        """Decode, serve, reply with the response's CDR and an attachment echoing the request's sequence number
        and the client's GID (rmw_zenoh matches replies to requests by them). A request that cannot be decoded
        gets an error reply and a warning event; the service is never called with it."""
        try:
            try:
                if raw is None:
                    raise ValueError(f"request larger than {MAX_PAYLOAD} bytes")
                request_type = f"{type_name}_Request"
                # a large request is decoded off the loop (a long trajectory is thousands of objects)
                if len(raw) > FAST_DECODE:
                    request = await asyncio.to_thread(types.decode, raw, request_type)
                else:
                    request = types.decode(raw, request_type)
                meta = parse_attachment(raw_attachment)
            except ValueError as exc:
                self.refused(name, str(exc))
                with contextlib.suppress(zenoh.ZError):
                    query.reply_err(clip(str(exc)).encode())
                return
            response = await serve(request)
            payload = types.encode(response, f"{type_name}_Response")
            with contextlib.suppress(zenoh.ZError):
                query.reply(query.key_expr, payload, attachment=attachment(meta.sequence, meta.gid))
        except asyncio.CancelledError:
            raise
        except Exception:  # a bug costs one reply, not the daemon
            log.exception("ROS service %s failed", name)
        finally:
            drop(query)

    def refused(self, name: str, reason: str) -> None:
        self.engine.events.emit("warning", SOURCE, f"refused ROS request on {name}: {clip(reason)}")
