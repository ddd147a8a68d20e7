"""`shsas backproject SURVEY --grid N --out DIR`: time-domain backprojection onto a voxel grid."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "backproject", help="image a survey by time-domain backprojection (complex voxel volume)",
        description="Backproject a survey onto a voxel grid over its scene box: every voxel sums "
        "each ping's signal at the voxel's two-way time of flight (linear interpolation, carrier "
        "phase restored). Writes DIR/volume.npy (complex64, shape = grid) and its sidecar "
        "DIR/volume.json (box, shape, spacing, settings), the volume format of `shsas reconstruct`. "
        "The signal imaged is the pulse-deconvolved one by default (the survey's stored "
        "extras/deconvolved when present and --deconv is not given, else computed with --deconv).",
        epilog="Example: shsas backproject survey.h5 --grid 128 --out bp/ --device auto")
    p.add_argument("survey", help="survey file (canonical .h5 or any format `shsas convert` reads)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--grid", type=int, default=128,
                   help="voxels along the longest axis of the scene box (cubic voxels; 8..512, the job "
                   "spec's bounds; default 128)")
    p.add_argument("--signal", choices=["deconvolved", "matched", "raw"], default="deconvolved",
                   help="deconvolved: pulse-deconvolved s_PD (default); matched: matched filter; "
                   "raw: the analytic signal of the samples without pulse compression")
    p.add_argument("--deconv", choices=["wiener", "neural", "none"], default=None,
                   help="how to deconvolve when --signal deconvolved (default: use the survey's "
                   "stored extras/deconvolved if present, else wiener)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda or cuda:N")
    p.add_argument("--interpolation", choices=["linear", "nearest"], default="linear")
    p.add_argument("--upsample", type=int, default=1, help="FFT upsampling factor before interpolation")
    p.add_argument("--no-beams", action="store_true", help="ignore the survey's TX/RX beam cones")
    # the choices of BackprojectionConfig.backend (not imported here: --help stays free of torch)
    p.add_argument("--backend", choices=["auto", "compiled", "eager", "triton"], default="auto",
                   help="kernel: compiled (torch.compile), eager, triton (CUDA only), or auto "
                   "(triton on CUDA, else compile large problems)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from shsas_core.common.device import resolve_device
    from shsas_core.common.errors import ShsasError
    from shsas_core.common.progress import TqdmProgress
    from shsas_core.data.volume import Grid
    from shsas_core.formats import load_survey
    from shsas_core.imaging.backprojection import BackprojectionConfig, backproject_survey
    from shsas_core.outputs.export import write_volume_npy
    from shsas_core.signal.deconv import DeconvConfig
    from shsas_core.signal.sources import signals_for

    _check_grid(args.grid)
    if not 1 <= args.upsample <= 32:
        raise ShsasError(f"--upsample: {args.upsample} is outside 1..32")
    device = resolve_device(args.device)
    survey = load_survey(args.survey)
    progress = TqdmProgress(disable=args.quiet)
    t_start = time.perf_counter()
    try:
        if args.signal == "matched":
            source = "matched"
        elif args.signal == "raw" or args.deconv == "none":
            source = "raw"
        else:  # the stored signals unless a deconvolution is named
            source = "auto" if args.deconv is None else "deconvolve"
        got = signals_for(survey, source, DeconvConfig(method=args.deconv or "wiener"), device=device,
                          progress=progress)
        signals, source = got.values, got.label
        grid = Grid.over(survey.meta.scene_box, args.grid)
        cfg = BackprojectionConfig(interpolation=args.interpolation, upsample=args.upsample,
                                   use_beams=not args.no_beams, backend=args.backend)
        volume = backproject_survey(survey, grid, signals, config=cfg, device=device, progress=progress)
    finally:
        progress.close()
    seconds = time.perf_counter() - t_start
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_volume_npy(volume, out / "volume.npy", extra={
        "survey": str(args.survey), "signal": source, "device": str(device),
        "config": cfg.model_dump(), "pings": survey.num_pings, "seconds": round(seconds, 3)})
    mag = volume.magnitude()
    peak = np.unravel_index(int(np.argmax(mag)), grid.shape)
    centre = np.asarray(grid.box_min) + (np.asarray(peak) + 0.5) * grid.spacing
    print(json.dumps({"out": str(out), "grid": list(grid.shape),
                      "signal": source, "seconds": round(seconds, 2),
                      "peak_voxel": [int(i) for i in peak], "peak_position_m": centre.round(4).tolist()}))
    return 0


def _check_grid(count: int) -> None:
    """The job spec's grid bounds (shsas_core.spec.options.GridCount), one line naming the option."""
    from pydantic import TypeAdapter, ValidationError

    from shsas_core.common.errors import ShsasError
    from shsas_core.spec.options import GridCount

    try:
        TypeAdapter(GridCount).validate_python(count)
    except ValidationError as exc:
        raise ShsasError(f"--grid: {exc.errors()[0]['msg']} (got {count})") from None
