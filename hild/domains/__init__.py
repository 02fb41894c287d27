"""The two domains of a running daemon (docs/architecture.md, "Two domains").

- ``link``          what the client domain needs of the cycle: the :class:`~hild.domains.link.CycleLink` protocol,
                    met by the :class:`~hild.engine.Engine` itself (one process) and by ``remote.RemoteCycle``
- ``layout``        the engine's cells in the shared region, as both processes name and size them
- ``remote``        the client domain's side: spawns, feeds and watches the cycle process
- ``cycle_process`` the cycle process: ``python -m hild.domains.cycle_process``, started only by ``remote``
"""
