"""The uploaded file's name and the operator's label, end to end over HTTP against a real
`shsas serve`: stored, shown in the status and the list, searched, and used for downloads."""

from __future__ import annotations

import io
import json
import zipfile
from urllib.parse import unquote

import httpx
import pytest

from service.job_names import MAX_LABEL, download_name

from .conftest import SERVER_START_S, start_server, wait_for, write_demo_survey

pytestmark = pytest.mark.service

QUICK = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("job-names")
    proc, base = start_server(tmp, {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"},
                              timeout=SERVER_START_S)
    with httpx.Client(base_url=base, timeout=60) as client:
        yield client, write_demo_survey(tmp / "demo.h5")
    proc.stop()


def post(client: httpx.Client, survey, filename: str, label: str | None = None, spec=QUICK) -> httpx.Response:
    data = {"spec": json.dumps(spec)} | ({"label": label} if label is not None else {})
    return client.post("/reconstructions", files={"survey": (filename, survey.read_bytes())}, data=data)


def test_name_and_label_kept_from_upload_to_download(server) -> None:
    client, survey = server
    r = post(client, survey, "Harbour scan ü 42.h5", label="  north wall, pass 2 ")
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["input"]["filename"] == "Harbour scan ü 42.h5" and job["input"]["name"] == "survey.h5"
    assert job["label"] == "north wall, pass 2"
    done = wait_for(client, job["id"], lambda j: j["status"] in ("succeeded", "failed"), 180, "the job to end")
    assert done["status"] == "succeeded" and done["input"]["filename"] == "Harbour scan ü 42.h5"
    done["artifacts_names"] = [a["name"] for a in done["artifacts"]]
    assert any(n.endswith("_mesh_preview.glb") for n in done["artifacts_names"])  # the worker's previews
    listed = client.get("/reconstructions", params={"q": "HARBOUR SCAN"}).json()["items"]
    assert [j["id"] for j in listed] == [job["id"]] and listed[0]["label"] == "north wall, pass 2"
    assert [j["id"] for j in client.get("/reconstructions", params={"q": "north wall"}).json()["items"]] == [job["id"]]
    # downloads are named after the uploaded file, so files of several jobs stay apart in one folder
    got = client.get(f"/reconstructions/{job['id']}/artifacts/report.json")
    cd = got.headers["content-disposition"]
    assert unquote(cd.split("filename*=UTF-8''")[1]) == "Harbour scan ü 42_report.json"
    assert 'filename="Harbour scan _ 42_report.json"' in cd  # the ASCII fallback
    assert got.json()["methods"]
    # "download all": one zip, streamed (no Content-Length: it is made as it is sent), holding
    # every artifact byte for byte
    with client.stream("GET", f"/reconstructions/{job['id']}/artifacts.zip") as resp:
        assert resp.status_code == 200 and resp.headers["content-type"] == "application/zip"
        assert "content-length" not in resp.headers and resp.headers.get("transfer-encoding") == "chunked"
        cd = resp.headers["content-disposition"]
        body = b"".join(resp.iter_bytes())
    assert cd.startswith("attachment;") and unquote(cd.split("filename*=UTF-8''")[1]) == "Harbour scan ü 42_results.zip"
    with zipfile.ZipFile(io.BytesIO(body)) as zf:
        assert zf.testzip() is None and sorted(zf.namelist()) == sorted(done["artifacts_names"])
        for name in zf.namelist():
            assert zf.read(name) == client.get(f"/reconstructions/{job['id']}/artifacts/{name}").content, name


def test_list_filters_orders_and_refusals(server) -> None:
    client, survey = server
    slow = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}
    long_job = post(client, survey, "long.h5", spec=slow).json()
    queued = post(client, survey, "behind.h5").json()
    try:
        wait_for(client, long_job["id"], lambda j: j["status"] == "running", 180, "the long job to start")
        active = client.get("/reconstructions", params={"order": "active", "limit": 1})
        first = active.json()
        assert first["items"][0]["id"] == long_job["id"], first  # running first, although not the newest
        second = client.get("/reconstructions", params={"order": "active", "limit": 1, "cursor": first["next_cursor"]})
        assert second.json()["items"][0]["id"] == queued["id"]
        ids = {j["id"] for j in client.get("/reconstructions", params={"status": "queued,running"}).json()["items"]}
        assert ids == {long_job["id"], queued["id"]}
        for params, field in (({"order": "oldest"}, "order"), ({"status": "queued,done"}, "status"),
                              ({"cursor": first["next_cursor"]}, "cursor")):
            bad = client.get("/reconstructions", params=params)
            assert bad.status_code == 400 and bad.json()["detail"].startswith(f"{field}:"), bad.text
        long_label = post(client, survey, "x.h5", label="x" * (MAX_LABEL + 1))
        assert long_label.status_code == 422 and long_label.json()["detail"].startswith("label:")
        two_lines = post(client, survey, "x.h5", label="a\nb")
        assert two_lines.status_code == 422 and "control characters" in two_lines.json()["detail"]
    finally:
        for j in (long_job, queued):
            client.post(f"/reconstructions/{j['id']}/cancel")


def test_download_name() -> None:
    assert download_name("scan 42.h5", "shsas_mesh.glb") == "scan 42_shsas_mesh.glb"
    assert download_name("C:\\surveys\\bay.zip", "report.html") == "bay_report.html"
    assert download_name(None, "report.html") == "report.html"
    assert download_name("...", "report.json") == "report.json"


def test_zip_of_a_job_without_files_is_refused(server) -> None:
    client, survey = server
    job = post(client, survey, "q.h5", spec={**QUICK, "iters": 5}).json()
    client.post(f"/reconstructions/{job['id']}/cancel")
    wait_for(client, job["id"], lambda j: j["status"] in ("cancelled", "succeeded"), 120, "the job to end")
    if client.get(f"/reconstructions/{job['id']}").json()["artifacts"]:
        pytest.skip("the job finished before the cancel landed")
    r = client.get(f"/reconstructions/{job['id']}/artifacts.zip")
    assert r.status_code == 409 and "no files" in r.json()["detail"]
