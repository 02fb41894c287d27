"""`hild emulate --serve-remote`'s bus (drivers/can/emulator/remote_host.py) against python-can-remote's own client.

The finding (issue [layout], item 7.3): beside everyday load the loopback rig's drives all reported 0xd, while the
emulator loop and the daemon's cycle were on time. python-can-remote's server moved each frame from the daemon on a
thread of its own, which had to win the GIL from the emulator loop four times per frame. The first test holds the
GIL in the loop's thread (a switch interval of minutes: no other thread of the process runs while it computes) and
still expects the drive to hear the frame: it can only pass when the loop reads the socket itself.

Everything listens on 127.0.0.1 with a port the OS chooses; tests wait for conditions, never for time.
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest
from can_remote.client import RemoteClientProtocol
from can_remote.websocket import WebSocket, WebsocketClosed

from drivers.can.emulator import remote_host
from drivers.can.emulator.remote_host import RemoteServerBus, parse_frames, ws_frame
from drivers.can.emulator.runtime import RuntimeOptions, build_runtime
from drivers.can.protocol import damiao_registers as reg
from hild.config import load_config
from tests.drivers.can.test_emulate_runtime import arm6

WAIT = 10.0  # s: generous; conditions are normally met in microseconds


def until(condition: Callable[[], object], what: str, step: Callable[[], None] = lambda: None) -> None:
    deadline = time.monotonic() + WAIT
    while not condition():
        assert time.monotonic() < deadline, f"no {what} within {WAIT:g} s"
        step()
        time.sleep(0.001)


def client(bus: RemoteServerBus, **config: object) -> can.BusABC:
    return can.Bus(interface="remote", channel=f"ws://127.0.0.1:{bus.address[1]}/", **config)


def frame(ident: int, data: bytes = b"\x01\x02") -> can.Message:
    return can.Message(arbitration_id=ident, data=data, is_extended_id=False)


@contextlib.contextmanager
def looping(step: Callable[[], None]) -> Iterator[None]:
    """``step`` every millisecond on a thread, as the emulator loop does: a python-can-remote client's shutdown
    waits for the server's answer to its close."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.wait(0.001):
            step()

    thread = threading.Thread(target=loop, name="test-emulator-loop", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(WAIT)


def close(step: Callable[[], None], *clients: can.BusABC) -> None:
    """Shut the clients down while ``step`` runs as the emulator loop would."""
    with looping(step):
        for peer in clients:
            peer.shutdown()


def test_a_frame_reaches_the_drive_with_the_gil_held_by_the_emulator_loop(write_config: Callable[..., Path]) -> None:
    config = arm6(bus={"interface": "remote", "channel": "ws://127.0.0.1:54701/"})
    runtime = build_runtime(load_config(write_config(config)), RuntimeOptions(plant="motors"))
    runtime.open(serve_remote=("127.0.0.1", 0))
    loop = lambda: runtime.service(time.monotonic())  # noqa: E731 — the emulator loop's one step
    elbow = runtime.joints[2].firmware
    try:
        assert runtime.remote_address is not None
        daemon = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{runtime.remote_address[1]}/")
        try:
            daemon.send(reg.refresh_request(0x03))  # elbow's drive, MST_ID 0x13: first, a round trip as usual
            until(lambda: daemon.recv(timeout=0) is not None, "the first reply", loop)
            handled = elbow.counters["handled"]
            before = sys.getswitchinterval()
            sys.setswitchinterval(600.0)  # from here, another thread runs only when this one blocks in a call
            try:
                daemon.send(reg.refresh_request(0x03))
                deadline = time.monotonic() + WAIT
                while elbow.counters["handled"] == handled and time.monotonic() < deadline:
                    loop()  # computing without a pause
            finally:
                sys.setswitchinterval(before)
            assert elbow.counters["handled"] == handled + 1, "the frame waited for another thread"
            reply = daemon.recv(timeout=WAIT)
            assert reply is not None and reply.arbitration_id == 0x13 and reply.data[0] & 0x0F == 0x03
        finally:
            close(loop, daemon)
    finally:
        runtime.close()


def test_frames_go_both_ways_and_to_every_other_client(served: RemoteServerBus) -> None:
    a, b, c = client(served), client(served), client(served, receive_own_messages=True)
    try:
        until(lambda: len(served.clients) == 3, "three clients", served.pump)
        a.send(frame(0x101))
        got: list[can.Message] = []
        until(lambda: got.append(m) or m if (m := served.recv(timeout=0)) else False, "the frame", served.pump)
        assert got[0].arbitration_id == 0x101 and bytes(got[0].data) == b"\x01\x02"
        served.pump()  # forwards it to the others
        assert (b.recv(timeout=WAIT).arbitration_id, c.recv(timeout=WAIT).arbitration_id) == (0x101, 0x101)
        assert a.recv(timeout=0.05) is None  # not its own frame back, unless asked for (c)
        served.send(can.Message(arbitration_id=0x1ABCDEF, data=bytes(8), is_extended_id=True))
        for peer in (a, b, c):
            reply = peer.recv(timeout=WAIT)
            assert reply is not None and reply.arbitration_id == 0x1ABCDEF and reply.is_extended_id
    finally:
        close(served.pump, a, b, c)


def test_a_json_client_is_served_in_json(served: RemoteServerBus) -> None:
    websocket = WebSocket(f"ws://127.0.0.1:{served.address[1]}/", ["can.json.v1"])
    protocol = RemoteClientProtocol({}, websocket)
    try:
        assert protocol.channel_info.startswith("hild emulate on 127.0.0.1")
        protocol.send_msg(frame(0x7FF, bytes([1, 0, 0x33, 0])))
        got: list[can.Message] = []
        until(lambda: got.append(m) or m if (m := served.recv(timeout=0)) else False, "the frame", served.pump)
        assert got[0].arbitration_id == 0x7FF and bytes(got[0].data) == bytes([1, 0, 0x33, 0])
        served.send(frame(0x11, bytes(8)))
        reply = protocol.recv(WAIT)
        assert isinstance(reply, can.Message) and reply.arbitration_id == 0x11
    finally:
        websocket.close()


def test_a_closed_client_is_dropped_and_shutdown_closes_the_rest(served: RemoteServerBus) -> None:
    a = client(served)
    b = RemoteClientProtocol({}, WebSocket(f"ws://127.0.0.1:{served.address[1]}/", ["can.binary+json.v1"]))
    until(lambda: len(served.clients) == 2, "two clients", served.pump)
    close(served.pump, a)
    assert len(served.clients) == 1
    stopping = threading.Thread(target=served.shutdown)  # while the client reads, as the daemon's cycle does
    stopping.start()
    with pytest.raises(WebsocketClosed):  # the server's close, answered: python-can-remote's orderly end
        while True:
            b.recv(WAIT)
    stopping.join(WAIT)
    assert not served.clients


def test_a_client_that_stops_reading_is_dropped(served: RemoteServerBus, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(remote_host, "MAX_BACKLOG", 4096)
    websocket = WebSocket(f"ws://127.0.0.1:{served.address[1]}/", ["can.binary+json.v1"])
    try:
        RemoteClientProtocol({}, websocket)  # connected, and never reads again
        until(lambda: served.clients, "the client", served.pump)
        websocket.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        served.clients[0].sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)

        def replies() -> None:
            for _ in range(100):
                served.send(frame(0x11, bytes(8)))
            served.pump()

        until(lambda: not served.clients, "the client dropped", replies)
    finally:
        websocket.socket.close()


def test_a_client_that_sends_no_whole_frame_is_dropped(served: RemoteServerBus) -> None:
    websocket = WebSocket(f"ws://127.0.0.1:{served.address[1]}/", ["can.binary+json.v1"])
    try:
        RemoteClientProtocol({}, websocket)
        until(lambda: served.clients, "the client", served.pump)
        websocket.socket.sendall(b"\x82\xff" + (1 << 40).to_bytes(8, "big") + bytes(4))  # a frame of a terabyte
        chunk = bytes(65536)
        for _ in range(remote_host.MAX_BACKLOG // len(chunk) + 1):
            try:
                websocket.socket.sendall(chunk)
            except OSError:  # dropped already
                break
            served.pump()
        until(lambda: not served.clients, "the client dropped", served.pump)
    finally:
        websocket.socket.close()


def test_a_browser_gets_the_trace_page(served: RemoteServerBus) -> None:
    with socket.create_connection(served.address, timeout=WAIT) as sock:
        sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        page = b""
        while chunk := sock.recv(65536):
            page += chunk
    assert page.startswith(b"HTTP/1.1 200 OK") and b"<html" in page.lower()
    with socket.create_connection(served.address, timeout=WAIT) as sock:
        sock.sendall(b"GET /../../../etc/passwd HTTP/1.1\r\n\r\n")
        assert sock.recv(100).startswith(b"HTTP/1.1 404")


def test_an_incomplete_frame_waits_for_the_rest() -> None:
    whole = ws_frame(0x2, bytes(range(30)))
    buffer = bytearray(whole[:10])
    assert parse_frames(buffer) == [] and len(buffer) == 10
    buffer += whole[10:] + whole[:1]
    assert parse_frames(buffer) == [(0x2, bytes(range(30)))] and buffer == bytearray(whole[:1])
