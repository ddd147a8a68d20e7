"""A surface mesh from oriented surface points: screened Poisson, trimmed to the data, simplified.

Screened Poisson reconstruction (Kazhdan & Hoppe 2013, through MeshLab's ``pymeshlab``) fits an
indicator function whose gradient matches the oriented points and takes its level set: one
closed, manifold surface however noisy or uneven the points are, where marching cubes of a
thresholded volume gives a sheet per side of every shell and a speck per noise peak. Poisson also
closes the surface where no point says where it is (the unseen underside of an object on the
floor); those parts are cut away: every face with a corner farther than ``trim`` from the nearest
point is dropped (distance trimming, the same cut as Open3D's density trimming, with the cut in
metres). Last, quadric edge collapse (``fast_simplification``) brings the face count down to a
budget proportional to the number of points, so the exported mesh is about as detailed as the
data that carved it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from shsas_core.common.errors import ShsasError

#: Points a vertex's sheet is fitted from (:func:`sheet_offset`).
SHEET_NEIGHBOURS = 8


def _empty_mesh():
    import trimesh

    return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)


def poisson_depth(extent: float, spacing: float, max_depth: int = 10) -> int:
    """Octree depth whose finest cell is no larger than ``spacing`` over ``extent`` (m), with
    Poisson's 10 % margin, between 5 and ``max_depth``."""
    if not (extent > 0 and spacing > 0):
        return 5
    return int(min(max_depth, max(5, math.ceil(math.log2(1.1 * extent / spacing)))))


def screened_poisson(points: np.ndarray, normals: np.ndarray, depth: int, point_weight: float = 4.0,
                     threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Screened Poisson surface of oriented points.

    Args:
        points: (P, 3) m; normals: (P, 3) unit, pointing out of the object (toward the sensors).
        depth: octree depth (grid of ``2**depth`` cells across the points' bounds).
        point_weight: screening weight (interpolation of the points; 0: classic Poisson).
        threads: solver threads; None: one. The OpenMP solver's threads spin while they wait, so on
            a shared CPU two threads ran 10x slower than one (2,000 points: 20 s against 2 s).
    Returns:
        ``(vertices (V, 3) float64 m, faces (F, 3) int64)``, faces wound so their normals point
        the way the input normals do.
    """
    import pymeshlab

    if len(points) < 4:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(points, dtype=np.float64),
                               v_normals_matrix=np.ascontiguousarray(normals, dtype=np.float64)))
    ms.generate_surface_reconstruction_screened_poisson(
        depth=int(depth), pointweight=float(point_weight), preclean=False,
        threads=int(threads or 1))
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def keep_vertices(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces whose three corners ``keep`` (V,) bool marks, and the vertices they use,
    re-indexed: ``(vertices, faces)``."""
    f = faces[keep[faces].all(1)]
    used = np.unique(f)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[f]


def trim_to_points(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                   distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Drop the faces with a corner farther than ``distance`` (m) from every point, and the
    vertices no face uses. Returns ``(vertices, faces)`` re-indexed."""
    if len(faces) == 0 or len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    d, _ = cKDTree(points).query(vertices, distance_upper_bound=distance * 1.0001)
    return keep_vertices(vertices, faces, np.isfinite(d) & (d <= distance))


def sheet_offset(vertices: np.ndarray, points: np.ndarray, normals: np.ndarray, reach: float,
                 k: int = SHEET_NEIGHBOURS) -> np.ndarray:
    """Each vertex's distance off the sheet of its nearest points: the mean of ``|(v - p)·n|``
    over its ``k`` nearest points within ``reach`` (m); inf where none lies that near.

    Args:
        vertices: (V, 3) m. points, normals: (P, 3) m and unit normals.
    Returns:
        (V,) m.
    """
    d, idx = cKDTree(points).query(vertices, k=min(k, len(points)), distance_upper_bound=reach)
    d, idx = d.reshape(len(vertices), -1), idx.reshape(len(vertices), -1)
    near = np.isfinite(d)
    idx = np.where(near, idx, 0)
    along = np.abs(np.einsum("vkc,vkc->vk", vertices[:, None, :] - points[idx], normals[idx]))
    count = near.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (along * near).sum(1) / count, np.inf)


def trim_off_sheet(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, normals: np.ndarray,
                   distance: float, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Drop the faces with a corner farther than ``distance`` (m) off the sheet of the points
    within ``reach`` (m) of it (:func:`sheet_offset`). Returns ``(vertices, faces)`` re-indexed."""
    if len(faces) == 0 or len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return keep_vertices(vertices, faces, sheet_offset(vertices, points, normals, reach) <= distance)


def simplify(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge collapse down to about ``max_faces`` faces (unchanged when already fewer)."""
    if len(faces) <= max_faces or max_faces < 4:
        return vertices, faces
    import fast_simplification

    v, f = fast_simplification.simplify(np.ascontiguousarray(vertices, dtype=np.float64),
                                        np.ascontiguousarray(faces, dtype=np.int32), target_count=int(max_faces))
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def drop_small_components(mesh, min_share: float):
    """``mesh`` without the connected pieces whose area is under ``min_share`` of the largest's."""
    if len(mesh.faces) == 0 or min_share <= 0:
        return mesh
    import trimesh

    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    areas = np.array([p.area for p in parts])
    keep = [p for p, a in zip(parts, areas, strict=True) if a >= min_share * areas.max()]
    return trimesh.util.concatenate(keep)


def poisson_mesh(points: np.ndarray, normals: np.ndarray, spacing: float, *, trim: float,
                 faces_per_point: float, max_faces: int, min_piece: float, point_weight: float = 4.0,
                 sheet_trim: float | None = None):
    """The module's chain: Poisson at a depth resolving ``spacing`` (m), trimmed to ``trim`` (m)
    from the points (and, when ``sheet_trim`` is given, to ``sheet_trim`` m off their sheet),
    pieces under ``min_piece`` of the largest's area dropped, simplified to
    ``min(max_faces, faces_per_point * P)`` faces.

    Returns:
        ``trimesh.Trimesh`` in the points' frame (empty when there are too few points).
    """
    import trimesh

    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 4:
        return _empty_mesh()
    if spacing <= 0 or trim <= 0:
        raise ShsasError(f"meshing: spacing and trim must be > 0 m, got {spacing} and {trim}")
    extent = float(np.max(pts.max(0) - pts.min(0)))
    v, f = screened_poisson(pts, normals, poisson_depth(extent, spacing), point_weight)
    v, f = trim_to_points(v, f, pts, trim)
    if sheet_trim is not None:
        v, f = trim_off_sheet(v, f, pts, np.asarray(normals, dtype=np.float64), sheet_trim, trim)
    if len(f) == 0:
        return _empty_mesh()
    budget = int(min(max_faces, max(4, faces_per_point * len(pts))))
    v, f = simplify(v, f, budget)
    m = trimesh.Trimesh(v, f, process=True)
    return drop_small_components(m, min_piece)
