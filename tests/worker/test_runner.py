"""The job runner in-process against a real SQLite job store and the pipeline module:
success, bad input, soft time limit, cancel, lost lease, and clean-up of half-written files."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

from jobs.layout import job_paths
from jobs.settings import Settings
from jobs.store import JobStore, jobs
from shsas_core.outputs.report import load_report
from tests.service.conftest import write_tiny_survey
from worker.runner import execute_job

QUICK = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
LONG = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}


@pytest.fixture
def env(tmp_path: Path):
    settings = Settings(data_dir=tmp_path / "data", heartbeat_interval_s=0.2, lease_timeout_s=1.0,
                        job_soft_time_limit_s=600, job_hard_time_limit_s=700)
    store = JobStore.from_settings(settings)
    yield settings, store
    store.dispose()


def queue_job(settings: Settings, store: JobStore, spec: dict, survey: Path | None = None, tmp: Path | None = None):
    job, _ = store.create_job(owner="o", spec=spec, input_digest="x", input_name="survey.h5", input_bytes=1,
                              queue="cpu")
    in_dir, _ = job_paths(settings, job.id)
    in_dir.mkdir(parents=True)
    if survey is None:
        write_tiny_survey(in_dir / "survey.h5")
    else:
        (in_dir / "survey.h5").write_bytes(survey.read_bytes())
    return job


def run_in_thread(settings, store, job_id, owner="w1"):
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("status", execute_job(store, settings, job_id, owner)))
    t.start()
    return t, out


def wait_running(store: JobStore, job_id: str, timeout: float = 30) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        j = store.get(job_id)
        if j.status == "running" and j.progress > 0:
            return
        time.sleep(0.05)
    raise AssertionError(f"job never ran: {store.get(job_id)}")


def test_success_writes_artifacts_and_removes_stale_tmp(env) -> None:
    settings, store = env
    job = queue_job(settings, store, QUICK)
    _, out_dir = job_paths(settings, job.id)
    out_dir.mkdir(parents=True)
    (out_dir / "shsas_mesh.glb.tmp").write_bytes(b"half a file from a killed run")
    (out_dir / ".shsas_mesh.ply.123.tmp").write_bytes(b"half")
    (out_dir / "checkpoints").mkdir()
    (out_dir / "checkpoints" / "state.pt.tmp4567").write_bytes(b"half")
    assert execute_job(store, settings, job.id, "w1") == "succeeded"
    done = store.get(job.id)
    assert done.status == "succeeded" and done.attempts == 1 and done.progress == 1.0
    assert done.artifacts and all((out_dir / a).is_file() for a in done.artifacts)
    # the status and the report say which device ran it (a "cpu" spec here; "auto" on a GPU worker)
    assert done.device == "cpu" and load_report(out_dir / "report.json").device == "cpu"
    assert not list(out_dir.rglob("*.tmp*"))
    assert execute_job(store, settings, job.id, "w2") == "skipped"  # a duplicate delivery does nothing


def test_a_failed_looking_result_succeeds_with_warnings(env, tmp_path: Path) -> None:
    settings, store = env
    silent = write_tiny_survey(tmp_path / "silent.h5", silent=True)  # backprojects to zeros
    job = queue_job(settings, store, QUICK, survey=silent)
    assert execute_job(store, settings, job.id, "w1") == "succeeded"
    done = store.get(job.id)
    assert [(w["method"], w["code"], w["measure"]) for w in done.warnings] == [("backprojection", "collapsed", 0.0)]
    assert set(done.metrics) == {"backprojection"}  # the metrics keep their shape


def test_bad_input_fails_with_the_validation_message(env, tmp_path: Path) -> None:
    settings, store = env
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100)
    job = queue_job(settings, store, QUICK, survey=bad)
    assert execute_job(store, settings, job.id, "w1") == "failed"
    err = store.get(job.id).error
    assert err and "could not be read" in err


def test_cancel_mid_run_removes_outputs(env) -> None:
    settings, store = env
    job = queue_job(settings, store, LONG)
    t, out = run_in_thread(settings, store, job.id)
    wait_running(store, job.id)
    t0 = time.monotonic()
    store.request_cancel(job.id, "o")
    t.join(10)
    assert out["status"] == "cancelled" and time.monotonic() - t0 < 2
    assert store.get(job.id).status == "cancelled"
    assert not job_paths(settings, job.id)[1].exists()


def test_soft_time_limit_fails_job_with_message(env) -> None:
    settings, store = env
    settings = settings.model_copy(update={"job_soft_time_limit_s": 0.5})
    job = queue_job(settings, store, LONG)
    assert execute_job(store, settings, job.id, "w1") == "failed"
    assert "soft time limit of 0.5 s" in store.get(job.id).error


def test_lost_lease_stops_without_touching_the_job(env) -> None:
    settings, store = env
    job = queue_job(settings, store, LONG)
    t, out = run_in_thread(settings, store, job.id)
    wait_running(store, job.id)
    # Another worker took the job over (as after a reconciler re-queue and a new claim).
    with store.engine.begin() as conn:
        conn.execute(sa.update(jobs).where(jobs.c.id == job.id).values(lease_owner="w2"))
    t.join(10)
    assert out["status"] == "lost"
    after = store.get(job.id)
    assert after.status == "running" and after.lease_owner == "w2"
    assert (job_paths(settings, job.id)[1] / "checkpoints").is_dir()  # left for the new owner


def test_past_the_hard_time_limit_the_heartbeat_fails_the_job_and_ends_the_process(tmp_path: Path):
    # the pipeline is not listening any more, so the heartbeat thread itself ends the process
    import subprocess
    import sys

    code = f"""
import time
from pathlib import Path
from worker.runner import JobControl
from jobs.settings import Settings
from jobs.store import JobStore
settings = Settings(data_dir=Path({str(tmp_path / 'data')!r}), heartbeat_interval_s=0.1,
                    job_soft_time_limit_s=0.2, job_hard_time_limit_s=0.3)
store = JobStore.from_settings(settings)
job, _ = store.create_job(owner="o", spec={{}}, input_digest="x", input_name="s.h5", input_bytes=1, queue="cpu")
print(job.id, flush=True)
store.claim(job.id, "w1")
JobControl(store, settings, job, "w1").start()
time.sleep(30)
"""
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=root)
    assert proc.returncode == 70, proc.stderr[-2000:]
    job_id = proc.stdout.split()[0]
    store = JobStore.from_settings(Settings(data_dir=tmp_path / "data"))
    job = store.get(job_id)
    store.dispose()
    assert job.status == "failed" and "hard time limit of 0.3 s" in job.error
