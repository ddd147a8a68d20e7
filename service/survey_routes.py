"""A job's survey as the console plots it: the summary ``shsas info`` prints, the sensor
positions, a few pings' envelopes and the ground-truth mesh when the survey has one.

Made once per job from the stored input (metadata and geometry only; the few pings are read
as rows where the format allows) and kept as ``jobs/<id>/survey/`` beside ``out/``.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response
from pydantic import BaseModel, Field

from shsas_core.errors import ShsasError
from shsas_core.export import write_json, write_mesh_glb
from shsas_core.io import summarize
from worker.runner import job_paths
from worker.store import Job

from .artifacts import file_response
from .lookup import caller_job
from .models import ErrorOut

#: At most this many sensor positions are sent (evenly spaced over the pings).
MAX_POSITIONS = 2000
#: Pings whose envelope is sent, and samples per envelope (max over blocks).
PINGS_SHOWN = 3
ENVELOPE_POINTS = 400
#: Surveys in formats that cannot be read by rows are loaded whole up to this size for the pings.
WHOLE_LOAD_MAX_BYTES = 64 * 1024**2
_LOCK = threading.Lock()

ERRORS = {401: {"model": ErrorOut}, 404: {"model": ErrorOut}}


class Ping(BaseModel):
    index: int
    t0_s: float = Field(description="time of the first sample after transmit")
    dt_s: float = Field(description="time between two envelope points")
    envelope: list[float] = Field(description="|sample| maxima over equal blocks of the ping")


class SurveyView(BaseModel):
    summary: dict[str, Any] = Field(description="what `shsas info --json` prints for the input")
    tx: list[list[float]] = Field(description="transmitter positions, m (evenly thinned)")
    rx: list[list[float]] = Field(description="receiver positions, m (evenly thinned)")
    pings: list[Ping] = Field(description="a few pings, evenly spaced (empty for a large non-HDF5 input)")
    ground_truth_url: str | None = Field(description="GLB of the ground-truth mesh, when the survey has one")
    ground_truth_origin_offset: list[float] | None = None


router = APIRouter(tags=["surveys"])


def _evenly(n: int, k: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(np.int64)) if n else np.zeros(0, int)


def _envelope(row: np.ndarray, fs: float) -> tuple[list[float], float]:
    mag = np.abs(np.asarray(row)).astype(np.float64)
    block = max(1, int(np.ceil(mag.size / ENVELOPE_POINTS)))
    pad = (-mag.size) % block
    mag = np.pad(mag, (0, pad)).reshape(-1, block).max(1)
    return mag.round(6).tolist(), block / fs


def _ping_rows(path: Path, survey, idx: np.ndarray, size: int) -> np.ndarray | None:
    import h5py

    from shsas_core.importers import load_survey

    if path.suffix == ".h5":
        with h5py.File(path, "r") as f:
            if "pings/samples" in f:
                return f["pings/samples"][np.sort(idx)]
    if size <= WHOLE_LOAD_MAX_BYTES:
        return load_survey(path).samples[idx]
    return None


def _build(job: Job, in_path: Path, folder: Path) -> dict:
    from shsas_core.importers import load_survey

    try:
        survey = load_survey(in_path, load_samples=False)
    except ShsasError as exc:  # the upload was validated; this is a changed or unreadable file
        raise HTTPException(409, f"the stored survey of reconstruction {job.id} could not be read: {exc}") from None
    keep = _evenly(survey.num_pings, MAX_POSITIONS)
    idx = _evenly(survey.num_pings, PINGS_SHOWN)
    rows = _ping_rows(in_path, survey, idx, in_path.stat().st_size)
    pings = []
    if rows is not None:
        for i, row in zip(idx, rows, strict=True):
            env, dt = _envelope(row, survey.meta.fs)
            pings.append({"index": int(i), "t0_s": float(survey.t0[i]), "dt_s": dt, "envelope": env})
    view: dict[str, Any] = {
        "summary": summarize(survey), "tx": survey.tx[keep].round(5).tolist(),
        "rx": survey.rx[keep].round(5).tolist(), "pings": pings,
        "ground_truth_url": None, "ground_truth_origin_offset": None}
    folder.mkdir(parents=True, exist_ok=True)
    if survey.has_ground_truth:
        import trimesh

        gt = trimesh.Trimesh(survey.gt_vertices, survey.gt_faces, process=False)
        view["ground_truth_origin_offset"] = write_mesh_glb(gt, folder / "ground_truth.glb")["origin_offset"]
        view["ground_truth_url"] = f"/reconstructions/{job.id}/survey/ground_truth.glb"
    write_json(view, folder / "survey.json")  # last: its presence means the folder is complete
    return view


def _view(request: Request, job_id: str) -> tuple[dict, Path]:
    job = caller_job(request, job_id)
    in_dir, _ = job_paths(request.app.state.settings, job.id)
    in_path = in_dir / job.input_name
    if not in_path.is_file():
        raise HTTPException(404, f"reconstruction {job.id} has no stored survey")
    folder = in_dir.parent / "survey"
    kept = folder / "survey.json"
    if kept.is_file():
        return json.loads(kept.read_text()), folder
    with _LOCK:
        if kept.is_file():
            return json.loads(kept.read_text()), folder
        return _build(job, in_path, folder), folder


@router.get("/reconstructions/{job_id}/survey", response_model=SurveyView, responses={
    **ERRORS, 409: {"model": ErrorOut}})
def survey_view(job_id: str, request: Request) -> SurveyView:
    """The job's survey: the `shsas info` summary, sensor positions, a few pings, ground truth."""
    return SurveyView.model_validate(_view(request, job_id)[0])


@router.get("/reconstructions/{job_id}/survey/ground_truth.glb", responses={
    **ERRORS, 200: {"content": {"model/gltf-binary": {}}}, 206: {"description": "partial content"},
    304: {"description": "not modified"}, 416: {"description": "range not satisfiable"}})
def ground_truth(job_id: str, request: Request) -> Response:
    """The survey's ground-truth mesh as GLB (404 when the survey has none)."""
    view, folder = _view(request, job_id)
    if view["ground_truth_url"] is None:
        raise HTTPException(404, f"the survey of reconstruction {job_id} has no ground truth")
    return file_response(folder / "ground_truth.glb", request.headers, "ground_truth.glb")
