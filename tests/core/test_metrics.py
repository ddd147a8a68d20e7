import math

import numpy as np
import pytest
import trimesh

from shsas_core.errors import ShsasError
from shsas_core.metrics import (
    GroundTruth,
    OccupancyGrid,
    chamfer,
    fscore,
    nn_distances,
    occupancy_scores,
    point_triangle_distance,
    sample_surface,
    score_mesh,
    score_points,
    signal_errors,
    surface_concentration,
    within_distance_of_mesh,
)
from shsas_core.survey import SceneBox


def brute_nn(a, b):
    return np.array([min(np.linalg.norm(p - q) for q in b) for p in a])


def test_nn_distances_match_brute_force():
    rng = np.random.default_rng(1)
    a, b = rng.random((60, 3)), rng.random((45, 3))
    np.testing.assert_allclose(nn_distances(a, b), brute_nn(a, b), rtol=1e-12)


def test_chamfer_and_fscore_match_brute_force():
    rng = np.random.default_rng(2)
    a, b = rng.random((50, 3)) * 0.02, rng.random((70, 3)) * 0.02
    dab, dba = brute_nn(a, b), brute_nn(b, a)
    c = chamfer(a, b)
    assert c["chamfer_l2"] == pytest.approx(np.mean(dab**2) + np.mean(dba**2), rel=1e-12)
    assert c["chamfer_l1"] == pytest.approx(0.5 * (dab.mean() + dba.mean()), rel=1e-12)
    f = fscore(a, b, tau=0.004)
    p, r = np.mean(dab <= 0.004), np.mean(dba <= 0.004)
    assert f["fscore_precision"] == pytest.approx(p)
    assert f["fscore_recall"] == pytest.approx(r)
    assert f["fscore"] == pytest.approx(2 * p * r / (p + r))


def test_chamfer_of_shifted_sets_is_the_shift():
    # every point's nearest neighbour is its own shifted copy when the shift is small vs spacing
    g = np.stack(np.meshgrid(*[np.arange(5) * 0.1] * 3, indexing="ij"), -1).reshape(-1, 3)
    c = chamfer(g, g + np.array([0.01, 0, 0]))
    assert c["chamfer_l2"] == pytest.approx(2 * 0.01**2)
    assert c["chamfer_l1"] == pytest.approx(0.01)
    assert chamfer(np.zeros((0, 3)), g)["chamfer_l2"] == math.inf


def test_sample_surface_is_on_the_mesh_area_weighted_and_seeded():
    m = trimesh.creation.box(extents=(0.2, 0.1, 0.1))
    p = sample_surface(m.vertices, m.faces, 20000, seed=0)
    np.testing.assert_array_equal(p, sample_surface(m.vertices, m.faces, 20000, seed=0))
    h = np.array([0.1, 0.05, 0.05])
    # every point lies on the box surface: max over axes of |p|/h equals 1
    np.testing.assert_allclose(np.max(np.abs(p) / h, axis=1), 1.0, atol=1e-12)
    # the two 0.1 x 0.1 faces (x = ±0.1) hold 0.02 / 0.1 of the area
    share = np.mean(np.isclose(np.abs(p[:, 0]), 0.1))
    assert share == pytest.approx(0.2, abs=0.01)


def test_point_triangle_distance_analytic():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    pts = np.array([[0.2, 0.2, 0.5],      # above the face
                    [-1.0, -1.0, 0.0],    # vertex region of a
                    [2.0, 0.0, 1.0],      # vertex region of b
                    [0.5, -2.0, 0.0],     # edge ab
                    [1.0, 1.0, 0.0],      # edge bc
                    [0.1, 0.1, 0.0]])     # on the triangle
    exp = [0.5, math.sqrt(2), math.sqrt(2), 2.0, math.sqrt(0.5), 0.0]
    n = len(pts)
    d = point_triangle_distance(pts, np.tile(a, (n, 1)), np.tile(b, (n, 1)), np.tile(c, (n, 1)))
    np.testing.assert_allclose(d, exp, atol=1e-12)


def test_within_distance_of_cube_matches_box_distance():
    m = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.08, 0.08, (4000, 3))
    q = np.abs(p) - 0.05
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = -np.max(q, axis=1)
    dist = np.where(np.all(q <= 0, axis=1), inside, outside)  # unsigned distance to the surface
    got = within_distance_of_mesh(p, m.vertices, m.faces, 0.01)
    np.testing.assert_array_equal(got, dist <= 0.01)


def test_occupancy_scores_known_sets():
    gt = np.zeros((4, 4, 4), bool)
    gt[:2] = True          # 32 voxels
    pred = np.zeros_like(gt)
    pred[1:3] = True       # 32 voxels, 16 shared
    s = occupancy_scores(pred, gt)
    assert s["iou"] == pytest.approx(16 / 48)
    assert s["precision"] == pytest.approx(0.5)
    assert s["recall"] == pytest.approx(0.5)
    assert s["f1"] == pytest.approx(0.5)
    with pytest.raises(ShsasError):
        occupancy_scores(pred[:2], gt)


def test_gt_occupancy_equals_contains_or_band_for_watertight_mesh():
    box = SceneBox(min=(-0.06, -0.06, 0.0), max=(0.06, 0.06, 0.1))
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.035)
    m.apply_translation([0.003, -0.002, 0.05])
    grid = OccupancyGrid(box, 0.005)
    occ = grid.from_mesh(m.vertices, m.faces)
    c = grid.centres()
    ref = m.contains(c) | within_distance_of_mesh(c, m.vertices, m.faces, 0.005)
    np.testing.assert_array_equal(occ.ravel(), ref)
    assert occ.sum() > 1000


def test_two_cubes_offset_by_known_distance():
    """Two unit-style cubes (4 cm) offset along x by 3 mm: point metrics follow analytically."""
    box = SceneBox(min=(-0.05, -0.05, 0.0), max=(0.05, 0.05, 0.1))
    a = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    a.apply_translation([0.0012, 0.0007, 0.0503])  # faces off the voxel boundaries
    gt = GroundTruth(a.vertices, a.faces, box)
    same = score_mesh(a.vertices, a.faces, gt)
    assert same["chamfer_l2"] < 1e-7 and same["fscore"] == pytest.approx(1.0)
    # a perfect surface lies inside the GT occupancy (solid + band) but covers only its shell:
    # precision 1, and IoU = recall = shell voxels / GT voxels
    assert same["precision"] == 1.0 and same["iou"] == pytest.approx(same["recall"])
    shell = gt.grid.from_points(sample_surface(a.vertices, a.faces, 200000, seed=9))
    assert same["recall"] == pytest.approx(shell.sum() / gt.occupancy.sum(), abs=0.01)
    shift = np.array([0.003, 0, 0])
    b = a.copy()
    b.apply_translation(shift)
    pb = sample_surface(b.vertices, b.faces, 20000, seed=5)
    s = score_points(pb, gt)
    # exact point-to-surface distances of a 4 cm box (analytic) bound the sampled Chamfer from
    # below; the GT sample spacing (~0.7 mm) bounds the excess from above
    centre = np.array([0.0012, 0.0007, 0.0503])

    def box_dist(p, c):
        q = np.abs(p - c) - 0.02
        return np.where(np.all(q <= 0, 1), -q.max(1), np.linalg.norm(np.maximum(q, 0), axis=1))

    d_ba, d_ab = box_dist(pb, centre), box_dist(gt.samples, centre + shift)
    exact_l1 = 0.5 * (d_ba.mean() + d_ab.mean())
    assert 0.0008 < exact_l1 < 0.0012  # mostly the ±x faces (1/3 of the area) at 3 mm
    assert exact_l1 <= s["chamfer_l1"] <= exact_l1 + 4e-4
    exact_l2 = np.mean(d_ba**2) + np.mean(d_ab**2)
    assert exact_l2 <= s["chamfer_l2"] <= exact_l2 + 2 * 2 * 0.003 * 4e-4 + 2 * 4e-4**2
    far = b.copy()
    far.apply_translation([0.02, 0, 0])
    s2 = score_points(sample_surface(far.vertices, far.faces, 20000, seed=5), gt)
    assert s2["chamfer_l2"] > s["chamfer_l2"] and s2["fscore"] < s["fscore"]


def test_signal_errors():
    t = np.array([[1 + 1j, 0, 2j]])
    p = np.array([[1 + 0j, 1, 2j]])
    e = signal_errors(p, t)
    assert e["l1_real"] == pytest.approx(1 / 3)
    assert e["l1_imag"] == pytest.approx(1 / 3)
    assert e["mse_abs"] == pytest.approx(((1 - math.sqrt(2)) ** 2 + 1) / 3)
    with pytest.raises(ShsasError):
        signal_errors(p[:, :2], t)


def test_surface_concentration_matches_the_analytic_sphere_sets():
    """A volume of 1 + 4 exp(-(d/shell)^2), d the distance to a 5 cm sphere: the ratio over the
    mesh's band and outside equals the ratio over the exact analytic sets to 2 %."""
    from shsas_core.volume import Grid, Volume

    box = SceneBox(min=(-0.1, -0.1, -0.1), max=(0.1, 0.1, 0.1))
    grid = Grid.over(box, 40)
    pts = grid.points()
    radius, shell = 0.05, 0.012
    d = np.linalg.norm(pts, axis=1) - radius
    vals = (1.0 + 4.0 * np.exp(-((d / shell) ** 2))).astype(np.float32)
    vol = Volume(grid, vals.reshape(grid.shape))
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    got = surface_concentration(vol, sphere.vertices, sphere.faces, shell=shell)
    ref = vals[np.abs(d) <= shell].mean() / vals[d > shell].mean()
    assert got == pytest.approx(ref, rel=0.02)
    assert got > 2.0
    flat = Volume(grid, np.ones(grid.shape, np.float32))
    assert surface_concentration(flat, sphere.vertices, sphere.faces, shell=shell) == pytest.approx(1.0)
    with pytest.raises(ShsasError, match="voxel diagonal"):
        surface_concentration(vol, sphere.vertices, sphere.faces, shell=0.001)


# --------------------------------------------------------------------------------------------
# the ground-truth band search (within_distance_of_mesh): exact against brute force, and local
def _brute_distances(p, v, f):
    """(P, F) exact point-triangle distances, every point against every triangle."""
    tri = np.asarray(v, float)[np.asarray(f)]
    pi, ti = np.repeat(np.arange(len(p)), len(f)), np.tile(np.arange(len(f)), len(p))
    return point_triangle_distance(p[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2]).reshape(len(p), len(f))


def _soup_with_slivers(rng, n):
    """``n`` random triangles in a 10 cm cube: a third ordinary, a third slivers (up to 15 cm
    long, 1 µm-1 mm wide) and some degenerate (repeated corner, collinear, a single point)."""
    tris = []
    for k in range(n):
        a = rng.uniform(0, 0.1, 3)
        kind = k % 3
        if kind == 0:
            b, c = a + rng.normal(0, 0.02, 3), a + rng.normal(0, 0.02, 3)
        else:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            side = np.cross(d, rng.normal(size=3))
            side /= np.linalg.norm(side)
            long = rng.uniform(0.03, 0.15)
            b = a + long * d
            c = a + rng.uniform(0.2, 1.0) * long * d + 10 ** rng.uniform(-6, -3) * side
        tris.append([a, b, c])
    tris += [[a, a, a + 0.01], [a, a + 0.02, a + 0.04], [a + 0.003, a + 0.003, a + 0.003]]
    v = np.asarray(tris, float).reshape(-1, 3)
    return v, np.arange(len(v)).reshape(-1, 3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_within_distance_matches_brute_force_on_slivers_and_degenerate_triangles(seed):
    from shsas_core.metrics import mesh_candidate_pairs
    from shsas_core.metrics_reference import reference_within_distance_of_mesh

    rng = np.random.default_rng(seed)
    v, f = _soup_with_slivers(rng, 30)
    on = sample_surface(v, f, 300, seed=seed)
    p = np.concatenate([rng.uniform(-0.05, 0.15, (1500, 3)), v, on,
                        on + rng.normal(size=on.shape) * 0.004])  # vertices, on and near the surface
    d = _brute_distances(p, v, f)
    for radius in (0.0, 0.002, 0.01, 0.04):
        want = d.min(1) <= radius
        got = within_distance_of_mesh(p, v, f, radius)
        np.testing.assert_array_equal(got, want, err_msg=f"radius {radius}")
        np.testing.assert_array_equal(reference_within_distance_of_mesh(p, v, f, radius), want)
        # small batches cut the search into many pieces: same answer
        np.testing.assert_array_equal(within_distance_of_mesh(p, v, f, radius, batch=50), want)
        # every pair within radius is a candidate, each once
        pi, ti = mesh_candidate_pairs(p, v, f, radius)
        assert len(np.unique(pi * len(f) + ti)) == len(pi)
        need = np.flatnonzero((d <= radius).ravel())
        assert np.isin(need, pi * len(f) + ti).all(), f"radius {radius}"
    # the mesh vertices (rows 1500 on) are at distance 0
    assert within_distance_of_mesh(p, v, f, 0.0)[1500:1500 + len(v)].all()


def test_within_distance_equals_reference_on_a_sliver_cone_grid():
    from shsas_core.metrics_reference import reference_within_distance_of_mesh

    # the ground truth's use: voxel centres within one voxel, where exact ties are likely
    m = trimesh.creation.cone(radius=0.04, height=0.12, sections=96)
    grid = OccupancyGrid(SceneBox(min=(-0.06, -0.06, -0.02), max=(0.06, 0.06, 0.14)), 0.008)
    c = grid.centres()
    got = within_distance_of_mesh(c, m.vertices, m.faces, grid.voxel)
    np.testing.assert_array_equal(got, reference_within_distance_of_mesh(c, m.vertices, m.faces, grid.voxel))
    assert 0 < got.sum() < len(c)


def test_band_search_on_slivers_measures_only_nearby_triangles():
    """Issue 12: on a cone of long thin triangles, the old rule (every lookup at the largest
    triangle's radius) paired ~every voxel with ~every triangle. The per-triangle search only
    pairs a point with triangles within radius + 2 cells (3 radius) of it."""
    from shsas_core.metrics import mesh_candidate_pairs
    from shsas_core.metrics_reference import reference_candidate_count

    m = trimesh.creation.cone(radius=0.04, height=0.12, sections=512)  # 1,024 slivers
    box = SceneBox(min=(-0.06, -0.06, -0.02), max=(0.06, 0.06, 0.14))
    c = OccupancyGrid(box).centres()
    radius = 0.005
    pi, ti = mesh_candidate_pairs(c, m.vertices, m.faces, radius)
    tri = m.vertices[m.faces]
    d = point_triangle_distance(c[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2])
    assert d.max() <= 3 * radius
    old = reference_candidate_count(c, m.vertices, m.faces, radius)
    assert old > 0.6 * len(c) * len(m.faces)  # the old rule: nearly all pairs
    assert len(pi) < 0.02 * old
