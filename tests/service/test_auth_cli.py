"""API keys end to end (`shsas keys` against a running server), the loopback-only default,
the CLI surface, and the rule that shsas_core never imports the web or queue stacks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from .conftest import FAST_TIMINGS, REPO, SHSAS, start_server, submit

pytestmark = pytest.mark.service

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}


def shsas(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    import os

    return subprocess.run([*SHSAS, *args], env={**os.environ, "PYTHONPATH": str(REPO), **env},
                          capture_output=True, text=True, timeout=60, cwd=REPO)


def test_keys_own_jobs_and_revocation(tmp_path, survey_file) -> None:
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), **FAST_TIMINGS}
    proc, base = start_server(tmp_path, env)
    try:
        with httpx.Client(base_url=base, timeout=30) as c:
            # No keys yet: a loopback client is served as the local owner.
            assert submit(c, survey_file, QUICK_SPEC).status_code == 202
            out_a = shsas(env, "keys", "create", "alice")
            out_b = shsas(env, "keys", "create", "bob")
            assert out_a.returncode == 0, out_a.stderr
            key_a, key_b = out_a.stdout.strip().splitlines()[-1], out_b.stdout.strip().splitlines()[-1]
            # With keys configured, a key is required even on loopback.
            r = c.get("/reconstructions")
            assert r.status_code == 401 and "API key required" in r.json()["detail"]
            assert c.get("/reconstructions", headers={"Authorization": "Bearer shsas_x_y"}).status_code == 401
            ha, hb = {"Authorization": f"Bearer {key_a}"}, {"X-API-Key": key_b}
            job = submit(c, survey_file, QUICK_SPEC, **ha).json()
            assert c.get(f"/reconstructions/{job['id']}", headers=ha).status_code == 200
            # Another key sees nothing of it: 404, not 403, so ids do not leak.
            for method, path in (("GET", ""), ("POST", "/cancel"), ("GET", "/artifacts")):
                assert c.request(method, f"/reconstructions/{job['id']}{path}", headers=hb).status_code == 404
            assert c.get("/reconstructions", headers=hb).json()["items"] == []
            assert [j["id"] for j in c.get("/reconstructions", headers=ha).json()["items"]] == [job["id"]]
            listed = shsas(env, "keys", "list")
            assert "alice" in listed.stdout and "bob" in listed.stdout and key_a not in listed.stdout
            key_id = key_a.split("_")[1]
            assert shsas(env, "keys", "revoke", key_id).returncode == 0
            assert c.get("/reconstructions", headers=ha).status_code == 401
            again = shsas(env, "keys", "revoke", key_id)
            assert again.returncode == 2 and "no active key" in again.stderr and "Traceback" not in again.stderr
    finally:
        proc.stop()


@pytest.mark.filterwarnings("ignore:Using `httpx` with `starlette.testclient`")
def test_keyless_default_refuses_non_loopback_clients(tmp_path) -> None:
    from starlette.testclient import TestClient

    from jobs.settings import Settings
    from service.app import create_app

    app = create_app(Settings(data_dir=tmp_path / "d"), reconcile=False)
    with TestClient(app, client=("192.0.2.7", 5555)) as remote, TestClient(app, client=("127.0.0.1", 5555)) as local:
        r = remote.get("/reconstructions")
        assert r.status_code == 401 and "loopback" in r.json()["detail"]
        assert local.get("/reconstructions").status_code == 200
        assert remote.get("/healthz").status_code == 200  # probes need no key
        assert "/reconstructions" in local.get("/openapi.json").json()["paths"]


def test_cli_help_and_errors(tmp_path) -> None:
    for cmd in (["serve", "--help"], ["worker", "--help"], ["keys", "--help"]):
        r = shsas({}, *cmd)
        assert r.returncode == 0 and "SHSAS_" in r.stdout
    r = shsas({"SHSAS_DATA_DIR": str(tmp_path)}, "worker")
    assert r.returncode == 2 and "SHSAS_BROKER_URL is not set" in r.stderr and "Traceback" not in r.stderr


def test_shsas_core_does_not_import_web_or_queue_stacks() -> None:
    # shsas_core never imports jobs, service or worker (also the import contract of `make test`); the
    # full parser loads their commands through entry points, which must stay import-light
    code = ("import sys, shsas_core, shsas_core.cli, shsas_core.pipeline.job;"
            "early = [m for m in ('jobs', 'service', 'worker') if m in sys.modules];"
            "from shsas_core.cli import build_parser; p = build_parser();"
            "bad = early + [m for m in ('fastapi', 'celery', 'starlette', 'uvicorn', 'sqlalchemy')"
            " if m in sys.modules];"
            "sub = next(a for a in p._actions if a.dest == 'command');"
            "missing = [c for c in ('serve', 'worker', 'keys') if c not in sub.choices];"
            "print(bad, missing); sys.exit(1 if bad or missing else 0)")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                       env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stdout + r.stderr


def test_import_contract_holds() -> None:
    # import-linter's contracts in pyproject.toml, as `make test` runs them
    r = subprocess.run([str(Path(sys.executable).with_name("lint-imports"))], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "0 broken" in r.stdout, r.stdout + r.stderr


def test_the_api_process_loads_neither_torch_nor_h5py() -> None:
    # the API never opens survey content and never computes: importing the app (every router
    # included) must not pull in the science's compute stack
    code = ("import sys, service.app;"
            "bad = [m for m in ('torch', 'h5py', 'trimesh', 'celery') if m in sys.modules];"
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                       env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stdout + r.stderr
