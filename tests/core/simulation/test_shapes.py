"""Built-in shapes, mesh loading and trajectories."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shsas_core.common.errors import ShsasError
from shsas_core.simulation.shapes import SHAPES, load_mesh, shape
from shsas_core.simulation.trajectory import TrajectoryConfig, make_trajectory, subset_indices


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



@pytest.mark.parametrize("name", sorted(SHAPES))
def test_shapes_have_no_degenerate_faces(name):
    m = shape(name)
    assert m.area_faces.min() > 1e-9 * m.area  # no zero-area triangles
    assert len(trimesh.Trimesh(m.vertices, m.faces).faces) == len(m.faces)  # processing drops none
    assert all(b.is_volume for b in m.split(only_watertight=False))


def test_backprojection_failure_scenes_dimensions():
    """The plate, pipe, bowl and shadow scenes against their documented dimensions."""
    plate = shape("plate")
    # a 16 x 14 cm x 4 mm box turned 30° about x: depth and height from the rotation
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    np.testing.assert_allclose(plate.extents, [0.16, 0.14 * c + 0.004 * s, 0.14 * s + 0.004 * c], rtol=1e-9)
    assert plate.volume == pytest.approx(0.16 * 0.14 * 0.004, rel=1e-9)
    # the plate's large faces are tilted 30° from the floor
    big = plate.face_normals[plate.area_faces > 0.25 * plate.area_faces.max()]
    np.testing.assert_allclose(np.abs(big[:, 2]), c, rtol=1e-9)
    pipe = shape("pipe")
    parts = sorted(pipe.split(only_watertight=False), key=lambda b: b.extents[2])
    assert len(parts) == 2
    np.testing.assert_allclose(parts[0].extents, [0.24, 0.24, 0.005], rtol=1e-9)  # the floor plate
    tube = parts[1]
    assert tube.bounds[0, 2] == pytest.approx(0.005) and tube.extents[0] == pytest.approx(0.18)
    # a 64-gon annulus: volume within 0.5 % of π (R² - r²) L
    assert tube.volume == pytest.approx(np.pi * (0.03**2 - 0.026**2) * 0.18, rel=5e-3)
    bowl = shape("bowl")
    assert bowl.extents == pytest.approx([0.18, 0.18, 0.09], rel=1e-3)
    assert bowl.volume == pytest.approx(2 / 3 * np.pi * (0.09**3 - 0.085**3), rel=5e-3)
    # concave: the point above the bottom, inside the cup, is outside the solid
    assert not bowl.contains([[0.0, 0.0, 0.05]])[0] and bowl.contains([[0.0, 0.0, 0.0025]])[0]
    shadow = shape("shadow")
    wall, ball = sorted(shadow.split(only_watertight=False), key=lambda b: -b.extents[2])
    np.testing.assert_allclose(wall.extents, [0.03, 0.16, 0.14], rtol=1e-9)
    assert ball.bounds[0, 0] - wall.bounds[1, 0] == pytest.approx(0.03, abs=1e-3)

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
