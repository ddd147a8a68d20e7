"""Declared-size memory bombs, against real processes and real HDF5 files.

A survey's declared sizes are checked against the worker memory budget
(``SHSAS_WORKER_MEMORY_BYTES``) before anything is allocated: at upload (413), in the worker
(the job fails before loading) and in ``shsas reconstruct``; samples that were never written
are refused outright (422; ``shsas info`` too). A job whose worker died twice is failed, not
retried a third time, and a worker that stops cleanly hands its job back without that counting.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from jobs.layout import job_paths
from jobs.settings import Settings
from jobs.store import JobStore
from tests.helpers.declared_size import unwritten_samples, zero_filled_samples
from worker.runner import execute_job

from .conftest import FAST_TIMINGS, REPO, SHSAS, start_server, submit, wait_for, write_tiny_survey
from .test_serve_shutdown import _alive, _worker_and_tracker

pytestmark = pytest.mark.service

GiB = 1024**3

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
LONG_SPEC = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}
#: (128, 500000) float32: 256 MB of samples in a ~1 MB file; about 4 GiB for the estimate.
MID = (128, 500_000)
SMALL_BUDGET = 2 * GiB
#: Lease timings for the tests that kill workers: short enough to wait for, long enough that a
#: loaded machine's late heartbeats do not count as deaths of their own.
DEATH_TIMINGS = {**FAST_TIMINGS, "SHSAS_LEASE_TIMEOUT_S": "8"}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("bombs")
    return {
        "unwritten": unwritten_samples(tmp / "unwritten.h5", 360, 1_000_000),  # the 0.7 MB file
        "declared_4e9": zero_filled_samples(tmp / "declared_4e9.h5", 4000, 1_000_000),
        "mid": zero_filled_samples(tmp / "mid.h5", *MID),
        "tiny": write_tiny_survey(tmp / "tiny.h5"),
    }


@pytest.fixture(scope="module")
def default_server(tmp_path_factory):
    """SHSAS_WORKER_MEMORY_BYTES unset: the budget comes from this machine's memory."""
    if os.environ.get("SHSAS_WORKER_MEMORY_BYTES"):
        pytest.skip("SHSAS_WORKER_MEMORY_BYTES is set in this environment")
    tmp = tmp_path_factory.mktemp("budget-default")
    proc, base = start_server(tmp, {"SHSAS_DATA_DIR": str(tmp / "data"), **FAST_TIMINGS})
    yield base
    proc.stop()


def _upload(base: str, survey: Path, spec: dict) -> httpx.Response:
    with httpx.Client(base_url=base, timeout=120) as c:
        return submit(c, survey, spec)


def _jobs(base: str) -> list[dict]:
    with httpx.Client(base_url=base, timeout=30) as c:
        return c.get("/reconstructions").json()["items"]


def test_upload_of_never_written_samples_is_refused(default_server, files) -> None:
    assert files["unwritten"].stat().st_size < 1_000_000
    r = _upload(default_server, files["unwritten"], QUICK_SPEC)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "pings/samples" in detail and "never written" in detail and "(360, 1000000)" in detail
    assert _jobs(default_server) == []


def test_upload_declaring_4e9_samples_is_over_the_default_budget(default_server, files) -> None:
    assert files["declared_4e9"].stat().st_size < 20_000_000
    t0 = time.monotonic()
    r = _upload(default_server, files["declared_4e9"], QUICK_SPEC)
    assert r.status_code == 413, r.text
    detail = r.json()["detail"]
    assert "4000 pings x 1000000 samples" in detail and "SHSAS_WORKER_MEMORY_BYTES" in detail
    assert "GiB of memory, over the worker memory budget of" in detail
    assert time.monotonic() - t0 < 60  # refused from the header: no scan of 16 GB of samples
    assert _jobs(default_server) == []


def test_budget_setting_refuses_large_jobs_and_runs_small_ones(tmp_path, files) -> None:
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), "SHSAS_WORKER_MEMORY_BYTES": str(SMALL_BUDGET),
           **FAST_TIMINGS}
    proc, base = start_server(tmp_path, env)
    try:
        r = _upload(base, files["mid"], QUICK_SPEC)
        assert r.status_code == 413, r.text
        assert f"{MID[0]} pings x {MID[1]} samples" in r.json()["detail"]
        assert "budget of 2.0 GiB (SHSAS_WORKER_MEMORY_BYTES" in r.json()["detail"]
        ok = _upload(base, files["tiny"], QUICK_SPEC)
        assert ok.status_code == 202, ok.text
        with httpx.Client(base_url=base, timeout=30) as c:
            done = wait_for(c, ok.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 120, "job")
        assert done["status"] == "succeeded", done
    finally:
        proc.stop()


def test_worker_fails_a_job_over_its_budget_before_loading(tmp_path, files) -> None:
    """The worker's own check: a job that reached it (an API with a larger budget, a file
    changed since) fails with the sizes and the budget named, having read no samples."""
    settings = Settings(data_dir=tmp_path / "data", worker_memory_bytes=SMALL_BUDGET)
    store = JobStore.from_settings(settings)
    try:
        job, _ = store.create_job(owner="o", spec=QUICK_SPEC, input_digest="x", input_name="survey.h5",
                                  input_bytes=1, queue="cpu")
        in_dir, out_dir = job_paths(settings, job.id)
        in_dir.mkdir(parents=True)
        (in_dir / "survey.h5").write_bytes(files["mid"].read_bytes())
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        assert execute_job(store, settings, job.id, "w1") == "failed"
        grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - peak
        err = store.get(job.id).error
        assert f"{MID[0]} pings x {MID[1]} samples" in err and "budget of 2.0 GiB" in err, err
        assert grown < 200 * 1024**2, f"peak RSS grew by {grown / 1024**2:.0f} MiB: samples were read"
        assert not out_dir.exists() or not any(p.is_file() for p in out_dir.rglob("*"))
    finally:
        store.dispose()


def _cli(args: list[str], env: dict[str, str] | None = None) -> tuple[int, str, int]:
    """(exit code, stderr, peak RSS in bytes) of one `shsas` run in a fresh child."""
    probe = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], capture_output=True, text=True);"
             "sys.stdout.write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024) + '\\n');"
             "sys.stdout.write(str(r.returncode) + '\\n' + r.stderr)")
    full_env = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    out = subprocess.run([sys.executable, "-c", probe, *SHSAS, *args], capture_output=True, text=True,
                         env=full_env, cwd=REPO, timeout=300).stdout
    peak, rc, stderr = out.split("\n", 2)
    return int(rc), stderr, int(peak)


def test_cli_refuses_in_one_line_without_allocating(tmp_path, files) -> None:
    rc, err, _ = _cli(["info", str(files["unwritten"])])
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "never written" in err, err
    rc, err, peak = _cli(["reconstruct", str(files["declared_4e9"]), "--out", str(tmp_path / "out")])
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "4000 pings x 1000000 samples" in err and "SHSAS_WORKER_MEMORY_BYTES" in err
    assert peak < 1 * GiB, f"peak RSS {peak / GiB:.1f} GiB"
    rc, err, _ = _cli(["reconstruct", str(files["mid"]), "--out", str(tmp_path / "out2"), "--quiet"],
                      {"SHSAS_WORKER_MEMORY_BYTES": str(SMALL_BUDGET)})
    assert rc == 2 and "budget of 2.0 GiB" in err, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "out2").exists()


# ---- worker deaths ---------------------------------------------------------------------------------

@pytest.mark.slow
def test_job_whose_worker_died_twice_is_failed_not_retried(tmp_path, files) -> None:
    """Two SIGKILLs of the worker mid-job (what an OOM kill looks like): failed, no third run."""
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), **DEATH_TIMINGS}
    proc, base = start_server(tmp_path, env)
    try:
        with httpx.Client(base_url=base, timeout=30) as c:
            job_id = submit(c, files["tiny"], LONG_SPEC).json()["id"]
            for attempt in (1, 2):
                wait_for(c, job_id, lambda j, a=attempt: j["status"] == "running" and j["attempts"] == a
                         and j["progress"] > 0, 90, f"attempt {attempt} under way")
                worker, _ = _worker_and_tracker(proc.pid)
                os.kill(worker, signal.SIGKILL)
            done = wait_for(c, job_id, lambda j: j["status"] != "running", 60, "the second death to be noticed")
            assert done["status"] == "failed" and done["attempts"] == 2, done
            assert "died 2 times" in done["error"] and "memory" in done["error"], done["error"]
            time.sleep(3)  # the restarted worker is idle: nothing re-runs the job
            again = c.get(f"/reconstructions/{job_id}").json()
            assert again["status"] == "failed" and again["attempts"] == 2, again
    finally:
        proc.stop()


@pytest.mark.slow
def test_stopping_serve_hands_the_running_job_back(tmp_path, files) -> None:
    """SIGTERM to serve mid-job: the job is queued again at once, not counted as a death, and
    the next serve takes it up again."""
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), **DEATH_TIMINGS}
    proc, base = start_server(tmp_path, env)
    try:
        with httpx.Client(base_url=base, timeout=30) as c:
            job_id = submit(c, files["tiny"], LONG_SPEC).json()["id"]
            wait_for(c, job_id, lambda j: j["status"] == "running" and j["progress"] > 0, 90, "job under way")
        worker, _ = _worker_and_tracker(proc.pid)
        os.kill(proc.pid, signal.SIGTERM)
        proc.p.wait(30)
        deadline = time.monotonic() + 10
        while _alive(worker):
            assert time.monotonic() < deadline, "the local worker outlived serve"
            time.sleep(0.1)
    finally:
        proc.stop()
    store = JobStore(f"sqlite:///{tmp_path / 'data' / 'shsas.db'}")
    try:
        row = store.get(job_id)
        assert row.status == "queued" and row.attempts == 0 and row.lease_owner is None, (row, proc.tail())
    finally:
        store.dispose()
    proc, base = start_server(tmp_path, env, name="api-2")
    try:
        with httpx.Client(base_url=base, timeout=30) as c:
            wait_for(c, job_id, lambda j: j["status"] == "running" and j["attempts"] == 1 and j["progress"] > 0,
                     90, "the next serve to run the job again, as its first counted attempt")
            c.post(f"/reconstructions/{job_id}/cancel")
            wait_for(c, job_id, lambda j: j["status"] == "cancelled", 30, "cancel")
    finally:
        proc.stop()
