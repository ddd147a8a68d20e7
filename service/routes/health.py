"""Health routes: liveness (/healthz) and readiness (/readyz: the job store and the broker)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response

from worker.dispatch import broker_ping

from ..deps import RETRY_AFTER_S, SettingsDep, StoreDep
from ..models import Health

router = APIRouter()


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """Liveness: the process answers."""
    return Health(status="ok")


@router.head("/healthz")
def head_healthz() -> Response:
    """Liveness, headers only."""
    return Response(status_code=200)


@router.head("/readyz", responses={503: {"description": "not ready"}})
def head_readyz(store: StoreDep, settings: SettingsDep) -> Response:
    """Readiness, headers only: 200 or 503."""
    ready = readyz(store, settings)
    return Response(status_code=ready.status_code, headers={
        k: v for k, v in ready.headers.items() if k == "retry-after"})


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(store: StoreDep, settings: SettingsDep) -> Response:
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
    down = [{"job_store": "the job store", "broker": "the broker"}[k] for k, v in checks.items() if v.startswith("error")]
    body = Health(status="ok" if ok else "unavailable", checks=checks,
                  detail=None if ok else f"{' and '.join(down)} unavailable; retry later")
    return JSONResponse(body.model_dump(exclude_none=True), status_code=200 if ok else 503,
                        headers=None if ok else {"Retry-After": str(RETRY_AFTER_S)})
