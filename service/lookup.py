"""The caller's job by id, for routers outside the app factory (same rules as app.py's routes:
ids are server-made hex, another key's job is a 404)."""

from __future__ import annotations

from fastapi import HTTPException, Request

from jobs.store import Job, JobStore

from .auth import owner_of


def job_of(store: JobStore, job_id: str, who: str) -> Job:
    """The job ``job_id`` owned by ``who``, or HTTPException 404 (also for a malformed id)."""
    job = store.get(job_id, who) if len(job_id) <= 32 and job_id.isalnum() else None
    if job is None:
        raise HTTPException(404, f"no reconstruction {job_id!r} for this API key")
    return job


def caller_job(request: Request, job_id: str) -> Job:
    """The job ``job_id`` of the caller's key, or HTTPException 401/404."""
    store = request.app.state.store
    return job_of(store, job_id, owner_of(request, store))


def succeeded_job(request: Request, job_id: str) -> Job:
    """As :func:`caller_job`, and 409 unless the job succeeded (its outputs exist only then)."""
    job = caller_job(request, job_id)
    if job.status != "succeeded":
        raise HTTPException(409, f"reconstruction {job_id} is {job.status}; this needs a succeeded job")
    return job
