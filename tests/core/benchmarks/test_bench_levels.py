"""benchmarks/bench_levels.py: its decibel Otsu rule against a brute-force between-class-variance
search, and its re-scoring against the pipeline's own point cloud at the same τ."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.bench_scripts import load_bench


@pytest.fixture(scope="module")
def levels():
    return load_bench("bench_levels")


def brute_otsu(x: np.ndarray, candidates: np.ndarray) -> float:
    """The candidate level maximising w0 w1 (mu0 - mu1)^2 over the raw values (no histogram)."""
    best, best_t = -1.0, float(candidates[0])
    for t in candidates:
        lo, hi = x[x < t], x[x >= t]
        if len(lo) == 0 or len(hi) == 0:
            continue
        v = len(lo) * len(hi) * (lo.mean() - hi.mean()) ** 2
        if v > best:
            best, best_t = v, float(t)
    return best_t


def test_otsu_db_matches_a_brute_force_search_on_the_decibel_scale(levels) -> None:
    rng = np.random.default_rng(3)
    norm = np.concatenate([rng.uniform(1e-4, 3e-3, 5000), rng.uniform(0.02, 0.1, 800), rng.uniform(0.5, 1, 400)])
    db = 20 * np.log10(np.maximum(norm, 10 ** (levels.DB_FLOOR / 20)))
    ref_db = brute_otsu(db, np.linspace(db.min(), db.max(), 2001)[1:])
    got_db = 20 * np.log10(levels.otsu_db(norm))
    bin_width = (db.max() - db.min()) / 256  # skimage's histogram
    assert abs(got_db - ref_db) <= 1.5 * bin_width


def test_rescore_scores_the_same_cloud_as_the_pipeline_at_each_tau(levels) -> None:
    import trimesh

    from shsas_core.data.survey import SceneBox
    from shsas_core.data.volume import Grid, Volume
    from shsas_core.evaluation.extract import point_cloud
    from shsas_core.evaluation.metrics import GroundTruth, score_points

    box = SceneBox(min=(-0.05, -0.05, -0.05), max=(0.05, 0.05, 0.05))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    gt = GroundTruth(mesh.vertices, mesh.faces, box)
    grid = Grid(box_min=box.min, box_max=box.max, shape=(24, 24, 24))
    r = np.linalg.norm(grid.points(), axis=1).reshape(grid.shape)
    # a Gaussian shell on the sphere plus a dim offset shell, so the rules pick different τ
    shell = np.exp(-((r - 0.03) / 0.004) ** 2) + 0.08 * np.exp(-((r - 0.04) / 0.003) ** 2)
    vol = Volume(grid, shell.astype(np.float32))
    out = levels.rescore(vol, gt)
    assert set(out) == set(levels.RULES)
    for name, s in out.items():
        want = score_points(point_cloud(vol, s["tau"]).points, gt)
        for key in ("surface_f1", "solid_f1", "chamfer_l2", "fscore"):
            assert s[key] == pytest.approx(want[key]), (name, key)
    assert out["paper"]["tau"] == pytest.approx(0.2) and out["fixed0.1"]["tau"] == pytest.approx(0.1)



def test_rescore_fog_scores_the_products_extraction_with_the_step_off_and_on(levels) -> None:
    import trimesh

    from shsas_core.data.survey import SceneBox
    from shsas_core.data.volume import Grid, Volume
    from shsas_core.evaluation.extract import ExtractConfig, extract
    from shsas_core.evaluation.metrics import GroundTruth, score_reconstruction

    box = SceneBox(min=(-0.05, -0.05, -0.05), max=(0.05, 0.05, 0.05))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    gt = GroundTruth(mesh.vertices, mesh.faces, box)
    grid = Grid(box_min=box.min, box_max=box.max, shape=(32, 32, 32))
    x = grid.points()
    r = np.linalg.norm(x, axis=1).reshape(grid.shape)
    # the sphere's shell plus a faint flat sheet in a corner: a fog for the step to remove
    sheet = 0.12 * np.exp(-(((x[:, 2] + 0.04) / 0.003) ** 2)).reshape(grid.shape)
    sheet *= ((np.abs(x[:, 0] - 0.035) < 0.012) & (np.abs(x[:, 1] - 0.035) < 0.012)).reshape(grid.shape)
    vol = Volume(grid, np.maximum(np.exp(-((r - 0.03) / 0.004) ** 2), sheet).astype(np.float32))
    sensors = np.array([[1.0, 0.0, 0.3], [0.0, 1.0, 0.3], [-1.0, 0.0, 0.3], [0.0, -1.0, 0.3]])
    out = levels.rescore_fog(vol, gt, sensors, 0.01, 0.05)
    assert set(out) == {"ridge", "ridge+fog"}
    for name, cfg in (("ridge", ExtractConfig()), ("ridge+fog", ExtractConfig(fog_share=0.05))):
        tau, cloud, m = extract(vol, cfg, sensors, 0.01)
        want = score_reconstruction(cloud.points, m, gt)
        assert out[name]["points"] == len(cloud) and out[name]["tau"] == pytest.approx(tau)
        for key in levels.FOG_SCORES:
            assert out[name][key] == pytest.approx(want[key]), (name, key)
    assert set(levels.rescore_fog(vol, gt, sensors, 0.01, None)) == {"ridge"}

def _shell_case(open_above: float | None = None):
    """A 2-voxel-thick spherical shell (radius 12 voxels) on a 40³ grid, and 300 views on a sphere
    of radius 1 m around it (Fibonacci points). ``open_above``: remove the shell above this
    height, in radii."""
    from shsas_core.data.volume import Grid

    grid = Grid(box_min=(-0.05, -0.05, -0.05), box_max=(0.05, 0.05, 0.05), shape=(40, 40, 40))
    h = float(grid.spacing[0])
    x = grid.points().reshape(*grid.shape, 3)
    r = np.linalg.norm(x, axis=-1)
    radius = 12 * h
    shell = np.abs(r - radius) < h
    if open_above is not None:
        shell &= x[..., 2] <= open_above * radius
    k = np.arange(300) + 0.5
    z = 1 - 2 * k / 300
    phi = np.pi * (1 + 5**0.5) * k
    views = np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], -1)
    return grid, r, radius, shell, views, x


def test_hidden_voxels_of_a_closed_shell_are_exactly_its_inside(levels) -> None:
    grid, r, radius, shell, views, _ = _shell_case()
    hidden = levels.hidden_voxels(shell, grid, views, ~shell)
    inside = (r < radius) & ~shell
    assert inside.sum() > 1000
    np.testing.assert_array_equal(hidden, inside)


def test_hidden_voxels_through_an_opening_are_seen(levels) -> None:
    grid, r, radius, shell, views, x = _shell_case(open_above=0.5)
    hidden = levels.hidden_voxels(shell, grid, views, ~shell)
    inside = (r < radius) & ~shell
    assert not (hidden & ~inside).any()  # never hides the outside
    centre = tuple(np.unravel_index(np.argmin(r), r.shape))
    assert not hidden[centre]  # seen from above through the opening
    assert hidden[inside & (x[..., 2] < -0.7 * radius)].mean() < 1.0


def test_hidden_band_stops_at_its_depth(levels) -> None:
    from scipy.ndimage import distance_transform_edt

    grid, r, radius, shell, views, _ = _shell_case()
    h = float(grid.spacing[0])
    band = levels.with_hidden_band(shell, grid, views, 3 * h)
    dist = distance_transform_edt(~shell, sampling=grid.spacing)
    want = shell | ((r < radius) & (dist <= 3 * h))
    np.testing.assert_array_equal(band, want)
    assert (band & ~shell).sum() > 500
