"""Malformed inputs: each is rejected with a message naming the field, in-process and by the CLI.

Every case builds one bad file (or folder), checks ``load_survey`` raises a ShsasError whose
message names the field, then runs the real CLI (``python -m shsas_core.cli info PATH``) and
checks exit code 2, a single line on stderr naming the field, and no traceback.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from shsas_core.common.errors import ShsasError
from shsas_core.formats import load_survey
from shsas_core.formats.hdf5 import write_survey
from tests.conftest import make_survey
from tests.helpers.importer_data import AirSASScan, SVSSTrack

ROOT = Path(__file__).resolve().parents[3]


def _valid(tmp: Path) -> Path:
    return write_survey(make_survey(n=8, t=512), tmp / "s.h5")


def _replace(path: Path, name: str, data) -> Path:
    with h5py.File(path, "a") as f:
        del f[name]
        f[name] = data
    return path


def _meta(path: Path, **changes) -> Path:
    with h5py.File(path, "a") as f:
        meta = json.loads(f.attrs["meta"])
        meta.update(changes)
        f.attrs["meta"] = json.dumps(meta)
    return path


# -- builders: tmp folder -> bad path ---------------------------------------------------------


def truncated(tmp):
    p = _valid(tmp)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return p


def tx_wrong_shape(tmp):
    return _replace(_valid(tmp), "pings/tx", np.zeros((8, 2)))


def t0_wrong_length(tmp):
    return _replace(_valid(tmp), "pings/t0", np.full(7, 3e-3))


def nan_position(tmp):
    s = make_survey(n=8, t=512)
    tx = s.tx.copy()
    tx[3, 1] = np.nan
    return _replace(_valid(tmp), "pings/tx", tx)


def fs_too_low(tmp):
    return _meta(_valid(tmp), fs=40e3)


def sound_speed_zero(tmp):
    return _meta(_valid(tmp), sound_speed=0.0)


def zero_pings(tmp):
    p = _valid(tmp)
    for name, data in (("pings/samples", np.zeros((0, 512), np.float32)), ("pings/tx", np.zeros((0, 3))),
                       ("pings/rx", np.zeros((0, 3))), ("pings/t0", np.zeros(0))):
        _replace(p, name, data)
    return p


def external_link(tmp):
    p = _valid(tmp)
    with h5py.File(tmp / "other.h5", "w") as f:
        f["tx"] = np.zeros((8, 3))
    with h5py.File(p, "a") as f:
        del f["pings/tx"]
        f["pings/tx"] = h5py.ExternalLink(str(tmp / "other.h5"), "/tx")
    return p


def virtual_dataset(tmp):
    p = _valid(tmp)
    with h5py.File(tmp / "src.h5", "w") as f:
        f["data"] = np.arange(4.0)
    layout = h5py.VirtualLayout(shape=(4,), dtype="f8")
    layout[:] = h5py.VirtualSource(str(tmp / "src.h5"), "data", shape=(4,))
    with h5py.File(p, "a") as f:
        f.create_group("extras").create_virtual_dataset("mapped", layout)
    return p


def external_storage(tmp):
    p = _valid(tmp)
    raw = tmp / "raw.bin"
    raw.write_bytes(np.arange(4.0).tobytes())
    with h5py.File(p, "a") as f:
        f.create_group("extras").create_dataset("outside", shape=(4,), dtype="f8", external=[(str(raw), 0, 32)])
    return p


def code_executing_pickle(tmp):
    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch '{tmp / 'pwned'}'",))

    p = tmp / "system_data.pik"
    p.write_bytes(pickle.dumps({"wfm_data": np.zeros((2, 4)), "payload": Evil()}, protocol=4))
    return p


def csv_missing_sysparams(tmp):
    folder = AirSASScan().write(tmp / "scan")
    (folder / "SysParams.csv").unlink()
    return folder


def csv_flights_out_of_order(tmp):
    folder = AirSASScan().write(tmp / "scan")
    lines = (folder / "Coordinates.csv").read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    (folder / "Coordinates.csv").write_text("\n".join(lines) + "\n")
    return folder


def csv_bad_waveform_params(tmp):
    folder = AirSASScan().write(tmp / "scan")
    (folder / "WaveformParams.csv").write_text("chirp from ten to thirty\n")
    return folder


def csv_flight_length_differs(tmp):
    folder = AirSASScan().write(tmp / "scan")
    f3 = folder / "Flight-000003.csv"
    f3.write_text("\n".join(f3.read_text().splitlines()[:-5]) + "\n")
    return folder


def missing_dataset(tmp):
    p = _valid(tmp)
    with h5py.File(p, "a") as f:
        del f["pings/t0"]
    return p


def wrong_format_attribute(tmp):
    p = _valid(tmp)
    with h5py.File(p, "a") as f:
        f.attrs["format"] = "some-other-survey"
    return p


def wrong_schema_version(tmp):
    p = _valid(tmp)
    with h5py.File(p, "a") as f:
        f.attrs["schema_version"] = 2
    return p


def scene_box_inverted(tmp):
    return _meta(_valid(tmp), scene_box={"min": [0.1, -0.1, 0.0], "max": [-0.1, 0.1, 0.2]})


def declared_size_over_limit(tmp):
    p = _valid(tmp)
    with h5py.File(p, "a") as f:
        del f["pings/samples"]
        # declared only: HDF5 allocates contiguous storage late, so the file stays small
        f["pings"].create_dataset("samples", shape=(8, 1_000_001), dtype="f4")
    assert p.stat().st_size < 1_000_000
    return p


def garbage_file(tmp):
    p = tmp / "upload.h5"
    p.write_bytes(np.random.default_rng(0).bytes(4096))
    return p


def zip_path_traversal(tmp):
    p = tmp / "scan.zip"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("scan/Coordinates.csv", "Flight,Angle,Height,Temperature,Waveform\n1,0,0,20,0\n")
        zf.writestr("../escaped.txt", "written outside")
    return p


def svss_imag_shape_mismatch(tmp):
    tr = SVSSTrack()
    folder = tr.write(tmp)
    with h5py.File(folder / f"unpack float - LF - down - {tr.number}.hdf5", "a") as f:
        del f["DataImag"]
        f["DataImag"] = np.zeros((tr.rows, tr.n_samples - 1), np.float32)
    return folder


# (builder, text that names the field, text that names the problem)
CASES: list[tuple[Callable[[Path], Path], str, str]] = [
    (truncated, "file", "truncated or corrupt"),
    (tx_wrong_shape, "pings/tx", "shape (8, 2)"),
    (t0_wrong_length, "pings/t0", "shape (7,)"),
    (nan_position, "pings/tx", "non-finite position at ping 3"),
    (fs_too_low, "meta", "fs=40000 Hz is not above twice"),
    (sound_speed_zero, "meta.sound_speed", "greater than or equal to 300"),
    (zero_pings, "pings/samples", "no pings"),
    (external_link, "pings/tx", "external link"),
    (virtual_dataset, "extras/mapped", "virtual dataset"),
    (external_storage, "extras/outside", "external raw storage"),
    (code_executing_pickle, "pickle", f"'{os.system.__module__}.system'"),
    (csv_missing_sysparams, "SysParams.csv", "is missing"),
    (csv_flights_out_of_order, "Coordinates.csv: flight", "expected 2"),
    (csv_bad_waveform_params, "WaveformParams.csv: row 1", "cannot parse"),
    (csv_flight_length_differs, "Flight-000003.csv", "same length"),
    (missing_dataset, "pings/t0", "is missing"),
    (wrong_format_attribute, "format", "'some-other-survey'"),
    (wrong_schema_version, "schema_version", "is 2"),
    (scene_box_inverted, "meta.scene_box", "must exceed min"),
    (declared_size_over_limit, "pings/samples", "exceeds the limit"),
    (garbage_file, "file", "not a recognised survey"),
    (zip_path_traversal, "zip", "path traversal"),
    (svss_imag_shape_mismatch, "DataImag", "differs from DataReal"),
]


def _run_cli(path: Path, command: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    args = [str(path)] if command == "info" else [str(path), str(path.parent / "out.h5")]
    return subprocess.run([sys.executable, "-m", "shsas_core.cli", command, *args],
                          capture_output=True, text=True, env=env, cwd=path.parent, timeout=120)


@pytest.mark.parametrize(("build", "field", "problem"), CASES, ids=[c[0].__name__ for c in CASES])
def test_malformed_input_is_rejected_by_name(tmp_path, build, field, problem):
    path = build(tmp_path)
    with pytest.raises(ShsasError) as ei:
        load_survey(path)
    msg = str(ei.value)
    assert msg.startswith(field) or f"{field}:" in msg, msg
    assert problem in msg, msg

    # `info` reads headers only, so a bad sample file is caught by `convert`, which reads all
    command = "convert" if build is csv_flight_length_differs else "info"
    res = _run_cli(path, command)
    assert res.returncode == 2, res.stderr
    err = res.stderr.strip()
    assert "Traceback" not in res.stderr and "\n" not in err, res.stderr
    assert not (path.parent / "out.h5").exists()
    assert err.startswith(f"shsas {command}: error: ") and field in err and problem in err, err
    # nothing the file asked for happened: no code ran, nothing escaped the extraction folder
    assert not (tmp_path / "pwned").exists()
    assert not (tmp_path / "escaped.txt").exists() and not (tmp_path.parent / "escaped.txt").exists()


def test_at_least_twelve_distinct_cases():
    assert len({c[0].__name__ for c in CASES}) >= 12
