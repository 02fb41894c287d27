#!/usr/bin/env python3
"""Tracking on the lockstep twin, goal acceptance and servo latency over Zenoh, with every knob
(``hild.bench.motion``; ``hild bench --only motion`` runs it with the defaults). ``--help`` lists the flags."""

import sys

from hild.bench.motion import main

if __name__ == "__main__":
    sys.exit(main())
