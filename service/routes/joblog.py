"""A job's own log lines (``jobs.joblog``): ``GET /reconstructions/{id}/log``."""

from __future__ import annotations

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from jobs.joblog import NAME, read_tail
from jobs.layout import job_paths

from ..deps import ERRORS, Owner, SettingsDep, StoreDep, job_of

router = APIRouter()

#: The most lines and bytes one answer carries (the file itself is capped by the worker).
MAX_LINES = 1000
MAX_BYTES = 128 * 1024


class JobLog(BaseModel):
    job_id: str
    status: str
    lines: list[str] = Field(description="the last lines of the job's log, oldest first: 'HH:MM:SS level message' (UTC)")
    truncated: bool = Field(description="true when earlier lines were left out")


@router.get("/reconstructions/{job_id}/log", response_model=JobLog, responses=ERRORS)
def job_log(job_id: str, who: Owner, store: StoreDep, settings: SettingsDep,
            tail: int = Query(200, ge=1, le=MAX_LINES, description="how many of the last lines")) -> JobLog:
    """The last ``tail`` lines the worker logged while running the job (stages, progress with
    the loss, warnings, the outcome); empty until a worker started it."""
    job = job_of(store, job_id, who)
    _, out_dir = job_paths(settings, job.id)
    lines, cut = read_tail(out_dir.parent / NAME, tail, MAX_BYTES)
    return JobLog(job_id=job.id, status=job.status, lines=lines, truncated=cut)
