"""The measuring room: ``hild bench`` and every piece of code that measures hild or the machine under it.

Like the tests, this room may import any library and any driver directly (docs/architecture.md, "Rooms"); no
product code imports it. Modules, one job each: ``cli`` (the command and the order of a run), ``floor`` (the
empty sleep+spin thread), ``probes`` (each library timed alone: Zenoh, python-can, ``mj_step``), ``rigs``
(emulated hardware for a scenario's process, and its loopback bridge), ``measure`` (an in-process engine: warm
up, restart the statistics, count a window), ``window`` (reading the loop statistics without the cycle's help),
``scenarios`` (robot configs and one daemon process per scenario), ``host`` (what runs inside that process),
``load`` (the clients: trajectories, pollers, a servo stream), ``latency`` (command → frame and reply → sample
matching), ``report`` (figures, targets, the table and the JSON), ``children`` (free ports, a child process with a
log file), ``daemon`` (``hild run`` and the CAN emulator as child processes, shared with the tests and tools),
``motion`` and ``soak`` (``hild bench --only motion``, ``--only soak``). docs/performance.md has the method and what
each figure means.
"""
