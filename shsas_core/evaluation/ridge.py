"""The ridge of a volume's magnitude: one sheet of points where a blurred shell peaks.

A sonar image of a surface is a shell: the magnitude peaks on the surface and falls off over the
range resolution on either side. Thresholding keeps the whole shell (several voxels thick, so a
marching-cubes mesh of it is two sheets, inside and outside); the surface is the shell's ridge.

Ridge test (a height ridge, Eberly 1996): smooth the magnitude ``m`` with a Gaussian of
``sigma`` voxels, take its gradient ``g`` and Hessian ``H`` by central differences at the
candidate voxels, and let ``n`` be the eigenvector of ``H``'s most negative eigenvalue ``λ``
(the direction across the sheet: ``m`` curves down fastest along it; ``|λ|`` must be the Hessian's
largest, and the whole gradient no steeper than ``|λ| h``, else the voxel sits on the flank of a
curved shell, where ``m`` also curves down along the sheet). Along ``n`` the magnitude is
locally ``m(c + t n) ≈ m(c) + (g·n) t + ½ λ t²``, whose peak lies at ``t* = -(g·n) / λ``. The voxel
at ``c`` is a ridge voxel when ``λ < 0`` and that peak lies in its slab, ``|t*| <= h/2`` (``h`` the
voxel size along ``n``): exactly one voxel of every column across a sheet passes, whatever the
sheet's orientation (non-maximum suppression along ``n``). Its point is the peak itself,
``c + t* n``, so points sit on the ridge to a fraction of a voxel rather than on voxel centres.

The volume gradient vanishes on the ridge, so the normal is ``n`` (the gradient's direction just
off the ridge, up to sign); :func:`orient_toward_sensors` gives it a sign. The smoothing that
places the ridge to a fraction of a voxel is too fine for its direction on a speckled image: the
across-sheet direction of a more heavily smoothed copy (:func:`sheet_normals`) follows the surface
better where speckle makes the fine one turn along the sheet.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

#: A ridge voxel's gradient is at most this many voxels of Newton step (``|g| <= STEEP |λ| h``):
#: on a shell of radius R the flank's ratio is about R (tens of voxels), on the ridge of a sonar
#: image brightness varies along the surface by a voxel's worth or less (speckle included).
STEEP = 4.0


@dataclasses.dataclass
class Ridge:
    """Ridge points of a volume.

    Attributes:
        index: (P, 3) int64 voxel indices of the ridge voxels.
        points: (P, 3) float64 sub-voxel ridge positions, m, survey frame.
        normals: (P, 3) float64 unit normals across the sheet (sign not yet chosen).
        values: (P,) float32 smoothed magnitude at the voxel, same scale as the input.
    """

    index: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def subset(self, keep: np.ndarray) -> Ridge:
        """The points selected by a boolean mask or index array ``keep``."""
        return Ridge(self.index[keep], self.points[keep], self.normals[keep], self.values[keep])


def smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """``values`` (X, Y, Z) smoothed by a Gaussian of ``sigma`` voxels (0: unchanged), float32."""
    v = np.asarray(values, dtype=np.float32)
    if sigma <= 0:
        return v
    return ndimage.gaussian_filter(v, sigma=sigma, mode="nearest").astype(np.float32)


def derivatives(s: np.ndarray, index: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient and Hessian of ``s`` at voxels ``index`` by central differences.

    Args:
        s: (X, Y, Z) values.
        index: (P, 3) voxel indices.
        spacing: (3,) voxel size, m.
    Returns:
        ``(g, H)``: (P, 3) gradient and (P, 3, 3) symmetric Hessian, per metre (per m²). The volume
        is extended by repeating its faces, so derivatives at the faces are one-sided.
    """
    p = np.pad(s.astype(np.float64), 1, mode="edge")
    i = index + 1
    h = np.asarray(spacing, dtype=np.float64)
    eye = np.eye(3, dtype=np.int64)

    def at(off: np.ndarray) -> np.ndarray:
        j = i + off
        return p[j[:, 0], j[:, 1], j[:, 2]]

    c = at(np.zeros(3, dtype=np.int64))
    g = np.empty((len(index), 3))
    hess = np.empty((len(index), 3, 3))
    for a in range(3):
        fwd, bwd = at(eye[a]), at(-eye[a])
        g[:, a] = (fwd - bwd) / (2 * h[a])
        hess[:, a, a] = (fwd - 2 * c + bwd) / h[a] ** 2
        for b in range(a + 1, 3):
            hab = (at(eye[a] + eye[b]) - at(eye[a] - eye[b]) - at(-eye[a] + eye[b]) + at(-eye[a] - eye[b])) / (
                4 * h[a] * h[b])
            hess[:, a, b] = hess[:, b, a] = hab
    return g, hess


def ridge(values: np.ndarray, candidates: np.ndarray, box_min: np.ndarray, spacing: np.ndarray,
          sigma: float = 1.0) -> Ridge:
    """Ridge voxels of ``values`` among ``candidates`` (module doc).

    Args:
        values: (X, Y, Z) non-negative magnitude.
        candidates: (X, Y, Z) bool, voxels allowed to be ridge voxels (e.g. above a threshold).
        box_min: (3,) grid corner, m; voxel (i, j, k) has centre ``box_min + (idx + 0.5) * spacing``.
        spacing: (3,) voxel size, m.
        sigma: Gaussian smoothing before the derivatives, voxels.
    Returns:
        :class:`Ridge` (empty when no candidate is a ridge voxel).
    """
    spacing = np.asarray(spacing, dtype=np.float64)
    s = smooth(values, sigma)
    idx = np.argwhere(candidates)
    if len(idx) == 0:
        return Ridge(np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.float32))
    g, hess = derivatives(s, idx, spacing)
    lam, vec = np.linalg.eigh(hess)  # ascending: column 0 is the most negative curvature
    n = vec[:, :, 0]
    lam0 = lam[:, 0]
    slope = np.einsum("pi,pi->p", g, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -slope / lam0
    half = 0.5 * np.sqrt(np.einsum("pi,i->p", n * n, spacing * spacing))  # half the voxel along n
    # on the outer flank of a curved shell the magnitude also curves down along the sheet, where
    # the gradient has no component; there the gradient is steep across the sheet. On the ridge
    # the whole gradient is what one voxel of Newton step along n explains (brightness that
    # varies along the surface changes over many voxels, not one)
    steep = np.linalg.norm(g, axis=1) > -lam0 * STEEP * 2 * half
    keep = (lam0 < 0) & (-lam0 >= np.abs(lam[:, 2])) & ~steep & np.isfinite(t) & (np.abs(t) <= half)
    idx, n, t = idx[keep], n[keep], t[keep]
    centres = np.asarray(box_min, dtype=np.float64) + (idx + 0.5) * spacing
    pts = centres + t[:, None] * n
    vals = s[tuple(idx.T)].astype(np.float32)
    return Ridge(idx.astype(np.int64), pts, n, vals)


def sheet_normals(values: np.ndarray, index: np.ndarray, spacing: np.ndarray, sigma: float) -> np.ndarray:
    """Across-sheet directions of ``values`` smoothed by ``sigma`` voxels at voxels ``index``.

    Args:
        values: (X, Y, Z) magnitude; index: (P, 3) voxel indices; spacing: (3,) voxel size, m.
    Returns:
        (P, 3) unit eigenvectors of the smoothed Hessian's most negative eigenvalue (sign arbitrary).
    """
    if len(index) == 0:
        return np.zeros((0, 3))
    _, hess = derivatives(smooth(values, sigma), index, np.asarray(spacing, dtype=np.float64))
    return np.linalg.eigh(hess)[1][:, :, 0]


def piece_labels(r: Ridge, shape: tuple[int, int, int]) -> tuple[np.ndarray, int]:
    """The 26-connected piece of each ridge voxel: ((P,) labels in 1..count, count)."""
    mask = np.zeros(shape, dtype=bool)
    mask[tuple(r.index.T)] = True
    labels, count = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    return labels[tuple(r.index.T)], int(count)


def drop_small_pieces(r: Ridge, shape: tuple[int, int, int], min_share: float, reach: float = 0.0) -> Ridge:
    """Keep the ridge voxels whose 26-connected piece holds at least ``min_share`` of the points of
    the largest piece, and, with ``reach`` > 0 (m), the smaller pieces with a point within
    ``reach`` of such a piece: a surface is a connected sheet, isolated noise peaks are specks,
    but a surface lit at grazing angles breaks into small pieces along the sheet it continues."""
    if len(r) == 0 or min_share <= 0:
        return r
    lab, count = piece_labels(r, shape)
    sizes = np.bincount(lab, minlength=count + 1)
    return _pieces_and_their_reach(r, lab, count, sizes >= min_share * sizes[1:].max(), reach)


def orient_toward_sensors(points: np.ndarray, normals: np.ndarray, sensors: np.ndarray,
                          nearest: int = 8, neighbours: int = 12, rounds: int = 2,
                          votes: np.ndarray | None = None) -> np.ndarray:
    """Sign each normal so it points toward the sensors that lit its point.

    A sonar only sees the side of a surface that faces it. Each point's own vote is ``votes``
    where given and non-zero (a signed confidence in [-1, 1] that the input normal faces the
    lit side, e.g. :func:`visibility_votes`); elsewhere it is the nearest sensors' vote: the object
    lies inside the survey, so of the sensors on either side of a point's tangent plane those
    nearest the point are taken to be the ones that saw it, and the normal is flipped to face the
    mean direction to its ``nearest`` sensors (wrong on faces turned toward the survey's axis, such
    as the inner faces of a bunny's ears: the sensors that lit them are across the circle). Where
    the own vote is weak ``rounds`` passes of a neighbourhood vote (the ``neighbours`` nearest
    points, weighted by ``|n·n_j|``) make the sign agree with the sheet around it.

    Args:
        points: (P, 3) m; normals: (P, 3) unit vectors, any sign.
        sensors: (M, 3) sensor (e.g. transmitter) positions, m.
        votes: (P,) signed confidence that each input normal faces the lit side; 0 = no vote.
    Returns:
        (P, 3) normals, each ``±`` the input.
    """
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64).copy()
    sens = np.unique(np.asarray(sensors, dtype=np.float64).reshape(-1, 3), axis=0)
    if len(pts) == 0 or len(sens) == 0:
        return nrm
    k = min(nearest, len(sens))
    _, j = cKDTree(sens).query(pts, k=k)
    j = j.reshape(len(pts), k)
    to_sensor = sens[j] - pts[:, None, :]
    to_sensor /= np.linalg.norm(to_sensor, axis=2, keepdims=True) + 1e-30
    toward = to_sensor.mean(1)  # (P, 3); |toward·n| in [0, 1]: how clearly the sensors pick a side
    own = np.einsum("pc,pc->p", toward, nrm)  # vote for the input sign
    if votes is not None:
        v = np.asarray(votes, dtype=np.float64)
        own = np.where(v != 0, v, own)
    nrm[own < 0] *= -1
    strength = np.abs(own)  # of the vote for the sign now held
    if len(pts) > 1 and rounds > 0:
        kk = min(neighbours + 1, len(pts))
        _, nb = cKDTree(pts).query(pts, k=kk)
        nb = nb.reshape(len(pts), kk)[:, 1:]
        held = np.ones(len(pts))  # +1 while a point holds its voted sign, -1 once flipped
        for _ in range(rounds):
            # a point keeps its sign while its own vote outweighs its neighbours' (each weighted
            # by the strength of its own vote): only weakly held signs follow the sheet around them
            agree = np.einsum("pkc,pc->pk", nrm[nb], nrm)
            score = held * strength + (agree * strength[nb]).mean(1)
            flip = score < 0
            nrm[flip] *= -1
            held[flip] *= -1
    return nrm


def visibility_votes(points: np.ndarray, normals: np.ndarray, sensors: np.ndarray, occupied: np.ndarray,
                     box_min: np.ndarray, spacing: np.ndarray, own_cell: float, max_sensors: int = 32,
                     min_cos: float = 0.2, chunk: int = 2048) -> np.ndarray:
    """Which side of each point's sheet the sensors that could see it lie on.

    The object blocks sound: a sensor behind the surface (on the inner side of a point's tangent
    plane) sees the point only through the object, whose far wall is bright in the image. For each
    point and each of up to ``max_sensors`` sensors (evenly chosen) the line of sight is marched
    voxel by voxel through ``occupied`` (the image's bright voxels) to the sensor or the box's
    face; hits within ``own_cell`` of the point's tangent plane are the point's own echo and
    do not block. The vote is the share of the sensors on the normal's side that see the point
    unblocked less the share on the other side: on an object closed by bright walls the inner
    side sees nothing, the outer side some or all. Sensors within ``asin(min_cos)`` of the
    tangent plane (grazing) take no part.

    Args:
        points: (P, 3) m; normals: (P, 3) unit, any sign; sensors: (M, 3) m.
        occupied: (X, Y, Z) bool, voxels that block a line of sight.
        box_min: (3,) grid corner, m; spacing: (3,) voxel size, m.
        own_cell: half-thickness of the point's own echo across its sheet, m (the range
            resolution: the mainlobe of a point's echo reaches its first null there).
    Returns:
        (P,) votes in [-1, 1] for the input normal's sign (0: no sensor decides).
    """
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    sens = np.unique(np.asarray(sensors, dtype=np.float64).reshape(-1, 3), axis=0)
    out = np.zeros(len(pts))
    if len(pts) == 0 or len(sens) == 0:
        return out
    if len(sens) > max_sensors:
        sens = sens[np.linspace(0, len(sens) - 1, max_sensors).round().astype(np.int64)]
    h = np.asarray(spacing, dtype=np.float64)
    lo = np.asarray(box_min, dtype=np.float64)
    shape = np.asarray(occupied.shape)
    hi = lo + shape * h
    step = float(h.min())  # one voxel per step: a sheet of bright voxels is not stepped over
    for a in range(0, len(pts), chunk):
        p, n = pts[a:a + chunk], nrm[a:a + chunk]
        u = sens[None, :, :] - p[:, None, :]  # (C, S, 3) toward each sensor
        dist = np.linalg.norm(u, axis=2)
        u /= dist[..., None]
        cos = np.einsum("pc,psc->ps", n, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            exits = np.where(u > 0, (hi - p[:, None, :]) / u, np.where(u < 0, (lo - p[:, None, :]) / u, np.inf))
        reach = np.minimum(exits.min(2), dist)  # the march ends at the box's face or the sensor
        blocked = np.zeros(cos.shape, dtype=bool)
        for k in range(1, int(np.ceil(float(reach.max()) / step)) + 1):
            t = k * step
            live = (t < reach) & ~blocked & (np.abs(t * cos) > own_cell)
            if not live.any():
                if not np.any((t < reach) & ~blocked):
                    break
                continue
            idx = np.floor((p[:, None, :] + t * u - lo) / h).astype(np.int64)
            live &= np.all((idx >= 0) & (idx < shape), axis=2)
            j = idx[live]
            blocked[live] = occupied[j[:, 0], j[:, 1], j[:, 2]]
        use = np.abs(cos) >= min_cos
        seen = use & ~blocked
        front, back = use & (cos > 0), use & (cos < 0)
        out[a:a + chunk] = ((seen & front).sum(1) / np.maximum(front.sum(1), 1)
                            - (seen & back).sum(1) / np.maximum(back.sum(1), 1))
    return out


def suppress_sidelobes(points: np.ndarray, normals: np.ndarray, strength: np.ndarray, reach: float,
                       gap: float, width: float) -> np.ndarray:
    """Which points are not a range sidelobe standing in front of a stronger point's sheet.

    A bright sheet's range sidelobes stand as weaker parallel sheets within the range resolution
    of it. In front of a lit surface (on the side of the sensors that lit it) there is only the
    medium, so a weaker sheet there is the surface's sidelobe; behind it a weaker sheet may be a
    real surface (the far face of a thin part, lit from the other side) and stays. Point ``i`` is
    dropped when a stronger point ``j`` has it in front, along ``j``'s oriented normal at a
    distance between ``gap`` and ``reach`` and within ``width`` of that line (a KD-tree finds the
    candidates). ``gap`` keeps ``j``'s own sheet (the ridge places one point per voxel column,
    so its neighbours on the sheet lie within a voxel of the tangent plane).

    Args:
        points: (P, 3) m; normals: (P, 3) unit, facing the sensors that lit each point;
        strength: (P,) magnitude. reach, gap, width: m.
    Returns:
        (P,) bool, True for the points kept.
    """
    pts = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(pts), dtype=bool)
    if len(pts) < 2 or reach <= gap:
        return keep
    pairs = cKDTree(pts).query_pairs(float(np.hypot(reach, width)), output_type="ndarray")
    if len(pairs) == 0:
        return keep
    pairs = np.concatenate([pairs, pairs[:, ::-1]])  # (i, j) both ways
    i, j = pairs[:, 0], pairs[:, 1]
    val = np.asarray(strength, dtype=np.float64)
    stronger = val[j] > val[i]
    i, j = i[stronger], j[stronger]
    d = pts[i] - pts[j]
    n = np.asarray(normals, dtype=np.float64)[j]
    along = np.einsum("pc,pc->p", d, n)  # > 0: i stands in front of j's sheet
    across = np.linalg.norm(d - along[:, None] * n, axis=1)
    hit = (along >= gap) & (along <= reach) & (across <= width)
    keep[i[hit]] = False
    return keep


def connected_to_strong(r: Ridge, shape: tuple[int, int, int], strong: float,
                        values: np.ndarray | None = None, reach: float = 0.0) -> Ridge:
    """Hysteresis: keep the ridge voxels whose 26-connected piece of ridge voxels holds at least
    one voxel of value >= ``strong`` (Canny's rule: weak ridge continues a strong one or goes),
    and, with ``reach`` > 0, the pieces with a point within ``reach`` m of such a piece's points
    (a weak continuation across a gap the ridge test left).

    Args:
        values: (P,) the value each ridge voxel is judged by (None: ``r.values``).
        reach: m, 0 for 26-connectivity alone.
    """
    if len(r) == 0:
        return r
    values = r.values if values is None else np.asarray(values)
    lab, count = piece_labels(r, shape)
    good = np.zeros(count + 1, dtype=bool)
    good[lab[values >= strong]] = True
    return _pieces_and_their_reach(r, lab, count, good, reach)


def _pieces_and_their_reach(r: Ridge, lab: np.ndarray, count: int, good: np.ndarray, reach: float) -> Ridge:
    """The points of ``r`` whose piece (``lab``, (P,) in 1..count) is ``good`` ((count + 1,)
    bool), and, with ``reach`` > 0 (m), of the pieces with a point within ``reach`` of those."""
    keep = good[lab]
    if reach > 0 and keep.any() and not keep.all():
        dist, _ = cKDTree(r.points[keep]).query(r.points[~keep], distance_upper_bound=reach)
        near = np.zeros(count + 1, dtype=bool)
        near[lab[~keep][dist <= reach]] = True
        keep |= near[lab]
    return r.subset(keep)
