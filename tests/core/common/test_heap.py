"""heap_cache: freed large buffers stay resident inside the block and are given back after it."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from shsas_core.common.heap import heap_cache

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")

MB = 2**20


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _alloc_touch_free(nbytes: int) -> int:
    """RSS growth that remains after allocating, touching and freeing ``nbytes``."""
    before = _rss()
    a = np.ones(nbytes // 8)  # touched: every page resident
    assert a.sum() > 0
    del a
    return _rss() - before


def _in_fresh_interpreter(name: str) -> None:
    """Run ``name`` of this module in a new interpreter.

    "Outside the block" depends on the process's heap history: after any earlier
    heap_cache block (a training test), malloc_trim(0) gives the pages back but the free
    chunks stay inside the heap's address range, so a later 256 MiB request is carved from
    them instead of being mmapped, and stays resident after free. Both tests failed that
    way in full-suite runs only (224 and 256 MiB kept), never alone.
    """
    import subprocess
    from pathlib import Path

    code = f"import tests.core.common.test_heap as t; t.{name}()"
    r = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[3],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_freed_buffer_stays_resident_only_inside_the_block():
    _in_fresh_interpreter("_freed_buffer_stays_resident_only_inside_the_block")


def _freed_buffer_stays_resident_only_inside_the_block():
    # outside: glibc mmaps a 256 MiB block and unmaps it on free, nothing stays
    assert _alloc_touch_free(256 * MB) < 32 * MB
    with heap_cache() as active:
        assert active
        kept = _alloc_touch_free(256 * MB)
        assert kept > 200 * MB  # served from the heap and kept for the next iteration
        # reused, not grown again: a second round adds (almost) nothing
        assert _alloc_touch_free(256 * MB) < 32 * MB
        with heap_cache() as nested:  # nesting keeps it active
            assert nested
        assert _alloc_touch_free(256 * MB) < 32 * MB
        resident = _rss()
    # on exit malloc_trim(0) returns the kept memory, and large blocks are mmapped again
    assert _rss() < resident - 200 * MB
    assert _alloc_touch_free(256 * MB) < 32 * MB


def test_disabled_is_a_no_op():
    _in_fresh_interpreter("_disabled_is_a_no_op")


def _disabled_is_a_no_op():
    with heap_cache(enabled=False) as active:
        assert not active
        assert _alloc_touch_free(256 * MB) < 32 * MB
