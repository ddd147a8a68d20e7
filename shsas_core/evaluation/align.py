"""Rigid alignment of a reconstruction to a ground-truth surface whose pose is not known.

A real scan's object stands on the turntable in a pose nobody recorded (the AirSAS bunny), so
its reconstruction is scored after a rigid alignment (rotation + translation, scale fixed,
no reflection) to the reference mesh: iterative closest point (``trimesh.registration.icp``)
from several starts, and the start whose result has the lowest symmetric Chamfer-L2 wins.
Scores are always after the rigid alignment; ``scale=True`` also lets ICP fit one uniform scale,
which measures how much larger or smaller the reconstruction reads than the reference (a
geometry check, never a score: scaling can only lower the Chamfer).

Starts: the two centroids brought together, then rotations about the vertical axis through
the predicted centroid at ``yaw_starts`` even steps (the object stands upright on the table, so
yaw is the unknown that ICP alone does not find; tilts it refines).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.evaluation.metrics import chamfer


@dataclasses.dataclass(frozen=True)
class Alignment:
    """The best rigid transform found and the scores after it.

    Attributes:
        matrix: (4, 4) homogeneous transform sending predicted points onto the reference.
        points: (P, 3) the predicted points after ``matrix``.
        chamfer_l2: symmetric Chamfer-L2 after alignment, m² (metrics.chamfer).
        chamfer_l1: m.
        start_yaw_deg: the start that won.
    """

    matrix: np.ndarray
    points: np.ndarray
    chamfer_l2: float
    chamfer_l1: float
    start_yaw_deg: float

    def move(self, points: np.ndarray) -> np.ndarray:
        """(P, 3) points of the prediction's frame, m, sent onto the reference by ``matrix``."""
        return transform(self.matrix, points)

    @property
    def scale(self) -> float:
        """The uniform scale in ``matrix`` (1 for a rigid alignment)."""
        return float(np.cbrt(np.linalg.det(self.matrix[:3, :3])))

    def pose(self) -> dict[str, float]:
        """``scale``; ``yaw_deg``, ``tilt_deg`` (the angle between the turned vertical and the
        vertical); ``shift_m`` (x, y, z): where the prediction's origin lands on the reference."""
        r = self.matrix[:3, :3] / self.scale
        return {"scale": self.scale, "yaw_deg": float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))),
                "tilt_deg": float(np.degrees(np.arccos(np.clip(r[2, 2], -1.0, 1.0)))),
                "shift_x_m": float(self.matrix[0, 3]), "shift_y_m": float(self.matrix[1, 3]),
                "shift_z_m": float(self.matrix[2, 3])}


def transform(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P, 3) ``points``, m, moved by the (4, 4) homogeneous ``matrix``."""
    p = np.asarray(points, np.float64)
    return p @ matrix[:3, :3].T + matrix[:3, 3]


def _yaw(deg: float, about: np.ndarray) -> np.ndarray:
    a = np.deg2rad(deg)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    shift = np.eye(4)
    shift[:3, 3] = -about
    back = np.eye(4)
    back[:3, 3] = about
    return back @ m @ shift


def align_rigid(points: np.ndarray, reference: np.ndarray, *, yaw_starts: int = 12, iterations: int = 60,
                max_points: int = 20_000, seed: int = 0, scale: bool = False) -> Alignment:
    """Align ``points`` rigidly (scale fixed) to the ``reference`` point set (module docstring).

    Args:
        points: (P, 3) predicted points, m.
        reference: (R, 3) reference surface sample, m (e.g. metrics.sample_surface of the mesh).
        yaw_starts: starts at even yaw steps about the vertical axis.
        iterations: ICP iterations per start.
        max_points: the ICP runs on at most this many predicted points (a fixed random subset);
            the scores use all of them.
        scale: also fit one uniform scale (:attr:`Alignment.scale`); each start is the rigid
            alignment's result, then refined with the scale free, so the scale never has to
            undo a wrong turn.
    """
    from trimesh.registration import icp

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if len(p) < 3 or len(ref) < 3:
        raise ShsasError(f"align: need at least 3 points on each side (got {len(p)} and {len(ref)})")
    if yaw_starts < 1:
        raise ShsasError("align: yaw_starts must be >= 1")
    rng = np.random.default_rng(seed)
    sub = p if len(p) <= max_points else p[rng.choice(len(p), max_points, replace=False)]
    centre = p.mean(0)
    to_ref = np.eye(4)
    to_ref[:3, 3] = ref.mean(0) - centre
    best: Alignment | None = None
    for k in range(yaw_starts):
        deg = 360.0 * k / yaw_starts
        init = to_ref @ _yaw(deg, centre)
        matrix, _, _ = icp(sub, ref, initial=init, threshold=1e-9, max_iterations=iterations,
                           reflection=False, translation=True, scale=False)
        if scale:
            matrix, _, _ = icp(sub, ref, initial=matrix, threshold=1e-9, max_iterations=iterations,
                               reflection=False, translation=True, scale=True)
        moved = transform(matrix, p)
        score = chamfer(moved, ref)
        if best is None or score["chamfer_l2"] < best.chamfer_l2:
            best = Alignment(matrix, moved, score["chamfer_l2"], score["chamfer_l1"], deg)
    assert best is not None
    return best


def aligned_scores(volume, vertices: np.ndarray, faces: np.ndarray, *, extract_config=None,
                   yaw_starts: int = 12, iterations: int = 60, scale: bool = False
                   ) -> tuple[dict[str, float], Alignment]:
    """Extract ``volume``'s point cloud (the project's rule, :mod:`shsas_core.evaluation.extract`), align it
    to the mesh's surface sample (:data:`shsas_core.evaluation.metrics.GT_SAMPLES` points) and score it.
    ``scale``: as :func:`align_rigid` (the scores are then after the scaled alignment).

    Returns:
        ({"tau", "points", "chamfer_l2_raw", "chamfer_l2", "chamfer_l1", its two halves
        (:func:`~shsas_core.evaluation.metrics.chamfer_l2_parts`), and the F-scores of
        :func:`~shsas_core.evaluation.metrics.point_fscores` after alignment}, the alignment).
    """
    from shsas_core.evaluation.extract import choose_threshold, point_cloud
    from shsas_core.evaluation.metrics import chamfer_l2_parts, point_fscores, sample_surface

    gt = sample_surface(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    tau = choose_threshold(volume, extract_config)
    pc = point_cloud(volume, tau)
    if len(pc) < 3:
        raise ShsasError(f"align: the volume gives {len(pc)} points at tau {tau:.3f}")
    best = align_rigid(pc.points, gt, yaw_starts=yaw_starts, iterations=iterations, scale=scale)
    return ({"tau": tau, "points": float(len(pc)), "chamfer_l2_raw": chamfer(pc.points, gt)["chamfer_l2"],
             "chamfer_l2": best.chamfer_l2, "chamfer_l1": best.chamfer_l1,
             **chamfer_l2_parts(best.points, gt), **point_fscores(best.points, gt)}, best)
