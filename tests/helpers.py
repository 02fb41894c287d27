"""What many tests need, in one place: free loopback ports, waiting for a condition, and ``hild run`` as the
operator starts it. They live in the measuring room (``hild.bench.children``, ``hild.bench.daemon``), which the
tools and ``hild bench`` share; this module names them for the tests."""

from typing import Any, TypeVar

from hild.bench.children import distinct_free_ports, free_endpoint, free_port, wait_for
from hild.bench.daemon import HildRun, domain_pid, running

__all__ = [
    "HildRun",
    "component",
    "distinct_free_ports",
    "domain_pid",
    "free_endpoint",
    "free_port",
    "running",
    "wait_for",
]

C = TypeVar("C")


def component(engine: Any, kind: type[C], index: int = 0) -> C:
    """The engine's hardware component ``index``, checked to be a ``kind`` (the twin, the mock)."""
    found = engine.hardware[index].component
    assert isinstance(found, kind), type(found)
    return found
