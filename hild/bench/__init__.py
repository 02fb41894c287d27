"""``hild bench``: the real-time cycle measured side by side with the machine's own floor, in one run.

Modules, one job each: ``cli`` (the command and the order of a run), ``floor`` (the empty sleep+spin thread and
the library probes), ``scenarios`` (robot configs and one daemon process per scenario), ``host`` (what runs inside
that process), ``load`` (the clients: trajectories, pollers, a servo stream), ``latency`` (command → frame and
reply → sample matching), ``report`` (statistics, targets, the table and the JSON). docs/performance.md has the
method and what each figure means.
"""
