#!/usr/bin/env python3
"""Run the fault-injection scenarios and write their table into docs/safety.md (between the fault-table markers).

    python tools/fault_table.py            # run every scenario (~1 min), rewrite the table
    python tools/fault_table.py --check    # exit 1 if the committed table differs from a fresh run
    python tools/fault_table.py --only damiao_0x8 sigkill   # run some, print their rows, write nothing

The scenarios live in tests/faults/scenarios.py (lockstep CAN and twin rigs, the Zenoh API with real clients, and a
daemon killed and restarted against an emulator process); every cell is built from what a scenario observed and
checked. The suite (tests/faults/test_faults.py) runs the same scenarios and fails if the committed table is stale.
"""

from __future__ import annotations

import argparse
import difflib
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.faults is imported

from tests.faults.scenarios import SCENARIOS, Row
from tests.faults.table import DOC, committed, embed, render


def run(keys: list[str] | None) -> list[Row]:
    rows = []
    for scenario in SCENARIOS:
        if keys and scenario.key not in keys:
            continue
        started = time.perf_counter()
        rows.append(scenario.row())
        print(f"{scenario.key:<22} {time.perf_counter() - started:5.1f} s", file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="compare with docs/safety.md instead of writing it")
    parser.add_argument("--only", nargs="+", metavar="KEY", help="run these scenarios, print their rows")
    args = parser.parse_args(argv)
    known = [s.key for s in SCENARIOS]
    unknown = sorted(set(args.only or []) - set(known))
    if unknown:
        parser.error(f"unknown scenarios {unknown} (known: {', '.join(known)})")
    table = render(run(args.only))
    if args.only:
        print(table)
        return 0
    if args.check:
        old = committed()
        if old == table:
            print(f"{DOC}: the fault table is up to date")
            return 0
        sys.stdout.writelines(difflib.unified_diff(old.splitlines(True), table.splitlines(True), "committed", "run"))
        print(f"\n{DOC}: the fault table is stale; run python tools/fault_table.py", file=sys.stderr)
        return 1
    DOC.write_text(embed(DOC.read_text(), table))
    print(f"{DOC}: fault table written ({len(table.splitlines()) - 2} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
