"""Elevation-poor surveys: levels, classification, focus height, plane images, outlines."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shsas_core.data.geometry import elevation_info, height_levels
from shsas_core.data.survey import SceneBox, Survey, SurveyMeta, default_pulse
from shsas_core.data.volume import Grid, Volume
from shsas_core.imaging.planar import (
    FOCUS_MIN_DEPTH,
    find_focus,
    focus_height,
    outline,
    plane_grid,
    plane_image,
    search_range,
    volume_focus_height,
)
from shsas_core.signal.deconv import deconvolve
from tests.helpers.focus_scenes import BOX, NARROW_BAND_HZ, PLANE_POINTS, PLANE_Z, plane_scene


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
    from shsas_core.imaging.backprojection import backproject_survey

    grid = Grid(BOX.min, BOX.max, (24, 24, 12))  # 1 cm slices
    vz = volume_focus_height(Volume(grid, backproject_survey(s, grid, sig).values))
    assert vz == pytest.approx(PLANE_Z, abs=0.01)
    assert plane_grid(BOX, 0.0, 10).shape == (10, 10, 1)


def test_search_range_reaches_from_the_record_end_to_the_lowest_sensor(plane_survey):
    """Brute force: the two-way path from every sensor pair to the box's centre column, on a
    fine grid of heights; the deepest height every ping recorded is the search's floor unless
    the sensors' height mirrored below the box's floor is higher."""
    s, _ = plane_survey
    lo, hi = search_range(s)
    assert hi == pytest.approx(min(s.tx[:, 2].min(), s.rx[:, 2].min()))
    assert lo == pytest.approx(BOX.min[2] - (hi - BOX.min[2]))  # the record reaches deeper
    # a short record: its reach is the floor
    s = s.subset(slice(None))
    s.samples, s.shape = s.samples[:, :150], (s.num_pings, 150)
    lo, hi = search_range(s)
    zs = np.linspace(hi - 3.0, hi, 30001)
    c = BOX.center
    pts = np.stack([np.full_like(zs, c[0]), np.full_like(zs, c[1]), zs], 1)
    path = (np.linalg.norm(s.tx[:, None] - pts[None], axis=2) + np.linalg.norm(s.rx[:, None] - pts[None], axis=2))
    end = s.meta.sound_speed * (s.t0 + (s.num_samples - 1) / s.meta.fs)
    recorded = np.all(path <= end[:, None], axis=0)
    assert lo == pytest.approx(zs[recorded].min(), abs=2 * (zs[1] - zs[0]))
    assert lo < BOX.min[2]


def test_focus_below_the_scene_box_is_found(plane_survey):
    """The scene box says the scene is 30-110 mm above the points: the search is not the box's."""
    s, sig = plane_survey
    high = SceneBox(min=(BOX.min[0], BOX.min[1], PLANE_Z + 0.03), max=(BOX.max[0], BOX.max[1], PLANE_Z + 0.11))
    moved = dataclasses.replace(s, meta=s.meta.model_copy(update={"scene_box": high}))
    f = find_focus(moved, sig)
    assert f.found and f.reason is None
    assert f.z == pytest.approx(PLANE_Z, abs=2e-3)
    assert f.heights[0] < PLANE_Z < high.min[2] < f.heights[-1]


def test_a_focus_on_the_search_edge_is_not_found(plane_survey):
    s, sig = plane_survey
    f = find_focus(s, sig, z_range=(PLANE_Z + 0.03, 0.2))  # the sharpest plane is the lowest
    assert not f.found and f.z == pytest.approx(PLANE_Z + 0.03) and "lowest" in f.reason
    assert f.costs[0] == f.costs.min() and f.heights.shape == f.costs.shape


def test_a_flat_measure_is_not_a_focus(plane_survey):
    """An interior minimum that is no deeper than the measure's noise: not a focus."""
    s, sig = plane_survey
    f = find_focus(s, sig, z_range=(PLANE_Z - 0.001, PLANE_Z + 0.001))  # within the depth of focus
    assert not f.found and "flat" in f.reason
    assert min(f.costs[0], f.costs[-1]) - f.costs.min() < FOCUS_MIN_DEPTH


def test_narrowband_plane_is_found():
    """5 kHz of band (34 mm range resolution): the points' plane still focuses."""
    s = plane_scene(band_hz=NARROW_BAND_HZ, snr_db=20.0)
    f = find_focus(s, deconvolve(s))
    assert f.found and f.range_resolution_m == pytest.approx(s.meta.sound_speed / 10e3)
    assert f.z == pytest.approx(PLANE_Z, abs=5e-3)


def test_an_echo_at_one_delay_in_every_ping_does_not_take_the_focus():
    """A strong point on the rotation axis 55 mm below the plane returns at the same delay in
    every ping (a turntable scan's room echo does too): imaged, it is one sharp spot, sharper
    than the plane. The search leaves such returns out."""
    s = plane_scene(axis_echo=(PLANE_Z - 0.055, 5.0))
    sig = deconvolve(s)
    assert find_focus(s, sig).z == pytest.approx(PLANE_Z, abs=2e-3)
    # the spot is sharper than the plane: with the returns kept, it would be the focus
    from shsas_core.imaging.sharpness import image_entropy

    spot = plane_image(s, sig, PLANE_Z - 0.055, longest=48)
    plane = plane_image(s, sig, PLANE_Z, longest=48)
    assert image_entropy(spot.values) < image_entropy(plane.values)


def test_ping_mean_removal_matches_a_loop_over_delays(plane_survey):
    """Pings start whole samples apart: the mean is taken per absolute delay (brute force)."""
    from shsas_core.imaging.planar import _without_ping_mean

    s, _ = plane_survey
    rng = np.random.default_rng(3)
    n, t = 6, 20
    s = s.subset(np.arange(n))
    offsets = np.array([0, 3, 1, 3, 7, 2])
    s.t0 = s.t0.min() + offsets / s.meta.fs
    sig = (rng.standard_normal((n, t)) + 1j * rng.standard_normal((n, t))).astype(np.complex64)
    out = _without_ping_mean(s, sig)
    want = sig.copy()
    for i in range(n):
        for k in range(t):
            same = [sig[j, offsets[i] + k - offsets[j]] for j in range(n) if 0 <= offsets[i] + k - offsets[j] < t]
            if len(same) >= n / 2:
                want[i, k] -= np.mean(same)
    assert np.allclose(out, want, atol=1e-6)
    s.t0 = s.t0 + np.linspace(0, 0.3, n) / s.meta.fs  # not whole samples apart: left alone
    assert np.array_equal(_without_ping_mean(s, sig), sig)
