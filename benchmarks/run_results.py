"""Experiment runner: the paper's Table 1 protocol at CPU budgets (its figures: docs/notebook/).

For each scene (the Stanford bunny from ../shared/data/meshes and the built-in shapes), simulate
a circular AirSAS-like survey at 20 dB, reconstruct it with backprojection, Reed et al. (L = 0)
and SH-SAS (L = 3) through ``shsas_core.pipeline.job.run`` and score the point cloud and the mesh
with the metrics of shsas_core/evaluation/metrics.py (surface F1 first; the paper code's solid F1 as a
secondary column; the mesh's pieces, area ratio and normal consistency). Then a sparse-view run (20 % of the pings, seeded) and an SH-degree
ablation (L = 1, 2, 3) on the first scene. Prints markdown tables; never asserts.

Usage::

    python benchmarks/run_results.py                       # CPU defaults (takes a while)
    python benchmarks/run_results.py --quick               # tiny budgets, minutes
    python benchmarks/run_results.py --scenes bunny,sphere --iters 2000 --grid 64 --device cuda

Every run writes into ``--out/<experiment>/<scene>/`` and resumes when re-run (finished methods
are skipped), so a long session can be split over several invocations.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from shsas_core.pipeline.job import run  # noqa: E402
from shsas_core.simulation.simulate import simulate_shape  # noqa: E402
from shsas_core.simulation.trajectory import TrajectoryConfig  # noqa: E402
from shsas_core.spec.catalogue import LABELS  # noqa: E402
from shsas_core.spec.job import ReconstructionSpec  # noqa: E402

#: The columns (metric key, header, format): the primary surface F1 first, the paper code's
#: solid F1 as a secondary column, then the mesh's quality (mesh rows only).
METRICS = [("surface_f1", "surface F1 ↑", "{:.3f}"), ("fscore", "F@5mm ↑", "{:.3f}"),
           ("fscore_2_5mm", "F@2.5mm ↑", "{:.3f}"),
           ("chamfer_l2", "Chamfer-L2 (m²) ↓", "{:.3e}"), ("chamfer_l1", "Chamfer-L1 (m) ↓", "{:.3e}"),
           ("solid_f1", "solid F1 (paper code) ↑", "{:.3f}"), ("pieces", "pieces ↓", "{:.0f}"),
           ("area_ratio", "area ratio", "{:.2f}"), ("normal_consistency", "normal cons. ↑", "{:.3f}")]
#: Each method's name in the tables: the method catalogue's label.
LABEL = LABELS


def shared_mesh(name: str) -> str | None:
    for base in (ROOT.parent / "shared", ROOT / "shared", Path(os.environ.get("SHSAS_SHARED", "shared"))):
        p = base / "data" / "meshes" / f"{name}.obj"
        if p.exists():
            return str(p)
    return None


def scene_source(name: str) -> str:
    from shsas_core.simulation.shapes import SHAPES

    if name in SHAPES:
        return name
    p = shared_mesh(name)
    if p is None:
        raise SystemExit(f"scene '{name}': not a built-in shape and not in ../shared/data/meshes")
    return p


def simulate(name: str, args: argparse.Namespace, fraction: float = 1.0):
    traj = TrajectoryConfig(heights=args.heights, angles=args.angles, fraction=fraction, subset_seed=args.seed)
    return simulate_shape(scene_source(name), snr_db=args.snr, seed=args.seed, trajectory=traj)


def spec_for(args: argparse.Namespace, methods: list[str], sh_degree: int = 3) -> ReconstructionSpec:
    return ReconstructionSpec(methods=methods, sh_degree=sh_degree, iters=args.iters, grid=args.grid,
                              device=args.device, seed=args.seed, num_bins=args.bins, num_rays=args.rays,
                              pings_per_batch=args.ppb, lr=args.lr, encoding=args.encoding,
                              target=args.target)


def fmt(v: float | None, f: str) -> str:
    return "–" if v is None or not math.isfinite(v) else f.format(v)


def table(rows: list[tuple[str, str, dict[str, float]]], title: str) -> str:
    """rows: (scene, method label, metrics with pc_/mesh_ keys)."""
    head = "| scene | method | output | " + " | ".join(h for _, h, _ in METRICS) + " |"
    lines = [f"### {title}", "", head, "|" + "---|" * (3 + len(METRICS))]
    for scene, label, m in rows:
        for rep, out in (("pc", "point cloud"), ("mesh", "mesh")):
            cells = " | ".join(fmt(m.get(f"{rep}_{k}"), f) for k, _, f in METRICS)
            lines.append(f"| {scene} | {label} | {out} | {cells} |")
    return "\n".join(lines)


def mean_rows(per_scene: dict[str, dict[str, dict[str, float]]]) -> list[tuple[str, str, dict[str, float]]]:
    methods = sorted({m for d in per_scene.values() for m in d}, key=list(LABEL).index)
    rows = []
    for method in methods:
        keys = {k for d in per_scene.values() for k in d.get(method, {})}
        avg = {}
        for k in keys:
            vals = [d.get(method, {}).get(k) for d in per_scene.values()]
            # undefined for any scene (e.g. an empty point cloud has no Chamfer) -> undefined mean
            avg[k] = sum(vals) / len(vals) if all(v is not None and math.isfinite(v) for v in vals) else None
        rows.append(("mean", LABEL[method], avg))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="bunny,sphere,cube,torus")
    ap.add_argument("--out", default="results_out")
    ap.add_argument("--heights", type=int, default=5)
    ap.add_argument("--angles", type=int, default=120)
    ap.add_argument("--snr", type=float, default=20.0)
    ap.add_argument("--iters", type=int, default=1000)
    ap.add_argument("--grid", type=int, default=48)
    ap.add_argument("--bins", type=int, default=32)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--ppb", type=int, default=1, help="pings per batch")
    ap.add_argument("--lr", type=float, default=3e-3, help="Adam lr (3e-3: best of 1e-3/3e-3 on the envelope target in the demo runs)")
    ap.add_argument("--encoding", default="cpu", choices=["cpu", "small", "paper_gpu"])
    ap.add_argument("--target", default="envelope", choices=["coherent", "envelope"],
                    help="neural data term (default envelope = |s_PD|, the CPU-budget choice; "
                    "coherent = the paper's complex s_PD, see docs/neural.md)")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sparse-fraction", type=float, default=0.2)
    ap.add_argument("--skip", default="", help="comma list of parts to skip: table1,sparse,ablation")
    ap.add_argument("--quick", action="store_true", help="tiny budgets (smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.heights, args.angles, args.iters, args.grid, args.bins, args.rays = 3, 60, 100, 32, 16, 64
    skip = set(filter(None, args.skip.split(",")))
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    out = Path(args.out)
    t_all = time.perf_counter()
    print(f"# shsas results (CPU budgets)\n\nmachine: {platform.platform()}, {platform.processor() or 'cpu'}; "
          f"survey: circular, {args.heights} heights x {args.angles} pings, {args.snr:g} dB; "
          f"grid {args.grid}, {args.iters} iterations, {args.bins} bins x {args.rays} rays x {args.ppb} pings "
          f"per iteration, lr {args.lr:g}, encoding {args.encoding}, target {args.target}, device {args.device}, seed {args.seed}\n",
          flush=True)
    timings: list[str] = []
    per_scene: dict[str, dict[str, dict[str, float]]] = {}
    if "table1" not in skip:
        rows = []
        for name in scenes:
            t = time.perf_counter()
            survey = simulate(name, args)
            res = run(spec_for(args, ["backprojection", "reed", "shsas"]), survey, out / "table1" / name)
            per_scene[name] = res.metrics
            timings.append(f"table1/{name}: {survey.num_pings} pings, " + ", ".join(
                f"{k} {v:.0f} s" for k, v in res.timings.items() if k in ("backprojection", "reed", "shsas", "total"))
                + f" (incl. simulation {time.perf_counter() - t:.0f} s)")
            rows += [(name, LABEL[m], res.metrics[m]) for m in res.metrics]
            print(table([r for r in rows if r[0] == name], f"Table 1, {name}") + "\n", flush=True)
        print(table(mean_rows(per_scene), f"Table 1, mean over {', '.join(scenes)}") + "\n", flush=True)
    first = scenes[0]
    if "sparse" not in skip:
        survey = simulate(first, args, fraction=args.sparse_fraction)
        res = run(spec_for(args, ["backprojection", "reed", "shsas"]), survey, out / "sparse" / first)
        timings.append(f"sparse/{first}: {survey.num_pings} pings, total {res.timings['total']:.0f} s")
        print(table([(first, LABEL[m], res.metrics[m]) for m in res.metrics],
                    f"Sparse views: {first}, {args.sparse_fraction:.0%} of the pings ({survey.num_pings})") + "\n", flush=True)
    if "ablation" not in skip:
        survey = simulate(first, args)
        rows = []
        for L in (1, 2, 3):
            if L == 3 and first in per_scene:  # Table 1's SH-SAS run is the L = 3 point
                m = per_scene[first]["shsas"]
            else:
                res = run(spec_for(args, ["shsas"], sh_degree=L), survey, out / "ablation" / f"{first}_L{L}")
                m = res.metrics["shsas"]
                timings.append(f"ablation/{first} L={L}: total {res.timings['total']:.0f} s")
            rows.append((first, f"SH-SAS L={L}", m))
        print(table(rows, f"SH-degree ablation: {first}") + "\n", flush=True)
    print("timings: " + "; ".join(timings))
    print(f"total wall time {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
