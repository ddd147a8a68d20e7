"""`shsas edit`: round trips, subsets whose metadata stays true, one-line errors, the help."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from shsas_core.cli import build_parser, main
from shsas_core.formats.hdf5 import read_survey, write_survey
from tests.helpers.focus_scenes import levels_scene


@pytest.fixture(scope="module")
def survey_file(tmp_path_factory):
    s = levels_scene(angles=12, levels=3)
    s = dataclasses.replace(s, meta=s.meta.model_copy(
        update={"attrs": {**s.meta.attrs, "height_levels": 3, "pings_per_level": 12}}))
    path = tmp_path_factory.mktemp("edit") / "in.h5"
    write_survey(s, path)
    return path


def _datasets(path) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()].tobytes()) if isinstance(obj, h5py.Dataset)
                     else None)
    return out


def test_sound_speed_plus_two_percent_and_back_gives_the_same_payload(survey_file, tmp_path, capsys):
    """Compared dataset by dataset: the files differ in meta.attrs['edits'], the log of edits."""
    c0 = read_survey(survey_file, load_samples=False).meta.sound_speed
    assert main(["edit", str(survey_file), str(tmp_path / "up.h5"), "--sound-speed", "+2%"]) == 0
    up = read_survey(tmp_path / "up.h5", load_samples=False)
    assert up.meta.sound_speed == pytest.approx(1.02 * c0, rel=1e-12)
    assert main(["edit", str(tmp_path / "up.h5"), str(tmp_path / "back.h5"), "--sound-speed", repr(c0)]) == 0
    back = read_survey(tmp_path / "back.h5", load_samples=False)
    assert back.meta.sound_speed == c0
    assert _datasets(tmp_path / "back.h5") == _datasets(survey_file)
    strip = {"attrs"}
    assert back.meta.model_dump(exclude=strip) == read_survey(survey_file, load_samples=False).meta.model_dump(
        exclude=strip)
    assert "sound_speed" in back.meta.attrs["edits"] and "wrote" in capsys.readouterr().out


@pytest.mark.parametrize("argv,pings,per_level,levels", [
    (["--every", "3"], 12, 4, 3),
    (["--levels", "0,2"], 24, 12, 2),
    (["--levels", "1:3", "--every", "2"], 12, 6, 2),
    (["--count", "10"], 10, None, 3),
])
def test_subsets_metadata_matches_the_pings(survey_file, tmp_path, argv, pings, per_level, levels):
    from shsas_core.data.geometry import height_levels

    out = tmp_path / "sub.h5"
    assert main(["edit", str(survey_file), str(out), *argv]) == 0
    s = read_survey(out)
    counts = np.bincount(height_levels(s.tx).index)
    assert s.num_pings == pings == s.samples.shape[0] and len(counts) == levels == s.meta.attrs["height_levels"]
    assert s.meta.attrs.get("pings_per_level") == per_level
    if per_level is not None:
        assert np.all(counts == per_level)


def test_geometry_edits_land_in_the_file(survey_file, tmp_path):
    from shsas_core.data.geometry import height_levels

    out = tmp_path / "geo.h5"
    before = read_survey(survey_file)
    z = [round(float(h) + 0.01, 6) for h in height_levels(before.tx).heights]
    argv = ["edit", str(survey_file), str(out), "--range-offset", "0.002", "--box=-0.1,-0.1,-0.05,0.1,0.1,0.1",
            "--level-z", ",".join(map(str, z)), "--sound-speed", "-1.5"]
    assert main(argv) == 0
    s = read_survey(out)
    assert s.meta.scene_box.min == (-0.1, -0.1, -0.05) and s.meta.scene_box.max == (0.1, 0.1, 0.1)
    assert np.allclose(height_levels(s.tx).heights, z)
    assert s.meta.sound_speed == pytest.approx(before.meta.sound_speed - 1.5)
    assert np.allclose(s.t0, before.t0 - 2 * 0.002 / (before.meta.sound_speed - 1.5))
    assert json.dumps(s.meta.attrs["edits"]).count(";") == 3


@pytest.mark.parametrize("argv,needle", [
    ([], "nothing to edit"),
    (["--sound-speed", "fast"], "--sound-speed"),
    (["--sound-speed", "5000"], "sound_speed"),
    (["--sound-speed=-200%"], "sound_speed"),
    (["--box", "1,2,3"], "--box"),
    (["--box", "0,0,0,-1,1,1"], "--box"),
    (["--levels", "7"], "--levels"),
    (["--levels", "a:b"], "--levels"),
    (["--every", "0"], "--every"),
    (["--count", "1000"], "--count"),
    (["--level-z", "0.1,0.2"], "--level-z"),
    (["--range-offset", "50"], "before transmit"),
])
def test_bad_input_one_line_exit_2(survey_file, tmp_path, capsys, argv, needle):
    rc = main(["edit", str(survey_file), str(tmp_path / "x.h5"), *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("shsas edit: error:") and needle in err
    assert not (tmp_path / "x.h5").exists()


def test_missing_input_is_one_line(tmp_path, capsys):
    assert main(["edit", str(tmp_path / "none.h5"), str(tmp_path / "x.h5"), "--count", "3"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_help_explains_every_option():
    sub = next(a for a in build_parser()._subparsers._group_actions if a.choices)  # type: ignore[union-attr]
    edit = sub.choices["edit"]
    for action in edit._actions:
        if action.dest != "help":
            assert action.help and len(action.help) > 20, action.dest
