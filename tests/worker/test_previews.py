"""The worker's light previews (worker/previews.py): a decimated mesh that still is the shape,
in the same frame as the full GLB, and an even subset of the cloud's own points."""

from __future__ import annotations

import io

import numpy as np
import trimesh

from shsas_core.evaluation.extract import PointCloud
from shsas_core.outputs.export import (
    read_point_cloud_ply,
    write_mesh_glb,
    write_mesh_ply,
    write_point_cloud_ply,
)
from worker.previews import PREVIEW_FACES, PREVIEW_POINTS, preview_name, subsample, write_previews

#: A survey far from the origin (UTM-like), where the GLB is written with a whole-metre offset.
FAR = np.array([431_207.0, 5_621_344.0, -12.0])


def glb_vertices(path, offset) -> np.ndarray:
    scene = trimesh.load(io.BytesIO(path.read_bytes()), file_type="glb", force="mesh")
    return np.asarray(scene.vertices, dtype=np.float64) + offset


def test_mesh_preview_is_the_same_shape_in_the_same_frame(tmp_path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=7, radius=0.3)  # 327,680 triangles
    assert len(sphere.faces) > 4 * PREVIEW_FACES
    mesh = trimesh.Trimesh(sphere.vertices + FAR, sphere.faces, process=False)
    write_mesh_ply(mesh, tmp_path / "shsas_mesh.ply")
    offset = np.array(write_mesh_glb(mesh, tmp_path / "shsas_mesh.glb")["origin_offset"])
    assert np.abs(offset).max() > 0  # the far-away case: the preview must use this offset too
    made = write_previews(tmp_path, ["shsas_mesh.ply", "shsas_mesh.glb", "report.json"])
    assert made == ["shsas_mesh_preview.glb"]
    full = (tmp_path / "shsas_mesh.glb").stat().st_size
    small = tmp_path / "shsas_mesh_preview.glb"
    v = glb_vertices(small, offset)
    faces = len(trimesh.load(small, force="mesh").faces)
    assert PREVIEW_FACES * 0.9 <= faces <= PREVIEW_FACES * 1.01 and small.stat().st_size < full / 4
    # every vertex still lies on the sphere (float32 in the file: ~mm), all around it
    r = np.linalg.norm(v - FAR, axis=1)
    assert np.abs(r - 0.3).max() < 0.003
    assert np.allclose(v.mean(0), FAR, atol=0.005)


def test_small_mesh_kept_whole_and_cloud_subset(tmp_path) -> None:
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    write_mesh_ply(box, tmp_path / "bp_mesh.ply")
    write_mesh_glb(box, tmp_path / "bp_mesh.glb")
    rng = np.random.default_rng(3)
    n = 3 * PREVIEW_POINTS + 17
    pts = rng.normal(size=(n, 3))
    scal = rng.uniform(0.3, 1.0, n).astype(np.float32)
    write_point_cloud_ply(PointCloud(points=pts, scalars=scal), tmp_path / "bp_pointcloud.ply")
    made = write_previews(tmp_path, ["bp_mesh.ply", "bp_mesh.glb", "bp_pointcloud.ply"])
    assert sorted(made) == ["bp_mesh_preview.glb", "bp_pointcloud_preview.ply"]
    assert len(trimesh.load(tmp_path / "bp_mesh_preview.glb", force="mesh").faces) == 12
    cols = read_point_cloud_ply(tmp_path / "bp_pointcloud_preview.ply")
    got = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    assert len(got) == PREVIEW_POINTS
    # each preview point is one of the cloud's own points, with its own scalar
    index = {tuple(p): i for i, p in enumerate(pts)}
    rows = np.array([index[tuple(p)] for p in got])
    assert np.array_equal(cols["scalar_magnitude"], scal[rows])
    assert rows[0] == 0 and rows[-1] == n - 1 and np.all(np.diff(rows) >= 2)  # spread over all of it


def test_names_and_subsample() -> None:
    assert preview_name("reed_pointcloud.ply") == "reed_pointcloud_preview.ply"
    assert np.array_equal(subsample(5, 10), np.arange(5))
    idx = subsample(1000, 10)
    assert len(idx) == 10 and idx[0] == 0 and idx[-1] == 999


def test_a_preview_that_fails_does_not_fail_the_job(tmp_path) -> None:
    (tmp_path / "x_mesh.ply").write_bytes(b"not a ply")
    (tmp_path / "x_mesh.glb").write_bytes(b"")
    assert write_previews(tmp_path, ["x_mesh.ply", "x_mesh.glb"]) == []
