"""TEMPORARY stand-in for the reconstruction pipeline (branch ``service`` only).

The real ``shsas_core.pipeline`` is being written on branch ``pipeline``; the coordinator
replaces this file with it at merge. This stand-in implements only the contract the service
depends on, so the service can be built and tested end to end:

    run(spec, survey, out_dir, progress, should_stop) -> PipelineResult

- ``PipelineResult.artifacts``: file names inside ``out_dir``; ``.metrics``: {method: {name: value}}.
- Files are written to ``<name>.tmp`` and renamed, so a reader never sees half a file.
- Per-method checkpoints under ``out_dir/checkpoints`` make a re-run in the same ``out_dir``
  resume where the last run stopped.
- ``should_stop()`` is checked between steps; ``Cancelled`` is raised when it says so.

It does no science: each method "trains" for a number of steps that scales with the spec
(sleeping briefly per step), then writes a sphere that fills the scene box.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
from pydantic import BaseModel, Field

from .progress import ProgressFn, StopFn, check_stop, never_stop, no_progress
from .spec import ReconstructionSpec
from .survey import Survey

STEP_SECONDS = 0.1  # per "iteration": about the real pipeline's CPU speed on a tiny survey, so tests catch jobs mid-run
CHECKPOINT_EVERY = 10


class PipelineResult(BaseModel):
    """What a pipeline run produced."""

    artifacts: list[str] = Field(default_factory=list, description="file names inside out_dir")
    metrics: dict[str, dict[str, float]] = Field(default_factory=dict)


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _steps(spec: ReconstructionSpec, method: str) -> int:
    return 4 if method == "backprojection" else spec.iters


def run(spec: ReconstructionSpec, survey: Survey | Path | str, out_dir: Path,
        progress: ProgressFn = no_progress, should_stop: StopFn = never_stop) -> PipelineResult:
    """TEMPORARY: see the module docstring."""
    import trimesh

    out_dir = Path(out_dir)
    ckpt_dir = out_dir / "checkpoints"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    if not isinstance(survey, Survey):
        from .importers import load_survey

        progress(0.0, "load", {})
        survey = load_survey(survey)
    box = survey.meta.scene_box
    total = sum(_steps(spec, m) for m in spec.methods)
    done_before = 0
    metrics: dict[str, dict[str, float]] = {}
    for method in spec.methods:
        n = _steps(spec, method)
        ckpt = ckpt_dir / f"{method}.json"
        start = json.loads(ckpt.read_text())["step"] if ckpt.exists() else 0
        t_start = time.perf_counter()
        for step in range(start, n):
            check_stop(should_stop)
            time.sleep(STEP_SECONDS)
            rate = (step - start + 1) / max(time.perf_counter() - t_start, 1e-9)
            progress((done_before + step + 1) / total, f"fit:{method}", {"it_per_s": rate})
            if (step + 1) % CHECKPOINT_EVERY == 0 or step + 1 == n:
                _atomic_write(ckpt, json.dumps({"step": step + 1}).encode())
        metrics[method] = {"steps": float(n), "resumed_from_step": float(start)}
        done_before += n
    check_stop(should_stop)
    progress(1.0, "export", {})
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    mesh.apply_scale(box.size)
    mesh.apply_translation(box.center)
    _atomic_write(out_dir / "shsas_mesh.glb", mesh.export(file_type="glb"))
    _atomic_write(out_dir / "shsas_mesh.ply", mesh.export(file_type="ply"))
    cloud = trimesh.PointCloud(mesh.vertices)
    _atomic_write(out_dir / "shsas_pointcloud.ply", cloud.export(file_type="ply"))
    g = spec.grid
    ax = np.linspace(-1, 1, g, dtype=np.float32)
    vol = 1.0 - np.sqrt(ax[:, None, None] ** 2 + ax[None, :, None] ** 2 + ax[None, None, :] ** 2)
    tmp = out_dir / "backprojection_volume.npy.tmp"
    with open(tmp, "wb") as fh:
        np.save(fh, vol.astype(np.complex64))
    os.replace(tmp, out_dir / "backprojection_volume.npy")
    report = {"temporary_pipeline": True, "spec": spec.model_dump(), "metrics": metrics}
    _atomic_write(out_dir / "report.json", json.dumps(report, indent=2).encode())
    _atomic_write(out_dir / "report.html",
                  f"<html><body><h1>shsas (temporary pipeline)</h1><pre>{json.dumps(metrics)}</pre></body></html>".encode())
    artifacts = ["shsas_mesh.glb", "shsas_mesh.ply", "shsas_pointcloud.ply", "backprojection_volume.npy",
                 "report.json", "report.html"]
    return PipelineResult(artifacts=artifacts, metrics=metrics)
