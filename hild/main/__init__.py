"""The daemon's main process: starts and keeps the client domain and the cycle process, speaks to systemd.

It is the process ``hild run`` is, the one systemd and a user stop (docs/architecture.md, "Three processes").
"""
