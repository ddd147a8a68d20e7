"""What a job's status adds for its owner: queue position, ETA and the worker's heartbeat age
(so an owner can tell a queued job from a stuck one).

A running job's ETA is what its worker measured from the current stage's pace
(:mod:`worker.eta`; ``null`` while the stage has not measured it). A queued job's is a rough
figure from the job table: the mean run time of the last jobs that ran to an end in the same
queue (``null`` until one has), with every running job in the queue counting as one worker.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from jobs.settings import Settings
from jobs.store import Job, JobStore

#: A heartbeat older than this many intervals means the worker is not running the job's
#: heartbeat thread: it died, hangs, or cannot reach the job store (the reconciler re-queues it
#: once the age passes SHSAS_LEASE_TIMEOUT_S).
MISSED_BEATS = 3
#: How long a queue's measured rate is reused: polls of queued jobs do not each scan the table.
RATE_CACHE_S = 5.0

_rates: dict[tuple[int, str], tuple[float, float | None, list[Job]]] = {}


@dataclass(frozen=True)
class LiveStatus:
    queue_position: int | None = None
    eta_s: float | None = None
    heartbeat_age_s: float | None = None
    worker_responding: bool | None = None


def _remaining(job: Job, mean: float | None, now: float) -> float | None:
    """Seconds a running job still needs: its worker's measure, else the queue's mean run time
    less the time it has run."""
    eta = running_eta(job, now)
    if eta is not None:
        return eta
    elapsed = max(0.0, now - (job.started_at or now))
    return None if mean is None else max(0.0, mean - elapsed)


def running_eta(job: Job, now: float) -> float | None:
    """Seconds left of a running job: what its worker last measured (``worker.eta``, from the
    current stage's pace), aged by the time since; None while the stage has not measured it."""
    lm = job.live_metrics
    if "eta_s" not in lm or "eta_at" not in lm:
        return None
    return round(max(0.0, lm["eta_s"] - max(0.0, now - lm["eta_at"])), 1)


def _rate(store: JobStore, queue: str, now: float) -> tuple[float | None, list[Job]]:
    key = (id(store), queue)
    hit = _rates.get(key)
    if hit is not None and now - hit[0] < RATE_CACHE_S:
        return hit[1], hit[2]
    mean, running = store.queue_rate(queue)
    if mean is not None:
        # "no job has finished yet" is not cached: the first job to finish (a quick one can take
        # under RATE_CACHE_S) must give the very next poll its ETA
        _rates[key] = (now, mean, running)
    return mean, running


def live_status(store: JobStore, settings: Settings, job: Job) -> LiveStatus:
    """The live fields of ``job`` (all None for a finished job)."""
    now = time.time()
    if job.status == "running":
        age = max(0.0, now - job.heartbeat_at) if job.heartbeat_at is not None else None
        responding = age is not None and age <= MISSED_BEATS * settings.heartbeat_interval_s
        eta = running_eta(job, now)
        return LiveStatus(heartbeat_age_s=None if age is None else round(age, 2), worker_responding=responding,
                          eta_s=None if eta is None else round(eta, 1))
    if job.status == "queued":
        ahead = store.queue_position(job)
        mean, running = _rate(store, job.queue, now)
        if mean is None:
            return LiveStatus(queue_position=ahead)
        busy = [r for r in (_remaining(j, mean, now) for j in running) if r is not None]
        workers = max(1, len(running))
        # The running jobs' remainders and the jobs ahead share the workers; then this job runs.
        eta = (sum(busy) + ahead * mean) / workers + mean
        return LiveStatus(queue_position=ahead, eta_s=round(eta, 1))
    return LiveStatus()
