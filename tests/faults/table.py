"""docs/safety.md's fault table: rendered from the scenarios' rows, written between two markers."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from tests.faults.scenarios import Row

DOC = Path(__file__).resolve().parents[2] / "docs" / "safety.md"
BEGIN = "<!-- fault-table:begin -->"
END = "<!-- fault-table:end -->"
HEADER = ("fault", "injected how", "detected after (cycles)", "joints do", "event", "recovery")


def render(rows: Sequence[Row]) -> str:
    """The Markdown table (no trailing newline)."""
    lines = ["| " + " | ".join(HEADER) + " |", "|" + " --- |" * len(HEADER)]
    for row in rows:
        cells = (row.fault, row.injected, row.detected, row.joints, row.event, row.recovery)
        lines.append("| " + " | ".join(cell.replace("\n", " ") for cell in cells) + " |")
    return "\n".join(lines)


def embed(document: str, table: str) -> str:
    """``document`` with the text between the markers replaced by ``table``."""
    start, end = document.find(BEGIN), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{DOC.name} has no {BEGIN} … {END} markers")
    return document[: start + len(BEGIN)] + "\n" + table + "\n" + document[end:]


def committed() -> str:
    """The table as committed in docs/safety.md."""
    document = DOC.read_text()
    start, end = document.find(BEGIN), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{DOC.name} has no {BEGIN} … {END} markers")
    return document[start + len(BEGIN) : end].strip("\n")
