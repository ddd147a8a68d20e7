"""heap_cache: freed large buffers stay resident inside the block and are given back after it."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from shsas_core.heap import heap_cache

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


def test_freed_buffer_stays_resident_only_inside_the_block():
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
    with heap_cache(enabled=False) as active:
        assert not active
        assert _alloc_touch_free(256 * MB) < 32 * MB
