"""Re-queue jobs whose lease went stale (their worker died or hung) (docs/service.md), and re-send
queued jobs whose broker message may be lost.

A queued job's message can vanish with the broker's data (Redis restarted without persistence,
flushed). The job table still says ``queued``, so the job is sent again: at once for every
queued job when the broker is found emptied (:func:`~worker.dispatch.broker_was_emptied`), and,
as a safety net for any other loss, whenever a job has waited ``SHSAS_REDISPATCH_AFTER_S``
since it was last sent. A job that gets two messages still runs once: only the worker that
wins the ``queued`` -> ``running`` claim runs it, the other delivery is skipped.

Safe to run in several processes at once: each transition is a conditional UPDATE, and a
job is dispatched again only by the reconciler whose UPDATE won.
"""

from __future__ import annotations

import logging
import shutil

from jobs.layout import job_paths
from jobs.periodic import Periodic
from jobs.settings import Settings
from jobs.store import JobStore

from .dispatch import broker_was_emptied, dispatch

log = logging.getLogger("shsas.reconciler")


def redispatch_queued(store: JobStore, settings: Settings) -> int:
    """Send queued jobs whose message may be lost to the broker again. Returns how many."""
    if settings.embedded:
        return 0  # the job table is the queue: nothing to lose
    emptied = broker_was_emptied(settings)
    waiting = store.queued_older_than(0.0 if emptied else settings.redispatch_after_s)
    sent = 0
    for job in waiting:
        if not store.mark_redispatched(job):
            continue  # claimed, cancelled or re-sent by another reconciler meanwhile
        why = "the broker is new or came back empty" if emptied else f"queued for over {settings.redispatch_after_s:g} s"
        log.warning("job %s: re-sent to queue %s (%s)", job.id, job.queue, why)
        try:
            dispatch(settings, job)
            sent += 1
        except Exception:
            log.exception("could not re-send job %s; it stays queued", job.id)
    return sent


def reconcile_once(store: JobStore, settings: Settings) -> tuple[int, int]:
    """One pass. Returns (requeued, failed) counts."""
    requeued, failed = store.requeue_stale(settings.lease_timeout_s, settings.max_attempts)
    for job in requeued:
        log.warning("job %s: lease of %s went stale; re-queued (attempt %d done)", job.id, job.lease_owner,
                    job.attempts)
        try:
            dispatch(settings, job)
        except Exception:
            log.exception("could not re-send job %s; it stays queued", job.id)
    for job in failed:
        if job.cancel_requested:
            # Cancelled while its worker was gone: drop what that worker left half-done.
            shutil.rmtree(job_paths(settings, job.id)[1], ignore_errors=True)
            log.warning("job %s cancelled after its worker was lost", job.id)
        else:
            log.error("job %s failed: its worker died %d times without a word (most often killed for "
                      "memory); not retried", job.id, job.attempts,
                      extra={"job_id": job.id, "status": "failed", "attempt": job.attempts,
                             "reason": "worker lost (stale lease) SHSAS_MAX_ATTEMPTS times"})
    redispatch_queued(store, settings)
    return len(requeued), len(failed)


class Reconciler(Periodic):
    """A daemon thread calling :func:`reconcile_once` every ``reconcile_interval_s``."""

    def __init__(self, store: JobStore, settings: Settings):
        self.store, self.settings = store, settings
        super().__init__("shsas-reconciler", settings.reconcile_interval_s,
                         lambda: reconcile_once(store, settings), log, "reconciler pass")
