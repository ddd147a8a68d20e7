"""End to end through the embedded default: one `shsas serve` process, no Redis.

A real uvicorn server in a subprocess (and its local worker child), driven over HTTP with httpx.
"""

from __future__ import annotations

import io
import json
import time
import uuid
from pathlib import Path

import h5py
import httpx
import numpy as np
import pytest
import trimesh

from shsas_core.evaluation.diagnostics import COLLAPSE_SPREAD_LIMIT

from .conftest import (
    FAST_TIMINGS,
    RESUMABLE_SPEC,
    db_env,
    start_server,
    submit,
    wait_for,
    write_tiny_survey,
)

pytestmark = pytest.mark.service

#: Small specs: quick to run with the stand-in and with the real pipeline.
QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
#: Long enough that a cancel always lands mid-run.
LONG_SPEC = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}
UPLOAD_CAP = 2_000_000
VALIDATE_MEMORY = 512 * 1024**2


@pytest.fixture(scope="module", params=["sqlite", "postgres"])
def server(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(f"embedded-{request.param}")
    pg = request.getfixturevalue("pg_url") if request.param == "postgres" else None
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_MAX_UPLOAD_BYTES": str(UPLOAD_CAP),
           "SHSAS_VALIDATE_MEMORY_BYTES": str(VALIDATE_MEMORY),
           **FAST_TIMINGS, **db_env(request.param, pg)}
    proc, base = start_server(tmp, env)
    yield {"base": base, "data": tmp / "data", "proc": proc, "backend": request.param}
    proc.stop()


@pytest.fixture
def client(server):
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        yield c


@pytest.fixture(scope="module")
def done_job(server):
    """One quick job run to success on this server (shared by the download tests)."""
    survey = write_tiny_survey(server["data"].parent / "tiny.h5")
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        r = submit(c, survey, QUICK_SPEC)
        assert r.status_code == 202, r.text
        done = wait_for(c, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 120,
                        "job to finish")
    return r, done


def test_upload_poll_download_meshes(client, done_job) -> None:
    r, done = done_job
    job = r.json()
    assert r.headers["location"] == f"/reconstructions/{job['id']}"
    assert job["status"] in ("queued", "running") and job["spec"]["grid"] == 16
    assert done["status"] == "succeeded", done
    assert done["progress"] == 1.0 and done["attempts"] == 1 and done["error"] is None
    assert done["started_at"] and done["finished_at"] and done["metrics"]
    assert isinstance(done["warnings"], list)
    assert done["device"] == "cpu"  # the device that ran it (the spec asks for the CPU)
    names = [a["name"] for a in done["artifacts"]]
    glb = next(n for n in names if n.endswith("_mesh.glb"))
    ply = next(n for n in names if n.endswith("_mesh.ply"))
    for name, ftype in ((glb, "glb"), (ply, "ply")):
        resp = client.get(f"/reconstructions/{job['id']}/artifacts/{name}")
        assert resp.status_code == 200
        loaded = trimesh.load(io.BytesIO(resp.content), file_type=ftype, force="mesh")
        assert len(loaded.faces) > 0 and np.all(np.isfinite(loaded.vertices))
    listing = client.get(f"/reconstructions/{job['id']}/artifacts").json()
    assert sorted(a["name"] for a in listing["items"]) == sorted(names)
    page = client.get("/reconstructions", params={"status": "succeeded"}).json()
    assert job["id"] in [j["id"] for j in page["items"]]
    assert client.get("/readyz").json()["checks"]["job_store"] == "ok"


def test_status_carries_the_warnings_of_a_failed_looking_result(client, server) -> None:
    silent = write_tiny_survey(server["data"].parent / "silent.h5", silent=True)  # backprojects to zeros
    r = submit(client, silent, QUICK_SPEC)
    assert r.status_code == 202, r.text
    assert r.json()["warnings"] == []
    done = wait_for(client, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 120, "job to finish")
    assert done["status"] == "succeeded", done  # the job ran; its result is flagged
    assert [(w["method"], w["code"], w["measure"], w["limit"]) for w in done["warnings"]] == [
        ("backprojection", "collapsed", 0.0, COLLAPSE_SPREAD_LIMIT)]
    assert "near-constant" in done["warnings"][0]["message"]
    assert set(done["metrics"]) == {"backprojection"}
    listed = client.get("/reconstructions", params={"status": "succeeded"}).json()["items"]
    assert next(j for j in listed if j["id"] == done["id"])["warnings"] == done["warnings"]


def test_artifact_range_etag_and_names(client, done_job) -> None:
    _, done = done_job
    job = done
    name = next(a["name"] for a in done["artifacts"] if a["name"].endswith(".glb"))
    url = f"/reconstructions/{job['id']}/artifacts/{name}"
    full = client.get(url)
    etag = full.headers["etag"]
    size = len(full.content)
    assert full.headers["content-type"] == "model/gltf-binary" and full.headers["accept-ranges"] == "bytes"
    assert client.get(url, headers={"If-None-Match": etag}).status_code == 304
    assert client.get(url, headers={"If-None-Match": '"other"'}).status_code == 200
    part = client.get(url, headers={"Range": "bytes=10-109"})
    assert part.status_code == 206 and part.content == full.content[10:110]
    assert part.headers["content-range"] == f"bytes 10-109/{size}"
    tail = client.get(url, headers={"Range": "bytes=-16"})
    assert tail.status_code == 206 and tail.content == full.content[-16:]
    assert client.get(url, headers={"Range": f"bytes={size + 10}-"}).status_code == 416
    assert client.get(url, headers={"Range": "bytes=0-9", "If-Range": '"stale"'}).status_code == 200
    # Names are server-made: anything not in the job's list is 404, paths included.
    for bad in ("shsas.db", "..%2F..%2Fshsas.db", "checkpoints", "nope.ply"):
        assert client.get(f"/reconstructions/{job['id']}/artifacts/{bad}").status_code == 404


def test_cancel_running_job_keeps_no_artifacts(client, server, survey_file: Path) -> None:
    job = submit(client, survey_file, LONG_SPEC).json()
    wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] > 0, 60, "job to run")
    t0 = time.monotonic()
    r = client.post(f"/reconstructions/{job['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"]
    done = wait_for(client, job["id"], lambda j: j["status"] != "running", 15, "cancel to land")
    assert done["status"] == "cancelled", done
    assert time.monotonic() - t0 < 5.0  # the runner polls the flag between pipeline steps
    assert client.get(f"/reconstructions/{job['id']}/artifacts").json()["items"] == []
    out = server["data"] / "jobs" / job["id"] / "out"
    assert not out.exists() or not [p for p in out.rglob("*") if p.is_file()]
    # Cancelling again is harmless; a queued job cancels at once.
    assert client.post(f"/reconstructions/{job['id']}/cancel").json()["status"] == "cancelled"


def test_idempotency_key(client, survey_file: Path, tmp_path: Path) -> None:
    key = uuid.uuid4().hex
    a = submit(client, survey_file, QUICK_SPEC, **{"Idempotency-Key": key})
    b = submit(client, survey_file, QUICK_SPEC, **{"Idempotency-Key": key})
    assert a.status_code == b.status_code == 202 and a.json()["id"] == b.json()["id"]
    c = submit(client, survey_file, {**QUICK_SPEC, "grid": 20}, **{"Idempotency-Key": key})
    assert c.status_code == 409 and "Idempotency-Key" in c.json()["detail"]
    other = write_tiny_survey(tmp_path / "other.h5", seed=5)
    d = submit(client, other, QUICK_SPEC, **{"Idempotency-Key": key})
    assert d.status_code == 409
    client.post(f"/reconstructions/{a.json()['id']}/cancel")  # no backlog for the next tests


def test_list_pagination(client, survey_file: Path) -> None:
    ids = [submit(client, survey_file, {**QUICK_SPEC, "seed": i}).json()["id"] for i in range(3)]
    seen, cursor = [], None
    for _ in range(20):
        params = {"limit": 2, **({"cursor": cursor} if cursor else {})}
        page = client.get("/reconstructions", params=params).json()
        seen += [j["id"] for j in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert seen[:3] == ids[::-1] and len(seen) == len(set(seen))
    assert client.get("/reconstructions", params={"cursor": "garbage!"}).status_code == 400
    assert client.get("/reconstructions", params={"status": "bogus"}).status_code == 400
    for job_id in ids:
        client.post(f"/reconstructions/{job_id}/cancel")


# ---- bad uploads: every one a 4xx naming the problem, never a 500 ------------------------------

def _h5_variant(path: Path, base: Path, edit) -> Path:
    path.write_bytes(base.read_bytes())
    with h5py.File(path, "a") as f:
        edit(f)
    return path


def _bad_cases(tmp: Path, good: Path) -> list[tuple[str, dict, int, str]]:
    """(name, request kwargs, expected status, word the message must contain)."""
    def files(p: Path | bytes, name="s.h5"):
        return {"survey": (name, p.read_bytes() if isinstance(p, Path) else p, "application/octet-stream")}

    spec = {"spec": json.dumps(QUICK_SPEC)}
    text = tmp / "notes.txt"
    text.write_text("this is not a survey\n" * 50)
    truncated = good.read_bytes()[: len(good.read_bytes()) // 2]

    def wrong_shape(f):
        del f["pings/tx"]
        f["pings/tx"] = np.zeros((f["pings/rx"].shape[0], 2))

    def nan_samples(f):
        s = f["pings/samples"][()]
        s[3, 7] = np.nan
        f["pings/samples"][...] = s

    def nan_positions(f):
        tx = f["pings/tx"][()]
        tx[1, 0] = np.nan
        f["pings/tx"][...] = tx

    def external(f):
        f["pings/extra"] = h5py.ExternalLink("/etc/passwd", "/data")

    def bomb(f):
        # 240 MB of vertices in a ~20 kB file (never-written gzip chunks read as the fill value).
        g = f.create_group("ground_truth")
        for name, dtype in (("vertices", "f8"), ("faces", "i8")):
            g.create_dataset(name, shape=(10_000_000, 3), dtype=dtype, chunks=(1 << 18, 3),
                             compression="gzip", fillvalue=0)

    return [
        ("not hdf5", {"files": files(text, "notes.txt"), "data": spec}, 422, "not a recognised survey"),
        ("truncated", {"files": files(truncated), "data": spec}, 422, "truncated"),
        ("wrong shapes", {"files": files(_h5_variant(tmp / "shape.h5", good, wrong_shape)), "data": spec},
         422, "pings/tx"),
        ("nan samples", {"files": files(_h5_variant(tmp / "nan.h5", good, nan_samples)), "data": spec},
         422, "NaN"),
        ("nan positions", {"files": files(_h5_variant(tmp / "nanpos.h5", good, nan_positions)), "data": spec},
         422, "non-finite"),
        ("external link", {"files": files(_h5_variant(tmp / "ext.h5", good, external)), "data": spec},
         422, "external link"),
        # refused from the mesh's declared shape, before the validator reads (and runs out of) memory
        ("decompression bomb", {"files": files(_h5_variant(tmp / "bomb.h5", good, bomb)), "data": spec},
         413, "SHSAS_MAX_GROUND_TRUTH_ELEMENTS"),
        ("over size cap", {"files": files(b"\x89HDF\r\n\x1a\n" + bytes(UPLOAD_CAP + 1000)), "data": spec},
         413, "SHSAS_MAX_UPLOAD_BYTES"),
        ("empty file", {"files": files(b""), "data": spec}, 422, "empty"),
        ("spec out of range", {"files": files(good), "data": {"spec": json.dumps({"grid": 100000})}},
         422, "spec.grid"),
        ("unknown method", {"files": files(good), "data": {"spec": json.dumps({"methods": ["magic"]})}},
         422, "spec.methods"),
        ("unknown spec key", {"files": files(good), "data": {"spec": json.dumps({"gird": 16})}}, 422, "gird"),
        ("spec not json", {"files": files(good), "data": {"spec": "{grid: 16"}}, 422, "spec"),
        ("no survey part", {"data": spec, "files": {"other": ("x", b"123", "text/plain")}}, 422, "survey"),
        ("not multipart", {"json": QUICK_SPEC}, 415, "multipart"),
    ]


def test_bad_uploads_all_4xx_with_message(client, server, survey_file: Path, tmp_path: Path) -> None:
    if server["backend"] != "sqlite":
        pytest.skip("upload validation does not depend on the job store; run once")
    problems = []
    for name, kwargs, status, word in _bad_cases(tmp_path, survey_file):
        r = client.post("/reconstructions", **kwargs)
        detail = r.json().get("detail") if r.headers.get("content-type", "").startswith("application/json") else r.text
        if r.status_code >= 500 or r.status_code != status or word.lower() not in str(detail).lower():
            problems.append(f"{name}: {r.status_code} {detail!r}")
    assert not problems, "\n".join(problems)
    # Nothing half-uploaded is left behind.
    uploads = server["data"] / "uploads"
    assert not uploads.exists() or not any(uploads.iterdir())


def _local_worker_pid(serve_pid: int) -> int:
    """The spawn child of `shsas serve` that runs jobs (not multiprocessing's resource tracker)."""
    for task in Path(f"/proc/{serve_pid}/task").iterdir():
        for pid in (task / "children").read_text().split():
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
            if b"spawn_main" in cmd:
                return int(pid)
    raise AssertionError("no local worker child found")


@pytest.mark.slow
def test_local_worker_killed_mid_job_is_restarted_and_job_resumes(client, server, survey_file: Path) -> None:
    if server["backend"] != "sqlite":
        pytest.skip("same code path on both stores; run once")
    import os
    import signal

    job = submit(client, survey_file, RESUMABLE_SPEC).json()
    wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] >= 0.25, 90, "job under way")
    victim = _local_worker_pid(server["proc"].pid)
    os.kill(victim, signal.SIGKILL)
    done = wait_for(client, job["id"], lambda j: j["status"] in ("succeeded", "failed"), 120,
                    "the supervisor's new local worker to finish the job")
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    assert _local_worker_pid(server["proc"].pid) != victim
    out = server["data"] / "jobs" / job["id"] / "out"
    assert not list(out.rglob("*.tmp*"))
    names = [a["name"] for a in done["artifacts"]]
    assert sorted(names) == sorted(p.name for p in out.iterdir() if p.is_file())
