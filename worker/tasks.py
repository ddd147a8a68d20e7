"""Celery tasks. The task body runs in the pool child, which is where torch/CUDA get used."""

from __future__ import annotations

import logging

from celery.signals import worker_process_init

from jobs.settings import get_settings
from jobs.store import JobStore

from .app import app
from .celery_app import TASK_NAME
from .runner import execute_job

log = logging.getLogger("shsas.worker")

_store: JobStore | None = None


def _get_store() -> JobStore:
    # Created lazily in the child: a connection pool must never cross a fork.
    global _store
    if _store is None:
        _store = JobStore.from_settings(get_settings())
    return _store


@worker_process_init.connect
def _pool_child_start(**_) -> None:
    """In each pool child, before it runs a task: the service log format, a lower CPU priority
    than the API and thread pools sized to the CPUs it owns (the child is where the job's
    threads run)."""
    from shsas_core.common.threads import size_thread_pools

    from .logs import configure_logging
    from .priority import lower_priority

    settings = get_settings()
    configure_logging(settings.log_format, logging.getLogger("shsas").level or "info")
    lower_priority(settings.worker_nice)
    size_thread_pools(settings.worker_threads)


@app.task(name=TASK_NAME, acks_late=True, reject_on_worker_lost=True, ignore_result=True)
def run_job(job_id: str) -> str:
    """Run one job by id. Duplicate or stale deliveries are harmless: the claim fails."""
    status = execute_job(_get_store(), get_settings(), job_id)
    log.info("job %s: %s", job_id, status, extra={"job_id": job_id, "status": status})
    return status
