"""End to end in distributed mode: real Redis, real Celery worker processes (`shsas worker`),
a real uvicorn API (`shsas serve` with SHSAS_BROKER_URL) and the job store on PostgreSQL."""

from __future__ import annotations

import contextlib
import io
import json
import signal
import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest
import trimesh

from .conftest import (
    FAST_TIMINGS,
    RESUMABLE_SPEC,
    db_env,
    start_server,
    start_worker,
    submit,
    wait_for,
)

pytestmark = pytest.mark.service

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
LONG_SPEC = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}

# how long a wait for a job's next state may take: the workers run at nice 10 (SHSAS_WORKER_NICE),
# so on a machine busy with other work a short job's stages take several times their idle
# length (one CI run beside a training job timed out at 60 s in the warm start); no speed is checked
WAIT_S = 240


@pytest.fixture(scope="module")
def cluster(tmp_path_factory, pg_url, redis_url):
    tmp = tmp_path_factory.mktemp("celery")
    run = uuid.uuid4().hex[:8]
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_BROKER_URL": redis_url,
           "SHSAS_GPU_QUEUE": f"gpu-{run}", "SHSAS_CPU_QUEUE": f"cpu-{run}",
           **FAST_TIMINGS, **db_env("postgres", pg_url)}
    api, base = start_server(tmp, env)
    state = {"env": env, "tmp": tmp, "base": base, "workers": [start_worker(tmp, env, "worker-1")]}
    yield state
    for w in state["workers"]:
        w.stop()
    api.stop()
    import redis

    r = redis.Redis.from_url(redis_url)
    ours = {env["SHSAS_GPU_QUEUE"], env["SHSAS_CPU_QUEUE"]}
    r.delete(*ours, "shsas:broker-mark")
    # The killed worker's message waits in kombu's unacked hash until its visibility timeout;
    # drop ours so no later consumer of this database restores it.
    for tag, raw in r.hgetall("unacked").items():
        with contextlib.suppress(ValueError, IndexError, TypeError):
            if json.loads(raw)[0]["properties"]["delivery_info"]["routing_key"] in ours:
                r.hdel("unacked", tag)
                r.zrem("unacked_index", tag)
    r.close()


@pytest.fixture
def client(cluster):
    with httpx.Client(base_url=cluster["base"], timeout=30) as c:
        yield c


def test_readyz_sees_store_and_broker(client) -> None:
    r = client.get("/readyz")
    assert r.status_code == 200 and r.json()["checks"] == {"job_store": "ok", "broker": "ok"}


def test_celery_job_succeeds_and_meshes_load(client, cluster, survey_file) -> None:
    job = submit(client, survey_file, QUICK_SPEC).json()
    done = wait_for(client, job["id"], lambda j: j["status"] in ("succeeded", "failed"), WAIT_S,
                    "the Celery worker to finish the job")
    assert done["status"] == "succeeded", (done, cluster["workers"][0].tail())
    assert done["attempts"] == 1
    for suffix, ftype in (("_mesh.glb", "glb"), ("_mesh.ply", "ply")):
        name = next(a["name"] for a in done["artifacts"] if a["name"].endswith(suffix))
        body = client.get(f"/reconstructions/{job['id']}/artifacts/{name}").content
        mesh = trimesh.load(io.BytesIO(body), file_type=ftype, force="mesh")
        assert len(mesh.faces) > 0 and np.all(np.isfinite(mesh.vertices))
    # CUDA may only be initialised in the pool child: the worker's main process never loads torch.
    maps = Path(f"/proc/{cluster['workers'][0].pid}/maps").read_text()
    assert "libtorch" not in maps and "libcuda" not in maps


def test_celery_cancel(client, cluster, survey_file) -> None:
    job = submit(client, survey_file, LONG_SPEC).json()
    wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] > 0, WAIT_S, "job to run")
    client.post(f"/reconstructions/{job['id']}/cancel")
    done = wait_for(client, job["id"], lambda j: j["status"] != "running", 5, "cancel to land")
    assert done["status"] == "cancelled"
    assert client.get(f"/reconstructions/{job['id']}/artifacts").json()["items"] == []
    assert not (Path(cluster["env"]["SHSAS_DATA_DIR"]) / "jobs" / job["id"] / "out").exists()


def test_sigkill_worker_mid_job_then_restart_resumes(client, cluster, survey_file) -> None:
    job = submit(client, survey_file, RESUMABLE_SPEC).json()
    wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] >= 0.25, WAIT_S,
             "job to be well under way")
    victim = cluster["workers"].pop()
    victim.signal_group(signal.SIGKILL)  # the whole worker: main process and pool child
    victim.stop()
    mid = client.get(f"/reconstructions/{job['id']}").json()
    assert mid["status"] == "running" and mid["attempts"] == 1
    cluster["workers"].append(start_worker(cluster["tmp"], cluster["env"], "worker-2"))
    done = wait_for(client, job["id"], lambda j: j["status"] in ("succeeded", "failed"), WAIT_S,
                    "the re-queued job to finish on the new worker")
    assert done["status"] == "succeeded", (done, cluster["workers"][-1].tail())
    assert done["attempts"] == 2
    names = [a["name"] for a in done["artifacts"]]
    assert len(names) == len(set(names)) and names
    out = cluster["tmp"] / "data" / "jobs" / job["id"] / "out"
    assert not list(out.rglob("*.tmp*"))  # no half-written files survive
    on_disk = sorted(p.name for p in out.iterdir() if p.is_file())
    assert on_disk == sorted(names)
    glb = next(n for n in names if n.endswith(".glb"))
    body = client.get(f"/reconstructions/{job['id']}/artifacts/{glb}").content
    assert len(trimesh.load(io.BytesIO(body), file_type="glb", force="mesh").faces) > 0


def test_broker_down_answers_503_and_fails_nothing_silently(tmp_path, survey_file) -> None:
    from .conftest import free_port

    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), "SHSAS_BROKER_URL": f"redis://127.0.0.1:{free_port()}/0",
           **FAST_TIMINGS}
    api, base = start_server(tmp_path, env)
    try:
        with httpx.Client(base_url=base, timeout=60) as c:
            ready = c.get("/readyz")
            assert ready.status_code == 503 and ready.json()["checks"]["broker"].startswith("error")
            r = submit(c, survey_file, QUICK_SPEC, **{"Idempotency-Key": "k"})
            assert r.status_code == 503 and "broker is unreachable" in r.json()["detail"]
            assert ready.headers["retry-after"].isdigit() and r.headers["retry-after"].isdigit()
            # Nothing is left queued forever: the job row says what happened.
            jobs = c.get("/reconstructions").json()["items"]
            assert [j["status"] for j in jobs] == ["failed"] and "broker" in jobs[0]["error"]
    finally:
        api.stop()
