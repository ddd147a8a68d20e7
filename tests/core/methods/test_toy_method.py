"""A method installed from outside the project runs through `shsas reconstruct` (real CLI process).

The toy method (tests/helpers/toy_method.py) is a module plus a ``.dist-info`` on ``PYTHONPATH``:
the catalogue finds it through the ``shsas.methods`` entry points, so the CLI's choices, the spec
and the pipeline know it without any file of the project being edited.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from shsas_core.data.survey import Survey
from shsas_core.formats.hdf5 import write_survey
from shsas_core.outputs.export import read_volume_npy
from shsas_core.pipeline.finish import artifact_names
from tests.conftest import make_survey
from tests.helpers.toy_method import TOY, install_toy_method

REPO = Path(__file__).resolve().parents[3]


def _shsas(args: list[str], pythonpath: list[Path]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(p) for p in [*pythonpath, REPO]),
           "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "shsas_core.cli", *args], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=600)


def _two_level_survey() -> Survey:
    """make_survey's pings with every second one 10 cm higher: two height levels make it a 3-D
    survey, whose report searches no plane of best focus. That search compiles the quick-look
    kernel, about half of the CPU time of a fresh process, and has tests of its own
    (tests/core/imaging/test_planar.py, tests/core/outputs/test_planar_report.py)."""
    s = make_survey()
    tx, rx = s.tx.copy(), s.rx.copy()
    tx[::2, 2] += 0.1
    rx[::2, 2] += 0.1
    return dataclasses.replace(s, tx=tx, rx=rx)


def test_an_installed_method_runs_through_shsas_reconstruct(tmp_path: Path) -> None:
    plugin = install_toy_method(tmp_path / "plugin")
    survey = write_survey(_two_level_survey(), tmp_path / "s.h5")
    args = ["reconstruct", str(survey), "--methods", f"backprojection,{TOY}", "--grid", "12", "--device", "cpu",
            "--out", str(tmp_path / "out"), "--quiet"]

    # without the distribution the method does not exist: one line, exit 2
    refused = _shsas([*args[:-3], "--out", str(tmp_path / "refused"), "--quiet"], [])
    assert refused.returncode == 2 and "--methods" in refused.stderr and "Traceback" not in refused.stderr

    help_ = _shsas(["reconstruct", "--help"], [plugin])
    assert help_.returncode == 0 and TOY in help_.stdout

    done = _shsas(args, [plugin])
    assert done.returncode == 0, done.stderr[-3000:]
    out = tmp_path / "out"
    report = json.loads((out / "report.json").read_text())
    assert [m["method"] for m in report["methods"]] == ["backprojection", TOY]
    for name in artifact_names(TOY).values():
        assert (out / name).exists(), name
    bp = read_volume_npy(out / artifact_names("backprojection")["volume"])
    toy = read_volume_npy(out / artifact_names(TOY)["volume"])
    np.testing.assert_allclose(toy.values, np.abs(bp.values) ** 2, rtol=1e-6)
    assert np.abs(bp.values).max() > 0
