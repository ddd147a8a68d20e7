"""Thread pools follow the CPUs a process owns: its affinity set and its cgroup CPU quota."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from shsas_core.common import threads
from shsas_core.common.threads import cgroup_cpu_quota, owned_cpus


def test_cgroup_quota_is_read_from_v2_then_v1(tmp_path: Path) -> None:
    v2, q, p = tmp_path / "cpu.max", tmp_path / "quota", tmp_path / "period"
    assert cgroup_cpu_quota(v2, q, p) is None  # no cgroup files
    v2.write_text("max 100000\n")
    assert cgroup_cpu_quota(v2, q, p) is None
    v2.write_text("150000 100000\n")
    assert cgroup_cpu_quota(v2, q, p) == 1.5
    v2.unlink()
    q.write_text("-1\n"), p.write_text("100000\n")
    assert cgroup_cpu_quota(v2, q, p) is None
    q.write_text("50000\n")
    assert cgroup_cpu_quota(v2, q, p) == 0.5


def test_owned_cpus_is_the_affinity_capped_by_the_quota(tmp_path: Path, monkeypatch) -> None:
    affinity = len(os.sched_getaffinity(0))
    monkeypatch.setattr(threads, "CGROUP_V2_CPU_MAX", tmp_path / "none")
    monkeypatch.setattr(threads, "CGROUP_V1_QUOTA", tmp_path / "none")
    assert owned_cpus() == affinity
    cpu_max = tmp_path / "cpu.max"
    monkeypatch.setattr(threads, "CGROUP_V2_CPU_MAX", cpu_max)
    cpu_max.write_text("50000 100000\n")  # half a CPU: still one thread
    assert owned_cpus() == 1
    cpu_max.write_text(f"{(affinity + 8) * 100000} 100000\n")  # a quota above the affinity set
    assert owned_cpus() == affinity


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs CPU affinity (Linux)")
def test_size_thread_pools_follows_a_one_cpu_affinity_set() -> None:
    """A fresh interpreter pinned to one CPU: torch gets one thread and OpenMP's variables say 1,
    whatever the machine's core count."""
    code = ("import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); import torch; "
            "torch.set_num_threads(max(2, os.cpu_count() or 2)); "  # a pool sized for the machine
            "from shsas_core.common.threads import size_thread_pools; n = size_thread_pools(); "
            "print(n, torch.get_num_threads(), os.environ['OMP_NUM_THREADS'])")
    env = {k: v for k, v in os.environ.items() if k not in threads.THREAD_ENV}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split() == ["1", "1", "1"]
