"""The CPU run-time estimate of a job, part by part, against the rates computed by hand."""

from __future__ import annotations

from shsas_core.spec.cost import CPU_FIXED_S, cpu_job_seconds
from shsas_core.spec.job import ReconstructionSpec


def test_cpu_estimate_adds_its_parts() -> None:
    """By hand: 2 neural methods x 1000 iterations x 2 x 100 x 10 samples at 6e5/s, 100 pings on
    20^3 voxels at 1.5e8/s, 100 x 9000 samples at 4.5e6/s."""
    spec = ReconstructionSpec(methods=["backprojection", "reed", "shsas"], iters=1000, pings_per_batch=2,
                              num_rays=100, num_bins=10, device="cpu")
    est = cpu_job_seconds(spec, pings=100, samples_per_ping=9000, grid=20)
    assert est.train_s == 2 * 1000 * 2 * 100 * 10 / 6e5
    assert est.backprojection_s == 100 * 20**3 / 1.5e8 and est.signal_s == 100 * 9000 / 4.5e6
    assert est.total_s == CPU_FIXED_S + est.train_s + est.backprojection_s + est.signal_s
    assert cpu_job_seconds(ReconstructionSpec(methods=["backprojection"], iters=200_000)).train_s == 0
