"""What a method is given (:class:`MethodContext`) and what it gives back (:class:`MethodResult`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from shsas_core.common.progress import ProgressFn, StopFn
from shsas_core.data.survey import Survey
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.diagnostics import ResultWarning
from shsas_core.outputs.report import SignalFit
from shsas_core.spec.job import ReconstructionSpec


class ImageFn(Protocol):
    """The job's backprojection image of the training pings on its grid, computed on first use
    and cached (a resumed job reads it back)."""

    def __call__(self, progress: ProgressFn) -> Volume: ...


@dataclasses.dataclass(frozen=True)
class MethodContext:
    """One method's share of a job.

    Attributes:
        name: the method's catalogue name.
        spec: the job's spec.
        survey: every ping of the job's survey (held-out ones included).
        signals: (N, T) complex64 deconvolved signals s_PD of all pings (the job's, cached).
        train_idx, held_idx: sorted ping indices to fit / held out for the novel-view errors.
        grid: the job's voxel grid (``spec.grid_count`` over the scene box); the volume is on it.
        image: the job's backprojection image of the training pings (:class:`ImageFn`).
        device: the torch device the job runs on.
        checkpoint_dir: the method's own folder under the job's checkpoints (exists); what is
            there is resumed from when the job runs again.
        progress: ``progress(fraction of this method, stage, metrics)``; the method reports
            up to 0.8, the pipeline the rest.
        should_stop: polled inside every long step; True cancels (``Cancelled``).
    """

    name: str
    spec: ReconstructionSpec
    survey: Survey
    signals: np.ndarray
    train_idx: np.ndarray
    held_idx: np.ndarray
    grid: Grid
    image: ImageFn
    device: Any
    checkpoint_dir: Path
    progress: ProgressFn
    should_stop: StopFn


@dataclasses.dataclass(frozen=True)
class MethodResult:
    """What a method reconstructed.

    Attributes:
        volume: the volume extraction runs on, on ``ctx.grid``.
        field: the fitted model (a neural method's field as rendered), else None.
        loss_curve: (iteration, loss) points for the report; empty when there was no fit.
        signal_errors: errors of the rendered held-out pings (``shsas_core.neural.render.signal_errors``).
        signal_fit: the measured and predicted signals of a few pings, drawn in the report.
        warnings: signs from the reconstruction itself that it failed (e.g. a loss that did not fall).
        record: the method's own figures, JSON-ready, for a caller that keeps them (a neural
            fit: ``FitResult.to_json()``, the whole loss history included).
    """

    volume: Volume
    field: Any = None
    loss_curve: list[tuple[int, float]] = dataclasses.field(default_factory=list)
    signal_errors: dict[str, float] = dataclasses.field(default_factory=dict)
    signal_fit: SignalFit | None = None
    warnings: list[ResultWarning] = dataclasses.field(default_factory=list)
    record: dict[str, Any] = dataclasses.field(default_factory=dict)


class Reconstruct(Protocol):
    """A method's entry point."""

    def __call__(self, ctx: MethodContext) -> MethodResult: ...
