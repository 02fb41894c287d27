"""The CAN bench rig's channels, served to a daemon's drivers in another process — as before [teleop].

Only with ``hild bench --stock-can-bridge`` now (and for ``bridged_document``/``virtual_channels``, which the rig
process shares): its stock server's per-client threads wait for the daemon's GIL once per blocking socket call,
and beside busy Python threads the cycle's frames queue — the 195 ms command → frame finding (docs/performance.md,
"The command path: the 195 ms finding"). The default is :mod:`hild.bench.rigs.can_process`.

The ``mit_can`` bench rig emulates its drives on python-can ``virtual`` channels in the scenario's process
(``hild.bench.host``). A virtual channel does not leave its process, and with ``realtime.cycle_process`` the
drivers run in the cycle process. So, as ``hild emulate --serve-remote`` does for a rig of its own, each channel is
served by a python-can-remote server on 127.0.0.1 (a thread of the scenario's process, bridging every client onto
the channel) and the daemon's config names the bus ``interface: remote`` at that server. The drivers then pay a
socket ``send`` and a zero-timeout ``recv`` per frame (socketcan's cost, roughly, not the virtual bus's in-process
queue), and a frame reaches the emulated drive one loopback hop later; the bridge's threads share the GIL with
the emulated drives and the daemon's asyncio side, never with the cycle process. Their CPU is reported apart
(``bridge``), like the emulator's.

Measuring code: the measuring room may import the python-can stack, like the tests (docs/architecture.md,
"Rooms"); it only starts servers, and the product's code paths never see it.
"""

from __future__ import annotations

import contextlib
import json
import threading
from pathlib import Path
from typing import Any

from hild.config.documents import load_document

HOST = "127.0.0.1"
THREAD_NAME = "bench-can-bridge"
BRIDGED_TARGETS = ("process_request_thread", "_send_to_client")  # the server's per-client threads


def bridged_document(data: dict[str, Any], channels: dict[str, str]) -> dict[str, Any]:
    """``data`` with every bus on a served virtual channel renamed to the remote server of that channel
    (``channels``: virtual channel → ws:// address). Pure: the tests check it."""
    out = json.loads(json.dumps(data))
    for component in out.get("hardware", {}).values():
        bus = component.get("params", {}).get("bus")
        if isinstance(bus, dict) and bus.get("interface") == "virtual" and str(bus.get("channel")) in channels:
            bus["interface"] = "remote"
            bus["channel"] = channels[str(bus["channel"])]
    return out


def virtual_channels(data: dict[str, Any]) -> list[str]:
    """The virtual channels the config's hardware components use, in order."""
    found = []
    for component in data.get("hardware", {}).values():
        bus = component.get("params", {}).get("bus")
        if isinstance(bus, dict) and bus.get("interface") == "virtual" and str(bus.get("channel")) not in found:
            found.append(str(bus["channel"]))
    return found


class CanBridge:
    def __init__(self) -> None:
        self._servers: list[Any] = []
        self._threads: list[threading.Thread] = []

    def serve(self, config: Path) -> Path:
        """Serve every virtual channel of ``config``; write and return the daemon's config (remote buses)."""
        from can_remote import RemoteServer  # python-can's remote interface, a dependency of drivers/can

        data: dict[str, Any] = load_document(config)
        channels = {}
        for channel in virtual_channels(data):
            server = RemoteServer(HOST, 0, interface="virtual", channel=channel, receive_own_messages=False)
            thread = threading.Thread(target=server.serve_forever, name=THREAD_NAME, daemon=True)
            thread.start()
            self._servers.append(server)
            self._threads.append(thread)
            channels[channel] = f"ws://{HOST}:{server.server_address[1]}/"
        if not channels:
            raise ValueError(f"{config}: no hardware component on a virtual CAN channel to bridge")
        bridged = config.with_name(f"{config.stem}-bridged{config.suffix}")
        bridged.write_text(json.dumps(bridged_document(data, channels), indent=1))  # JSON is YAML
        return bridged

    def threads(self) -> list[int]:
        """Native ids of the servers' threads (listening, and per client: receiving and sending)."""
        ids = []
        for thread in threading.enumerate():
            if thread.native_id is None:
                continue
            if thread.name == THREAD_NAME or any(target in thread.name for target in BRIDGED_TARGETS):
                ids.append(thread.native_id)
        return ids

    def close(self) -> None:
        for server in self._servers:
            with contextlib.suppress(Exception):
                server.shutdown()
                server.server_close()
        for thread in self._threads:
            thread.join(2.0)
        self._servers, self._threads = [], []
