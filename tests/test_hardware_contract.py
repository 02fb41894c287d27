"""The hardware contract's lifecycle names: the same as controllers' (``on_configure`` …), with the earlier names
still honoured for drivers written before."""

from __future__ import annotations

import pytest

from hild.arrays import JointState, ServoCommand
from hild.hardware import HardwareComponent


def test_a_driver_with_the_earlier_hook_names_still_has_its_hooks_called() -> None:
    calls: list[str] = []
    with pytest.warns(DeprecationWarning, match=r"Old: .*\(configure → on_configure, cleanup → on_cleanup\)"):

        class Old(HardwareComponent):
            def configure(self) -> None:
                calls.append("configure")

            def cleanup(self) -> None:
                calls.append("cleanup")

            def read(self, t: float, dt: float, state: JointState) -> None: ...

            def write(self, t: float, dt: float, command: ServoCommand) -> None: ...

    driver = Old.__new__(Old)
    driver.on_configure()
    driver.on_activate()  # not overridden: the base's no-op
    driver.on_cleanup()
    assert calls == ["configure", "cleanup"]


def test_a_driver_with_the_current_names_gets_no_warning(recwarn: pytest.WarningsRecorder) -> None:
    class New(HardwareComponent):
        def on_configure(self) -> None: ...

        def read(self, t: float, dt: float, state: JointState) -> None: ...

        def write(self, t: float, dt: float, command: ServoCommand) -> None: ...

    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]
