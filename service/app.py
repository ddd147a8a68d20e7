"""The FastAPI application: ``create_app(settings)``; OpenAPI at /docs.

Routes: POST/GET /reconstructions, GET/DELETE /reconstructions/{id}, POST .../cancel,
GET .../artifacts and GET/HEAD .../artifacts/{name}, GET/HEAD /healthz and /readyz, GET /methods (docs/service.md),
and /docs (Swagger UI served from the installed ``swagger-ui-py`` package, no CDN).
"""

from __future__ import annotations

import importlib.util
import logging
from contextlib import asynccontextmanager
from pathlib import Path

import sqlalchemy as sa
from fastapi import FastAPI, HTTPException, Request
from fastapi.exception_handlers import http_exception_handler, request_validation_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from jobs.settings import Settings, get_settings
from jobs.store import JobStore
from shsas_core.spec.job import spec_json_schema
from worker.reconciler import Reconciler

from .deps import RETRY_AFTER_S, unavailable
from .logs import AccessLogMiddleware
from .redact import redact_paths
from .routes import (
    artifacts,
    bundle,
    console,
    extracts,
    health,
    joblog,
    methods,
    presets,
    reconstructions,
    surveys,
)
from .sweeper import Sweeper
from .uploads import UploadError

log = logging.getLogger("shsas.api")

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
        detail = redact_paths(exc.message, [str(settings.data_dir.resolve())])
        _refused(request, exc.status, detail)
        headers = {"Retry-After": str(RETRY_AFTER_S)} if exc.status == 503 else None
        return JSONResponse({"detail": detail}, status_code=exc.status, headers=headers)

    # The job store down (stopped, restarting, failing over, unreachable, out of connections):
    # every route that needs it answers 503 with the documented JSON error and a Retry-After,
    # never a bare 500. What failed is logged here; the client is told only which dependency.
    @app.exception_handler(sa.exc.OperationalError)
    @app.exception_handler(sa.exc.InterfaceError)
    @app.exception_handler(sa.exc.TimeoutError)
    @app.exception_handler(sa.exc.DisconnectionError)
    async def _store_down(request: Request, exc: Exception) -> JSONResponse:
        log.warning("job store unavailable: %s %s: %s", request.method, request.url.path,
                    str(exc).splitlines()[0][:300], extra={"status": 503, "reason": type(exc).__name__})
        return unavailable("the job store is unavailable; retry later")

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

    app.include_router(reconstructions.router)
    app.include_router(artifacts.router)
    app.include_router(bundle.router)  # every artifact in one streamed zip
    app.include_router(joblog.router)  # the job's own log lines
    app.include_router(presets.router)  # presets and the cost estimate, before an upload
    app.include_router(health.router)
    app.include_router(methods.router)  # the method catalogue (the console's colours)
    # The console and the routes made for it (re-extraction, survey view), kept in their modules.
    app.include_router(extracts.router)
    app.include_router(surveys.router)
    console.add_console(app)
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
            spec = spec_json_schema(ref_template="#/components/schemas/{model}")
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            components.update(spec.pop("$defs", {}))
            components["ReconstructionSpec"] = spec
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _app_from_env() -> FastAPI:
    """``uvicorn --factory service.app:_app_from_env``: what each API process of
    ``shsas serve --workers N`` runs. Started by serve (``SERVE_PID_ENV`` names it), such a
    process ends with its parent (SIGKILL of serve included), so no API process outlives the
    serve that started it; started any other way it is left alone."""
    import os

    from worker.local import die_with_parent

    serve_pid = os.environ.get(SERVE_PID_ENV, "")
    if serve_pid.isdigit():  # also ends this process now if serve died while it was starting
        die_with_parent(int(serve_pid))
    return create_app()


#: Set by ``shsas serve`` to its pid for the API processes it starts.
SERVE_PID_ENV = "SHSAS_SERVE_PID"

