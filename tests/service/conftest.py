"""Fixtures for the service tests: real PostgreSQL/Redis, real server and worker processes.

Every run gets its own data dir, PostgreSQL schema, Redis database number, Celery queue
names and TCP ports, so parallel runs on one machine do not collide. Every process started
here runs in its own session and is killed (whole process group) by its fixture's finalizer.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from shsas_core.formats.hdf5 import write_survey
from tests.conftest import make_survey

REPO = Path(__file__).resolve().parents[2]
PG_URL = os.environ.get("SHSAS_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
REDIS_URL = os.environ.get("SHSAS_TEST_REDIS_URL", "redis://127.0.0.1:6379")

#: Fast lease/heartbeat timings so lost-worker recovery fits in a test.
FAST_TIMINGS = {
    "SHSAS_HEARTBEAT_INTERVAL_S": "0.5",
    "SHSAS_LEASE_TIMEOUT_S": "3",
    "SHSAS_RECONCILE_INTERVAL_S": "0.5",
    "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2",
}

#: A job that runs a few seconds, so a worker can be killed mid-job and the job still finish soon
#: after. No warm start: its fixed budget (300 steps of 32k points) is a minute on two cores at
#: any grid, paid again by the second attempt; resuming does not depend on how the field started.
RESUMABLE_SPEC = {"methods": ["reed"], "iters": 200, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8,
                  "init": "none"}

#: How long the console tests wait for `shsas serve` to answer (imports take long on loaded cores).
SERVER_START_S = 180


def port_open(host: str, port: int) -> bool:
    with contextlib.closing(socket.socket()) as s:
        s.settimeout(0.5)
        return s.connect_ex((host, port)) == 0


def free_port() -> int:
    with contextlib.closing(socket.socket()) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def pg_url() -> Iterator[str]:
    """A PostgreSQL URL plus a fresh schema name, dropped at the end: yields 'url#schema'."""
    if not port_open("127.0.0.1", 5432):
        pytest.skip("PostgreSQL is not reachable on 127.0.0.1:5432")
    import sqlalchemy as sa

    schema = f"shsas_test_{uuid.uuid4().hex[:10]}"
    yield f"{PG_URL}#{schema}"
    eng = sa.create_engine(PG_URL)
    with eng.begin() as conn:
        # db_env() and the store tests derive one schema per use: <schema>_<suffix>.
        names = conn.execute(sa.text("SELECT schema_name FROM information_schema.schemata "
                                     "WHERE schema_name = :s OR schema_name LIKE :p"),
                             {"s": schema, "p": schema + "\\_%"}).scalars().all()
        for name in names:
            conn.execute(sa.text(f'DROP SCHEMA IF EXISTS "{name}" CASCADE'))
    eng.dispose()


@pytest.fixture(scope="session")
def redis_url() -> str:
    """A Redis URL on a database number picked per run (queues are unique per run as well)."""
    if not port_open("127.0.0.1", 6379):
        pytest.skip("Redis is not reachable on 127.0.0.1:6379")
    return f"{REDIS_URL}/{1 + uuid.uuid4().int % 15}"


def db_env(backend: str, pg: str | None) -> dict[str, str]:
    if backend == "sqlite":
        return {}
    assert pg is not None
    url, schema = pg.split("#")
    # A schema per backend use inside the run: the keys table must start empty for each server.
    return {"SHSAS_DATABASE_URL": url, "SHSAS_DATABASE_SCHEMA": f"{schema}_{uuid.uuid4().hex[:6]}"}


def write_tiny_survey(path: Path, silent: bool = False, **kw) -> Path:
    """A small random survey (``silent``: all samples zero, a recording with the transmitter off)."""
    survey = make_survey(**kw)
    if silent:
        survey = dataclasses.replace(survey, samples=np.zeros_like(survey.samples))
    write_survey(survey, path)
    return path


@pytest.fixture
def survey_file(tmp_path: Path) -> Path:
    return write_tiny_survey(tmp_path / "tiny.h5")


class Proc:
    """A subprocess in its own process group, with its output in a log file."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path, cwd: Path = REPO):
        self.args, self.log = args, log
        full_env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1", **env}
        self._fh = open(log, "ab")
        self.p = subprocess.Popen(args, env=full_env, cwd=cwd, stdout=self._fh, stderr=subprocess.STDOUT,
                                  start_new_session=True)

    @property
    def pid(self) -> int:
        return self.p.pid

    def alive(self) -> bool:
        return self.p.poll() is None

    def signal_group(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.p.pid, sig)

    def stop(self, timeout: float = 10.0) -> None:
        if self.alive():
            self.signal_group(signal.SIGTERM)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                pass
        # Children (pool workers, local worker) may outlive the leader: always clear the group.
        self.signal_group(signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.p.wait(5)
        self._fh.close()

    def tail(self, n: int = 60) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


SHSAS = [sys.executable, "-m", "shsas_core.cli"]


def start_server(tmp: Path, env: dict[str, str], name: str = "api", log_level: str = "warning",
                 timeout: float = 180, args: tuple[str, ...] = (), wrap: tuple[str, ...] = ()) -> tuple[Proc, str]:
    """``shsas serve`` on a free port (``args``: more options; ``wrap``: a command it runs under,
    e.g. ``prlimit --nofile=...``); returns the process and its base URL once /healthz answers."""
    port = free_port()
    proc = Proc([*wrap, *SHSAS, "serve", "--host", "127.0.0.1", "--port", str(port), "--log-level", log_level,
                 *args], env, tmp / f"{name}.log")
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout  # a niced start on two loaded cores can take a minute
    while time.monotonic() < deadline:
        if not proc.alive():
            raise RuntimeError(f"server exited early:\n{proc.tail()}")
        try:
            if httpx.get(base + "/healthz", timeout=1).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.stop()
    raise RuntimeError(f"server did not come up:\n{proc.tail()}")


def start_worker(tmp: Path, env: dict[str, str], name: str = "worker") -> Proc:
    return Proc([*SHSAS, "worker", "--log-level", "info", "--no-reconcile"], env, tmp / f"{name}.log")


def wait_for(client: httpx.Client, job_id: str, pred, timeout: float, what: str) -> dict:
    """Poll the job until ``pred(job)``; fail with the job's state after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    job: dict = {}
    while time.monotonic() < deadline:
        job = client.get(f"/reconstructions/{job_id}").json()
        if pred(job):
            return job
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}; job: {job}")


def submit(client: httpx.Client, survey: Path, spec: dict | None, **headers) -> httpx.Response:
    import json

    files = {"survey": (survey.name, survey.read_bytes(), "application/octet-stream")}
    data = {"spec": json.dumps(spec)} if spec is not None else {}
    return client.post("/reconstructions", files=files, data=data, headers=headers)


def write_demo_survey(path: Path) -> Path:
    """A small simulated survey of a sphere (10 x 90 pings), with ground truth: a backprojection
    at grid 32 shows the shape in seconds (the console tests' demo survey)."""
    from shsas_core.simulation.simulate import simulate_shape

    write_survey(simulate_shape("sphere", heights=10, angles=90, snr_db=20.0, seed=0), path)
    return path
