"""ROS package locations without ROS: ``$(find pkg)`` and ``package://pkg/...`` resolved against given roots.

ROS answers these from its install index. Here a user names the roots (``--package-root pkg=DIR``); a package not
named is looked for among the directories above the URDF (a source checkout ``my_arm_description/urdf/arm.urdf``
sits in a directory named after its package), and that guess is reported.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse


@dataclass
class PackageRoots:
    roots: Mapping[str, Path]
    near: Path  # directory of the URDF: its ancestors are searched for packages not in ``roots``
    inferred: dict[str, Path] = field(default_factory=dict)  # guesses made, for the report

    def find(self, package: str) -> Path | None:
        """The package's directory, or None when it is neither given nor an ancestor of the URDF."""
        if package in self.roots:
            return Path(self.roots[package]).resolve()
        for parent in (self.near.resolve(), *self.near.resolve().parents):
            if parent.name == package:
                self.inferred[package] = parent
                return parent
        return None

    def resolve_uri(self, uri: str, base: Path) -> tuple[Path | None, str | None]:
        """A mesh reference → (absolute path, None), or (None, why not). Relative paths are relative to ``base``."""
        if uri.startswith("package://"):
            package, _, rest = uri[len("package://") :].partition("/")
            root = self.find(package)
            if root is None:
                return None, f"unknown ROS package {package!r}: pass --package-root {package}=DIR"
            return root / unquote(rest).lstrip("/"), None  # package://pkg//meshes/… is inside pkg, not at /meshes
        if uri.startswith("file://"):
            # file:////abs/… (xacro's file:///$(find pkg)/…): POSIX keeps a leading "//" as it is, so trim it
            return Path("/" + unquote(urlparse(uri).path).lstrip("/")), None
        if "://" in uri:
            return None, f"unsupported URI scheme in {uri!r} (package:// and file:// are)"
        return (base / uri).resolve(), None


def parse_package_root(text: str) -> tuple[str, Path]:
    """``NAME=DIR`` → (name, path); raises ValueError otherwise."""
    name, sep, directory = text.partition("=")
    if not sep or not name or not directory:
        raise ValueError(f"expected NAME=DIR, got {text!r}")
    return name, Path(directory)
