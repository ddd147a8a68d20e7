"""The job model the API (``service``) and the worker (``worker``) share: the job store
(:mod:`jobs.store`), the settings (:mod:`jobs.settings`), where a job's files live
(:mod:`jobs.layout`) and the periodic daemon thread both processes run (:mod:`jobs.periodic`:
the sweeper, the reconciler, a running job's heartbeat). Free of Celery and of the web
framework (the import contract checks it), so either process uses it without the other's stack.
"""
