"""The scores of a re-extraction (``service.routes.extracts``) against the survey's ground truth, when it has
one: the same metrics the job's report gives (``shsas_core.evaluation.metrics.score_reconstruction``:
``pc_*`` for the cloud, ``mesh_*`` for the mesh), so the console's metrics table follows the
iso level. Without ground truth only the mesh's pieces (they need none).

The ground truth comes from the survey view written at validation (``ground_truth.glb`` and
the scene box of its summary): the API never opens the survey itself.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from jobs.layout import SURVEY_VIEW

from .quotas import box_of
from .survey_view import GROUND_TRUTH_NAME, VIEW_NAME

#: Ground truths kept in memory (one per job; building one samples and voxelises the mesh).
KEEP = 4
_kept: OrderedDict[str, Any] = OrderedDict()
_lock = threading.Lock()


def _ground_truth(job_id: str, out_dir: Path) -> Any | None:
    """The job's :class:`~shsas_core.evaluation.metrics.GroundTruth`, or None when its survey has none."""
    with _lock:
        if job_id in _kept:
            _kept.move_to_end(job_id)
            return _kept[job_id]
    folder = out_dir.parent / SURVEY_VIEW
    view_path, glb = folder / VIEW_NAME, folder / GROUND_TRUTH_NAME
    if not view_path.is_file() or not glb.is_file():
        return None
    view = json.loads(view_path.read_text())
    box = box_of(view.get("summary") or {})
    offset = view.get("ground_truth_origin_offset")
    if box is None or offset is None:
        return None
    import trimesh

    from shsas_core.evaluation.metrics import GroundTruth

    mesh = trimesh.load(glb, file_type="glb", force="mesh", process=False)
    vertices = np.asarray(mesh.vertices, dtype=np.float64) + np.asarray(offset, dtype=np.float64)
    gt = GroundTruth(vertices, np.asarray(mesh.faces), box)
    with _lock:
        _kept[job_id] = gt
        while len(_kept) > KEEP:
            _kept.popitem(last=False)
    return gt


def scores(job_id: str, out_dir: Path, points: np.ndarray, surface: Any) -> dict[str, float | None]:
    """The metrics of a re-extracted cloud ``points`` (N, 3) m and mesh ``surface`` (trimesh)."""
    from shsas_core.evaluation.metrics import finite_or_none, mesh_quality, score_reconstruction

    gt = _ground_truth(job_id, out_dir)
    if gt is None:
        return {"mesh_pieces": float(mesh_quality(surface.vertices, surface.faces)["pieces"])}
    return finite_or_none(score_reconstruction(points, surface, gt))
