import math

import numpy as np
import pytest
import trimesh

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox
from shsas_core.evaluation.metrics import (
    GroundTruth,
    ScoringGrid,
    chamfer,
    chamfer_l2_parts,
    fscore,
    nn_distances,
    occupancy_scores,
    point_triangle_distance,
    sample_surface,
    score_mesh,
    score_points,
    surface_concentration,
    within_distance_of_mesh,
)
from shsas_core.neural.render import signal_errors


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


def test_chamfer_l2_parts_are_the_directed_halves():
    rng = np.random.default_rng(3)
    a, b = rng.random((40, 3)) * 0.02, rng.random((55, 3)) * 0.02
    parts = chamfer_l2_parts(a, b)
    assert parts["chamfer_l2_accuracy"] == pytest.approx(np.mean(brute_nn(a, b) ** 2), rel=1e-12)
    assert parts["chamfer_l2_completeness"] == pytest.approx(np.mean(brute_nn(b, a) ** 2), rel=1e-12)
    assert sum(parts.values()) == pytest.approx(chamfer(a, b)["chamfer_l2"], rel=1e-12)
    # a stray point far off hurts accuracy only; a missed half of the reference, completeness only
    g = np.stack(np.meshgrid(*[np.arange(4) * 0.1] * 3, indexing="ij"), -1).reshape(-1, 3)
    stray = chamfer_l2_parts(np.vstack([g, [[1.0, 1.0, 1.0]]]), g)
    assert stray["chamfer_l2_accuracy"] > 0 and stray["chamfer_l2_completeness"] == 0
    half = chamfer_l2_parts(g[g[:, 0] < 0.15], g)
    assert half["chamfer_l2_accuracy"] == 0 and half["chamfer_l2_completeness"] > 0
    assert chamfer_l2_parts(np.zeros((0, 3)), g)["chamfer_l2_accuracy"] == math.inf


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
    grid = ScoringGrid(box, 0.005)
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
    # a perfect surface lies inside the solid GT occupancy (solid + band) but covers only its
    # shell: solid precision 1, and IoU = recall = shell voxels / GT voxels
    assert same["solid_precision"] == 1.0 and same["solid_iou"] == pytest.approx(same["solid_recall"])
    shell = gt.grid.from_points(sample_surface(a.vertices, a.faces, 200000, seed=9))
    assert same["solid_recall"] == pytest.approx(shell.sum() / gt.solid.sum(), abs=0.01)
    # the surface band of the mesh itself is the GT's band: a perfect surface scores 1
    assert same["surface_f1"] == 1.0 and same["surface_iou"] == 1.0
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
    assert s2["surface_f1"] < s["surface_f1"] < 1.0


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
    from shsas_core.data.volume import Grid, Volume

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
    from shsas_core.evaluation.metrics import mesh_candidate_pairs
    from shsas_core.evaluation.metrics_reference import reference_within_distance_of_mesh

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
    from shsas_core.evaluation.metrics_reference import reference_within_distance_of_mesh

    # the ground truth's use: voxel centres within one voxel, where exact ties are likely
    m = trimesh.creation.cone(radius=0.04, height=0.12, sections=96)
    grid = ScoringGrid(SceneBox(min=(-0.06, -0.06, -0.02), max=(0.06, 0.06, 0.14)), 0.008)
    c = grid.centres()
    got = within_distance_of_mesh(c, m.vertices, m.faces, grid.voxel)
    np.testing.assert_array_equal(got, reference_within_distance_of_mesh(c, m.vertices, m.faces, grid.voxel))
    assert 0 < got.sum() < len(c)


def test_band_search_on_slivers_measures_only_nearby_triangles():
    """On a cone of long thin triangles, the old rule (every lookup at the largest
    triangle's radius) paired ~every voxel with ~every triangle. The per-triangle search only
    pairs a point with triangles within radius + 2 cells (3 radius) of it."""
    from shsas_core.evaluation.metrics import mesh_candidate_pairs
    from shsas_core.evaluation.metrics_reference import reference_candidate_count

    m = trimesh.creation.cone(radius=0.04, height=0.12, sections=512)  # 1,024 slivers
    box = SceneBox(min=(-0.06, -0.06, -0.02), max=(0.06, 0.06, 0.14))
    c = ScoringGrid(box).centres()
    radius = 0.005
    pi, ti = mesh_candidate_pairs(c, m.vertices, m.faces, radius)
    tri = m.vertices[m.faces]
    d = point_triangle_distance(c[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2])
    assert d.max() <= 3 * radius
    old = reference_candidate_count(c, m.vertices, m.faces, radius)
    assert old > 0.6 * len(c) * len(m.faces)  # the old rule: nearly all pairs
    assert len(pi) < 0.02 * old


# --------------------------------------------------------------------------------------------
# the surface protocol: surface F1, F@2.5mm, mesh quality
def _box_around(m, margin=0.02):
    return SceneBox(min=tuple(m.bounds[0] - margin), max=tuple(m.bounds[1] + margin))


def _protocol_meshes(shared):
    from shsas_core.simulation.shapes import load_mesh

    return {"sphere": load_mesh("sphere"), "cube": load_mesh("cube"),
            "bunny": load_mesh(shared / "data" / "meshes" / "bunny.obj")}


def test_perfectly_placed_surface_sample_scores_surface_f1_near_one(shared):
    """A sample of the true surface (20,000 points, another seed than the GT's) is a perfect
    surface reconstruction: surface F1 >= 0.95, while the solid F1, which also wants the inside
    filled, scores it far lower."""
    for name, m in _protocol_meshes(shared).items():
        gt = GroundTruth(m.vertices, m.faces, _box_around(m))
        s = score_points(sample_surface(m.vertices, m.faces, 20000, seed=7), gt)
        assert s["surface_f1"] >= 0.95, (name, s)
        assert s["surface_f1"] > s["solid_f1"] + 0.2, (name, s)
        # the mesh itself: its band is the GT band, voxel for voxel
        assert score_mesh(m.vertices, m.faces, gt)["surface_f1"] == 1.0, name


def test_surface_band_from_points_matches_brute_force():
    rng = np.random.default_rng(4)
    box = SceneBox(min=(0.0, 0.0, 0.0), max=(0.04, 0.03, 0.035))
    grid = ScoringGrid(box, 0.005)
    pts = rng.uniform(-0.005, 0.045, (40, 3))
    got = grid.band_from_points(pts, 0.005)
    want = (brute_nn(grid.centres(), pts) <= 0.005).reshape(grid.shape)
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < got.size
    assert not grid.band_from_points(np.zeros((0, 3))).any()


def test_thick_shell_and_offset_lose_surface_f1():
    """A ±5 mm shell of points describes the surface 1 cm thick: its band reaches ~10 mm from the
    surface, twice the GT's, so surface precision falls to about half (F@5mm stays near 1)."""
    from shsas_core.simulation.shapes import sphere

    m = sphere()
    gt = GroundTruth(m.vertices, m.faces, _box_around(m))
    ax = [np.arange(lo, hi, 0.0035) for lo, hi in zip(gt.box.min, gt.box.max, strict=True)]
    c = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
    shell = c[within_distance_of_mesh(c, m.vertices, m.faces, 0.005)]
    s = score_points(shell, gt)
    assert s["surface_recall"] == 1.0 and 0.45 < s["surface_precision"] < 0.7, s
    assert s["fscore"] > 0.95


def test_fscore_2_5mm_matches_brute_force_loop():
    from shsas_core.evaluation.metrics import point_fscores

    rng = np.random.default_rng(6)
    a, b = rng.random((80, 3)) * 0.015, rng.random((60, 3)) * 0.015
    p = np.mean([min(np.linalg.norm(x - y) for y in b) <= 0.0025 for x in a])
    r = np.mean([min(np.linalg.norm(y - x) for x in a) <= 0.0025 for y in b])
    f = point_fscores(a, b)
    assert f["fscore_2_5mm_precision"] == pytest.approx(p) and f["fscore_2_5mm_recall"] == pytest.approx(r)
    assert f["fscore_2_5mm"] == pytest.approx(2 * p * r / (p + r))
    assert 0 < p < 1 and 0 < r < 1
    assert f["fscore"] == pytest.approx(fscore(a, b, 0.005)["fscore"])


def test_double_sheet_fails_the_area_check_and_one_sheet_passes():
    """An offset copy 7.5 mm outside the sphere (each vertex moved along its normal) beside the
    sphere: the double sheet a thresholded volume gives. Its area is ~2.2x the true area."""
    from shsas_core.evaluation.metrics import MESH_CHECKS, mesh_check_failures, mesh_quality
    from shsas_core.simulation.shapes import sphere

    m = sphere()
    gt = GroundTruth(m.vertices, m.faces, _box_around(m, 0.03))
    outer = trimesh.Trimesh(m.vertices + 0.0075 * m.vertex_normals, m.faces, process=False)
    double = trimesh.util.concatenate([m, outer])
    q = mesh_quality(double.vertices, double.faces, gt)
    assert q["area_ratio"] == pytest.approx(1 + ((0.08 + 0.0075) / 0.08) ** 2, rel=0.01)
    assert q["pieces"] == 2.0 and q["normal_consistency"] > 0.99
    assert [f[0] for f in mesh_check_failures(q)] == ["area_ratio"]
    assert q["area_ratio"] > MESH_CHECKS.area_ratio[1]
    one = mesh_quality(m.vertices, m.faces, gt)
    assert one == {"pieces": 1.0, "area_ratio": pytest.approx(1.0), "normal_consistency": pytest.approx(1.0)}
    assert mesh_check_failures(one) == []
    # the double sheet also widens the surface band: surface precision drops, recall stays
    s2, s1 = score_mesh(double.vertices, double.faces, gt), score_mesh(m.vertices, m.faces, gt)
    assert s2["surface_recall"] == 1.0 and s2["surface_precision"] < 0.8 < s1["surface_precision"]


def _brute_pieces(v, f, share):
    """Union-find over faces joined when they share an edge by position; then the fewest
    largest components holding ``share`` of the area."""
    parent = list(range(len(f)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    key = [tuple(np.round(p, 9)) for p in v]
    edges = [{frozenset((key[t[0]], key[t[1]])), frozenset((key[t[1]], key[t[2]])),
              frozenset((key[t[2]], key[t[0]]))} for t in f]
    for i in range(len(f)):
        for j in range(i + 1, len(f)):
            if edges[i] & edges[j]:
                parent[find(i)] = find(j)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    comp: dict[int, float] = {}
    for i in range(len(f)):
        comp[find(i)] = comp.get(find(i), 0.0) + area[i]
    sizes = sorted(comp.values(), reverse=True)
    held, k = 0.0, 0
    while held < share * sum(sizes) * (1 - 1e-12):
        held += sizes[k]
        k += 1
    return k


def test_pieces_match_brute_force_union_find():
    """Spheres and boxes of several sizes, flecks of single triangles, a fin sharing a
    non-manifold edge, a component touching another at a vertex only, and one part stored as a
    triangle soup (every face its own vertices)."""
    from shsas_core.evaluation.metrics import mesh_pieces

    rng = np.random.default_rng(8)
    parts = [trimesh.creation.icosphere(1, radius=0.05), trimesh.creation.box(extents=(0.03, 0.02, 0.01))]
    for k in range(6):
        s = trimesh.creation.icosphere(0, radius=0.004 * (k + 1))
        s.apply_translation(rng.uniform(0.1, 0.3, 3))
        parts.append(s)
    for _ in range(10):  # flecks
        parts.append(trimesh.Trimesh(rng.uniform(-0.2, -0.1, (3, 3)), [[0, 1, 2]], process=False))
    parts[1].apply_translation([0.2, 0, 0])
    # a fin on an edge of the box: a third face on that edge
    e = parts[1].vertices[parts[1].edges_unique[0]]
    parts.append(trimesh.Trimesh(np.vstack([e, e.mean(0) + np.array([0.0, 0.0, 0.03])]), [[0, 1, 2]], process=False))
    # a small box touching the big sphere at a vertex only
    tip = parts[0].vertices[np.argmax(parts[0].vertices[:, 0])]
    touch = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    touch.apply_translation(tip - touch.vertices.min(0))
    touch.vertices[np.argmin(np.linalg.norm(touch.vertices - tip, axis=1))] = tip
    parts.append(touch)
    soup = trimesh.creation.icosphere(1, radius=0.02)
    soup.apply_translation([-0.1, 0.1, 0])
    parts.append(trimesh.Trimesh(soup.vertices[soup.faces].reshape(-1, 3), np.arange(3 * len(soup.faces)).reshape(-1, 3),
                                 process=False))
    mesh = trimesh.util.concatenate(parts)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    for share in (0.5, 0.8, 0.95, 0.99, 1.0):
        assert mesh_pieces(v, f, share) == _brute_pieces(v, f, share), share
    assert mesh_pieces(v, f, 1.0) > mesh_pieces(v, f, 0.95) > 1
    assert mesh_pieces(np.zeros((0, 3)), np.zeros((0, 3), int)) == 0


def test_foam_fails_the_pieces_check_without_ground_truth():
    from shsas_core.evaluation.metrics import mesh_check_failures, mesh_quality

    blobs = []
    for k in range(12):
        b = trimesh.creation.icosphere(1, radius=0.01)
        b.apply_translation([0.03 * k, 0, 0])
        blobs.append(b)
    foam = trimesh.util.concatenate(blobs)
    q = mesh_quality(foam.vertices, foam.faces)
    assert q == {"pieces": 12.0}  # 11 of 12 equal blobs hold 91.7 % < 95 %
    assert [f[0] for f in mesh_check_failures(q)] == ["pieces"]


def test_normal_consistency_analytic_cases():
    from shsas_core.evaluation.metrics import face_normals, normal_consistency, sample_surface_faces

    plane = trimesh.Trimesh([[-0.05, -0.05, 0], [0.05, -0.05, 0], [0.05, 0.05, 0], [-0.05, 0.05, 0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    pts, tri = sample_surface_faces(plane.vertices, plane.faces, 4000, seed=1)
    n = face_normals(plane.vertices, plane.faces)[tri]
    assert normal_consistency(pts, n, pts, n) == pytest.approx(1.0)
    assert normal_consistency(pts, -n, pts, n) == pytest.approx(1.0)  # orientation does not count
    # the plane tilted by θ about its centre: every nearest-point pair differs by θ
    for theta in (0.2, 0.7, 1.2):
        t = plane.copy()
        t.apply_transform(trimesh.transformations.rotation_matrix(theta, [1, 0, 0]))
        q, tq = sample_surface_faces(t.vertices, t.faces, 4000, seed=2)
        got = normal_consistency(q, face_normals(t.vertices, t.faces)[tq], pts, n)
        assert got == pytest.approx(math.cos(theta), rel=1e-9)
    # normals drawn uniformly on the sphere: E|cos| = 1/2
    rng = np.random.default_rng(3)
    noise = rng.normal(size=(200000, 3))
    noise /= np.linalg.norm(noise, axis=1, keepdims=True)
    many = sample_surface(plane.vertices, plane.faces, 200000, seed=4)
    assert normal_consistency(many, noise, pts, n) == pytest.approx(0.5, abs=0.005)
    # the same mesh scores 1, a crumpled copy (vertices jittered by 2 mm) lower
    from shsas_core.evaluation.metrics import mesh_quality
    from shsas_core.simulation.shapes import sphere

    m = sphere()
    gt = GroundTruth(m.vertices, m.faces, _box_around(m))
    assert mesh_quality(m.vertices, m.faces, gt)["normal_consistency"] == pytest.approx(1.0)
    rough = m.vertices + rng.normal(scale=0.002, size=m.vertices.shape)
    nc = mesh_quality(rough, m.faces, gt)["normal_consistency"]
    assert 0.5 < nc < 0.85
