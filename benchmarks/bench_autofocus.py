"""Autofocus wall time and estimates, search images by the eager vs the compiled kernel.

For each case (the real AirSAS cut-out scan, 360 pings, read in place from ../shared, with its
sound speed put 2 % off; ``narrow``: the same recording band-limited to 5 kHz around 20 kHz) it
runs :func:`shsas_core.imaging.autofocus.autofocus` at the defaults (one unknown, the sound speed, on
this single-height scan; three ping subsets) and prints one JSON line per (case, imager): wall
time, evaluations, the all-ping estimate, what was applied, and whether the data identified it.

* ``compiled``: search images by the compiled backprojection kernel (the default; its first
  call in the process compiles: ``compile_s`` is that first image's time);
* ``eager``: the same search with the kernel run op by op (what the search ran before).

``--plane known`` images the plane of best focus under the nominal geometry (what an operator
gives as ``--plane-z``); ``--plane auto`` leaves the plane to the search under the perturbed
geometry.

    python benchmarks/bench_autofocus.py [--cases wide,narrow] [--imagers compiled,eager]
        [--plane known|auto] [--rel 0.02]

Never asserts: figures are reported, not tested.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import torch

from shsas_core.formats import load_survey
from shsas_core.imaging import quicklook
from shsas_core.imaging.autofocus import AutofocusConfig, autofocus
from shsas_core.imaging.planar import focus_height
from shsas_core.signal.deconv import deconvolve
from tests.helpers.focus_scenes import perturbed
from tests.helpers.narrowband import band_limited

AIRSAS = Path(__file__).resolve().parents[2] / "shared" / "data" / "airsas"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="wide,narrow")
    ap.add_argument("--imagers", default="compiled,eager")
    ap.add_argument("--plane", choices=["known", "auto"], default="known")
    ap.add_argument("--rel", type=float, default=0.02, help="relative sound-speed error put in")
    args = ap.parse_args()
    wide = load_survey(AIRSAS / "cutout_20k", background=AIRSAS / "bg_20k")
    c_true = wide.meta.sound_speed
    plane_z = focus_height(wide, deconvolve(wide)) if args.plane == "known" else None
    print(json.dumps({"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                      "torch_threads": torch.get_num_threads(), "pings": wide.num_pings,
                      "plane_z_m": plane_z, "sound_speed_true": c_true, "rel_put_in": args.rel}), flush=True)
    for case in args.cases.split(","):
        base = wide if case == "wide" else band_limited(wide, 20e3, 5e3)
        survey = perturbed(base, sound_speed_rel=args.rel)
        for imager in args.imagers.split(","):
            # the eager path is the quicklook's own fallback for a process without a compiler
            quicklook._compile_failed = imager == "eager"
            t = time.perf_counter()
            res = autofocus(survey, config=AutofocusConfig(plane_z=plane_z))
            wall = time.perf_counter() - t
            (ident,) = res.identifiability
            print(json.dumps({
                "case": case, "imager": imager, "wall_s": round(wall, 1), "evaluations": res.evaluations,
                "plane_z_m": round(res.plane_z, 4),
                "estimate_err_pct": round(100 * (ident.estimate / c_true - 1), 3),
                "applied_err_pct": round(100 * (res.correction.sound_speed / c_true - 1), 3),
                "identified": ident.identified, "curvature": round(ident.curvature, 4),
                "spread_m_s": None if ident.spread is None else round(ident.spread, 3),
                "resolution_step_m_s": round(ident.resolution_step, 3)}), flush=True)


if __name__ == "__main__":
    main()
