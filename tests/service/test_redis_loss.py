"""Queued jobs survive a broker that loses its messages.

A Redis of this test's own (no persistence, like the one that lost the jobs), a real
`shsas serve` API with its reconciler, a real Celery worker (`shsas worker`) and the job store on
PostgreSQL. Restarting that Redis empties it: the queued jobs' messages are gone, and every job
must still complete, exactly once.
"""

from __future__ import annotations

import shutil
import time
import uuid
from pathlib import Path

import httpx
import pytest

from .conftest import (
    FAST_TIMINGS,
    Proc,
    db_env,
    free_port,
    port_open,
    start_server,
    start_worker,
    submit,
    wait_for,
    write_tiny_survey,
)

pytestmark = [pytest.mark.service, pytest.mark.slow]

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
#: Holds the only worker busy while other jobs wait in Redis; cancelled once Redis is restarted.
BLOCKER_SPEC = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}


class OwnRedis:
    """A redis-server on a free port, without RDB or AOF, restartable on the same port."""

    def __init__(self, tmp: Path):
        self.tmp, self.port = tmp, free_port()
        self.proc: Proc | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.proc = Proc(["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
                          "--appendonly", "no", "--dir", str(self.tmp)], {}, self.tmp / "redis.log")
        deadline = time.monotonic() + 10
        while not port_open("127.0.0.1", self.port):
            assert time.monotonic() < deadline and self.proc.alive(), self.proc.tail()
            time.sleep(0.05)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.stop()
            self.proc = None

    def restart(self) -> None:
        self.stop()
        self.start()


@pytest.fixture
def cluster(tmp_path: Path, pg_url):
    if shutil.which("redis-server") is None:
        pytest.skip("redis-server is not installed")
    redis = OwnRedis(tmp_path)
    redis.start()
    run = uuid.uuid4().hex[:8]
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), "SHSAS_BROKER_URL": redis.url,
           "SHSAS_GPU_QUEUE": f"gpu-{run}", "SHSAS_CPU_QUEUE": f"cpu-{run}", **FAST_TIMINGS,
           # No worker dies here: a long lease keeps a busy machine's late heartbeats from
           # re-queueing a running job, which would add attempts and messages of its own.
           "SHSAS_LEASE_TIMEOUT_S": "120", **db_env("postgres", pg_url)}
    procs: list[Proc] = []
    try:
        api, base = start_server(tmp_path, env)
        procs.append(api)
        yield {"env": env, "tmp": tmp_path, "base": base, "redis": redis, "procs": procs}
    finally:
        for p in procs:
            p.stop()
        redis.stop()


def _queue_lengths(redis_url: str, env: dict[str, str]) -> int:
    import redis

    r = redis.Redis.from_url(redis_url)
    try:
        return sum(r.llen(env[k]) for k in ("SHSAS_GPU_QUEUE", "SHSAS_CPU_QUEUE"))
    finally:
        r.close()


def _set_sentinel(redis_url: str) -> None:
    import redis

    with redis.Redis.from_url(redis_url) as r:
        r.set("test:sentinel", "1")


def _has_sentinel(redis_url: str) -> bool:
    import redis

    with redis.Redis.from_url(redis_url) as r:
        return bool(r.exists("test:sentinel"))


def test_queued_jobs_survive_a_redis_restart_and_run_once(cluster) -> None:
    env, redis = cluster["env"], cluster["redis"]
    # SHSAS_REDISPATCH_AFTER_S keeps its default (600 s): what saves the jobs here must be the
    # reconciler noticing the emptied broker, not the age-based re-send.
    cluster["procs"].append(worker := start_worker(cluster["tmp"], env))
    with httpx.Client(base_url=cluster["base"], timeout=30) as c:
        blocker = submit(c, _survey(cluster), BLOCKER_SPEC).json()
        wait_for(c, blocker["id"], lambda j: j["status"] == "running" and j["progress"] > 0, 90,
                 f"the blocker job to run\n{worker.tail()}")
        stranded = [submit(c, _survey(cluster), {**QUICK_SPEC, "seed": i}).json()["id"] for i in range(2)]
        # both wait in Redis behind the blocker; a reconciler pass that finds the fresh Redis
        # without its mark key may already have re-sent one (runs stay single through the claim,
        # which the end of this test checks), so a duplicate message is allowed here
        assert _queue_lengths(redis.url, env) >= 2
        _set_sentinel(redis.url)
        redis.restart()  # no RDB, no AOF: it comes back empty
        # (The queues may already hold messages again: the worker restores the blocker's, the
        # reconciler re-sends; the sentinel shows the restart really lost everything.)
        assert not _has_sentinel(redis.url)
        c.post(f"/reconstructions/{blocker['id']}/cancel")
        later = submit(c, _survey(cluster), {**QUICK_SPEC, "seed": 9}).json()["id"]
        done = [wait_for(c, job_id, lambda j: j["status"] in ("succeeded", "failed"), 120,
                         f"job {job_id} to finish\n{worker.tail()}") for job_id in [*stranded, later]]
    for job in done:
        # attempts counts successful claims: 1 = the job ran exactly once, whatever the duplicates.
        assert job["status"] == "succeeded" and job["attempts"] == 1, job
    runs = [line for line in worker.log.read_text().splitlines() if " attempt " in line]
    for job in done:
        assert sum(job["id"] in line for line in runs) == 1, runs


def test_lost_message_is_resent_after_redispatch_after_s(cluster) -> None:
    """A message lost without emptying Redis (the mark survives): the age-based re-send."""
    import redis as redis_lib

    env, redis = cluster["env"], cluster["redis"]
    api_env = {**env, "SHSAS_REDISPATCH_AFTER_S": "2"}
    cluster["procs"][0].stop()
    api, base = start_server(cluster["tmp"], api_env, name="api-2")
    cluster["procs"].append(api)
    with httpx.Client(base_url=base, timeout=30) as c:
        job_id = submit(c, _survey(cluster), QUICK_SPEC).json()["id"]
        r = redis_lib.Redis.from_url(redis.url)
        try:
            r.delete(env["SHSAS_GPU_QUEUE"], env["SHSAS_CPU_QUEUE"])  # the message is gone
            deadline = time.monotonic() + 20
            while _queue_lengths(redis.url, env) == 0:
                assert time.monotonic() < deadline, f"job {job_id} was never re-sent\n{api.tail()}"
                time.sleep(0.2)
            time.sleep(1.0)  # two more reconciler passes: no second message before 2 s are up again
            assert _queue_lengths(redis.url, env) == 1
        finally:
            r.close()
        cluster["procs"].append(worker := start_worker(cluster["tmp"], env))
        job = wait_for(c, job_id, lambda j: j["status"] in ("succeeded", "failed"), 120,
                       f"the re-sent job to finish\n{worker.tail()}")
    assert job["status"] == "succeeded" and job["attempts"] == 1, job


def _survey(cluster) -> Path:
    path = cluster["tmp"] / "tiny.h5"
    return path if path.exists() else write_tiny_survey(path)
