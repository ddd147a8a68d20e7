"""Keep freed CPU memory in the process heap during training (glibc).

A CPU training iteration allocates and frees the same few dozen buffers of 10-100 MB every
step. glibc serves blocks that large with ``mmap`` and hands them back with ``munmap`` on free,
so every iteration page-faults (and the kernel zeroes) all of that memory again: on the 2-core
development machine a third of the CPU time of the fast training path was system time.
:func:`heap_cache` sets ``M_MMAP_MAX = 0`` (large blocks come from the heap) and a high
``M_TRIM_THRESHOLD`` (freed heap memory is kept) for the duration of a ``with`` block, so after
the first iteration the buffers are reused without page faults; on exit it restores glibc's
defaults and calls ``malloc_trim(0)`` so the process gives the memory back. Measured with
``benchmarks/bench_train.py`` (docs/notebook/2026-11-lab-notebook.md). This is what PyTorch's CUDA caching allocator
does for GPU memory; the CPU allocator has no cache of its own.

After the block, free chunks that sit below live allocations stay inside the heap's address
range (their pages are given back, the range is not), so a later large request may be carved
from them instead of being mmapped, and stays resident after it is freed until trimmed again.

Process-wide while active (other threads' allocations are served the same way); nested and
concurrent blocks are reference-counted. A no-op where there is no glibc ``mallopt`` (macOS,
musl, Windows).
"""

from __future__ import annotations

import contextlib
import ctypes
import sys
import threading
from collections.abc import Iterator

M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
#: glibc's defaults, restored on exit
DEFAULT_TRIM_THRESHOLD = 128 * 1024
DEFAULT_MMAP_MAX = 65536
#: freed memory kept in the heap while active (C int: at most 2 GiB - 1)
KEEP_BYTES = 2**31 - 1

_lock = threading.Lock()
_depth = 0


def _libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None


@contextlib.contextmanager
def heap_cache(enabled: bool = True) -> Iterator[bool]:
    """Within the block, freed large CPU buffers stay in the heap for reuse.

    Yields True when the setting is active (glibc found and ``mallopt`` accepted it).
    """
    global _depth
    libc = _libc() if enabled else None
    if libc is None:
        yield False
        return
    with _lock:
        if _depth == 0:
            ok = libc.mallopt(M_MMAP_MAX, 0) == 1 and libc.mallopt(M_TRIM_THRESHOLD, KEEP_BYTES) == 1
            if not ok:
                _restore(libc)
                yield_value = False
            else:
                _depth = 1
                yield_value = True
        else:
            _depth += 1
            yield_value = True
    try:
        yield yield_value
    finally:
        if yield_value:
            with _lock:
                _depth -= 1
                if _depth == 0:
                    _restore(libc)


def _restore(libc: ctypes.CDLL) -> None:
    libc.mallopt(M_MMAP_MAX, DEFAULT_MMAP_MAX)
    libc.mallopt(M_TRIM_THRESHOLD, DEFAULT_TRIM_THRESHOLD)
    libc.malloc_trim(0)
