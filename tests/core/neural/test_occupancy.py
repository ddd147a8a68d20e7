"""Occupancy grid and the masked field (shsas_core.neural.fields.occupancy)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import Grid, Volume
from shsas_core.neural.fields import HashEncodingConfig, SHField
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.fields.occupancy import MaskedField, OccupancyConfig, OccupancyGrid
from shsas_core.neural.fields.volume import field_volume
from shsas_core.neural.render import RenderConfig
from shsas_core.neural.train import TrainConfig, fit
from shsas_core.simulation.simulate import simulate_shape

SMALL = HashEncodingConfig(n_levels=6, log2_table_size=12, base_resolution=4, finest_resolution=64)
BOX = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))


def _field(degree: int = 2) -> SHField:
    torch.manual_seed(0)
    field = SHField(FieldConfig(sh_degree=degree, scene_box=BOX, encoding=SMALL))
    with torch.no_grad():  # a non-trivial field: the table's init is almost zero
        field.encoding.table.normal_(0, 0.5)
    return field


def test_lookup_matches_a_brute_force_loop() -> None:
    grid = Grid(BOX.min, BOX.max, (7, 5, 6))
    mask = np.random.default_rng(0).random(grid.shape) > 0.5
    occ = OccupancyGrid(grid, mask)
    pts = np.random.default_rng(1).uniform(-0.13, 0.23, size=(2000, 3))
    pts[:5] = np.nan
    got = occ.lookup(torch.from_numpy(pts)).numpy()
    lo, d = np.asarray(grid.box_min), grid.spacing
    want = np.zeros(len(pts), bool)
    for n, p in enumerate(pts):
        if not np.all(np.isfinite(p)):
            continue
        ijk = [int(np.floor((p[a] - lo[a]) / d[a])) for a in range(3)]
        if all(0 <= ijk[a] < grid.shape[a] for a in range(3)):
            want[n] = mask[ijk[0], ijk[1], ijk[2]]
    np.testing.assert_array_equal(got, want)
    assert 0.05 < got.mean() < 0.5  # some points in occupied voxels, most outside


def test_from_volume_is_a_level_then_a_dilation() -> None:
    grid = Grid(BOX.min, BOX.max, (12, 12, 12))
    vals = np.random.default_rng(2).normal(size=grid.shape) + 1j * np.random.default_rng(3).normal(size=grid.shape)
    vals[3, 4, 5] = 20.0
    occ = OccupancyGrid.from_volume(Volume(grid, vals.astype(np.complex64)), OccupancyConfig(level=0.15, dilate_voxels=1))
    mag = np.abs(vals)
    want = np.zeros(grid.shape, bool)
    for i, j, k in zip(*np.nonzero(mag > 0.15 * mag.max()), strict=True):  # every voxel within one step (26-neighbourhood)
        want[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2, max(k - 1, 0):k + 2] = True
    np.testing.assert_array_equal(occ.mask.numpy(), want)
    with pytest.raises(ShsasError, match="empty"):
        OccupancyGrid.from_volume(Volume(grid, np.zeros(grid.shape, np.complex64)))
    with pytest.raises(ShsasError, match="does not match"):
        OccupancyGrid(grid, np.ones((3, 3, 3), bool))


def test_the_floor_test_bounds_a_mask_that_the_level_alone_spreads_over_the_box() -> None:
    """An image with a floor above the level (as a real backprojection has): the level alone marks
    every voxel; with the floor test a voxel must also exceed floor_factor x the median
    magnitude. On a clean image (floor below the level) the floor test changes nothing."""
    grid = Grid(BOX.min, BOX.max, (10, 10, 10))
    rng = np.random.default_rng(4)
    mag = 0.1 + 0.02 * rng.random(grid.shape)  # a floor at about 0.1 of the peak
    mag[2:4, 5:7, 1:3] = rng.uniform(0.3, 1.0, size=(2, 2, 2))  # the scene
    vol = Volume(grid, (mag * np.exp(1j * rng.uniform(0, 6.3, size=grid.shape))).astype(np.complex64))
    level_only = OccupancyGrid.from_volume(vol, OccupancyConfig(level=0.05, dilate_voxels=0, floor_factor=0))
    assert level_only.mask.all()
    occ = OccupancyGrid.from_volume(vol, OccupancyConfig(level=0.05, dilate_voxels=0, floor_factor=2.0))
    want = (mag > 0.05 * mag.max()) & (mag > 2.0 * np.median(mag))  # numpy's own median of |image|
    np.testing.assert_array_equal(occ.mask.numpy(), want)
    assert occ.fraction == pytest.approx(8 / 1000)
    clean = np.zeros(grid.shape)
    clean[2:4, 5:7, 1:3] = mag[2:4, 5:7, 1:3]
    clean += 1e-3 * rng.random(grid.shape)
    cvol = Volume(grid, clean.astype(np.complex64))
    for dil in (0, 1):
        a = OccupancyGrid.from_volume(cvol, OccupancyConfig(level=0.05, dilate_voxels=dil))
        b = OccupancyGrid.from_volume(cvol, OccupancyConfig(level=0.05, dilate_voxels=dil, floor_factor=0))
        np.testing.assert_array_equal(a.mask.numpy(), b.mask.numpy())


def test_masked_field_is_the_field_inside_and_empty_outside() -> None:
    field = _field()
    grid = Grid(BOX.min, BOX.max, (10, 10, 10))
    mask = np.zeros(grid.shape, bool)
    mask[2:7, 3:8, 1:9] = True
    occ = OccupancyGrid(grid, mask)
    masked = MaskedField(field, occ)
    x = torch.from_numpy(np.random.default_rng(4).uniform(-0.1, 0.2, size=(3000, 3))).float()
    d = torch.nn.functional.normalize(torch.randn(3000, 3, generator=torch.Generator().manual_seed(5)), dim=1)
    inside = occ.lookup(x)
    assert 0.05 < inside.float().mean() < 0.5
    full = field(x, d, with_normals=True, create_graph=True)
    got = masked(x, d, with_normals=True, create_graph=True)
    for key in ("density", "scattering", "normals", "dc"):
        torch.testing.assert_close(got[key][inside], full[key][inside])
        assert torch.count_nonzero(got[key][~inside]) == 0
    torch.testing.assert_close(masked.coefficients(x)[inside], field.coefficients(x)[inside])
    # gradients reach the wrapped field's parameters exactly as the inside points' outputs send them
    w = torch.randn(3000, generator=torch.Generator().manual_seed(6))
    g_masked = torch.autograd.grad((got["scattering"].real * w).sum() + got["normals"].sum(),
                                   field.encoding.table)[0]
    sel = inside.to(w.dtype)
    g_ref = torch.autograd.grad((full["scattering"].real * w * sel).sum() + (full["normals"] * sel[:, None]).sum(),
                                field.encoding.table)[0]
    torch.testing.assert_close(g_masked, g_ref)
    vol = field_volume(masked, grid)
    assert np.count_nonzero(vol.values[~mask]) == 0 and np.count_nonzero(vol.values[mask]) == mask.sum()


def test_fit_with_a_full_mask_matches_the_plain_fit() -> None:
    """A mask that covers the whole box changes nothing (the field is empty outside the box)."""
    survey = simulate_shape("sphere", heights=2, angles=12, snr_db=30.0, seed=0)
    s = survey.samples.astype(np.complex64)
    box = survey.meta.scene_box
    # the paper's normal: the masked field evaluates a subset of the points, so its floats round
    # differently, and a window's normalised sums of the untrained field's near-zero gradients
    # amplify that (with the default window the two fits agree at steps 1-2, to 1e-3 at step 3 and
    # 2 % at step 4); the mask's own claim is checked where the rounding stays rounding
    cfg = TrainConfig(iters=4, num_bins=16, num_rays=64, seed=0, render=RenderConfig(normal_window=1))
    losses = []
    for occ in (None, OccupancyGrid.full(Grid.over(box, 16))):
        torch.manual_seed(0)
        field = SHField(FieldConfig(sh_degree=1, scene_box=box, encoding=SMALL))
        losses.append(fit(field, survey, s, cfg, occupancy=occ).loss_history)
    np.testing.assert_allclose(losses[1], losses[0], rtol=1e-4)
