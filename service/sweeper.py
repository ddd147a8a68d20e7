"""Removes what nobody will ask for again: finished jobs past
``SHSAS_RETENTION_DAYS``, and upload folders no live request owns.

Each upload gets a folder ``uploads/<random>/`` holding a ``lock`` file that the request keeps
``flock``-ed until it ends (:func:`upload_dir`). The kernel drops the lock when the process
dies, so a folder whose lock can be taken belongs to a request that ended without cleaning up
(the API process was killed mid-upload): it is removed at once, whatever its age, at startup
and every ``SHSAS_SWEEP_INTERVAL_S``. Other API processes sharing the data dir keep their
locks, so their uploads in flight are left alone. Folders of this process's own requests are
skipped by name as well, as some network file systems emulate ``flock`` with POSIX locks that
do not conflict within one process.

Runs as a daemon thread in every API process; several at once are safe (removing a removed
folder or row is a no-op).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

from jobs.layout import remove_job_files, uploads_dir
from jobs.periodic import Periodic
from jobs.settings import Settings
from jobs.store import JobStore

log = logging.getLogger("shsas.sweeper")

LOCK_NAME = "lock"
#: A folder without its lock file is a request between mkdir and open (microseconds), or one
#: that died there; it is removed once older than this.
NO_LOCK_GRACE_S = 60.0
DAY_S = 86400.0

#: Upload folders of requests in flight in this process.
_active: set[str] = set()


@contextlib.contextmanager
def upload_dir(root: Path) -> Iterator[Path]:
    """A fresh upload folder under ``root``, locked for the request's lifetime, then removed."""
    while True:
        d = root / uuid.uuid4().hex
        d.mkdir(parents=True)
        _active.add(d.name)
        fd = os.open(d / LOCK_NAME, os.O_CREAT | os.O_RDWR, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)
        if os.fstat(fd).st_nlink > 0:
            break
        # Another process's sweeper took the lock first, between our open and flock, and
        # removed the folder: start again with a new one.
        os.close(fd)
        _active.discard(d.name)
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)
        os.close(fd)
        _active.discard(d.name)


def _remove(d: Path) -> None:
    size = sum(p.stat().st_size for p in d.rglob("*") if p.is_file())
    shutil.rmtree(d, ignore_errors=True)
    log.warning("removed abandoned upload %s (%d bytes)", d.name, size,
                extra={"upload": d.name, "bytes": size, "reason": "no request owns it"})


def _sweep_one(d: Path) -> bool:
    """Remove ``d`` if no live request holds its lock. True if removed."""
    if d.name in _active:
        return False
    try:
        fd = os.open(d / LOCK_NAME, os.O_RDWR)
    except FileNotFoundError:
        with contextlib.suppress(OSError):
            if time.time() - d.stat().st_mtime > NO_LOCK_GRACE_S:
                _remove(d)
                return True
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return False
    try:
        _remove(d)  # holding the lock: a request that opened the file meanwhile waits, then retries
    finally:
        os.close(fd)
    return True


def sweep_uploads(root: Path) -> int:
    """Remove the upload folders under ``root`` that no request owns. Returns how many."""
    if not root.is_dir():
        return 0
    return sum(_sweep_one(d) for d in root.iterdir() if d.is_dir())


def sweep_expired(store: JobStore, settings: Settings, now: float | None = None) -> int:
    """Delete finished jobs older than the retention, files first. Returns how many rows went."""
    if settings.retention_days <= 0:
        return 0
    cutoff = (now or time.time()) - settings.retention_days * DAY_S
    deleted = 0
    for job in store.finished_before(cutoff):
        # Files first: a crash in between leaves a row without files (its artifacts 404), which
        # the next pass deletes, rather than files no row points to.
        remove_job_files(settings, job.id)
        if store.delete(job.id):
            deleted += 1
            log.info("job %s deleted: finished over %g days ago (SHSAS_RETENTION_DAYS)", job.id,
                     settings.retention_days, extra={"job_id": job.id, "owner": job.owner,
                                                     "status": job.status, "reason": "retention"})
    return deleted


class Sweeper(Periodic):
    """A daemon thread sweeping uploads and retention every ``sweep_interval_s`` (call
    :meth:`sweep_once` first for the sweep at startup)."""

    def __init__(self, store: JobStore, settings: Settings):
        self.store, self.settings = store, settings
        super().__init__("shsas-sweeper", settings.sweep_interval_s, self.sweep_once, log, "sweep")

    def sweep_once(self) -> None:
        try:
            sweep_uploads(uploads_dir(self.settings))
            sweep_expired(self.store, self.settings)
        except Exception:  # the database may be briefly away; try again next time
            log.exception("sweep failed")
