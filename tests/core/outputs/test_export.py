import json

import numpy as np
import pytest
import trimesh

from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.extract import PointCloud
from shsas_core.outputs.export import (
    SCALAR_NAME,
    glb_offset,
    read_point_cloud_ply,
    read_point_cloud_points,
    read_volume_npy,
    write_mesh_glb,
    write_mesh_ply,
    write_point_cloud_ply,
    write_volume_npy,
)


@pytest.fixture
def sphere():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    m.apply_translation([0.01, 0.02, 0.06])
    return m


def test_mesh_ply_roundtrip_with_trimesh(tmp_path, sphere):
    p = write_mesh_ply(sphere, tmp_path / "m.ply")
    back = trimesh.load(p, process=False)
    np.testing.assert_array_equal(back.vertices, sphere.vertices)  # float64: exact
    np.testing.assert_array_equal(back.faces, sphere.faces)
    assert not list(tmp_path.glob(".*.tmp"))


def test_mesh_glb_roundtrip_and_offset(tmp_path, sphere):
    info = write_mesh_glb(sphere, tmp_path / "m.glb")
    assert info["origin_offset"] == [0.0, 0.0, 0.0]
    scene = trimesh.load(tmp_path / "m.glb")
    back = next(iter(scene.geometry.values()))
    assert len(back.faces) == len(sphere.faces)
    np.testing.assert_allclose(np.sort(back.vertices, 0), np.sort(sphere.vertices, 0), atol=1e-6)
    far = sphere.copy()
    far.apply_translation([512345.3, 4412345.7, -20.0])
    info = write_mesh_glb(far, tmp_path / "far.glb")
    off = np.asarray(info["origin_offset"])
    np.testing.assert_array_equal(off, glb_offset(far.vertices))
    assert np.all(off == np.round(off)) and np.abs(off).max() > 1e6
    back = next(iter(trimesh.load(tmp_path / "far.glb").geometry.values()))
    # millimetre-exact after adding the offset back, which float32 alone could not hold
    np.testing.assert_allclose(np.sort(back.vertices + off, 0), np.sort(far.vertices, 0), atol=1e-5)


def test_empty_mesh_exports_open(tmp_path):
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    write_mesh_ply(empty, tmp_path / "e.ply")
    write_mesh_glb(empty, tmp_path / "e.glb")
    assert (tmp_path / "e.glb").stat().st_size > 0
    trimesh.load(tmp_path / "e.glb")


def test_point_cloud_ply_scalar_property(tmp_path):
    rng = np.random.default_rng(0)
    pc = PointCloud(rng.random((500, 3)), rng.random(500).astype(np.float32))
    write_point_cloud_ply(pc, tmp_path / "pc.ply")
    header = (tmp_path / "pc.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"property float {SCALAR_NAME}" in header
    ours = read_point_cloud_ply(tmp_path / "pc.ply")
    np.testing.assert_array_equal(np.stack([ours["x"], ours["y"], ours["z"]], 1), pc.points)
    np.testing.assert_array_equal(ours[SCALAR_NAME], pc.scalars)
    tm = trimesh.load(tmp_path / "pc.ply")  # independent reader
    np.testing.assert_array_equal(tm.vertices, pc.points)
    np.testing.assert_allclose(tm.metadata["_ply_raw"]["vertex"]["data"][SCALAR_NAME], pc.scalars)
    pts = read_point_cloud_points(tmp_path / "pc.ply")
    assert pts.dtype == np.float64
    np.testing.assert_array_equal(pts, tm.vertices)


def test_volume_npy_roundtrip(tmp_path):
    g = Grid((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (4, 5, 6))
    vals = (np.arange(120).reshape(4, 5, 6) * (1 + 2j)).astype(np.complex64)
    info = write_volume_npy(Volume(g, vals, "backprojection"), tmp_path / "v.npy")
    np.testing.assert_array_equal(np.load(info["path"]), vals)
    side = json.loads((tmp_path / "v.json").read_text())
    assert side["shape"] == [4, 5, 6]
    back = read_volume_npy(tmp_path / "v.npy")
    assert back.grid == g and back.name == "backprojection"
