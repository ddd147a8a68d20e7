"""``celery -A worker.app worker``: the Celery app built from the environment (``SHSAS_*``)."""

from __future__ import annotations

from jobs.settings import get_settings

from .celery_app import make_celery

app = make_celery(get_settings())
celery = app  # the name `celery -A worker.app` also looks for
