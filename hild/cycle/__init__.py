"""The cycle domain: what runs in the cycle process (docs/architecture.md, "Three processes").

The engine (read → supervise → controllers → supervise → write), the supervisor and plausibility checks, the
controller manager, transmissions, the pacing loop, real-time settings and the process entry. Nothing here
imports the client domain (``hild.daemon``, ``hild.api``), the main process (``hild.main``) or their libraries
(Zenoh, rerun, rosbags): tests/test_layout.py checks the import graph.
"""
