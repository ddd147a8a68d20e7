"""Celery tasks. The task body runs in the pool child, which is where torch/CUDA get used."""

from __future__ import annotations

import logging

from .app import app
from .celery_app import TASK_NAME
from .runner import execute_job
from .settings import get_settings
from .store import JobStore

log = logging.getLogger("shsas.worker")

_store: JobStore | None = None


def _get_store() -> JobStore:
    # Created lazily in the child: a connection pool must never cross a fork.
    global _store
    if _store is None:
        _store = JobStore.from_settings(get_settings())
    return _store


@app.task(name=TASK_NAME, acks_late=True, reject_on_worker_lost=True, ignore_result=True)
def run_job(job_id: str) -> str:
    """Run one job by id. Duplicate or stale deliveries are harmless: the claim fails."""
    status = execute_job(_get_store(), get_settings(), job_id)
    log.info("job %s: %s", job_id, status)
    return status
