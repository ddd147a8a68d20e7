"""Job routes: submit (POST /reconstructions), list, status, cancel and delete."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
import uuid
from contextlib import AsyncExitStack
from typing import Annotated

import anyio
import pydantic
from anyio import to_thread
from fastapi import APIRouter, Header, HTTPException, Query, Request
from fastapi.responses import JSONResponse, Response

from shsas_core.common.errors import pydantic_fix
from shsas_core.formats.registry import stored_name
from shsas_core.spec.job import ReconstructionSpec
from worker.dispatch import dispatch
from worker.runner import job_paths, remove_job_files
from worker.store import ORDERS, STATUSES, IdempotencyConflict, Job

from ..deps import ERRORS, Owner, SettingsDep, StoreDep, json_response
from ..job_names import job_label
from ..lookup import job_of
from ..models import ErrorOut, JobOut, JobPage
from ..quotas import box_of, check_cpu_time, check_spec_cost, hold_slot
from ..status import live_status
from ..survey_view import FOLDER as VIEW_FOLDER
from ..sweeper import upload_dir
from ..uploads import UploadError, receive_upload
from ..validation import ValidationsBusy, validate_in_child, validation_slot

log = logging.getLogger("shsas.api")
router = APIRouter()

#: Seconds a client is told to wait (Retry-After) when every validation slot stayed busy.
VALIDATIONS_BUSY_RETRY_S = 10


def spec_error(exc: pydantic.ValidationError) -> str:
    """One line per problem, each naming the spec field and a fix: ``spec.grid: ... (got 9999) (fix: ...)``."""
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in err["loc"])
        got = f" (got {err['input']!r})" if "input" in err and err["type"] != "json_invalid" else ""
        fix = pydantic_fix(err, list(ReconstructionSpec.model_fields), "the ReconstructionSpec, shsas_core/spec/job.py")
        parts.append(f"spec{'.' + loc if loc else ''}: {err['msg']}{got}"[:300] + f" (fix: {fix})")
    return "; ".join(parts)


@router.post("/reconstructions", status_code=202, response_model=JobOut,
          responses={**ERRORS, 409: {"model": ErrorOut}, 413: {"model": ErrorOut},
                     415: {"model": ErrorOut}, 422: {"model": ErrorOut}, 429: {"model": ErrorOut},
                     503: {"model": ErrorOut}},
          openapi_extra={"requestBody": {"required": True, "content": {"multipart/form-data": {
              "schema": {
                  "type": "object", "required": ["survey"], "additionalProperties": False, "properties": {
                      "survey": {"type": "string", "format": "binary",
                                 "description": "canonical shsas HDF5, or any format `shsas convert` reads: "
                                                "a zip of an AirSAS scan, deconvolved-ping or SVSS track "
                                                "folder, or an AirSAS pickle"},
                      "spec": {"$ref": "#/components/schemas/ReconstructionSpec",
                               "description": "the ReconstructionSpec as JSON (defaults if absent)"},
                  }},
              "encoding": {"spec": {"contentType": "application/json"}}}}}})
async def submit(request: Request, who: Owner, store: StoreDep, settings: SettingsDep,
                 idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> Response:
    """Upload a survey and a spec; answers 202 with the queued job and its Location.

    Refused with 429 past the key's quota of queued and running jobs, and with 422 when the
    spec is over the cost cap (docs/service.md, "Limits")."""
    async with AsyncExitStack() as held:  # the key's quota slot, reserved until the job row exists
        return await _submit(request, who, store, settings, idempotency_key, held)


async def _submit(request: Request, who: str, store: StoreDep, settings: SettingsDep,
                  idempotency_key: str | None, held: AsyncExitStack) -> Response:
    with upload_dir(settings.data_dir / "uploads") as tmp_dir:
        # "label" (optional): the operator's name for the job, shown in lists and searched
        up = await receive_upload(request, tmp_dir / "upload.part", settings.max_upload_bytes,
                                  text_fields=("spec", "label"))
        if up.path is None:
            raise UploadError(422, "survey: missing file part 'survey' (fix: send the survey file as "
                                   "the multipart field 'survey', e.g. curl -F survey=@scan.h5)")
        if up.size == 0:
            raise UploadError(422, f"survey '{up.display_name}': the uploaded file is empty "
                                   "(fix: check the path given to the upload)")
        label = job_label(up.fields.get("label"))
        if "spec" not in up.fields and not settings.allow_default_spec:
            raise UploadError(422, "spec: missing form field 'spec' (fix: send the ReconstructionSpec as JSON "
                                   "in the multipart field 'spec', e.g. -F 'spec={\"methods\":[\"backprojection\"]}'; "
                                   "-F 'spec={}' runs every default; the operator can accept a missing spec "
                                   "with SHSAS_ALLOW_DEFAULT_SPEC=1)")
        spec_text = up.fields.get("spec", "").strip() or "{}"
        try:
            spec = ReconstructionSpec.model_validate_json(spec_text)
        except pydantic.ValidationError as exc:
            raise UploadError(422, spec_error(exc)) from None
        check_spec_cost(spec, settings)
        check_cpu_time(spec, settings)
        spec_json = spec.model_dump(mode="json")
        request_digest = hashlib.sha256(
            (json.dumps(spec_json, sort_keys=True) + up.sha256).encode()).hexdigest()
        if idempotency_key is not None:
            prior = await to_thread.run_sync(store.find_by_idempotency_key, who, idempotency_key)
            if prior is not None:
                if prior.request_digest != request_digest:
                    raise UploadError(409, f"Idempotency-Key already used for job {prior.id} "
                                           "with a different survey or spec")
                return _accepted(prior, request)
        await hold_slot(held, store, who, settings)
        upload_path = up.path
        try:
            async with validation_slot(settings.data_dir / "validation-slots", settings.max_concurrent_validations,
                                       settings.validate_wait_s):
                checked = await to_thread.run_sync(lambda: validate_in_child(
                    upload_path, settings.validate_memory_bytes, settings.validate_timeout_s,
                    display_name=up.display_name, spec=spec_json, worker_memory_bytes=settings.worker_memory_bytes,
                    max_ground_truth_elements=settings.max_ground_truth_elements,
                    max_extras_bytes=settings.max_extras_bytes))
        except ValidationsBusy:
            raise HTTPException(503, f"survey: all {settings.max_concurrent_validations} validation slots stayed "
                                     f"busy for {settings.validate_wait_s:g} s (SHSAS_MAX_CONCURRENT_VALIDATIONS); "
                                     "nothing was queued (fix: resubmit after Retry-After seconds)",
                                headers={"Retry-After": str(VALIDATIONS_BUSY_RETRY_S)}) from None
        check_spec_cost(spec, settings, box_of(checked.summary))  # the automatic grid, now known
        check_cpu_time(spec, settings, checked.summary)
        job_id = uuid.uuid4().hex
        in_dir, _ = job_paths(settings, job_id)
        in_dir.mkdir(parents=True)
        # the format registry names the stored input: a canonical upload as it came, any other
        # format as the canonical file its validation converted it to
        input_name = stored_name(checked.format)
        checked.input_path.replace(in_dir / input_name)
        checked.view_dir.replace(in_dir.parent / VIEW_FOLDER)
        try:
            job, created = await to_thread.run_sync(lambda: store.create_job(
                owner=who, spec=spec_json, input_digest=up.sha256, input_name=input_name,
                input_bytes=up.size, queue=settings.queue_for(spec.device), job_id=job_id,
                idempotency_key=idempotency_key, request_digest=request_digest,
                client_name=up.filename, label=label))
        except IdempotencyConflict as exc:
            shutil.rmtree(in_dir.parent, ignore_errors=True)
            raise UploadError(409, str(exc)) from None
        if not created:  # a concurrent request with the same key won
            shutil.rmtree(in_dir.parent, ignore_errors=True)
            return _accepted(job, request)
        try:
            await to_thread.run_sync(dispatch, settings, job)
        except Exception as exc:
            log.exception("could not send job %s to the broker", job.id,
                          extra={"job_id": job.id, "key_id": who, "reason": type(exc).__name__})
            msg = f"the broker is unreachable ({type(exc).__name__}); nothing was queued, resubmit later"
            await to_thread.run_sync(store.fail_queued, job.id, msg)
            shutil.rmtree(in_dir.parent, ignore_errors=True)
            raise UploadError(503, msg) from None
        log.info("job %s submitted", job.id, extra={
            "job_id": job.id, "key_id": who, "queue": job.queue, "methods": spec.methods,
            "grid": spec.grid, "iters": spec.iters, "input_bytes": up.size, "format": checked.format,
            "client_filename": up.display_name})
        return _accepted(job, request)


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
async def get_job(job_id: str, who: Owner, store: StoreDep, settings: SettingsDep) -> Response:
    """Status, progress, stage, attempts, timestamps, error, metrics and artifact links; for a
    queued job its queue position and ETA, for a running one its ETA and heartbeat age."""
    # Inline like current_owner: this is the route pollers hit, one indexed read (a queued
    # job adds one count; the queue's measured rate is cached for a few seconds).
    job = job_of(store, job_id, who)
    return json_response(JobOut.from_job(job, live=live_status(store, settings, job)))


@router.head("/reconstructions/{job_id}", responses=ERRORS)
async def head_job(job_id: str, who: Owner, store: StoreDep, settings: SettingsDep) -> Response:
    """The headers ``GET /reconstructions/{id}`` would send (status, length, type), no body."""
    full = await get_job(job_id, who, store, settings)
    return Response(status_code=full.status_code, media_type=full.media_type,
                    headers={"content-length": str(len(full.body))})


@router.post("/reconstructions/{job_id}/cancel", response_model=JobOut, status_code=202, responses=ERRORS)
def cancel_job(job_id: str, who: Owner, store: StoreDep) -> JobOut:
    """Ask a job to stop. Queued jobs end at once; running ones at their next step."""
    job_of(store, job_id, who)
    job = store.request_cancel(job_id, who)
    assert job is not None
    log.info("job %s: cancel requested", job_id, extra={"job_id": job_id, "key_id": who,
                                                       "status": job.status})
    return JobOut.from_job(job)


@router.delete("/reconstructions/{job_id}", status_code=204, responses={
    **ERRORS, 204: {"description": "deleted: the job and its files are gone"}})
async def delete_job(job_id: str, who: Owner, store: StoreDep, settings: SettingsDep) -> Response:
    """Delete a job and its files (the survey and every artifact). A queued job is cancelled; a
    running one is cancelled first and deleted once it stopped (or after SHSAS_DELETE_WAIT_S;
    its worker then removes what it still writes). Only the key that submitted it can."""
    job = job_of(store, job_id, who)
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
