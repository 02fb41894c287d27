#!/usr/bin/env python3
"""Soak a real daemon under random goals, servo streams and injected faults, twin or CAN (``hild.bench.soak``;
``hild bench --only soak`` runs the twin). ``--help`` lists the flags."""

import sys

from hild.bench.soak import main

if __name__ == "__main__":
    sys.exit(main())
