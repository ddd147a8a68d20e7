"""What the upload route makes of mistaken requests.

A real `shsas serve` (embedded, SQLite) in a subprocess, driven over HTTP: misnamed form
fields, query parameters, validation messages naming the user's file, header values that
used to give 500.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import httpx
import numpy as np
import pytest

from .conftest import start_server, submit, wait_for, write_tiny_survey

pytestmark = pytest.mark.service

QUICK_SPEC = {"methods": ["backprojection"], "grid": 16, "device": "cpu"}
UPLOAD_CAP = 2_000_000


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("input")
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_MAX_UPLOAD_BYTES": str(UPLOAD_CAP),
           "SHSAS_VALIDATE_MEMORY_BYTES": str(512 * 1024**2),
           # Default lease timings: the short test ones re-queue a job on a loaded machine.
           "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"}
    proc, base = start_server(tmp, env)
    yield {"base": base, "data": tmp / "data", "tmp": tmp}
    proc.stop()


@pytest.fixture
def client(server):
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        yield c


def _job_count(client: httpx.Client) -> int:
    return len(client.get("/reconstructions", params={"limit": 1000}).json()["items"])


def _detail(r: httpx.Response) -> str:
    return str(r.json().get("detail")) if r.headers.get("content-type", "").startswith("application/json") \
        else r.text


def test_misnamed_form_fields_get_422_naming_them(client, survey_file: Path, tmp_path: Path) -> None:
    """`-F specs=`, a spec in the query string, `-F file=@big`, stray or repeated fields: all
    422 naming the field and the expected ones; none of them queues a job."""
    survey = ("scan.h5", survey_file.read_bytes(), "application/octet-stream")
    spec = json.dumps(QUICK_SPEC)
    big = np.random.default_rng(0).bytes(200_000)  # over the 64 kB text-field cap
    cases = [
        ("specs", {"files": {"survey": survey}, "data": {"specs": spec}}, "specs"),
        ("spec in the query", {"files": {"survey": survey}, "params": {"spec": spec}}, "spec"),
        ("other query parameter", {"files": {"survey": survey}, "data": {"spec": spec},
                                   "params": {"grid": "16"}}, "grid"),
        ("file=@big", {"files": {"file": ("scan.h5", big, "application/octet-stream")}}, "file"),
        ("stray text field", {"files": {"survey": survey}, "data": {"spec": spec, "note": "hi"}}, "note"),
        ("spec twice", {"files": [("survey", survey), ("spec", (None, spec)), ("spec", (None, spec))]},
         "more than once"),
        ("two surveys", {"files": [("survey", survey), ("survey", survey)]}, "more than one"),
    ]
    before = _job_count(client)
    problems = []
    for name, kwargs, word in cases:
        r = client.post("/reconstructions", **kwargs)
        detail = _detail(r)
        if r.status_code != 422 or word not in detail:
            problems.append(f"{name}: {r.status_code} {detail!r}")
        elif "fix:" not in detail or (name != "spec twice" and "two surveys" != name
                                      and not ("'survey'" in detail and "'spec'" in detail)):
            problems.append(f"{name}: message does not name the expected fields or a fix: {detail!r}")
    assert not problems, "\n".join(problems)
    assert _job_count(client) == before, "a refused request queued a job"


def test_spec_errors_carry_a_fix(client, survey_file: Path) -> None:
    """A bad spec gets 422 naming the spec field, the problem and how to fix it."""
    cases = {"{\"gird\": 16}": ("spec.gird", "grid"), "{\"grid\": 100000}": ("spec.grid", "≤ 512"),
             "{\"methods\": [\"magic\"]}": ("spec.methods.0", "'shsas'"), "{grid: 16": ("spec", "JSON")}
    problems = []
    for spec, (field, fix_word) in cases.items():
        r = client.post("/reconstructions", files={"survey": ("scan.h5", survey_file.read_bytes())},
                        data={"spec": spec})
        detail = _detail(r)
        fix = detail.partition("(fix: ")[2]
        if r.status_code != 422 or not detail.startswith(f"{field}: ") or fix_word not in fix:
            problems.append(f"{spec}: {r.status_code} {detail!r}")
    assert not problems, "\n".join(problems)


def _corrupt(path: Path, good: Path, edit) -> Path:
    path.write_bytes(good.read_bytes())
    with h5py.File(path, "a") as f:
        edit(f)
    return path


def test_validation_messages_name_the_users_file(client, survey_file: Path, tmp_path: Path) -> None:
    """Every survey validation message names the uploaded file's own name, not `upload.part`."""
    def wrong_shape(f):
        del f["pings/tx"]
        f["pings/tx"] = np.zeros((f["pings/rx"].shape[0], 2))

    def bad_meta(f):
        f.attrs["meta"] = json.dumps({"fs": -1})

    good = survey_file.read_bytes()
    cases = {
        "notes from the lab.txt": b"this is not a survey\n" * 50,
        "half of scan.h5": good[: len(good) // 2],
        "shape.h5": _corrupt(tmp_path / "a.h5", survey_file, wrong_shape).read_bytes(),
        "meta.h5": _corrupt(tmp_path / "b.h5", survey_file, bad_meta).read_bytes(),
        "empty.h5": b"",
    }
    problems = []
    for filename, content in cases.items():
        r = client.post("/reconstructions", files={"survey": (filename, content, "application/octet-stream")},
                        data={"spec": json.dumps(QUICK_SPEC)})
        detail = _detail(r)
        if r.status_code != 422 or filename not in detail or "upload.part" in detail or "/uploads/" in detail:
            problems.append(f"{filename}: {r.status_code} {detail!r}")
    assert not problems, "\n".join(problems)


def test_long_multipart_boundary_gets_400(client) -> None:
    boundary = "b" * 300
    body = f"--{boundary}\r\nContent-Disposition: form-data; name=\"spec\"\r\n\r\n{{}}\r\n--{boundary}--\r\n"
    r = client.post("/reconstructions", content=body.encode(),
                    headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert r.status_code == 400, r.text
    assert "boundary" in _detail(r)


@pytest.fixture(scope="module")
def artifact(server) -> tuple[str, bytes]:
    """The URL and bytes of one artifact of a finished job."""
    survey = write_tiny_survey(server["tmp"] / "tiny.h5")
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        r = submit(c, survey, QUICK_SPEC)
        assert r.status_code == 202, r.text
        done = wait_for(c, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 180,
                        "job to finish")
        assert done["status"] == "succeeded", done
        url = done["artifacts"][0]["url"]
        return url, c.get(url).content


def test_range_numbers_of_any_length(client, artifact) -> None:
    """Range positions of any length: 206, 416 or 200, never 500 (int() refuses > 4300 digits)."""
    url, content = artifact
    size = len(content)
    huge = "9" * 5000
    expect = {
        "bytes=0-99999999999999999999999999": (206, content),
        f"bytes=0-{huge}": (206, content),
        f"bytes={huge}-": (416, b""),
        f"bytes={huge}-{huge}": (416, b""),
        f"bytes=-{huge}": (206, content),
        f"bytes={'0' * 5000}5-9": (206, content[5:10]),
        f"bytes=10-{'0' * 5000}{size - 1}": (206, content[10:]),
    }
    problems = []
    for rng, (status, body) in expect.items():
        try:
            r = client.get(url, headers={"Range": rng})
        except httpx.HTTPError as exc:  # what a server error looked like before the fix
            problems.append(f"{rng[:40]}...: {type(exc).__name__}")
            continue
        if r.status_code != status or (status != 416 and r.content != body):
            problems.append(f"{rng[:40]}...: {r.status_code}, {len(r.content)} bytes")
    assert not problems, "\n".join(problems)


def test_files_from_other_tools(client, tmp_path: Path) -> None:
    """A survey written from docs/formats.md with dotted meta keys is accepted; one whose two
    pulse descriptions disagree gets 422 naming the file, the problem and the fix (item 6)."""
    from tests.core.formats.test_formats_doc import _disagreeing, write_from_tables

    good = tmp_path / "from another tool.h5"
    write_from_tables(good, style="dotted")
    r = submit(client, good, QUICK_SPEC)
    assert r.status_code == 202, r.text
    client.post(f"/reconstructions/{r.json()['id']}/cancel")

    bad = tmp_path / "other band.h5"
    write_from_tables(bad, style="dotted", pulse=_disagreeing("other band"))
    r = submit(client, bad, QUICK_SPEC)
    detail = _detail(r)
    assert r.status_code == 422, detail
    assert "'other band.h5'" in detail and "pulse/samples" in detail and "disagree" in detail and "(fix: " in detail
