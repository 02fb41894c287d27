"""`hild emulate --serve-remote`'s bus: a python-can-remote server whose frames are moved by the emulator loop itself.

python-can-remote's own server (``can_remote.RemoteServer``) gives every client two threads of the emulator's
process, a receiving and a sending one, bridged to the drives through an in-process ``virtual`` channel. Beside the
1 kHz emulation loop they compete for the GIL: each frame from the daemon takes four blocking calls, each a GIL
hand-over, and on a loaded machine that thread falls behind until every drive's CAN watchdog fires while the loop
itself is on time (measured by hild.bench.loopback_gaps; docs/drivers.md "Emulator"). Here only the handshake has
a thread; once a client is connected its socket is non-blocking and the loop reads, parses and answers it between
two services: no GIL hand-over per frame, no copy through a virtual channel.

The wire is python-can-remote 0.3's (a websocket, ``can.binary+json.v1`` or ``can.json.v1``), so the daemon's
``interface: remote`` bus is unchanged, and like its server this one also serves the trace web page to browsers.
Frames from one client reach the drives and every other client, as on a bus. A client that stops reading is
dropped once ``MAX_BACKLOG`` bytes wait for it; periodic sends are not emulated (hild's drivers send no periodic
frames) and are refused with an error event.
"""

from __future__ import annotations

import base64
import collections
import contextlib
import hashlib
import json
import logging
import mimetypes
import queue
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

log = logging.getLogger("hild.emulate")

MAX_BACKLOG = 1 << 20  # bytes waiting for a client that does not read, or from one that sends no frame: dropped
HANDSHAKE_TIMEOUT = 5.0  # s for a client to send its request and its bus request
CLOSE_TIMEOUT = 0.5  # s for the clients to answer the close on shutdown
ACCEPT_POLL = 0.2  # s: how often the handshake thread looks whether the bus was shut down
READ_SIZE = 65536

_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
_BINARY, _TEXT, _CLOSE, _PING, _PONG = 0x2, 0x1, 0x8, 0x9, 0xA
_MESSAGE = struct.Struct(">dIBB")  # python-can-remote's binary message: timestamp, id, DLC, flags; then the data
_EXTENDED, _REMOTE, _ERROR, _FD, _BRS, _ESI = 0x1, 0x2, 0x4, 0x8, 0x10, 0x20
_PROTOCOLS = ("can.binary+json.v1", "can.json.v1")


def accept_key(key: str) -> str:
    return base64.b64encode(hashlib.sha1(key.encode("ascii") + _GUID).digest()).decode()


def ws_frame(opcode: int, payload: bytes) -> bytes:
    """One unmasked websocket frame (server to client)."""
    n = len(payload)
    if n <= 125:
        head = bytes((0x80 | opcode, n))
    elif n <= 0xFFFF:
        head = bytes((0x80 | opcode, 126)) + struct.pack(">H", n)
    else:
        head = bytes((0x80 | opcode, 127)) + struct.pack(">Q", n)
    return head + payload


def _unmask(data: bytes | bytearray, mask: bytes | bytearray) -> bytes:
    n = len(data)
    key = (bytes(mask) * (n // 4 + 1))[:n]
    return (int.from_bytes(data, "little") ^ int.from_bytes(key, "little")).to_bytes(n, "little")


def parse_frames(buffer: bytearray) -> list[tuple[int, bytes]]:
    """Every complete websocket frame at the start of ``buffer`` as (opcode, unmasked payload); consumed bytes are
    removed, an incomplete frame stays for the next read."""
    frames = []
    pos, end = 0, len(buffer)
    while end - pos >= 2:
        opcode, length, at = buffer[pos] & 0x0F, buffer[pos + 1] & 0x7F, pos + 2
        masked = buffer[pos + 1] & 0x80
        if length == 126:
            if end - at < 2:
                break
            (length,) = struct.unpack_from(">H", buffer, at)
            at += 2
        elif length == 127:
            if end - at < 8:
                break
            (length,) = struct.unpack_from(">Q", buffer, at)
            at += 8
        stop = at + (4 if masked else 0) + length
        if stop > end:
            break
        payload = bytes(buffer[stop - length : stop])
        frames.append((opcode, _unmask(payload, buffer[at : at + 4]) if masked else payload))
        pos = stop
    del buffer[:pos]
    return frames


def encode_message(msg: can.Message, binary: bool) -> bytes:
    """``msg`` as python-can-remote sends it to a client of that protocol (a whole websocket frame)."""
    if binary:
        flags = (
            (_EXTENDED if msg.is_extended_id else 0)
            | (_REMOTE if msg.is_remote_frame else 0)
            | (_ERROR if msg.is_error_frame else 0)
            | (_FD if msg.is_fd else 0)
            | (_BRS if msg.bitrate_switch else 0)
            | (_ESI if msg.error_state_indicator else 0)
        )
        head = b"\x01" + _MESSAGE.pack(msg.timestamp, msg.arbitration_id, msg.dlc, flags)
        return ws_frame(_BINARY, head + bytes(msg.data))
    payload: dict[str, Any] = {
        "timestamp": msg.timestamp,
        "arbitration_id": msg.arbitration_id,
        "is_extended_id": msg.is_extended_id,
        "is_remote_frame": msg.is_remote_frame,
        "is_error_frame": msg.is_error_frame,
        "dlc": msg.dlc,
        "data": list(msg.data),
    }
    if msg.is_fd:
        payload |= {
            "is_fd": True,
            "bitrate_switch": msg.bitrate_switch,
            "error_state_indicator": msg.error_state_indicator,
        }
    return _event("message", payload)


def _event(kind: str, payload: Any) -> bytes:
    return ws_frame(_TEXT, json.dumps({"type": kind, "payload": payload}).encode())


def decode_message(opcode: int, payload: bytes) -> can.Message | dict[str, Any] | None:
    """A client's frame: a CAN message, another event (a dict), or None for what carries neither."""
    if opcode == _BINARY:
        if len(payload) < 1 + _MESSAGE.size or payload[0] != 1:
            return None
        stamp, ident, dlc, flags = _MESSAGE.unpack_from(payload, 1)
        return can.Message(
            timestamp=stamp,
            arbitration_id=ident,
            dlc=dlc,
            is_extended_id=bool(flags & _EXTENDED),
            is_remote_frame=bool(flags & _REMOTE),
            is_error_frame=bool(flags & _ERROR),
            is_fd=bool(flags & _FD),
            bitrate_switch=bool(flags & _BRS),
            error_state_indicator=bool(flags & _ESI),
            data=payload[1 + _MESSAGE.size :],
        )
    if opcode != _TEXT:
        return None
    event = json.loads(payload)
    if not isinstance(event, dict):
        return None
    if event.get("type") == "message" and isinstance(event.get("payload"), dict):
        return can.Message(**event["payload"])
    return event


@dataclass
class Client:
    """One connected client, owned by the emulator loop once its handshake is done."""

    sock: socket.socket
    name: str
    binary: bool
    own: bool = False  # receive_own_messages, as the client's bus request asked
    inbox: bytearray = field(default_factory=bytearray)
    outbox: bytearray = field(default_factory=bytearray)
    lost: bool = False  # gone, or too far behind: dropped at the next pump
    refused_periodic: bool = False

    def queue(self, frame: bytes) -> None:
        if not self.lost:
            self.outbox += frame

    def flush(self) -> None:
        """Write what waits without blocking."""
        if not self.outbox or self.lost:
            return
        try:
            sent = self.sock.send(self.outbox)
        except BlockingIOError:
            sent = 0
        except OSError:
            sent = 0
            self.lost = True
        del self.outbox[:sent]
        if len(self.outbox) > MAX_BACKLOG:
            self.lost = True
        if self.lost:
            self.outbox.clear()


class RemoteServerBus(can.BusABC):
    """The emulator's side of a python-can-remote bus on HOST:PORT (port 0: any free one, see ``address``)."""

    def __init__(self, host: str, port: int, **kwargs: Any) -> None:
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(ACCEPT_POLL)
        self.address: tuple[str, int] = self._listener.getsockname()[:2]
        self.channel_info = f"hild emulate on {self.address[0]}:{self.address[1]}"
        self.clients: list[Client] = []
        self._arrivals: queue.SimpleQueue[Client] = queue.SimpleQueue()
        self._received: collections.deque[can.Message] = collections.deque()
        self._closed = threading.Event()
        # the handshake thread's word to a loop waiting on the clients' sockets (`waitables`): a client arrived
        self._arrived, self._announce = socket.socketpair()
        for end in (self._arrived, self._announce):
            end.setblocking(False)
        self._thread = threading.Thread(target=self._accept, name="emulate-remote-handshake", daemon=True)
        self._thread.start()
        super().__init__(channel=f"ws://{self.address[0]}:{self.address[1]}/", **kwargs)

    # ---- the loop's side ----------------------------------------------------------------------------------------
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if not self._received:
                self.pump()
            if self._received:
                return self._received.popleft(), False
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0.0:
                return None, False
            time.sleep(0.001 if remaining is None else min(remaining, 0.001))

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """To every client, at once (what a slow client cannot take waits in its outbox)."""
        self._deliver(msg, source=None)

    def waitables(self) -> tuple[list[socket.socket], list[socket.socket]]:
        """What the loop waits on between two services (`drivers.can.emulator.core.frame_wakeup`): every client's
        socket and the handshake thread's word of a new client for reading; the clients whose output waits, for
        room."""
        readable = [self._arrived, *(client.sock for client in self.clients)]
        return readable, [client.sock for client in self.clients if client.outbox]

    def pump(self) -> None:
        """Take new clients, read every client's frames into the receive queue, write what waits."""
        with contextlib.suppress(BlockingIOError, OSError):
            while self._arrived.recv(4096):
                pass
        while True:
            try:
                self.clients.append(self._arrivals.get_nowait())
            except queue.Empty:
                break
        for client in list(self.clients):
            if not self._read(client):
                client.lost = True
            client.flush()
            if client.lost:
                self._drop(client)

    def _read(self, client: Client) -> bool:
        """Read what the client sent; False when it closed or broke the protocol."""
        open_ = True
        while open_:
            try:
                data = client.sock.recv(READ_SIZE)
            except BlockingIOError:
                break
            except OSError:
                return False
            open_ = bool(data)  # at its end, what came before it still counts
            client.inbox += data
        frames = parse_frames(client.inbox)
        if len(client.inbox) > MAX_BACKLOG:  # no frame ends within a megabyte: not a python-can-remote client
            log.warning("remote client %s sent %d bytes without a whole frame", client.name, len(client.inbox))
            return False
        for opcode, payload in frames:
            if opcode == _CLOSE:
                client.queue(ws_frame(_CLOSE, payload[:2]))
                client.flush()
                return False
            if opcode == _PING:
                client.queue(ws_frame(_PONG, payload))
                continue
            try:
                event = decode_message(opcode, payload)
            except (ValueError, TypeError) as exc:
                log.warning("remote client %s sent an unreadable frame: %s", client.name, exc)
                continue
            if isinstance(event, can.Message):
                event.timestamp = time.time()
                self._deliver(event, source=client)
            elif isinstance(event, dict) and str(event.get("type", "")).startswith("periodic"):
                self._refuse_periodic(client)
        return open_

    def _deliver(self, msg: can.Message, source: Client | None) -> None:
        if source is not None:
            self._received.append(msg)
        frames: dict[bool, bytes] = {}
        for client in self.clients:
            if client is source and not client.own:
                continue
            frame = frames.get(client.binary)
            if frame is None:
                frame = frames[client.binary] = encode_message(msg, client.binary)
            client.queue(frame)
            if source is None:
                client.flush()

    def _refuse_periodic(self, client: Client) -> None:
        if not client.refused_periodic:
            client.refused_periodic = True
            log.warning("remote client %s asked for periodic sends: not emulated", client.name)
        client.queue(_event("error", "periodic sends are not supported by hild emulate"))

    def _drop(self, client: Client) -> None:
        self.clients.remove(client)
        with contextlib.suppress(OSError):
            client.sock.close()
        log.info("remote client %s disconnected", client.name)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        self._closed.set()
        self._thread.join(2 * ACCEPT_POLL + HANDSHAKE_TIMEOUT)
        self._listener.close()
        self.pump()  # adopt whoever finished a handshake meanwhile, so they are told too
        for client in self.clients:  # a websocket close: ours, then the client's answer, then the connection's end
            with contextlib.suppress(OSError):
                client.sock.setblocking(True)
                client.sock.sendall(ws_frame(_CLOSE, struct.pack(">H", 1001)))  # 1001: going away
                client.sock.shutdown(socket.SHUT_WR)
        deadline = time.monotonic() + CLOSE_TIMEOUT
        for client in list(self.clients):
            with contextlib.suppress(OSError):
                client.sock.settimeout(max(0.0, deadline - time.monotonic()))
                while client.sock.recv(READ_SIZE):
                    pass
            self._drop(client)
        self._arrived.close()
        self._announce.close()
        super().shutdown()

    # ---- the handshake thread -----------------------------------------------------------------------------------
    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                sock, peer = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            name = f"{peer[0]}:{peer[1]}"
            try:
                client = self._handshake(sock, name)
            except (OSError, ValueError, KeyError, UnicodeDecodeError) as exc:
                log.warning("remote client %s refused: %s", name, exc)
                sock.close()
                continue
            if client is None:
                sock.close()
                continue
            log.info("remote client %s connected (%s)", name, _PROTOCOLS[0] if client.binary else _PROTOCOLS[1])
            self._arrivals.put(client)
            with contextlib.suppress(BlockingIOError, OSError):  # full: a word is already waiting
                self._announce.send(b"!")

    def _handshake(self, sock: socket.socket, name: str) -> Client | None:
        """The HTTP upgrade and the bus request, blocking (this thread only); None when a web page was served."""
        sock.settimeout(HANDSHAKE_TIMEOUT)
        buffer = bytearray()
        while b"\r\n\r\n" not in buffer:
            chunk = sock.recv(4096)
            if not chunk or len(buffer) > 16384:
                raise ValueError("no complete HTTP request")
            buffer += chunk
        head, _, rest = bytes(buffer).partition(b"\r\n\r\n")
        request_line, *lines = head.decode("latin-1").split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines)}
        if headers.get("upgrade", "").lower() != "websocket":
            _serve_page(sock, request_line)
            return None
        offered = [p.strip() for p in headers.get("sec-websocket-protocol", _PROTOCOLS[1]).split(",")]
        binary = _PROTOCOLS[0] in offered
        sock.sendall(
            (
                "HTTP/1.1 101 Switching Protocols\r\nUpgrade: WebSocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Accept: {accept_key(headers['sec-websocket-key'])}\r\n"
                f"Sec-WebSocket-Protocol: {_PROTOCOLS[0] if binary else _PROTOCOLS[1]}\r\n\r\n"
            ).encode()
        )
        inbox = bytearray(rest)
        while not (frames := parse_frames(inbox)):
            chunk = sock.recv(4096)
            if not chunk:
                raise ValueError("closed before its bus request")
            inbox += chunk
        (opcode, payload), *early = frames
        event = decode_message(opcode, payload)
        if not isinstance(event, dict) or event.get("type") != "bus_request":
            raise ValueError("the first message is not a bus request")
        config = event.get("payload", {}).get("config", {})
        sock.sendall(_event("bus_response", {"channel_info": self.channel_info}))
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        leftover = bytearray().join(ws_frame(op, data) for op, data in early) + inbox  # none from python-can-remote
        return Client(sock, name, binary, own=bool(config.get("receive_own_messages")), inbox=leftover)


def _serve_page(sock: socket.socket, request_line: str) -> None:
    """python-can-remote's trace page (its ``web`` directory), for a browser pointed at the bus."""
    import can_remote

    parts = request_line.split()
    root = (Path(can_remote.__file__).parent / "web").resolve()
    path = (root / (parts[1] if len(parts) > 1 else "/").split("?")[0].lstrip("/")).resolve()
    if path.is_dir():
        path = path / "index.html"
    if path.with_name(path.name + ".gz").is_file():
        path = path.with_name(path.name + ".gz")
    if root not in path.parents or not path.is_file():
        sock.sendall(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
        return
    kind, encoding = mimetypes.guess_type(str(path), strict=False)
    body = path.read_bytes()
    head = f"HTTP/1.1 200 OK\r\nContent-Type: {kind or 'application/octet-stream'}\r\nContent-Length: {len(body)}\r\n"
    if encoding:
        head += f"Content-Encoding: {encoding}\r\n"
    sock.sendall(head.encode() + b"Connection: close\r\n\r\n" + body)
