"""Job execution for the shsas service: the job store, the runner, the Celery app and tasks,
and the embedded local worker. Imports only ``shsas_core`` (never ``service``)."""
