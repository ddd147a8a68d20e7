"""Re-extraction at another iso level from a finished job's saved volume (no retraining).

``GET /reconstructions/{id}/extract?method=&threshold=`` answers the point and face counts and
the scores at that level (``service.iso_scores``);
``.../extract/mesh.glb`` and ``.../extract/pointcloud.ply`` with the same query answer the files.
The level is rounded to :data:`TAU_STEP`, and each (method, level) is extracted once and kept
under the job's folder (``jobs/<id>/extracts/``), beside ``out/``, so deleting the job removes it.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response
from pydantic import BaseModel, Field

from jobs.layout import extracts_dir, job_paths, survey_view_dir
from jobs.settings import Settings
from jobs.store import Job
from shsas_core.evaluation.extract import ExtractConfig, extract
from shsas_core.outputs.artifacts import artifact_names
from shsas_core.outputs.export import (
    read_volume_npy,
    write_json,
    write_mesh_glb,
    write_point_cloud_ply,
)
from shsas_core.spec.job import Method

from ..deps import SucceededJobDep
from ..file_responses import file_response, safe_artifact_path
from ..iso_scores import scores
from ..models import ErrorOut
from ..survey_view import VIEW_NAME

#: Levels are rounded to this step: a slider cannot make unbounded distinct extractions.
TAU_STEP = 0.001
#: One extraction at a time per API process: a 512³ volume is ~1 GB in memory.
_LOCK = threading.Lock()

ERRORS = {401: {"model": ErrorOut}, 404: {"model": ErrorOut}, 409: {"model": ErrorOut}}
MethodQ = Annotated[Method, Query(description="one of the job's methods")]
LevelQ = Annotated[float, Query(gt=0, lt=1, description="normalised iso level τ in (0, 1); rounded to 0.001")]


class Extraction(BaseModel):
    """One method's geometry re-extracted at a given level."""

    method: str
    threshold: float = Field(description="the level used: the requested one rounded to 0.001")
    points: int = Field(description="points of the surface cloud at that level (the job's own extraction)")
    faces: int = Field(description="triangles of the mesh (the job's own mesher)")
    origin_offset: list[float] = Field(description="survey coordinates = GLB coordinates + this")
    seconds: float = Field(description="time the extraction took (0 when it was kept from before)")
    metrics: dict[str, float | None] | None = Field(
        None, description="the report's metrics at this level (pc_*, mesh_*) when the survey has ground "
        "truth; else only mesh_pieces")
    mesh_url: str
    pointcloud_url: str


router = APIRouter(tags=["results"])


def _level(threshold: float) -> float:
    steps = min(max(round(threshold / TAU_STEP), 1), round(1 / TAU_STEP) - 1)
    return round(steps * TAU_STEP, 6)


def _config(job: Job, tau: float) -> ExtractConfig:
    """The job's own extraction (its spec's surface and mesher; defaults for older jobs) at ``tau``."""
    spec = job.spec
    default = ExtractConfig()
    return ExtractConfig(threshold=tau, surface=spec.get("surface", default.surface),
                         mesher=spec.get("mesher", default.mesher))


def _sensors(view_dir: Path) -> np.ndarray | None:
    """(M, 3) transmitter positions, m, that the surface normals face: the thinned ones of the
    survey view written at validation (the API never opens the survey itself); None without one."""
    view = view_dir / VIEW_NAME
    if not view.is_file():
        return None
    tx = np.asarray(json.loads(view.read_text()).get("tx") or [], dtype=np.float64)
    return tx.reshape(-1, 3) if tx.size else None


def _resolution(view_dir: Path) -> float | None:
    """The survey's range resolution ``c / 2B``, m, from the survey view's summary; None without one."""
    view = view_dir / VIEW_NAME
    if not view.is_file():
        return None
    value = (json.loads(view.read_text()).get("summary") or {}).get("range_resolution_m")
    return float(value) if isinstance(value, int | float) and value > 0 else None


def _extract(job: Job, settings: Settings, method: str, tau: float) -> tuple[dict, Path, bool]:
    """The kept extraction of ``method`` at ``tau``, made now if absent: (info, folder, made now)."""
    names = artifact_names(method)
    _, out_dir = job_paths(settings, job.id)
    vol_path = safe_artifact_path(out_dir, names["volume"], job.artifacts)
    if vol_path is None or safe_artifact_path(out_dir, names["grid"], job.artifacts) is None:
        raise HTTPException(404, f"reconstruction {job.id} has no saved volume for method {method!r} "
                                 f"(its methods: {', '.join(job.spec.get('methods', []))})")
    folder = extracts_dir(settings, job.id) / f"{method}-{round(tau / TAU_STEP):04d}"
    info_path = folder / "extraction.json"
    if info_path.is_file():
        return json.loads(info_path.read_text()), folder, False
    with _LOCK:
        if info_path.is_file():  # another request made it while this one waited
            return json.loads(info_path.read_text()), folder, False
        t0 = time.perf_counter()
        vol = read_volume_npy(vol_path)
        view_dir = survey_view_dir(settings, job.id)
        _, cloud, surface = extract(vol, _config(job, tau), _sensors(view_dir), _resolution(view_dir))
        folder.mkdir(parents=True, exist_ok=True)
        write_point_cloud_ply(cloud, folder / "pointcloud.ply")
        glb = write_mesh_glb(surface, folder / "mesh.glb")
        info = {"method": method, "threshold": tau, "points": len(cloud), "faces": len(surface.faces),
                "origin_offset": glb["origin_offset"], "seconds": time.perf_counter() - t0,
                "metrics": scores(job.id, out_dir, cloud.points, surface)}
        write_json(info, info_path)  # last: its presence means the files are complete
    return info, folder, True


def _run(request: Request, job: Job, method: str, threshold: float) -> tuple[dict, Path, str, bool]:
    if method not in job.spec.get("methods", []):
        raise HTTPException(404, f"method {method!r} was not run in reconstruction {job.id} "
                                 f"(its methods: {', '.join(job.spec.get('methods', []))})")
    tau = _level(threshold)
    info, folder, made = _extract(job, request.app.state.settings, method, tau)
    return info, folder, f"/reconstructions/{job.id}/extract/{{}}?method={method}&threshold={tau:g}", made


@router.get("/reconstructions/{job_id}/extract", response_model=Extraction, responses=ERRORS)
def extract_summary(job: SucceededJobDep, request: Request, method: MethodQ, threshold: LevelQ) -> Extraction:
    """Re-extract one method's point cloud and mesh at another iso level from the job's saved
    volume (seconds; no retraining). 409 unless the job succeeded."""
    info, _, url, made = _run(request, job, method, threshold)
    return Extraction(**{**info, "seconds": info["seconds"] if made else 0.0},
                      mesh_url=url.format("mesh.glb"), pointcloud_url=url.format("pointcloud.ply"))


FILE_RESPONSES = {**ERRORS, 200: {"content": {"model/gltf-binary": {}, "application/octet-stream": {}}},
                  206: {"description": "partial content"}, 304: {"description": "not modified"},
                  416: {"description": "range not satisfiable"}}


@router.get("/reconstructions/{job_id}/extract/{name}", responses=FILE_RESPONSES)
def extract_file(job: SucceededJobDep, name: Literal["mesh.glb", "pointcloud.ply"], request: Request,
                 method: MethodQ, threshold: LevelQ) -> Response:
    """The re-extracted mesh (GLB) or point cloud (PLY, scalar ``scalar_magnitude``) at a level."""
    info, folder, _, _ = _run(request, job, method, threshold)
    stem, ext = name.split(".")
    return file_response(folder / name, request.headers, f"{method}_{stem}_{info['threshold']:g}.{ext}")
