"""Workers run at a lower CPU priority than the API, so status polls stay fast.

A training job keeps every core busy; at equal priority the API's event loop waits its turn
behind the job's threads, and status polls took seconds. With the worker at niceness 10 the
kernel's scheduler gives the API about nine times the worker's share whenever both want a
core, and the worker still gets all the CPU the API leaves idle.

Linux applies niceness per thread, and a thread inherits it from the thread that creates it,
so this runs before the job's thread pools exist, and also renices the threads already there.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path

log = logging.getLogger("shsas.worker")


def lower_priority(nice: int) -> int:
    """Raise this process's niceness to at least ``nice`` (never lowers it). Returns the result."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return os.getpriority(os.PRIO_PROCESS, 0) if hasattr(os, "getpriority") else 0
    current = os.getpriority(os.PRIO_PROCESS, 0)
    target = max(current, nice)
    tasks = Path("/proc/self/task")
    tids = [int(t.name) for t in tasks.iterdir()] if tasks.is_dir() else [0]
    for tid in tids:
        with contextlib.suppress(OSError):  # a thread may end meanwhile
            os.setpriority(os.PRIO_PROCESS, tid, target)
    log.info("worker niceness %d (SHSAS_WORKER_NICE)", target, extra={"nice": target})
    return target
