"""Trajectory math and jerk-limited planning for the trajectory controllers.

A pure library: no daemon, no threads. ``segments``, ``tables`` (many segments as a few arrays: how a long plan
crosses to the cycle process) and ``trajectory`` are plain numpy and cheap to sample on the cycle thread;
``planning`` (whole plans) and ``online`` (the per-cycle generator's types, for the streaming controllers) are
the only modules that import ruckig.
"""
