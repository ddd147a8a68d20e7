"""Response models of the HTTP API (pydantic v2; they make the OpenAPI schema at /docs)."""

from __future__ import annotations

import dataclasses
import time
from datetime import UTC, datetime
from typing import Any, Literal

from pydantic import BaseModel, Field

from jobs.store import Job
from shsas_core.evaluation.diagnostics import ResultWarning

from .status import LiveStatus, running_eta

Status = Literal["queued", "running", "succeeded", "failed", "cancelled"]


def iso(ts: float | None) -> str | None:
    return None if ts is None else datetime.fromtimestamp(ts, UTC).isoformat().replace("+00:00", "Z")


class ArtifactLink(BaseModel):
    name: str = Field(description="server-made file name, e.g. shsas_mesh.glb")
    url: str


class Artifact(ArtifactLink):
    size: int = Field(description="bytes")
    media_type: str
    etag: str


class JobInput(BaseModel):
    digest: str = Field(description="sha256 of the uploaded survey file")
    bytes: int
    name: str = Field(description="server-made name of the stored input")
    filename: str | None = Field(None, description="the survey's file name as the client uploaded it "
                                 "(null for jobs submitted before it was kept)")


class ResultWarningOut(ResultWarning):
    """A sign that one method's result failed (docs/usage.md, Warnings): the pipeline's warning
    plus the method it concerns."""

    method: str = Field(description="backprojection, reed or shsas")


class JobOut(BaseModel):
    """A reconstruction job as the API shows it."""

    id: str
    status: Status
    progress: float = Field(ge=0, le=1, description="overall fraction done")
    stage: str | None = Field(description="current pipeline stage, e.g. fit:shsas")
    iterations_per_s: float | None = Field(None, description="latest training speed reported by the pipeline")
    live_metrics: dict[str, float] = Field(default_factory=dict, description="latest progress metrics "
                                               "(loss, it/s, ...; eta_s as measured at eta_at, unix seconds)")
    attempts: int = Field(description="deliveries so far; > 1 after a worker was lost and the job resumed")
    cancel_requested: bool
    created_at: str | None
    started_at: str | None
    finished_at: str | None
    updated_at: str | None
    error: str | None
    spec: dict[str, Any]
    label: str | None = Field(None, description="the submitter's name for the job (form field `label`)")
    input: JobInput
    metrics: dict[str, dict[str, float | None]] | None = Field(
        None, description="per-method metrics summary (null: undefined, e.g. Chamfer of an empty cloud)")
    warnings: list[ResultWarningOut] = Field(
        default_factory=list, description="signs that a method's result failed although the job succeeded "
        "(collapsed volume, cloud filling the scene box, data loss that did not fall); empty when none")
    device: str | None = Field(
        None, description="the device that ran the job: cpu or cuda:N (card name); null until it succeeded")
    artifacts: list[ArtifactLink]
    links: dict[str, str]
    queue_position: int | None = Field(
        None, description="queued jobs (of any key) ahead of this one in its queue; 0 = next. "
        "Only in GET /reconstructions/{id}, null elsewhere and once the job left the queue")
    eta_s: float | None = Field(
        None, description="rough seconds until the job finishes. Running: from the pace its current "
        "stage measured (null until it has); queued (only in GET /reconstructions/{id}): from the "
        "measured run time of recent jobs in its queue; null until measured")
    heartbeat_age_s: float | None = Field(
        None, description="running jobs: seconds since the worker last wrote its heartbeat. Only in "
        "GET /reconstructions/{id}")
    worker_responding: bool | None = Field(
        None, description="running jobs: false once the heartbeat is older than three heartbeat "
        "intervals (the worker died, hangs or lost the job store); the job is re-queued once the age "
        "passes the lease timeout")

    @classmethod
    def from_job(cls, job: Job, base: str = "", live: LiveStatus | None = None) -> JobOut:
        url = f"{base}/reconstructions/{job.id}"
        lm = job.live_metrics
        rate = next((lm[k] for k in ("it_per_s", "iters_per_s", "it/s") if k in lm), None)
        return cls(
            id=job.id, status=job.status, progress=job.progress, stage=job.stage, iterations_per_s=rate,  # type: ignore[arg-type]
            live_metrics=lm, attempts=job.attempts, cancel_requested=job.cancel_requested,
            created_at=iso(job.created_at), started_at=iso(job.started_at), finished_at=iso(job.finished_at),
            updated_at=iso(job.updated_at), error=job.error, spec=job.spec, label=job.label,
            input=JobInput(digest=job.input_digest, bytes=job.input_bytes, name=job.input_name,
                           filename=job.client_name),
            metrics=job.metrics, warnings=[ResultWarningOut.model_validate(w) for w in job.warnings],
            device=job.device,
            artifacts=[ArtifactLink(name=a, url=f"{url}/artifacts/{a}") for a in job.artifacts],
            links={"self": url, "cancel": f"{url}/cancel", "artifacts": f"{url}/artifacts"},
            **(dataclasses.asdict(live) if live is not None
               else {"eta_s": running_eta(job, time.time())} if job.status == "running" else {}),
        )


class JobPage(BaseModel):
    items: list[JobOut]
    next_cursor: str | None = Field(description="pass as ?cursor= for the next page; null on the last")


class ArtifactList(BaseModel):
    job_id: str
    status: Status
    items: list[Artifact]


class Health(BaseModel):
    status: str
    checks: dict[str, str] = Field(default_factory=dict)
    #: when not ready: which dependencies are down, in words (the other 503s' ``detail``)
    detail: str | None = None


class ErrorOut(BaseModel):
    detail: str
