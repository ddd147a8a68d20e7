"""The suite's own scheduling rule (tests/conftest.py): modules with a slow test go first."""

from __future__ import annotations

import types

from tests.conftest import slow_modules_first


class FakeItem:
    def __init__(self, module: str, slow: bool) -> None:
        self.module = types.SimpleNamespace(__name__=module)
        self.slow = slow

    def get_closest_marker(self, name: str) -> object | None:
        return object() if name == "slow" and self.slow else None


def test_modules_with_a_slow_test_go_first_whole_and_in_order() -> None:
    items = [FakeItem("a", False), FakeItem("b", False), FakeItem("b", True), FakeItem("c", False),
             FakeItem("d", True), FakeItem("d", False)]
    got = [(i.module.__name__, i.slow) for i in slow_modules_first(items)]  # type: ignore[arg-type]
    assert got == [("b", False), ("b", True), ("d", True), ("d", False), ("a", False), ("c", False)]
