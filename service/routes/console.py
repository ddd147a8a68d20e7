"""The operator console: one static page at ``/`` (built from ``web/`` by ``make console``) and
the spec's JSON schema it builds its form from (``GET /schemas/reconstruction-spec``).

The page uses only the public API. Its assets are served from ``/console/``; a checkout whose
page was not built answers ``/`` with 503 and the command that builds it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from shsas_core.spec.job import spec_json_schema

#: Where `make console` writes the built page (package data in ``service/console/``; git-ignored).
STATIC = Path(__file__).resolve().parent.parent / "console" / "static"
#: The page loads nothing from elsewhere; this makes the browser refuse it if it ever tried.
CSP = ("default-src 'self'; img-src 'self' blob: data:; style-src 'self' 'unsafe-inline'; "
       "script-src 'self'; connect-src 'self'; frame-src blob:; object-src 'none'; base-uri 'none'")

router = APIRouter()


@router.get("/schemas/reconstruction-spec", tags=["specs"])
def reconstruction_spec_schema() -> dict[str, Any]:
    """The JSON schema of the `spec` form field of POST /reconstructions, defaults filled in."""
    return spec_json_schema()


@router.get("/", include_in_schema=False)
def console_page() -> FileResponse:
    index = STATIC / "index.html"
    if not index.is_file():
        raise HTTPException(503, "the console page is not built in this install (run `make console`)")
    return FileResponse(index, headers={"Content-Security-Policy": CSP, "Cache-Control": "no-cache"})


def add_console(app: FastAPI) -> None:
    """Serve the console and its schema route on ``app``."""
    app.include_router(router)
    # check_dir=False: an unbuilt checkout still starts; its /console/* answers 404.
    app.mount("/console", StaticFiles(directory=STATIC, check_dir=False), name="console")
