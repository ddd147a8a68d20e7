"""Built-in shapes, mesh loading and trajectories."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shsas_core.errors import ShsasError
from shsas_core.shapes import SHAPES, load_mesh, shape
from shsas_core.trajectory import TrajectoryConfig, make_trajectory, subset_indices


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_shapes_fit_the_turntable_box_and_stand_on_the_floor(name):
    m = shape(name)
    lo, hi = m.bounds
    assert lo[2] == pytest.approx(0.0, abs=1e-9)
    assert np.all(lo[:2] >= -0.125) and np.all(hi[:2] <= 0.125) and hi[2] <= 0.2
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0  # outward normals
    assert len(load_mesh(name).faces) == len(m.faces)


def test_sphere_and_torus_dimensions():
    s = shape("sphere")
    r = np.linalg.norm(s.vertices - [0, 0, 0.08], axis=1)
    np.testing.assert_allclose(r, 0.08, rtol=1e-9)
    t = shape("torus")
    # the torus volume is 2π² R r² (faceting makes the mesh slightly smaller)
    assert t.volume == pytest.approx(2 * np.pi**2 * 0.07 * 0.025**2, rel=0.02)
    assert shape("scene").body_count == 4


def test_load_mesh_files(tmp_path):
    cube = shape("cube")
    for ext in ("obj", "ply", "stl", "glb"):
        p = tmp_path / f"cube.{ext}"
        cube.export(p)
        m = load_mesh(p)
        assert len(m.faces) == 12
        np.testing.assert_allclose(m.bounds, cube.bounds, atol=1e-6)
    # a GLB scene with two parts is concatenated
    other = shape("sphere")
    other.apply_translation([0.3, 0, 0])
    p = tmp_path / "two.glb"
    trimesh.Scene([cube, other]).export(p)
    m = load_mesh(p)
    assert len(m.faces) == 12 + len(other.faces)


def test_load_mesh_errors(tmp_path):
    with pytest.raises(ShsasError, match="not found"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(ShsasError, match="not found"):
        load_mesh("dodecahedron")
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ShsasError, match="no triangles|cannot read"):
        load_mesh(empty)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\nend_header\n\x00")
    with pytest.raises(ShsasError):
        load_mesh(junk)
    with pytest.raises(ShsasError, match="not a file"):
        load_mesh(tmp_path)


def test_bunny_loads(shared):
    m = load_mesh(shared / "data" / "meshes" / "bunny.obj")
    assert len(m.faces) == 4968
    assert m.bounds[0, 2] == pytest.approx(0.0, abs=2e-3)


def test_circular_trajectory_geometry():
    cfg = TrajectoryConfig(heights=3, angles=8)
    tx, rx, idx = make_trajectory(cfg)
    assert tx.shape == (24, 3) and np.array_equal(idx, np.arange(24))
    np.testing.assert_allclose(np.hypot(tx[:, 0], tx[:, 1]), 0.85)
    np.testing.assert_allclose(np.hypot(rx[:, 0], rx[:, 1]), 0.863)
    np.testing.assert_allclose(rx[:, 2] - tx[:, 2], -0.038)
    np.testing.assert_allclose(np.unique(tx[:, 2]), [0.11, 0.485, 0.86])
    # one height at a time, angles in order; RX on the same azimuth as the TX
    np.testing.assert_allclose(tx[:8, 2], 0.11)
    az = np.degrees(np.arctan2(tx[:8, 1], tx[:8, 0])) % 360
    np.testing.assert_allclose(az, np.arange(0, 360, 45), atol=1e-9)
    np.testing.assert_allclose(np.arctan2(rx[:, 1], rx[:, 0]), np.arctan2(tx[:, 1], tx[:, 0]))
    step = TrajectoryConfig(heights=150, angles=1, height_step=0.005)
    z = make_trajectory(step)[0][:, 2]
    assert z[0] == pytest.approx(0.11) and z[-1] == pytest.approx(0.11 + 149 * 0.005)


def test_helical_and_linear_trajectories():
    tx, _, _ = make_trajectory(TrajectoryConfig(kind="helical", heights=3, angles=10))
    assert np.all(np.diff(tx[:, 2]) > 0)
    assert tx[10, 2] - tx[0, 2] == pytest.approx((0.86 - 0.11) / 2)
    tx, rx, _ = make_trajectory(TrajectoryConfig(kind="linear", heights=2, track_pings=5,
                                                 track_length=0.4))
    np.testing.assert_allclose(tx[:5, 0], np.linspace(-0.2, 0.2, 5))
    np.testing.assert_allclose(tx[:, 1], -0.85)
    np.testing.assert_allclose(rx[:, 1], -0.863)
    np.testing.assert_allclose(np.unique(tx[:, 2]), [0.11, 0.86])


def test_sparse_subsets_and_explicit():
    np.testing.assert_array_equal(subset_indices(10, every=3), [0, 3, 6, 9])
    a = subset_indices(1000, fraction=0.1, seed=4)
    assert len(a) == 100 and np.all(np.diff(a) > 0)
    np.testing.assert_array_equal(a, subset_indices(1000, fraction=0.1, seed=4))
    assert not np.array_equal(a, subset_indices(1000, fraction=0.1, seed=5))
    tx, _, idx = make_trajectory(TrajectoryConfig(heights=2, angles=10, every=2, fraction=0.5))
    assert len(tx) == 5 and np.all(idx % 2 == 0)
    e = TrajectoryConfig(kind="explicit", tx=[[1, 0, 0], [0, 1, 0]], rx=[[1, 0, 0.1], [0, 1, 0.1]])
    assert make_trajectory(e)[0].shape == (2, 3)
    with pytest.raises(ValueError, match="needs both"):
        TrajectoryConfig(kind="explicit", tx=[[1, 0, 0]])
    with pytest.raises(ValueError, match="same shape"):
        TrajectoryConfig(kind="explicit", tx=[[1, 0, 0]], rx=[[1, 0, 0], [1, 1, 1]])
    with pytest.raises(ValueError, match="NaN"):
        TrajectoryConfig(kind="explicit", tx=[[np.nan, 0, 0]], rx=[[1, 0, 0]])
    with pytest.raises(ValueError, match="only used"):
        TrajectoryConfig(tx=[[1, 0, 0]], rx=[[1, 0, 0]])
