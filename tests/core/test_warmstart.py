"""Warm start: distilling an image into the field (shsas_core.warmstart)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from shsas_core.deconv import deconvolve
from shsas_core.errors import ShsasError
from shsas_core.extract import extract, field_volume
from shsas_core.fields import FieldConfig, HashEncodingConfig, SHField
from shsas_core.metrics import GroundTruth, score_points
from shsas_core.simulate import simulate_shape
from shsas_core.survey import SceneBox
from shsas_core.train import coarse_start_levels, fit
from shsas_core.volume import Grid, Volume
from shsas_core.warmstart import INV_SQRT_4PI, WarmStartConfig, distill, image_target, sample_image

SMALL = HashEncodingConfig(n_levels=6, log2_table_size=12, base_resolution=4, finest_resolution=64)


def _blob(grid: Grid) -> np.ndarray:
    """A complex Gaussian blob with a phase ramp: smooth, so a small field can represent it."""
    p = grid.points()
    c = (np.asarray(grid.box_min) + np.asarray(grid.box_max)) / 2
    r2 = ((p - c) ** 2).sum(1) / 0.03**2
    return (np.exp(-r2) * np.exp(1j * 40 * p[:, 0])).reshape(grid.shape).astype(np.complex64)


def test_sample_image_matches_scipy_trilinear() -> None:
    grid = Grid((-0.1, -0.1, 0.0), (0.1, 0.1, 0.15), (8, 9, 7))
    vals = np.random.default_rng(0).normal(size=grid.shape).astype(np.float32)
    target = torch.from_numpy(vals)[None, None]
    # points between the first and last voxel centres, where no border clamp applies
    lo, d = np.asarray(grid.box_min), grid.spacing
    u_min = (lo + d / 2 - lo) / (np.asarray(grid.box_max) - lo)
    u = u_min + np.random.default_rng(1).random((500, 3)) * (1 - 2 * u_min)
    ref = RegularGridInterpolator(grid.axes(), vals.astype(np.float64))(lo + u * (np.asarray(grid.box_max) - lo))
    got = sample_image(target, torch.from_numpy(u).float())[0].numpy()
    np.testing.assert_allclose(got, ref, atol=1e-5)


def test_image_target_scales_peak_and_keeps_phase() -> None:
    grid = Grid((0, 0, 0), (1, 1, 1), (4, 4, 4))
    vals = np.zeros(grid.shape, np.complex64)
    vals[1, 2, 3] = 2j
    vals[0, 0, 0] = -1.0
    t = image_target(Volume(grid, vals), peak=3.0)
    assert t.shape == (1, 2, 4, 4, 4)
    assert float(t[0, 1, 1, 2, 3]) == pytest.approx(3.0) and float(t[0, 0, 0, 0, 0]) == pytest.approx(-1.5)
    with pytest.raises(ShsasError, match="all zero"):
        image_target(Volume(grid, np.zeros(grid.shape, np.complex64)), 1.0)


def test_distill_reproduces_a_complex_image() -> None:
    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    grid = Grid.over(box, 24)
    vol = Volume(grid, _blob(grid))
    torch.manual_seed(0)
    field = SHField(FieldConfig(sh_degree=1, scene_box=box, encoding=SMALL))
    res = distill(field, vol, WarmStartConfig(steps=300, batch=4096, peak=2.0))
    assert res.loss_history[-1] < 0.05 * res.loss_history[0]
    with torch.no_grad():
        c00 = field.coefficients(torch.from_numpy(grid.points()).float())[:, 0].numpy() * INV_SQRT_4PI
    want = 2.0 * vol.values.ravel() / np.abs(vol.values).max()
    rel = np.linalg.norm(c00 - want) / np.linalg.norm(want)
    assert rel < 0.2, rel


@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason="known gap (issue 12): with 2^15-row hash tables the default "
                   "fit ended slightly below its start on this sphere (F1 0.1811 -> 0.1775 on a 2-core "
                   "AMD EPYC; 0.1815 -> 0.1723 on an Intel Xeon with the averaged weights); with 2^17 "
                   "rows it passed on the Intel Xeon (0.1696 -> 0.1747) but not on the AMD EPYC (0.1866 "
                   "-> 0.1848); with coarse-to-fine levels (the default since e418990, the start distilled "
                   "with the 8 coarse levels as the pipeline does) the Intel Xeon gives 0.1658 -> 0.1604 "
                   "and the AMD EPYC 0.1715 -> 0.1700, so it stays marked until it passes")
def test_fit_from_backprojection_scores_no_worse_than_its_start() -> None:
    """The issue's guarantee on a tiny scene: a short fit at the job spec's defaults (point-spread
    forward model, occupancy grid and sparsity prior from the same image), started from the
    distilled backprojection image, ends with a point-cloud F1 at least that of the started field."""
    from shsas_core.backprojection import backproject_survey
    from shsas_core.deconv import point_spread
    from shsas_core.fields.occupancy import MaskedField, OccupancyConfig, OccupancyGrid
    from shsas_core.pipeline import deconv_config, train_config
    from shsas_core.spec import ReconstructionSpec

    spec = ReconstructionSpec(iters=150)
    survey = simulate_shape("sphere", heights=4, angles=60, snr_db=20.0, seed=0)
    s_pd = np.asarray(deconvolve(survey, deconv_config(spec)), dtype=np.complex64)
    box = survey.meta.scene_box
    grid = Grid.over(box, 48)
    image = backproject_survey(survey, grid, s_pd)
    gt = GroundTruth.from_survey(survey)
    torch.manual_seed(0)
    field = SHField(FieldConfig(sh_degree=3, scene_box=box))
    if spec.coarse_to_fine is not None:  # as the pipeline: the start holds the levels the fit starts with
        field.set_active_levels(coarse_start_levels(field.config.encoding))
    distill(field, image, WarmStartConfig(steps=150))
    assert spec.occupancy is not None
    occupancy = OccupancyGrid.from_volume(image, OccupancyConfig(level=spec.occupancy))
    model = MaskedField(field, occupancy)

    def f1() -> float:
        _tau, cloud, _mesh = extract(field_volume(model, grid))
        return score_points(cloud.points, gt)["f1"]

    start = f1()
    fit(field, survey, s_pd, train_config(spec), psf=point_spread(survey, deconv_config(spec)),
        occupancy=occupancy)
    end = f1()
    assert start > 0.1, start  # the distilled image holds the surface already
    print(f"F1 start {start:.4f} end {end:.4f}")
    assert end >= start, (start, end)
