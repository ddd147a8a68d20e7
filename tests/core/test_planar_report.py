"""A single-height survey's report: the elevation note and each method's plane of best focus
instead of projections over z; a 3-D survey keeps the projections."""

from __future__ import annotations

import numpy as np

from shsas_core.pipeline import _add_focus_height
from shsas_core.report import Report, ReportFigures, render_html
from shsas_core.spec import ReconstructionSpec
from shsas_core.volume import Grid, Volume


def _volume() -> Volume:
    """A 3-D volume whose slice at z = 0.05 holds a sharp point; the others a wide blur."""
    g = Grid((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (10, 10, 10))
    x, y, z = g.axes()
    X, Y = np.meshgrid(x, y, indexing="ij")
    vals = np.stack([np.exp(-(X**2 + Y**2) / (0.002 if abs(zk - 0.05) < 1e-9 else 0.05)) for zk in z], -1)
    return Volume(g, vals.astype(np.float32))


def _html(kind: str) -> tuple[str, dict]:
    summary = {"platform": "airsas", "pings": 360,
               "elevation": {"kind": kind, "levels": 1, "elevation_span_deg": 0.0,
                             "vertical_resolution_m": None, "message": f"{kind} survey: note"}}
    figs = ReportFigures(volumes={"backprojection": _volume(), "reed": _volume()})
    _add_focus_height(summary, figs)
    rep = Report(spec=ReconstructionSpec(methods=["backprojection"]), survey=summary, ground_truth=False)
    return render_html(rep, figs), summary


def test_single_height_report_shows_the_focused_plane():
    html, summary = _html("single-height")
    assert summary["elevation"]["focus_height_m"] == 0.05  # the sharp slice's centre
    assert "Plane of best focus (z = 0.050 m)" in html and "single-height survey: note" in html
    assert "Maximum-intensity projections" not in html


def test_3d_report_keeps_the_projections():
    html, summary = _html("3d")
    assert "focus_height_m" not in summary["elevation"]
    assert "Maximum-intensity projections" in html and "Plane of best focus" not in html
