"""The survey view the console plots, made once by the validation child at upload.

``GET /reconstructions/{id}/survey`` serves what this module wrote, so the API process never
opens an uploaded survey (docs/service.md): the ``shsas info`` summary, the sensor positions
thinned to :data:`MAX_POSITIONS`, :data:`PINGS_SHOWN` pings' envelopes of
:data:`ENVELOPE_POINTS` points, and the ground-truth mesh as GLB (its size bounded by the
upload cap on ground-truth meshes). The JSON is bounded: meta attributes over
:data:`MAX_ATTRS_BYTES` are left out of it.

Imported by the validation child: keep it free of the web framework.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

#: The view's files (in the job's view folder, :func:`jobs.layout.survey_view_dir`).
VIEW_NAME = "survey.json"
GROUND_TRUTH_NAME = "ground_truth.glb"
#: At most this many sensor positions are kept (evenly spaced over the pings).
MAX_POSITIONS = 2000
#: Pings whose envelope is kept, and points per envelope (max over blocks).
PINGS_SHOWN = 3
ENVELOPE_POINTS = 400
#: The summary's ``attrs`` (the survey's free-form metadata) is replaced by a note past this.
MAX_ATTRS_BYTES = 64 * 1024


def evenly(n: int, k: int) -> np.ndarray:
    """Up to ``k`` indices evenly spaced over ``range(n)``, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(np.int64)) if n else np.zeros(0, int)


def ping_indices(num_pings: int) -> np.ndarray:
    return evenly(num_pings, PINGS_SHOWN)


def envelope(row: np.ndarray, fs: float) -> tuple[list[float], float]:
    """(maxima of |row| over at most ENVELOPE_POINTS equal blocks, seconds per block)."""
    mag = np.abs(np.asarray(row)).astype(np.float64)
    block = max(1, int(np.ceil(mag.size / ENVELOPE_POINTS)))
    pad = (-mag.size) % block
    mag = np.pad(mag, (0, pad)).reshape(-1, block).max(1)
    return mag.round(6).tolist(), block / fs


def bounded_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """``summary`` with its ``attrs`` replaced by a note when they are over MAX_ATTRS_BYTES."""
    size = len(json.dumps(summary.get("attrs", {}), default=str))
    if size <= MAX_ATTRS_BYTES:
        return summary
    return {**summary, "attrs": {"omitted": f"{size} bytes of attributes, over the view's "
                                            f"limit of {MAX_ATTRS_BYTES} (shsas info shows them)"}}


def write_view(survey, summary: dict[str, Any], rows: np.ndarray | None, folder: Path) -> dict[str, Any]:
    """Write ``folder/survey.json`` (and ``ground_truth.glb``); return the view.

    Args:
        survey: the :class:`~shsas_core.data.survey.Survey` (header and geometry; samples not needed).
        rows: the samples of the pings :func:`ping_indices` names, (k, T), or None.
    """
    from shsas_core.outputs.export import write_json

    keep = evenly(survey.num_pings, MAX_POSITIONS)
    idx = ping_indices(survey.num_pings)
    pings = []
    if rows is not None:
        for i, row in zip(idx, rows, strict=True):
            env, dt = envelope(row, survey.meta.fs)
            pings.append({"index": int(i), "t0_s": float(survey.t0[i]), "dt_s": dt, "envelope": env})
    view: dict[str, Any] = {
        "summary": bounded_summary(summary), "tx": survey.tx[keep].round(5).tolist(),
        "rx": survey.rx[keep].round(5).tolist(), "pings": pings, "ground_truth_origin_offset": None}
    folder.mkdir(parents=True, exist_ok=True)
    if survey.has_ground_truth:
        import trimesh

        from shsas_core.outputs.export import write_mesh_glb

        gt = trimesh.Trimesh(survey.gt_vertices, survey.gt_faces, process=False)
        view["ground_truth_origin_offset"] = write_mesh_glb(gt, folder / GROUND_TRUTH_NAME)["origin_offset"]
    write_json(view, folder / VIEW_NAME)  # last: its presence means the folder is complete
    return view
