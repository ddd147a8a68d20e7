"""What the pipeline does with every method's volume, the same for all: extract, export, score,
check for a failed result, and mark the method done in the job cache."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.common.progress import ProgressFn, StopFn, check_stop
from shsas_core.data.volume import Volume
from shsas_core.evaluation.diagnostics import ResultWarning, mesh_warnings, volume_warnings
from shsas_core.evaluation.extract import PAPER_TAU, ExtractConfig, extract, point_cloud
from shsas_core.evaluation.metrics import (
    METRICS_VERSION,
    GroundTruth,
    finite_or_none,
    mesh_quality,
    score_reconstruction,
)
from shsas_core.methods import MethodResult
from shsas_core.outputs.artifacts import artifact_names
from shsas_core.outputs.export import (
    write_mesh_glb,
    write_mesh_ply,
    write_point_cloud_ply,
    write_volume_npy,
)
from shsas_core.outputs.report import MethodReport, SignalFit
from shsas_core.pipeline.job_cache import MethodCache
from shsas_core.spec.catalogue import REGISTRY
from shsas_core.spec.job import EXTRACTION_FIELDS, ReconstructionSpec

#: Bump when extraction changes: finished runs then re-extract from their saved volumes.
EXTRACT_VERSION = 12


@dataclasses.dataclass(frozen=True)
class MethodOutput:
    """One method's result: its report entry, volume, extracted mesh and (neural methods) the
    signal fit drawn in the report."""

    report: MethodReport
    volume: Volume
    mesh: Any
    fit: SignalFit | None = None


@dataclasses.dataclass(frozen=True)
class MethodOutputs:
    """Where and how one method of a job is finished.

    Attributes:
        method: its catalogue name. spec: the job's. gt: the ground truth when the survey has one.
        out: the job's output folder. cache: the method's checkpoints.
        sensors: (N, 3) transmitter positions, m, that the surface normals face.
        resolution: the survey's range resolution ``c / 2B``, m (the extraction's scales).
        progress: the method's progress (fraction of the method). should_stop: as everywhere.
    """

    method: str
    spec: ReconstructionSpec
    gt: GroundTruth | None
    out: Path
    cache: MethodCache
    sensors: np.ndarray
    resolution: float | None
    progress: ProgressFn
    should_stop: StopFn

    @property
    def names(self) -> dict[str, str]:
        return artifact_names(self.method)

    @property
    def extract_key(self) -> dict[str, Any]:
        """The settings the outputs are extracted with: other settings re-extract a finished method."""
        return {**{f: getattr(self.spec, f) for f in EXTRACTION_FIELDS}, "version": EXTRACT_VERSION,
                "metrics": METRICS_VERSION}


def finish(where: MethodOutputs, result: MethodResult, t0: float) -> tuple[MethodReport, Any]:
    """Extract, export, score, check for a failed result (the volume's checks plus the
    reconstruction's own ``result.warnings``), and mark the method done.

    Args:
        where: the method's place in the job. result: what it reconstructed.
        t0: ``time.perf_counter()`` when the method started (its report's seconds).
    Returns:
        (the method's report entry, its extracted mesh).
    """
    spec, vol, out, names = where.spec, result.volume, where.out, where.names
    ecfg = ExtractConfig(threshold=spec.threshold, surface=spec.surface, mesher=spec.mesher)
    tau, cloud, mesh_ = extract(vol, ecfg, where.sensors, where.resolution)
    write_volume_npy(vol, out / names["volume"])
    write_point_cloud_ply(cloud, out / names["pointcloud"])
    write_mesh_ply(mesh_, out / names["mesh_ply"])
    glb = write_mesh_glb(mesh_, out / names["mesh_glb"])
    if where.gt is not None:
        check_stop(where.should_stop)
        # the paper's fixed level beside the rule's, so a figure can be compared with Table 1
        fixed = point_cloud(vol, PAPER_TAU).points
        metrics: dict[str, float | None] = finite_or_none(score_reconstruction(cloud.points, mesh_, where.gt, fixed))
    else:  # the mesh's pieces need no ground truth: a foam shows without it
        metrics = {"mesh_pieces": mesh_quality(mesh_.vertices, mesh_.faces)["pieces"]}
    rep = MethodReport(method=where.method, sh_degree=REGISTRY[where.method].sh_degree(spec.sh_degree),
                       threshold=tau, points=len(cloud), faces=len(mesh_.faces),
                       seconds=time.perf_counter() - t0, metrics=metrics, signal_errors=result.signal_errors,
                       loss_curve=result.loss_curve, artifacts=names, origin_offset=glb["origin_offset"],
                       warnings=result_warnings(vol, tau, metrics, ridge_cloud_size(spec, len(cloud)), where.resolution)
                       + list(result.warnings))
    where.cache.mark_done(rep, where.extract_key)
    where.progress(1.0, where.method, {})
    return rep, mesh_


def ridge_cloud_size(spec: ReconstructionSpec, points: int) -> int | None:
    """A cloud's size when the spec extracts the ridge (whose surface test the checks judge), else None."""
    return points if spec.surface == "ridge" else None


def result_warnings(vol: Volume, tau: float, metrics: dict[str, float | None], ridge_points: int | None = None,
                    resolution: float | None = None) -> list[ResultWarning]:
    """The volume's checks (with its ridge cloud's size, when it has one, at the survey's range
    ``resolution``, m); the mesh's only when the volume passed (a collapsed or fog-filled volume's
    mesh says nothing more)."""
    return volume_warnings(vol, tau, ridge_points, resolution) or mesh_warnings(metrics)
