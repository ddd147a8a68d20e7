"""The default extraction keeps the surface on surveys unlike the simulator's defaults.

Four variants (``shsas_core.simulation.variants``) of one small bunny survey (10 rings of 90
pings), each changing one thing the extraction must not depend on: records that start at transmit
and run long (``t0 = 0``, a guard of 700 samples), a scene box much larger and taller than the
object, another sample rate, and 5 dB SNR. On each the default
extraction of the backprojection image must keep points on the ground-truth surface (at least
70 % within 1 cm of the mesh, and a larger share than the paper's Otsu cloud keeps) and about as
many as the surface holds (its area over the voxel face), and the default mesh must be at most 3
pieces holding 95 % of its area, of 0.6-1.3 times the surface's area.

The large box is the hardest (0.73 within 1 cm measured): it keeps the image's elevation and
azimuth sidelobes above the object that the default box cuts off (with 180 pings a ring the
share is 0.90); docs/decisions/ridge-poisson-extraction.md has the other figures.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from shsas_core.data.volume import Grid, auto_grid_count
from shsas_core.evaluation.extract import extract, point_cloud
from shsas_core.imaging.backprojection import backproject_survey
from shsas_core.signal.deconv import deconvolve
from shsas_core.signal.sources import deconv_config
from shsas_core.simulation.shapes import load_mesh
from shsas_core.simulation.simulate import simulate_shape
from shsas_core.simulation.variants import variant_overrides
from shsas_core.spec.job import ReconstructionSpec

pytestmark = pytest.mark.slow


def pieces95(mesh) -> int:
    areas = np.sort([p.area for p in mesh.split(only_watertight=False)])[::-1]
    return int(np.searchsorted(np.cumsum(areas), 0.95 * areas.sum()) + 1)


@pytest.mark.parametrize("name", ["long_from_transmit", "large_box", "sample_rate", "snr_5db"])
def test_default_extraction_keeps_the_surface(name: str, shared) -> None:
    bunny = str(shared / "data" / "meshes" / "bunny.obj")
    kw = variant_overrides(name, load_mesh(bunny).bounds)
    snr = kw.pop("snr_db", 20.0)
    survey = simulate_shape(bunny, heights=10, angles=90, snr_db=snr, seed=0, **kw)
    if name == "long_from_transmit":
        assert np.all(survey.t0 == 0) and survey.num_samples > 900
    box = survey.meta.scene_box
    grid = Grid.over(box, auto_grid_count(box))
    s_pd = np.asarray(deconvolve(survey, deconv_config(ReconstructionSpec())), dtype=np.complex64)
    vol = backproject_survey(survey, grid, s_pd)
    gt = survey.ground_truth_mesh()
    tau, cloud, mesh = extract(vol, sensors=survey.tx, resolution=survey.meta.range_resolution)
    surface = cKDTree(gt.sample(200_000, seed=0))
    # Only "within 1 cm" is asked: a bounded query answers it exactly (inf beyond the bound)
    # without searching the tree for the nearest surface point of every far-off voxel, which
    # took ~40 s for the paper cloud's ~800,000 points on the large box.
    near = {"distance_upper_bound": 0.01}
    dist = surface.query(cloud.points, **near)[0]
    old = point_cloud(vol, tau)  # the paper's cloud: every voxel at or above the same τ
    old_share = np.mean(surface.query(old.points, **near)[0] < 0.01)
    gt_voxels = gt.area / float(np.min(grid.spacing)) ** 2
    assert np.mean(dist < 0.01) >= 0.7
    assert np.mean(dist < 0.01) > old_share
    assert 0.3 <= len(cloud) / gt_voxels <= 1.5
    assert pieces95(mesh) <= 3
    assert 0.6 <= mesh.area / gt.area <= 1.3
