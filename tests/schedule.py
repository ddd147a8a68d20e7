"""The science run's scheduling rule (``make test``, tests/run_suite.py), without the suite's
heavy imports: the rule's own test runs it in a child pytest, and importing torch there would
cost more than the test."""

from __future__ import annotations

import os

import pytest


def slow_modules_first(items: list[pytest.Item]) -> list[pytest.Item]:
    """``items`` with the modules that hold a ``slow`` test first, each module's tests kept
    together and in order. Under pytest-xdist the workers are handed whole modules in this order
    (``--dist loadfile --no-loadscope-reorder``; without the second option xdist hands them out
    by number of tests, most first): a long module handed out last ran alone at the end while
    the other worker idled (longest first is the classic greedy rule for two machines)."""
    def module(item: pytest.Item) -> str | None:
        mod = getattr(item, "module", None)
        return mod.__name__ if mod is not None else None

    slow = {module(item) for item in items if item.get_closest_marker("slow") is not None}
    return sorted(items, key=lambda item: module(item) is None or module(item) not in slow)


def order_items(items: list[pytest.Item]) -> None:
    """Reorder ``items`` in place under pytest-xdist (every worker sorts alike, so the order is
    deterministic); a plain run keeps pytest's order."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        items[:] = slow_modules_first(items)
