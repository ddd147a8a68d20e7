"""Write reconstructions to files viewers open: PLY/GLB meshes, PLY point clouds, NPY volumes.

Every writer goes through :func:`atomic_path` (write a temporary file beside the target, then
``os.replace``), so a reader never sees half a file and a crashed job leaves no partial artifact.

Coordinates are survey-frame metres. PLY stores them as float64, so they are exact. GLB holds
float32 only; when a scene lies far from the origin (UTM-like coordinates) float32 would lose
millimetres, so the mesh is shifted by a whole-metre ``origin_offset`` before writing and the
offset is returned (the pipeline records it in ``report.json``): survey = file + offset.
GLB is written as stored (z up); glTF viewers assume y up and show the scene lying on its side.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.common.atomic import atomic_path
from shsas_core.common.errors import ShsasError
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.extract import PointCloud

#: Name of the per-point scalar in point-cloud PLY files (CloudCompare shows it as a scalar field).
SCALAR_NAME = "scalar_magnitude"
#: Beyond this distance from the origin (m) GLB vertices are shifted by a whole-metre offset.
GLB_OFFSET_LIMIT = 1000.0


def write_mesh_ply(mesh: Any, path: str | os.PathLike) -> Path:
    """Binary little-endian PLY with float64 vertices and int32 faces (empty meshes allowed)."""
    v = np.asarray(mesh.vertices, dtype="<f8").reshape(-1, 3)
    f = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment shsas mesh, survey frame, metres, z up\n"
        f"element vertex {len(v)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    faces = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = f
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(faces.tobytes())
    return Path(path)


def glb_offset(vertices: np.ndarray) -> np.ndarray:
    """(3,) whole-metre shift applied before a float32 GLB write (zeros near the origin)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) == 0 or float(np.abs(v).max()) < GLB_OFFSET_LIMIT:
        return np.zeros(3)
    return np.round(0.5 * (v.min(0) + v.max(0)))


def write_mesh_glb(mesh: Any, path: str | os.PathLike) -> dict[str, Any]:
    """Binary glTF of the mesh (float32 vertices).

    Returns:
        ``{"path": str, "origin_offset": [x, y, z]}``: survey coordinates = file coordinates +
        offset.
    """
    import trimesh

    offset = glb_offset(mesh.vertices)
    m = trimesh.Trimesh(np.asarray(mesh.vertices) - offset, np.asarray(mesh.faces), process=False)
    if len(m.faces) == 0:
        data = _empty_glb()
    else:
        data = m.export(file_type="glb")
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data)
    return {"path": str(path), "origin_offset": offset.tolist()}


def _empty_glb() -> bytes:
    """A valid glTF 2.0 binary with one empty scene (trimesh refuses to export no geometry)."""
    import struct

    body = json.dumps({"asset": {"version": "2.0", "generator": "shsas"}, "scene": 0,
                       "scenes": [{"nodes": []}]}).encode()
    body += b" " * (-len(body) % 4)
    return struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(body)) + struct.pack("<I4s", len(body), b"JSON") + body


def write_point_cloud_ply(cloud: PointCloud, path: str | os.PathLike, scalar_name: str = SCALAR_NAME) -> Path:
    """Binary PLY point cloud: float64 x, y, z plus a float32 vertex property ``scalar_name``.

    CloudCompare and MeshLab read extra vertex properties as scalar fields.
    """
    if not scalar_name.isidentifier():
        raise ShsasError(f"export: scalar name {scalar_name!r} must be an identifier")
    p = np.asarray(cloud.points, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(cloud.scalars, dtype=np.float32).reshape(-1)
    if len(s) != len(p):
        raise ShsasError(f"export: {len(p)} points but {len(s)} scalars")
    rec = np.empty(len(p), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), (scalar_name, "<f4")])
    rec["x"], rec["y"], rec["z"], rec[scalar_name] = p[:, 0], p[:, 1], p[:, 2], s
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment shsas point cloud, survey frame, metres, z up\n"
        f"element vertex {len(p)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"property float {scalar_name}\nend_header\n"
    )
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rec.tobytes())
    return Path(path)


def read_point_cloud_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a binary little-endian PLY vertex element into ``{property: (P,) array}``.

    A small independent parser (header + numpy structured dtype) used by tests and
    ``shsas evaluate``; it supports the scalar vertex properties this module writes.
    """
    types = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
             "uint": "<u4", "float": "<f4", "double": "<f8", "float32": "<f4", "float64": "<f8",
             "int32": "<i4", "uint8": "u1"}
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise ShsasError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ShsasError(f"{path}: only binary little-endian PLY is supported")
    n, fields, in_vertex = 0, [], False
    for ln in lines:
        parts = ln.split()
        if parts[:1] == ["element"]:
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                n = int(parts[2])
        elif parts[:1] == ["property"] and in_vertex:
            if parts[1] == "list":
                raise ShsasError(f"{path}: list properties on vertices are not supported")
            fields.append((parts[2], types[parts[1]]))
    body = raw[end + len(b"end_header\n"):]
    arr = np.frombuffer(body, dtype=np.dtype(fields), count=n)
    return {name: np.array(arr[name]) for name, _ in fields}


def read_point_cloud_points(path: str | os.PathLike) -> np.ndarray:
    """The (P, 3) float64 ``x, y, z`` positions, m, of a PLY point cloud (:func:`read_point_cloud_ply`)."""
    d = read_point_cloud_ply(path)
    return np.stack([d["x"], d["y"], d["z"]], axis=1).astype(np.float64)


def write_volume_npy(volume: Volume, path: str | os.PathLike, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Save ``volume.values`` (complex64 or float32, shape ``grid.shape``) as NPY plus a JSON
    sidecar ``<stem>.json`` with the grid (box corners in m, shape; voxel (i,j,k) has centre
    ``box_min + (ijk + 0.5) * spacing``) and ``extra`` (how the volume was made, say).

    Returns:
        ``{"path": str, "grid_path": str}``.
    """
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.save(fh, np.ascontiguousarray(volume.values))
    side = path.with_suffix(".json")
    g = volume.grid
    info = {"box_min": list(g.box_min), "box_max": list(g.box_max), "shape": list(g.shape),
            "spacing": g.spacing.tolist(), "dtype": str(volume.values.dtype), "name": volume.name,
            "layout": "C order, axes (x, y, z); voxel centre = box_min + (index + 0.5) * spacing",
            **(extra or {})}
    write_json(info, side)
    return {"path": str(path), "grid_path": str(side)}


def read_volume_npy(path: str | os.PathLike) -> Volume:
    """Load a volume written by :func:`write_volume_npy` (NPY + JSON sidecar)."""
    path = Path(path)
    info = json.loads(path.with_suffix(".json").read_text())
    grid = Grid(tuple(info["box_min"]), tuple(info["box_max"]), tuple(info["shape"]))
    return Volume(grid, np.load(path, allow_pickle=False), name=info.get("name", ""))


def write_json(obj: Any, path: str | os.PathLike) -> Path:
    """JSON with indentation, written atomically."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(obj, indent=2, allow_nan=False))
    return Path(path)


def write_text(text: str, path: str | os.PathLike) -> Path:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return Path(path)
