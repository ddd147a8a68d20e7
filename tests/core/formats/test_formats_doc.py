"""docs/formats.md is enough to write a survey: files built from its tables with plain h5py (not
shsas_core.formats.hdf5.write_survey) load, keep every value, and agree with the pulse the docs describe.

Also: a file whose two pulse descriptions disagree gets a warning from `shsas info`, dotted
meta keys work, and every validation error carries a fix.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy.signal import hilbert, windows

from shsas_core.common.errors import ShsasError, SurveyValidationError
from shsas_core.data.pulse import lfm_pulse
from shsas_core.data.survey import parse_meta, pulse_disagreement
from shsas_core.formats import load_survey
from shsas_core.formats.hdf5 import read_survey, summarize
from shsas_core.signal.chain import matched_filter

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "formats.md"


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-m", "shsas_core.cli", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=120)


# -- the pulse, written from the doc's formula ("The pulse: /pulse/samples and meta.pulse") ----

def doc_pulse(f_start: float, f_stop: float, duration: float, fs: float, window: str, param: float) -> np.ndarray:
    p = max(round(duration * fs), 1)
    tk = np.arange(p) / fs
    chirp = np.cos(2 * np.pi * (f_start * tk + 0.5 * (f_stop - f_start) / duration * tk**2))
    w = {"tukey": lambda: windows.tukey(p, alpha=param, sym=True), "hann": lambda: windows.hann(p, sym=True),
         "taylor": lambda: windows.taylor(p, sll=param or 35, sym=True), "rect": lambda: np.ones(p)}[window]()
    return w * chirp


@pytest.mark.parametrize(("window", "param"), [("tukey", 0.1), ("tukey", 0.5), ("hann", 0.0), ("taylor", 0.0),
                                               ("taylor", 50.0), ("rect", 0.0)])
@pytest.mark.parametrize(("duration", "fs"), [(1e-3, 100e3), (255e-6, 125e3), (0.0125e-3, 200e3)])
def test_doc_pulse_formula_is_the_one_shsas_writes(window: str, param: float, duration: float, fs: float) -> None:
    ours = doc_pulse(10e3, 30e3, duration, fs, window, param)
    theirs = lfm_pulse(10e3, 30e3, duration, fs, window, param)
    assert ours.shape == theirs.shape == (max(round(duration * fs), 1),)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)


# -- a file from the tables --------------------------------------------------------------------

FS, C, CARRIER = 100e3, 343.0, 20e3
PULSE = {"f_start": 10e3, "f_stop": 30e3, "duration": 1e-3, "window": "hann", "window_param": 0.0}
BOX = {"min": [-0.125, -0.125, 0.0], "max": [0.125, 0.125, 0.2]}
N, T = 12, 900


def _meta(style: str, kind: str) -> dict:
    common = {"fs": FS, "sound_speed": C, "signal_kind": kind, "platform": "other-tool",
              "tx_beamwidth_deg": 60.0, "carrier_hz": CARRIER if kind == "baseband" else None}
    if style == "nested":
        return {**common, "pulse": PULSE, "scene_box": BOX, "attrs": {"writer": "plain h5py", "run": 3}}
    dotted = {**{f"pulse.{k}": v for k, v in PULSE.items()}, **{f"scene_box.{k}": v for k, v in BOX.items()},
              "attrs.writer": "plain h5py", "attrs.run": 3}
    if style == "dotted":
        return {**common, **dotted}
    # mixed: some fields nested, the others dotted
    return {**common, "pulse": {"f_start": PULSE["f_start"]},
            **{k: v for k, v in dotted.items() if k != "pulse.f_start"}}


def _geometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ang = np.linspace(0, 2 * np.pi, N, endpoint=False)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(N, 0.3)], 1)
    rx = tx + np.array([0.0, 0.0, -0.04])
    return tx, rx, np.full(N, 3e-3)


def _echoes(tx: np.ndarray, rx: np.ndarray, t0: np.ndarray, pulse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real passband samples: one unit echo of the pulse from the scene centre per ping; the delays."""
    centre = np.array([0.0, 0.0, 0.1])
    tau = (np.linalg.norm(tx - centre, axis=1) + np.linalg.norm(rx - centre, axis=1)) / C
    out = np.zeros((N, T))
    for i in range(N):
        k = round((tau[i] - t0[i]) * FS)
        out[i, k:k + pulse.size] = pulse
        tau[i] = t0[i] + k / FS  # on the sample grid: the matched filter peaks exactly there
    return out, tau


def write_from_tables(path: Path, style: str = "nested", kind: str = "real", pulse: np.ndarray | None = None) -> dict:
    """A survey file written from docs/formats.md's tables with h5py only."""
    tx, rx, t0 = _geometry()
    passband = doc_pulse(PULSE["f_start"], PULSE["f_stop"], PULSE["duration"], FS, PULSE["window"], 0.0)
    real, tau = _echoes(tx, rx, t0, passband)
    if kind == "real":
        samples, stored_pulse = real.astype(np.float32), passband
    else:  # the doc: basebanded like the samples, the pulse relative to its own start
        k = np.arange(passband.size) / FS
        stored_pulse = hilbert(passband) * np.exp(-2j * np.pi * CARRIER * k)
        t = t0[:, None] + np.arange(T)[None, :] / FS
        samples = (hilbert(real, axis=1) * np.exp(-2j * np.pi * CARRIER * t)).astype(np.complex64)
    if pulse is not None:
        stored_pulse = pulse
    meta = _meta(style, kind)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "shsas-survey"
        f.attrs["schema_version"] = 1
        f.attrs["meta"] = json.dumps(meta)
        f.create_dataset("pings/samples", data=samples)
        f.create_dataset("pings/tx", data=tx)
        f.create_dataset("pings/rx", data=rx.astype(np.float32))  # float32 is accepted
        f.create_dataset("pings/t0", data=t0)
        f.create_dataset("pings/tx_dir", data=np.tile([0.0, 0.0, -1.0], (N, 1)))
        f.create_dataset("pulse/samples", data=stored_pulse)
        f.create_dataset("ground_truth/vertices", data=np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], float))
        f.create_dataset("ground_truth/faces", data=np.array([[0, 1, 2]], np.int32))
        f.create_dataset("extras/clean", data=samples)
    return {"tx": tx, "rx": rx, "t0": t0, "samples": samples, "pulse": stored_pulse, "tau": tau, "meta": meta}


@pytest.mark.parametrize("kind", ["real", "baseband"])
@pytest.mark.parametrize("style", ["nested", "dotted", "mixed"])
def test_file_from_the_tables_loads_with_every_value(tmp_path: Path, style: str, kind: str) -> None:
    wrote = write_from_tables(tmp_path / "scan.h5", style, kind)
    s = read_survey(tmp_path / "scan.h5")
    m = s.meta
    assert (m.fs, m.sound_speed, m.signal_kind, m.platform, m.tx_beamwidth_deg) == (FS, C, kind, "other-tool", 60.0)
    assert m.carrier_hz == (CARRIER if kind == "baseband" else None)
    assert m.pulse.model_dump() == PULSE
    assert list(m.scene_box.min) == BOX["min"] and list(m.scene_box.max) == BOX["max"]
    assert m.attrs == {"writer": "plain h5py", "run": 3}
    for name in ("tx", "rx", "t0", "samples", "pulse"):
        np.testing.assert_allclose(getattr(s, name), wrote[name], rtol=1e-6, atol=1e-7)
    assert s.shape == (N, T) and s.tx_dir is not None and s.has_ground_truth and list(s.extras) == ["clean"]
    assert pulse_disagreement(m, s.pulse) is None and summarize(s)["warnings"] == []
    # The pulse convention the doc states is the one processing uses: the matched filter of
    # each echo peaks at its delay, with the pulse's energy (a basebanded complex pulse is not
    # basebanded a second time).
    mf = np.abs(matched_filter(s))
    peak = mf.argmax(axis=1)
    np.testing.assert_array_equal(s.t0 + peak / FS, wrote["tau"])
    energy = np.sum(doc_pulse(PULSE["f_start"], PULSE["f_stop"], PULSE["duration"], FS, "hann", 0.0) ** 2)
    np.testing.assert_allclose(mf.max(axis=1), energy, rtol=0.05)


def test_shsas_info_on_a_file_from_the_tables(tmp_path: Path) -> None:
    write_from_tables(tmp_path / "scan.h5", "dotted", "baseband")
    res = _cli("info", "--json", "scan.h5", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    info = json.loads(res.stdout)
    assert info["pings"] == N and info["samples_per_ping"] == T and info["signal_kind"] == "baseband"
    assert info["band_hz"] == [PULSE["f_start"], PULSE["f_stop"]] and info["pulse_samples"] == 100
    assert info["scene_box_m"] == BOX and info["warnings"] == []


def test_the_docs_writer_example_runs_and_loads(tmp_path: Path) -> None:
    """The h5py example in docs/formats.md, run as written, makes a file `shsas info` accepts."""
    text = DOC.read_text()
    section = text[text.index("### Writing a survey with another tool"):]
    code = re.search(r"```python\n(.*?)```", section, re.S)
    assert code, "no python example under 'Writing a survey with another tool'"
    (tmp_path / "example.py").write_text(code.group(1))
    run = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    res = _cli("info", "--json", "scan.h5", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    info = json.loads(res.stdout)
    assert info["platform"] == "my-sonar" and info["pings"] == 36 and info["warnings"] == []


# -- the two pulse descriptions disagree ---------------------------------------------------------

def _disagreeing(kind: str) -> np.ndarray:
    if kind == "other band":  # a 30-45 kHz chirp where meta says 10-30 kHz
        return doc_pulse(30e3, 45e3, 1e-3, FS, "hann", 0.0)
    if kind == "other length":  # 3 ms where meta says 1 ms
        return doc_pulse(10e3, 30e3, 3e-3, FS, "hann", 0.0)
    # sampled at 200 kHz, stored as if at meta.fs = 100 kHz: the band seems halved
    return doc_pulse(10e3, 30e3, 1e-3, 2 * FS, "hann", 0.0)


@pytest.mark.parametrize("kind", ["other band", "other length", "other rate"])
def test_disagreeing_pulse_descriptions_get_a_warning(tmp_path: Path, kind: str) -> None:
    write_from_tables(tmp_path / "scan.h5", pulse=_disagreeing(kind))
    s = load_survey(tmp_path / "scan.h5")  # the library still loads it ...
    msg = pulse_disagreement(s.meta, s.pulse)
    assert msg and msg.startswith("pulse/samples: ") and "disagree" in msg and "(fix: " in msg
    res = _cli("info", "scan.h5", cwd=tmp_path)  # ... and `shsas info` says what is wrong
    assert res.returncode == 0, res.stderr
    assert res.stderr.strip() == f"shsas info: warning: {msg}"
    res = _cli("info", "--json", "scan.h5", cwd=tmp_path)
    assert json.loads(res.stdout)["warnings"] == [msg]


# -- every error names a fix -----------------------------------------------------------------------

META_ERRORS = [
    ({"pulse.f_begin": 1e4}, "meta.pulse.f_begin", "Extra inputs"),
    ({"pulse": {"f_begin": 1e4}}, "meta.pulse.f_begin", "Extra inputs"),
    ({"sample_rate": 1e5}, "meta.sample_rate", "Extra inputs"),
    ({"fs": -1}, "meta.fs", "greater than 0"),
    ({"fs": "fast"}, "meta.fs", "valid number"),
    ({"signal_kind": "iq"}, "meta.signal_kind", "'real', 'analytic' or 'baseband'"),
    ({"platform": "x" * 65}, "meta.platform", "at most 64"),
    ({"scene_box.min": [0, 0]}, "meta.scene_box.min", "three numbers"),
    ({"scene_box.min": [0, 0, 0, 0]}, "meta.scene_box.min", "at most 3 items"),
    ({"scene_box.min": [1, 1, 1], "scene_box.max": [0, 0, 0]}, "meta.scene_box", "must exceed min"),
    ({"fs": 40e3}, "meta", "not above twice"),
    ({"signal_kind": "baseband"}, "meta", "carrier_hz is required"),
    ({"pulse.f_start": 1e4, "pulse": {"f_start": 2e4}}, "meta.pulse.f_start", "given twice"),
    ({"pulse": 3, "pulse.f_start": 1e4}, "meta.pulse", "both as a value"),
    ("[1, 2]", "meta", "JSON object"),
    ("{fs: 1}", "meta", "not valid JSON"),
]


@pytest.mark.parametrize(("meta", "field", "problem"), META_ERRORS, ids=[e[1] + ":" + e[2] for e in META_ERRORS])
def test_meta_errors_name_the_field_and_a_fix(meta, field: str, problem: str) -> None:
    with pytest.raises(SurveyValidationError) as ei:
        parse_meta(meta if isinstance(meta, str) else json.dumps(meta))
    msg = str(ei.value)
    assert msg.startswith(f"{field}: ") and problem in msg, msg
    assert re.search(r"\(fix: [^)]+", msg), msg


def test_every_malformed_file_error_carries_a_fix(tmp_path: Path) -> None:
    from tests.core.formats.test_malformed import CASES

    missing = []
    for build, _field, _problem in CASES:
        folder = tmp_path / build.__name__
        folder.mkdir()
        with pytest.raises(ShsasError) as ei:
            load_survey(build(folder))
        if "(fix: " not in str(ei.value):
            missing.append(f"{build.__name__}: {ei.value}")
    assert not missing, "\n".join(missing)


def test_meta_fields_nested_dotted_or_mixed_are_the_same() -> None:
    nested = {"fs": 1e5, "pulse": {"f_start": 1e4, "f_stop": 3e4, "window": "hann"},
              "scene_box": {"min": [-1, -1, 0], "max": [1, 1, 1]}, "attrs": {"writer": "x"}}
    dotted = {"fs": 1e5, "pulse.f_start": 1e4, "pulse.f_stop": 3e4, "pulse.window": "hann",
              "scene_box.min": [-1, -1, 0], "scene_box.max": [1, 1, 1], "attrs.writer": "x"}
    mixed = {"fs": 1e5, "pulse": {"f_start": 1e4}, "pulse.f_stop": 3e4, "pulse.window": "hann",
             "scene_box": {"min": [-1, -1, 0], "max": [1, 1, 1]}, "attrs.writer": "x"}
    want = parse_meta(json.dumps(nested))
    assert want.pulse.window == "hann" and want.attrs == {"writer": "x"}
    assert parse_meta(json.dumps(dotted)) == want == parse_meta(mixed)
