"""Every format `shsas convert` reads is accepted as an upload, over HTTP against a real
`shsas serve`: the real AirSAS recordings of ``../shared/data/airsas/`` zipped on the fly (the
CSV scan with its background, the deconvolved-ping folder), and, where no real file exists,
the importers' test builders (the pickle, an SVSS track). Each upload is validated (202),
stored as the canonical conversion and its survey view is the one `shsas info` gives for the
original; the two real formats run a short backprojection end to end."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from shsas_core.formats import detect_format, load_survey
from shsas_core.formats.hdf5 import read_survey, summarize
from tests.helpers.airsas_zips import WINDOW_ROWS, cutout_zip, deconvolved_zip, need
from tests.helpers.importer_data import AirSASScan, SVSSTrack, write_airsas_pickle

from .conftest import start_server, submit, wait_for

pytestmark = pytest.mark.service

QUICK_SPEC = {"methods": ["backprojection"], "grid": 32, "device": "cpu"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("formats")
    proc, base = start_server(tmp, {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"})
    yield {"base": base, "data": tmp / "data", "tmp": tmp}
    proc.stop()


@pytest.fixture
def client(server):
    with httpx.Client(base_url=server["base"], timeout=120) as c:
        yield c


def _accepted(client: httpx.Client, server: dict, upload: Path, fmt: str, spec: dict = QUICK_SPEC) -> dict:
    """Upload ``upload``; check 202, the stored canonical file against the original's import,
    and the survey view's summary against `shsas info`'s."""
    assert detect_format(upload) == fmt
    r = submit(client, upload, spec)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["input"]["bytes"] == upload.stat().st_size
    original = load_survey(upload)
    stored = read_survey(server["data"] / "jobs" / job["id"] / "input" / job["input"]["name"])
    assert stored.shape == original.shape and stored.meta.model_dump(exclude={"attrs"}) == \
        original.meta.model_dump(exclude={"attrs"})
    rows = slice(None, None, max(1, original.num_pings // 50))
    np.testing.assert_array_equal(stored.samples[rows], original.samples[rows].astype(stored.samples.dtype))
    np.testing.assert_array_equal(stored.tx, original.tx)
    view = client.get(f"/reconstructions/{job['id']}/survey")
    assert view.status_code == 200, view.text
    local = json.loads(json.dumps(summarize(load_survey(upload, load_samples=False))))
    got = view.json()["summary"]
    assert {k: v for k, v in got.items() if k != "attrs"} == {k: v for k, v in local.items() if k != "attrs"}
    return job


def _succeeds(client: httpx.Client, job: dict, methods: tuple[str, ...] = ("backprojection",)) -> dict:
    done = wait_for(client, job["id"], lambda j: j["status"] in ("succeeded", "failed"), 300, "job to end")
    assert done["status"] == "succeeded", done
    names = {a["name"] for a in done["artifacts"]}
    assert {"report.json", *(f"{m}_volume.npy" for m in methods), *(f"{m}_mesh.ply" for m in methods)} <= names
    return done


@pytest.mark.slow
def test_real_airsas_csv_scan_zip_runs_end_to_end(client, server, tmp_path) -> None:
    """cutout_20k (first 60 flights) with bg_20k as its background/, zipped."""
    job = _accepted(client, server, cutout_zip(tmp_path / "cutout_20k.zip", flights=60), "airsas-csv")
    summary = client.get(f"/reconstructions/{job['id']}/survey").json()["summary"]
    assert summary["pings"] == 60 and summary["attrs"]["background_subtracted"] is True
    assert summary["attrs"]["file"] == "cutout_20k.zip"  # the client's name, not the server's
    _succeeds(client, job)


@pytest.mark.slow
def test_real_deconvolved_folder_zip_is_accepted(client, server, tmp_path) -> None:
    """bunny_20k_deconvolved (54,000 pings and its waveform file), zipped: the format the
    service's stored inputs had no name for."""
    job = _accepted(client, server, deconvolved_zip(tmp_path / "bunny_20k_deconvolved.zip"), "airsas-deconvolved")
    client.post(f"/reconstructions/{job['id']}/cancel")  # a full-size job; the CSV scan runs one
    summary = client.get(f"/reconstructions/{job['id']}/survey").json()["summary"]
    assert summary["pings"] == 54000 and summary["samples_per_ping"] == 608 and summary["pulse_deconvolved"]


@pytest.mark.slow
def test_real_deconvolved_rows_zip_runs_every_method_end_to_end(client, server, tmp_path) -> None:
    """The first 46 turntable steps of all 150 levels of bunny_20k_deconvolved, zipped: the same
    range window as the whole folder (so the samples keep their ranges), and every method runs
    on it through the service (short: grid 24, 10 iterations from the empty field; the warm
    start alone takes minutes on 6,900 pings and is tested on small surveys)."""
    upload = deconvolved_zip(tmp_path / "bunny_rows.zip", rows=WINDOW_ROWS)
    whole = load_survey(need("bunny_20k_deconvolved"), load_samples=False).meta
    part = load_survey(upload, load_samples=False).meta
    for key in ("range_min_dist_m", "range_max_dist_m"):
        assert part.attrs[key] == pytest.approx(whole.attrs[key], rel=1e-12)
    assert part.fs == pytest.approx(whole.fs, rel=1e-12)
    methods = ("backprojection", "reed", "shsas")
    job = _accepted(client, server, upload, "airsas-deconvolved",
                    {"methods": list(methods), "grid": 24, "iters": 10, "init": "none", "device": "cpu"})
    summary = client.get(f"/reconstructions/{job['id']}/survey").json()["summary"]
    assert summary["pings"] == 150 * WINDOW_ROWS and summary["pulse_deconvolved"]
    _succeeds(client, job, methods)


def test_airsas_pickle_is_accepted(client, server, tmp_path) -> None:
    pik = tmp_path / "system_data.pik"
    write_airsas_pickle(pik, AirSASScan())
    _accepted(client, server, pik, "airsas-pickle")


def test_svss_track_zip_is_accepted(client, server, tmp_path) -> None:
    track = SVSSTrack(kernel=False).write(tmp_path / "svss")
    z = tmp_path / "track.zip"
    with zipfile.ZipFile(z, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for p in track.iterdir():
            zf.write(p, f"{track.name}/{p.name}")
    job = _accepted(client, server, z, "svss")
    summary = client.get(f"/reconstructions/{job['id']}/survey").json()["summary"]
    assert summary["platform"] == "svss" and summary["attrs"]["temperature_source"] == "table"
