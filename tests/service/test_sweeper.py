"""The sweeper: abandoned uploads go whatever their age, uploads a live
request holds stay, finished jobs past the retention go with their files. Real files, real
locks held by real processes, a real job store; the HTTP side is in test_operations.py."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from jobs.settings import Settings
from jobs.store import JobStore
from service.sweeper import LOCK_NAME, sweep_expired, sweep_uploads, upload_dir


def _upload(root: Path, name: str, size: int = 1000, lock: bool = True) -> Path:
    d = root / name
    d.mkdir(parents=True)
    (d / "upload.part").write_bytes(b"x" * size)
    if lock:
        (d / LOCK_NAME).touch()
    return d


def test_abandoned_uploads_go_whatever_their_age_live_ones_stay(tmp_path: Path) -> None:
    root = tmp_path / "uploads"
    fresh = _upload(root, "fresh")  # its request died a moment ago: no process holds the lock
    held = _upload(root, "held")
    # Another API process with a request in flight holds its folder's lock.
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR); fcntl.flock(fd, fcntl.LOCK_EX); "
        "print('locked', flush=True); time.sleep(120)"), str(held / LOCK_NAME)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with upload_dir(root) as mine:  # this process's own request in flight
            (mine / "upload.part").write_bytes(b"y")
            assert sweep_uploads(root) == 1
            assert not fresh.exists() and held.exists() and mine.exists()
        assert not mine.exists()  # the request removes its own folder
    finally:
        holder.kill()
        holder.wait()
    assert sweep_uploads(root) == 1 and not held.exists()  # its process died: the lock went with it


def test_folder_without_a_lock_goes_after_the_grace(tmp_path: Path) -> None:
    root = tmp_path / "uploads"
    young = _upload(root, "young", lock=False)
    old = _upload(root, "old", lock=False)
    past = time.time() - 3600
    os.utime(old, (past, past))
    assert sweep_uploads(root) == 1 and young.exists() and not old.exists()


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    s = JobStore(f"sqlite:///{tmp_path / 'jobs.db'}")
    yield s
    s.dispose()


def _finished(store: JobStore, settings: Settings, status: str = "succeeded"):
    job, _ = store.create_job(owner="alice", spec={}, input_digest="d" * 64, input_name="survey.h5",
                              input_bytes=1, queue="cpu")
    store.claim(job.id, "w")
    store.finish(job.id, "w", status, artifacts=[])
    (settings.jobs_dir() / job.id / "out").mkdir(parents=True)
    (settings.jobs_dir() / job.id / "out" / "report.json").write_text("{}")
    return store.get(job.id)


def test_retention_deletes_finished_jobs_and_their_files(tmp_path: Path, store: JobStore) -> None:
    settings = Settings(data_dir=tmp_path / "data", retention_days=1.0)
    old = _finished(store, settings)
    failed = _finished(store, settings, "failed")
    running, _ = store.create_job(owner="alice", spec={}, input_digest="d" * 64, input_name="survey.h5",
                                  input_bytes=1, queue="cpu")
    store.claim(running.id, "w")
    assert sweep_expired(store, settings) == 0  # finished just now
    later = old.finished_at + 86400 + 1
    assert sweep_expired(store, settings, now=later) == 2
    for job in (old, failed):
        assert not store.exists(job.id) and not (settings.jobs_dir() / job.id).exists()
    assert store.exists(running.id)
    keep = Settings(data_dir=tmp_path / "data", retention_days=0)  # 0 keeps everything
    kept = _finished(store, keep)
    assert sweep_expired(store, keep, now=later + 1e9) == 0 and store.exists(kept.id)
