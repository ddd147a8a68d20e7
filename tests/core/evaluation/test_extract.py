import math

import numpy as np
import pytest
import torch

from shsas_core.common.errors import ShsasError
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.extract import (
    ExtractConfig,
    choose_threshold,
    extract,
    mesh,
    normalize,
    otsu_threshold,
    point_cloud,
    threshold_sweep,
)
from shsas_core.neural.fields.volume import field_volume


def ramp_volume():
    # values linear in x: 0 at the first voxel centre, 1 at the last -> iso-surface is a plane
    g = Grid((0.0, -0.1, 0.0), (0.2, 0.1, 0.1), (20, 20, 10))
    x = g.axes()[0]
    v = (x - x[0]) / (x[-1] - x[0])
    return g, Volume(g, np.broadcast_to(v[:, None, None], g.shape).astype(np.float32).copy())


def test_mesh_vertices_in_survey_frame_exact():
    g, vol = ramp_volume()
    x = g.axes()[0]
    m = mesh(vol, 0.3, close_boundary=False)
    x_iso = x[0] + 0.3 * (x[-1] - x[0])
    assert len(m.faces) > 0
    np.testing.assert_allclose(m.vertices[:, 0], x_iso, atol=1e-6)
    # the plane spans the voxel centres in y and z
    np.testing.assert_allclose(m.vertices[:, 1].min(), g.axes()[1][0], atol=1e-9)
    np.testing.assert_allclose(m.vertices[:, 2].max(), g.axes()[2][-1], atol=1e-9)


def test_mesh_closed_sphere_is_watertight_outward_and_in_place():
    g = Grid((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (40, 40, 40))
    c = np.array([0.01, -0.02, 0.1])
    r = np.linalg.norm(g.points() - c, axis=1).reshape(g.shape)
    vol = Volume(g, np.exp(-((r / 0.05) ** 2)).astype(np.float32))
    m = mesh(vol, 0.5)
    peak = float(np.exp(-((r.min() / 0.05) ** 2)))
    r_iso = 0.05 * math.sqrt(-math.log(0.5 * peak))
    d = np.linalg.norm(m.vertices - c, axis=1)
    assert m.is_watertight
    assert m.volume > 0  # outward normals
    np.testing.assert_allclose(d, r_iso, atol=0.6e-3)  # linear interpolation error < h²/8·curvature


def test_point_cloud_voxel_centres_and_scalars():
    g, vol = ramp_volume()
    pc = point_cloud(vol, 0.5)
    x = g.axes()[0]
    assert len(pc) == int(np.sum((x - x[0]) / (x[-1] - x[0]) >= 0.5)) * 20 * 10
    assert pc.scalars.min() >= 0.5 and pc.scalars.max() == pytest.approx(1.0)
    np.testing.assert_allclose(np.unique(pc.points[:, 0]), x[x >= x[0] + 0.5 * (x[-1] - x[0])])


def test_threshold_rules():
    rng = np.random.default_rng(0)
    g = Grid((0, 0, 0), (1, 1, 1), (16, 16, 16))
    bright = rng.random(g.shape) < 0.1
    vals = np.where(bright, 0.8, 0.1) + 0.01 * rng.standard_normal(g.shape)
    vol = Volume(g, np.abs(vals).astype(np.float32))
    tau = choose_threshold(vol)
    n = normalize(vol)
    # Otsu splits the two classes (up to one of its 256 histogram bins)
    assert n[bright].min() >= tau
    assert n[~bright].max() < tau + (n.max() - n.min()) / 256
    assert otsu_threshold(normalize(vol)) == pytest.approx(tau)
    assert choose_threshold(vol, ExtractConfig(threshold=0.42)) == 0.42
    t99 = choose_threshold(vol, ExtractConfig(rule="percentile", percentile=99, tau_max=0.999))
    assert np.mean(normalize(vol) >= t99) == pytest.approx(0.01, abs=0.002)
    # range normalisation: an offset (fog) does not change the rule's selection
    fog = Volume(g, (vol.values + 5.0).astype(np.float32))
    assert choose_threshold(fog) == pytest.approx(tau, abs=1e-6)
    np.testing.assert_allclose(normalize(fog), normalize(vol), atol=1e-5)
    flat = Volume(g, np.zeros(g.shape, np.float32))
    assert choose_threshold(flat) == ExtractConfig().tau_min
    with pytest.raises(ShsasError):
        point_cloud(vol, 1.5)


def test_empty_volume_gives_empty_outputs_and_sweep():
    g, vol = ramp_volume()
    empty = Volume(g, np.zeros(g.shape, np.float32))
    _, pc, m = extract(empty)
    assert len(pc) == 0 and len(m.faces) == 0
    rows = threshold_sweep(vol, [0.2, 0.5, 0.8], score=lambda pc, m: {"n": float(len(pc))})
    assert [r["tau"] for r in rows] == [0.2, 0.5, 0.8]
    assert rows[0]["points"] > rows[1]["points"] > rows[2]["points"] == rows[2]["n"]


class RadialField(torch.nn.Module):
    """c_00 = 2 - |x| (complex), one more coefficient that extraction must ignore."""

    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(()))

    def coefficients(self, x):
        c0 = (2 - x.norm(dim=1)) * self.w
        return torch.stack([torch.complex(c0, -c0), torch.complex(5 * c0, c0)], 1)


def test_field_volume_samples_dc_magnitude_in_chunks():
    g = Grid((-1, -1, -1), (1, 1, 1), (6, 5, 4))
    vol = field_volume(RadialField(), g, chunk=7)
    exp = np.sqrt(2) * (2 - np.linalg.norm(g.points(), axis=1)) / math.sqrt(4 * math.pi)
    np.testing.assert_allclose(vol.values.ravel(), exp, rtol=1e-5)
    assert vol.values.dtype == np.float32


def test_a_double_sheet_7_5_mm_apart_meshes_as_one_sheet():
    # a bright plane at z = 0 and its range sidelobe 7.5 mm above it at half its peak (under the
    # 8.6 mm range resolution of a 20 kHz band in air), each 2 mm across, over a 10 cm square,
    # seen from above: the default mesh is one sheet at the bright plane (the ridge, smoothed over
    # the mainlobe, sits 1.5 mm toward the sidelobe). test_ridge checks that the suppression
    # itself drops the sidelobe sheet; here Poisson is fed the bright sheet alone
    g = Grid((-0.08, -0.08, -0.04), (0.08, 0.08, 0.04), (64, 64, 32))
    p = g.points().reshape(*g.shape, 3)
    inside = np.all(np.abs(p[..., :2]) < 0.05, axis=-1)
    z = p[..., 2] - 0.0003

    def sheet(at: float) -> np.ndarray:
        return np.exp(-0.5 * ((z - at) / 0.002) ** 2)

    # a faint floor everywhere, as an image has: exact zeros would read as no estimate (a neural
    # field's mask), whose edge the ridge keeps away from
    vol = Volume(g, ((sheet(0.0) + 0.5 * sheet(0.0075)) * inside + 1e-4).astype(np.float32))
    ang = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    sensors = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(90, 0.5)], 1)
    _, cloud, m = extract(vol, sensors=sensors, resolution=343.0 / (2 * 20e3))
    assert np.mean(np.abs(cloud.points[:, 2] - 0.0075) < 0.002) > 0.2  # the ridge holds both sheets
    centre = np.all(np.abs(m.triangles_center[:, :2]) < 0.045, axis=1)  # away from Poisson's rim
    assert centre.sum() > 100
    np.testing.assert_allclose(m.triangles_center[centre, 2], 0.0, atol=0.002)  # one sheet, on the bright one
    assert 0.8 < m.area / 0.01 < 1.5


def test_local_contrast_over_the_estimated_voxels_matches_a_brute_force_mean():
    from shsas_core.evaluation.extract import local_contrast

    rng = np.random.default_rng(3)
    norm = rng.random((9, 8, 7)).astype(np.float32)
    support = rng.random(norm.shape) < 0.6
    norm[~support] = 0.0
    h = np.array([0.01, 0.01, 0.01])
    got = local_contrast(norm, h, 0.03, support)  # a 3-voxel cube
    plain = local_contrast(norm, h, 0.03)
    pad_v = np.pad(norm.astype(np.float64), 1, mode="edge")
    pad_s = np.pad(support, 1, mode="edge")
    for i, j, k in np.ndindex(norm.shape):
        v, s = pad_v[i:i + 3, j:j + 3, k:k + 3], pad_s[i:i + 3, j:j + 3, k:k + 3]
        mean = v[s].mean() if s.any() else 0.0
        assert got[i, j, k] == pytest.approx(norm[i, j, k] / mean if mean > 0 else 0.0, rel=1e-4, abs=1e-6)
        assert plain[i, j, k] == pytest.approx(norm[i, j, k] / v.mean() if v.mean() > 0 else 0.0, rel=1e-4,
                                               abs=1e-6)


def test_a_faint_sheet_by_the_edge_of_a_neural_mask_is_no_surface():
    # a bright plane inside a slab where a field was evaluated (faint noise everywhere in it), a
    # faint plane 5 mm inside the slab's edge, and zeros outside (no estimate: the occupancy
    # mask). Counted as dark background, the zeros nearly halve the faint plane's local mean and
    # it passes the contrast test; over the estimated voxels alone it does not
    rng = np.random.default_rng(4)
    g = Grid((-0.06, -0.06, -0.08), (0.06, 0.06, 0.08), (48, 48, 64))
    z = g.points().reshape(*g.shape, 3)[..., 2]
    slab = (z > -0.055) & (z < 0.035)
    bright_at, faint_at = -0.04, 0.03

    def sheet(at: float) -> np.ndarray:
        return np.exp(-0.5 * ((z - at) / 0.002) ** 2)

    values = (sheet(bright_at) + 0.1 * sheet(faint_at) + 0.1 * rng.random(g.shape)) * slab
    vol = Volume(g, values.astype(np.float32))
    sensors = np.array([[0.0, 0.0, 1.0]])
    near = lambda cloud, at: int(np.sum(np.abs(cloud.points[:, 2] - at) < 0.003))  # noqa: E731
    # the contrast test alone: no edge margin, no bright-pieces step (which drops the faint plane
    # too, 7 cm from the bright one)
    alone = {"threshold": 0.15, "support_margin": 0, "piece_level": None}
    _, dark, _ = extract(vol, ExtractConfig(background="all", **alone), sensors=sensors)
    _, est, _ = extract(vol, ExtractConfig(background="estimated", **alone), sensors=sensors)
    assert near(dark, faint_at) > 500 and near(dark, bright_at) > 1000
    assert near(est, faint_at) < 0.05 * near(dark, faint_at) and near(est, bright_at) > 1000
    # the default keeps ridge candidates 1.25 range resolutions (10.6 mm here) inside the
    # estimate: the faint plane 5 mm inside goes, the bright one 15 mm inside stays
    _, default, _ = extract(vol, ExtractConfig(threshold=0.15), sensors=sensors)
    assert near(default, faint_at) == 0 and near(default, bright_at) > 1000


def test_inside_support_matches_a_brute_force_distance():
    from shsas_core.evaluation.extract import inside_support

    rng = np.random.default_rng(5)
    support = rng.random((10, 9, 8)) < 0.8
    h = np.array([0.01, 0.02, 0.015])
    got = inside_support(support, h, 0.0255)
    centres = np.indices(support.shape).reshape(3, -1).T * h
    outside = centres[~support.ravel()]
    for n, c in enumerate(centres):
        nearest = np.sqrt(((outside - c) ** 2).sum(axis=1)).min()
        assert got.ravel()[n] == (bool(support.ravel()[n]) and nearest >= 0.0255)
    assert inside_support(np.ones((3, 3, 3), bool), h, 0.025).all()  # nothing outside: all of it


def test_the_default_mesh_of_a_bowl_stays_on_its_sheet_past_the_rim():
    from shsas_core.evaluation.extract import PointCloud, surface_mesh
    from tests.helpers.sphere_data import fibonacci_sphere

    # a bowl's points (the lower half of a 5 cm sphere, seen from inside); at the default survey's
    # range resolution the plain trim keeps Poisson's bend past the rim, 8.3 mm off the sphere
    r, res, spacing = 0.05, 0.0086, 0.0025
    u = fibonacci_sphere(3000)
    u[:, 2] = np.abs(u[:, 2])
    cloud = PointCloud(points=-r * u, scalars=np.ones(len(u)), normals=u)
    cfg = ExtractConfig()
    plain = surface_mesh(cloud, spacing, cfg.model_copy(update={"sheet_trim": None}), res)
    cut = surface_mesh(cloud, spacing, cfg, res)
    # the tangent plane of points a trim (12.5 mm) away departs from the sphere by 1.6 mm
    bound = cfg.sheet_trim * res + 0.0016
    assert np.abs(np.linalg.norm(plain.vertices, axis=1) - r).max() > bound
    assert np.abs(np.linalg.norm(cut.vertices, axis=1) - r).max() <= bound
    assert cut.area > 0.95 * 2 * math.pi * r**2
