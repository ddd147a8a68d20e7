"""A method installed from outside the project runs through ``POST /reconstructions`` on a real
`shsas serve` (its local worker is another process: the method reaches it through the
``shsas.methods`` entry points of the distribution on ``PYTHONPATH``, tests/helpers/toy_method.py)."""

from __future__ import annotations

import io
import os

import httpx
import numpy as np
import pytest

from tests.helpers.toy_method import TOY, TOY_COLOUR, install_toy_method

from .conftest import FAST_TIMINGS, REPO, start_server, submit, wait_for, write_tiny_survey

pytestmark = pytest.mark.service


def test_an_installed_method_runs_through_post_reconstructions(tmp_path) -> None:
    plugin = install_toy_method(tmp_path / "plugin")
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), **FAST_TIMINGS,
           "PYTHONPATH": os.pathsep.join([str(plugin), str(REPO)])}
    proc, base = start_server(tmp_path, env)
    try:
        with httpx.Client(base_url=base, timeout=30) as c:
            listed = {m["name"]: m for m in c.get("/methods").json()}
            assert listed[TOY]["colour"] == TOY_COLOUR and not listed[TOY]["default"]
            assert listed["shsas"]["neural"] and listed["backprojection"]["default"]
            schema = c.get("/openapi.json").text
            assert f'"{TOY}"' in schema
            survey = write_tiny_survey(tmp_path / "tiny.h5")
            r = submit(c, survey, {"methods": ["backprojection", TOY], "grid": 12, "device": "cpu"})
            assert r.status_code == 202, r.text
            job = wait_for(c, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 300,
                           "job to finish")
            assert job["status"] == "succeeded", job
            vols = {}
            for m in ("backprojection", TOY):
                got = c.get(f"/reconstructions/{job['id']}/artifacts/{m}_volume.npy")
                assert got.status_code == 200, got.text
                vols[m] = np.load(io.BytesIO(got.content), allow_pickle=False)
            np.testing.assert_allclose(vols[TOY], np.abs(vols["backprojection"]) ** 2, rtol=1e-6)
            # a name no installed distribution defines is refused with a clear 422
            bad = submit(c, survey, {"methods": ["nonesuch"], "grid": 12, "device": "cpu"})
            assert bad.status_code == 422 and "methods" in bad.text
    finally:
        proc.stop()
