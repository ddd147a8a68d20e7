"""Warm start: distilling an image into the field (shsas_core.neural.warmstart)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import Grid, Volume
from shsas_core.neural.fields import HashEncodingConfig, SHField
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.fields.occupancy import OccupancyConfig, OccupancyGrid
from shsas_core.neural.warmstart import (
    INV_SQRT_4PI,
    WarmStartConfig,
    distill,
    image_target,
    sample_image,
)
from tests.helpers.bench_scripts import load_bench

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


def test_distill_inside_a_mask_reads_the_field_only_there_and_a_full_mask_changes_nothing() -> None:
    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    grid = Grid.over(box, 24)
    vol = Volume(grid, _blob(grid))
    occ = OccupancyGrid.from_volume(vol, OccupancyConfig(level=0.2, dilate_voxels=1))
    assert 0.01 < occ.fraction < 0.5
    cfg = WarmStartConfig(steps=150, batch=4096, peak=2.0)

    def started(occupancy: OccupancyGrid | None) -> tuple[SHField, list[torch.Tensor]]:
        torch.manual_seed(0)
        field = SHField(FieldConfig(sh_degree=1, scene_box=box, encoding=SMALL))
        seen: list[torch.Tensor] = []
        read = field.coefficients

        def coefficients(x: torch.Tensor) -> torch.Tensor:
            seen.append(x.detach().clone())
            return read(x)

        field.coefficients = coefficients  # type: ignore[method-assign]
        distill(field, vol, cfg, occupancy=occupancy)
        field.coefficients = read  # type: ignore[method-assign]
        return field, seen

    plain, _ = started(None)
    full, _ = started(OccupancyGrid.full(grid))
    for a, b in zip(plain.parameters(), full.parameters(), strict=True):
        assert torch.equal(a, b)
    masked, seen = started(occ)
    pts = torch.cat(seen)
    assert bool(occ.lookup(pts).all())  # every point regressed lies in the mask
    assert 0.5 * occ.fraction < len(pts) / (cfg.steps * cfg.batch) < 2 * occ.fraction
    # inside the mask it reproduces the image as well as the plain start does
    inside = occ.mask.numpy().ravel()
    x = torch.from_numpy(grid.points()[inside]).float()
    want = 2.0 * vol.values.ravel()[inside] / np.abs(vol.values).max()
    with torch.no_grad():
        err = {name: np.linalg.norm(f.coefficients(x)[:, 0].numpy() * INV_SQRT_4PI - want) / np.linalg.norm(want)
               for name, f in (("plain", plain), ("masked", masked))}
    assert err["masked"] < max(0.25, 1.5 * err["plain"]), err


def test_distill_reproduces_a_complex_image() -> None:
    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    grid = Grid.over(box, 24)
    vol = Volume(grid, _blob(grid))
    torch.manual_seed(0)
    field = SHField(FieldConfig(sh_degree=1, scene_box=box, encoding=SMALL))
    # 150 steps end well inside both bounds (measured: loss ratio 0.002, relative error 0.052;
    # 300 steps gave 0.0005 and 0.033) at half the cost
    res = distill(field, vol, WarmStartConfig(steps=150, batch=4096, peak=2.0))
    assert res.loss_history[-1] < 0.05 * res.loss_history[0]
    with torch.no_grad():
        c00 = field.coefficients(torch.from_numpy(grid.points()).float())[:, 0].numpy() * INV_SQRT_4PI
    want = 2.0 * vol.values.ravel() / np.abs(vol.values).max()
    rel = np.linalg.norm(c00 - want) / np.linalg.norm(want)
    assert rel < 0.2, rel


@pytest.mark.slow
def test_fit_from_backprojection_scores_no_worse_than_its_start(shared: Path) -> None:
    """The issue's guarantee on a small scene: SH-SAS started from the distilled backprojection
    image as the pipeline does (spec defaults: point-spread forward model, occupancy grid and
    sparsity prior from the same image), fitted for 300 iterations, ends with a point-cloud
    surface F1 (design §5's primary score, of the default ridge extraction) at least that of the
    started field and of the image itself.

    The scene is the Stanford bunny (6 x 90 pings, 48^3 grid): its mesh is open underneath, so its
    occupancy (design §5) is its surface band and F1 scores the surface the fit sharpens. The
    solid sphere this test used before counts its unobservable inside, so a sharper shell loses
    recall there whatever the fit does (docs/notebook/2026-11-lab-notebook.md, "Does the fit end above its start?")."""
    bench = load_bench("bench_warmstart")
    case = bench.warm_start_case(str(shared / "data" / "meshes" / "bunny.obj"), seed=0)
    print(case)
    assert case.image["surface_f1"] > 0.2, case  # the image holds the surface already
    assert case.loss_ratio < 0.9, case  # the fit learnt the data
    assert case.end["surface_f1"] >= case.start["surface_f1"], case
    assert case.end["surface_f1"] >= case.image["surface_f1"], case

