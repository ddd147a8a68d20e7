"""The embedded local worker of ``shsas serve``: the job table is the queue, no Redis.

:func:`run_local_worker` loops in a child process: claim the oldest queued job atomically
(a conditional UPDATE takes the lease), run it with :func:`~worker.runner.execute_job`, repeat.
:class:`LocalWorkerSupervisor` (in the ``shsas serve`` process) starts that child with the
``spawn`` method, so torch and CUDA are only ever initialised in the child, and restarts it if
it dies; the job it was running is re-queued by the reconciler once its lease goes stale.

The child never outlives ``shsas serve``: serve stops it on SIGTERM/SIGINT, and when serve dies
without a word (SIGKILL, OOM kill) the child gets SIGTERM from the kernel (Linux
``PR_SET_PDEATHSIG``) or, elsewhere, notices its parent pid change; an orphan would otherwise
keep claiming jobs beside the worker of the next ``shsas serve``.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time

log = logging.getLogger("shsas.local")

#: How often the child checks that ``shsas serve`` is still its parent.
PARENT_CHECK_S = 1.0
#: After the parent is gone, how long the child may take to stop on its own before it is ended.
ORPHAN_GRACE_S = 5.0
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int) -> None:
    """Ask Linux to send SIGTERM to this process when its parent dies (best effort)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            log.warning("prctl(PR_SET_PDEATHSIG) failed: errno %d", ctypes.get_errno())
    except (OSError, AttributeError):
        log.warning("prctl is unavailable; relying on the parent watch alone")
    # The parent may have died before prctl took effect: then no signal will ever come.
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGTERM)


def _watch_parent(parent_pid: int) -> None:
    """Portable fallback of PR_SET_PDEATHSIG: stop once reparented, end the process if stuck."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_CHECK_S)
    log.error("shsas serve (pid %d) is gone; the local worker stops", parent_pid)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(ORPHAN_GRACE_S)
    os._exit(1)  # the main thread did not stop in time (stuck in native code)


def run_local_worker(parent_pid: int | None = None) -> None:
    """Child-process entry point: poll, claim, run until SIGTERM or until ``parent_pid`` dies."""
    from jobs.settings import get_settings
    from jobs.store import JobStore
    from shsas_core.common.threads import size_thread_pools

    from .logs import configure_logging
    from .priority import lower_priority
    from .runner import execute_job, request_shutdown, worker_id

    settings = get_settings()
    configure_logging(settings.log_format, "info")
    lower_priority(settings.worker_nice)  # before torch starts its threads (they inherit it)
    stopping = threading.Event()

    @functools.cache
    def size_pools() -> None:
        # at the first job, not at start: torch is imported here, so a worker that never gets a
        # job (a server that only takes uploads, a restart) neither holds torch's few hundred MB
        # nor pays its import. The CPUs this child owns (not the machine's), or the setting.
        size_thread_pools(settings.worker_threads)

    def on_term(*_) -> None:
        # A running job stops at its next should_stop() and goes back to the queue, where the
        # next worker resumes it from its checkpoints; then the loop ends.
        stopping.set()
        request_shutdown()

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    if parent_pid is not None:
        die_with_parent(parent_pid)
        threading.Thread(target=_watch_parent, args=(parent_pid,), name="shsas-parent-watch", daemon=True).start()
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
        if stopping.is_set():  # the stop came while claiming: hand the job straight back
            store.release(job.id, owner)
            break
        status = execute_job(store, settings, job.id, owner, claimed=job, prepare=size_pools)
        log.info("job %s: %s", job.id, status, extra={"job_id": job.id, "status": status})


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
        self._proc = self._ctx.Process(target=run_local_worker, args=(os.getpid(),), name="shsas-local-worker",
                                       daemon=False)
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
