"""The job store: the relational table that is the source of truth for every job (docs/service.md).

SQLAlchemy 2 Core over SQLite (default, a file in the data dir) or PostgreSQL (psycopg 3).
Celery only delivers work; whoever holds a job's lease (``lease_owner`` + fresh
``heartbeat_at``) runs it, and every state change is a single conditional UPDATE so that two
workers, two API processes or two reconcilers can never both win the same transition.

Times are float seconds since the epoch (UTC), so staleness is plain arithmetic in SQL on
both back ends.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import math
import os
import secrets
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.engine import Connection, Engine

STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
TERMINAL = frozenset({"succeeded", "failed", "cancelled"})

metadata = sa.MetaData()

jobs = sa.Table(
    "shsas_jobs", metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("owner", sa.String(64), nullable=False),
    sa.Column("spec", sa.Text, nullable=False),
    sa.Column("input_digest", sa.String(64), nullable=False),
    sa.Column("input_name", sa.String(64), nullable=False),
    sa.Column("input_bytes", sa.BigInteger, nullable=False),
    sa.Column("queue", sa.String(64), nullable=False),
    sa.Column("status", sa.String(16), nullable=False),
    sa.Column("progress", sa.Double, nullable=False, default=0.0),
    sa.Column("stage", sa.String(64), nullable=True),
    sa.Column("live_metrics", sa.Text, nullable=True),
    sa.Column("attempts", sa.Integer, nullable=False, default=0),
    sa.Column("lease_owner", sa.String(128), nullable=True),
    sa.Column("heartbeat_at", sa.Double, nullable=True),
    sa.Column("cancel_requested", sa.Boolean, nullable=False, default=False),
    sa.Column("created_at", sa.Double, nullable=False),
    sa.Column("started_at", sa.Double, nullable=True),
    sa.Column("finished_at", sa.Double, nullable=True),
    sa.Column("updated_at", sa.Double, nullable=False),
    sa.Column("error", sa.Text, nullable=True),
    sa.Column("artifacts", sa.Text, nullable=False, default="[]"),
    sa.Column("metrics", sa.Text, nullable=True),
    sa.Column("idempotency_key", sa.String(200), nullable=True),
    sa.Column("request_digest", sa.String(64), nullable=True),
    sa.UniqueConstraint("owner", "idempotency_key", name="uq_shsas_jobs_owner_idem"),
    sa.Index("ix_shsas_jobs_owner_created", "owner", "created_at"),
    sa.Index("ix_shsas_jobs_status_heartbeat", "status", "heartbeat_at"),
)

api_keys = sa.Table(
    "shsas_api_keys", metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("name", sa.String(100), nullable=False),
    sa.Column("secret_hash", sa.String(64), nullable=False),
    sa.Column("created_at", sa.Double, nullable=False),
    sa.Column("revoked_at", sa.Double, nullable=True),
)

#: The owner of jobs submitted without a key (embedded default, loopback clients only).
LOCAL_OWNER = "local"
#: Key under which a finished job's result warnings ride in the ``metrics`` JSON column (method
#: names never start with "_"), so existing databases need no new column; :meth:`Job.from_row`
#: takes it out again, and rows written before it existed read as "no warnings".
WARNINGS_KEY = "_warnings"
KEY_PREFIX = "shsas_"


@dataclass(frozen=True)
class Job:
    """One row of the job table, decoded."""

    id: str
    owner: str
    spec: dict[str, Any]
    input_digest: str
    input_name: str
    input_bytes: int
    queue: str
    status: str
    progress: float
    stage: str | None
    live_metrics: dict[str, float]
    attempts: int
    lease_owner: str | None
    heartbeat_at: float | None
    cancel_requested: bool
    created_at: float
    started_at: float | None
    finished_at: float | None
    updated_at: float
    error: str | None
    artifacts: list[str]
    metrics: dict[str, dict[str, float]] | None
    idempotency_key: str | None
    request_digest: str | None
    #: signs that the result failed: ``{"method", "code", "message", "measure", "limit"}`` each
    #: (``shsas_core.diagnostics.ResultWarning`` plus the method); stored inside ``metrics``
    warnings: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_row(cls, row: sa.Row) -> Job:
        m = dict(row._mapping)
        m["spec"] = json.loads(m["spec"])
        m["live_metrics"] = json.loads(m["live_metrics"]) if m["live_metrics"] else {}
        m["artifacts"] = json.loads(m["artifacts"] or "[]")
        metrics = json.loads(m["metrics"]) if m["metrics"] else None
        m["warnings"] = list(metrics.pop(WARNINGS_KEY, None) or []) if metrics else []
        if metrics:  # rows written before undefined metrics were None hold the text NaN
            metrics = {meth: {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                              for k, v in d.items()} for meth, d in metrics.items()}
        m["metrics"] = metrics
        m["cancel_requested"] = bool(m["cancel_requested"])
        return cls(**m)


@dataclass(frozen=True)
class ApiKey:
    id: str
    name: str
    created_at: float
    revoked_at: float | None


class IdempotencyConflict(Exception):
    """The Idempotency-Key was used before with a different request body."""

    def __init__(self, job: Job):
        super().__init__(f"Idempotency-Key already used for job {job.id} with a different request")
        self.job = job


def make_engine(url: str, schema: str | None = None) -> Engine:
    """An engine for ``url``; SQLite gets WAL and a busy timeout so several processes can share it."""
    if url.startswith("sqlite"):
        engine = sa.create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @sa.event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record) -> None:  # pragma: no cover - trivial
            cur = dbapi_conn.cursor()
            # WAL lets the API read while a worker writes progress; NORMAL sync is safe under WAL.
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    kwargs: dict[str, Any] = {"pool_pre_ping": True, "pool_size": 10, "max_overflow": 20}
    if schema:
        if not schema.replace("_", "").isalnum():
            raise ValueError(f"database schema name must be alphanumeric/underscore, got {schema!r}")
        kwargs["connect_args"] = {"options": f"-csearch_path={schema}"}
    engine = sa.create_engine(url, **kwargs)
    if schema:
        with engine.begin() as conn:
            conn.execute(sa.text(f'CREATE SCHEMA IF NOT EXISTS "{schema}"'))
    return engine


def _hash_secret(secret: str) -> str:
    # Keys are 256-bit random tokens, so a fast hash is enough (no dictionary to attack).
    return hashlib.sha256(secret.encode()).hexdigest()


def _encode_cursor(created_at: float, job_id: str) -> str:
    return base64.urlsafe_b64encode(f"{created_at!r}|{job_id}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str) -> tuple[float, str]:
    """Inverse of the cursor encoding; raises ValueError on garbage."""
    raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
    created, job_id = raw.split("|", 1)
    if not job_id.isalnum() or len(job_id) > 32:
        raise ValueError("bad cursor")
    return float(created), job_id


class JobStore:
    """All reads and writes of jobs and API keys."""

    def __init__(self, url: str, schema: str | None = None, *, create: bool = True):
        self.url = url
        self.engine = make_engine(url, schema)
        # A pooled connection must never be shared across fork (Celery's prefork pool):
        # the child drops the parent's pool without closing the parent's sockets.
        engine = self.engine
        os.register_at_fork(after_in_child=lambda: engine.dispose(close=False))
        if create:
            self._create_tables()

    def _create_tables(self) -> None:
        with self.engine.begin() as conn:
            if conn.dialect.name == "postgresql":
                # API replicas and workers start together: serialise CREATE TABLE IF NOT EXISTS.
                conn.execute(sa.text("SELECT pg_advisory_xact_lock(7274201)"))
            metadata.create_all(conn)

    @classmethod
    def from_settings(cls, settings) -> JobStore:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        return cls(settings.db_url, settings.database_schema)

    def dispose(self) -> None:
        self.engine.dispose()

    @contextmanager
    def _tx(self) -> Iterator[Connection]:
        with self.engine.begin() as conn:
            yield conn

    def ping(self) -> None:
        """Raise if the database cannot answer a trivial query."""
        with self.engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))

    # ---- jobs: submission and queries -------------------------------------------------------
    def create_job(self, *, owner: str, spec: dict[str, Any], input_digest: str, input_name: str,
                   input_bytes: int, queue: str, job_id: str | None = None,
                   idempotency_key: str | None = None, request_digest: str | None = None) -> tuple[Job, bool]:
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

    def list_jobs(self, owner: str, *, status: str | None = None, cursor: str | None = None,
                  limit: int = 50) -> tuple[list[Job], str | None]:
        """The owner's jobs newest first; returns (page, next_cursor or None)."""
        q = jobs.select().where(jobs.c.owner == owner)
        if status is not None:
            q = q.where(jobs.c.status == status)
        if cursor:
            created, jid = decode_cursor(cursor)
            q = q.where(sa.or_(jobs.c.created_at < created,
                               sa.and_(jobs.c.created_at == created, jobs.c.id < jid)))
        q = q.order_by(jobs.c.created_at.desc(), jobs.c.id.desc()).limit(limit + 1)
        with self.engine.connect() as conn:
            rows = [Job.from_row(r) for r in conn.execute(q)]
        nxt = _encode_cursor(rows[limit - 1].created_at, rows[limit - 1].id) if len(rows) > limit else None
        return rows[:limit], nxt

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

    # ---- jobs: the worker side ---------------------------------------------------------------
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
               warnings: list[dict[str, Any]] | None = None) -> bool:
        """Move a running job this worker leases to a terminal status. False if the lease was lost.

        ``warnings`` (see :attr:`Job.warnings`) are stored with the metrics.
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

    # ---- API keys -----------------------------------------------------------------------------
    def create_key(self, name: str) -> tuple[ApiKey, str]:
        """Make a key; returns (record, token). The token is shown once and stored only hashed."""
        key_id = secrets.token_hex(6)
        secret = secrets.token_urlsafe(32)
        rec = ApiKey(id=key_id, name=name[:100], created_at=time.time(), revoked_at=None)
        with self._tx() as conn:
            conn.execute(api_keys.insert().values(id=rec.id, name=rec.name, created_at=rec.created_at,
                                                  secret_hash=_hash_secret(secret)))
        return rec, f"{KEY_PREFIX}{key_id}_{secret}"

    def list_keys(self) -> list[ApiKey]:
        with self.engine.connect() as conn:
            rows = conn.execute(sa.select(api_keys.c.id, api_keys.c.name, api_keys.c.created_at,
                                          api_keys.c.revoked_at).order_by(api_keys.c.created_at))
            return [ApiKey(*r) for r in rows]

    def revoke_key(self, key_id: str) -> bool:
        with self._tx() as conn:
            res = conn.execute(api_keys.update().where(api_keys.c.id == key_id, api_keys.c.revoked_at.is_(None))
                               .values(revoked_at=time.time()))
        return res.rowcount == 1

    def has_active_keys(self) -> bool:
        with self.engine.connect() as conn:
            return conn.execute(sa.select(api_keys.c.id).where(api_keys.c.revoked_at.is_(None)).limit(1)).first() is not None

    def verify_key(self, token: str) -> str | None:
        """The key id (= job owner) for a valid, unrevoked token, else None."""
        if not token.startswith(KEY_PREFIX):
            return None
        key_id, _, secret = token[len(KEY_PREFIX):].partition("_")
        if not key_id or not secret:
            return None
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(api_keys.c.secret_hash).where(
                api_keys.c.id == key_id, api_keys.c.revoked_at.is_(None))).first()
        if row is None:
            return None
        return key_id if hmac.compare_digest(row[0], _hash_secret(secret)) else None
