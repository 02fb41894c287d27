"""The compiled momentum update (hild/dynamics/_momentum.c) against the Python path it replaces on the cycle: the
same figures to the bit, used only when they are, and the Python path wherever it is not built or disagrees."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.dynamics import compiled
from hild.dynamics.momentum import MomentumObserver
from tests.conftest import CONFIGS

ARM6 = CONFIGS / "arm6.xml"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
# A tendon couples two joints: the observer then runs the full position stage (mj_fwdPosition), not its subset.
TENDON = """
<mujoco model="coupled">
  <worldbody>
    <body name="a">
      <joint name="j1" type="hinge" axis="0 1 0" damping="0.3"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="1.5"/>
      <body name="b" pos="0.3 0 0">
        <joint name="j2" type="hinge" axis="0 1 0" armature="0.01"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03" mass="0.8"/>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="coupling" stiffness="20" damping="0.5">
      <joint joint="j1" coef="1"/>
      <joint joint="j2" coef="-0.5"/>
    </fixed>
  </tendon>
</mujoco>
"""


def pair(path: Path, joints: list[str], **kwargs: Any) -> tuple[MomentumObserver, MomentumObserver]:
    fast = MomentumObserver(path, joints, 150.0, 0.001, **kwargs)
    slow = MomentumObserver(path, joints, 150.0, 0.001, compiled=False, **kwargs)
    assert fast.implementation == "compiled", fast.implementation
    assert slow.implementation.startswith("python")
    return fast, slow


@pytest.mark.parametrize(
    ("joints", "gravity"),
    [
        (JOINTS, True),  # the engine's case: one block of dofs, g(q) shared with the supervisor
        (JOINTS, False),
        (["wrist_1", "shoulder_pan", "elbow"], True),  # a subset out of model order: gathered, not one block
    ],
)
def test_on_arm6_it_gives_the_python_paths_figures_to_the_bit(joints: list[str], gravity: bool) -> None:
    fast, slow = pair(ARM6, joints, gravity=gravity)
    rng = np.random.default_rng(11)
    n = len(joints)
    q, qd = rng.uniform(-1.5, 1.5, n), rng.normal(0.0, 1.0, n)
    for o in (fast, slow):
        o.reset(q, qd)
    for k in range(3000):
        if k % 1000 == 999:  # a restart midway, as after a stale reading
            for o in (fast, slow):
                o.reset(q, qd)
        q, qd, tau = q + 0.001 * qd, qd + rng.normal(0.0, 0.3, n), rng.normal(0.0, 15.0, n)
        dt = 0.001 + rng.uniform(-2e-4, 2e-4)  # the measured interval, not the nominal one
        assert fast.update(q, qd, tau, dt).tobytes() == slow.update(q, qd, tau, dt).tobytes()
        if gravity:
            assert fast.gravity.tobytes() == slow.gravity.tobytes()
            out = np.empty(n)
            assert fast.gravity_at(q, out) and out.tobytes() == slow.gravity.tobytes()
    assert np.abs(fast.residual).max() > 1.0  # the random torques were not explained: something was compared


def test_with_a_tendon_it_runs_the_full_position_stage_and_still_agrees(tmp_path: Path) -> None:
    path = tmp_path / "coupled.xml"
    path.write_text(TENDON)
    fast, slow = pair(path, ["j1", "j2"], gravity=True)
    assert not fast._staged
    rng = np.random.default_rng(3)
    q, qd = np.array([0.2, -0.4]), np.array([0.5, 0.1])
    for o in (fast, slow):
        o.reset(q, qd)
    for _ in range(500):
        q, qd, tau = q + 0.001 * qd, qd + rng.normal(0.0, 0.2, 2), rng.normal(0.0, 3.0, 2)
        assert fast.update(q, qd, tau, 0.001).tobytes() == slow.update(q, qd, tau, 0.001).tobytes()
        assert fast.gravity.tobytes() == slow.gravity.tobytes()


def test_building_it_leaves_the_residual_array_as_it_found_it() -> None:
    """The check before use runs both updates on the observer's own arrays: the cycle log's tau_ext keeps its NaN."""
    residual = np.full(6, np.nan)
    observer = MomentumObserver(ARM6, JOINTS, 150.0, 0.001, gravity=True, residual=residual)
    assert observer.implementation == "compiled"
    assert observer.residual is residual and np.isnan(residual).all()
    assert observer.evaluated_at == []  # no reading is claimed as evaluated: gravity_at waits for a real one
    assert not observer.gravity_at(np.zeros(6), np.empty(6))


def test_without_the_compiled_module_it_runs_python_and_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "hild.dynamics._momentum", None)  # import fails, as where gcc was missing
    observer = MomentumObserver(ARM6, JOINTS, 150.0, 0.001)
    assert observer.implementation.startswith("python (the compiled update was not built")
    observer.reset(np.zeros(6), np.zeros(6))
    assert np.isfinite(observer.update(np.full(6, 0.01), np.full(6, 0.1), np.zeros(6), 0.001)).all()


def test_a_compiled_update_that_disagrees_by_one_bit_is_not_used(monkeypatch: pytest.MonkeyPatch) -> None:
    real = compiled.momentum_kernel

    class OffByOneBit:
        def __init__(self, kernel: Any, residual: np.ndarray) -> None:
            self.kernel, self.residual = kernel, residual

        def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
            self.kernel.reset(q, qd)

        def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> None:
            self.kernel.update(q, qd, tau, dt)
            self.residual[2] = np.nextafter(self.residual[2], np.inf)

    def skewed(observer: MomentumObserver) -> tuple[Any, str]:
        kernel, why = real(observer)
        return OffByOneBit(kernel, observer.residual), why

    monkeypatch.setattr(compiled, "momentum_kernel", skewed)
    observer = MomentumObserver(ARM6, JOINTS, 150.0, 0.001)
    assert observer.implementation.startswith("python (the compiled update disagreed with it: residual at reading 1")
    reference = MomentumObserver(ARM6, JOINTS, 150.0, 0.001, compiled=False)
    q, qd, tau = np.full(6, 0.2), np.full(6, 0.3), np.full(6, 1.0)
    for o in (observer, reference):
        o.reset(np.zeros(6), np.zeros(6))
    assert observer.update(q, qd, tau, 0.001).tobytes() == reference.update(q, qd, tau, 0.001).tobytes()


@pytest.mark.parametrize(
    ("q", "words"),
    [(np.zeros(5), "q: expected 6 contiguous float64 values"), (np.zeros(6, np.float32), "q: expected 6")],
)
def test_a_reading_of_the_wrong_shape_or_type_is_refused_not_read_past(q: np.ndarray, words: str) -> None:
    observer = MomentumObserver(ARM6, JOINTS, 150.0, 0.001)
    with pytest.raises(ValueError, match=words):
        observer.update(q, np.zeros(6), np.zeros(6), 0.001)


def test_it_is_built_where_the_project_installs() -> None:
    """.ci/run and the README install with gcc present: the cycle gets the compiled update, not a silent fallback."""
    from hild.dynamics import _momentum

    assert _momentum.Kernel.__name__ == "Kernel"
    functions, why = compiled.mujoco_functions()
    assert all(functions) and len(functions) == len(compiled.FUNCTIONS), why
