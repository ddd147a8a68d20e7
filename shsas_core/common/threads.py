"""How many CPUs this process owns, and thread pools sized to them.

A thread pool sized from the machine's core count oversubscribes a process that owns fewer
CPUs: one pinned to a CPU set (``taskset``, Kubernetes' static CPU manager, Celery with
``--concurrency`` on a share of the host) or one under a cgroup CPU quota (``docker --cpus``,
Kubernetes CPU limits). OpenMP's threads then spin waiting for CPUs they will not get
(benchmarks/bench_threads.py shows the cost). The workers size torch's and OpenMP's pools from
:func:`owned_cpus` before a job's threads start.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

#: cgroup v2 and v1 quota files, in the order they are tried.
CGROUP_V2_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")
CGROUP_V1_QUOTA = Path("/sys/fs/cgroup/cpu/cpu.cfs_quota_us")
CGROUP_V1_PERIOD = Path("/sys/fs/cgroup/cpu/cpu.cfs_period_us")

#: Environment variables the native thread pools (OpenMP, MKL, OpenBLAS, numexpr) read when they
#: start: set for libraries loaded after :func:`size_thread_pools` and for child processes.
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def cgroup_cpu_quota(v2: Path | None = None, v1_quota: Path | None = None,
                     v1_period: Path | None = None) -> float | None:
    """The CPU quota of this process's cgroup in CPUs (``200000 100000`` -> 2.0), or None when
    there is none (``max``, ``-1``, or no cgroup files). The paths default to the module's."""
    v2, v1_quota, v1_period = (v2 or CGROUP_V2_CPU_MAX, v1_quota or CGROUP_V1_QUOTA,
                               v1_period or CGROUP_V1_PERIOD)
    try:
        quota, period = v2.read_text().split()[:2]
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        pass
    try:
        q, p = int(v1_quota.read_text()), int(v1_period.read_text())
        return None if q <= 0 or p <= 0 else q / p
    except (OSError, ValueError):
        return None


def owned_cpus() -> int:
    """CPUs this process may use: its affinity set, capped by its cgroup's CPU quota (rounded
    down, at least 1: a pool one thread short idles a fraction of a CPU, one thread over spins)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        n = os.cpu_count() or 1
    quota = cgroup_cpu_quota()
    if quota is not None:
        n = min(n, max(1, math.floor(quota)))
    return max(1, n)


def size_thread_pools(threads: int | None = None) -> int:
    """Size torch's intra-op pool (its OpenMP threads) and the pools of native libraries loaded
    later to ``threads`` (default :func:`owned_cpus`). Returns the number used.

    Call it before the job's work starts: OpenMP reads its environment once, when it starts.
    """
    import torch

    n = max(1, threads or owned_cpus())
    for var in THREAD_ENV:
        os.environ[var] = str(n)
    torch.set_num_threads(n)
    return n
