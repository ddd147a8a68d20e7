"""Job execution for the shsas service: the runner, the Celery app and tasks, the reconciler and
the embedded local worker. Imports ``jobs`` and ``shsas_core`` (never ``service``)."""
