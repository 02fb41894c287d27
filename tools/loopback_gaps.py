"""The loopback CAN pair beside load: each emulated drive's longest silence (``hild.bench.loopback_gaps``).

    python tools/loopback_gaps.py                          # 60 s of moves beside 2 CPU hogs
    python tools/loopback_gaps.py --seconds 600 --hold     # the README example, 10 minutes
    python tools/loopback_gaps.py --restart-every 15       # the client domain SIGKILLed every 15 s

Exit status 1 if a drive faulted or a silence passed half its watchdog. Every process it starts is stopped on exit.
"""

from __future__ import annotations

import sys

from hild.bench.loopback_gaps import main

if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("interrupted: every process it started is stopped", file=sys.stderr)
        sys.exit(130)
