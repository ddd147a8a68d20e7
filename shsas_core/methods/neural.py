"""What the neural methods share: build the SH field of the method's degree, start it from the
backprojection image (``spec.init``), fit it to the training pings' deconvolved signals
(:func:`shsas_core.neural.train.fit`, checkpointed and resumable), then sample its volume and
render a few pings for the novel-view errors and the report's signal figure.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shsas_core.common.progress import ProgressFn, check_stop, sub_progress
from shsas_core.data.survey import Survey
from shsas_core.evaluation.diagnostics import fit_warnings
from shsas_core.methods.base import MethodContext, MethodResult
from shsas_core.outputs.report import SignalFit
from shsas_core.spec.catalogue import REGISTRY
from shsas_core.spec.job import ReconstructionSpec

#: Pings whose signal fit is drawn in the report.
_FIT_PINGS = 3
#: At most this many held-out pings (evenly spaced) are rendered for the novel-view errors:
#: rendering a whole ping costs about as much as a few hundred training iterations on a CPU.
_MAX_NOVEL_PINGS = 32
#: The pings rendered for the signal figure and the novel-view errors use the job's ``num_rays``
#: up to this many rays per ping: whole pings cost far more than a training batch, and 512 rays
#: already give errors stable to a few per cent.
MAX_SCORING_RAYS = 512


def fit_field(ctx: MethodContext) -> MethodResult:
    """Fit the method's field (degree from the catalogue) and sample it on ``ctx.grid``."""
    from shsas_core.neural.fields.volume import field_volume

    field, result, window = _fit(ctx, sub_progress(ctx.progress, 0.0, 0.8))
    loss_curve = _loss_curve(result.loss_history)
    warns = fit_warnings(result.data_loss_history)
    check_stop(ctx.should_stop)
    ctx.progress(0.8, ctx.name, {"stage": 1.0})
    vol = field_volume(field, ctx.grid, name=f"{ctx.name} |sigma_DC|")
    amplitude = float(result.amplitude or 1.0)
    # held-out pings give the novel-view errors and the figure; else a few training pings
    scored = _evenly(ctx.held_idx, _MAX_NOVEL_PINGS)
    fit_pings = scored if len(scored) else _evenly(ctx.train_idx, _FIT_PINGS)
    check_stop(ctx.should_stop)
    pred = _render(field, ctx.survey, fit_pings, ctx.spec, amplitude, ctx.device, window)
    signal_errs: dict[str, float] = {}
    if len(ctx.held_idx):
        from shsas_core.neural.render import signal_errors

        signal_errs = signal_errors(pred, ctx.signals[scored])
    show = slice(0, _FIT_PINGS)
    fit_fig = SignalFit(times=ctx.survey.times()[fit_pings[show]] * 1e3, measured=ctx.signals[fit_pings[show]],
                        predicted=pred[show], pings=[int(i) for i in fit_pings[show]])
    return MethodResult(volume=vol, field=field, loss_curve=loss_curve, signal_errors=signal_errs,
                        signal_fit=fit_fig, warnings=warns, record={**result.to_json(), "normal_window": window})


def _fit(ctx: MethodContext, progress: ProgressFn) -> tuple[Any, Any, int]:
    """Build the SH field, start it from the backprojection image when ``spec.init`` says so,
    and fit it to the training pings' s_PD (checkpointed under ``ctx.checkpoint_dir``; a
    compatible checkpoint there is resumed, and then holds the started field already).

    Returns:
        (the field as it was trained, i.e. inside its occupancy mask when there is one;
        :class:`~shsas_core.neural.train.FitResult`; the Lambertian normal's window it was
        trained with, :func:`normal_window`).
    """
    import torch

    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.fields.occupancy import OccupancyConfig, OccupancyGrid, within
    from shsas_core.neural.train import CHECKPOINT_NAME, coarse_start_levels, fit
    from shsas_core.neural.warmstart import WarmStartConfig, distill

    spec, survey, ckpt = ctx.spec, ctx.survey, ctx.checkpoint_dir
    torch.manual_seed(spec.seed)
    fcfg = FieldConfig(sh_degree=REGISTRY[ctx.name].sh_degree(spec.sh_degree), scene_box=survey.meta.scene_box,
                       encoding=encoding_preset(spec.encoding))
    field = SHField(fcfg).to(ctx.device)
    fit_progress = progress
    occupancy = None
    if spec.init == "backprojection" or spec.occupancy is not None:
        fit_progress = sub_progress(progress, 0.25, 1.0)
        vol = ctx.image(sub_progress(progress, 0.0, 0.15))
        if spec.occupancy is not None:
            occupancy = OccupancyGrid.from_volume(vol, OccupancyConfig(level=spec.occupancy, floor_factor=spec.occupancy_floor))
        if spec.init == "backprojection" and not (ckpt / CHECKPOINT_NAME).exists():
            if spec.coarse_to_fine is not None:  # the start holds only the levels the fit starts with
                field.set_active_levels(coarse_start_levels(fcfg.encoding))
            distill(field, vol, WarmStartConfig(seed=spec.seed), progress=sub_progress(progress, 0.15, 0.25),
                    should_stop=ctx.should_stop, stage=f"warm start:{ctx.name}", occupancy=occupancy)
    psf = fit_kernel(spec, survey)
    window = normal_window(spec, psf, survey)
    result = fit(field, survey, ctx.signals, train_config(spec, window), progress=fit_progress,
                 should_stop=ctx.should_stop, checkpoint_dir=ckpt, ping_indices=ctx.train_idx,
                 stage=f"fit:{ctx.name}", psf=psf, occupancy=occupancy)
    # the model is the field inside its mask: render and extract it as it was trained
    return within(field, occupancy), result, window


def fit_kernel(spec: ReconstructionSpec, survey: Survey) -> np.ndarray | None:
    """The point-spread kernel a fit renders through (``forward = "psf"``), else None."""
    if spec.forward != "psf":
        return None
    from shsas_core.signal.deconv import point_spread
    from shsas_core.signal.sources import deconv_config

    return point_spread(survey, deconv_config(spec))


def normal_window(spec: ReconstructionSpec, psf: Any, survey: Survey) -> int:
    """The Lambertian normal's window a fit uses, in samples: where the trainer renders whole
    range windows (a point-spread kernel ``psf``) the spec's, or by default the whole samples in
    :data:`~shsas_core.spec.options.NORMAL_WINDOW_RESOLUTIONS` range resolutions of ``survey``
    (``meta.resolution_samples``, ``fs / B``), at least ``NORMAL_WINDOW_MIN_SAMPLES``; 1 under
    the impulse model (``psf`` None).

    The window is a length: counted in samples, it shrank to 0.4 of a range resolution at 250
    kHz, where it no longer lit the whole ridge. The impulse model's bins are drawn apart along
    each ray, so a sum of gradients over several of them is no finite difference. It is also
    what ``forward = "psf"`` falls back to on pre-deconvolved pings (a real AirSAS folder),
    which have no kernel."""
    from shsas_core.spec.options import NORMAL_WINDOW_MIN_SAMPLES, NORMAL_WINDOW_RESOLUTIONS

    if psf is None:
        return 1
    if spec.normal_window is not None:
        return spec.normal_window
    samples = math.floor(round(NORMAL_WINDOW_RESOLUTIONS * survey.meta.resolution_samples, 6))
    return max(NORMAL_WINDOW_MIN_SAMPLES, samples)


def train_config(spec: ReconstructionSpec, window: int | None = None) -> Any:
    """The trainer's config from the job spec (``window``: the normal window, :func:`normal_window`;
    None: the spec's, or where the spec leaves it to the survey the renderer's default, the
    default survey's). Every key is a TrainConfig field: a name that is not (a renamed field,
    say) fails here instead of being dropped."""
    from shsas_core.neural.render import RenderConfig
    from shsas_core.neural.train import LossWeights, TrainConfig

    if window is None:
        window = spec.normal_window if spec.normal_window is not None else RenderConfig().normal_window

    return TrainConfig(
        iters=spec.iters, seed=spec.seed, num_bins=spec.num_bins, num_rays=spec.num_rays, lr=spec.lr,
        lr_final=spec.lr_final, average_last=spec.average_last, coarse_to_fine=spec.coarse_to_fine,
        target=spec.target, pings_per_batch=spec.pings_per_batch,
        device=spec.device, weights=LossWeights(sparsity=spec.sparsity, angular=spec.angular_prior, tv_density=spec.tv_density,
                            tv_scatter=spec.tv_scatter, tv_phase=spec.tv_phase),
        render=RenderConfig(normal_window=window),
        # about ten checkpoints per fit, so a re-delivered job loses at most a tenth of it
        checkpoint_every=max(10, min(500, spec.iters // 10)))


def _render(field: Any, survey: Survey, pings: np.ndarray, spec: ReconstructionSpec, amplitude: float,
            device: Any, window: int) -> np.ndarray:
    """Whole pings rendered as the field was trained (``window``: its normal window)."""
    from shsas_core.neural.render import RenderConfig, render_transients

    cfg = RenderConfig(num_rays=min(spec.num_rays, MAX_SCORING_RAYS), normal_window=window)
    return render_transients(field, survey, pings, cfg, amplitude=amplitude, device=device, seed=spec.seed)


def _evenly(idx: np.ndarray, k: int) -> np.ndarray:
    """At most ``k`` entries of ``idx``, evenly spaced."""
    if len(idx) <= k:
        return np.asarray(idx)
    return np.asarray(idx)[np.linspace(0, len(idx) - 1, k).round().astype(np.int64)]


def _loss_curve(loss_history: list[float], max_points: int = 400) -> list[tuple[int, float]]:
    """(iteration, total loss) from ``FitResult.loss_history``, thinned to ``max_points``."""
    hist = list(loss_history)
    step = max(1, math.ceil(len(hist) / max_points))
    keep = list(range(0, len(hist), step))
    if hist and keep[-1] != len(hist) - 1:
        keep.append(len(hist) - 1)
    return [(i, float(hist[i])) for i in keep if math.isfinite(float(hist[i]))]
