"""Job routes: submit (POST /reconstructions), list, status, cancel and delete."""

from __future__ import annotations

import logging
import time
from typing import Annotated

import anyio
from anyio import to_thread
from fastapi import APIRouter, Header, HTTPException, Query, Request
from fastapi.responses import JSONResponse, Response

from jobs.layout import remove_job_files
from jobs.store import ORDERS, STATUSES, Job
from shsas_core.formats import all_formats

from ..deps import ERRORS, JobDep, Owner, SettingsDep, StoreDep, json_response
from ..models import ErrorOut, JobOut, JobPage
from ..status import live_status
from ..submission import submit_job

#: The upload's formats, from the one registry (a folder format travels as a .zip of it).
SURVEY_DESCRIPTION = "a survey in any format `shsas convert` reads: " + "; ".join(
    f"{f.name}: {f.summary}" for f in all_formats())

log = logging.getLogger("shsas.api")
router = APIRouter()


@router.post("/reconstructions", status_code=202, response_model=JobOut,
          responses={**ERRORS, 409: {"model": ErrorOut}, 413: {"model": ErrorOut},
                     415: {"model": ErrorOut}, 422: {"model": ErrorOut}, 429: {"model": ErrorOut},
                     503: {"model": ErrorOut}},
          openapi_extra={"requestBody": {"required": True, "content": {"multipart/form-data": {
              "schema": {
                  "type": "object", "required": ["survey"], "additionalProperties": False, "properties": {
                      "survey": {"type": "string", "format": "binary",
                                 "description": SURVEY_DESCRIPTION},
                      "spec": {"$ref": "#/components/schemas/ReconstructionSpec",
                               "description": "the ReconstructionSpec as JSON (defaults if absent)"},
                  }},
              "encoding": {"spec": {"contentType": "application/json"}}}}}})
async def submit(request: Request, who: Owner, store: StoreDep, settings: SettingsDep,
                 idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> Response:
    """Upload a survey and a spec; answers 202 with the queued job and its Location.

    Refused with 429 past the key's quota of queued and running jobs, and with 422 when the
    spec is over the cost cap (docs/service.md, "Limits")."""
    return _accepted(await submit_job(request, who, store, settings, idempotency_key), request)


def _accepted(job: Job, request: Request) -> JSONResponse:
    body = JobOut.from_job(job).model_dump(mode="json")
    return JSONResponse(body, status_code=202, headers={"Location": f"/reconstructions/{job.id}"})


@router.get("/reconstructions", response_model=JobPage, responses=ERRORS)
async def list_jobs(
    who: Owner, store: StoreDep, settings: SettingsDep,
    status: Annotated[str | None, Query(description="filter: one of " + ", ".join(STATUSES)
                                        + ", or several joined by commas (queued,running)")] = None,
    q: Annotated[str | None, Query(max_length=200, description="text search: part of the uploaded file "
                                   "name or the label (any case), or the start of the job id")] = None,
    order: Annotated[str, Query(description="newest (default): newest first; active: running, then "
                                "queued, then finished jobs, each newest first")] = "newest",
    cursor: str | None = None, limit: Annotated[int, Query(ge=1, le=1000)] = 50,
) -> Response:
    """The caller's jobs, one page at a time (``next_cursor`` for the next, with the same filters)."""
    wanted = tuple(s.strip() for s in status.split(",") if s.strip()) if status else None
    for s in wanted or ():
        if s not in STATUSES:
            raise HTTPException(400, f"status: unknown status {s!r} (one of {', '.join(STATUSES)})")
    if order not in ORDERS:
        raise HTTPException(400, f"order: unknown order {order!r} (one of {', '.join(ORDERS)})")
    try:
        items, nxt = await to_thread.run_sync(lambda: store.list_jobs(
            who, status=wanted, text=q, order=order, cursor=cursor,  # type: ignore[arg-type]
            limit=min(limit, settings.page_size_max)))
    except ValueError:
        raise HTTPException(400, "cursor: not a cursor this API returned for this order") from None
    return json_response(JobPage(items=[JobOut.from_job(j) for j in items], next_cursor=nxt))


@router.get("/reconstructions/{job_id}", response_model=JobOut, responses=ERRORS)
async def get_job(job: JobDep, store: StoreDep, settings: SettingsDep) -> Response:
    """Status, progress, stage, attempts, timestamps, error, metrics and artifact links; for a
    queued job its queue position and ETA, for a running one its ETA and heartbeat age."""
    # The route pollers hit: one indexed read on the event loop (a queued job adds one count;
    # the queue's measured rate is cached for a few seconds).
    return json_response(JobOut.from_job(job, live=live_status(store, settings, job)))


@router.head("/reconstructions/{job_id}", responses=ERRORS)
async def head_job(job: JobDep, store: StoreDep, settings: SettingsDep) -> Response:
    """The headers ``GET /reconstructions/{id}`` would send (status, length, type), no body."""
    full = await get_job(job, store, settings)
    return Response(status_code=full.status_code, media_type=full.media_type,
                    headers={"content-length": str(len(full.body))})


@router.post("/reconstructions/{job_id}/cancel", response_model=JobOut, status_code=202, responses=ERRORS)
def cancel_job(job: JobDep, who: Owner, store: StoreDep) -> JobOut:
    """Ask a job to stop. Queued jobs end at once; running ones at their next step."""
    cancelled = store.request_cancel(job.id, who)
    assert cancelled is not None
    log.info("job %s: cancel requested", job.id, extra={"job_id": job.id, "key_id": who,
                                                       "status": cancelled.status})
    return JobOut.from_job(cancelled)


@router.delete("/reconstructions/{job_id}", status_code=204, responses={
    **ERRORS, 204: {"description": "deleted: the job and its files are gone"}})
async def delete_job(job: JobDep, who: Owner, store: StoreDep, settings: SettingsDep) -> Response:
    """Delete a job and its files (the survey and every artifact). A queued job is cancelled; a
    running one is cancelled first and deleted once it stopped (or after SHSAS_DELETE_WAIT_S;
    its worker then removes what it still writes). Only the key that submitted it can."""
    was = job.status
    if job.status in ("queued", "running"):
        current = await to_thread.run_sync(store.request_cancel, job.id, who)
        deadline = time.monotonic() + settings.delete_wait_s
        while current is not None and current.status == "running" and time.monotonic() < deadline:
            await anyio.sleep(0.1)
            current = await to_thread.run_sync(store.get, job.id, who)
    await to_thread.run_sync(store.delete, job.id, who)
    await to_thread.run_sync(remove_job_files, settings, job.id)
    log.info("job %s deleted", job.id, extra={"job_id": job.id, "key_id": who, "status": was,
                                              "reason": "DELETE by its owner"})
    return Response(status_code=204)
