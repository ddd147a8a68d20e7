"""A single-height survey's report: the elevation note, the plane of best focus found over
every height the geometry allows (or a warning that there is none), the focus measure along
height, and the object's size beside the range resolution; a 3-D survey keeps the projections."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import Grid, Volume
from shsas_core.formats.hdf5 import summarize
from shsas_core.outputs.focus import add_focus
from shsas_core.outputs.report import Report, ReportFigures, render_html
from shsas_core.signal.deconv import deconvolve
from shsas_core.spec.job import ReconstructionSpec
from tests.helpers.focus_scenes import BOX, PLANE_Z, plane_scene


def _volume(box: SceneBox) -> Volume:
    g = Grid(box.min, box.max, (10, 10, 10))
    return Volume(g, np.ones(g.shape, dtype=np.float32))


@pytest.fixture(scope="module")
def scene():
    s = plane_scene()
    return s, deconvolve(s)


def _render(survey, signals) -> tuple[str, dict]:
    summary = summarize(survey)
    figs = ReportFigures(volumes={"backprojection": _volume(survey.meta.scene_box)})
    add_focus(summary, figs, survey, signals)
    rep = Report(spec=ReconstructionSpec(methods=["backprojection"]), survey=summary, ground_truth=False)
    return render_html(rep, figs), summary


def test_single_height_report_shows_the_plane_found_below_the_box(scene):
    """The scene box starts 30 mm above the points' plane: the report's plane is still theirs."""
    s, sig = scene
    high = SceneBox(min=(BOX.min[0], BOX.min[1], PLANE_Z + 0.03), max=BOX.max)
    s = dataclasses.replace(s, meta=s.meta.model_copy(update={"scene_box": high}))
    page, summary = _render(s, sig)
    elev = summary["elevation"]
    assert elev["focus"]["found"] and elev["focus_height_m"] == pytest.approx(PLANE_Z, abs=2e-3)
    assert len(elev["focus"]["heights_m"]) == len(elev["focus"]["costs"]) > 10
    assert f"Plane of best focus (z = {elev['focus_height_m']:.3f} m)" in page
    assert "single-height survey" in page and "Maximum-intensity projections" not in page
    assert 'alt="focus measure along height"' in page
    # the outline comes with the range resolution beside it
    assert elev["outline"]["range_resolution_m"] == pytest.approx(s.meta.range_resolution)
    assert f"c / 2B = <b>{1e3 * s.meta.range_resolution:.1f} mm</b>" in page
    assert not summary["warnings"]


def test_no_focus_gives_a_warning_and_the_projections(scene, monkeypatch):
    """A search that stops 30 mm above the points' plane: its sharpest plane is its edge."""
    import shsas_core.imaging.planar as planar

    s, sig = scene
    full = planar.search_range(s)
    monkeypatch.setattr(planar, "search_range", lambda survey: (PLANE_Z + 0.03, full[1]))
    page, summary = _render(s, sig)
    focus = summary["elevation"]["focus"]
    assert not focus["found"] and "focus_height_m" not in summary["elevation"]
    assert focus["reason"] in summary["warnings"]
    assert "No plane of focus found" in page and "Maximum-intensity projections" in page
    assert "class='warn'" in page and "<b>survey</b>" in page


def test_3d_report_keeps_the_projections(scene):
    from tests.helpers.focus_scenes import levels_scene

    s = levels_scene(angles=12, levels=10)
    summary = summarize(s)
    assert summary["elevation"]["kind"] == "3d"
    figs = ReportFigures(volumes={"backprojection": _volume(s.meta.scene_box)})
    add_focus(summary, figs, s, np.zeros(s.shape, dtype=np.complex64))
    assert "focus" not in summary["elevation"]
    page = render_html(Report(spec=ReconstructionSpec(methods=["backprojection"]), survey=summary,
                              ground_truth=False), figs)
    assert "Maximum-intensity projections" in page and "Plane of best focus" not in page
