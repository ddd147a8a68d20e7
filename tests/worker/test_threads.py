"""A job's thread pools: the CPUs its worker owns, or ``SHSAS_WORKER_THREADS``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from shsas_core.common.threads import owned_cpus

ROOT = Path(__file__).resolve().parents[2]

#: What a Celery pool child does before its first task, in a fresh interpreter (the call renices
#: the process and sizes torch's pool for good); prints torch's pool and OpenMP's variable.
_CHILD = ("import os, torch\nfrom worker.tasks import _pool_child_start\n_pool_child_start()\n"
          "print(torch.get_num_threads(), os.environ['OMP_NUM_THREADS'])")


def _child(**env: str) -> subprocess.CompletedProcess[str]:
    full = {k: v for k, v in os.environ.items() if k != "SHSAS_WORKER_THREADS"}
    full.update({"PYTHONPATH": str(ROOT), "SHSAS_LOG_FORMAT": "text", **env})
    return subprocess.run([sys.executable, "-c", _CHILD], env=full, cwd=ROOT, capture_output=True, text=True,
                          timeout=120)


def _pools(**env: str) -> list[str]:
    proc = _child(**env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.split()


@pytest.mark.parametrize("setting, want", [(None, owned_cpus()), ("1", 1)])
def test_pool_child_sizes_its_pools_to_its_cpus_or_the_setting(setting: str | None, want: int) -> None:
    got = _pools(**({"SHSAS_WORKER_THREADS": setting} if setting else {}))
    assert got == [str(want), str(want)]


def test_a_bad_thread_count_is_refused_by_name() -> None:
    proc = _child(SHSAS_WORKER_THREADS="0")
    assert proc.returncode != 0 and "worker_threads" in proc.stderr
