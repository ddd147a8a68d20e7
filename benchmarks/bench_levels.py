"""Re-extract the fidelity benchmark's stored volumes at other iso levels: does a ground-truth-free
level rule beat the product's Otsu rule?

Runs nothing new. For every ``<method>_volume.npy`` a ``bench_fidelity.py`` run left under
``--out/<profile>/<regime>/<scene>/seed<S>/`` it picks τ by each rule below, thresholds the
normalised magnitude exactly as ``shsas_core.extract.point_cloud`` does, and scores the cloud
against the cell's ground truth (its cached survey, design §5). Prints point-cloud F1,
Chamfer-L2 and F@5mm per volume and rule, then the means over scenes per method, side by side.

Rules (τ on the range-normalised magnitude ``n``, ``extract.normalize``):

- ``otsu``: the product's rule, ``extract.choose_threshold`` with the default config;
- ``paper``: the paper's fixed τ = 0.2 (``extract.PAPER_TAU``);
- ``fixed0.1``: τ = 0.1;
- ``li``: Li's minimum cross-entropy threshold of ``n`` (``skimage.filters.threshold_li``);
- ``otsu_db``: Otsu's threshold of ``20 log10 n`` with a -40 dB floor, back to linear; sonar
  images are read in decibels, and a level picked there keeps dim but real surfaces (a grazing cap).

The rules other than ``otsu`` and ``paper`` are candidates measured here, not product options.

Usage::

    python benchmarks/bench_levels.py --regimes dense --scenes bunny,armadillo,sphere,cube
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fidelity as fid

from shsas_core.export import read_volume_npy
from shsas_core.extract import PAPER_TAU, choose_threshold, normalize, otsu_threshold, point_cloud
from shsas_core.metrics import GroundTruth, score_points
from shsas_core.volume import Volume

#: Floor of the decibel scale for ``otsu_db`` (dB below the peak); lower magnitudes count as it.
DB_FLOOR = -40.0


def otsu_db(norm: np.ndarray, floor_db: float = DB_FLOOR) -> float:
    """Otsu's level of ``20 log10(norm)`` (floored at ``floor_db``), returned as a linear τ.

    Args:
        norm: any shape, normalised magnitude in [0, 1].
    """
    db = 20.0 * np.log10(np.maximum(norm, 10.0 ** (floor_db / 20.0)))
    return float(10.0 ** (otsu_threshold(db) / 20.0))


def li(norm: np.ndarray) -> float:
    """Li's minimum cross-entropy threshold of the normalised magnitude."""
    from skimage.filters import threshold_li

    return float(threshold_li(norm))


#: name -> τ from the volume (normalised magnitude for the candidates).
RULES: dict[str, Callable[[Volume], float]] = {
    "otsu": choose_threshold,
    "paper": lambda v: PAPER_TAU,
    "fixed0.1": lambda v: 0.1,
    "li": lambda v: li(normalize(v)),
    "otsu_db": lambda v: otsu_db(normalize(v)),
}


def rescore(volume: Volume, gt: GroundTruth) -> dict[str, dict[str, float]]:
    """Per rule: τ (clipped into (0, 1) as ``point_cloud`` requires) and the cloud's scores."""
    out = {}
    for name, rule in RULES.items():
        tau = float(np.clip(rule(volume), 1e-3, 1 - 1e-3))
        s = score_points(point_cloud(volume, tau).points, gt)
        out[name] = {"tau": tau, "f1": s["f1"], "chamfer_l2": s["chamfer_l2"], "fscore": s["fscore"]}
    return out


def main(argv: list[str] | None = None) -> int:
    from shsas_core.io import read_survey

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(fid.ROOT / "benchmarks" / "out" / "fidelity"),
                    help="bench_fidelity's results folder (default benchmarks/out/fidelity)")
    ap.add_argument("--profile", default="defaults", help="defaults, paper or dev (default defaults)")
    ap.add_argument("--regimes", help="comma list (default: every stored regime)")
    ap.add_argument("--scenes", help="comma list (default: every stored scene)")
    ap.add_argument("--cache-dir", help="simulated-survey cache (as bench_fidelity.py)")
    args = ap.parse_args(argv)
    regimes = fid._names(args.regimes, fid.REGIMES, "regimes")
    scenes = fid._names(args.scenes, fid.SCENES, "scenes")
    cache = fid.cache_dir(args.cache_dir)
    rows: dict[tuple[str, str, str], dict[str, float]] = {}
    records = sorted((Path(args.out) / args.profile).glob("*/*/seed*/result.json"))
    for path in records:
        rec = fid.read_record(path)
        if not rec or (regimes and rec["regime"] not in regimes) or (scenes and rec["scene"] not in scenes):
            continue
        survey_file = cache / f"{rec['scene']}-{rec['survey']['cache_key']}.h5"
        if not survey_file.is_file():
            print(f"skipped {path.parent}: its survey {survey_file} is not in the cache")
            continue
        gt = GroundTruth.from_survey(read_survey(survey_file))
        cell = f"{rec['regime']}/{rec['scene']}/seed{rec['seed']}"
        for method in rec.get("methods", {}):
            stored = path.parent / method / f"{method}_volume.npy"
            if not stored.is_file():
                continue
            for rule, s in rescore(read_volume_npy(stored), gt).items():
                rows[(cell, method, rule)] = s
                print(f"{cell:24s} {method:14s} {rule:9s} τ {s['tau']:.3f}  F1 {s['f1']:.3f}  "
                      f"Chamfer {s['chamfer_l2']:.2e}  F@5mm {s['fscore']:.3f}", flush=True)
    if not rows:
        print(f"no stored volumes under {Path(args.out) / args.profile}")
        return 1
    methods = sorted({m for _, m, _ in rows})
    cells = sorted({c for c, _, _ in rows})
    print(f"\nmean over {len(cells)} cell(s): pc F1 / Chamfer-L2 m² / F@5mm")
    print("| rule | " + " | ".join(fid.LABEL.get(m, m) for m in methods) + " |")
    print("|---|" + "---|" * len(methods))
    for rule in RULES:
        out = []
        for m in methods:
            sel = [rows[(c, m, rule)] for c in cells if (c, m, rule) in rows]
            out.append(" / ".join([f"{np.mean([s['f1'] for s in sel]):.3f}",
                                   f"{np.mean([s['chamfer_l2'] for s in sel]):.2e}",
                                   f"{np.mean([s['fscore'] for s in sel]):.3f}"]))
        print(f"| {rule} | " + " | ".join(out) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
