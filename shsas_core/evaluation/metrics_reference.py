"""The first ground-truth band test, kept as a test oracle and benchmark baseline only.

:func:`reference_within_distance_of_mesh` is :func:`shsas_core.evaluation.metrics.within_distance_of_mesh`
as it was before the per-triangle search, the reference: candidate pairs are every (point, triangle)
whose centroids lie within ``radius`` plus the *largest* triangle's bounding radius. That is
correct but, on a mesh with long thin triangles, pairs nearly every point with nearly every
triangle (a 7,264-face cone: 44 s and an 8.4 GB peak for one ground truth). The tests compare
the new search against it and against brute force; ``benchmarks/bench_metrics.py`` times both.
Nothing in the library calls it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from shsas_core.evaluation.metrics import point_triangle_distance


def reference_candidate_count(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                              radius: float) -> int:
    """Number of exact distance evaluations :func:`reference_within_distance_of_mesh` makes
    (its candidate (point, triangle) pairs), counted without building them."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
    if len(tri) == 0 or len(pts) == 0:
        return 0
    cen = tri.mean(1)
    brad = float(np.linalg.norm(tri - cen[:, None], axis=2).max())
    counts = cKDTree(cen).query_ball_point(pts, r=radius + brad + 1e-12, return_length=True)
    return int(np.sum(counts))


def reference_within_distance_of_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                                      radius: float, batch: int = 200_000) -> np.ndarray:
    """(P,) bool: exact test ``distance(point, surface) <= radius`` (m), global-radius search.

    A triangle can be within ``radius`` only if its centroid is within ``radius`` plus the
    triangle's bounding radius; this version uses the largest bounding radius of the mesh for
    every lookup, then measures every candidate exactly with :func:`point_triangle_distance`.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    hit = np.zeros(len(pts), dtype=bool)
    if len(f) == 0 or len(pts) == 0:
        return hit
    tri = v[f]
    cen = tri.mean(1)
    brad = float(np.linalg.norm(tri - cen[:, None], axis=2).max())
    # points farther than radius + brad from every centroid cannot be within radius
    dmin, _ = cKDTree(cen).query(pts, k=1, distance_upper_bound=radius + brad + 1e-12)
    cand = np.flatnonzero(np.isfinite(dmin))
    if len(cand) == 0:
        return hit
    lists = cKDTree(cen).query_ball_point(pts[cand], r=radius + brad + 1e-12)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    pi = np.repeat(cand, counts)
    ti = np.fromiter((t for x in lists for t in x), dtype=np.int64, count=int(counts.sum()))
    for s in range(0, len(pi), batch):
        p_, t_ = pi[s:s + batch], ti[s:s + batch]
        d = point_triangle_distance(pts[p_], tri[t_, 0], tri[t_, 1], tri[t_, 2])
        hit[p_[d <= radius]] = True
    return hit
