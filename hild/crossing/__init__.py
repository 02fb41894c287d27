"""What crosses between the processes: the client domain, the cycle process and the main process
(docs/architecture.md, "What crosses").

One shared-memory region (:mod:`.region`), carved into fixed-size cells: single-producer queues of records
(:mod:`.queue`), latest-value cells (:mod:`.latest`), sample rings and flags, handed to controllers and the engine
as *mailboxes* (:mod:`.mailboxes`). Neither side ever waits for the other: a full queue refuses, a torn read is
retried next cycle, a slow reader skips. This room imports nothing but the standard library and numpy, so the
cycle process can load it without loading Zenoh, rerun or anything else the client domain uses.
"""
