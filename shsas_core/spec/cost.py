"""How long a reconstruction job takes on a CPU worker, estimated before it runs.

The service refuses a CPU-queue job whose estimate is over ``SHSAS_MAX_CPU_JOB_S`` at
submission, so a spec that would train for days on a CPU is not accepted only to be stopped by
the time limit hours later. The rates are what a 2-core Xeon measured (docs/notebook/2026-11-lab-notebook.md: the
training and backprojection tables), rounded in the job's favour; a faster CPU worker finishes
sooner than the estimate, so the cap errs towards accepting.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from shsas_core.spec.job import ReconstructionSpec

#: Training samples (rays x bins x pings per batch, one iteration) a neural method renders per
#: second on a CPU: 65,536 per iteration at ~100 ms and 960,000 at ~1.6 s on 2 cores.
CPU_TRAIN_SAMPLES_PER_S = 6.0e5
#: Voxel-pings per second of the CPU backprojection (compiled kernel, 160-370 M measured).
CPU_VOXEL_PINGS_PER_S = 1.5e8
#: Survey samples per second through the analytic signal and Wiener deconvolution (52 M in 11 s).
CPU_SAMPLES_PER_S = 4.5e6
#: Interpreter, libraries, export and the report: a job's floor.
CPU_FIXED_S = 30.0


@dataclass(frozen=True)
class CpuEstimate:
    """Estimated CPU seconds of a job, by part."""

    train_s: float
    backprojection_s: float
    signal_s: float

    @property
    def total_s(self) -> float:
        return CPU_FIXED_S + self.train_s + self.backprojection_s + self.signal_s

    def words(self) -> str:
        """``about 9.3 h (training 9.2 h, backprojection 2 min, ...)``."""
        return (f"about {_duration(self.total_s)} on a CPU (training {_duration(self.train_s)}, "
                f"backprojection {_duration(self.backprojection_s)}, signal processing "
                f"{_duration(self.signal_s)})")


def _duration(s: float) -> str:
    if s >= 3600:
        return f"{s / 3600:.1f} h"
    if s >= 60:
        return f"{s / 60:.0f} min"
    return f"{s:.0f} s"


def cpu_job_seconds(spec: ReconstructionSpec, pings: int = 0, samples_per_ping: int = 0,
                    grid: int | None = None) -> CpuEstimate:
    """Estimate ``spec``'s run time on a CPU worker. The survey's size (``pings`` x
    ``samples_per_ping``) and the grid (explicit or automatic) add their parts when known; the
    training part needs only the spec."""
    from shsas_core.spec.catalogue import NEURAL

    neural = sum(1 for m in spec.methods if m in NEURAL)
    samples = spec.iters * spec.pings_per_batch * spec.num_rays * spec.num_bins
    grid = spec.grid if spec.grid is not None else grid
    # every method starts from (or is) the backprojection image of the training pings
    voxel_pings = (grid**3) * pings if grid is not None else 0
    return CpuEstimate(train_s=neural * samples / CPU_TRAIN_SAMPLES_PER_S,
                       backprojection_s=voxel_pings / CPU_VOXEL_PINGS_PER_S,
                       signal_s=pings * samples_per_ping / CPU_SAMPLES_PER_S)
