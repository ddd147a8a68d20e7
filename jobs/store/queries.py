"""Jobs as the API sees them: submission (with idempotency keys), reads, listing, cancel, delete and
queue statistics."""

from __future__ import annotations

import hashlib
import json
import time
import uuid
from typing import Any

import sqlalchemy as sa

from .base import StoreBase
from .records import (
    TERMINAL,
    IdempotencyConflict,
    Job,
    jobs,
    reservations,
)


class JobQueries(StoreBase):
    """Submission and queries."""

    def create_job(self, *, owner: str, spec: dict[str, Any], input_digest: str, input_name: str,
                   input_bytes: int, queue: str, job_id: str | None = None,
                   idempotency_key: str | None = None, request_digest: str | None = None,
                   client_name: str | None = None, label: str | None = None) -> tuple[Job, bool]:
        """Insert a queued job. Returns (job, created); with an Idempotency-Key seen before and
        the same ``request_digest`` returns the earlier job and False.

        Raises:
            IdempotencyConflict: same key, different request.
        """
        now = time.time()
        row = {
            "id": job_id or uuid.uuid4().hex, "owner": owner, "spec": json.dumps(spec, sort_keys=True),
            "input_digest": input_digest, "input_name": input_name, "input_bytes": input_bytes,
            "queue": queue, "status": "queued", "progress": 0.0, "attempts": 0,
            "cancel_requested": False, "created_at": now, "updated_at": now, "artifacts": "[]",
            "idempotency_key": idempotency_key, "request_digest": request_digest,
            "client_name": client_name, "label": label,
        }
        if idempotency_key is not None:
            prior = self.find_by_idempotency_key(owner, idempotency_key)
            if prior is not None:
                return self._same_request(prior, request_digest), False
        try:
            with self._tx() as conn:
                conn.execute(jobs.insert().values(**row))
        except sa.exc.IntegrityError:
            # Lost a race with a concurrent request carrying the same key.
            prior = self.find_by_idempotency_key(owner, idempotency_key) if idempotency_key else None
            if prior is None:
                raise
            return self._same_request(prior, request_digest), False
        job = self.get(row["id"])
        assert job is not None
        return job, True

    @staticmethod
    def _same_request(prior: Job, request_digest: str | None) -> Job:
        if prior.request_digest != request_digest:
            raise IdempotencyConflict(prior)
        return prior

    def find_by_idempotency_key(self, owner: str, key: str) -> Job | None:
        with self.engine.connect() as conn:
            row = conn.execute(jobs.select().where(jobs.c.owner == owner, jobs.c.idempotency_key == key)).first()
        return Job.from_row(row) if row else None

    def get(self, job_id: str, owner: str | None = None) -> Job | None:
        """The job, or None if absent or (with ``owner``) owned by someone else."""
        q = jobs.select().where(jobs.c.id == job_id)
        if owner is not None:
            q = q.where(jobs.c.owner == owner)
        with self.engine.connect() as conn:
            row = conn.execute(q).first()
        return Job.from_row(row) if row else None

    def request_cancel(self, job_id: str, owner: str) -> Job | None:
        """Cancel a queued job at once; flag a running one for its worker to stop cooperatively."""
        now = time.time()
        with self._tx() as conn:
            conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.owner == owner,
                                             jobs.c.status == "queued")
                         .values(status="cancelled", cancel_requested=True, finished_at=now,
                                 updated_at=now, stage="cancelled"))
            conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.owner == owner,
                                             jobs.c.status == "running")
                         .values(cancel_requested=True, updated_at=now))
        return self.get(job_id, owner)

    def fail_queued(self, job_id: str, error: str) -> bool:
        """Fail a job that never left the queue (e.g. its message could not be sent)."""
        now = time.time()
        with self._tx() as conn:
            res = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "queued")
                               .values(status="failed", error=error, finished_at=now, updated_at=now,
                                       stage="failed", idempotency_key=None))  # a retry may reuse the key
        return res.rowcount == 1

    def count_active(self, owner: str) -> int:
        """Queued plus running jobs of ``owner`` (the per-key quota counts these)."""
        with self.engine.connect() as conn:
            return int(conn.execute(sa.select(sa.func.count()).select_from(jobs).where(
                jobs.c.owner == owner, jobs.c.status.in_(("queued", "running")))).scalar() or 0)

    def reserve_slot(self, owner: str, limit: int, stale_after_s: float) -> tuple[str | None, int]:
        """Take one of ``owner``'s ``limit`` slots for a submission in flight, atomically.

        Returns (reservation id, slots in use before it); the id is None when all ``limit`` are
        taken by queued or running jobs and other submissions in flight. Release the slot with
        :meth:`release_slot` once the job row exists (or the submission failed). Reservations
        older than ``stale_after_s`` (their API process died) are removed first.
        """
        now = time.time()
        with self._tx() as conn:
            if conn.dialect.name == "postgresql":
                # One submission of a key at a time between the count and the insert.
                lock = int.from_bytes(hashlib.sha256(owner.encode()).digest()[:8], "big", signed=True)
                conn.execute(sa.text("SELECT pg_advisory_xact_lock(:k)"), {"k": lock})
            # On SQLite this DELETE, the transaction's first statement, takes the database's
            # write lock: the count below cannot change before the insert commits.
            conn.execute(reservations.delete().where(reservations.c.created_at < now - stale_after_s))
            jobs_in_use = conn.execute(sa.select(sa.func.count()).select_from(jobs).where(
                jobs.c.owner == owner, jobs.c.status.in_(("queued", "running")))).scalar() or 0
            held = conn.execute(sa.select(sa.func.count()).select_from(reservations).where(
                reservations.c.owner == owner)).scalar() or 0
            in_use = int(jobs_in_use) + int(held)
            if in_use >= limit:
                return None, in_use
            rid = uuid.uuid4().hex
            conn.execute(reservations.insert().values(id=rid, owner=owner, created_at=now))
            return rid, in_use

    def release_slot(self, reservation_id: str) -> None:
        """Give back a slot taken by :meth:`reserve_slot` (its job row now counts instead)."""
        with self._tx() as conn:
            conn.execute(reservations.delete().where(reservations.c.id == reservation_id))

    def queue_position(self, job: Job) -> int:
        """Queued jobs of any owner ahead of ``job`` in its queue (0: it is next)."""
        ahead = sa.or_(jobs.c.created_at < job.created_at,
                       sa.and_(jobs.c.created_at == job.created_at, jobs.c.id < job.id))
        with self.engine.connect() as conn:
            return int(conn.execute(sa.select(sa.func.count()).select_from(jobs).where(
                jobs.c.status == "queued", jobs.c.queue == job.queue, ahead)).scalar() or 0)

    def queue_rate(self, queue: str, recent: int = 20) -> tuple[float | None, list[Job]]:
        """What an ETA is made of: the mean run time (s) of the last ``recent`` jobs that ran to
        an end in ``queue`` (None before any did), and the jobs running there now."""
        ran = (jobs.c.queue == queue) & jobs.c.status.in_(("succeeded", "failed")) & jobs.c.started_at.isnot(None)
        with self.engine.connect() as conn:
            last = (sa.select((jobs.c.finished_at - jobs.c.started_at).label("d")).where(ran)
                    .order_by(jobs.c.finished_at.desc()).limit(recent).subquery())
            mean = conn.execute(sa.select(sa.func.avg(last.c.d))).scalar()
            running = [Job.from_row(r) for r in conn.execute(
                jobs.select().where(jobs.c.queue == queue, jobs.c.status == "running"))]
        return (float(mean) if mean is not None else None), running

    def delete(self, job_id: str, owner: str | None = None) -> bool:
        """Remove the job's row (with ``owner``: only that owner's). Its worker, if any, loses
        the lease at its next heartbeat. True if a row went."""
        q = jobs.delete().where(jobs.c.id == job_id)
        if owner is not None:
            q = q.where(jobs.c.owner == owner)
        with self._tx() as conn:
            return conn.execute(q).rowcount == 1

    def finished_before(self, cutoff: float, limit: int = 500) -> list[Job]:
        """Finished jobs (succeeded, failed, cancelled) that ended before ``cutoff``, oldest first."""
        with self.engine.connect() as conn:
            rows = conn.execute(jobs.select().where(jobs.c.status.in_(tuple(TERMINAL)),
                                                    jobs.c.finished_at < cutoff)
                                .order_by(jobs.c.finished_at).limit(limit))
            return [Job.from_row(r) for r in rows]

    def exists(self, job_id: str) -> bool:
        with self.engine.connect() as conn:
            return conn.execute(sa.select(jobs.c.id).where(jobs.c.id == job_id)).first() is not None

    def count_by_status(self) -> dict[str, int]:
        with self.engine.connect() as conn:
            rows = conn.execute(sa.select(jobs.c.status, sa.func.count()).group_by(jobs.c.status))
            return {s: int(n) for s, n in rows}
