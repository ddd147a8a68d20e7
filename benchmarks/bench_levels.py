"""Re-extract the fidelity benchmark's stored volumes at other iso levels: does a ground-truth-free
level rule beat the product's Otsu rule?

Runs nothing new. For every ``<method>_volume.npy`` a ``bench_fidelity.py`` run left under
``--out/<profile>/<regime>/<scene>/seed<S>/`` it picks τ by each rule below, thresholds the
normalised magnitude exactly as ``shsas_core.evaluation.extract.point_cloud`` does, and scores the cloud
against the cell's ground truth (its cached survey, design §5). Prints point-cloud surface F1,
the paper code's solid F1, Chamfer-L2 and F@5mm per volume and rule, then the means over scenes per method, side by side.

Rules (τ on the range-normalised magnitude ``n``, ``extract.normalize``):

- ``otsu``: the product's rule, ``extract.choose_threshold`` with the default config;
- ``paper``: the paper's fixed τ = 0.2 (``extract.PAPER_TAU``);
- ``fixed0.1``: τ = 0.1;
- ``li``: Li's minimum cross-entropy threshold of ``n`` (``skimage.filters.threshold_li``);
- ``otsu_db``: Otsu's threshold of ``20 log10 n`` with a -40 dB floor, back to linear; sonar
  images are read in decibels, and a level picked there keeps dim but real surfaces (a grazing cap).

The rules other than ``otsu`` and ``paper`` are candidates measured here, not product options.

With ``--hidden-band MM,...`` it also scores the Otsu cloud plus the voxels that lie within that
depth (mm) of it and that no sonar position can see (:func:`hidden_voxels`): the truncation band a
TSDF fusion marks as inside behind an observed surface. The solid F1 counts the solid object
(the paper code's convention), which a surface-only cloud cannot reach on large convex scenes; this asks whether
adding the unobservable space behind the surface separates the methods. A candidate, not a
product option.

With ``--fog SHARE`` it instead re-extracts every stored volume with the product's own extraction
(``extract.extract``: ridge cloud and Poisson mesh, the survey's sensors and range resolution) and,
for the neural methods, again with the fog step on at that share (``ExtractConfig.fog_share``: a
candidate, off in the product), and prints the cloud's and the mesh's surface F1, the cloud's
F@5mm and Chamfer-L2 and the mesh's area ratio of both. Backprojection is printed with the step
off only, for reference.

Usage::

    python benchmarks/bench_levels.py --regimes dense --scenes bunny,armadillo,sphere,cube
    python benchmarks/bench_levels.py --regimes dense --hidden-band 5,10,20
    python benchmarks/bench_levels.py --regimes sparse,dense --fog 0.05
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fidelity as fid

from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.extract import (
    PAPER_TAU,
    ExtractConfig,
    choose_threshold,
    extract,
    normalize,
    otsu_threshold,
    point_cloud,
)
from shsas_core.evaluation.metrics import GroundTruth, score_points, score_reconstruction
from shsas_core.outputs.export import read_volume_npy
from shsas_core.spec.catalogue import REGISTRY

#: Every how many pings a TX position serves as a view for :func:`hidden_voxels` (3,600 -> 515).
VIEW_STRIDE = 7

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


def hidden_voxels(mask: np.ndarray, grid: Grid, views: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Which candidate voxels the occupied voxels hide from every view.

    A candidate is seen from a view when no occupied voxel lies in front of it, more than half a
    voxel nearer, inside its line of sight. Per view the occupied voxels are splatted, with a
    one-bin margin, into a depth map over gnomonic angular bins one voxel wide at the farthest
    occupied voxel, so a closed surface cannot leak between its voxels.

    Args:
        mask: ``grid.shape`` bool, the occupied (surface) voxels.
        grid: the volume's grid (box and spacing, m).
        views: (V, 3) sonar positions, m, outside the box.
        candidates: ``grid.shape`` bool, the voxels to test (not in ``mask``).
    Returns:
        ``grid.shape`` bool: the candidates hidden from every view.
    """
    lo, h = np.asarray(grid.box_min), np.asarray(grid.spacing)
    occ_pts = lo + (np.argwhere(mask) + 0.5) * h
    cand_idx = np.argwhere(candidates & ~mask)
    cand_pts = lo + (cand_idx + 0.5) * h
    hidden = np.ones(len(cand_pts), dtype=bool)
    out = np.zeros(grid.shape, dtype=bool)
    if len(occ_pts) == 0 or len(cand_pts) == 0:
        return out
    centre = (lo + np.asarray(grid.box_max)) / 2
    for p in np.asarray(views, dtype=np.float64).reshape(-1, 3):
        e0 = (centre - p) / np.linalg.norm(centre - p)
        up = np.array([0.0, 0.0, 1.0]) if abs(e0[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(e0, up)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(e1, e0)

        def project(x: np.ndarray, p=p, e0=e0, e1=e1, e2=e2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            d = x - p
            z = d @ e0
            return d @ e1 / z, d @ e2 / z, np.linalg.norm(d, axis=1)

        oa, ob, orng = project(occ_pts)
        step = float(h.min()) / float(orng.max())
        ia, ib = np.floor(oa / step).astype(np.int64), np.floor(ob / step).astype(np.int64)
        a0, b0 = ia.min() - 1, ib.min() - 1
        na, nb = int(ia.max() - a0 + 2), int(ib.max() - b0 + 2)
        depth = np.full(na * nb, np.inf)
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                np.minimum.at(depth, (ia - a0 + da) * nb + (ib - b0 + db), orng)
        todo = np.flatnonzero(hidden)
        ca, cb, crng = project(cand_pts[todo])
        ja = np.floor(ca / step).astype(np.int64) - a0
        jb = np.floor(cb / step).astype(np.int64) - b0
        inside = (ja >= 0) & (ja < na) & (jb >= 0) & (jb < nb)
        front = np.full(len(todo), np.inf)
        front[inside] = depth[ja[inside] * nb + jb[inside]]
        hidden[todo[~(front < crng - 0.5 * float(h.min()))]] = False
        if not hidden.any():
            break
    out[tuple(cand_idx[hidden].T)] = True
    return out


def with_hidden_band(mask: np.ndarray, grid: Grid, views: np.ndarray, depth_m: float) -> np.ndarray:
    """``mask`` plus the voxels within ``depth_m`` (m) of it that it hides from every view."""
    from scipy.ndimage import distance_transform_edt

    near = distance_transform_edt(~mask, sampling=np.asarray(grid.spacing)) <= depth_m
    return mask | hidden_voxels(mask, grid, views, near & ~mask)


#: The scores kept per rule: the primary surface F1, the paper code's solid F1, Chamfer-L2, F@5mm.
SCORES = ("surface_f1", "solid_f1", "chamfer_l2", "fscore")


def rescore(volume: Volume, gt: GroundTruth) -> dict[str, dict[str, float]]:
    """Per rule: τ (clipped into (0, 1) as ``point_cloud`` requires) and the cloud's scores."""
    out = {}
    for name, rule in RULES.items():
        tau = float(np.clip(rule(volume), 1e-3, 1 - 1e-3))
        s = score_points(point_cloud(volume, tau).points, gt)
        out[name] = {"tau": tau, **{k: s[k] for k in SCORES}}
    return out


def rescore_hidden(volume: Volume, gt: GroundTruth, views: np.ndarray,
                   depths_mm: list[float]) -> dict[str, dict[str, float]]:
    """``otsu+hidden<D>mm`` per depth: the Otsu cloud plus its hidden band (:func:`with_hidden_band`)."""
    tau = float(np.clip(choose_threshold(volume), 1e-3, 1 - 1e-3))
    mask = normalize(volume) >= tau
    lo, h = np.asarray(volume.grid.box_min), np.asarray(volume.grid.spacing)
    out = {}
    for d in depths_mm:
        full = with_hidden_band(mask, volume.grid, views, d / 1000.0)
        s = score_points(lo + (np.argwhere(full) + 0.5) * h, gt)
        out[f"otsu+hidden{d:g}mm"] = {"tau": tau, **{k: s[k] for k in SCORES}}
    return out


#: The scores ``--fog`` prints per extraction (``metrics.score_reconstruction``'s keys).
FOG_SCORES = ("pc_surface_f1", "mesh_surface_f1", "pc_fscore", "pc_chamfer_l2", "mesh_area_ratio")


def rescore_fog(volume: Volume, gt: GroundTruth, sensors: np.ndarray, resolution: float,
                share: float | None) -> dict[str, dict[str, float]]:
    """The product's extraction of ``volume`` (``ridge``) and, when ``share`` is given, the same
    with the fog step at that share (``ridge+fog``), each with :data:`FOG_SCORES` and τ."""
    configs = {"ridge": ExtractConfig()}
    if share is not None:
        configs["ridge+fog"] = ExtractConfig(fog_share=share)
    out = {}
    for name, cfg in configs.items():
        tau, cloud, mesh = extract(volume, cfg, sensors, resolution)
        s = score_reconstruction(cloud.points, mesh, gt)
        out[name] = {"tau": tau, "points": float(len(cloud)), **{k: float(s[k]) for k in FOG_SCORES}}
    return out


def main(argv: list[str] | None = None) -> int:
    from shsas_core.formats.hdf5 import read_survey

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(fid.ROOT / "benchmarks" / "out" / "fidelity"),
                    help="bench_fidelity's results folder (default benchmarks/out/fidelity)")
    ap.add_argument("--profile", default="defaults", help="defaults, paper or dev (default defaults)")
    ap.add_argument("--regimes", help="comma list (default: every stored regime)")
    ap.add_argument("--scenes", help="comma list (default: every stored scene)")
    ap.add_argument("--cache-dir", help="simulated-survey cache (as bench_fidelity.py)")
    ap.add_argument("--hidden-band", metavar="MM,...",
                    help="also score the Otsu cloud plus its hidden band at these depths, mm (module doc)")
    ap.add_argument("--fog", metavar="SHARE", type=float,
                    help="instead: the product's extraction with the fog step off and at this share, for "
                         "the neural methods (module doc)")
    args = ap.parse_args(argv)
    if args.fog is not None and not 0 <= args.fog <= 1:
        ap.error(f"--fog: a share in [0, 1], got {args.fog}")
    if args.fog is not None and args.hidden_band:
        ap.error("--fog and --hidden-band exclude each other")
    try:
        depths = [float(x) for x in args.hidden_band.split(",")] if args.hidden_band else []
    except ValueError:
        ap.error(f"--hidden-band: comma list of depths in mm, got {args.hidden_band!r}")
    if any(not d > 0 for d in depths):
        ap.error(f"--hidden-band: depths must be > 0 mm, got {args.hidden_band!r}")
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
        survey = read_survey(survey_file)
        gt = GroundTruth.from_survey(survey)
        cell = f"{rec['regime']}/{rec['scene']}/seed{rec['seed']}"
        for method in rec.get("methods", {}):
            stored = path.parent / method / f"{method}_volume.npy"
            if not stored.is_file():
                continue
            volume = read_volume_npy(stored)
            if args.fog is not None:
                share = args.fog if REGISTRY[method].neural else None
                for rule, s in rescore_fog(volume, gt, survey.tx, survey.meta.range_resolution, share).items():
                    rows[(cell, method, rule)] = s
                    print(f"{cell:24s} {method:14s} {rule:9s} τ {s['tau']:.3f}  points {s['points']:6.0f}  "
                          + "  ".join(f"{k} {s[k]:.3g}" for k in FOG_SCORES), flush=True)
                continue
            scores = rescore(volume, gt)
            if depths:
                scores |= rescore_hidden(volume, gt, survey.tx[::VIEW_STRIDE], depths)
            for rule, s in scores.items():
                rows[(cell, method, rule)] = s
                print(f"{cell:24s} {method:14s} {rule:9s} τ {s['tau']:.3f}  surface F1 {s['surface_f1']:.3f}  "
                      f"solid F1 {s['solid_f1']:.3f}  Chamfer {s['chamfer_l2']:.2e}  F@5mm {s['fscore']:.3f}",
                      flush=True)
    if not rows:
        print(f"no stored volumes under {Path(args.out) / args.profile}")
        return 1
    if args.fog is not None:
        print_fog_means(rows)
        return 0
    methods = sorted({m for _, m, _ in rows})
    cells = sorted({c for c, _, _ in rows})
    print(f"\nmean over {len(cells)} cell(s): pc surface F1 / solid F1 (paper code) / Chamfer-L2 m² / F@5mm")
    print("| rule | " + " | ".join(fid.LABEL.get(m, m) for m in methods) + " |")
    print("|---|" + "---|" * len(methods))
    for rule in dict.fromkeys(r for _, _, r in rows):
        out = []
        for m in methods:
            sel = [rows[(c, m, rule)] for c in cells if (c, m, rule) in rows]
            out.append(" / ".join([f"{np.mean([s['surface_f1'] for s in sel]):.3f}",
                                   f"{np.mean([s['solid_f1'] for s in sel]):.3f}",
                                   f"{np.mean([s['chamfer_l2'] for s in sel]):.2e}",
                                   f"{np.mean([s['fscore'] for s in sel]):.3f}"]))
        print(f"| {rule} | " + " | ".join(out) + " |")
    return 0


def print_fog_means(rows: dict[tuple[str, str, str], dict[str, float]]) -> None:
    """Per regime, the mean over its cells of each (method, extraction) row of ``--fog``."""
    regimes = sorted({c.split("/")[0] for c, _, _ in rows})
    print("\nmean over the stored scenes: " + " / ".join(FOG_SCORES))
    for regime in regimes:
        print(f"\n{regime}\n| method | extraction | cells | " + " | ".join(FOG_SCORES) + " |")
        print("|---|---|---|" + "---|" * len(FOG_SCORES))
        for method, rule in dict.fromkeys((m, r) for c, m, r in rows if c.startswith(regime + "/")):
            sel = [s for (c, m, r), s in rows.items() if c.startswith(regime + "/") and m == method and r == rule]
            vals = [f"{np.mean([s[k] for s in sel]):.3g}" for k in FOG_SCORES]
            print(f"| {fid.LABEL.get(method, method)} | {rule} | {len(sel)} | " + " | ".join(vals) + " |")


if __name__ == "__main__":
    sys.exit(main())
