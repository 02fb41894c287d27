"""The client domain as a process of its own: ``python -m hild.domains.client_process``.

Started (and restarted) by the daemon's main process (:mod:`hild.domains.main_process`) with a pickled
:class:`hild.domains.main_process.ClientSpec` on its standard input and the shared region and doorbell as
inherited file descriptors. It runs :class:`hild.daemon.Daemon` attached to the cycle process the main process
started: Zenoh, the API, telemetry. It exits when told (SIGTERM), when the cycle has stopped, or when the main
process is gone.
"""

from __future__ import annotations

import asyncio
import logging
import pickle
import sys

from hild.cli import setup_logging
from hild.daemon import Daemon, StartupError
from hild.domains.main_process import ClientSpec
from hild.events import log_event
from hild.hardware import HardwareError

log = logging.getLogger("hild.daemon")


def main() -> int:
    spec: ClientSpec = pickle.load(sys.stdin.buffer)
    sys.stdin.close()
    setup_logging(spec.log_level)
    daemon = Daemon(spec.loaded, spec.listen, spec.attachment)
    try:
        return asyncio.run(daemon.run())
    except (HardwareError, StartupError) as exc:
        asyncio.run(daemon.close_telemetry())
        for event in daemon._take_events():
            log_event(event)
        log.error("start-up failed: %s", exc)
        return 1
    finally:
        daemon.cpu_latency.release()


if __name__ == "__main__":
    sys.exit(main())
