"""Jobs as the workers see them: claims, heartbeats, finishing, releasing and the reconciler's
re-queueing, each one conditional UPDATE (whoever holds the lease runs the job)."""

from __future__ import annotations

import json
import time
from typing import Any

import sqlalchemy as sa

from .base import StoreBase
from .records import (
    DEVICE_KEY,
    TERMINAL,
    WARNINGS_KEY,
    Job,
    jobs,
)


class Leases(StoreBase):
    """The worker side of the job table."""

    def claim(self, job_id: str, worker_id: str) -> Job | None:
        """Take the lease of a queued job (attempts + 1). None if it is not queued any more."""
        now = time.time()
        with self._tx() as conn:
            res = conn.execute(
                jobs.update().where(jobs.c.id == job_id, jobs.c.status == "queued")
                .values(status="running", lease_owner=worker_id, heartbeat_at=now,
                        attempts=jobs.c.attempts + 1, updated_at=now,
                        started_at=sa.func.coalesce(jobs.c.started_at, now)))
        return self.get(job_id) if res.rowcount == 1 else None

    def claim_next(self, worker_id: str, queues: list[str] | None = None) -> Job | None:
        """Embedded queue: claim the oldest queued job (in ``queues`` if given), or None."""
        for _ in range(10):  # another worker may win the race for the oldest; try the next
            q = sa.select(jobs.c.id).where(jobs.c.status == "queued")
            if queues:
                q = q.where(jobs.c.queue.in_(queues))
            with self.engine.connect() as conn:
                job_id = conn.execute(q.order_by(jobs.c.created_at, jobs.c.id).limit(1)).scalar()
            if job_id is None:
                return None
            job = self.claim(job_id, worker_id)
            if job is not None:
                return job
        return None

    def heartbeat(self, job_id: str, worker_id: str, *, progress: float | None = None,
                  stage: str | None = None, live_metrics: dict[str, float] | None = None) -> tuple[bool, bool]:
        """Refresh the lease (and optionally progress). Returns (still_owner, cancel_requested)."""
        now = time.time()
        values: dict[str, Any] = {"heartbeat_at": now, "updated_at": now}
        if progress is not None:
            values["progress"] = float(min(max(progress, 0.0), 1.0))
        if stage is not None:
            values["stage"] = stage[:64]
        if live_metrics is not None:
            values["live_metrics"] = json.dumps(live_metrics)
        with self._tx() as conn:
            res = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "running",
                                                   jobs.c.lease_owner == worker_id).values(**values))
        if res.rowcount != 1:
            return False, False
        return True, self.cancel_requested(job_id)

    def cancel_requested(self, job_id: str) -> bool:
        with self.engine.connect() as conn:
            return bool(conn.execute(sa.select(jobs.c.cancel_requested).where(jobs.c.id == job_id)).scalar())

    def finish(self, job_id: str, worker_id: str, status: str, *, error: str | None = None,
               artifacts: list[str] | None = None, metrics: dict | None = None,
               warnings: list[dict[str, Any]] | None = None, device: str | None = None) -> bool:
        """Move a running job this worker leases to a terminal status. False if the lease was lost.

        ``warnings`` (see :attr:`Job.warnings`) and ``device`` (:attr:`Job.device`) are stored
        with the metrics.
        """
        if status not in TERMINAL:
            raise ValueError(f"not a terminal status: {status}")
        now = time.time()
        values: dict[str, Any] = {"status": status, "finished_at": now, "updated_at": now,
                                  "error": error, "lease_owner": None, "stage": status}
        if status == "succeeded":
            values["progress"] = 1.0
        if artifacts is not None:
            values["artifacts"] = json.dumps(artifacts)
        if warnings:
            metrics = {**(metrics or {}), WARNINGS_KEY: warnings}
        if device:
            metrics = {**(metrics or {}), DEVICE_KEY: device}
        if metrics is not None:
            values["metrics"] = json.dumps(metrics)
        with self._tx() as conn:
            res = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "running",
                                                   jobs.c.lease_owner == worker_id).values(**values))
        return res.rowcount == 1

    def release(self, job_id: str, worker_id: str) -> bool:
        """A worker stopping cleanly hands its running job back: queued again at once, and this
        delivery does not count in ``attempts`` (which counts deliveries whose worker died).
        False if this worker does not hold the lease."""
        now = time.time()
        with self._tx() as conn:
            res = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "running",
                                                   jobs.c.lease_owner == worker_id)
                               .values(status="queued", lease_owner=None, stage="requeued", updated_at=now,
                                       attempts=jobs.c.attempts - 1))
        return res.rowcount == 1

    def requeue_stale(self, lease_timeout_s: float, max_attempts: int) -> tuple[list[Job], list[Job]]:
        """Reconciler: running jobs whose heartbeat is older than ``lease_timeout_s`` go back to
        queued, or to failed once their worker died ``max_attempts`` times. A stale lease is a
        worker that died without a word (a clean stop releases its job), most often killed for
        memory, so retrying without end would only kill more workers. Returns (requeued, failed)."""
        now = time.time()
        cutoff = now - lease_timeout_s
        stale = (jobs.c.status == "running") & (jobs.c.heartbeat_at < cutoff)
        with self.engine.connect() as conn:
            cands = [Job.from_row(r) for r in conn.execute(jobs.select().where(stale))]
        requeued, failed = [], []
        for job in cands:
            this = stale & (jobs.c.id == job.id) & (jobs.c.attempts == job.attempts)
            if job.cancel_requested:
                values = {"status": "cancelled", "finished_at": now, "stage": "cancelled"}
            elif job.attempts >= max_attempts:
                values = {"status": "failed", "finished_at": now, "stage": "failed",
                          "error": f"the worker running this job died {job.attempts} times without reporting "
                                   "why (killed: most often by the out-of-memory killer or a container memory "
                                   "limit), so it is not retried (SHSAS_MAX_ATTEMPTS="
                                   f"{max_attempts}); the job likely needs more memory than the worker has "
                                   "(lower SHSAS_WORKER_MEMORY_BYTES to what the worker really has, so such "
                                   "jobs are refused at upload, or use a smaller grid or survey)"}
            else:
                values = {"status": "queued", "stage": "requeued"}
            with self._tx() as conn:
                res = conn.execute(jobs.update().where(this).values(lease_owner=None, updated_at=now, **values))
            if res.rowcount == 1:
                (requeued if values["status"] == "queued" else failed).append(job)
        return requeued, failed

    def queued_older_than(self, age_s: float) -> list[Job]:
        """Queued jobs not created, re-queued or re-sent for ``age_s`` seconds, oldest first (their
        broker message may be lost; the reconciler sends them again)."""
        cutoff = time.time() - age_s
        with self.engine.connect() as conn:
            rows = conn.execute(jobs.select().where(jobs.c.status == "queued", jobs.c.updated_at < cutoff)
                                .order_by(jobs.c.created_at, jobs.c.id))
            return [Job.from_row(r) for r in rows]

    def mark_redispatched(self, job: Job) -> bool:
        """Take the right to send ``job`` to the broker again: True for exactly one caller among
        concurrent reconcilers (the row must still be queued and unchanged since it was read)."""
        with self._tx() as conn:
            res = conn.execute(jobs.update().where(jobs.c.id == job.id, jobs.c.status == "queued",
                                                   jobs.c.updated_at == job.updated_at)
                               .values(updated_at=time.time()))
        return res.rowcount == 1
