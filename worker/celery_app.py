"""The Celery application (``celery -A worker.app worker`` or ``shsas worker``).

Settings (docs/service.md): late acks and rejection on worker loss so a crashed worker's job is
delivered again, prefetch 1 and concurrency 1 (one process per GPU; CUDA is only touched in the
pool child that runs the task), a visibility timeout longer than the hard job limit, and
no result backend (the job table is the source of truth).
"""

from __future__ import annotations

from celery import Celery

from jobs.settings import Settings

TASK_NAME = "shsas.run_job"


def make_celery(settings: Settings) -> Celery:
    """A configured Celery app for ``settings`` (broker = ``SHSAS_BROKER_URL``)."""
    app = Celery("shsas", broker=settings.broker_url or "redis://127.0.0.1:6379/0", include=["worker.tasks"])
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        worker_concurrency=1,
        task_ignore_result=True,
        task_store_errors_even_if_ignored=False,
        task_default_queue=settings.gpu_queue,
        task_create_missing_queues=True,
        # Just above ours: the runner fails the job itself first, with a clear message.
        task_soft_time_limit=settings.job_soft_time_limit_s + 30,
        task_time_limit=settings.job_hard_time_limit_s + 60,
        broker_transport_options={"visibility_timeout": settings.visibility_timeout_s},
        broker_connection_retry_on_startup=True,
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
        task_send_sent_event=False,
    )
    return app
