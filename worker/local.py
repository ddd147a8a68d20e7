"""The embedded local worker of ``shsas serve``: the job table is the queue, no Redis.

:func:`run_local_worker` loops in a child process: claim the oldest queued job atomically
(a conditional UPDATE takes the lease), run it with :func:`~worker.runner.execute_job`, repeat.
:class:`LocalWorkerSupervisor` (in the ``shsas serve`` process) starts that child with the
``spawn`` method, so torch and CUDA are only ever initialised in the child, and restarts it if
it dies; the job it was running is re-queued by the reconciler once its lease goes stale.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import signal
import threading
import time

log = logging.getLogger("shsas.local")


def run_local_worker() -> None:
    """Child-process entry point: poll, claim, run until SIGTERM."""
    from .runner import execute_job, worker_id
    from .settings import get_settings
    from .store import JobStore

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    stopping = threading.Event()
    busy = False

    def on_term(*_) -> None:
        stopping.set()
        if busy:
            # Leave the job as a lost worker would: its lease goes stale, the reconciler
            # re-queues it and the next run resumes from its checkpoints.
            raise SystemExit(0)

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    settings = get_settings()
    store = JobStore.from_settings(settings)
    owner = worker_id()
    log.info("local worker %s polling %s", owner, settings.db_url.split("@")[-1])
    while not stopping.is_set():
        try:
            job = store.claim_next(owner)
        except Exception:
            log.exception("could not poll the job table")
            job = None
        if job is None:
            stopping.wait(settings.local_poll_interval_s)
            continue
        busy = True
        try:
            status = execute_job(store, settings, job.id, owner, claimed=job)
        finally:
            busy = False
        log.info("job %s: %s", job.id, status)


class LocalWorkerSupervisor:
    """Keep one local worker child alive while the API runs."""

    def __init__(self) -> None:
        self._ctx = mp.get_context("spawn")
        self._proc: mp.process.BaseProcess | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="shsas-local-supervisor", daemon=True)

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def start(self) -> LocalWorkerSupervisor:
        self._spawn()
        self._thread.start()
        return self

    def _spawn(self) -> None:
        self._proc = self._ctx.Process(target=run_local_worker, name="shsas-local-worker", daemon=False)
        self._proc.start()
        log.info("started local worker pid %s", self._proc.pid)

    def _watch(self) -> None:
        while not self._stop.wait(1.0):
            if self._proc is not None and not self._proc.is_alive():
                log.error("local worker pid %s exited with %s; restarting", self._proc.pid, self._proc.exitcode)
                time.sleep(1.0)
                if not self._stop.is_set():
                    self._spawn()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        if self._proc is not None and self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(2)
