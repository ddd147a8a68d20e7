"""The FastAPI application: ``create_app(settings)``; OpenAPI at /docs.

Routes: POST/GET /reconstructions, GET/DELETE /reconstructions/{id}, POST .../cancel,
GET .../artifacts and GET/HEAD .../artifacts/{name}, GET/HEAD /healthz and /readyz (docs/service.md),
and /docs (Swagger UI served from the installed ``swagger-ui-py`` package, no CDN).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import shutil
import time
import uuid
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

import anyio
import pydantic
from anyio import to_thread
from fastapi import Depends, FastAPI, Header, HTTPException, Query, Request
from fastapi.exception_handlers import http_exception_handler, request_validation_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from shsas_core.errors import pydantic_fix
from shsas_core.spec import ReconstructionSpec
from worker.dispatch import broker_ping, dispatch
from worker.reconciler import Reconciler
from worker.runner import job_paths, remove_job_files
from worker.settings import Settings, get_settings
from worker.store import STATUSES, IdempotencyConflict, JobStore

from . import iso, survey_routes
from .artifacts import etag_of, file_response, media_type, safe_artifact_path
from .auth import owner_of
from .console import add_console
from .logs import AccessLogMiddleware
from .lookup import job_of
from .models import Artifact, ArtifactList, ErrorOut, Health, JobOut, JobPage
from .quotas import box_of, check_active_jobs, check_spec_cost
from .status import live_status
from .sweeper import Sweeper, upload_dir
from .uploads import UploadError, receive_upload
from .validation import validate_in_child

log = logging.getLogger("shsas.api")

#: Stored input names by detected format; the pipeline detects the format from the contents.
INPUT_NAMES = {"shsas": "survey.h5", "svss": "survey.hdf5", "airsas-csv": "survey.zip",
               "airsas-pickle": "survey.pkl"}
ERRORS = {400: {"model": ErrorOut}, 401: {"model": ErrorOut}, 404: {"model": ErrorOut}}
#: Where /docs loads Swagger UI from: the static files of the installed swagger-ui-py package.
DOCS_ASSETS = "/docs-assets"


def swagger_ui_dir() -> Path | None:
    """The folder of Swagger UI's built files in the installed ``swagger-ui-py`` package (found
    without importing it: its __init__ pulls in web-framework handlers), or None."""
    found = importlib.util.find_spec("swagger_ui")
    if found is None or not found.submodule_search_locations:
        return None
    static = Path(next(iter(found.submodule_search_locations))) / "static"
    return static if (static / "swagger-ui-bundle.js").is_file() else None


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



def create_app(settings: Settings | None = None, *, reconcile: bool = True) -> FastAPI:
    """Build the app. ``reconcile`` runs the stale-lease reconciler thread in this process."""
    settings = settings or get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = JobStore.from_settings(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        sweeper = Sweeper(store, settings)
        sweeper.sweep_once()  # before the first request: whatever a killed process left
        sweeper.start()
        rec = Reconciler(store, settings).start() if reconcile else None
        yield
        if rec:
            rec.stop()
        sweeper.stop()
        store.dispose()

    app = FastAPI(
        title="shsas", version="0.1.0", lifespan=lifespan, docs_url=None, redoc_url=None,
        description="3D reconstruction from synthetic aperture sonar surveys (SH-SAS). Upload a survey "
                    "with a ReconstructionSpec, poll the job, download meshes, point clouds, volumes and "
                    "reports. Auth: `Authorization: Bearer <key>` (see `shsas keys create`).")
    app.state.settings = settings
    app.state.store = store
    app.add_middleware(AccessLogMiddleware)
    _offline_docs(app)

    def _refused(request: Request, status: int, reason: str) -> None:
        log.warning("submission refused (%d): %s", status, reason,
                    extra={"status": status, "reason": reason, "key_id": getattr(request.state, "key_id", None)})

    @app.exception_handler(UploadError)
    async def _upload_error(request: Request, exc: UploadError) -> JSONResponse:
        _refused(request, exc.status, exc.message)
        return JSONResponse({"detail": exc.message}, status_code=exc.status)

    # Submissions refused before the handler runs (no or a bad key, a bad header) are logged
    # with their reason too; other routes' 4xx are in the access log.
    @app.exception_handler(HTTPException)
    async def _http_error(request: Request, exc: HTTPException) -> Response:
        if request.method == "POST" and request.url.path == "/reconstructions":
            _refused(request, exc.status_code, str(exc.detail))
        return await http_exception_handler(request, exc)

    @app.exception_handler(RequestValidationError)
    async def _invalid_request(request: Request, exc: RequestValidationError) -> Response:
        if request.method == "POST" and request.url.path == "/reconstructions":
            _refused(request, 422, "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors()[:3]))
        return await request_validation_exception_handler(request, exc)

    def job_or_404(job_id: str, who: str):
        return job_of(store, job_id, who)

    @app.post("/reconstructions", status_code=202, response_model=JobOut,
              responses={**ERRORS, 409: {"model": ErrorOut}, 413: {"model": ErrorOut},
                         415: {"model": ErrorOut}, 422: {"model": ErrorOut}, 429: {"model": ErrorOut},
                         503: {"model": ErrorOut}},
              openapi_extra={"requestBody": {"required": True, "content": {"multipart/form-data": {
                  "schema": {
                      "type": "object", "required": ["survey"], "additionalProperties": False, "properties": {
                          "survey": {"type": "string", "format": "binary",
                                     "description": "canonical shsas HDF5, AirSAS zip or SVSS HDF5"},
                          "spec": {"$ref": "#/components/schemas/ReconstructionSpec",
                                   "description": "the ReconstructionSpec as JSON (defaults if absent)"},
                      }},
                  "encoding": {"spec": {"contentType": "application/json"}}}}}})
    async def submit(request: Request, who: Owner,
                     idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> Response:
        """Upload a survey and a spec; answers 202 with the queued job and its Location.

        Refused with 429 past the key's quota of queued and running jobs, and with 422 when the
        spec is over the cost cap (docs/service.md, "Limits")."""
        with upload_dir(settings.data_dir / "uploads") as tmp_dir:
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
            check_spec_cost(spec, settings)
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
            check_active_jobs(await to_thread.run_sync(store.count_active, who), settings)
            upload_path = up.path
            checked = await to_thread.run_sync(lambda: validate_in_child(
                upload_path, settings.validate_memory_bytes, settings.validate_timeout_s,
                display_name=up.display_name, spec=spec_json, worker_memory_bytes=settings.worker_memory_bytes))
            check_spec_cost(spec, settings, box_of(checked["summary"]))  # the automatic grid, now known
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
                log.exception("could not send job %s to the broker", job.id,
                              extra={"job_id": job.id, "key_id": who, "reason": type(exc).__name__})
                msg = f"the broker is unreachable ({type(exc).__name__}); nothing was queued, resubmit later"
                await to_thread.run_sync(store.fail_queued, job.id, msg)
                shutil.rmtree(in_dir.parent, ignore_errors=True)
                raise UploadError(503, msg) from None
            log.info("job %s submitted", job.id, extra={
                "job_id": job.id, "key_id": who, "queue": job.queue, "methods": spec.methods,
                "grid": spec.grid, "iters": spec.iters, "input_bytes": up.size, "format": checked["format"],
                "client_filename": up.display_name})
            return _accepted(job, request)

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
        """Status, progress, stage, attempts, timestamps, error, metrics and artifact links; for a
        queued job its queue position and ETA, for a running one its ETA and heartbeat age."""
        # Inline like current_owner: this is the route pollers hit, one indexed read (a queued
        # job adds one count; the queue's measured rate is cached for a few seconds).
        job = job_or_404(job_id, who)
        return _json(JobOut.from_job(job, live=live_status(store, settings, job)))

    @app.post("/reconstructions/{job_id}/cancel", response_model=JobOut, status_code=202, responses=ERRORS)
    def cancel_job(job_id: str, who: Owner) -> JobOut:
        """Ask a job to stop. Queued jobs end at once; running ones at their next step."""
        job_or_404(job_id, who)
        job = store.request_cancel(job_id, who)
        assert job is not None
        log.info("job %s: cancel requested", job_id, extra={"job_id": job_id, "key_id": who,
                                                           "status": job.status})
        return JobOut.from_job(job)

    @app.delete("/reconstructions/{job_id}", status_code=204, responses={
        **ERRORS, 204: {"description": "deleted: the job and its files are gone"}})
    async def delete_job(job_id: str, who: Owner) -> Response:
        """Delete a job and its files (the survey and every artifact). A queued job is cancelled; a
        running one is cancelled first and deleted once it stopped (or after SHSAS_DELETE_WAIT_S;
        its worker then removes what it still writes). Only the key that submitted it can."""
        job = job_or_404(job_id, who)
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
        return file_response(p, request.headers, name, head=request.method == "HEAD")

    @app.head("/reconstructions/{job_id}/artifacts/{name}", responses={
        **ERRORS, 304: {"description": "not modified"}, 416: {"description": "range not satisfiable"},
        200: {"description": "the headers of the download (Content-Length, ETag, ...), no body"}})
    def head_artifact(job_id: str, name: str, who: Owner, request: Request,
                      range_: Annotated[str | None, Header(alias="Range")] = None,
                      if_range: Annotated[str | None, Header()] = None,
                      if_none_match: Annotated[str | None, Header()] = None) -> Response:
        """The headers GET would send (size, type, ETag, Content-Range), without the body."""
        return get_artifact(job_id, name, who, request)

    @app.get("/healthz", response_model=Health)
    def healthz() -> Health:
        """Liveness: the process answers."""
        return Health(status="ok")

    @app.head("/healthz")
    def head_healthz() -> Response:
        """Liveness, headers only."""
        return Response(status_code=200)

    @app.head("/readyz", responses={503: {"description": "not ready"}})
    def head_readyz() -> Response:
        """Readiness, headers only: 200 or 503."""
        return Response(status_code=readyz().status_code)

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

    # The console and the routes made for it (re-extraction, survey view), kept in their modules.
    app.include_router(iso.router)
    app.include_router(survey_routes.router)
    add_console(app)
    return app


def _offline_docs(app: FastAPI) -> None:
    """/docs from local files, and the spec's JSON schema in the OpenAPI document.

    The Swagger UI page FastAPI makes loads its script and style from a CDN, so the page is
    blank without internet; here they come from the installed ``swagger-ui-py`` package.
    """
    assets = swagger_ui_dir()
    if assets is not None:
        app.mount(DOCS_ASSETS, StaticFiles(directory=assets), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        if assets is None:
            return HTMLResponse("Swagger UI is not installed (pip install swagger-ui-py); the OpenAPI "
                                "schema is at <a href='/openapi.json'>/openapi.json</a>", status_code=503)
        return get_swagger_ui_html(openapi_url=app.openapi_url or "/openapi.json", title="shsas API",
                                   swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
                                   swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
                                   swagger_favicon_url=f"{DOCS_ASSETS}/favicon-32x32.png")

    plain_openapi = app.openapi

    def openapi() -> dict:
        # The multipart `spec` field refers to ReconstructionSpec, which no route returns, so
        # FastAPI does not put its schema in the components: add it (and its own $defs).
        if app.openapi_schema is None:
            schema = plain_openapi()
            spec = ReconstructionSpec.model_json_schema(ref_template="#/components/schemas/{model}")
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            components.update(spec.pop("$defs", {}))
            components["ReconstructionSpec"] = spec
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _app_from_env() -> FastAPI:
    """``uvicorn --factory service.app:_app_from_env`` (what ``shsas serve`` runs)."""
    return create_app()

