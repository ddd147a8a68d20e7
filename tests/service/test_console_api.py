"""The API routes made for the console, over HTTP against a real `shsas serve`: re-extraction
at another iso level, the survey view, the spec schema, and the page itself."""

from __future__ import annotations

import io
import json

import httpx
import numpy as np
import pytest
import trimesh

from shsas_core.outputs.export import read_point_cloud_ply
from shsas_core.spec.job import ReconstructionSpec

from .conftest import SERVER_START_S, start_server, submit, wait_for, write_demo_survey

pytestmark = pytest.mark.service

DEMO_SPEC = {"methods": ["backprojection"], "grid": 32, "device": "cpu"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console-api")
    proc, base = start_server(tmp, {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"},
                              timeout=SERVER_START_S)
    yield {"base": base, "tmp": tmp, "data": tmp / "data"}
    proc.stop()


@pytest.fixture(scope="module")
def client(server):
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        yield c


@pytest.fixture(scope="module")
def done(server, client) -> dict:
    r = submit(client, write_demo_survey(server["tmp"] / "demo.h5"), DEMO_SPEC)
    assert r.status_code == 202, r.text
    job = wait_for(client, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 180, "job to finish")
    assert job["status"] == "succeeded", job
    return job


def test_reextract_at_other_levels_changes_the_geometry(client, done, server) -> None:
    report = client.get(f"/reconstructions/{done['id']}/artifacts/report.json").json()
    tau0 = next(m for m in report["methods"] if m["method"] == "backprojection")["threshold"]
    url = f"/reconstructions/{done['id']}/extract"
    low = client.get(url, params={"method": "backprojection", "threshold": 0.1})
    high = client.get(url, params={"method": "backprojection", "threshold": 0.6})
    assert low.status_code == high.status_code == 200, (low.text, high.text)
    lo, hi = low.json(), high.json()
    assert lo["threshold"] == 0.1 and hi["threshold"] == 0.6
    assert lo["points"] > hi["points"] > 0 and lo["faces"] > 0
    # the job's own level reproduces the job's own point cloud
    same = client.get(url, params={"method": "backprojection", "threshold": round(tau0, 3)}).json()
    assert abs(same["points"] - report_points(report)) <= 0.02 * report_points(report) + 5
    # the files match the counts
    cloud = client.get(lo["pointcloud_url"])
    assert cloud.status_code == 200
    path = server["tmp"] / "lo.ply"
    path.write_bytes(cloud.content)
    pts = read_point_cloud_ply(path)
    assert len(pts["x"]) == lo["points"] and float(pts["scalar_magnitude"].min()) >= 0.1 - 1e-6
    glb = client.get(hi["mesh_url"])
    assert glb.status_code == 200 and glb.headers["content-type"] == "model/gltf-binary"
    m = trimesh.load(io.BytesIO(glb.content), file_type="glb", force="mesh")
    assert len(m.faces) == hi["faces"] and np.all(np.isfinite(m.vertices))
    # kept: a second call does no work and gives the same answer
    again = client.get(url, params={"method": "backprojection", "threshold": 0.1004}).json()
    assert again["seconds"] == 0.0 and again["points"] == lo["points"] and again["threshold"] == 0.1


def report_points(report: dict) -> int:
    return next(m for m in report["methods"] if m["method"] == "backprojection")["points"]


def test_reextract_refuses_what_it_cannot_do(client, done, survey_file) -> None:
    url = f"/reconstructions/{done['id']}/extract"
    cases = [
        ({"method": "shsas", "threshold": 0.3}, 404, "was not run"),
        ({"method": "magic", "threshold": 0.3}, 422, "method"),
        ({"method": "backprojection", "threshold": 1.5}, 422, "threshold"),
        ({"method": "backprojection", "threshold": 0}, 422, "threshold"),
        ({"method": "backprojection"}, 422, "threshold"),
    ]
    for params, status, word in cases:
        r = client.get(url, params=params)
        assert r.status_code == status and word in r.text, (params, r.status_code, r.text)
    r = client.get("/reconstructions/0123456789abcdef0123456789abcdef/extract",
                   params={"method": "backprojection", "threshold": 0.3})
    assert r.status_code == 404
    queued = submit(client, survey_file, {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu"}).json()
    r = client.get(f"/reconstructions/{queued['id']}/extract", params={"method": "shsas", "threshold": 0.3})
    assert r.status_code == 409 and "succeeded" in r.json()["detail"]
    client.post(f"/reconstructions/{queued['id']}/cancel")


def test_survey_view_is_the_info_summary_plus_geometry(client, done, server) -> None:
    from shsas_core.formats import load_survey
    from shsas_core.formats.hdf5 import summarize

    r = client.get(f"/reconstructions/{done['id']}/survey")
    assert r.status_code == 200, r.text
    view = r.json()
    local = summarize(load_survey(server["tmp"] / "demo.h5", load_samples=False))
    assert view["summary"] == json.loads(json.dumps(local))
    n = local["pings"]
    assert len(view["tx"]) == len(view["rx"]) == n == 900
    assert [p["index"] for p in view["pings"]] == [0, round((n - 1) / 2), n - 1]
    assert all(len(p["envelope"]) <= 400 and max(p["envelope"]) > 0 for p in view["pings"])
    gt = client.get(view["ground_truth_url"])
    assert gt.status_code == 200
    assert len(trimesh.load(io.BytesIO(gt.content), file_type="glb", force="mesh").faces) == local["ground_truth"]["faces"]


def test_spec_schema_has_every_default(client) -> None:
    schema = client.get("/schemas/reconstruction-spec").json()
    defaults = ReconstructionSpec().model_dump(mode="json")
    assert {k: v["default"] for k, v in schema["properties"].items()} == defaults
    assert schema["properties"]["grid"]["anyOf"][0]["maximum"] == 512


def test_page_is_served_with_a_strict_policy(client) -> None:
    r = client.get("/")
    if r.status_code == 503:
        pytest.fail("the console is not built: run `make console` (make test does)")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    assert "default-src 'self'" in r.headers["content-security-policy"]
    assert "http://" not in r.text and "https://" not in r.text


def test_levels_are_rounded_inside_the_open_interval() -> None:
    from service.routes.extracts import _level

    assert [_level(t) for t in (0.0001, 0.0004, 0.1004, 0.1006, 0.9996, 0.99999)] == \
        [0.001, 0.001, 0.1, 0.101, 0.999, 0.999]
