"""Service configuration from the environment (``SHSAS_*``), via pydantic-settings.

One :class:`Settings` object is shared by the API, the Celery worker, the embedded local worker
and the ``shsas`` commands that start them, so a deployment is configured in one place.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from shsas_core.spec.memory import DEFAULT_FRACTION, default_memory_budget

GiB = 1024**3


class Settings(BaseSettings):
    """Everything the service reads from the environment. Every field is ``SHSAS_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="SHSAS_", extra="ignore")

    data_dir: Path = Field(Path("shsas_data"), description="uploads, job outputs and the default SQLite job store")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL of the job store; unset = sqlite file <data_dir>/shsas.db. "
        "PostgreSQL: postgresql+psycopg://user@host/db")
    database_schema: str | None = Field(None, description="PostgreSQL schema for the tables (default: search_path)")
    broker_url: str | None = Field(
        None, description="Celery broker (redis://host:6379/0); unset = embedded local worker, no Redis")
    gpu_queue: str = Field("gpu", description="Celery queue for jobs with device auto/cuda")
    cpu_queue: str = Field("cpu", description="Celery queue for jobs with device cpu")
    auto_device_queue: str = Field("gpu", pattern=r"^(gpu|cpu)$",
                                   description="which queue takes jobs whose spec says device=auto")
    max_upload_bytes: int = Field(4 * GiB, ge=1, description="survey upload cap; larger uploads get 413")
    validate_memory_bytes: int = Field(4 * GiB, ge=512 * 1024**2,
                                       description="address-space limit of the survey validation process")
    validate_timeout_s: float = Field(300.0, gt=0, description="time limit of the survey validation process")
    max_concurrent_validations: int = Field(
        2, ge=1, description="validation processes running at once (across the API processes sharing the "
        "data dir); a submission waits for a free one")
    validate_wait_s: float = Field(
        30.0, ge=0, description="how long a submission waits for a validation slot before it gets 503 "
        "with Retry-After")
    max_ground_truth_elements: int = Field(
        2_000_000, ge=0, description="upload cap: vertices plus faces of a survey's ground-truth mesh; "
        "larger meshes get 413")
    max_extras_bytes: int = Field(
        256 * 1024**2, ge=0, description="upload cap: bytes declared by the arrays under a survey's /extras; "
        "more gets 413")
    worker_memory_bytes: int = Field(
        default_factory=default_memory_budget, ge=256 * 1024**2,
        description="memory a job may need (estimated from the survey's declared sizes and the spec); "
        f"larger jobs get 413 at upload and fail in the worker before loading. Unset: {DEFAULT_FRACTION:.0%} "
        "of the memory of the machine (or container) reading the setting")
    job_soft_time_limit_s: float = Field(6 * 3600.0, gt=0, description="a job past this is stopped and failed")
    job_hard_time_limit_s: float = Field(6 * 3600.0 + 300, gt=0, description="the worker child is killed past this")
    heartbeat_interval_s: float = Field(5.0, gt=0, description="how often a running job refreshes its lease")
    lease_timeout_s: float = Field(60.0, gt=0, description="a running job whose heartbeat is older is re-queued")
    reconcile_interval_s: float = Field(10.0, gt=0, description="how often stale leases are looked for")
    max_attempts: int = Field(2, ge=1, description="a job whose worker died (lease went stale) this many times "
                              "is failed, not retried: such deaths are most often out-of-memory kills")
    redispatch_after_s: float = Field(
        600.0, gt=0, description="a queued job not picked up for this long is sent to the broker again "
        "(its message may be lost); duplicates are harmless, a job runs once")
    local_poll_interval_s: float = Field(0.5, gt=0, description="embedded worker: how often it looks for queued jobs")
    page_size_max: int = Field(100, ge=1, le=1000)

    # ---- limits: quotas and the cost cap (service/quotas.py applies them) -----------------------
    max_active_jobs_per_key: int = Field(
        20, ge=1, description="queued plus running jobs one API key may have; the next submission gets 429")
    max_train_samples: float = Field(
        1e11, gt=0, description="cost cap of a spec: iterations x pings per batch x rays x bins of one neural "
        "method (the paper preset is 4.8e10); a larger spec gets 422")
    max_grid_voxels: int = Field(
        512**3, ge=8**3, description="cost cap of a spec: grid^3 (the explicit grid, or the automatic one "
        "from the survey's scene box); a larger spec gets 422")

    max_cpu_job_s: float | None = Field(
        None, gt=0, description="a job for the CPU queue whose estimated run time on a CPU "
        "(shsas_core/spec/cost.py) is over this gets 422 at submission; unset: SHSAS_JOB_SOFT_TIME_LIMIT_S, "
        "past which the job would be stopped anyway")
    allow_default_spec: bool = Field(
        False, description="accept a submission without a `spec` field as the default spec; "
        "unset, a missing spec is 422 (a forgotten or misnamed field never runs a full default job)")

    # ---- lifecycle: retention and sweeping (worker/sweeper.py) ----------------------------------
    retention_days: float = Field(
        30.0, ge=0, description="finished jobs (succeeded, failed, cancelled) older than this are deleted "
        "with their files; 0 keeps them forever")
    sweep_interval_s: float = Field(
        600.0, gt=0, description="how often the sweeper applies retention and removes abandoned uploads")
    delete_wait_s: float = Field(
        10.0, ge=0, description="DELETE of a running job: how long it waits for the job's cancel to land "
        "before it removes the job anyway")

    # ---- operations ---------------------------------------------------------------------------
    log_format: str = Field("json", pattern=r"^(json|text)$",
                            description="service logs: one JSON object per line, or plain text")
    worker_nice: int = Field(
        10, ge=0, le=19, description="scheduling niceness the workers add to themselves, so the API "
        "keeps the CPU it needs while a job trains")
    worker_threads: int | None = Field(
        None, ge=1, le=1024, description="threads of a job's torch and OpenMP pools; None: the CPUs the "
        "worker owns (its affinity set, capped by its cgroup quota). Fewer leave cores to other work on "
        "the host")

    # ---- HTTP connections (service/http_guard.py; docs/service.md, "Connections") ---------------
    api_workers: int = Field(
        1, ge=1, le=64, description="API processes `shsas serve` runs (uvicorn workers sharing the port); "
        "the connection limits below apply to each")
    http_header_timeout_s: float = Field(
        10.0, gt=0, description="a request's line and headers must arrive within this many seconds of "
        "its first byte (or of the connection's opening), else 408 and the connection closes")
    http_keepalive_s: int = Field(5, ge=1, description="an idle keep-alive connection is closed after this")
    http_max_header_bytes: int = Field(
        64 * 1024, ge=8 * 1024, description="request line plus headers larger than this get 431")
    http_max_connections: int = Field(
        1000, ge=16, description="open connections one API process serves; past it a new one gets 503")
    http_max_connections_per_client: int = Field(
        200, ge=1, description="open connections from one client address to one API process; past it "
        "503 (behind a proxy every client has the proxy's address: raise it there)")

    @model_validator(mode="after")
    def _limits(self) -> Settings:
        if self.job_hard_time_limit_s <= self.job_soft_time_limit_s:
            raise ValueError("SHSAS_JOB_HARD_TIME_LIMIT_S must exceed SHSAS_JOB_SOFT_TIME_LIMIT_S")
        if self.lease_timeout_s <= 2 * self.heartbeat_interval_s:
            raise ValueError("SHSAS_LEASE_TIMEOUT_S must exceed twice SHSAS_HEARTBEAT_INTERVAL_S")
        return self

    @cached_property
    def db_url(self) -> str:
        """The effective job-store URL (the SQLite default lives in the data dir)."""
        if self.database_url:
            url = self.database_url
            # Users write postgresql://; SQLAlchemy would pick psycopg2, which we do not ship.
            if url.startswith("postgresql://") or url.startswith("postgres://"):
                url = "postgresql+psycopg://" + url.split("://", 1)[1]
            return url
        return f"sqlite:///{(self.data_dir / 'shsas.db').resolve()}"

    @property
    def cpu_job_limit_s(self) -> float:
        """The effective cap of a CPU-queue job's estimated run time."""
        return self.max_cpu_job_s if self.max_cpu_job_s is not None else self.job_soft_time_limit_s

    @property
    def embedded(self) -> bool:
        """True when no broker is configured: the job table itself is the queue."""
        return not self.broker_url

    @property
    def visibility_timeout_s(self) -> int:
        """Redis redelivers an unacknowledged task after this; it must outlast the longest job."""
        return int(self.job_hard_time_limit_s + 600)

    def jobs_dir(self) -> Path:
        return self.data_dir / "jobs"

    def queue_for(self, device: str) -> str:
        """The Celery queue for a spec's device string."""
        if device == "cpu":
            return self.cpu_queue
        if device.startswith("cuda"):
            return self.gpu_queue
        return self.gpu_queue if self.auto_device_queue == "gpu" else self.cpu_queue


def get_settings() -> Settings:
    """Read the settings from the environment now (not cached: tests and CLIs change env)."""
    return Settings()
