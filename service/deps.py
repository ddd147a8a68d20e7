"""FastAPI dependencies shared by the routers: the job store, the settings, the caller and the
caller's job named by the route's ``{job_id}``.

Each reads what ``create_app`` put on ``app.state``; they are ``async`` so they run on the event
loop (a thread hop per request would cost more than these reads under 100 pollers).
"""

from __future__ import annotations

from typing import Annotated

import pydantic
from fastapi import Depends, HTTPException, Request
from fastapi.responses import JSONResponse, Response

from jobs.settings import Settings
from jobs.store import Job, JobStore

from .auth import owner_of
from .models import ErrorOut

#: The error answers every job route documents.
ERRORS = {400: {"model": ErrorOut}, 401: {"model": ErrorOut}, 404: {"model": ErrorOut}}


async def current_owner(request: Request) -> str:
    """The job owner (API key id, or ``local`` for keyless loopback clients): one indexed read."""
    return owner_of(request, request.app.state.store)


async def current_store(request: Request) -> JobStore:
    return request.app.state.store


async def current_settings(request: Request) -> Settings:
    return request.app.state.settings


Owner = Annotated[str, Depends(current_owner)]
StoreDep = Annotated[JobStore, Depends(current_store)]
SettingsDep = Annotated[Settings, Depends(current_settings)]


def job_of(store: JobStore, job_id: str, who: str) -> Job:
    """The job ``job_id`` owned by ``who``, or HTTPException 404: also for a malformed id (ids
    are server-made hex) and for another key's job (whose existence is not revealed)."""
    job = store.get(job_id, who) if len(job_id) <= 32 and job_id.isalnum() else None
    if job is None:
        raise HTTPException(404, f"no reconstruction {job_id!r} for this API key")
    return job


async def current_job(job_id: str, who: Owner, store: StoreDep) -> Job:
    """The route's ``{job_id}`` if the caller's key owns it: 401 without a valid key, else 404."""
    return job_of(store, job_id, who)


JobDep = Annotated[Job, Depends(current_job)]


async def current_succeeded_job(job: JobDep) -> Job:
    """As :data:`JobDep`, and 409 unless the job succeeded (its outputs exist only then)."""
    if job.status != "succeeded":
        raise HTTPException(409, f"reconstruction {job.id} is {job.status}; this needs a succeeded job")
    return job


SucceededJobDep = Annotated[Job, Depends(current_succeeded_job)]


def json_response(model: pydantic.BaseModel, status: int = 200) -> Response:
    """The model serialised once; returning a Response skips FastAPI's second validation pass."""
    return Response(model.model_dump_json(), status_code=status, media_type="application/json")


#: Seconds a client is asked to wait (``Retry-After``) when a dependency (job store, broker) or
#: a bound of this process (connections, concurrent validations) makes the API answer 503.
RETRY_AFTER_S = 5


def unavailable(detail: str) -> JSONResponse:
    """The 503 answer: the documented JSON error plus ``Retry-After``."""
    return JSONResponse({"detail": detail}, status_code=503, headers={"Retry-After": str(RETRY_AFTER_S)})
