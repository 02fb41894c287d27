"""Fixtures of the bad-input suite: one real daemon per test module, and the examples table at the end."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.fuzz import tally
from tests.fuzz.daemon import FuzzDaemon


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FuzzDaemon]:
    d = FuzzDaemon(tmp_path_factory.mktemp("fuzz-daemon"))
    d.start()
    try:
        yield d
    finally:
        d.stop()


@pytest.fixture(scope="session", autouse=True)
def examples_table() -> Iterator[None]:
    yield
    text = tally.table()
    if text:
        print(f"\n\nbad-input examples per endpoint\n{text}")
