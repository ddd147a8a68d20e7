"""One reconstruction job, end to end (the flow of docs/architecture.md): the function the CLI and the worker call.

``run(spec, survey, out_dir)``:

1. read the survey (when given a path) and split off held-out pings (``spec.holdout_fraction``);
2. pulse deconvolution once (``spec.deconvolution``) → ``s_PD`` per ping, checkpointed;
3. every requested method reconstructs (:func:`shsas_core.methods.reconstruct`, the catalogue's
   module for it: ``backprojection``, ``reed``, ``shsas`` or an installed one) a volume on
   ``Grid.over(scene_box, spec.grid_count(scene_box))``. The backprojection image of the training
   pings is computed once per job, on first use (cached as ``checkpoints/backprojection_image.npy``),
   and handed to every method (the backprojection's volume, the neural methods' warm start);
4. :func:`~shsas_core.pipeline.finish.finish`, the same for every method: extraction (:mod:`shsas_core.evaluation.extract`: ``spec.surface`` points above ``spec.threshold`` or the
   rule's τ, normals facing the survey's transmitters, ``spec.mesher`` mesh); export to PLY/GLB/NPY;
5. metrics against the ground truth when the survey has one (protocol of :mod:`shsas_core.evaluation.metrics`);
6. checks for a failed result (:mod:`shsas_core.evaluation.diagnostics`: collapsed or box-filling volume, a
   neural fit whose data loss did not fall) → ``MethodReport.warnings``;
7. ``report.json`` + ``report.html``.

Idempotent and resumable: every artifact name is fixed (``{method}_volume.npy``,
``{method}_pointcloud.ply``, ``{method}_mesh.ply``, ``{method}_mesh.glb``, ``report.json``, ...),
written to a temporary file and renamed; what a re-run finds under ``out_dir/checkpoints`` (and
when that folder is cleared) is :mod:`shsas_core.pipeline.job_cache`'s: a finished method is skipped when
the job is run again in the same ``out_dir`` with the same spec and survey. ``should_stop()`` is checked between
steps and inside every long step; it raises :class:`~shsas_core.common.errors.Cancelled`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import (
    ProgressFn,
    StopFn,
    check_stop,
    never_stop,
    no_progress,
    sub_progress,
)
from shsas_core.data.survey import Survey
from shsas_core.data.volume import Grid
from shsas_core.evaluation.diagnostics import ResultWarning
from shsas_core.evaluation.metrics import GroundTruth
from shsas_core.methods import MethodContext, MethodResult, reconstruct
from shsas_core.outputs.export import read_volume_npy
from shsas_core.outputs.focus import add_focus
from shsas_core.outputs.report import MethodReport, Report, ReportFigures, write_report
from shsas_core.pipeline.finish import (
    MethodOutput,
    MethodOutputs,
    finish,
    result_warnings,
    ridge_cloud_size,
)
from shsas_core.pipeline.image_cache import ImageCache
from shsas_core.pipeline.job_cache import JobCache, MethodCache
from shsas_core.pipeline.load import load_input
from shsas_core.signal.sources import deconv_config, signals_for
from shsas_core.spec.catalogue import REGISTRY
from shsas_core.spec.job import ReconstructionSpec

__all__ = ["MethodOutput", "PipelineResult", "holdout_split", "load_input", "run"]

#: Relative cost of each stage, for the overall progress fraction (each method's from the catalogue).
_WEIGHTS = {"deconvolution": 0.05, **{m.name: m.cost for m in REGISTRY.values()}, "report": 0.05}


class PipelineResult(BaseModel):
    """What :func:`run` produced."""

    out_dir: str
    artifacts: list[str] = Field(description="file names in out_dir, sorted")
    metrics: dict[str, dict[str, float | None]] = Field(
        description="method -> metric -> value: pc_*/mesh_* geometry metrics when the survey has ground "
        "truth (None = undefined), plus threshold, points, faces, seconds")
    report_json: str
    report_html: str
    timings: dict[str, float] = Field(description="seconds per stage")
    device: str = Field(description="the torch device that ran the job: cpu or cuda:N (card)")
    warnings: dict[str, list[ResultWarning]] = Field(
        default_factory=dict, description="method -> signs that its result failed (empty list: none found)")


def holdout_split(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) ping indices, sorted; a seeded random ``fraction`` is held out."""
    k = math.floor(n * fraction)
    if k <= 0:
        return np.arange(n), np.zeros(0, dtype=np.int64)
    if n - k < 1:
        raise ShsasError(f"holdout_fraction: {fraction} leaves no training pings out of {n}")
    held = np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))
    return np.setdiff1d(np.arange(n), held), held


def run(
    spec: ReconstructionSpec,
    survey: Survey | str | os.PathLike,
    out_dir: str | os.PathLike,
    progress: ProgressFn = no_progress,
    should_stop: StopFn = never_stop,
    memory_budget: int | None = None,
) -> PipelineResult:
    """Run a reconstruction job and write its artifacts into ``out_dir`` (see module doc).

    Args:
        spec: what to run.
        survey: a loaded :class:`Survey` or a path to any format ``shsas convert`` reads.
        out_dir: output folder (created); re-running in the same folder resumes.
        progress: ``progress(fraction of the whole job, stage, metrics)``.
        should_stop: polled between and within steps, the loading of the samples included;
            True cancels (raises ``Cancelled``).
        memory_budget: bytes the job may use (:mod:`shsas_core.spec.memory`); checked from the
            survey's declared sizes before its samples are read. None: not checked.
    Returns:
        :class:`PipelineResult`.
    Raises:
        ShsasError: bad input (survey, spec, device), ``MemoryBudgetError`` over the budget;
        Cancelled: on request.
    """
    from shsas_core.common.device import describe_device, resolve_device

    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out = Path(out_dir)
    device = resolve_device(spec.device)
    t = time.perf_counter()
    survey = load_input(survey, spec, memory_budget, should_stop, progress)
    timings["load"] = time.perf_counter() - t
    out.mkdir(parents=True, exist_ok=True)  # only once the input is known to be good
    cache = JobCache(out / "checkpoints", spec, survey)
    check_stop(should_stop)

    total = _WEIGHTS["deconvolution"] + sum(_WEIGHTS[m] for m in spec.methods) + _WEIGHTS["report"]
    bounds: dict[str, tuple[float, float]] = {}
    acc = 0.0
    for stage in ("deconvolution", *spec.methods, "report"):
        w = _WEIGHTS[stage] / total
        bounds[stage] = (acc, acc + w)
        acc += w

    # -- deconvolution (once, cached) -------------------------------------------------------
    t = time.perf_counter()
    s_pd = _deconvolve(survey, spec, device, cache, sub_progress(progress, *bounds["deconvolution"]), should_stop)
    timings["deconvolution"] = time.perf_counter() - t
    train_idx, held_idx = holdout_split(survey.num_pings, spec.holdout_fraction, spec.seed)
    grid = Grid.over(survey.meta.scene_box, spec.grid_count(survey.meta.scene_box))
    # the training pings' s_PD go to the image explicitly (not through survey.extras)
    image = ImageCache(survey.subset(train_idx), s_pd[train_idx], grid, device, cache, should_stop)
    gt = None
    if survey.has_ground_truth:
        t = time.perf_counter()
        gt = GroundTruth.from_survey(survey)
        timings["ground_truth"] = time.perf_counter() - t
    # what every method is given; each gets its own name, checkpoint folder and progress
    shared = MethodContext(name="", spec=spec, survey=survey, signals=s_pd, train_idx=train_idx,
                           held_idx=held_idx, grid=grid, image=image, device=device,
                           checkpoint_dir=cache.folder, progress=no_progress, should_stop=should_stop)

    figures = ReportFigures(gt_mesh=survey.ground_truth_mesh())
    reports: list[MethodReport] = []
    for method in spec.methods:
        check_stop(should_stop)
        prog = sub_progress(progress, *bounds[method])
        done = _run_method(dataclasses.replace(shared, name=method, progress=prog), cache.method(method), gt, out)
        reports.append(done.report)
        timings[method] = done.report.seconds
        figures.volumes[method] = done.volume
        figures.meshes[method] = done.mesh
        if done.fit is not None:
            figures.signal_fits[method] = done.fit

    # -- report -----------------------------------------------------------------------------
    check_stop(should_stop)
    progress(bounds["report"][0], "report", {})
    from shsas_core.formats.hdf5 import summarize

    t = time.perf_counter()
    artifacts = sorted({a for r in reports for a in r.artifacts.values()} | {"report.json", "report.html"})
    timings["total"] = time.perf_counter() - t_start
    summary = summarize(survey)
    add_focus(summary, figures, survey.subset(train_idx), s_pd[train_idx])
    report = Report(spec=spec, survey=summary, ground_truth=gt is not None, timings=timings,
                    device=describe_device(device), methods=reports, artifacts=artifacts)
    json_path, html_path = write_report(report, figures, out)
    timings["report"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    # the HTML was rendered before its own time was known; report.json gets the final figures
    report = report.model_copy(update={"timings": timings})
    _rewrite_json(report, out / "report.json")
    progress(1.0, "done", {"seconds": timings["total"]})
    metrics = report.metrics()
    for r in reports:  # also without ground truth: what was extracted and how long it took
        metrics[r.method].update({"threshold": r.threshold, "points": float(r.points),
                                  "faces": float(r.faces), "seconds": r.seconds})
    return PipelineResult(out_dir=str(out), artifacts=artifacts, metrics=metrics,
                          report_json=str(json_path), report_html=str(html_path), timings=timings,
                          device=report.device or "", warnings=report.warnings())


def _rewrite_json(report: Report, path: Path) -> None:
    from shsas_core.outputs.export import write_text

    write_text(report.model_dump_json(indent=2), path)


def _deconvolve(survey: Survey, spec: ReconstructionSpec, device: Any, cache: JobCache,
                progress: ProgressFn, should_stop: StopFn) -> np.ndarray:
    """(N, T) complex64 s_PD of every ping: the spec's deconvolution (``signals_for``'s
    ``deconvolve``), computed once per job and cached."""
    arr = cache.array("deconvolved", survey.shape)
    if arr is not None:
        progress(1.0, "deconvolution", {"cached": 1.0})
        return arr
    got = signals_for(survey, "deconvolve", deconv_config(spec), device=device, progress=progress,
                      should_stop=should_stop)
    s_pd = np.asarray(got.values, dtype=np.complex64)
    cache.save_array("deconvolved", s_pd)
    return s_pd


def _run_method(ctx: MethodContext, cache: MethodCache, gt: GroundTruth | None, out: Path) -> MethodOutput:
    """Reconstruct (:func:`shsas_core.methods.reconstruct`), then :func:`finish` method
    ``ctx.name``, or reload it when already done; checkpoints in ``cache``."""
    method, progress = ctx.name, ctx.progress
    where = MethodOutputs(method=method, spec=ctx.spec, gt=gt, out=out, cache=cache, sensors=ctx.survey.tx,
                          resolution=ctx.survey.meta.range_resolution,
                          progress=progress, should_stop=ctx.should_stop)
    names = where.names
    rep = cache.finished() if all((out / n).exists() for n in names.values()) else None
    if rep is not None:
        vol = read_volume_npy(out / names["volume"])
        fit = cache.load_fit()
        # the fit is not redone, so its verdict carries over; the volume's checks are cheap and
        # redone, so a run finished before they existed (or with other limits) is checked too
        kept = [w for w in rep.warnings if w.code == "loss_not_falling"]
        if cache.extracted_with(where.extract_key):
            import trimesh

            mesh_ = trimesh.load(out / names["mesh_ply"], process=False, force="mesh")
            checks = result_warnings(vol, rep.threshold, rep.metrics, ridge_cloud_size(ctx.spec, rep.points),
                                     where.resolution)
            rep = rep.model_copy(update={"warnings": checks + kept})
            progress(1.0, method, {"cached": 1.0})
            return MethodOutput(rep, vol, mesh_, fit)
        # reconstruction done, extraction settings (or code) changed: extract again, no refit
        progress(0.9, method, {"cached": 1.0})
        again = MethodResult(volume=vol, loss_curve=rep.loss_curve, signal_errors=rep.signal_errors,
                             warnings=kept)
        rep, mesh_ = finish(where, again, time.perf_counter() - rep.seconds)
        return MethodOutput(rep, vol, mesh_, fit)

    cache.folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = reconstruct(dataclasses.replace(ctx, checkpoint_dir=cache.folder))
    if result.signal_fit is not None:
        cache.save_fit(result.signal_fit)
    check_stop(ctx.should_stop)
    progress(0.9, method, {})
    rep, mesh_ = finish(where, result, t0)
    return MethodOutput(rep, result.volume, mesh_, result.signal_fit)
