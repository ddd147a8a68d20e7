"""How much memory a reconstruction job needs, and how much a worker may use.

A survey declares its sizes before any of its data is read, and HDF5 lets a small file declare
a huge dataset (chunks never written read as the fill value; zeros compress a thousandfold).
So a job's memory is estimated from the declared sizes and the spec and compared with a budget
before anything is allocated: at upload (the API answers 413), in the worker before it loads
the samples (the job fails), and in ``shsas reconstruct`` (one line, exit 2).

The budget is ``SHSAS_WORKER_MEMORY_BYTES``; unset, :data:`DEFAULT_FRACTION` of the machine's
memory (the smaller of physical memory and the container's cgroup limit). This module is the
one place that rule is declared: the service settings use :func:`default_memory_budget`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shsas_core.common.errors import ShsasError

if TYPE_CHECKING:
    from shsas_core.data.survey import Survey
    from shsas_core.spec.job import ReconstructionSpec

MiB = 1024**2
GiB = 1024**3

#: The environment variable holding the budget, read by the service settings and the CLI.
BUDGET_ENV = "SHSAS_WORKER_MEMORY_BYTES"
#: Unset budget = this share of the machine's memory; the rest is left to the system, to the API
#: process beside an embedded worker, and to the error of the estimate.
DEFAULT_FRACTION = 0.75

# The estimate: peak RSS of `shsas reconstruct` on a CPU, measured on float32 surveys of 8x512,
# 64x500000 and 256x125000 samples and grids of 16 and 192 (docs/service.md), rounded up.
#: Interpreter, numpy, scipy, h5py, torch (390 MiB measured with backprojection alone).
BASE_BYTES = 512 * MiB
#: Added by a neural method: the trainer and autograd (660 MiB measured in all).
NEURAL_BASE_BYTES = 512 * MiB
#: Per stored sample of a real survey: the samples, their analytic signal, s_PD, the training
#: copies and the FFT blocks of the deconvolution (50-52 B measured).
SAMPLE_BYTES = 56
#: Added per sample when the samples are complex (8 bytes instead of 4, held twice).
COMPLEX_SAMPLE_BYTES = 8
#: Added per sample by a neural method: its complex, magnitude and mask tensors (64 B in all).
NEURAL_SAMPLE_BYTES = 16
#: Per voxel of the output grid: backprojection accumulators, voxel centres, extraction (133 B).
VOXEL_BYTES = 160
#: Per voxel and method: each method's complex64 volume is kept for the report.
VOLUME_BYTES = 8
#: Per vertex and per face of a ground-truth mesh: the survey's own float64/int64 copies (24 B
#: each) plus the metrics' surface sample and occupancy band, the report's trimesh and figure
#: (63 B more per element measured between 0.5 M and 2 M elements; 128 B with margin).
GROUND_TRUTH_ELEMENT_BYTES = 128


class MemoryBudgetError(ShsasError):
    """The job would need more memory than the budget allows (HTTP 413 at upload)."""

    http_status = 413


def _cgroup_limit() -> int | None:
    """The memory limit of this process's cgroup (v2, then v1), or None when unlimited."""
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(path).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 1 << 60:  # v1 says "no limit" with a huge number
            return int(text)
    return None


def machine_memory_bytes() -> int:
    """Physical memory, or the container's cgroup limit when that is smaller."""
    physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    limit = _cgroup_limit()
    return min(physical, limit) if limit else physical


def default_memory_budget() -> int:
    """The budget when ``SHSAS_WORKER_MEMORY_BYTES`` is unset."""
    return int(DEFAULT_FRACTION * machine_memory_bytes())


def memory_budget() -> int:
    """``SHSAS_WORKER_MEMORY_BYTES`` when set (for the CLI; the service reads it in its settings)."""
    raw = os.environ.get(BUDGET_ENV, "").strip()
    if not raw:
        return default_memory_budget()
    if not raw.isdigit() or int(raw) <= 0:
        raise ShsasError(f"{BUDGET_ENV}: expected a positive number of bytes, got {raw!r}")
    return int(raw)


def job_memory_bytes(survey: Survey, spec: ReconstructionSpec) -> int:
    """Estimated peak memory of running ``spec`` on ``survey`` (samples need not be loaded).

    Counts everything a job holds: the samples and what is derived from them, the grid, the
    ground-truth mesh (``survey.gt_vertices`` / ``gt_faces``, read with the header) and any
    ``/extras`` arrays loaded with the survey (the pipeline itself does not read them)."""
    from shsas_core.data.volume import Grid
    from shsas_core.spec.catalogue import NEURAL

    neural = any(m in NEURAL for m in spec.methods)
    per_sample = SAMPLE_BYTES + (COMPLEX_SAMPLE_BYTES if survey.meta.signal_kind != "real" else 0)
    per_sample += NEURAL_SAMPLE_BYTES if neural else 0
    voxels = Grid.over(survey.meta.scene_box, spec.grid_count(survey.meta.scene_box)).num_voxels
    n, t = survey.shape
    return (BASE_BYTES + (NEURAL_BASE_BYTES if neural else 0) + n * t * per_sample
            + voxels * (VOXEL_BYTES + VOLUME_BYTES * len(spec.methods))
            + ground_truth_elements(survey) * GROUND_TRUTH_ELEMENT_BYTES
            + sum(int(np.asarray(v).nbytes) for v in survey.extras.values()))


def ground_truth_elements(survey: Survey) -> int:
    """Vertices plus faces of the survey's ground-truth mesh (0 without one)."""
    if survey.gt_vertices is None or survey.gt_faces is None:
        return 0
    return len(survey.gt_vertices) + len(survey.gt_faces)


def _gib(n: int) -> str:
    return f"{n / GiB:.1f} GiB"


def check_job_memory(survey: Survey, spec: ReconstructionSpec, budget: int) -> int:
    """Raise :class:`MemoryBudgetError` when the job needs more than ``budget`` bytes; return
    the estimate otherwise."""
    need = job_memory_bytes(survey, spec)
    if need > budget:
        n, t = survey.shape
        mesh = ground_truth_elements(survey)
        with_mesh = f" and a ground-truth mesh of {mesh} vertices and faces" if mesh else ""
        raise MemoryBudgetError(
            f"survey: {n} pings x {t} samples{with_mesh} with methods {', '.join(spec.methods)} at grid {spec.grid_count(survey.meta.scene_box)} "
            f"need about {_gib(need)} of memory, over the worker memory budget of {_gib(budget)} "
            f"({BUDGET_ENV}; default {DEFAULT_FRACTION:.0%} of the machine's memory) "
            "(fix: crop the samples to the scene's range window or decimate them, split the survey, "
            "lower the grid, or run on a worker with more memory)")
    return need
