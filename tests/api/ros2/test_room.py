"""docs/architecture.md, "Rules": each third-party library lives in one room. ROS 2's libraries (rosbags: CDR and
type hashes; xxhash: rmw_zenoh's GIDs) are imported only in hild/api/ros2, and a daemon without a ``ros2:`` section
never loads them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO
from tests.test_rooms import imports

ROOM = REPO / "hild" / "api" / "ros2"
ROOM_LIBRARIES = ("rosbags", "xxhash")
CODE = [REPO / "hild", REPO / "drivers", REPO / "tools"]
EXEMPT = REPO / "hild" / "bench"  # the measuring room may import anything, like the tests (docs/architecture.md)


def imported_roots(path: Path) -> set[str]:
    return {module.split(".")[0] for module in imports(path)}


def test_ros2_libraries_are_imported_only_in_their_room() -> None:
    outside = [
        f"{path.relative_to(REPO)} imports {library}"
        for folder in CODE
        if folder.exists()
        for path in folder.rglob("*.py")
        if ROOM not in path.parents and EXEMPT not in path.parents
        for library in ROOM_LIBRARIES
        if library in imported_roots(path)
    ]
    assert outside == []


def test_the_room_is_where_rosbags_is_used() -> None:
    assert any("rosbags" in imported_roots(path) for path in ROOM.rglob("*.py"))  # the rule checks something


def test_the_api_without_ros2_never_loads_rosbags() -> None:
    code = "import sys, hild.api.server, hild.daemon.daemon; assert 'rosbags' not in sys.modules, 'rosbags loaded'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_the_independent_implementations_are_used_by_tests_only() -> None:
    """rclpy and pyzeros check hild's bytes (the ros2-verify extra); no shipped code may lean on them."""
    used = [
        f"{path.relative_to(REPO)} imports {library}"
        for folder in CODE
        if folder.exists()
        for path in folder.rglob("*.py")
        if EXEMPT not in path.parents
        for library in ("rclpy", "pyzeros", "ros2_pyterfaces")
        if library in imported_roots(path)
    ]
    assert used == []
