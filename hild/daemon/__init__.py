"""The client domain: the asyncio daemon around the cycle (docs/architecture.md, "Three processes").

``Daemon`` runs the Zenoh API (``hild.api``), the ROS 2 face and telemetry feeding on one asyncio loop, and
reaches the cycle only through a ``CycleLink``: the cycle process across the shared region, or an engine in this
very process for lockstep tests and embedding. ``process`` is its entry under ``hild run``.
"""
