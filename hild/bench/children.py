"""The measuring room's child processes: a free loopback endpoint for one, and ending one that stops on EOF."""

from __future__ import annotations

import socket
import subprocess

END_TIMEOUT = 5.0  # s for a child to end by itself once its stdin is closed


def free_endpoint() -> str:
    """A Zenoh TCP endpoint on 127.0.0.1 nobody listens on now (the OS picks the port)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def end_child(process: subprocess.Popen[str] | subprocess.Popen[bytes], timeout: float = END_TIMEOUT) -> None:
    """Close the child's stdin (its sign to stop), wait for it, and kill it if it does not end in time."""
    if process.stdin is not None:
        process.stdin.close()
    try:
        process.wait(timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
