"""The FastAPI application: ``create_app(settings)``; OpenAPI at /docs.

Routes: POST/GET /reconstructions, GET /reconstructions/{id}, POST .../cancel,
GET .../artifacts and .../artifacts/{name}, /healthz, /readyz (design §6).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import shutil
import time
import uuid
from contextlib import asynccontextmanager
from typing import Annotated

import pydantic
from anyio import to_thread
from fastapi import Depends, FastAPI, Header, HTTPException, Query, Request
from fastapi.responses import JSONResponse, Response

from shsas_core.errors import pydantic_fix
from shsas_core.spec import ReconstructionSpec
from worker.dispatch import broker_ping, dispatch
from worker.reconciler import Reconciler
from worker.runner import job_paths
from worker.settings import Settings, get_settings
from worker.store import STATUSES, IdempotencyConflict, JobStore

from .artifacts import etag_of, file_response, media_type, safe_artifact_path
from .auth import owner_of
from .models import Artifact, ArtifactList, ErrorOut, Health, JobOut, JobPage
from .uploads import UploadError, receive_upload
from .validation import validate_in_child

log = logging.getLogger("shsas.api")

#: Stored input names by detected format; the pipeline detects the format from the contents.
INPUT_NAMES = {"shsas": "survey.h5", "svss": "survey.hdf5", "airsas-csv": "survey.zip",
               "airsas-pickle": "survey.pkl"}
ERRORS = {400: {"model": ErrorOut}, 401: {"model": ErrorOut}, 404: {"model": ErrorOut}}


def spec_error(exc: pydantic.ValidationError) -> str:
    """One line per problem, each naming the spec field and a fix: ``spec.grid: ... (got 9999) (fix: ...)``."""
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in err["loc"])
        got = f" (got {err['input']!r})" if "input" in err and err["type"] != "json_invalid" else ""
        fix = pydantic_fix(err, list(ReconstructionSpec.model_fields), "the ReconstructionSpec, shsas_core/spec.py")
        parts.append(f"spec{'.' + loc if loc else ''}: {err['msg']}{got}"[:300] + f" (fix: {fix})")
    return "; ".join(parts)


async def current_owner(request: Request) -> str:
    """Dependency: the job owner (API key id, or ``local`` for keyless loopback clients).

    Runs on the event loop: it is one indexed read (< 1 ms), and a thread hop per request
    costs more than the query under 100 pollers.
    """
    return owner_of(request, request.app.state.store)


def _json(model: pydantic.BaseModel, status: int = 200) -> Response:
    # Serialised once here; returning a Response skips FastAPI's second validation pass.
    return Response(model.model_dump_json(), status_code=status, media_type="application/json")


Owner = Annotated[str, Depends(current_owner)]


#: Upload folders older than this are leftovers of a crashed API process (other replicas
#: sharing the data dir may have younger ones in flight).
STALE_UPLOAD_S = 24 * 3600


def _sweep_uploads(root) -> None:
    if not root.is_dir():
        return
    cutoff = time.time() - STALE_UPLOAD_S
    for d in root.iterdir():
        with contextlib.suppress(OSError):
            if d.stat().st_mtime < cutoff:
                shutil.rmtree(d, ignore_errors=True)


def create_app(settings: Settings | None = None, *, reconcile: bool = True) -> FastAPI:
    """Build the app. ``reconcile`` runs the stale-lease reconciler thread in this process."""
    settings = settings or get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = JobStore.from_settings(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        _sweep_uploads(settings.data_dir / "uploads")
        rec = Reconciler(store, settings).start() if reconcile else None
        yield
        if rec:
            rec.stop()
        store.dispose()

    app = FastAPI(
        title="shsas", version="0.1.0", lifespan=lifespan,
        description="3D reconstruction from synthetic aperture sonar surveys (SH-SAS). Upload a survey "
                    "with a ReconstructionSpec, poll the job, download meshes, point clouds, volumes and "
                    "reports. Auth: `Authorization: Bearer <key>` (see `shsas keys create`).")
    app.state.settings = settings
    app.state.store = store

    @app.exception_handler(UploadError)
    async def _upload_error(request: Request, exc: UploadError) -> JSONResponse:
        return JSONResponse({"detail": exc.message}, status_code=exc.status)

    def job_or_404(job_id: str, who: str):
        job = store.get(job_id, who) if len(job_id) <= 32 and job_id.isalnum() else None
        if job is None:
            raise HTTPException(404, f"no reconstruction {job_id!r} for this API key")
        return job

    @app.post("/reconstructions", status_code=202, response_model=JobOut,
              responses={**ERRORS, 409: {"model": ErrorOut}, 413: {"model": ErrorOut},
                         415: {"model": ErrorOut}, 422: {"model": ErrorOut}, 503: {"model": ErrorOut}},
              openapi_extra={"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
                  "type": "object", "required": ["survey"], "additionalProperties": False, "properties": {
                      "survey": {"type": "string", "format": "binary",
                                 "description": "canonical shsas HDF5, AirSAS zip or SVSS HDF5"},
                      "spec": {"type": "string", "description": "ReconstructionSpec as JSON (defaults if absent)"},
                  }}}}}})
    async def submit(request: Request, who: Owner,
                     idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> Response:
        """Upload a survey and a spec; answers 202 with the queued job and its Location."""
        tmp_dir = settings.data_dir / "uploads" / uuid.uuid4().hex
        tmp_dir.mkdir(parents=True)
        try:
            up = await receive_upload(request, tmp_dir / "upload.part", settings.max_upload_bytes)
            if up.path is None:
                raise UploadError(422, "survey: missing file part 'survey' (fix: send the survey file as "
                                       "the multipart field 'survey', e.g. curl -F survey=@scan.h5)")
            if up.size == 0:
                raise UploadError(422, f"survey '{up.display_name}': the uploaded file is empty "
                                       "(fix: check the path given to the upload)")
            spec_text = up.fields.get("spec", "").strip() or "{}"
            try:
                spec = ReconstructionSpec.model_validate_json(spec_text)
            except pydantic.ValidationError as exc:
                raise UploadError(422, spec_error(exc)) from None
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
            upload_path = up.path
            checked = await to_thread.run_sync(lambda: validate_in_child(
                upload_path, settings.validate_memory_bytes, settings.validate_timeout_s,
                display_name=up.display_name, spec=spec_json, worker_memory_bytes=settings.worker_memory_bytes))
            job_id = uuid.uuid4().hex
            in_dir, _ = job_paths(settings, job_id)
            in_dir.mkdir(parents=True)
            input_name = INPUT_NAMES.get(checked["format"], "survey.bin")
            up.path.replace(in_dir / input_name)
            try:
                job, created = await to_thread.run_sync(lambda: store.create_job(
                    owner=who, spec=spec_json, input_digest=up.sha256, input_name=input_name,
                    input_bytes=up.size, queue=settings.queue_for(spec.device), job_id=job_id,
                    idempotency_key=idempotency_key, request_digest=request_digest))
            except IdempotencyConflict as exc:
                shutil.rmtree(in_dir.parent, ignore_errors=True)
                raise UploadError(409, str(exc)) from None
            if not created:  # a concurrent request with the same key won
                shutil.rmtree(in_dir.parent, ignore_errors=True)
                return _accepted(job, request)
            try:
                await to_thread.run_sync(dispatch, settings, job)
            except Exception as exc:
                log.exception("could not send job %s to the broker", job.id)
                msg = f"the broker is unreachable ({type(exc).__name__}); nothing was queued, resubmit later"
                await to_thread.run_sync(store.fail_queued, job.id, msg)
                shutil.rmtree(in_dir.parent, ignore_errors=True)
                raise UploadError(503, msg) from None
            return _accepted(job, request)
        finally:
            shutil.rmtree(tmp_dir, ignore_errors=True)

    def _accepted(job, request: Request) -> JSONResponse:
        body = JobOut.from_job(job).model_dump(mode="json")
        return JSONResponse(body, status_code=202, headers={"Location": f"/reconstructions/{job.id}"})

    @app.get("/reconstructions", response_model=JobPage, responses=ERRORS)
    async def list_jobs(who: Owner, status: Annotated[str | None, Query(description="filter: " + ", ".join(STATUSES))] = None,
                  cursor: str | None = None, limit: Annotated[int, Query(ge=1, le=1000)] = 50) -> Response:
        """The caller's jobs, newest first, one page at a time."""
        if status is not None and status not in STATUSES:
            raise HTTPException(400, f"status: unknown status {status!r} (one of {', '.join(STATUSES)})")
        try:
            items, nxt = store.list_jobs(who, status=status, cursor=cursor,
                                         limit=min(limit, settings.page_size_max))
        except ValueError:
            raise HTTPException(400, "cursor: not a cursor this API returned") from None
        return _json(JobPage(items=[JobOut.from_job(j) for j in items], next_cursor=nxt))

    @app.get("/reconstructions/{job_id}", response_model=JobOut, responses=ERRORS)
    async def get_job(job_id: str, who: Owner) -> Response:
        """Status, progress, stage, attempts, timestamps, error, metrics and artifact links."""
        # Inline like current_owner: this is the route pollers hit, one indexed read.
        return _json(JobOut.from_job(job_or_404(job_id, who)))

    @app.post("/reconstructions/{job_id}/cancel", response_model=JobOut, status_code=202, responses=ERRORS)
    def cancel_job(job_id: str, who: Owner) -> JobOut:
        """Ask a job to stop. Queued jobs end at once; running ones at their next step."""
        job_or_404(job_id, who)
        job = store.request_cancel(job_id, who)
        assert job is not None
        return JobOut.from_job(job)

    @app.get("/reconstructions/{job_id}/artifacts", response_model=ArtifactList, responses=ERRORS)
    def list_artifacts(job_id: str, who: Owner) -> ArtifactList:
        """The job's output files (empty until it succeeds)."""
        job = job_or_404(job_id, who)
        _, out_dir = job_paths(settings, job.id)
        items = []
        for name in job.artifacts:
            p = safe_artifact_path(out_dir, name, job.artifacts)
            if p is not None:
                items.append(Artifact(name=name, url=f"/reconstructions/{job.id}/artifacts/{name}",
                                      size=p.stat().st_size, media_type=media_type(name), etag=etag_of(p)))
        return ArtifactList(job_id=job.id, status=job.status, items=items)  # type: ignore[arg-type]

    @app.get("/reconstructions/{job_id}/artifacts/{name}", responses={
        **ERRORS, 206: {"description": "partial content"}, 304: {"description": "not modified"},
        416: {"description": "range not satisfiable"},
        200: {"content": {"application/octet-stream": {}, "model/gltf-binary": {}, "application/json": {},
                          "text/html": {}}}})
    def get_artifact(
        job_id: str, name: str, who: Owner, request: Request,
        # Declared so that the OpenAPI schema documents them (and fuzzers send them); the
        # values are read from request.headers by file_response.
        range_: Annotated[str | None, Header(alias="Range", description="one byte range: bytes=a-b, bytes=a- or "
                                                         "bytes=-n (206; 416 when unsatisfiable)")] = None,
        if_range: Annotated[str | None, Header(description="an ETag: Range applies only if it matches")] = None,
        if_none_match: Annotated[str | None, Header(description="ETags: 304 if one matches")] = None,
    ) -> Response:
        """Download one artifact; supports Range and ETag/If-None-Match."""
        job = job_or_404(job_id, who)
        _, out_dir = job_paths(settings, job.id)
        p = safe_artifact_path(out_dir, name, job.artifacts)
        if p is None:
            raise HTTPException(404, f"no artifact {name!r} in reconstruction {job.id} "
                                     f"(available: {', '.join(job.artifacts) or 'none yet'})")
        return file_response(p, request.headers, name)

    @app.get("/healthz", response_model=Health)
    def healthz() -> Health:
        """Liveness: the process answers."""
        return Health(status="ok")

    @app.get("/readyz", response_model=Health, responses={503: {"model": Health}})
    def readyz() -> Response:
        """Readiness: the job store and the broker (if any) answer."""
        checks, ok = {}, True
        try:
            store.ping()
            checks["job_store"] = "ok"
        except Exception as exc:
            ok, checks["job_store"] = False, f"error: {type(exc).__name__}"
        if settings.embedded:
            checks["broker"] = "embedded (job table)"
        else:
            try:
                broker_ping(settings)
                checks["broker"] = "ok"
            except Exception as exc:
                ok, checks["broker"] = False, f"error: {type(exc).__name__}"
        body = Health(status="ok" if ok else "unavailable", checks=checks)
        return JSONResponse(body.model_dump(), status_code=200 if ok else 503)

    return app


def _app_from_env() -> FastAPI:
    """``uvicorn --factory service.app:_app_from_env`` (what ``shsas serve`` runs)."""
    return create_app()

