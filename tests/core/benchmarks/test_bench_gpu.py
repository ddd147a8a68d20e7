"""benchmarks/bench_gpu.py --smoke on the CPU: the GPU record's whole path (every backend timed,
the paper fit stopped by its budget and resumed by a second call, the defaults, the record)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from shsas_core.neural.fields.encoding import BACKENDS

ROOT = Path(__file__).resolve().parents[3]


def _call(tmp: Path, *args: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("TRITON_INTERPRET", None)  # the script sets it for the triton backend's process only
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_gpu.py"), "--smoke", "--device", "cpu",
                           "--out", str(tmp / "rec"), "--work", str(tmp / "work"), *args],
                          capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (path,) = (tmp / "rec").glob("smoke-*.json")
    return json.loads(path.read_text())


@pytest.mark.slow
def test_smoke_record_with_a_fit_resumed_across_calls(tmp_path: Path) -> None:
    # first call: the timings, and a fit stopped after 4 of its 10 iterations
    rec = _call(tmp_path, "--steps", "time,fit", "--call-iters", "4")
    assert rec["smoke"] is True and rec["machine"]["card"].startswith("cpu")
    assert set(rec["paper_batch_ms"]) == set(BACKENDS)
    for b in ("reference", "fused", "native", "triton"):  # triton: under the interpreter
        assert rec["paper_batch_ms"][b] > 0, rec["time"]["backends"][b]
    assert rec["paper_batch_ms"]["compiled"] is None and "skipped" in rec["time"]["backends"]["compiled"]
    fit = rec["fit"]
    assert fit["calls"] == 1 and not fit["finished"] and fit["iters_done"] == 4 and fit["iters_target"] == 10
    assert "defaults" not in rec
    # second call: the fit resumes from its checkpoints and ends; then the defaults run
    rec = _call(tmp_path, "--steps", "time,fit,defaults")
    fit, dflt = rec["fit"], rec["defaults"]
    assert fit["calls"] == 2 and fit["finished"] and fit["iters_done"] == fit["iters_target"] == 10
    assert fit["iters_per_call"] == [4, 6]  # resumed from the checkpoint, not started again
    assert fit["spec"]["encoding"] == "small" and fit["spec"]["init"] == "none"  # the paper's start
    assert dflt["finished"] and dflt["spec"]["forward"] == "psf"  # the defaults' forward model
    for f in (fit, dflt):
        assert f["device"] == "cpu" and set(f["scores"]) == {"pc_f1", "mesh_f1", "pc_chamfer_l2", "pc_fscore",
                                                               "seconds"}
        assert f["scores"]["seconds"] > 0
