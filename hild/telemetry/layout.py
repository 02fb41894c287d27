"""Where things live in a hild recording (entity paths, timelines) and the default viewer layout.

One place for the names, so the recorder, the blueprint, the replay helpers and the docs agree. Per-joint values
are one entity per quantity holding a vector (one series per joint, named after the joint): ten ``send_columns``
calls per flush instead of ten per joint, since each call costs ~0.1 ms whatever its size.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun as rr
import rerun.blueprint as rrb

TICK = "tick"  # sequence timeline: the engine's cycle counter
CYCLE_TIME = "cycle_time"  # duration timeline: the cycle clock (sim or wall), seconds since start

QUANTITIES = ("position", "velocity", "effort")
MEASURED, COMMANDED = "measured", "commanded"
TRACKING_ERROR = "joints/tracking_error"  # commanded − measured position
MODE = "joints/mode"  # hild.modes.JointMode: 0 hold, 1 controlled, 2 fault, 3 estop
EVENTS = "events"
LOOP_PERIOD = "loop/period"  # µs
LOOP_DURATION = "loop/duration"  # µs, of the previous completed cycle
ARM = "arm"


def joint_path(quantity: str, which: str) -> str:
    """``joints/<position|velocity|effort>/<measured|commanded>``: one series per joint."""
    return f"joints/{quantity}/{which}"


def body_path(body: str) -> str:
    return f"{ARM}/{body}"


def _only(joints: Sequence[str], j: int) -> rr.SeriesLines:
    return rr.SeriesLines.from_fields(visible_series=[i == j for i in range(len(joints))])


def default_blueprint(joints: Sequence[str], with_arm: bool) -> rrb.Blueprint:
    """3D arm, events and loop timing on the left; joint plots (measured vs commanded, one per joint) in tabs."""
    left: list[rrb.View | rrb.Container] = []
    if with_arm:
        left.append(rrb.Spatial3DView(origin=ARM, name="arm"))
    left += [rrb.TextLogView(origin=EVENTS, name="events"), rrb.TimeSeriesView(origin="loop", name="loop timing (µs)")]
    tabs: list[rrb.View | rrb.Container] = []
    for q in QUANTITIES:
        views = [
            rrb.TimeSeriesView(
                origin=f"joints/{q}",
                name=f"{name} {q}",
                overrides={joint_path(q, MEASURED): _only(joints, j), joint_path(q, COMMANDED): _only(joints, j)},
            )
            for j, name in enumerate(joints)
        ]
        tabs.append(rrb.Grid(*views, name=q))
    tabs.append(rrb.TimeSeriesView(origin=TRACKING_ERROR, name="tracking error (rad)"))
    tabs.append(rrb.TimeSeriesView(origin=MODE, name="joint mode"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=[3, 1, 1] if with_arm else [1, 1]),
            rrb.Tabs(*tabs),
            column_shares=[2, 3],
        ),
        rrb.TimePanel(timeline=CYCLE_TIME),
    )
