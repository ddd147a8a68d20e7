"""Per-key quotas and the cost cap of a spec.

The limits themselves are settings (``SHSAS_MAX_ACTIVE_JOBS_PER_KEY``, ``SHSAS_MAX_TRAIN_SAMPLES``,
``SHSAS_MAX_GRID_VOXELS`` in :class:`jobs.settings.Settings`); this module only applies them
and words the refusal, naming the limit and the setting that raises it.
"""

from __future__ import annotations

from contextlib import AsyncExitStack

from anyio import to_thread

from jobs.settings import Settings
from jobs.store import JobStore
from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import auto_grid_count
from shsas_core.spec.catalogue import NEURAL
from shsas_core.spec.cost import cpu_job_seconds
from shsas_core.spec.job import ReconstructionSpec

from .uploads import UploadError


def train_samples(spec: ReconstructionSpec) -> int:
    """Samples one neural method renders over its whole fit: iterations x pings per batch x rays
    x bins (0 without a neural method)."""
    # (a neural method's cost grows with iterations x rays x bins)
    if not any(m in NEURAL for m in spec.methods):
        return 0
    return spec.iters * spec.pings_per_batch * spec.num_rays * spec.num_bins


def max_grid(voxels: int) -> int:
    """The largest grid whose cube is at most ``voxels``."""
    n = round(voxels ** (1 / 3))
    while n**3 > voxels:
        n -= 1
    while (n + 1) ** 3 <= voxels:
        n += 1
    return n


def check_spec_cost(spec: ReconstructionSpec, settings: Settings, box: SceneBox | None = None) -> None:
    """Refuse a spec over the cost cap (422 naming the limit).

    The grid is checked when it is explicit, or, with ``box`` (the survey's scene box, known after
    validation), the automatic grid the pipeline would pick for it.
    """
    samples = train_samples(spec)
    if samples > settings.max_train_samples:
        raise UploadError(422, (
            f"spec: iters x pings_per_batch x num_rays x num_bins = {spec.iters} x {spec.pings_per_batch} x "
            f"{spec.num_rays} x {spec.num_bins} = {samples:.3g} training samples, over the limit of "
            f"{settings.max_train_samples:.3g} (SHSAS_MAX_TRAIN_SAMPLES) (fix: lower iters, num_rays or "
            "num_bins, or ask the operator to raise the limit)"))
    grid = spec.grid if spec.grid is not None else (auto_grid_count(box) if box is not None else None)
    if grid is not None and grid**3 > settings.max_grid_voxels:
        which = "spec.grid" if spec.grid is not None else "spec.grid (automatic, from the scene box)"
        raise UploadError(422, (
            f"{which}: {grid}^3 = {grid**3} voxels, over the limit of {settings.max_grid_voxels} "
            f"(SHSAS_MAX_GRID_VOXELS: grid {max_grid(settings.max_grid_voxels)} at most) "
            "(fix: give a smaller grid, or ask the operator to raise the limit)"))


def check_cpu_time(spec: ReconstructionSpec, settings: Settings, summary: dict | None = None) -> None:
    """Refuse a CPU-queue job whose estimated run time is over the CPU cap (422 with the estimate).

    Without ``summary`` only the training part is known; with the validation summary the
    survey's size and the automatic grid count too.
    """
    if settings.queue_for(spec.device) != settings.cpu_queue:
        return
    pings = int(summary.get("pings", 0)) if summary else 0
    samples = int(summary.get("samples_per_ping", 0)) if summary else 0
    box = box_of(summary) if summary else None
    grid = spec.grid_count(box) if box is not None else spec.grid
    est = cpu_job_seconds(spec, pings, samples, grid)
    limit = settings.cpu_job_limit_s
    if est.total_s > limit:
        raise UploadError(422, (
            f"spec: this job runs on the CPU queue (device {spec.device!r}) and would take {est.words()}, "
            f"over the limit of {limit:.0f} s (SHSAS_MAX_CPU_JOB_S, default the job time limit "
            "SHSAS_JOB_SOFT_TIME_LIMIT_S) (fix: lower iters, num_rays, num_bins or grid, or send it to a "
            "GPU worker with device 'cuda')"))


def check_active_jobs(active: int, settings: Settings) -> None:
    """Refuse a submission past the key's quota of queued and running jobs (429)."""
    limit = settings.max_active_jobs_per_key
    if active >= limit:
        raise UploadError(429, (
            f"this API key already has {active} queued or running jobs, the limit is {limit} "
            "(SHSAS_MAX_ACTIVE_JOBS_PER_KEY) (fix: wait for some to finish, or cancel some with "
            "POST /reconstructions/{id}/cancel, then resubmit)"))


def reservation_ttl_s(settings: Settings) -> float:
    """How long a submission's quota slot may stay reserved: the validation's time limit plus a
    margin for the job's insert and dispatch. Older reservations belong to a dead API process."""
    return settings.validate_timeout_s + 300.0


async def hold_slot(held: AsyncExitStack, store: JobStore, owner: str, settings: Settings) -> None:
    """Reserve one of ``owner``'s quota slots until ``held`` closes, or refuse with 429.

    The count and the reservation are one transaction in the job store, so N concurrent
    submissions of one key get at most the quota's free slots between them.
    """
    rid, in_use = await to_thread.run_sync(
        store.reserve_slot, owner, settings.max_active_jobs_per_key, reservation_ttl_s(settings))
    if rid is None:
        check_active_jobs(in_use, settings)
        return
    held.push_async_callback(to_thread.run_sync, store.release_slot, rid)


def box_of(summary: dict) -> SceneBox | None:
    """The scene box of a validation summary (``scene_box_m``), or None if it has none."""
    box = summary.get("scene_box_m") if isinstance(summary, dict) else None
    if not box:
        return None
    return SceneBox(min=tuple(box["min"]), max=tuple(box["max"]))
