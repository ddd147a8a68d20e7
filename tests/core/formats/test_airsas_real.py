"""The public AirSAS cut-out scan (../shared/data/airsas), read in place: import with background
subtraction, the single-height verdict, the cut-out's size in the focused plane, and autofocus
recovering errors put into its sound speed and range offset (docs/notebook/2026-11-lab-notebook.md, "Real data")."""

from __future__ import annotations

import dataclasses

import pytest

from shsas_core.data.geometry import elevation_info
from shsas_core.data.survey import SceneBox
from shsas_core.imaging.autofocus import AutofocusConfig, autofocus
from shsas_core.imaging.planar import outline, plane_image
from shsas_core.imaging.sharpness import image_entropy
from tests.conftest import shared_dir
from tests.helpers.focus_scenes import perturbed

#: The cut-out as the issue and the data's README give it: about 90 mm x 210 mm.
CUTOUT_SIZE_M = (0.090, 0.210)
SIZE_TOLERANCE_M = 0.005
#: Plane images cover the turntable around the cut-out at 2 mm pixels.
PLANE_BOX = SceneBox(min=(-0.15, -0.15, -0.05), max=(0.15, 0.15, 0.2))


@pytest.fixture(scope="module")
def scan(airsas_cutout):
    """(survey, deconvolved signals, plane of best focus): tests/conftest.py's session copy."""
    return airsas_cutout


def test_import_is_a_single_height_scan_with_background_removed(scan):
    s, _, z_focus = scan
    assert s.shape == (360, 937) and s.meta.attrs["background_subtracted"] is True
    info = elevation_info(s)
    assert info.kind == "single-height" and info.levels == 1
    # the plane of best focus lies near the turntable (the nominal geometry's z = 0): measured
    # -11.5 mm, which a range offset of about +3.5 mm would also explain
    assert -0.03 < z_focus < 0.03


def test_info_says_single_height(scan, capsys):
    import json

    from shsas_core.cli import main

    folder = shared_dir() / "data" / "airsas" / "cutout_20k"
    assert main(["info", "--json", str(folder)]) == 0
    elev = json.loads(capsys.readouterr().out)["elevation"]
    assert elev["kind"] == "single-height" and "no elevation aperture" in elev["message"]


def test_cutout_extent_and_sharp_edges(scan):
    s, sig, _ = scan
    img = plane_image(s, sig, 0.0, longest=150, box=PLANE_BOX)  # the z = 0 slice
    o = outline(img.values, img.grid)
    assert o.extent_m == pytest.approx(CUTOUT_SIZE_M, abs=SIZE_TOLERANCE_M)
    # sharp: the plain short (y) edges fall from 90 % to 10 % within two range resolutions
    # c / 2B, the notched long (x) edges within four (measured 10-13 and 28-31 mm) ...
    res = s.meta.sound_speed / (2 * s.meta.pulse.bandwidth)
    assert max(o.edge_fall_m[2:]) < 2 * res and max(o.edge_fall_m[:2]) < 4 * res
    # ... which a 2 % sound-speed error undoes (measured 39-50 mm), and the image is sharper
    # than with either error
    for rel in (0.02, -0.02):
        c = s.meta.sound_speed * (1 + rel)
        wrong = dataclasses.replace(s, meta=s.meta.model_copy(update={"sound_speed": c}))
        img2 = plane_image(wrong, sig, 0.0, longest=150, box=PLANE_BOX)
        assert image_entropy(img2.values) > image_entropy(img.values) + 0.1
        if rel > 0:
            assert min(outline(img2.values, img2.grid).edge_fall_m) > 2 * res


# One case runs in make test-fast, the others (5-10 CPU s each) in make test only: the simulated
# scenes of tests/core/imaging/test_autofocus.py cover both signs of a sound-speed error and the
# range offset in the fast loop, and this first case keeps the real recording's path there.
_SLOW = pytest.mark.slow


@pytest.mark.parametrize("rel,dr", [(0.02, 0.0), pytest.param(-0.02, 0.0, marks=_SLOW),
                                    pytest.param(0.0, 0.005, marks=_SLOW), pytest.param(0.0, -0.005, marks=_SLOW)])
def test_autofocus_recovers_perturbed_sound_speed_and_range_offset(scan, rel, dr):
    """One parameter at a time, in the plane of best focus under the nominal geometry: on a
    single-height scan, c, the range offset and the plane's height trade off (see
    shsas_core.imaging.autofocus), so the other two are held."""
    s, _, z_focus = scan
    bad = perturbed(s, sound_speed_rel=rel, range_offset_m=dr)
    param = "sound_speed" if rel else "range_offset"
    res = autofocus(bad, config=AutofocusConfig(parameters=(param,), plane_z=z_focus))
    # the search finds the error put in ...
    assert res.estimate.sound_speed / s.meta.sound_speed - 1 == pytest.approx(0.0, abs=0.002)
    assert res.estimate.range_offset_m == pytest.approx(dr, abs=0.001)
    # ... and what it applies is never further off: a 2 % sound-speed error is identified; the
    # 5 mm offsets (0.6 range cells) sit at the subsets' agreement bound (measured scatter
    # 0.88 mm against the bound of 0.86 mm), so they may be kept
    assert abs(res.correction.range_offset_m - dr) <= abs(dr) + 1e-12
    if rel:
        assert res.identifiability[0].identified
        assert res.correction.sound_speed / s.meta.sound_speed - 1 == pytest.approx(0.0, abs=0.002)


#: The cut-out's plane of focus in the converted frame (docs/notebook/2026-11-lab-notebook.md, "Real data").
CUTOUT_FOCUS_Z = -0.0115
#: The report's plane must lie this close to it, or say there is none.
FOCUS_TOLERANCE_M = 0.010


def _report(survey, out):
    """Backprojection of the scan through the pipeline; report.json and report.html."""
    from shsas_core.outputs.report import load_report
    from shsas_core.pipeline.job import run
    from shsas_core.spec.job import ReconstructionSpec

    res = run(ReconstructionSpec(methods=["backprojection"], grid=32, device="cpu"), survey, out)
    return load_report(res.report_json), (out / "report.html").read_text()


def _check_focus(report, page) -> dict:
    """The report's plane is within FOCUS_TOLERANCE_M of the cut-out's focus, or the report
    says (json and page) that there is none."""
    focus = report.survey["elevation"]["focus"]
    lo, hi = focus["search_range_m"]
    box = report.survey["scene_box_m"]
    assert lo < box["min"][2] and hi > box["max"][2]  # not the scene box's heights
    if focus["found"]:
        assert report.survey["elevation"]["focus_height_m"] == pytest.approx(CUTOUT_FOCUS_Z, abs=FOCUS_TOLERANCE_M)
        assert f"Plane of best focus (z = {focus['z_m']:.3f} m)" in page
        assert "range resolution c / 2B" in page
    else:
        assert focus["reason"] in report.survey["warnings"] and "No plane of focus found" in page
    return focus


@pytest.mark.slow
def test_report_plane_of_the_wideband_scan(scan, tmp_path):
    s, _, _ = scan
    report, page = _report(s, tmp_path)
    focus = _check_focus(report, page)
    assert focus["found"]  # 20 kHz of band: the plane is fixed to about a centimetre
    out = report.survey["elevation"]["outline"]
    assert out["range_resolution_m"] == pytest.approx(s.meta.range_resolution)
    assert out["extent_m"] == pytest.approx(CUTOUT_SIZE_M, abs=3 * s.meta.range_resolution)


@pytest.mark.slow
def test_report_plane_of_the_band_limited_scan(scan, tmp_path):
    """The same recording filtered to 5 kHz around 20 kHz (34 mm range resolution)."""
    from tests.helpers.narrowband import band_limited

    s, _, _ = scan
    narrow = band_limited(s, 20e3, 5e3)
    assert narrow.meta.range_resolution == pytest.approx(4 * s.meta.range_resolution)
    report, page = _report(narrow, tmp_path)
    _check_focus(report, page)
