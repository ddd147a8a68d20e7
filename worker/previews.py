"""Light previews of a finished job's meshes and point clouds, for the console's first view.

A full result can be large (a 256³ grid gives meshes of about a million triangles and clouds of
a few hundred thousand points, tens of MB per job), and a browser must download all of it before
it draws. So next to each ``{method}_mesh.glb`` the worker writes ``{method}_mesh_preview.glb``,
decimated by quadric edge collapse (fast-simplification) to at most :data:`PREVIEW_FACES`
triangles, and next to each ``{method}_pointcloud.ply`` a ``{method}_pointcloud_preview.ply`` of
at most :data:`PREVIEW_POINTS` of its points. A preview is in the same frame as its full file
(same GLB ``origin_offset``), so the console swaps one for the other in place. The full files
are unchanged; smaller meshes and clouds are copied as they are.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from shsas_core.common.atomic import atomic_path
from shsas_core.evaluation.extract import PointCloud
from shsas_core.outputs.export import (
    SCALAR_NAME,
    _empty_glb,
    glb_offset,
    read_point_cloud_ply,
    write_point_cloud_ply,
)

log = logging.getLogger("shsas.worker")

#: Triangles of a preview mesh at most: ~18 bytes each in GLB, so 3 methods stay under 3 MB.
PREVIEW_FACES = 50_000
#: Points of a preview cloud at most (28 bytes each in PLY).
PREVIEW_POINTS = 50_000
MESH, CLOUD = "_mesh.ply", "_pointcloud.ply"


def preview_name(artifact: str) -> str:
    """``shsas_mesh.glb`` -> ``shsas_mesh_preview.glb``."""
    stem, dot, ext = artifact.rpartition(".")
    return f"{stem}_preview{dot}{ext}"


def read_mesh_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (F, 3) int64 faces of a mesh PLY as ``write_mesh_ply`` writes it."""
    import trimesh

    m = trimesh.load(path, file_type="ply", process=False, force="mesh")
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64).reshape(-1, 3)


def decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int = PREVIEW_FACES) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with at most about ``max_faces`` triangles (quadric edge collapse); as it is when smaller."""
    if len(faces) <= max_faces:
        return vertices, faces
    import fast_simplification

    # The simplifier works in float32: far from the origin (UTM-like survey coordinates) that
    # is metres of rounding and nothing collapses, so it works on the mesh moved to its centre.
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    v, f = fast_simplification.simplify((vertices - centre).astype(np.float32), faces.astype(np.int32),
                                        target_reduction=1.0 - max_faces / len(faces))
    return np.asarray(v, dtype=np.float64) + centre, np.asarray(f, dtype=np.int64)


def subsample(n: int, max_points: int = PREVIEW_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` of ``n`` points, evenly spread over the file's order (no
    randomness: the same job always gives the same preview)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def write_mesh_preview(ply: Path, glb: Path) -> int:
    """Decimate the mesh ``ply`` into ``glb`` (float32, the full GLB's offset); returns its triangles."""
    import trimesh

    vertices, faces = read_mesh_ply(ply)
    offset = glb_offset(vertices)  # the full mesh's: the preview lies exactly where it does
    v, f = decimate(vertices, faces)
    data = trimesh.Trimesh(v - offset, f, process=False).export(file_type="glb") if len(f) else _empty_glb()
    with atomic_path(glb) as tmp:
        Path(tmp).write_bytes(data)
    return len(f)


def write_cloud_preview(ply: Path, out: Path) -> int:
    """At most :data:`PREVIEW_POINTS` points of the cloud ``ply`` into ``out``; returns their number."""
    cols = read_point_cloud_ply(ply)
    keep = subsample(len(cols["x"]))
    pts = np.stack([cols["x"][keep], cols["y"][keep], cols["z"][keep]], axis=1)
    write_point_cloud_ply(PointCloud(points=pts, scalars=cols[SCALAR_NAME][keep]), out)
    return len(keep)


def write_previews(out_dir: Path, artifacts: list[str]) -> list[str]:
    """Write the previews of every mesh and cloud in ``artifacts``; returns the new file names.

    A preview that cannot be made is logged and left out (the full files remain): it never
    fails the job.
    """
    made = []
    names = set(artifacts)
    for name in artifacts:
        if name.endswith(MESH) and name.replace(".ply", ".glb") in names:
            target, write = preview_name(name.replace(".ply", ".glb")), write_mesh_preview
        elif name.endswith(CLOUD):
            target, write = preview_name(name), write_cloud_preview
        else:
            continue
        try:
            write(out_dir / name, out_dir / target)
            made.append(target)
        except Exception as exc:  # a preview is a convenience: the job stands without it
            log.warning("preview of %s not written: %s: %s", name, type(exc).__name__, exc)
    return made
