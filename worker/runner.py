"""Run one job: claim its lease, call ``shsas_core.pipeline.job.run``, keep the job row current.

Shared by the Celery task and the embedded local worker. The job row is the source of truth:
the runner only acts while it holds the lease, writes progress and heartbeats to the row,
reads ``cancel_requested`` from it, and finishes the job with one conditional UPDATE.

A re-delivered job runs again in the same ``out_dir``; the pipeline's checkpoints make that a
resume, and files it left half-written are removed first (``shsas_core.common.atomic.remove_partials``).
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path

from jobs.joblog import job_log
from jobs.layout import job_paths, remove_job_files
from jobs.periodic import Periodic
from jobs.settings import Settings
from jobs.store import Job, JobStore
from shsas_core.common.atomic import is_partial, remove_partials

from .eta import EtaEstimator
from .previews import write_previews

log = logging.getLogger("shsas.worker")

#: How often should_stop() reads the cancel flag at most; pipelines call it between steps.
CANCEL_POLL_S = 0.1
#: How often progress is written at most (stage changes are always written).
PROGRESS_WRITE_S = 0.5
#: How often a stage's progress and live metrics are logged (the job's log shows them).
PROGRESS_LOG_S = 15.0


#: Set when this worker process is asked to stop (see :func:`request_shutdown`).
_shutdown = threading.Event()


def request_shutdown() -> None:
    """Stop the running job at its next ``should_stop()`` and hand it back to the queue.

    For signal handlers: unlike an exception raised from the handler, this never lands in the
    middle of a database write.
    """
    _shutdown.set()


def worker_id() -> str:
    """A unique lease-owner name for this process: host, pid and a random suffix."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"


class JobControl:
    """The ``progress`` / ``should_stop`` pair handed to the pipeline, plus a heartbeat thread.

    ``should_stop()`` turns True when the API asked to cancel, when this worker lost the lease
    (another worker took the job over), when the worker process is stopping
    (:func:`request_shutdown`) or past the soft time limit. Past the hard limit the
    heartbeat thread fails the job and ends the process, since the pipeline is not listening.
    """

    def __init__(self, store: JobStore, settings: Settings, job: Job, owner: str):
        self.store, self.settings, self.job_id, self.owner = store, settings, job.id, owner
        self.cancel = False
        self.lost_lease = False
        self.timed_out = False
        self._t0 = time.monotonic()
        self._last_poll = 0.0
        self._last_write = 0.0
        self._stage: str | None = None
        self._eta = EtaEstimator()
        self._last_log = time.monotonic()
        self._lock = threading.Lock()
        # a heartbeat write can wait on a busy database: give the last one longer to end
        self._beats = Periodic(f"heartbeat-{job.id}", settings.heartbeat_interval_s, self._beat, log,
                               f"job {job.id} heartbeat", join_timeout_s=10.0)

    def start(self) -> JobControl:
        self._beats.start()
        return self

    def close(self) -> None:
        self._beats.stop()

    def _apply(self, still_owner: bool, cancel: bool) -> None:
        if not still_owner:
            self.lost_lease = True
        if cancel:
            self.cancel = True

    def _beat(self) -> None:
        self._write()  # the lease tolerates a few missed beats
        if time.monotonic() - self._t0 > self.settings.job_hard_time_limit_s:
            reason = self._limit_message("hard")
            log.error("job %s failed: %s; ending the worker process", self.job_id, reason,
                      extra={"job_id": self.job_id, "status": "failed", "reason": reason})
            self.store.finish(self.job_id, self.owner, "failed", error=reason)
            os._exit(70)

    def _limit_message(self, kind: str) -> str:
        limit = self.settings.job_soft_time_limit_s if kind == "soft" else self.settings.job_hard_time_limit_s
        return f"the job ran past the {kind} time limit of {limit:g} s (SHSAS_JOB_{kind.upper()}_TIME_LIMIT_S)"

    def progress(self, fraction: float, stage: str, metrics: Mapping[str, float]) -> None:
        now = time.monotonic()
        eta = self._eta.update(now, fraction, stage)  # every report: the pace needs them all
        if stage == self._stage and now - self._last_write < PROGRESS_WRITE_S and fraction < 1.0:
            return
        if stage != self._stage or now - self._last_log >= PROGRESS_LOG_S:
            self._last_log = now
            shown = "".join(f", {k} {v:.4g}" for k, v in metrics.items() if isinstance(v, int | float))
            log.info("job %s: %s at %.1f %%%s", self.job_id, stage, 100 * fraction, shown,
                     extra={"job_id": self.job_id, "stage": stage})
        self._stage, self._last_write = stage, now
        live = {k: float(v) for k, v in metrics.items() if isinstance(v, int | float)}
        if eta is not None:  # seconds left as of eta_at (unix time): readers age it themselves
            live.update(eta_s=round(eta, 1), eta_at=round(time.time(), 2))
        self._write(progress=fraction, stage=stage, live_metrics=live)

    def _write(self, **values) -> None:
        try:
            with self._lock:
                self._apply(*self.store.heartbeat(self.job_id, self.owner, **values))
        except Exception:  # a DB blip must not fail the job; the next call tries again
            log.warning("job %s: could not write progress/heartbeat", self.job_id, exc_info=True)

    def should_stop(self) -> bool:
        now = time.monotonic()
        if now - self._t0 > self.settings.job_soft_time_limit_s:
            self.timed_out = True
        if now - self._last_poll >= CANCEL_POLL_S:
            self._last_poll = now
            self._write()
        return self.cancel or self.lost_lease or self.timed_out or _shutdown.is_set()


def _checked_artifacts(out_dir: Path, names: list[str]) -> list[str]:
    """Artifact names as the API will serve them: plain file names that exist, no repeats."""
    seen: list[str] = []
    for name in names:
        if Path(name).name != name or name.startswith(".") or is_partial(name):
            raise RuntimeError(f"pipeline returned an artifact name that is not a plain file name: {name!r}")
        if not (out_dir / name).is_file():
            raise RuntimeError(f"pipeline listed artifact {name!r} but did not write it")
        if name not in seen:
            seen.append(name)
    return seen


def execute_job(store: JobStore, settings: Settings, job_id: str, owner: str | None = None,
                *, claimed: Job | None = None, prepare: Callable[[], None] | None = None) -> str:
    """Claim and run ``job_id``. Returns the final status, or ``"skipped"`` when the job was not
    queued (already running elsewhere, finished or cancelled), ``"lost"`` when another
    worker took the lease over mid-run, or ``"released"`` when this worker is stopping and
    handed the job back to the queue. ``prepare`` runs once the job's heartbeat is going and
    before the science is imported (the local worker sizes its thread pools there, which
    imports torch: slow on a loaded machine, and the lease must not go stale meanwhile)."""
    owner = owner or worker_id()
    job = claimed or store.claim(job_id, owner)
    if job is None:
        log.info("job %s is not queued any more; nothing to do", job_id)
        return "skipped"
    in_dir, out_dir = job_paths(settings, job.id)
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_partials(out_dir)
    lines = job_log(out_dir.parent, job.id)  # the job's own log, beside its input and outputs
    lines.__enter__()
    log.info("job %s attempt %d on %s", job.id, job.attempts, owner)
    ctl = JobControl(store, settings, job, owner).start()
    try:
        if prepare is not None:
            prepare()
        from shsas_core.common.errors import Cancelled, ShsasError
        from shsas_core.pipeline.job import run
        from shsas_core.spec.job import ReconstructionSpec

        spec = ReconstructionSpec.model_validate(job.spec)
        try:
            result = run(spec, in_dir / job.input_name, out_dir, ctl.progress, ctl.should_stop,
                         memory_budget=settings.worker_memory_bytes)
        except Cancelled:
            if ctl.lost_lease:
                return _lost(store, settings, job)
            if ctl.timed_out and not ctl.cancel:
                return _fail(store, job, owner, ctl._limit_message("soft"))
            if _shutdown.is_set() and not ctl.cancel:
                _release(store, settings, job, owner)
                return "released"
            # No half-written artifacts kept: a cancelled job's outputs go entirely.
            shutil.rmtree(out_dir, ignore_errors=True)
            store.finish(job.id, owner, "cancelled", artifacts=[])
            log.info("job %s cancelled", job.id, extra={"job_id": job.id, "status": "cancelled"})
            return "cancelled"
        except ShsasError as exc:
            return _fail(store, job, owner, str(exc)[:2000])
        except MemoryError:
            return _fail(store, job, owner, "the job ran out of memory (try a smaller grid or fewer rays)")
        artifacts = _checked_artifacts(out_dir, list(result.artifacts))
        artifacts += write_previews(out_dir, artifacts)  # light copies for the console's first view
        # None (an undefined metric) is kept as it is: JSON null in the job table and the API
        metrics = {m: {k: (None if v is None else float(v)) for k, v in d.items()
                       if v is None or isinstance(v, int | float)}
                   for m, d in result.metrics.items()}
        # a result that looks failed still succeeds (the job ran), but says so in its status
        warnings = [{"method": m, **w.model_dump(mode="json")} for m, ws in result.warnings.items() for w in ws]
        for w in warnings:
            log.warning("job %s: %s: %s (%.3g vs limit %.3g)", job.id, w["method"], w["message"],
                        w["measure"], w["limit"])
        if not store.finish(job.id, owner, "succeeded", artifacts=artifacts, metrics=metrics, warnings=warnings,
                            device=result.device):
            return _lost(store, settings, job)
        log.info("job %s succeeded on %s", job.id, result.device,
                 extra={"job_id": job.id, "status": "succeeded", "device": result.device,
                        "artifacts": len(artifacts), "warnings": len(warnings)})
        return "succeeded"
    except Exception as exc:  # report, never crash the worker on one bad job
        log.error("job %s: unexpected error:\n%s", job.id, traceback.format_exc())
        name = "soft time limit" if type(exc).__name__ == "SoftTimeLimitExceeded" else type(exc).__name__
        return _fail(store, job, owner, f"internal error ({name}): {str(exc)[:500]}")
    except (SystemExit, KeyboardInterrupt):
        # Stopped by an exception rather than request_shutdown() (e.g. a pool child's exit).
        _release(store, settings, job, owner)
        raise
    finally:
        ctl.close()
        lines.__exit__(None, None, None)


def _fail(store: JobStore, job: Job, owner: str, reason: str) -> str:
    """Fail the job with ``reason``, and say why in the worker's log too."""
    store.finish(job.id, owner, "failed", error=reason)
    log.error("job %s failed: %s", job.id, reason, extra={"job_id": job.id, "status": "failed",
                                                          "attempt": job.attempts, "reason": reason})
    return "failed"


def _lost(store: JobStore, settings: Settings, job: Job) -> str:
    """This worker no longer holds the job. If another worker took it over, its out_dir is that
    worker's now; if the job was deleted (DELETE, retention), what this run wrote goes too."""
    if not store.exists(job.id):
        remove_job_files(settings, job.id)
        log.info("job %s was deleted while it ran; its files are removed", job.id,
                 extra={"job_id": job.id, "status": "deleted"})
    else:
        log.warning("job %s: lease lost to another worker", job.id, extra={"job_id": job.id, "status": "lost"})
    return "lost"


def _release(store: JobStore, settings: Settings, job: Job, owner: str) -> None:
    """Hand a job this stopping worker holds back to the queue. Left to go stale, its lease
    would count as a worker death, and two of those fail the job (SHSAS_MAX_ATTEMPTS)."""
    try:
        if not store.release(job.id, owner):
            return
        log.warning("job %s handed back to the queue: its worker is stopping", job.id)
        from .dispatch import dispatch

        dispatch(settings, job)
    except Exception:  # stopping anyway; the reconciler re-sends or re-queues it later
        log.warning("job %s: could not hand it back; the reconciler will", job.id, exc_info=True)
