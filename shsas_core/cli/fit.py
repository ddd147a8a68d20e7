"""`shsas fit SURVEY --method shsas|reed --out DIR`: train a neural scattering field on a survey."""

from __future__ import annotations

import argparse
import json
import sys
import typing
from pathlib import Path

import numpy as np

from shsas_core.common.atomic import atomic_path
from shsas_core.common.errors import ShsasError
from shsas_core.spec.options import (
    AVERAGE_LAST,
    AVERAGE_LAST_HELP,
    DEVICE,
    ITERS,
    LR,
    NUM_BINS,
    NUM_RAYS,
    PINGS_PER_BATCH,
    SEED,
    SH_DEGREE,
    EncodingName,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="train an SH-SAS (or Reed et al., L=0) neural field on a survey",
        description="Train a neural scattering field by analysis-by-synthesis on the survey's "
        "pulse-deconvolved signals (docs/neural.md). Writes OUT/checkpoint.pt (every "
        "--checkpoint-every iterations and at the end), OUT/field.pt (weights + configs) and "
        "OUT/loss_history.json. Re-running with the same OUT resumes from the checkpoint and "
        "gives the same result as an uninterrupted run; a larger --iters continues training "
        "(see --average-last).")
    p.add_argument("survey", help="survey file (canonical .h5 or any format `shsas convert` reads)")
    p.add_argument("--method", choices=["shsas", "reed"], default="shsas",
                   help="shsas: spherical-harmonic field of degree --sh-degree; reed: isotropic (L=0)")
    # defaults are the job spec's (shsas_core.spec.options); TrainConfig checks the bounds
    p.add_argument("--sh-degree", type=int, default=SH_DEGREE, choices=[0, 1, 2, 3], help="SH degree L (shsas only)")
    p.add_argument("--iters", type=int, default=ITERS,
                   help=f"training iterations (default {ITERS}; paper: 26k-100k on GPU)")
    p.add_argument("--out", required=True, help="output directory (created; resumed if it has a checkpoint)")
    p.add_argument("--device", default=DEVICE, help="auto, cpu, cuda or cuda:N")
    p.add_argument("--bins", type=int, default=NUM_BINS,
                   help=f"range bins per ping per iteration (default {NUM_BINS}; paper: 200)")
    p.add_argument("--rays", type=int, default=NUM_RAYS, help=f"TX rays per ping (default {NUM_RAYS}; paper: ~4800)")
    p.add_argument("--pings-per-batch", type=int, default=PINGS_PER_BATCH, help="pings rendered per iteration")
    p.add_argument("--lr", type=float, default=LR, help="Adam learning rate")
    p.add_argument("--lr-final", type=float, default=None,
                   help="learning rate at the last iteration, decayed exponentially from --lr (default: constant lr)")
    p.add_argument("--average-last", type=_fraction_or_none, default=AVERAGE_LAST, metavar="FRACTION",
                   help=f"{AVERAGE_LAST_HELP} (default {AVERAGE_LAST}; 'none' = None). A resumed run may "
                   "extend --iters only while its average has not begun at the checkpoint")
    p.add_argument("--seed", type=int, default=SEED, help="seed of every random draw")
    p.add_argument("--checkpoint-every", type=int, default=500, help="iterations between checkpoints")
    p.add_argument("--encoding", choices=sorted(typing.get_args(EncodingName)), default=None,
                   help="hash-grid preset (default: paper_gpu on CUDA, cpu otherwise)")
    p.add_argument("--beamwidth", type=float, default=None,
                   help="full TX cone angle, degrees (default: survey meta, else cover the scene box)")
    p.add_argument("--signals", choices=["auto", "deconvolved", "wiener", "analytic"], default="auto",
                   help="training target: 'deconvolved' = the file's extras/deconvolved; 'wiener' = "
                   "pulse deconvolution now; 'analytic' = analytic signal of the samples; 'auto' = "
                   "deconvolved if stored, else wiener")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _fraction_or_none(text: str) -> float | None:
    """``--average-last``'s value: ``none`` or a number (TrainConfig checks its bounds)."""
    if text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in (0, 1] or 'none', got {text!r}") from None


def _signals(survey, kind: str, device: str) -> tuple[np.ndarray, str]:
    if kind in ("auto", "deconvolved") and "deconvolved" in survey.extras:
        return np.asarray(survey.extras["deconvolved"]), "deconvolved (stored)"
    if kind == "deconvolved":
        raise ShsasError("fit: the survey has no extras/deconvolved (fix: use --signals wiener or run "
                         "the deconvolution first)")
    if kind in ("auto", "wiener"):
        try:
            from shsas_core.signal.deconv import DeconvConfig, deconvolve
        except ImportError:
            if kind == "wiener":
                raise ShsasError("fit: pulse deconvolution is not available in this build "
                                 "(fix: use --signals analytic)") from None
        else:
            from shsas_core.common.device import resolve_device

            return np.asarray(deconvolve(survey, DeconvConfig(), resolve_device(device))), "wiener"
    from shsas_core.signal.chain import (
        analytic_samples,  # the one definition of "the samples as complex"
    )

    complex_ = survey.samples is not None and np.iscomplexobj(survey.samples)
    return analytic_samples(survey), "samples (complex)" if complex_ else "analytic"


def run(args: argparse.Namespace) -> int:
    import torch

    from shsas_core.common.device import resolve_device
    from shsas_core.common.progress import TqdmProgress
    from shsas_core.formats import load_survey
    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.render import RenderConfig
    from shsas_core.neural.train import TrainConfig, fit

    device = resolve_device(args.device)
    survey = load_survey(args.survey)
    degree = 0 if args.method == "reed" else args.sh_degree
    preset = args.encoding or ("paper_gpu" if device.type == "cuda" else "cpu")
    try:
        fcfg = FieldConfig(sh_degree=degree, encoding=encoding_preset(preset), scene_box=survey.meta.scene_box)
        tcfg = TrainConfig(iters=args.iters, lr=args.lr, lr_final=args.lr_final,
                           average_last=args.average_last, num_bins=args.bins, num_rays=args.rays,
                           pings_per_batch=args.pings_per_batch, seed=args.seed,
                           checkpoint_every=args.checkpoint_every, device=str(device),
                           render=RenderConfig(beamwidth_deg=args.beamwidth))
    except ValueError as exc:  # pydantic: one line naming the option
        raise ShsasError(f"fit: invalid option: {str(exc).splitlines()[-2].strip()}") from None
    signals, source = _signals(survey, args.signals, str(device))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(args.seed)  # field initialisation
    field = SHField(fcfg)
    bar = TqdmProgress(disable=args.no_progress)
    try:
        res = fit(field, survey, signals, tcfg, progress=bar, checkpoint_dir=out, stage=f"fit:{args.method}")
    finally:
        bar.close()
    meta = {"method": args.method, "sh_degree": degree, "signals": source, "survey": str(args.survey),
            "field_config": fcfg.model_dump(mode="json"), "train_config": tcfg.model_dump(mode="json")}
    with atomic_path(out / "field.pt") as tmp:
        torch.save({"state_dict": field.state_dict(), "amplitude": res.amplitude, **meta}, tmp)
    (out / "loss_history.json").write_text(json.dumps({**res.to_json(), **meta}, indent=1))
    tail = res.data_loss_history[-min(50, len(res.data_loss_history)):]
    print(f"fit {args.method} (L={degree}) on {survey.num_pings} pings, signals: {source}: "
          f"{res.iterations} iterations ({res.start_iteration} resumed), {res.iters_per_s:.2f} it/s, "
          f"final data loss {np.mean(tail):.4g} -> {out}", file=sys.stderr)
    return 0
