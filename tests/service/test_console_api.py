"""The API routes made for the console, over HTTP against a real `shsas serve`: re-extraction
at another iso level, the survey view, the spec schema, and the page itself."""

from __future__ import annotations

import io
import json

import httpx
import numpy as np
import pytest
import trimesh

from shsas_core.evaluation.extract import ExtractConfig
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
    # the ridge's candidates start at candidate_share x the level (the contrast test decides)
    floor = ExtractConfig().candidate_share * 0.1
    assert len(pts["x"]) == lo["points"] and float(pts["scalar_magnitude"].min()) >= floor - 1e-6
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


def test_job_log_lines(client, done, server) -> None:
    """The job's own log: its stages in order, its outcome, bounded by ``tail``; a job of
    another key or an unknown id is a 404."""
    url = f"/reconstructions/{done['id']}/log"
    r = client.get(url)
    assert r.status_code == 200, r.text
    body = r.json()
    text = "\n".join(body["lines"])
    assert body["status"] == "succeeded" and not body["truncated"]
    assert all(line[:8].count(":") == 2 for line in body["lines"])  # "HH:MM:SS level message"
    for stage in ("deconvolution", "backprojection", "report"):
        assert f" info {stage} at " in text, text
    assert text.index("deconvolution at") < text.index("backprojection at") < text.index("report at")
    assert "succeeded on cpu" in body["lines"][-1], body["lines"][-1]
    assert done["id"] not in text  # the job's own id is not repeated on every line
    two = client.get(url, params={"tail": 2}).json()
    assert two["lines"] == body["lines"][-2:] and two["truncated"]
    assert client.get(url, params={"tail": 0}).status_code == 422
    assert client.get("/reconstructions/0123456789abcdef0123456789abcdef/log").status_code == 404


def test_job_log_capped(tmp_path) -> None:
    """A job that logs without end stops at the cap, with a line that says so."""
    import logging

    from jobs.joblog import MAX_BYTES, job_log, read_tail

    log = logging.getLogger("shsas.worker")
    with job_log(tmp_path, "abc") as path:
        for i in range(MAX_BYTES // 40):
            log.warning("job abc: line %d of a chatty job, padded to forty bytes", i)
    assert MAX_BYTES - 200 < path.stat().st_size <= MAX_BYTES
    lines, cut = read_tail(path, 5, 4096)
    assert cut and "later lines are not kept" in lines[-1]
    log.warning("job abc: after the job")  # the handler is gone once the job ended
    assert path.stat().st_size <= MAX_BYTES


def test_presets_and_estimates(client) -> None:
    """The three presets, each a valid spec, with the cost model's estimate; a spec a submission
    would refuse says why, before any upload."""
    from shsas_core.spec.cost import cpu_job_seconds

    presets = client.get("/schemas/reconstruction-presets").json()
    assert [p["name"] for p in presets] == ["quick", "standard", "paper"]
    est = {}
    for p in presets:
        spec = {**p["spec"], "device": "cpu"}
        r = client.post("/estimates", json={"spec": spec})
        assert r.status_code == 200, r.text
        est[p["name"]] = r.json()
        want = cpu_job_seconds(ReconstructionSpec.model_validate(spec)).total_s
        assert est[p["name"]]["cpu_s"] == pytest.approx(want, abs=0.1) and not est[p["name"]]["survey_known"]
    assert est["quick"]["parts"]["train_s"] == 0 < est["standard"]["parts"]["train_s"] < est["paper"]["parts"]["train_s"]
    assert est["quick"]["refused"] == [] and est["standard"]["refused"] == []
    # the paper's setting on a CPU: hours, over the CPU limit (and over the training cap)
    assert est["paper"]["cpu_s"] > 3600 and any("SHSAS_MAX_CPU_JOB_S" in m for m in est["paper"]["refused"])
    # the survey's size adds its parts when given
    sized = client.post("/estimates", json={"spec": {"methods": ["backprojection"], "grid": 64, "device": "cpu"},
                                            "pings": 1000, "samples_per_ping": 2000}).json()
    assert sized["survey_known"] and sized["parts"]["backprojection_s"] > 0 and sized["parts"]["signal_s"] > 0
    bad = client.post("/estimates", json={"spec": {"grid": 2, "iters": -1}})
    assert bad.status_code == 422 and "spec.grid" in bad.json()["detail"] and "spec.iters" in bad.json()["detail"]


def test_reextract_scores_follow_the_level(client, done) -> None:
    """With ground truth, a re-extraction carries the report's metrics at its level: at the
    job's own level they agree with the report's; at another level they change."""
    report = client.get(f"/reconstructions/{done['id']}/artifacts/report.json").json()
    bp = next(m for m in report["methods"] if m["method"] == "backprojection")
    assert bp["metrics"].get("pc_surface_f1") is not None  # the demo survey has ground truth
    url = f"/reconstructions/{done['id']}/extract"
    own = client.get(url, params={"method": "backprojection", "threshold": round(bp["threshold"], 3)}).json()
    other = client.get(url, params={"method": "backprojection", "threshold": 0.8}).json()
    for key in ("pc_surface_f1", "pc_fscore", "pc_chamfer_l2", "mesh_surface_f1", "mesh_pieces"):
        assert own["metrics"][key] is not None, key
    # the level is rounded to 0.001 and the ground truth goes through a float32 GLB: close, not equal
    assert own["metrics"]["pc_surface_f1"] == pytest.approx(bp["metrics"]["pc_surface_f1"], abs=0.03)
    assert own["metrics"]["pc_fscore"] == pytest.approx(bp["metrics"]["pc_fscore"], abs=0.03)
    assert own["metrics"]["mesh_pieces"] == bp["metrics"]["mesh_pieces"]
    assert other["metrics"]["pc_points"] < own["metrics"]["pc_points"]
    assert other["metrics"]["pc_surface_f1"] != own["metrics"]["pc_surface_f1"]
