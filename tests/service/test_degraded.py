"""The API with its job store down: a PostgreSQL of the test's own (initdb + pg_ctl into a temp
folder, on its own port; the machine's shared server is never touched) is stopped under a real
`shsas serve`, every route that needs the store answers 503 JSON ``{detail}`` with Retry-After
(never a bare 500), and once the database is back the same job answers 200 again."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from .conftest import free_port, port_open, start_server, submit, wait_for, write_tiny_survey

pytestmark = [pytest.mark.service, pytest.mark.slow]

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}


def _pg_bin() -> Path | None:
    found = sorted(Path("/usr/lib/postgresql").glob("*/bin/pg_ctl"))
    return found[-1].parent if found else None


class OwnPostgres:
    """A throw-away PostgreSQL cluster run as the ``postgres`` user (initdb refuses root)."""

    def __init__(self, bin_dir: Path, root: Path, port: int):
        self.bin, self.root, self.port = bin_dir, root, port
        self.data = root / "data"

    def _run(self, *args: str) -> None:
        cmd = [str(self.bin / args[0]), *args[1:]]
        if os.geteuid() == 0:
            cmd = ["runuser", "-u", "postgres", "--", *cmd]
        subprocess.run(cmd, check=True, capture_output=True, timeout=120)

    def init(self) -> None:
        self._run("initdb", "-D", str(self.data), "-U", "postgres", "--auth=trust", "-E", "UTF8")

    def start(self) -> None:
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.root / "pg.log"), "-w", "-t", "60", "start",
                  "-o", f"-p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c fsync=off")

    def stop(self) -> None:
        self._run("pg_ctl", "-D", str(self.data), "-m", "fast", "-w", "-t", "60", "stop")

    @property
    def url(self) -> str:
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/postgres"


@pytest.fixture
def own_pg() -> Iterator[OwnPostgres]:
    bin_dir = _pg_bin()
    if bin_dir is None or (os.geteuid() == 0 and shutil.which("runuser") is None):
        pytest.skip("no PostgreSQL server binaries (initdb, pg_ctl) to start a private cluster")
    root = Path(tempfile.mkdtemp(prefix="shsas-pg-"))
    if os.geteuid() == 0:
        shutil.chown(root, "postgres", "postgres")
    pg = OwnPostgres(bin_dir, root, free_port())
    pg.init()
    pg.start()
    try:
        yield pg
    finally:
        with contextlib.suppress(subprocess.SubprocessError):
            pg.stop()
        shutil.rmtree(root, ignore_errors=True)


def test_job_store_down_gives_503_json_with_retry_after_then_recovers(own_pg, tmp_path) -> None:
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), "SHSAS_DATABASE_URL": own_pg.url,
           "SHSAS_HEARTBEAT_INTERVAL_S": "0.5", "SHSAS_LEASE_TIMEOUT_S": "30",
           "SHSAS_RECONCILE_INTERVAL_S": "0.5", "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"}
    survey = write_tiny_survey(tmp_path / "tiny.h5")
    proc, base = start_server(tmp_path, env, name="degraded")
    try:
        with httpx.Client(base_url=base, timeout=60) as c:
            r = submit(c, survey, QUICK_SPEC)
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
            wait_for(c, job_id, lambda j: j["status"] == "succeeded", 300, "the job to finish")

            own_pg.stop()
            assert not port_open("127.0.0.1", own_pg.port)
            job = f"/reconstructions/{job_id}"
            routes = [("GET", "/reconstructions"), ("GET", job), ("HEAD", job), ("POST", job + "/cancel"),
                      ("GET", job + "/artifacts"), ("GET", job + "/artifacts/report.json"),
                      ("HEAD", job + "/artifacts/report.json"), ("GET", job + "/survey"),
                      ("GET", job + "/extract?method=backprojection&threshold=0.4"),
                      ("GET", "/readyz"), ("HEAD", "/readyz"), ("DELETE", job)]
            answers = {f"{m} {p}": c.request(m, p) for m, p in routes}
            answers["POST /reconstructions"] = submit(c, survey, QUICK_SPEC)
            for name, resp in answers.items():
                assert resp.status_code == 503, f"{name}: {resp.status_code} {resp.text[:200]}"
                assert resp.headers.get("retry-after", "").isdigit(), f"{name}: {dict(resp.headers)}"
                if not name.startswith("HEAD"):
                    assert resp.headers["content-type"].startswith("application/json"), name
                    body = resp.json()
                    assert "job store" in body["detail"], f"{name}: {body}"
            assert c.get("/healthz").status_code == 200  # liveness does not need the store

            own_pg.start()
            deadline = time.monotonic() + 60
            while c.get(job).status_code != 200 and time.monotonic() < deadline:
                time.sleep(0.5)
            back = c.get(job)
            assert back.status_code == 200 and back.json()["status"] == "succeeded"
            assert c.get("/readyz").status_code == 200
        assert proc.alive()
    finally:
        proc.stop()
