"""The format registry: each format is recognised by its own sniff alone, options are validated
against the detected format's model with one-line errors naming the option, and a format
registered from outside is detected, loaded and named for the service's stored input."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from pydantic import Field

from shsas_core.cli import main as cli_main
from shsas_core.common.errors import ShsasError, SurveyValidationError, UnsupportedFormatError
from shsas_core.data.survey import SceneBox, Survey, parse_meta
from shsas_core.formats import (
    Claim,
    Format,
    ImportOptions,
    all_formats,
    detect_format,
    format_names,
    get_format,
    load_survey,
    register,
    stored_name,
    unregister,
)
from shsas_core.formats.airsas_csv import AirSASCSVOptions
from shsas_core.formats.canonical import STORED_NAME
from shsas_core.formats.hdf5 import write_survey
from shsas_core.formats.probe import Probe
from shsas_core.formats.svss import SVSSOptions
from tests.conftest import make_survey
from tests.helpers.importer_data import AirSASScan, SVSSTrack, write_airsas_pickle


def _zip(folder: Path, dest: Path) -> Path:
    with zipfile.ZipFile(dest, "w") as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, f"{folder.name}/{p.relative_to(folder)}")
    return dest


def _deconvolved(folder: Path) -> Path:
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):
        np.save(folder / f"weights_trans_{4 * k}_{4 * k + 3}.npy", rng.standard_normal((4, 608)).astype(np.float16))
    return folder


@pytest.fixture(scope="module")
def samples(tmp_path_factory) -> dict[str, list[Path]]:
    """Format name -> files of that format: each folder format as a folder and as a zip."""
    tmp = tmp_path_factory.mktemp("samples")
    scan = AirSASScan()
    airsas = scan.write(tmp / "scan")
    pickle = tmp / "system_data.pik"
    write_airsas_pickle(pickle, scan)
    track = SVSSTrack().write(tmp / "svss")
    dec = _deconvolved(tmp / "dec")
    return {
        "shsas": [write_survey(make_survey(n=4, t=200), tmp / "canonical.h5")],
        "airsas-csv": [airsas, _zip(airsas, tmp / "scan.zip")],
        "airsas-pickle": [pickle],
        "svss": [track, _zip(track, tmp / "track.zip"), track / "unpack float - LF - down - 7.hdf5"],
        "airsas-deconvolved": [dec, _zip(dec, tmp / "dec.zip")],
    }


def test_every_built_in_format_has_samples_here(samples) -> None:
    assert set(samples) == set(format_names())


@pytest.mark.parametrize("name", ["shsas", "airsas-csv", "airsas-pickle", "svss", "airsas-deconvolved"])
def test_each_format_is_claimed_by_its_own_sniff_only(samples, name) -> None:
    for path in samples[name]:
        probe = Probe(path)
        sure = [f.name for f in all_formats() if f.sniff(probe) == Claim.YES]
        assert sure == [name], (path.name, sure)
        assert detect_format(path) == name
        assert load_survey(path, load_samples=False).num_pings > 0


def test_unclaimed_files_fall_back_to_the_reader_that_names_what_is_missing(tmp_path) -> None:
    (tmp_path / "notes.txt").write_text("hello")
    h5 = tmp_path / "other.h5"
    import h5py

    with h5py.File(h5, "w") as f:
        f["x"] = np.zeros(3)
    assert detect_format(h5) == "shsas"  # the canonical reader then says the format attribute is missing
    assert detect_format(_zip(tmp_path, tmp_path.parent / "misc.zip")) == "airsas-csv"
    with pytest.raises(UnsupportedFormatError, match="not a recognised survey") as ei:
        detect_format(tmp_path / "notes.txt")
    for f in all_formats():  # the message lists every registered format
        assert f.summary in str(ei.value)


def test_every_format_stores_its_input_as_the_canonical_file() -> None:
    assert {f.name: f.stored_name for f in all_formats()} == dict.fromkeys(format_names(), STORED_NAME)
    assert stored_name("airsas-deconvolved") == "survey.h5"


# ---------------------------------------------------------------------------------------------
# options


@pytest.mark.parametrize(("name", "options", "field", "problem"), [
    ("svss", {"background": "bg"}, "background", "is not an option of svss surveys"),
    ("shsas", {"waveform": 1}, "waveform", "shsas surveys take no options"),
    ("airsas-csv", {"waveform": -1}, "waveform", "greater than or equal to 0"),
    ("airsas-csv", {"mic": "two"}, "mic", "valid integer"),
    ("airsas-csv", {"pulse": "measured"}, "pulse", "'file' or 'analytic'"),
    ("svss", {"temperature_f": float("nan")}, "temperature_f", "finite"),
    ("airsas-deconvolved", {"geometry": 3}, "geometry", "got 3"),
    ("airsas-pickle", {"scene_box": {"min": [0, 0, 0], "max": [1, 1, 0]}}, "scene_box", "exceed"),
])
def test_bad_options_are_one_line_naming_the_option(samples, name, options, field, problem) -> None:
    with pytest.raises(SurveyValidationError) as ei:
        load_survey(samples[name][0], load_samples=False, **options)
    msg = str(ei.value)
    assert ei.value.field == field and msg.startswith(f"{field}: "), msg
    assert problem in msg and "(fix: " in msg and "\n" not in msg, msg


def test_options_as_the_model_a_mapping_or_keywords_agree(samples) -> None:
    folder = samples["airsas-csv"][0]
    box = SceneBox(min=(-0.3, -0.3, 0.0), max=(0.3, 0.3, 0.25))
    a = load_survey(folder, options=AirSASCSVOptions(scene_box=box, pulse="analytic"), load_samples=False)
    b = load_survey(folder, options={"scene_box": box}, pulse="analytic", load_samples=False)
    c = load_survey(folder, scene_box=box, pulse="analytic", load_samples=False)
    assert a.meta == b.meta == c.meta and a.meta.scene_box == box
    np.testing.assert_array_equal(a.pulse, c.pulse)


def test_the_options_model_of_another_format_is_refused(samples) -> None:
    with pytest.raises(SurveyValidationError, match=r"^options: are SVSSOptions, but the file is a airsas-csv"):
        load_survey(samples["airsas-csv"][0], options=SVSSOptions(image_number=1))


def test_cli_option_that_does_not_apply_is_one_line(samples, tmp_path, capsys) -> None:
    """`shsas convert TRACK --background X` used to reach the SVSS reader as a keyword it does
    not take: a TypeError and a traceback instead of a message."""
    code = cli_main(["convert", str(samples["svss"][0]), str(tmp_path / "out.h5"), "--background", "bg"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("shsas convert: error: background: is not an option of svss surveys"), err
    assert len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------------------------
# a format registered from outside

MAGIC = b"TOYSURV1"


class ToyOptions(ImportOptions):
    gain: float = Field(1.0, gt=0, description="multiplies every sample")


def _toy_sniff(probe: Probe) -> Claim:
    return Claim.YES if probe.kind == "file" and probe.head.startswith(MAGIC) else Claim.NO


def _toy_read(path: Path, options: ToyOptions, load_samples: bool, progress) -> Survey:
    """A text survey: the magic line, then one ping per line of samples (monostatic at the origin)."""
    rows = np.array([[float(v) for v in line.split()] for line in path.read_text().splitlines()[1:]])
    n, t = rows.shape
    meta = parse_meta({"fs": 100e3, "platform": "toy", **({"scene_box": options.scene_box.model_dump()}
                                                          if options.scene_box else {})})
    pulse = np.hanning(16)
    return Survey(tx=np.zeros((n, 3)), rx=np.zeros((n, 3)), t0=np.zeros(n), meta=meta, pulse=pulse,
                  samples=(rows * options.gain).astype(np.float32) if load_samples else None, shape=(n, t))


@pytest.fixture
def toy():
    fmt = register(Format(name="toy", summary="a toy text survey", sniff=_toy_sniff, read=_toy_read,
                          options=ToyOptions, stored_name="toy.txt"))
    yield fmt
    unregister("toy")


def _toy_file(path: Path) -> Path:
    rows = "\n".join(" ".join(str(v) for v in np.arange(40) * (k + 1)) for k in range(3))
    path.write_bytes(MAGIC + b"\n" + rows.encode())
    return path


def test_a_registered_format_is_detected_loaded_and_stored_by_name(toy, tmp_path, samples) -> None:
    path = _toy_file(tmp_path / "scan.toy")
    assert detect_format(path) == "toy"
    s = load_survey(path, gain=2.0)
    assert s.shape == (3, 40) and s.meta.platform == "toy"
    np.testing.assert_array_equal(s.samples[1], 4.0 * np.arange(40))
    assert stored_name("toy") == "toy.txt" and get_format("toy") is toy
    with pytest.raises(SurveyValidationError, match=r"^gain: .*greater than 0"):
        load_survey(path, gain=0)
    for name, paths in samples.items():  # it claims nothing of the others
        assert detect_format(paths[0]) == name


def test_a_registered_format_is_read_by_the_cli(toy, tmp_path) -> None:
    path = _toy_file(tmp_path / "scan.toy")
    assert cli_main(["convert", str(path), str(tmp_path / "toy.h5")]) == 0
    assert load_survey(tmp_path / "toy.h5").shape == (3, 40)


def test_names_are_unique_and_unknown_names_are_refused(toy) -> None:
    with pytest.raises(ValueError, match="already registered"):
        register(toy)
    with pytest.raises(ShsasError, match="unknown format 'nope'.*toy"):
        load_survey("x", fmt="nope")


def test_the_cli_offers_every_registered_format(toy, capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "2000")  # no wrapping inside a hyphenated name
    with pytest.raises(SystemExit):
        cli_main(["convert", "--help"])
    shown = " ".join(capsys.readouterr().out.split())  # argparse wraps the lines
    for f in all_formats():
        assert f"{f.name}: {' '.join(f.summary.split())}" in shown
    assert "toy" in [f.name for f in all_formats()]
