"""Hand a queued job to whoever runs it: a Celery message, or nothing in embedded mode
(the local worker polls the job table)."""

from __future__ import annotations

import time
from functools import lru_cache

from jobs.settings import Settings
from jobs.store import Job


@lru_cache(maxsize=4)
def _celery(settings_json: str):
    from jobs.settings import Settings

    from .celery_app import make_celery

    return make_celery(Settings.model_validate_json(settings_json))


def dispatch(settings: Settings, job: Job) -> None:
    """Send ``job`` to its queue. Raises on broker errors (the caller decides what to tell)."""
    if settings.embedded:
        return
    from .celery_app import TASK_NAME

    app = _celery(settings.model_dump_json())
    app.send_task(TASK_NAME, args=[job.id], queue=job.queue, retry=True,
                  retry_policy={"max_retries": 3, "interval_start": 0.2, "interval_step": 0.5})


#: A key the reconcilers keep in the Redis broker. Finding it gone means Redis came back empty
#: (restarted without persistence, flushed, failed over to an empty replica): every task message
#: it held went with it, so every queued job must be sent again.
BROKER_MARK_KEY = "shsas:broker-mark"


def _is_redis(url: str) -> bool:
    return url.startswith(("redis://", "rediss://", "unix://"))


def broker_was_emptied(settings: Settings, timeout_s: float = 2.0) -> bool:
    """True (for one caller) when the Redis broker lost its data since the mark was last set.

    Also True the first time a broker is used, which only re-sends messages that are duplicates.
    False in embedded mode and for other brokers (the age-based re-send covers those).
    """
    url = settings.broker_url or ""
    if settings.embedded or not _is_redis(url):
        return False
    import redis

    client = redis.Redis.from_url(url, socket_timeout=timeout_s, socket_connect_timeout=timeout_s)
    try:
        return bool(client.set(BROKER_MARK_KEY, repr(time.time()), nx=True))
    finally:
        client.close()


def broker_ping(settings: Settings, timeout_s: float = 2.0) -> None:
    """Raise if the broker cannot be reached (embedded mode has none and always passes)."""
    if settings.embedded:
        return
    url = settings.broker_url or ""
    if _is_redis(url):
        import redis

        client = redis.Redis.from_url(url, socket_timeout=timeout_s, socket_connect_timeout=timeout_s)
        try:
            client.ping()
        finally:
            client.close()
        return
    from kombu import Connection

    with Connection(url, connect_timeout=timeout_s) as conn:
        conn.ensure_connection(max_retries=1)
