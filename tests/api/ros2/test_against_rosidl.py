"""Type hashes against ROS 2 Jazzy itself (the ``ros2-verify`` extra): the type-description JSON files its PyPI
packages ship (written by rosidl when they were built) and rosidl's own hash generator.

- Every message and service those packages ship and hild's typestore can hold: hild's hash equals the shipped one.
- controller_manager_msgs and control_msgs are not on PyPI: their definitions (hild/api/ros2/definitions.py) are
  run through rosidl_adapter (.msg/.srv/.action → .idl) and rosidl_generator_type_description, exactly as a ROS
  build does; hild's hashes equal the generated ones. (This checks hild's derivation of services and actions and
  its hashing.)
- The released files themselves (``released/``, the Jazzy releases definitions.py copies) go through the same
  build: every type hash it writes — each message, service, its request/response/event, each action's derived
  types — equals hild's. With test_released.py (the same fields) this holds hild to what a current Jazzy install
  computes, not only to its own definitions.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import sys
from pathlib import Path

import pytest

generator = pytest.importorskip(
    "rosidl_generator_type_description", reason="the ros2-verify extra (ROS 2 Jazzy from PyPI) is not installed"
)

from rosidl_adapter.action import convert_action_to_idl  # noqa: E402
from rosidl_adapter.msg import convert_msg_to_idl  # noqa: E402
from rosidl_adapter.srv import convert_srv_to_idl  # noqa: E402

from hild.api.ros2 import types  # noqa: E402
from hild.api.ros2.definitions import ACTIONS, MESSAGES, SERVICES  # noqa: E402
from tests.api.ros2.conftest import released_files  # noqa: E402

SHARE = Path(sys.prefix) / "share"


def shipped(kind: str) -> dict[str, str]:
    """type name → RIHS01 hash from the JSON files Jazzy's packages ship (the first entry is the type itself)."""
    out = {}
    for path in sorted(SHARE.glob(f"*/{kind}/*.json")):
        first = json.loads(path.read_text())["type_hashes"][0]
        out[first["type_name"]] = first["hash_string"]
    return out


def test_every_shipped_message_hild_holds_has_jazzys_hash() -> None:
    store = types.typestore()
    known = {name: value for name, value in shipped("msg").items() if name in store.fielddefs}
    assert len(known) >= 100, sorted(known)  # std_msgs, sensor_msgs, geometry_msgs, trajectory_msgs, action_msgs …
    wrong = {name: (types.type_hash(name), value) for name, value in known.items() if types.type_hash(name) != value}
    assert wrong == {}


def test_every_shipped_service_has_jazzys_hash() -> None:
    """hild's service hash (rosbags on the struct rosidl derives) for every .srv the packages ship."""
    hashes = shipped("srv")
    assert len(hashes) >= 15, sorted(hashes)
    wrong = {}
    for name, value in hashes.items():
        package, _, short = name.split("/")
        text = (SHARE / package / "srv" / f"{short}.srv").read_text()
        request, response = re.split(r"^---[ \t]*$", text, maxsplit=1, flags=re.MULTILINE)
        ours = types.service_store(name, request, response).hash_rihs01(name)
        if ours != value:
            wrong[name] = (ours, value)
    assert wrong == {}


def write_package(root: Path, package: str) -> list[tuple[Path, Path]]:
    """hild's definitions of ``package`` as ROS source files: (package dir, relative path) each."""
    files: list[tuple[Path, str]] = []
    for name, (text, _) in MESSAGES.items():
        files.append((name, text))
    for name, srv in SERVICES.items():
        files.append((name, f"{srv.request}\n---\n{srv.response}\n"))
    for name, action in ACTIONS.items():
        files.append((name, f"{action.goal}\n---\n{action.result}\n---\n{action.feedback}\n"))
    out = []
    for name, text in files:
        pkg, kind, short = name.split("/")
        if pkg != package:
            continue
        relative = Path(kind) / f"{short}.{kind}"
        (root / package / kind).mkdir(parents=True, exist_ok=True)
        (root / package / relative).write_text(text.replace(f"{package}/", ""))  # a package's own types unqualified
        out.append((root / package, relative))
    return out


def generated_hashes(tmp_path: Path, package: str) -> dict[str, str]:
    """The hashes a ROS build of hild's definitions of ``package`` writes."""
    return rosidl_hashes(tmp_path, package, write_package(tmp_path / "src", package))


def rosidl_hashes(tmp_path: Path, package: str, sources: list[tuple[Path, Path]]) -> dict[str, str]:
    """rosidl_adapter then rosidl_generator_type_description, as a ROS build runs them for ``package``'s
    ``sources`` (package dir, relative path): every type name → hash the generated JSON files list."""
    idl_dir = tmp_path / "idl" / package
    tuples = []
    converters = {"msg": convert_msg_to_idl, "srv": convert_srv_to_idl, "action": convert_action_to_idl}
    for package_dir, relative in sources:
        out_dir = idl_dir / relative.parent
        out_dir.mkdir(parents=True, exist_ok=True)
        with contextlib.redirect_stdout(io.StringIO()):
            idl = converters[relative.parent.name](package_dir, package, relative, out_dir)
        tuples.append(f"{idl_dir}:{idl.relative_to(idl_dir)}")
    output = tmp_path / "out" / package
    deps = ["builtin_interfaces", "std_msgs", "geometry_msgs", "trajectory_msgs", "unique_identifier_msgs",
            "action_msgs", "service_msgs", "lifecycle_msgs", "rcl_interfaces", "sensor_msgs"]  # fmt: skip
    arguments = {
        "package_name": package,
        "output_dir": str(output),
        "idl_tuples": tuples,
        "include_paths": [f"{dep}:{SHARE / dep}" for dep in deps],
    }
    arguments_file = tmp_path / f"{package}.json"
    arguments_file.write_text(json.dumps(arguments))
    hashes = {}
    for path in generator.generate_type_hash(str(arguments_file)):
        entry = json.loads(Path(path).read_text())["type_hashes"]
        hashes.update({item["type_name"]: item["hash_string"] for item in entry})
    return hashes


@pytest.mark.parametrize(
    ("package", "names"),
    [
        (
            "controller_manager_msgs",
            [
                "msg/ControllerState",
                "msg/ChainConnection",
                "msg/HardwareInterface",
                "msg/HardwareComponentState",
                "srv/ListControllers",
                "srv/SwitchController",
                "srv/LoadController",
                "srv/ConfigureController",
                "srv/UnloadController",
                "srv/CleanupController",
                "srv/ReloadControllerLibraries",
                "srv/ListControllerTypes",
                "srv/ListHardwareComponents",
                "srv/ListHardwareInterfaces",
                "srv/SetHardwareComponentState",
            ],
        ),
        (
            "rcl_interfaces",
            [
                "srv/ListParameters",
                "srv/GetParameters",
                "srv/SetParameters",
                "srv/SetParametersAtomically",
                "srv/DescribeParameters",
                "srv/GetParameterTypes",
            ],
        ),
        (
            "control_msgs",
            [
                "msg/JointTolerance",
                "action/FollowJointTrajectory_SendGoal",
                "action/FollowJointTrajectory_GetResult",
                "action/FollowJointTrajectory_FeedbackMessage",
                "msg/GripperCommand",
                *(
                    f"action/{action}_{part}"
                    for action in ("GripperCommand", "ParallelGripperCommand")
                    for part in ("SendGoal", "GetResult", "FeedbackMessage")
                ),
            ],
        ),
    ],
)
def test_definitions_hash_as_rosidl_generates_them(tmp_path: Path, package: str, names: list[str]) -> None:
    generated = generated_hashes(tmp_path, package)
    for short in names:
        name = f"{package}/{short}"
        assert types.type_hash(name) == generated[name], name


def released_sources() -> dict[str, list[tuple[Path, Path]]]:
    """package → its released files as (package dir, relative path), for ``rosidl_hashes``."""
    out: dict[str, list[tuple[Path, Path]]] = {}
    for name, path in released_files().items():
        package_dir = path.parent.parent
        out.setdefault(name.split("/")[0], []).append((package_dir, path.relative_to(package_dir)))
    return out


@pytest.mark.parametrize("package", sorted(released_sources()))
def test_released_files_hash_as_hild_does(tmp_path: Path, package: str) -> None:
    """Every hash rosidl writes for the released files — the types themselves, a service's request, response and
    event, an action's goal, result, feedback, SendGoal, GetResult and FeedbackMessage, and what they reference —
    is hild's."""
    generated = rosidl_hashes(tmp_path, package, released_sources()[package])
    held = types.typestore().fielddefs
    # an action's own type: rmw_zenoh's keys carry its services' and FeedbackMessage's hashes, never its own
    assert {name for name in generated if name not in held} == {n for n in ACTIONS if n.startswith(f"{package}/")}
    compared = {name: value for name, value in generated.items() if name in held}
    assert len([name for name in compared if name.startswith(f"{package}/")]) >= len(released_sources()[package])
    wrong = {name: (types.type_hash(name), value) for name, value in compared.items() if types.type_hash(name) != value}
    assert wrong == {}
