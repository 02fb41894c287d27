"""What an import did with each piece of the source: mapped, approximated, or not supported — each with its line.

Every finding points at the element or key it comes from (``file:line``), so a reader can check the decision
against the source. Errors that stop an import are :class:`ImportFailure`, never findings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

Kind = Literal["mapped", "approximated", "unsupported", "tracking"]

SECTIONS: tuple[tuple[Kind, str], ...] = (
    ("mapped", "Mapped"),
    ("approximated", "Approximated"),
    ("unsupported", "Not supported"),
    ("tracking", "Tracking"),  # whether the config's trajectory controllers can meet their own tolerances
)


class ImportFailure(ValueError):
    """The import cannot produce a config; the message names the file, line and element or key."""


@dataclass(frozen=True)
class SourceRef:
    file: str
    line: int | None = None

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file

    @property
    def short(self) -> str:
        """``name:line`` without the directories (for comments in the written config)."""
        name = self.file.replace("\\", "/").rsplit("/", 1)[-1]
        return f"{name}:{self.line}" if self.line else name

    def fail(self, message: str) -> ImportFailure:
        return ImportFailure(f"{self}: {message}")


@dataclass(frozen=True)
class Finding:
    kind: Kind
    where: SourceRef
    text: str


@dataclass
class Report:
    findings: list[Finding] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # printed above the sections (what was written where)
    partial: list[Finding] = field(default_factory=list)  # given controllers and joints left out (also unsupported)

    def mapped(self, where: SourceRef, text: str) -> None:
        self.findings.append(Finding("mapped", where, text))

    def approximated(self, where: SourceRef, text: str) -> None:
        self.findings.append(Finding("approximated", where, text))

    def unsupported(self, where: SourceRef, text: str) -> None:
        self.findings.append(Finding("unsupported", where, text))

    def tracking(self, where: SourceRef, text: str) -> None:
        """Whether a trajectory controller meets its tolerances: what the gains allow, what the twin showed."""
        self.findings.append(Finding("tracking", where, text))

    def dropped(self, where: SourceRef, text: str) -> None:
        """A controller, joint or sensor the source gives that the import leaves out: the import is partial."""
        finding = Finding("unsupported", where, text)
        self.findings.append(finding)
        self.partial.append(finding)

    def partial_failure(self) -> ImportFailure:
        """The error for a partial import the user did not accept (``--allow-partial``)."""
        listed = "\n".join(f"  {f.where}: {f.text}" for f in self.partial)
        return ImportFailure(
            f"{len(self.partial)} controller(s), joint(s) or sensor(s) given cannot be imported:\n{listed}\n"
            "pass --allow-partial to import the rest without them"
        )

    def of(self, kind: Kind) -> list[Finding]:
        return [f for f in self.findings if f.kind == kind]

    def format(self) -> str:
        lines = list(self.notes)
        for kind, title in SECTIONS:
            found = self.of(kind)
            lines.append(f"{title} ({len(found)}):")
            lines.extend(f"  {f.where}: {f.text}" for f in found)
            if not found:
                lines.append("  (none)")
        return "\n".join(lines)
