"""The job store's records: the tables, the decoded rows (``Job``, ``ApiKey``), the engine.

Times are float seconds since the epoch (UTC), so staleness is plain arithmetic in SQL on
both back ends.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.engine import Engine

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
    # Added after the first release: nullable, so ``migrate.add_missing_columns`` can add them
    # to an existing table (rows from before read as None).
    sa.Column("client_name", sa.String(255), nullable=True),
    sa.Column("label", sa.String(200), nullable=True),
    sa.UniqueConstraint("owner", "idempotency_key", name="uq_shsas_jobs_owner_idem"),
    sa.Index("ix_shsas_jobs_owner_created", "owner", "created_at"),
    sa.Index("ix_shsas_jobs_status_heartbeat", "status", "heartbeat_at"),
)

#: Submissions between the quota check and their job row (upload validated, job not yet
#: inserted): counted with the key's queued and running jobs, so concurrent submissions cannot
#: all pass a count read before the seconds-long validation. A row whose API process died is
#: ignored and removed once it is older than the validation could take.
reservations = sa.Table(
    "shsas_reservations", metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("owner", sa.String(64), nullable=False),
    sa.Column("created_at", sa.Double, nullable=False),
    sa.Index("ix_shsas_reservations_owner", "owner"),
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
#: Likewise the device that ran a finished job (``shsas_core.common.device.describe_device``).
DEVICE_KEY = "_device"
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
    #: (``shsas_core.evaluation.diagnostics.ResultWarning`` plus the method); stored inside ``metrics``
    warnings: list[dict[str, Any]] = field(default_factory=list)
    #: the device that ran the job (``cpu``, ``cuda:0 (card)``); stored inside ``metrics``; None
    #: until the job succeeded, and for rows written before it was recorded
    device: str | None = None
    #: the survey's file name as the client sent it (None for rows from before it was kept)
    client_name: str | None = None
    #: the operator's free-text name for the job
    label: str | None = None

    @classmethod
    def from_row(cls, row: sa.Row) -> Job:
        m = dict(row._mapping)
        m["spec"] = json.loads(m["spec"])
        m["live_metrics"] = json.loads(m["live_metrics"]) if m["live_metrics"] else {}
        m["artifacts"] = json.loads(m["artifacts"] or "[]")
        metrics = json.loads(m["metrics"]) if m["metrics"] else None
        m["warnings"] = list(metrics.pop(WARNINGS_KEY, None) or []) if metrics else []
        m["device"] = metrics.pop(DEVICE_KEY, None) if metrics else None
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


#: Seconds to wait for a PostgreSQL connection (a new one, or a free one of the pool).
STORE_CONNECT_TIMEOUT_S = 5


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
    # A database host that drops packets would hold a request for the kernel's TCP timeout
    # (minutes); with a connect timeout and a pool timeout a request fails fast and the API
    # answers 503 (service/app.py) while the database is away.
    connect_args: dict[str, Any] = {"connect_timeout": STORE_CONNECT_TIMEOUT_S}
    kwargs: dict[str, Any] = {"pool_pre_ping": True, "pool_size": 10, "max_overflow": 20,
                              "pool_timeout": STORE_CONNECT_TIMEOUT_S, "connect_args": connect_args}
    if schema:
        if not schema.replace("_", "").isalnum():
            raise ValueError(f"database schema name must be alphanumeric/underscore, got {schema!r}")
        connect_args["options"] = f"-csearch_path={schema}"
    engine = sa.create_engine(url, **kwargs)
    if schema:
        with engine.begin() as conn:
            conn.execute(sa.text(f'CREATE SCHEMA IF NOT EXISTS "{schema}"'))
    return engine


def hash_secret(secret: str) -> str:
    # Keys are 256-bit random tokens, so a fast hash is enough (no dictionary to attack).
    return hashlib.sha256(secret.encode()).hexdigest()


def encode_cursor(created_at: float, job_id: str) -> str:
    return base64.urlsafe_b64encode(f"{created_at!r}|{job_id}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str) -> tuple[float, str]:
    """Inverse of the cursor encoding; raises ValueError on garbage."""
    raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
    created, job_id = raw.split("|", 1)
    if not job_id.isalnum() or len(job_id) > 32:
        raise ValueError("bad cursor")
    return float(created), job_id
