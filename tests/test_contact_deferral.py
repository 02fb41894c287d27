"""What the contact check leaves for after the cycle's writes (docs/performance.md, "The observer's cost"): a quiet
check's load update and force judgement run later on the same numbers, so every figure and every latch is the one
the check gives when it does everything before the command; and the force's bound never lets a judgement that
could report wait."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.emulator.disturbances import Push
from hild.arrays import JointState, ServoCommand
from hild.bench.contact import goal_done, random_direction, sample_pose
from hild.bench.contact_adapters import ContactAdapters
from hild.bench.contact_rig import JTC, ContactRig, RigSpec
from hild.cycle.contact import ContactMonitor, ContactSettings
from hild.cycle.contact_force import ToolForce
from hild.dynamics.friction import FrictionArrays


class FixedJacobian:
    def __init__(self, jac: np.ndarray) -> None:
        self.jac = jac

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        return self.jac


@pytest.mark.parametrize("seed", range(6))
def test_a_judgement_found_quiet_never_exceeds_the_limit_it_was_bounded_by(seed: int) -> None:
    """Random Jacobians and random walks of the estimate with jumps: whenever `quiet` answers yes, the judgement
    that follows finds an excess below the limit — and the bound is tight enough to answer yes most of the time."""
    rng = np.random.default_rng(seed)
    dt, limit, n = 0.001, 8.0, 6
    kin = FixedJacobian(rng.normal(0.0, 0.4, (3, n)))
    force = ToolForce(kin, n, damping=0.05, bandwidth=300.0, baseline=0.1, settle=0.02)
    q, margin = np.zeros(n), np.abs(rng.normal(0.0, 0.3, n))
    tau = rng.normal(0.0, 0.5, n)
    force.judge(q, tau, margin, dt)
    quiet = judged = loud = 0
    for k in range(4000):
        force.refresh(q, margin)
        force.predict(tau, dt)
        if k % 7 == 0:  # the pose moved: a new G the next judge uses
            kin.jac = kin.jac + rng.normal(0.0, 0.01, (3, n))
            force.refresh(q, margin)
            force.predict(tau, dt)
        jump = rng.normal(0.0, 3.0, n) if k % 200 == 199 else 0.0  # now and then a jump
        tau = 0.99 * tau + rng.normal(0.0, 0.05, n) + jump  # else noise about a slowly wandering level
        said_quiet = force.quiet(tau.tolist(), dt, limit)
        excess = force.judge(q, tau, margin, dt)
        judged += 1
        loud += excess >= limit
        if said_quiet:
            quiet += 1
            assert excess < limit, f"cycle {k}: bounded quiet, judged {excess:.6g} N"
    assert quiet > judged // 2
    assert loud > 0  # the jumps did cross the limit: the bound was tested where it matters


def test_no_prediction_stands_after_a_restart_a_bare_refresh_or_another_period() -> None:
    kin = FixedJacobian(np.eye(3, 6))
    force = ToolForce(kin, 6, damping=0.05, bandwidth=300.0, baseline=0.1, settle=0.0)
    q, tau, margin = np.zeros(6), np.zeros(6), np.zeros(6)
    force.judge(q, tau, margin, 0.001)
    force.refresh(q, margin)
    force.predict(tau, 0.001)
    assert force.quiet(tau.tolist(), 0.001, 8.0)
    assert not force.quiet(tau.tolist(), 0.002, 8.0)  # another filter share than the one predicted for
    force.refresh(q, margin)
    assert not force.quiet(tau.tolist(), 0.001, 8.0)  # a new G without its prediction
    force.predict(tau, 0.001)
    force.restart()
    assert not force.quiet(tau.tolist(), 0.001, 8.0)


def run(steps: int, defer: bool) -> np.ndarray:
    """The bench's rig with the config's thresholds, random moves, pushes of 6–25 N at the tool and recoveries;
    per cycle: tau_ext, the force figures, the joints' margins, the final command and whether a collision latched.
    ``defer=False``: every check does all of its work before the command (nothing is ever found quiet)."""
    rig = ContactRig(RigSpec(safety=ContactAdapters().observer_safety(True)))
    try:
        engine = rig.engine
        assert engine is not None and engine.contact is not None
        contact = engine.contact
        tool = contact.tool_force
        assert tool is not None
        if not defer:
            contact._quiet = lambda values: False  # type: ignore[method-assign]
            tool.quiet = lambda values, dt, limit: False  # type: ignore[method-assign]
        rng = np.random.default_rng(11)
        rig.activate(JTC)
        goal, since, rows = None, 0, []
        for k in range(steps):
            if not engine.supervisor.fault.any() and (goal is None or goal_done(rig, goal)):
                goal = rig.move(sample_pose(rng))
            if k % 600 == 300:
                push = float(rng.uniform(6.0, 25.0)) * random_direction(rng)
                rig.plant.pushes.append(Push(force=tuple(push.tolist()), start=rig.now + 0.001, duration=0.15))
            rig.cycle()
            rows.append(
                np.concatenate(
                    [
                        contact.tau_ext,
                        [tool.excess, tool.change, tool.level, float(contact.collided)],
                        contact._extra,
                        engine.final.position,
                        engine.final.effort,
                        engine.final.kp,
                    ]
                )
            )
            since = since + 1 if contact.collided else 0
            if since > 50:  # recover, as the bench does
                rig.plant.pushes.clear()
                rig.request(engine.reset, limit=2.0)
                rig.request(engine.enable, limit=2.0)
                rig.activate(JTC)
                goal, since = None, 0
        return np.array(rows)
    finally:
        rig.close()


def test_deferring_the_quiet_checks_changes_no_figure_and_no_latch() -> None:
    deferred, upfront = run(2400, True), run(2400, False)
    latched = deferred[:, 9]
    assert latched.any() and not latched.all()  # the pushes were caught and the arm recovered
    assert np.array_equal(deferred, upfront, equal_nan=True)


class Scripted:
    """A stand-in observer whose residual follows a script: ``update`` returns the next row."""

    def __init__(self, rows: np.ndarray) -> None:
        self.rows, self.k = rows, 0
        self.residual = np.zeros(rows.shape[1])

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        self.residual[:] = self.rows[self.k % len(self.rows)]
        self.k += 1
        return self.residual


def scripted_monitor(rows: np.ndarray) -> ContactMonitor:
    n = rows.shape[1]
    settings = ContactSettings(
        gain=100.0,
        use_reply=True,
        contact=np.full(n, 1.0),
        collision=np.full(n, 2.0),
        model_margin=0.1,
        retract=False,
        reflex_stiffness=0.25,
        retract_distance=0.005,
        retract_time=0.2,
    )
    return ContactMonitor(
        tuple(f"j{i}" for i in range(n)),
        settings,
        Scripted(rows),
        effort_limit=np.full(n, 30.0),
        applies_gains=np.ones(n, dtype=bool),
        friction=FrictionArrays.zeros(n),
        emit=lambda *_: None,
        update_rate=1000.0,
    )


def test_a_monitor_whose_after_write_is_never_called_does_the_deferred_work_before_its_next_check() -> None:
    """ContactMonitor on its own (nothing calls after_write): the next check settles the deferred load update
    first, so loads, margins, levels and collisions are those of a monitor that never defers."""
    rng = np.random.default_rng(4)
    rows = rng.normal(0.0, 0.5, (400, 3))
    rows[150:160, 1] = 2.5  # a collision on j1 among quiet cycles
    rows[300:320, 2] = 1.4  # a contact on j2
    deferring, upfront = scripted_monitor(rows), scripted_monitor(rows)
    upfront._quiet = lambda values: False  # type: ignore[method-assign]
    state, last = JointState.zeros(3), ServoCommand.zeros(3)
    deferred = 0
    for k in range(400):
        state.effort[:] = rng.normal(0.0, 20.0, 3)  # the load the thresholds rise with
        found = [m.observe(state, last, True, 0.001) for m in (deferring, upfront)]
        deferred += deferring._deferred >= 0.0
        assert found[0] == found[1], f"cycle {k}"
        assert deferring.level == upfront.level
        if deferring._deferred < 0.0:
            assert deferring._load == upfront._load and deferring._extra == upfront._extra
        if deferring.collided:
            deferring.clear()
            upfront.clear()
    assert deferred > 100  # most cycles were quiet and deferred
