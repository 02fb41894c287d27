"""Bad input found from outside (issue 15, "Bad input"): each finding reproduced here, then refused cheaply.

1. Unknown keys: the refusal names a few and counts the rest; it never sorts or joins them all.
2. Caps on elements, keys and depth, enforced while decoding.
3. Per-key size limits: a request larger than its service needs is refused before it is decoded.
4. Large command samples: at most one pending per input, superseded before decoding; none decoded for an
   inactive controller.

Assertions are on counts, outcomes and text lengths; the one CPU bound is generous (the old refusal took 45 ms).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from hild.action import GoalRejected
from hild.api.services import RequestError, names, parse_request
from hild.controllers.servo import ServoController
from hild.controllers.trajectory_goals import GoalContext, parse_goal
from hild.motion.limits import KinematicLimits

WIDE = 90_000  # keys: the object of the finding (1 MiB of them when sent)


def wide(n: int = WIDE, **body: object) -> dict[str, object]:
    return {**{f"k{k}": 0 for k in range(n)}, **body}


def goal_context() -> GoalContext:
    ones = np.ones(2)
    return GoalContext(
        joints=("a", "b"),
        soft_lower=-ones,
        soft_upper=ones,
        limits=KinematicLimits(ones, ones, ones),
        allow_partial=False,
        path_position=0 * ones,
        path_velocity=0 * ones,
        goal_position=0 * ones,
        goal_velocity=0 * ones,
        goal_time=1.0,
        start_tolerance=0.01,
    )


# ---- 1. unknown keys -------------------------------------------------------------------------------------------------
def test_a_goal_of_90k_unknown_keys_is_refused_in_a_short_sentence_at_once() -> None:
    payload = wide(trajectory={"joint_names": ["a", "b"], "points": [{"positions": [0, 0]}]})
    start = time.process_time()
    with pytest.raises(GoalRejected) as info:
        parse_goal(payload, goal_context())
    cpu = time.process_time() - start
    error = str(info.value)
    assert error.startswith("goal: unknown keys ['k0', 'k1', 'k2'] and 89997 more (allowed: ")
    assert len(error) < 200 and cpu < 0.005, (len(error), cpu)  # was 889 997 characters and 45 ms


def test_a_few_unknown_keys_are_still_all_named_sorted() -> None:
    with pytest.raises(GoalRejected, match=r"^goal: unknown keys \['x', 'y'\] \(allowed: \["):
        parse_goal({"y": 1, "trajectory": {}, "x": 2}, goal_context())
    with pytest.raises(RequestError, match=r"^unknown field\(s\) 'x', 'y' \(allowed: activate, deactivate\)$"):
        parse_request(b'{"y": 1, "x": 2}', {"activate": names, "deactivate": names})


def test_a_request_of_thousands_of_unknown_fields_is_refused_in_a_short_sentence() -> None:
    raw = json.dumps(wide(4000)).encode()  # within a request's limits: refused by its keys
    with pytest.raises(RequestError) as info:
        parse_request(raw, {"activate": names})
    error = str(info.value)
    assert error == "unknown field(s) 'k0', 'k1', 'k2' and 3997 more (allowed: activate)"


def test_a_servo_target_of_thousands_of_unknown_keys_is_refused_in_a_short_sentence() -> None:
    servo = ServoController.__new__(ServoController)  # the key check comes before anything configured is read
    servo.active = True
    with pytest.raises(ValueError) as info:
        servo.accept(wide(4000, positions=[0.0]))
    expected = "unknown keys ['k0', 'k1', 'k2'] and 3997 more; expected positions and optional velocities"
    assert str(info.value) == expected
