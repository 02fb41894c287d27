"""The client domain as a process of its own: ``python -m hild.domains.client_process``.

Started (and restarted) by the daemon's main process (:mod:`hild.domains.main_process`) with a pickled
:class:`hild.domains.main_process.ClientSpec` on its standard input and the shared region and wake-up eventfd as
inherited file descriptors. It runs :class:`hild.daemon.Daemon` attached to the cycle process the main process
started: Zenoh, the API, telemetry. It exits when told (SIGTERM), when the cycle has stopped, or when the main
process is gone.
"""

from __future__ import annotations

import pickle
import signal
import sys

from hild.cli import setup_logging
from hild.daemon import Daemon, serve
from hild.domains.main_process import ClientSpec


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C reaches every process: the main one stops us
    spec: ClientSpec = pickle.load(sys.stdin.buffer)
    sys.stdin.close()
    setup_logging(spec.log_level)
    return serve(Daemon(spec.loaded, spec.listen, spec.attachment))


if __name__ == "__main__":
    sys.exit(main())
