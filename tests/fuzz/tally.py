"""Examples run per endpoint across the fuzz suite, printed as a table at the end of the session (``pytest -s``)."""

from __future__ import annotations

from collections import Counter

EXAMPLES: Counter[str] = Counter()  # endpoint → hypothesis examples sent
CRASHES: Counter[str] = Counter()  # endpoint → times the daemon (or loader) was found dead / raised unexpectedly


def count(endpoint: str) -> None:
    EXAMPLES[endpoint] += 1


def table() -> str:
    if not EXAMPLES:
        return ""
    width = max(len(e) for e in EXAMPLES)
    lines = [f"{'endpoint':<{width}}  examples  crashes", f"{'-' * width}  --------  -------"]
    for endpoint in sorted(EXAMPLES):
        lines.append(f"{endpoint:<{width}}  {EXAMPLES[endpoint]:>8}  {CRASHES[endpoint]:>7}")
    lines.append(f"{'total':<{width}}  {sum(EXAMPLES.values()):>8}  {sum(CRASHES.values()):>7}")
    return "\n".join(lines)
