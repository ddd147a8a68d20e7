"""Geometry and signal metrics, the evaluation protocol every figure names (stated below).

Sonar sees surfaces, never insides, so the protocol scores surfaces. Ground truth is a mesh in
the survey frame.

- Surface sample: :data:`GT_SAMPLES` = 20,000 area-weighted points with seed :data:`SEED`.
- **Surface F1 (primary)**, keys ``surface_iou``, ``surface_precision``, ``surface_recall``,
  ``surface_f1``: 5 mm voxels over the scene box. A voxel belongs to a surface when its centre
  lies within :data:`SURFACE_BAND` (5 mm) of it, with no fill: for the ground truth, of the mesh
  surface (exact point-to-triangle distances, :func:`within_distance_of_mesh`); for a point cloud,
  of one of its points (a KD-tree); for a mesh, of its surface (exact, as for the ground truth).
  The same band on both sides is what makes a perfectly placed surface score 1: counting only the
  voxels that hold a predicted point would mark a ~1-voxel-thick layer against a band two voxels
  thick, and a perfect surface would score 0.72-0.76 (sphere, cube, bunny). A prediction thicker
  than the surface (a ±5 mm shell of points, a double sheet) widens its band and loses precision.
- F-score at τ = 5 mm (``fscore``, ``fscore_precision``, ``fscore_recall``) and τ = 2.5 mm
  (``fscore_2_5mm``, ``fscore_2_5mm_precision``, ``fscore_2_5mm_recall``) on points (Tanks and
  Temples): precision = share of predicted points within τ of the GT sample, recall = share of GT
  samples within τ of the prediction.
- Chamfer-L2 (``chamfer_l2``, the SAS papers' convention): mean squared nearest-neighbour
  distance pred→GT plus GT→pred, m². Chamfer-L1 (``chamfer_l1``, Occupancy Networks): mean of
  the two unsquared means, m.
- Secondary, the paper code's convention: **solid F1** (``solid_iou``, ``solid_precision``,
  ``solid_recall``, ``solid_f1``): a GT voxel is inside the mesh or within one voxel (5 mm) of
  its surface; a predicted voxel holds at least one predicted point (mesh: its surface sample).
  It counts the filled inside of the object, which no sonar sees: a perfect surface scores about
  0.5 on it.
- Mesh quality (:func:`mesh_quality`; a mesh only): ``pieces``, the fewest connected components
  (sharing an edge) that hold :data:`PIECES_AREA_SHARE` (95 %) of the mesh's area (no GT needed);
  ``area_ratio``, mesh area over GT area; ``normal_consistency``, the mean |n·n_gt| of face
  normals at nearest points, averaged over both directions (mesh sample → GT sample and back,
  Occupancy Networks' definition). :class:`MeshChecks` holds the bounds a usable mesh meets.

Meshes are scored as points: their surface is resampled (area-weighted, fixed seed) with
:data:`GT_SAMPLES` points for the point metrics and normals, and densely enough (≥ 4 samples per
voxel face area) for the solid occupancy, so that every voxel the surface crosses is marked.

"Inside" (solid F1) uses the shell-and-fill rule: the set of voxels within one voxel of the
surface is a closed shell (two 6-neighbour centres are 5 mm apart, so a path from inside to
outside passes a centre within 2.5 mm of the surface), and the voxels it encloses (``scipy.
ndimage.binary_fill_holes``) are the inside. For a watertight mesh this equals ``contains ∪
band`` (tested against trimesh's ray test); for meshes with holes smaller than ~1 cm, like the
Stanford bunny's base, it closes them instead of failing. That band is also the surface F1's
ground truth.

"Within a distance of the surface" is exact: point-to-triangle distances
(:func:`within_distance_of_mesh`). The search for candidate triangles covers each triangle with
its own cells no wider than the search radius, so its time and memory follow the mesh's area
and edge lengths, not its largest triangle (:mod:`shsas_core.evaluation.metrics_reference` keeps the
earlier global-radius search as a test oracle and benchmark baseline).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox

#: Changes whenever a metric's definition or key changes: stored scores of another version are
#: recomputed (the pipeline's extraction cache key holds it).
METRICS_VERSION = 2
GT_SAMPLES = 20_000
SEED = 0
VOXEL = 0.005  # m
FSCORE_TAU = 0.005  # m
FSCORE_TAU_FINE = 0.0025  # m, the second F-score distance (keys fscore_2_5mm*)
#: a voxel belongs to a surface when its centre is this close to it (m): one voxel
SURFACE_BAND = VOXEL
#: ``pieces`` counts the largest connected components until they hold this share of the area
PIECES_AREA_SHARE = 0.95
MAX_MESH_SAMPLES = 2_000_000
# ground-truth band search (within_distance_of_mesh): cell side in search radii (1 measured
# fastest of 0.5-2 on the bunny, armadillo and a sliver cone), the finest cell as a share of the
# mesh's diagonal, and the cells held at a time
_CELL_RADII = 1.0
_MIN_CELL_SHARE = 1e-3
_CHUNK_CELLS = 262_144


# --------------------------------------------------------------------------------------------
# sampling and distances
def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int = GT_SAMPLES, seed: int = SEED) -> np.ndarray:
    """``n`` points uniformly distributed over a triangle mesh's area (area-weighted faces,
    uniform barycentric coordinates), reproducible for a given ``seed``.

    Returns:
        (n, 3) float64, m. Empty meshes (no area) give (0, 3).
    """
    return sample_surface_faces(vertices, faces, n, seed)[0]


def sample_surface_faces(vertices: np.ndarray, faces: np.ndarray, n: int = GT_SAMPLES,
                         seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sample_surface` (the same points for the same arguments) and the face each point
    lies on.

    Returns:
        (n, 3) float64 points, m, and (n,) int64 face indices; (0, 3) and (0,) for a mesh
        without area.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    empty = (np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
    if len(f) == 0 or n <= 0:
        return empty
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = float(area.sum())
    if not total > 0:
        return empty
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(f), size=n, p=area / total)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    # (1-√r1, √r1(1-r2), √r1 r2) is uniform on the triangle (Osada et al. 2002)
    pts = (1 - s)[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri] + (s * r2)[:, None] * c[tri]
    return pts, tri.astype(np.int64)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit face normals (right-hand rule); zero rows for zero-area faces."""
    tri = _triangles(vertices, faces)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def nn_distances(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(len(src),) distance from each ``src`` point to its nearest ``dst`` point, m."""
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if len(dst) == 0:
        return np.full(len(src), np.inf)
    d, _ = cKDTree(dst).query(src, k=1)
    return np.asarray(d, dtype=np.float64)


def _directed(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Nearest-neighbour distances pred -> gt and gt -> pred (m); None when either set is empty."""
    if len(pred) == 0 or len(gt) == 0:
        return None
    return nn_distances(pred, gt), nn_distances(gt, pred)


def chamfer(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Chamfer distances between point sets (m², m); inf when either set is empty."""
    d = _directed(pred, gt)
    if d is None:
        return {"chamfer_l2": math.inf, "chamfer_l1": math.inf}
    d_pg, d_gp = d
    return {
        "chamfer_l2": float(np.mean(d_pg**2) + np.mean(d_gp**2)),
        "chamfer_l1": float(0.5 * (np.mean(d_pg) + np.mean(d_gp))),
    }


def chamfer_l2_parts(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """The two directed halves of Chamfer-L2 (m²), whose sum is :func:`chamfer`'s ``chamfer_l2``:
    ``chamfer_l2_accuracy``, the mean squared distance from a predicted point to the reference
    (stray points raise it), and ``chamfer_l2_completeness``, from a reference point to the
    prediction (missed surface raises it). Which half moves says why two clouds rank as they do."""
    d = _directed(pred, gt)
    if d is None:
        return {"chamfer_l2_accuracy": math.inf, "chamfer_l2_completeness": math.inf}
    return {"chamfer_l2_accuracy": float(np.mean(d[0] ** 2)), "chamfer_l2_completeness": float(np.mean(d[1] ** 2))}


def fscore(pred: np.ndarray, gt: np.ndarray, tau: float = FSCORE_TAU, key: str = "fscore") -> dict[str, float]:
    """Tanks-and-Temples precision, recall and F-score at distance ``tau`` (m), as ``<key>``,
    ``<key>_precision`` and ``<key>_recall``."""
    if len(pred) == 0 or len(gt) == 0:
        return {f"{key}_precision": 0.0, f"{key}_recall": 0.0, key: 0.0}
    p = float(np.mean(nn_distances(pred, gt) <= tau))
    r = float(np.mean(nn_distances(gt, pred) <= tau))
    return {f"{key}_precision": p, f"{key}_recall": r, key: _f1(p, r)}


def point_fscores(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """F-scores at :data:`FSCORE_TAU` (keys ``fscore*``) and :data:`FSCORE_TAU_FINE` (keys
    ``fscore_2_5mm*``)."""
    return {**fscore(pred, gt, FSCORE_TAU), **fscore(pred, gt, FSCORE_TAU_FINE, key="fscore_2_5mm")}


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from points to triangles, row by row (Ericson, Real-Time
    Collision Detection §5.1.5: Voronoi regions of vertices, edges and face).

    Args:
        p, a, b, c: (K, 3) float64.
    Returns:
        (K,) distances, m.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    out = np.empty(len(p))
    done = np.zeros(len(p), dtype=bool)

    def put(mask: np.ndarray, q: np.ndarray) -> None:
        m = mask & ~done
        out[m] = np.linalg.norm(p[m] - q[m], axis=1)
        done[m] = True

    put((d1 <= 0) & (d2 <= 0), a)
    put((d3 >= 0) & (d4 <= d3), b)
    put((d6 >= 0) & (d5 <= d6), c)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = d1 / (d1 - d3)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + v[:, None] * ab)
        w = d2 / (d2 - d6)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + w[:, None] * ac)
        w2 = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + w2[:, None] * (c - b))
        denom = 1.0 / (va + vb + vc)
        v3, w3 = vb * denom, vc * denom
        # inside the errstate too: a zero-area triangle gives inf * 0 here (handled below)
        put(np.ones(len(p), dtype=bool), a + v3[:, None] * ab + w3[:, None] * ac)
    # degenerate (zero-area) triangles give NaN in the face branch: fall back to the edges
    bad = ~np.isfinite(out)
    if bad.any():
        out[bad] = np.minimum.reduce([_seg(p[bad], a[bad], b[bad]), _seg(p[bad], b[bad], c[bad]),
                                      _seg(p[bad], c[bad], a[bad])])
    return out


def within_distance_of_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                            radius: float, batch: int = 200_000) -> np.ndarray:
    """(P,) bool: exact test ``distance(point, surface) <= radius``.

    Candidate (point, triangle) pairs come from a search that follows each triangle's own extent
    (:func:`mesh_candidate_pairs`): a long thin triangle costs in proportion to its length, and
    one large triangle no longer widens every other lookup. Each candidate of a point not yet
    within ``radius`` is measured with :func:`point_triangle_distance`, so the result is the same
    as measuring every point against every triangle. Memory stays bounded by about ``batch``
    pairs and 2^18 cells (or one triangle's) at a time, plus the points and a KD-tree over them,
    whatever the mesh.

    Args:
        points: (P, 3) m.
        vertices, faces: (V, 3) m and (F, 3) vertex indices.
        radius: m, >= 0.
        batch: candidate pairs handled per step.
    Returns:
        (P,) bool.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    hit = np.zeros(len(pts), dtype=bool)
    tri = _triangles(vertices, faces)
    if len(tri) == 0 or len(pts) == 0 or not radius >= 0:
        return hit
    for pj, ti in _band_search(pts, tri, float(radius), batch):
        # a point already within radius of one triangle needs no more measuring
        keep = ~hit[pj]
        pj, ti = _unique_pairs(pj[keep], ti[keep], len(pts))
        for s in range(0, len(pj), batch):
            p_, t_ = pj[s:s + batch], ti[s:s + batch]
            d = point_triangle_distance(pts[p_], tri[t_, 0], tri[t_, 1], tri[t_, 2])
            hit[p_[d <= radius]] = True
    return hit


def mesh_candidate_pairs(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, radius: float,
                         batch: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """The (point, triangle) pairs the search of :func:`within_distance_of_mesh` finds, each once:
    a superset of the pairs with ``distance(point, triangle) <= radius`` (m), and a subset of
    those within ``radius + 2 s``, ``s`` the cell side: ``radius``, or 1/1000 of the mesh's
    diagonal when that is larger.

    Each triangle is covered by cells of side at most ``s`` along its two shorter edges (a single
    cell, its centroid, when the triangle is smaller; a row of cells along a sliver), each within
    ``rho <= s`` of its centre. A point can have its nearest surface point in a cell only if it
    is within ``radius + rho`` of the cell's centre, which a KD-tree search over the points
    answers; the centre is within ``rho`` of the triangle, hence the upper bound.

    Returns:
        (K,) int64 point indices and (K,) int64 face indices (all held at once: for tests and
        benchmarks).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tri = _triangles(vertices, faces)
    found = list(_band_search(pts, tri, float(radius), batch))
    if not found:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return _unique_pairs(np.concatenate([f[0] for f in found]), np.concatenate([f[1] for f in found]), len(pts))


def _triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3, 3) float64 corners, m."""
    return np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]


def _unique_pairs(p: np.ndarray, t: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    # sort + neighbour compare: np.unique on these int64 keys measured ~80x slower than np.sort
    key = np.sort(t * n_points + p)
    key = key[np.concatenate([[True], key[1:] != key[:-1]])] if len(key) else key
    return key % n_points, key // n_points


def _band_search(pts: np.ndarray, tri: np.ndarray, radius: float, batch: int):
    """Yield (point indices, face indices) arrays: every point within ``radius + rho`` (m, plus a
    rounding margin) of a cell centre of the face (:class:`_Cells`), about ``batch`` pairs and
    ~:data:`_CHUNK_CELLS` cells (or one triangle's) at a time. A pair can repeat."""
    if len(tri) == 0 or len(pts) == 0 or not radius >= 0:
        return
    # the float distances of point_triangle_distance can be off by more than the coordinates'
    # rounding on thin slivers: the search reaches this far past the exact bound (0.2 µm for a
    # 20 cm scene) so that every pair it would put within radius is found
    margin = 1e-6 * (float(np.abs(tri).max()) + radius)
    diag = float(np.linalg.norm(tri.reshape(-1, 3).max(0) - tri.reshape(-1, 3).min(0)))
    # cells of ~radius keep a cell's search ball within 2 radius; the floor bounds the number of
    # cells when radius is tiny or 0
    step = max(_CELL_RADII * radius, _MIN_CELL_SHARE * diag, 1e-12)
    # the two shorter edges of each triangle are the ones split: its number of cells, to cut the
    # mesh into runs of whole triangles of about _CHUNK_CELLS cells
    e = np.sort(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    n_cells = np.maximum(1, np.ceil(e[:, 0] / step)) * np.maximum(1, np.ceil(e[:, 1] / step))
    last = np.cumsum(n_cells)
    starts = np.unique(np.searchsorted(last, np.arange(0, last[-1], _CHUNK_CELLS), side="right"))
    tree = cKDTree(pts)
    for t0, t1 in zip(starts, [*starts[1:], len(tri)], strict=True):
        cells = _Cells(tri[t0:t1], step, int(t0))
        s, size = 0, max(1, batch // 64)  # cells per search, adapted to the pairs each brings
        while s < len(cells.rho):
            e_ = min(len(cells.rho), s + size)
            reach = radius + cells.rho[s:e_] + margin
            found = cKDTree(cells.centres[s:e_]).sparse_distance_matrix(tree, float(reach[-1]),
                                                                        output_type="ndarray")
            near = found["v"] <= reach[found["i"]]
            yield found["j"][near], cells.owner[s + found["i"][near]]
            size = int(np.clip(batch * (e_ - s) / max(len(found), 1), 1, 4 * (e_ - s)))
            s = e_


class _Cells:
    """Cells of side <= ``step`` (m) covering each of ``tri`` (T, 3, 3), sorted by ``rho``.

    The origin of a triangle is the vertex opposite its longest edge; its two edges ``e1, e2``
    are split into ``n1, n2`` parts and the triangle into the parallelogram cells that touch it
    (cell ``(i, j)`` with ``i/n1 + j/n2 <= 1``). A point of the triangle at edge coordinates
    ``(u, v)`` lies in cell ``(min(floor(u n1), n1-1), min(floor(v n2), n2-1))``, which passes that
    test, so the cells cover the triangle; each lies within half its longer diagonal (``rho``)
    of its centre. A triangle with ``n1 = n2 = 1`` has one cell: its centroid, with ``rho`` the
    distance to its farthest vertex (tighter than the parallelogram's).

    Attributes:
        centres: (S, 3) m.
        owner: (S,) face index (``first`` + row of ``tri``).
        rho: (S,) m, ascending.
    """

    def __init__(self, tri: np.ndarray, step: float, first: int = 0):
        ar = np.arange(len(tri))
        opposite = np.stack([tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2], tri[:, 1] - tri[:, 0]], 1)
        k = np.linalg.norm(opposite, axis=2).argmax(1)
        o, e1, e2 = tri[ar, k], tri[ar, (k + 1) % 3] - tri[ar, k], tri[ar, (k + 2) % 3] - tri[ar, k]
        n1 = np.maximum(1, np.ceil(np.linalg.norm(e1, axis=1) / step)).astype(np.int64)
        n2 = np.maximum(1, np.ceil(np.linalg.norm(e2, axis=1) / step)).astype(np.int64)
        owner = np.repeat(ar, n1 * n2)
        local = np.arange(len(owner)) - np.repeat(np.cumsum(n1 * n2) - n1 * n2, n1 * n2)
        m1, m2 = n1[owner], n2[owner]
        i, j = local // m2, local % m2
        keep = i * m2 + j * m1 <= m1 * m2
        owner, i, j, m1, m2 = owner[keep], i[keep], j[keep], m1[keep], m2[keep]
        a, b = e1[owner] / m1[:, None], e2[owner] / m2[:, None]
        centres = o[owner] + (i + 0.5)[:, None] * a + (j + 0.5)[:, None] * b
        rho = 0.5 * np.maximum(np.linalg.norm(a + b, axis=1), np.linalg.norm(a - b, axis=1))
        single = (n1 == 1) & (n2 == 1)
        if single.any():
            cen = tri[single].mean(1)
            s = single[owner]
            centres[s] = cen
            rho[s] = np.linalg.norm(tri[single] - cen[:, None], axis=2).max(1)
        # one search radius serves a run of cells: sorting by rho keeps it tight
        order = np.argsort(rho, kind="stable")
        self.centres, self.owner, self.rho = centres[order], owner[order] + first, rho[order]


# --------------------------------------------------------------------------------------------
# occupancy
class ScoringGrid:
    """The voxels the occupancy scores are counted on (the neural field's occupancy mask is
    another thing, :mod:`shsas_core.neural.fields.occupancy`).

    Voxels of size ``voxel`` (m) tile ``box`` from its min corner (the last layer may reach
    past the max corner). Voxel (i,j,k) spans ``min + [ijk, ijk+1) * voxel``."""

    def __init__(self, box: SceneBox, voxel: float = VOXEL):
        if not voxel > 0:
            raise ShsasError(f"metrics.voxel: must be > 0, got {voxel}")
        self.lo = np.asarray(box.min, dtype=np.float64)
        self.voxel = float(voxel)
        self.shape = tuple(int(max(1, math.ceil(s / voxel - 1e-9))) for s in box.size)

    def centres(self) -> np.ndarray:
        idx = np.stack(np.meshgrid(*[np.arange(n) for n in self.shape], indexing="ij"), -1).reshape(-1, 3)
        return self.lo + (idx + 0.5) * self.voxel

    def from_points(self, points: np.ndarray) -> np.ndarray:
        """Bool grid: voxels containing at least one point (points outside the box are ignored)."""
        occ = np.zeros(self.shape, dtype=bool)
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            return occ
        idx = np.floor((p - self.lo) / self.voxel).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.asarray(self.shape)), axis=1)
        occ[tuple(idx[ok].T)] = True
        return occ

    def band_from_mesh(self, vertices: np.ndarray, faces: np.ndarray, radius: float = SURFACE_BAND) -> np.ndarray:
        """Bool grid: centre within ``radius`` (m) of the mesh surface, exact (no fill)."""
        return within_distance_of_mesh(self.centres(), vertices, faces, radius).reshape(self.shape)

    def band_from_points(self, points: np.ndarray, radius: float = SURFACE_BAND) -> np.ndarray:
        """Bool grid: centre within ``radius`` (m) of at least one of ``points`` (P, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(self.shape, dtype=bool)
        d, _ = cKDTree(p).query(self.centres(), k=1, distance_upper_bound=radius * (1 + 1e-12))
        return (np.asarray(d) <= radius).reshape(self.shape)

    def from_mesh(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Bool grid, the solid F1's ground truth: centre inside the mesh or within one voxel of
        its surface (module doc)."""
        from scipy.ndimage import binary_fill_holes

        return binary_fill_holes(self.band_from_mesh(vertices, faces, self.voxel))


def occupancy_scores(pred: np.ndarray, gt: np.ndarray, prefix: str = "") -> dict[str, float]:
    """IoU, precision, recall, F1 of two boolean voxel grids of the same shape, as
    ``<prefix>iou``, ``<prefix>precision``, ``<prefix>recall``, ``<prefix>f1``."""
    pred, gt = np.asarray(pred, dtype=bool), np.asarray(gt, dtype=bool)
    if pred.shape != gt.shape:
        raise ShsasError(f"metrics: occupancy shapes differ {pred.shape} vs {gt.shape}")
    inter = int(np.count_nonzero(pred & gt))
    union = int(np.count_nonzero(pred | gt))
    npred, ngt = int(np.count_nonzero(pred)), int(np.count_nonzero(gt))
    p = inter / npred if npred else 0.0
    r = inter / ngt if ngt else 0.0
    return {f"{prefix}iou": inter / union if union else 0.0, f"{prefix}precision": p, f"{prefix}recall": r,
            f"{prefix}f1": _f1(p, r)}


def surface_concentration(volume: Any, vertices: np.ndarray, faces: np.ndarray, shell: float = 0.01) -> float:
    """How much a volume concentrates on a surface: mean magnitude of the voxels within ``shell``
    (m) of the mesh over the mean magnitude of the voxels outside the mesh farther than ``shell``.

    1 means no concentration (e.g. a flat field), larger is better. The inside of the mesh is left
    out: the front surface hides it, so the data say nothing about it. Inside/outside comes from
    filling the holes of the ``shell`` band on the volume's own grid, so ``shell`` must be at
    least the voxel diagonal (the band is then closed) and the mesh closed.

    Args:
        volume: a :class:`~shsas_core.data.volume.Volume` (e.g. ``neural.fields.volume.field_volume`` of a field).
        vertices, faces: the true surface, (V, 3) m and (F, 3).
        shell: half-width of the surface band, m.
    """
    from scipy.ndimage import binary_fill_holes

    grid = volume.grid
    if shell < float(np.linalg.norm(grid.spacing)):
        raise ShsasError(f"surface_concentration: shell {shell} m is below the voxel diagonal "
                         f"{float(np.linalg.norm(grid.spacing)):.4g} m (fix: a finer grid or a wider shell)")
    near = within_distance_of_mesh(grid.points(), vertices, faces, shell).reshape(grid.shape)
    outside = ~binary_fill_holes(near)
    if not near.any() or not outside.any():
        raise ShsasError("surface_concentration: the surface band or the outside is empty on this grid")
    mag = volume.magnitude()
    return float(mag[near].mean() / max(float(mag[outside].mean()), 1e-30))


# --------------------------------------------------------------------------------------------
# the protocol
class GroundTruth:
    """The GT mesh with what every method is scored against, computed once: the fixed surface
    sample and its face normals, the area, and on the 5 mm grid the surface band (surface F1)
    and the filled solid (solid F1).

    Attributes:
        samples: (n_samples, 3) m; sample_normals: (n_samples, 3) unit face normals.
        area: mesh area, m².
        surface: bool grid, centre within :data:`SURFACE_BAND` of the surface.
        solid: bool grid, ``surface`` (a one-voxel band) with its inside filled.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, box: SceneBox, voxel: float = VOXEL,
                 n_samples: int = GT_SAMPLES, seed: int = SEED):
        from scipy.ndimage import binary_fill_holes

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        if len(self.faces) == 0:
            raise ShsasError("ground truth: mesh has no faces")
        self.box, self.seed, self.n_samples = box, seed, n_samples
        self.samples, tri = sample_surface_faces(self.vertices, self.faces, n_samples, seed)
        self.sample_normals = face_normals(self.vertices, self.faces)[tri]
        self.area = _area(self.vertices, self.faces)
        self.grid = ScoringGrid(box, voxel)
        self.surface = self.grid.band_from_mesh(self.vertices, self.faces, SURFACE_BAND)
        # the solid's shell is one voxel wide; with the surface band of the same width the
        # exact distance test runs once
        band = self.surface if SURFACE_BAND == self.grid.voxel else self.grid.band_from_mesh(
            self.vertices, self.faces, self.grid.voxel)
        self.solid = binary_fill_holes(band)

    @classmethod
    def from_survey(cls, survey: Any, voxel: float = VOXEL) -> GroundTruth | None:
        if not getattr(survey, "has_ground_truth", False):
            return None
        return cls(survey.gt_vertices, survey.gt_faces, survey.meta.scene_box, voxel)


def score_points(points: np.ndarray, gt: GroundTruth) -> dict[str, float]:
    """Every metric for a point cloud (module doc): chamfer_l2, chamfer_l1, surface_iou,
    surface_precision, surface_recall, surface_f1, fscore(_precision, _recall),
    fscore_2_5mm(_precision, _recall), solid_iou, solid_precision, solid_recall, solid_f1,
    points."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = {**chamfer(pts, gt.samples),
           **occupancy_scores(gt.grid.band_from_points(pts, SURFACE_BAND), gt.surface, "surface_"),
           **point_fscores(pts, gt.samples),
           **occupancy_scores(gt.grid.from_points(pts), gt.solid, "solid_")}
    out["points"] = float(len(pts))
    return out


def score_mesh(vertices: np.ndarray, faces: np.ndarray, gt: GroundTruth) -> dict[str, float]:
    """Every metric for a mesh (module doc): those of :func:`score_points` but ``points``, with
    the surface band measured on the mesh itself and the rest through its resampled surface,
    plus :func:`mesh_quality` (pieces, area_ratio, normal_consistency) and faces."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    pts = sample_surface(v, f, gt.n_samples, gt.seed)
    area = _area(v, f)
    dense_n = int(min(MAX_MESH_SAMPLES, max(gt.n_samples, math.ceil(4 * area / gt.grid.voxel**2))))
    dense = sample_surface(v, f, dense_n, gt.seed + 1) if dense_n > gt.n_samples else pts
    occ = gt.grid.from_points(np.concatenate([pts, dense]))
    out = {**chamfer(pts, gt.samples),
           **occupancy_scores(gt.grid.band_from_mesh(v, f, SURFACE_BAND), gt.surface, "surface_"),
           **point_fscores(pts, gt.samples),
           **occupancy_scores(occ, gt.solid, "solid_"),
           **mesh_quality(v, f, gt)}
    out["faces"] = float(len(f))
    return out


def score_reconstruction(points: np.ndarray | None, mesh: Any | None, gt: GroundTruth,
                         fixed_points: np.ndarray | None = None) -> dict[str, float]:
    """Flat dict: ``pc_<metric>`` for the point cloud, ``mesh_<metric>`` for the mesh and
    ``fixed_<metric>`` for the point cloud at the paper's fixed level (when given)."""
    out: dict[str, float] = {}
    if points is not None:
        out.update({f"pc_{k}": v for k, v in score_points(points, gt).items()})
    if fixed_points is not None:
        out.update({f"fixed_{k}": v for k, v in score_points(fixed_points, gt).items()})
    if mesh is not None:
        out.update({f"mesh_{k}": v for k, v in score_mesh(mesh.vertices, mesh.faces, gt).items()})
    return out


# --------------------------------------------------------------------------------------------
# mesh quality
@dataclasses.dataclass(frozen=True)
class MeshChecks:
    """What a usable mesh of a one-piece object meets (module doc's mesh-quality keys): at most
    ``max_pieces`` pieces, an area ratio within ``area_ratio`` (a foam or a double sheet has far
    more area than the object, a torn mesh far less) and a normal consistency of at least
    ``min_normal_consistency``."""

    max_pieces: int = 3
    area_ratio: tuple[float, float] = (0.7, 1.3)
    min_normal_consistency: float = 0.85


#: The checks the report, the CLI and the benchmarks apply.
MESH_CHECKS = MeshChecks()


def mesh_pieces(vertices: np.ndarray, faces: np.ndarray, share: float = PIECES_AREA_SHARE) -> int:
    """The fewest connected components of a triangle mesh that hold ``share`` of its area.

    Faces are connected when they share an edge (a non-manifold edge joins all its faces);
    vertices at the same position are merged first, so a triangle soup that was split into
    separate vertices counts as the surface it describes. 0 for a mesh without area.
    """
    import trimesh

    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return 0
    m = trimesh.Trimesh(v, f, process=False)
    m.merge_vertices()
    # trimesh's face_adjacency keeps only edges with exactly two faces: link every face to the
    # first face of each of its edges instead, so non-manifold edges connect too
    _, first, inverse = np.unique(m.edges_sorted, axis=0, return_index=True, return_inverse=True)
    owner = m.edges_face
    pairs = np.stack([owner, owner[first][inverse.ravel()]], axis=1)
    labels = trimesh.graph.connected_component_labels(pairs, node_count=len(m.faces))
    area = np.bincount(labels, weights=m.area_faces)
    total = float(area.sum())
    if not total > 0:
        return 0
    held = np.cumsum(np.sort(area)[::-1])
    return int(np.searchsorted(held, share * total * (1 - 1e-12)) + 1)


def normal_consistency(points: np.ndarray, normals: np.ndarray, gt_points: np.ndarray,
                       gt_normals: np.ndarray) -> float:
    """Mean |n·n_gt| at nearest points, averaged over both directions (Occupancy Networks).

    Args:
        points, normals: (P, 3) m and unit normals of the prediction's sample.
        gt_points, gt_normals: (G, 3) the same for the ground truth.
    Returns:
        In [0, 1]; NaN when either set is empty.
    """
    p, n = np.asarray(points, np.float64).reshape(-1, 3), np.asarray(normals, np.float64).reshape(-1, 3)
    q, m = np.asarray(gt_points, np.float64).reshape(-1, 3), np.asarray(gt_normals, np.float64).reshape(-1, 3)
    if len(p) == 0 or len(q) == 0:
        return math.nan
    _, to_gt = cKDTree(q).query(p, k=1)
    _, to_pred = cKDTree(p).query(q, k=1)
    return float(0.5 * (np.mean(np.abs(_dot(n, m[to_gt]))) + np.mean(np.abs(_dot(m, n[to_pred])))))


def mesh_quality(vertices: np.ndarray, faces: np.ndarray, gt: GroundTruth | None = None) -> dict[str, float]:
    """``pieces`` always; with ``gt`` also ``area_ratio`` (mesh area / GT area) and
    ``normal_consistency`` (the mesh's sample of ``gt.n_samples`` points against ``gt``'s)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out = {"pieces": float(mesh_pieces(v, f))}
    if gt is not None:
        pts, tri = sample_surface_faces(v, f, gt.n_samples, gt.seed)
        out["area_ratio"] = _area(v, f) / gt.area
        out["normal_consistency"] = normal_consistency(pts, face_normals(v, f)[tri], gt.samples,
                                                       gt.sample_normals)
    return out


def mesh_check_failures(quality: Mapping[str, float | None], checks: MeshChecks = MESH_CHECKS
                        ) -> list[tuple[str, str, float, float]]:
    """The checks of :class:`MeshChecks` a mesh fails, from its :func:`mesh_quality` (keys
    without prefix; a missing or None value is not judged).

    Returns:
        ``(key, plain-language message, measure, limit)`` per failed check.
    """
    out: list[tuple[str, str, float, float]] = []
    pieces, ratio, nc = (quality.get(k) for k in ("pieces", "area_ratio", "normal_consistency"))
    if pieces is not None and pieces > checks.max_pieces:
        out.append(("pieces", f"the mesh is in {int(pieces)} pieces (95 % of its area), not one surface: "
                    "probably a foam of fragments", float(pieces), float(checks.max_pieces)))
    lo, hi = checks.area_ratio
    if ratio is not None and ratio > hi:
        out.append(("area_ratio", f"the mesh has {ratio:.2f}x the true area: probably a double sheet or "
                    "fragments around the surface", float(ratio), hi))
    elif ratio is not None and ratio < lo:
        out.append(("area_ratio", f"the mesh has only {ratio:.2f}x the true area: parts of the surface "
                    "are missing", float(ratio), lo))
    if nc is not None and nc < checks.min_normal_consistency:
        out.append(("normal_consistency", f"the mesh's faces agree with the true surface's orientation "
                    f"by only {nc:.2f} on average (mean |cos| of the angle): a rough or crumpled surface", float(nc),
                    checks.min_normal_consistency))
    return out


def finite_or_none(metrics: Mapping[str, float]) -> dict[str, float | None]:
    """Replace inf/NaN (empty predictions) by None so the dict is valid JSON."""
    return {k: (float(v) if math.isfinite(float(v)) else None) for k, v in metrics.items()}


def _f1(p: float, r: float) -> float:
    return 2 * p * r / (p + r) if p + r > 0 else 0.0


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", x, y)


def _seg(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    L2 = _dot(ab, ab)
    t = np.where(L2 > 0, np.clip(_dot(p - a, ab) / np.where(L2 > 0, L2, 1), 0, 1), 0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _area(v: np.ndarray, f: np.ndarray) -> float:
    if len(f) == 0:
        return 0.0
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
