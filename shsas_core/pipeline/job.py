"""One reconstruction job, end to end (the flow of docs/architecture.md): the function the CLI and the worker call.

``run(spec, survey, out_dir)``:

1. read the survey (when given a path) and split off held-out pings (``spec.holdout_fraction``);
2. pulse deconvolution once (``spec.deconvolution``) → ``s_PD`` per ping, checkpointed;
3. every requested method: ``backprojection`` (complex image), ``reed`` (neural field, SH degree 0)
   and ``shsas`` (SH degree ``spec.sh_degree``) → a volume on ``Grid.over(scene_box,
   spec.grid_count(scene_box))``. The backprojection image is computed once per job (cached as
   ``checkpoints/backprojection_image.npy``): it is the backprojection method's volume and, with
   ``spec.init == "backprojection"``, the start of the neural methods (:mod:`shsas_core.neural.warmstart`);
4. extraction (:mod:`shsas_core.evaluation.extract`: ``spec.surface`` points above ``spec.threshold`` or the
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
from typing import TYPE_CHECKING, Any

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
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.diagnostics import (
    ResultWarning,
    fit_warnings,
    mesh_warnings,
    volume_warnings,
)
from shsas_core.evaluation.extract import PAPER_TAU, ExtractConfig, extract, point_cloud
from shsas_core.evaluation.metrics import (
    METRICS_VERSION,
    GroundTruth,
    finite_or_none,
    mesh_quality,
    score_reconstruction,
)
from shsas_core.neural.fields.volume import field_volume
from shsas_core.outputs.artifacts import artifact_names
from shsas_core.outputs.export import (
    read_volume_npy,
    write_mesh_glb,
    write_mesh_ply,
    write_point_cloud_ply,
    write_volume_npy,
)
from shsas_core.outputs.report import MethodReport, Report, ReportFigures, SignalFit, write_report
from shsas_core.pipeline.job_cache import JobCache, MethodCache
from shsas_core.spec.catalogue import REGISTRY
from shsas_core.spec.job import EXTRACTION_FIELDS, ReconstructionSpec

if TYPE_CHECKING:  # train imports torch: loaded only when a neural method runs
    from shsas_core.neural.train import FitResult

#: Relative cost of each stage, for the overall progress fraction (each method's from the registry).
_WEIGHTS = {"deconvolution": 0.05, **{m.name: m.cost for m in REGISTRY.values()}, "report": 0.05}
#: Bump when extraction changes: finished runs then re-extract from their saved volumes.
EXTRACT_VERSION = 4
#: Pings whose signal fit is drawn in the report.
_FIT_PINGS = 3
#: At most this many held-out pings (evenly spaced) are rendered for the novel-view errors:
#: rendering a whole ping costs about as much as a few hundred training iterations on a CPU.
_MAX_NOVEL_PINGS = 32
#: The pings rendered for the signal figure and the novel-view errors use the job's ``num_rays``
#: up to this many rays per ping: whole pings cost far more than a training batch, and 512 rays
#: already give errors stable to a few per cent.
MAX_SCORING_RAYS = 512


def _evenly(idx: np.ndarray, k: int) -> np.ndarray:
    """At most ``k`` entries of ``idx``, evenly spaced."""
    if len(idx) <= k:
        return np.asarray(idx)
    return np.asarray(idx)[np.linspace(0, len(idx) - 1, k).round().astype(np.int64)]


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


def sh_degree_of(method: str, spec: ReconstructionSpec) -> int | None:
    """SH degree of ``method``'s field under ``spec`` (None: backprojection, no field)."""
    return REGISTRY[method].sh_degree(spec.sh_degree)


def holdout_split(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) ping indices, sorted; a seeded random ``fraction`` is held out."""
    k = math.floor(n * fraction)
    if k <= 0:
        return np.arange(n), np.zeros(0, dtype=np.int64)
    if n - k < 1:
        raise ShsasError(f"holdout_fraction: {fraction} leaves no training pings out of {n}")
    held = np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))
    return np.setdiff1d(np.arange(n), held), held


def load_input(survey: Survey | str | os.PathLike, spec: ReconstructionSpec | None = None,
               memory_budget: int | None = None, should_stop: StopFn = never_stop,
               progress: ProgressFn = no_progress) -> Survey:
    """The survey with its samples, after checking the job fits ``memory_budget`` bytes.

    The "load" stage is reported only once the header is read and checked, so a bad file ends
    with its one-line error and no progress output.

    The check uses the sizes a file declares, before its samples are read; canonical files are
    then read block by block, polling ``should_stop``. Their ``/extras`` are not read: no stage
    of the pipeline uses them.
    """
    from shsas_core.spec.memory import check_job_memory

    if isinstance(survey, Survey):
        if survey.samples is None:
            raise ShsasError("survey: samples were not loaded (read it with load_samples=True)")
        if memory_budget is not None and spec is not None:
            check_job_memory(survey, spec, memory_budget)
        return survey
    from shsas_core.formats import detect_format, load_survey
    from shsas_core.formats.hdf5 import read_survey

    fmt = detect_format(survey)
    if fmt == "shsas":
        header = read_survey(survey, load_samples=False, load_extras=False)
    else:
        header = load_survey(survey, fmt, load_samples=False)
    if memory_budget is not None and spec is not None:
        check_job_memory(header, spec, memory_budget)
    progress(0.0, "load", {})  # the stage starts here, so a cancel during it is reported as such
    check_stop(should_stop)
    if fmt == "shsas":
        return read_survey(survey, load_extras=False, should_stop=should_stop)
    return load_survey(survey, fmt)


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
    image = _ImageCache(survey.subset(train_idx), s_pd[train_idx], grid, device, cache, should_stop)
    gt = None
    if survey.has_ground_truth:
        t = time.perf_counter()
        gt = GroundTruth.from_survey(survey)
        timings["ground_truth"] = time.perf_counter() - t
    job = _Job(spec=spec, survey=survey, s_pd=s_pd, train_idx=train_idx, held_idx=held_idx, grid=grid,
               image=image, gt=gt, device=device, out=out, should_stop=should_stop)

    figures = ReportFigures(gt_mesh=survey.ground_truth_mesh())
    reports: list[MethodReport] = []
    for method in spec.methods:
        check_stop(should_stop)
        prog = sub_progress(progress, *bounds[method])
        done = _run_method(method, job, cache.method(method), prog)
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
    _add_focus(summary, figures, survey.subset(train_idx), s_pd[train_idx])
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


def _add_focus(summary: dict[str, Any], figures: ReportFigures, survey: Survey, signals: np.ndarray) -> None:
    """A single-height (or elevation-poor) survey's report shows its plane of best focus.

    :func:`~shsas_core.imaging.planar.find_focus` searches every height the geometry allows, not only
    the scene box. Its record goes into the summary's elevation entry (``focus``); a focus
    also gives ``focus_height_m``, the backprojection of that plane (``figures.plane``) and
    the outline measured in it with the range resolution beside it; none found gives a
    warning in the summary's ``warnings`` instead.

    Args:
        summary: :func:`~shsas_core.formats.hdf5.summarize` of the survey, updated in place.
        figures: the report's figures, updated in place.
        survey: the training pings. signals: (N, T) their deconvolved signals.
    """
    elev = summary.get("elevation") or {}
    if elev.get("kind", "3d") == "3d":
        return
    from shsas_core.imaging.planar import find_focus, outline, plane_image

    focus = find_focus(survey, signals)
    elev["focus"] = focus.summary()
    figures.focus = focus
    if not focus.found:
        summary.setdefault("warnings", []).append(focus.reason)
        return
    elev["focus_height_m"] = focus.z
    plane = plane_image(survey, signals, focus.z)
    figures.plane = plane
    try:
        elev["outline"] = {**outline(plane.values, plane.grid).model_dump(),
                           "range_resolution_m": focus.range_resolution_m}
    except ShsasError:  # nothing outlined (an empty plane): the report shows the image alone
        pass


def _rewrite_json(report: Report, path: Path) -> None:
    from shsas_core.outputs.export import write_text

    write_text(report.model_dump_json(indent=2), path)


def _deconvolve(survey: Survey, spec: ReconstructionSpec, device: Any, cache: JobCache,
                progress: ProgressFn, should_stop: StopFn) -> np.ndarray:
    from shsas_core.signal.deconv import deconvolve

    arr = cache.array("deconvolved", survey.shape)
    if arr is not None:
        progress(1.0, "deconvolution", {"cached": 1.0})
        return arr
    s_pd = np.asarray(deconvolve(survey, deconv_config(spec), device=device, progress=progress,
                                 should_stop=should_stop),
                      dtype=np.complex64)
    cache.save_array("deconvolved", s_pd)
    return s_pd


class _ImageCache:
    """The job's backprojection image of the training pings on the job's grid, computed on first
    use and kept in the job cache (so a resumed job does not recompute it)."""

    def __init__(self, train: Survey, signals: np.ndarray, grid: Grid, device: Any, cache: JobCache,
                 should_stop: StopFn):
        self._train, self._signals, self._grid = train, signals, grid
        self._device, self._should_stop = device, should_stop
        self._cache = cache
        self._volume: Volume | None = None

    def __call__(self, progress: ProgressFn) -> Volume:
        if self._volume is None:
            arr = self._cache.array("backprojection_image", self._grid.shape)
            if arr is not None:
                self._volume = Volume(self._grid, arr, name="backprojection")
        if self._volume is None:
            from shsas_core.imaging.backprojection import backproject_survey

            vol = backproject_survey(self._train, self._grid, self._signals,
                                     device=self._device, progress=progress, should_stop=self._should_stop)
            self._cache.save_array("backprojection_image", vol.values)
            self._volume = vol
        progress(1.0, "backprojection", {})
        return self._volume


def deconv_config(spec: ReconstructionSpec) -> Any:
    """The deconvolution the job runs (its kernel is also the neural forward model's PSF)."""
    from shsas_core.signal.deconv import DeconvConfig

    cfg = DeconvConfig(method=spec.deconvolution)
    if spec.deconvolution == "neural":
        cfg = cfg.model_copy(update={"neural": cfg.neural.model_copy(update={"seed": spec.seed})})
    return cfg


@dataclasses.dataclass(frozen=True)
class _Job:
    """What every method of one job shares, built once by :func:`run`.

    Attributes:
        s_pd: (N, T) complex64 deconvolved signals of all pings; train_idx / held_idx: ping
            indices fitted / held out; image: the backprojection image of the training pings;
            gt: the ground truth when the survey has one; out: the job's output folder.
    """

    spec: ReconstructionSpec
    survey: Survey
    s_pd: np.ndarray
    train_idx: np.ndarray
    held_idx: np.ndarray
    grid: Grid
    image: _ImageCache
    gt: GroundTruth | None
    device: Any
    out: Path
    should_stop: StopFn


@dataclasses.dataclass(frozen=True)
class MethodOutput:
    """One method's result: its report entry, volume, extracted mesh and (neural methods) the
    signal fit drawn in the report."""

    report: MethodReport
    volume: Volume
    mesh: Any
    fit: SignalFit | None = None


def _run_method(method: str, job: _Job, cache: MethodCache, progress: ProgressFn) -> MethodOutput:
    """Reconstruct, extract, export and score one method (or reload it when already done);
    checkpoints in ``cache``."""
    spec, survey, s_pd, out, should_stop = job.spec, job.survey, job.s_pd, job.out, job.should_stop
    names = artifact_names(method)
    extract_key = {**{f: getattr(spec, f) for f in EXTRACTION_FIELDS}, "version": EXTRACT_VERSION,
                   "metrics": METRICS_VERSION}
    rep = cache.finished() if all((out / n).exists() for n in names.values()) else None
    if rep is not None:
        vol = read_volume_npy(out / names["volume"])
        fit = cache.load_fit()
        # the fit is not redone, so its verdict carries over; the volume's checks are cheap and
        # redone, so a run finished before they existed (or with other limits) is checked too
        kept = [w for w in rep.warnings if w.code == "loss_not_falling"]
        if cache.extracted_with(extract_key):
            import trimesh

            mesh_ = trimesh.load(out / names["mesh_ply"], process=False, force="mesh")
            rep = rep.model_copy(update={"warnings": _result_warnings(vol, rep.threshold, rep.metrics) + kept})
            progress(1.0, method, {"cached": 1.0})
            return MethodOutput(rep, vol, mesh_, fit)
        # reconstruction done, extraction settings (or code) changed: extract again, no refit
        progress(0.9, method, {"cached": 1.0})
        t0 = time.perf_counter() - rep.seconds
        rep, mesh_ = _finish(method, spec, vol, job.gt, out, cache, names, extract_key, t0, rep.loss_curve,
                             rep.signal_errors, progress, should_stop, kept, sensors=survey.tx)
        return MethodOutput(rep, vol, mesh_, fit)

    cache.folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    loss_curve: list[tuple[int, float]] = []
    signal_errs: dict[str, float] = {}
    fit_fig: SignalFit | None = None
    fit_warns: list[ResultWarning] = []
    if not REGISTRY[method].neural:  # the backprojection image
        vol = job.image(sub_progress(progress, 0.0, 0.8))
    else:
        field, result = _fit_neural(method, job, cache.folder, sub_progress(progress, 0.0, 0.8))
        loss_curve = _loss_curve(result.loss_history)
        fit_warns = fit_warnings(result.data_loss_history)
        check_stop(should_stop)
        progress(0.8, method, {"stage": 1.0})
        vol = field_volume(field, job.grid, name=f"{method} |sigma_DC|")
        amplitude = float(result.amplitude or 1.0)
        # held-out pings give the novel-view errors and the figure; else a few training pings
        scored = _evenly(job.held_idx, _MAX_NOVEL_PINGS)
        fit_pings = scored if len(scored) else _evenly(job.train_idx, _FIT_PINGS)
        check_stop(should_stop)
        pred = _render(field, survey, fit_pings, spec, amplitude, job.device)
        if len(job.held_idx):
            from shsas_core.neural.render import signal_errors

            signal_errs = signal_errors(pred, s_pd[scored])
        show = slice(0, _FIT_PINGS)
        fit_fig = SignalFit(times=survey.times()[fit_pings[show]] * 1e3, measured=s_pd[fit_pings[show]],
                            predicted=pred[show], pings=[int(i) for i in fit_pings[show]])
        cache.save_fit(fit_fig)
    check_stop(should_stop)
    progress(0.9, method, {})
    rep, mesh_ = _finish(method, spec, vol, job.gt, out, cache, names, extract_key, t0, loss_curve,
                         signal_errs, progress, should_stop, fit_warns, sensors=survey.tx)
    return MethodOutput(rep, vol, mesh_, fit_fig)


def _finish(method: str, spec: ReconstructionSpec, vol: Volume, gt: GroundTruth | None, out: Path,
            cache: MethodCache, names: dict[str, str], extract_key: dict[str, Any], t0: float,
            loss_curve: list[tuple[int, float]], signal_errs: dict[str, float], progress: ProgressFn,
            should_stop: StopFn, fit_warns: list[ResultWarning] | None = None,
            sensors: np.ndarray | None = None) -> tuple[MethodReport, Any]:
    """Extract, export, score, check for a failed result (the volume's checks plus
    ``fit_warns`` from the fit), and mark the method done. ``sensors``: (N, 3) transmitter
    positions, m, that the surface normals face."""
    ecfg = ExtractConfig(threshold=spec.threshold, surface=spec.surface, mesher=spec.mesher)
    tau, cloud, mesh_ = extract(vol, ecfg, sensors)
    write_volume_npy(vol, out / names["volume"])
    write_point_cloud_ply(cloud, out / names["pointcloud"])
    write_mesh_ply(mesh_, out / names["mesh_ply"])
    glb = write_mesh_glb(mesh_, out / names["mesh_glb"])
    if gt is not None:
        check_stop(should_stop)
        # the paper's fixed level beside the rule's, so a figure can be compared with Table 1
        fixed = point_cloud(vol, PAPER_TAU).points
        metrics: dict[str, float | None] = finite_or_none(score_reconstruction(cloud.points, mesh_, gt, fixed))
    else:  # the mesh's pieces need no ground truth: a foam shows without it
        metrics = {"mesh_pieces": mesh_quality(mesh_.vertices, mesh_.faces)["pieces"]}
    rep = MethodReport(method=method, sh_degree=sh_degree_of(method, spec), threshold=tau,
                       points=len(cloud), faces=len(mesh_.faces), seconds=time.perf_counter() - t0,
                       metrics=metrics, signal_errors=signal_errs, loss_curve=loss_curve,
                       artifacts=names, origin_offset=glb["origin_offset"],
                       warnings=_result_warnings(vol, tau, metrics) + list(fit_warns or []))
    cache.mark_done(rep, extract_key)
    progress(1.0, method, {})
    return rep, mesh_


def _result_warnings(vol: Volume, tau: float, metrics: dict[str, float | None]) -> list[ResultWarning]:
    """The volume's checks; the mesh's only when the volume passed (a collapsed or fog-filled
    volume's mesh says nothing more)."""
    return volume_warnings(vol, tau) or mesh_warnings(metrics)


def _fit_neural(method: str, job: _Job, ckpt: Path, progress: ProgressFn) -> tuple[Any, FitResult]:
    """Build the SH field for ``method``, start it from the backprojection image when
    ``spec.init`` says so, and fit it to the training pings' s_PD (checkpointed under ``ckpt``; a
    compatible checkpoint there is resumed, and then holds the started field already)."""
    import torch

    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.fields.occupancy import MaskedField, OccupancyConfig, OccupancyGrid
    from shsas_core.neural.train import CHECKPOINT_NAME, coarse_start_levels, fit
    from shsas_core.neural.warmstart import WarmStartConfig, distill

    spec, survey, should_stop = job.spec, job.survey, job.should_stop
    torch.manual_seed(spec.seed)
    fcfg = FieldConfig(sh_degree=sh_degree_of(method, spec), scene_box=survey.meta.scene_box,
                       encoding=encoding_preset(spec.encoding))
    field = SHField(fcfg).to(job.device)
    fit_progress = progress
    occupancy = None
    if spec.init == "backprojection" or spec.occupancy is not None:
        fit_progress = sub_progress(progress, 0.25, 1.0)
        vol = job.image(sub_progress(progress, 0.0, 0.15))
        if spec.occupancy is not None:
            occupancy = OccupancyGrid.from_volume(vol, OccupancyConfig(level=spec.occupancy))
        if spec.init == "backprojection" and not (ckpt / CHECKPOINT_NAME).exists():
            if spec.coarse_to_fine is not None:  # the start holds only the levels the fit starts with
                field.set_active_levels(coarse_start_levels(fcfg.encoding))
            distill(field, vol, WarmStartConfig(seed=spec.seed), progress=sub_progress(progress, 0.15, 0.25),
                    should_stop=should_stop, stage=f"warm start:{method}")
    cfg = train_config(spec)
    psf = None
    if spec.forward == "psf":
        from shsas_core.signal.deconv import point_spread

        psf = point_spread(survey, deconv_config(spec))
    result = fit(field, survey, job.s_pd, cfg, progress=fit_progress, should_stop=should_stop,
                 checkpoint_dir=ckpt, ping_indices=job.train_idx, stage=f"fit:{method}", psf=psf,
                 occupancy=occupancy)
    # the model is the field inside its mask: render and extract it as it was trained
    return (field if occupancy is None else MaskedField(field, occupancy)), result


def train_config(spec: ReconstructionSpec) -> Any:
    """The trainer's config from the job spec. Every key is a TrainConfig field: a name that is
    not (a renamed field, say) fails here instead of being dropped."""
    from shsas_core.neural.render import RenderConfig
    from shsas_core.neural.train import LossWeights, TrainConfig

    return TrainConfig(
        iters=spec.iters, seed=spec.seed, num_bins=spec.num_bins, num_rays=spec.num_rays, lr=spec.lr,
        lr_final=spec.lr_final, average_last=spec.average_last, coarse_to_fine=spec.coarse_to_fine,
        target=spec.target, pings_per_batch=spec.pings_per_batch,
        device=spec.device,
        weights=LossWeights(sparsity=spec.sparsity, angular=spec.angular_prior, tv_density=spec.tv_density,
                            tv_scatter=spec.tv_scatter, tv_phase=spec.tv_phase),
        render=RenderConfig(normal_window=spec.normal_window),
        # about ten checkpoints per fit, so a re-delivered job loses at most a tenth of it
        checkpoint_every=max(10, min(500, spec.iters // 10)))


def _render(field: Any, survey: Survey, pings: np.ndarray, spec: ReconstructionSpec, amplitude: float,
            device: Any) -> np.ndarray:
    from shsas_core.neural.render import RenderConfig, render_transients

    cfg = RenderConfig(num_rays=min(spec.num_rays, MAX_SCORING_RAYS), normal_window=spec.normal_window)
    return render_transients(field, survey, pings, cfg, amplitude=amplitude, device=device, seed=spec.seed)


def _loss_curve(loss_history: list[float], max_points: int = 400) -> list[tuple[int, float]]:
    """(iteration, total loss) from ``FitResult.loss_history``, thinned to ``max_points``."""
    hist = list(loss_history)
    step = max(1, math.ceil(len(hist) / max_points))
    keep = list(range(0, len(hist), step))
    if hist and keep[-1] != len(hist) - 1:
        keep.append(len(hist) - 1)
    return [(i, float(hist[i])) for i in keep if math.isfinite(float(hist[i]))]
