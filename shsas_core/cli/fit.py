"""`shsas fit SURVEY --method shsas|reed --out DIR`: fit one neural method's field as a
reconstruction job would, and keep the field.

The options are the job spec's (:mod:`shsas_core.cli.spec_options`, the same as ``shsas
reconstruct``), and so are the signals (the spec's deconvolution, :mod:`shsas_core.signal.sources`),
the start from the backprojection image, the occupancy grid and the forward model: the fit is
the method's own ``reconstruct`` (:mod:`shsas_core.methods`), run outside the job's cache so
that a larger ``--iters`` continues from ``DIR/checkpoint.pt``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.cli.spec_options import add_spec_options, spec_from_args
from shsas_core.spec.catalogue import NEURAL, REGISTRY


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="fit one neural method (SH-SAS, or Reed et al., L=0) to a survey and keep its field",
        description="Fit a neural scattering field by analysis-by-synthesis on the survey's "
        "pulse-deconvolved signals, exactly as `shsas reconstruct --methods METHOD` does (same spec "
        "options and defaults, same signals, warm start, occupancy grid and forward model). Writes "
        "DIR/checkpoint.pt (about ten times per fit and at the end), DIR/field.pt (weights + configs), "
        "DIR/loss_history.json and DIR/METHOD_volume.npy/.json (the field's |sigma_DC| on the spec's "
        "grid). Re-running with the same DIR resumes from the checkpoint and gives the same result "
        "as an uninterrupted run; a larger --iters continues training (see --average-last).")
    p.add_argument("survey", help="survey file (canonical .h5 or any format `shsas convert` reads)")
    p.add_argument("--method", choices=list(NEURAL), default="shsas",
                   help="; ".join(f"{n}: {REGISTRY[n].label}" for n in NEURAL) + " (default shsas)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (created; resumed if it has a checkpoint)")
    add_spec_options(p, exclude=frozenset({"methods"}))
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from shsas_core.common.atomic import atomic_path
    from shsas_core.common.device import resolve_device
    from shsas_core.common.progress import TqdmProgress, never_stop, sub_progress
    from shsas_core.data.volume import Grid
    from shsas_core.methods import MethodContext, reconstruct
    from shsas_core.methods.neural import train_config
    from shsas_core.outputs.export import write_volume_npy
    from shsas_core.pipeline.job import holdout_split, load_input
    from shsas_core.signal.sources import deconv_config, signals_for
    from shsas_core.spec.memory import memory_budget

    spec = spec_from_args(args, methods=[args.method])
    device = resolve_device(spec.device)
    survey = load_input(args.survey, spec, memory_budget())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bar = TqdmProgress(disable=args.no_progress)
    try:
        got = signals_for(survey, "deconvolve", deconv_config(spec), device=device,
                          progress=sub_progress(bar, 0.0, 0.05))
        signals = np.asarray(got.values, dtype=np.complex64)  # as the job caches them
        train_idx, held_idx = holdout_split(survey.num_pings, spec.holdout_fraction, spec.seed)
        grid = Grid.over(survey.meta.scene_box, spec.grid_count(survey.meta.scene_box))
        ctx = MethodContext(name=args.method, spec=spec, survey=survey, signals=signals, train_idx=train_idx,
                            held_idx=held_idx, grid=grid, image=_Image(survey, signals, train_idx, grid, device),
                            device=device, checkpoint_dir=out, progress=sub_progress(bar, 0.05, 1.0),
                            should_stop=never_stop)
        result = reconstruct(ctx)
    finally:
        bar.close()
    record: dict[str, Any] = result.record
    field = getattr(result.field, "field", result.field)  # the trained field, without its mask
    meta = {"method": args.method, "sh_degree": REGISTRY[args.method].sh_degree(spec.sh_degree),
            "signals": got.label, "survey": str(args.survey), "spec": spec.model_dump(mode="json"),
            "field_config": field.config.model_dump(mode="json"),
            "train_config": train_config(spec, record["normal_window"]).model_dump(mode="json")}
    with atomic_path(out / "field.pt") as tmp:
        torch.save({"state_dict": field.state_dict(), "amplitude": record.get("amplitude"), **meta}, tmp)
    (out / "loss_history.json").write_text(json.dumps({**record, **meta}, indent=1))
    write_volume_npy(result.volume, out / f"{args.method}_volume.npy")
    tail = record["data_loss_history"][-min(50, len(record["data_loss_history"])):]
    print(f"fit {args.method} (L={meta['sh_degree']}) on {len(train_idx)} pings, signals: {got.label}: "
          f"{record['iterations']} iterations ({record['start_iteration']} resumed), "
          f"{record['iters_per_s']:.2f} it/s, final data loss {np.mean(tail):.4g} -> {out}", file=sys.stderr)
    return 0


class _Image:
    """The backprojection image of the training pings on the grid, computed on first use (the
    job's is cached in its checkpoints; a fit has no job cache)."""

    def __init__(self, survey: Any, signals: np.ndarray, train_idx: np.ndarray, grid: Any, device: Any):
        self._args = (survey.subset(train_idx), grid, signals[train_idx])
        self._device = device
        self._volume: Any = None

    def __call__(self, progress: Any) -> Any:
        from shsas_core.imaging.backprojection import backproject_survey

        if self._volume is None:
            self._volume = backproject_survey(*self._args, device=self._device, progress=progress)
        progress(1.0, "backprojection", {})
        return self._volume
