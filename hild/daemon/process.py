"""The client domain as a process of its own: ``python -m hild.daemon.process``.

Started (and restarted) by the daemon's main process (:mod:`hild.main.process`) with a pickled
:class:`hild.main.process.ClientSpec` on its standard input and the shared region and wake-up eventfd as
inherited file descriptors. It runs :class:`hild.daemon.daemon.Daemon` attached to the cycle process the main process
started: Zenoh, the API, telemetry. It exits when told (SIGTERM), when the cycle has stopped, or when the main
process is gone.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import sys
from typing import NoReturn

from hild.cli import setup_logging
from hild.cycle.realtime import thaw_heap
from hild.daemon.daemon import Daemon, serve
from hild.daemon.remote import AttachedCycle
from hild.main.process import ClientSpec


def main() -> NoReturn:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C reaches every process: the main one stops us
    spec: ClientSpec = pickle.load(sys.stdin.buffer)
    sys.stdin.close()
    setup_logging(spec.log_level)
    code = serve(Daemon(spec.loaded, spec.listen, AttachedCycle(spec.loaded, spec.attachment)))
    thaw_heap()
    # Everything is closed (the API, telemetry). Zenoh drops the callbacks of undeclared subscribers on its own
    # threads, so at the interpreter's teardown a controller's API half may still be held there, and nanobind
    # (ruckig) reports it as a leak on stderr: end here, after the logs are flushed, without that teardown.
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
