"""Elevation-poor surveys: levels, classification, focus height, plane images, outlines."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.deconv import deconvolve
from shsas_core.planar import (
    elevation_info,
    focus_height,
    height_levels,
    outline,
    plane_grid,
    plane_image,
    volume_focus_height,
)
from shsas_core.survey import Survey, SurveyMeta, default_pulse
from shsas_core.volume import Grid, Volume

from .focus_scenes import BOX, PLANE_POINTS, PLANE_Z, plane_scene


def _circle(heights: list[float], n: int = 36) -> Survey:
    ang = np.tile(np.linspace(0, 2 * np.pi, n, endpoint=False), len(heights))
    z = np.repeat(heights, n)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), z], 1)
    rx = np.stack([0.863 * np.cos(ang), 0.863 * np.sin(ang), z - 0.038], 1)
    meta = SurveyMeta(platform="test")
    samples = np.random.default_rng(0).standard_normal((len(tx), 800)).astype(np.float32)
    return Survey(tx=tx, rx=rx, samples=samples, t0=np.full(len(tx), 3e-3), meta=meta, pulse=default_pulse(meta))


def test_height_levels_group_like_a_brute_force_pairing():
    rng = np.random.default_rng(1)
    true_level = rng.integers(0, 4, 200)
    z = np.array([0.1, 0.15, 0.3, 0.31])[true_level] + rng.uniform(-2e-4, 2e-4, 200)
    tx = np.column_stack([np.zeros(200), np.zeros(200), z])
    lv = height_levels(tx)
    assert lv.count == 4
    # brute force: two pings share a level exactly when their true levels match
    same = lv.index[:, None] == lv.index[None, :]
    assert np.array_equal(same, true_level[:, None] == true_level[None, :])
    assert np.all(np.diff(lv.heights) > 0)
    assert np.allclose(lv.heights, [z[true_level == k].mean() for k in range(4)])


def test_elevation_kinds():
    single = elevation_info(_circle([0.25]))
    assert single.kind == "single-height" and single.planar and single.levels == 1
    assert "single-height" in single.message
    poor = elevation_info(_circle([0.25, 0.255]))  # 5 mm apart: no useful elevation aperture
    assert poor.kind == "elevation-poor" and poor.levels == 2
    assert poor.vertical_resolution_m > 0.1
    full = elevation_info(_circle(list(np.linspace(0.11, 0.86, 10))))
    assert full.kind == "3d" and not full.planar and full.vertical_resolution_m < 0.05


def test_outline_of_an_analytic_rim():
    """A rectangle's rim drawn as Gaussian ridges: every measure has a closed form."""
    grid = Grid((-0.1, -0.15, -0.001), (0.1, 0.15, 0.001), (400, 600, 1))
    x, y, _ = grid.axes()
    X, Y = np.meshgrid(x, y, indexing="ij")
    hw, hh, sigma = 0.03, 0.1, 0.002
    rim = np.maximum(np.exp(-0.5 * ((np.abs(X) - hw) / sigma) ** 2) * (np.abs(Y) <= hh),
                     np.exp(-0.5 * ((np.abs(Y) - hh) / sigma) ** 2) * (np.abs(X) <= hw))
    o = outline(rim[:, :, None], grid)
    half = sigma * np.sqrt(2 * np.log(2))  # crest to half height
    assert o.ridge_extent_m == pytest.approx((2 * hw, 2 * hh), abs=grid.spacing[0])
    assert o.extent_m == pytest.approx((2 * hw + 2 * half, 2 * hh + 2 * half), abs=2e-4)
    assert o.centre_m == pytest.approx((0.0, 0.0), abs=2e-4)
    fall = sigma * (np.sqrt(2 * np.log(10)) - np.sqrt(2 * np.log(1 / 0.9)))  # 90 % to 10 %
    assert np.allclose(o.edge_fall_m, fall, rtol=0.05)


@pytest.fixture(scope="module")
def plane_survey():
    s = plane_scene()
    return s, deconvolve(s)


def test_focus_height_finds_the_points_plane(plane_survey):
    s, sig = plane_survey
    assert elevation_info(s).kind == "single-height"
    z = focus_height(s, sig)
    assert z == pytest.approx(PLANE_Z, abs=2e-3)


def test_plane_image_peaks_on_the_points_and_volume_height_agrees(plane_survey):
    s, sig = plane_survey
    vol = plane_image(s, sig, PLANE_Z, longest=80)
    mag = np.abs(vol.values[:, :, 0])
    x, y, _ = vol.grid.axes()
    for px, py in PLANE_POINTS:
        i, j = np.argmin(np.abs(x - px)), np.argmin(np.abs(y - py))
        assert mag[i - 1:i + 2, j - 1:j + 2].max() > 0.5 * mag.max()
    # slices of a small volume: the sharpest lies on the points' plane
    from shsas_core.backprojection import backproject_survey

    grid = Grid(BOX.min, BOX.max, (24, 24, 12))  # 1 cm slices
    vz = volume_focus_height(Volume(grid, backproject_survey(s, grid, sig).values))
    assert vz == pytest.approx(PLANE_Z, abs=0.01)
    assert plane_grid(BOX, 0.0, 10).shape == (10, 10, 1)
