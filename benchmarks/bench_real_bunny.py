"""The real AirSAS bunny end to end: import, (optional) autofocus result, backprojection, rigid
alignment to the reference mesh, aligned Chamfer-L2 (docs/notebook/2026-11-lab-notebook.md, "Real AirSAS bunny").

    python benchmarks/bench_real_bunny.py [--survey FILE.h5] [--grid 64] [--angle-step 2]
        [--level-step 1] [--pictures docs/img] [--backend compiled]

``--survey`` takes a canonical file (e.g. written by ``shsas autofocus``); by default the
deconvolved-ping folder is imported with the default geometry. The pings used are every
``angle-step``-th turntable step of every ``level-step``-th level. Prints one JSON line: the
settings, seconds per stage, the extraction threshold, Chamfer-L2 before and after alignment.
``--volumes DIR`` instead scores every ``*_volume.npy`` of a ``shsas reconstruct`` output
folder (Reed, SH-SAS, backprojection) the same way, with the mesh checks (pieces, area
ratio) of each ``*_mesh.ply``. ``--scoreboard DIR`` is the real-data scoreboard: every method
through the pipeline at the defaults (``--iters``, ``--spec-grid``, ``--methods`` override them)
on every ``--angle-steps`` subset (default 2 and 4: 27,000 and 13,500 pings), each scored so
(the threshold cloud, then the product's own point cloud and mesh moved by its alignment),
with the two halves of the Chamfer distance and wall times, and the real-data goals printed as
PASS / FAIL lines (:func:`goal_checks`, which say why when Reed is not between backprojection and
SH-SAS); the figures go to one JSON record under ``benchmarks/results/``.
``--pictures`` writes the MIPs, the centre slice beside the authors' reference slice, and the
aligned points over the mesh sample. Never asserts: figures are reported, not tested.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.align import aligned_scores
from shsas_core.formats import load_survey
from shsas_core.imaging.backprojection import BackprojectionConfig, backproject_survey
from shsas_core.outputs.export import write_volume_npy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import records

SHARED = Path(__file__).resolve().parents[2] / "shared"
FOLDER = SHARED / "data" / "airsas" / "bunny_20k_deconvolved"
MESH = SHARED / "data" / "meshes" / "bunny.obj"
RESULTS = Path(__file__).resolve().parent / "results"


def pictures(vol: np.ndarray, best, gt_v: np.ndarray, gt_f: np.ndarray, out: Path, tag: str) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    out.mkdir(parents=True, exist_ok=True)
    ext = [-0.125, 0.125, -0.125, 0.125]
    fig, ax = plt.subplots(1, 3, figsize=(10.5, 3.4))
    ax[0].imshow(vol.max(2).T, origin="lower", extent=ext, cmap="magma")
    ax[0].set(title="MIP along z (x, y)", xlabel="x, m", ylabel="y, m")
    ax[1].imshow(vol.max(1).T, origin="lower", extent=[-0.125, 0.125, 0, 0.2], cmap="magma")
    ax[1].set(title="MIP along y (x, z)", xlabel="x, m", ylabel="z, m")
    ax[2].imshow(vol.max(0).T, origin="lower", extent=[-0.125, 0.125, 0, 0.2], cmap="magma")
    ax[2].set(title="MIP along x (y, z)", xlabel="y, m", ylabel="z, m")
    fig.tight_layout()
    a = out / f"real_bunny_{tag}_mips.png"
    fig.savefig(a, dpi=70)
    plt.close(fig)
    fig, ax = plt.subplots(1, 3, figsize=(11, 3.6))
    # horizontal slices through the scene centre (z = 0.1 m, the authors' "center_xy") and lower
    for a_, z in zip(ax[:2], (0.1, 0.05), strict=True):
        k = min(int(z / 0.2 * vol.shape[2]), vol.shape[2] - 1)
        a_.imshow(vol[:, :, k].T, origin="lower", extent=ext, cmap="viridis")
        a_.set(title=f"shsas {tag}: |image| at z = {z:g} m", xlabel="x, m", ylabel="y, m")
    ref = FOLDER / "reference_bp_center_xy.png"
    if ref.is_file():
        ax[2].imshow(plt.imread(ref))
        ax[2].set(title="authors' reference_bp_center_xy.png")
        ax[2].axis("off")
    fig.tight_layout()
    b = out / f"real_bunny_{tag}_slice.png"
    fig.savefig(b, dpi=70)
    plt.close(fig)
    gt = np.asarray(trimesh.Trimesh(gt_v, gt_f, process=False).sample(4000, seed=0))
    fig = plt.figure(figsize=(4.5, 4.2))
    ax3 = fig.add_subplot(111, projection="3d")
    p = best.points[np.random.default_rng(0).choice(len(best.points), min(4000, len(best.points)), replace=False)]
    ax3.scatter(*gt.T, s=0.3, c="grey", alpha=0.4, label="bunny.obj")
    ax3.scatter(*p.T, s=0.6, c="crimson", label="aligned points")
    ax3.set_title(f"aligned ({tag})")
    ax3.legend(loc="upper left", fontsize=7)
    c = out / f"real_bunny_{tag}_aligned.png"
    fig.savefig(c, dpi=70)
    plt.close(fig)
    return [str(a), str(b), str(c)]


#: Room around the reference mesh for the scoring grid of the aligned meshes, m.
GT_BOX_MARGIN = 0.05
#: The mesh scores kept per method (``metrics.score_mesh`` keys).
MESH_KEYS = ("chamfer_l2", "fscore", "surface_f1", "area_ratio", "normal_consistency")


def score_folder(folder: Path, yaw_starts: int) -> list[dict]:
    """Aligned scores of every method's volume in a `shsas reconstruct` output folder (its
    threshold cloud at the rule's τ, :func:`~shsas_core.evaluation.align.aligned_scores`, which
    finds the alignment), and, moved by that alignment, of the files the product writes: its
    ``{method}_pointcloud.ply`` (the ridge; Chamfer-L2 with its halves and the F-scores, keys
    ``product_*``) and its ``{method}_mesh.ply`` (the protocol's mesh scores,
    ``metrics.score_mesh``: Chamfer-L2, F@5mm, surface F1, pieces, area ratio, normal
    consistency, keys ``mesh_*``)."""
    import trimesh

    from shsas_core.data.survey import SceneBox
    from shsas_core.evaluation.metrics import (
        GroundTruth,
        chamfer_l2_parts,
        point_fscores,
        sample_surface,
        score_mesh,
    )
    from shsas_core.outputs.export import read_point_cloud_points

    mesh = trimesh.load(MESH, force="mesh")
    gt_sample = sample_surface(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))
    lo, hi = mesh.bounds
    gt = GroundTruth(np.asarray(mesh.vertices), np.asarray(mesh.faces),
                     SceneBox(min=tuple(lo - GT_BOX_MARGIN), max=tuple(hi + GT_BOX_MARGIN)))
    rows = []
    for f in sorted(folder.glob("*_volume.npy")):
        method = f.name[: -len("_volume.npy")]
        info = json.loads(f.with_suffix(".json").read_text())
        grid = Grid.over(SceneBox(min=tuple(info["box_min"]), max=tuple(info["box_max"])), max(info["shape"]))
        if list(grid.shape) != list(info["shape"]):
            raise SystemExit(f"{f.name}: grid {info['shape']} is not a cubic-voxel grid over its box")
        vol = Volume(grid, np.abs(np.load(f)).astype(np.float32), name=f.stem)
        scores, best = aligned_scores(vol, np.asarray(mesh.vertices), np.asarray(mesh.faces), yaw_starts=yaw_starts)
        row = {"method": method, "volume": f.name, "grid": info["shape"], "start_yaw_deg": best.start_yaw_deg,
               **{k: round(v, 7) for k, v in scores.items()}}
        cloud = folder / f"{method}_pointcloud.ply"
        if cloud.is_file():
            # the cloud the product writes (the ridge), moved by the same alignment
            pts = best.move(read_point_cloud_points(cloud))
            cs = {**chamfer_l2_parts(pts, gt_sample), **point_fscores(pts, gt_sample)}
            row["product_chamfer_l2"] = round(cs["chamfer_l2_accuracy"] + cs["chamfer_l2_completeness"], 7)
            row.update({f"product_{k}": round(float(v), 7) for k, v in cs.items()})
            row["product_points"] = len(pts)
        ply = folder / f"{method}_mesh.ply"
        if ply.is_file():
            m = trimesh.load(ply, force="mesh", process=False)
            v = best.move(m.vertices)
            ms = score_mesh(v, np.asarray(m.faces), gt)
            row.update({f"mesh_{k}": round(float(ms[k]), 7) for k in MESH_KEYS})
            row["mesh_pieces"] = int(ms["pieces"])
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


#: The real-data scoreboard's columns (a row per method and ping subset).
COLUMNS = [["row", "method / pings", ""], ["chamfer_l2", "aligned Chamfer-L2 (m²)", "{:.3e}"],
           ["chamfer_l2_accuracy", "cloud→mesh half", "{:.2e}"],
           ["chamfer_l2_completeness", "mesh→cloud half", "{:.2e}"],
           ["fscore", "F@5mm", "{:.3f}"], ["fscore_precision", "precision", "{:.2f}"],
           ["fscore_recall", "recall", "{:.2f}"], ["fscore_2_5mm", "F@2.5mm", "{:.3f}"],
           ["product_chamfer_l2", "product cloud Chamfer-L2 (m²)", "{:.3e}"],
           ["product_fscore", "product cloud F@5mm", "{:.3f}"],
           ["mesh_chamfer_l2", "mesh Chamfer-L2 (m²)", "{:.3e}"], ["mesh_fscore", "mesh F@5mm", "{:.3f}"],
           ["mesh_surface_f1", "mesh surface F1", "{:.3f}"],
           ["mesh_pieces", "mesh pieces", "{:d}"], ["mesh_area_ratio", "area ratio", "{:.2f}"],
           ["mesh_normal_consistency", "normal cons.", "{:.3f}"],
           ["seconds", "method wall s", "{:.0f}"]]

#: What the real data must show (SH-SAS against backprojection at the defaults).
CHAMFER_RATIO_GOAL = 0.8
FSCORE_MARGIN_GOAL = 0.05
MAX_MESH_PIECES = 3
MAX_NEURAL_SECONDS = 15 * 60


def goal_checks(rows: list[dict]) -> list[str]:
    """PASS/FAIL lines for one ping subset's scored methods (rows of :func:`score_folder`, with
    ``seconds``) against the real-data goals above, on the point clouds and, where scored, on
    the meshes. Where Reed is not between backprojection and SH-SAS, the line says why from the
    Chamfer halves and the precision and recall: which of stray points and missed surface puts it
    outside."""
    by = {r["method"]: r for r in rows}
    bp, reed, sh = by.get("backprojection"), by.get("reed"), by.get("shsas")
    lines: list[str] = []

    def line(ok: bool, text: str) -> None:
        lines.append(f"{'PASS' if ok else 'FAIL'} {text}")

    for prefix, what in (("", ""), ("product_", " (product clouds)"), ("mesh_", " (meshes)")):
        if not (bp and sh and bp.get(f"{prefix}chamfer_l2") and sh.get(f"{prefix}chamfer_l2") is not None):
            continue
        ratio = sh[f"{prefix}chamfer_l2"] / bp[f"{prefix}chamfer_l2"]
        line(ratio <= CHAMFER_RATIO_GOAL,
             f"SH-SAS Chamfer-L2{what} {ratio:.2f} x backprojection's (goal <= {CHAMFER_RATIO_GOAL})")
        margin = sh[f"{prefix}fscore"] - bp[f"{prefix}fscore"]
        line(margin >= FSCORE_MARGIN_GOAL,
             f"SH-SAS F@5mm{what} {margin:+.3f} over backprojection (goal >= +{FSCORE_MARGIN_GOAL})")
    if sh and "mesh_pieces" in sh:
        line(sh["mesh_pieces"] <= MAX_MESH_PIECES, f"SH-SAS mesh {sh['mesh_pieces']} piece(s) (goal <= {MAX_MESH_PIECES})")
    for name, r in (("Reed", reed), ("SH-SAS", sh)):
        if r and r.get("seconds") is not None:
            line(r["seconds"] <= MAX_NEURAL_SECONDS, f"{name} {r['seconds']:.0f} s (goal <= {MAX_NEURAL_SECONDS} s)")
    if bp and sh and reed:
        for key, label, better in (("chamfer_l2", "Chamfer-L2", min), ("fscore", "F@5mm", max)):
            lo, hi = sorted((bp[key], sh[key]))
            if lo <= reed[key] <= hi:
                line(True, f"Reed between backprojection and SH-SAS on {label} ({reed[key]:.3g})")
                continue
            where = "the best" if better(reed[key], bp[key], sh[key]) == reed[key] else "the worst"
            line(False, f"Reed not between on {label}: it has {where} ({reed[key]:.3g}; backprojection "
                 f"{bp[key]:.3g}, SH-SAS {sh[key]:.3g}). Why: {_why(reed, sh)}")
    return lines


def _why(reed: dict, sh: dict) -> str:
    """Reed against SH-SAS by the Chamfer halves and the F@5mm precision and recall."""
    def cmp(a: float, b: float, more: str, less: str) -> str:
        return more if a < b else less

    acc = cmp(reed["chamfer_l2_accuracy"], sh["chamfer_l2_accuracy"], "fewer", "more")
    comp = cmp(reed["chamfer_l2_completeness"], sh["chamfer_l2_completeness"], "less", "more")
    return (f"against SH-SAS, Reed's cloud has {acc} stray points (cloud->mesh half "
            f"{reed['chamfer_l2_accuracy']:.2e} against {sh['chamfer_l2_accuracy']:.2e} m², precision "
            f"{reed['fscore_precision']:.2f} against {sh['fscore_precision']:.2f}) and misses {comp} of the "
            f"surface (mesh->cloud half {reed['chamfer_l2_completeness']:.2e} against "
            f"{sh['chamfer_l2_completeness']:.2e} m², recall {reed['fscore_recall']:.2f} against "
            f"{sh['fscore_recall']:.2f})")


def board_rows(board: dict) -> list[dict]:
    """The scoreboard's table rows: one per method of every ping subset."""
    return [{"row": f"{m['method']} / {sub['pings']}", **{k: m.get(k) for k, _, _ in COLUMNS[1:]}}
            for sub in board["subsets"] for m in sub["methods"]]


def write_board_record(board: dict, load_info: dict) -> Path:
    """The run as a result record (benchmarks/records.py), for docs/results.md's scoreboard."""
    steps = ",".join(str(s["angle_step"]) for s in board["subsets"])
    # a run of some of the methods is its own record (runs of other methods do not overwrite it)
    methods = board.get("overrides", {}).get("methods")
    changed = {k: v for k, v in board.get("overrides", {}).items() if k != "methods"}
    # ... and so is a run away from the defaults (an A/B arm must not overwrite the scoreboard's row)
    name = (f"real-bunny-steps{steps}" + ("-" + "-".join(methods) if methods else "")
            + records.override_suffix(changed))
    who = ", ".join(methods) if methods else "every method"
    budget = "the defaults" + (" but " + ", ".join(f"{k} {v}" for k, v in changed.items()) if changed else "")
    rec = records.make_record(
        "real_bunny", name, f"Real AirSAS bunny: {who} at {budget}, aligned to the mesh (rigid, scale fixed)", " ".join(["python benchmarks/bench_real_bunny.py", *sys.argv[1:]]),
        COLUMNS, board_rows(board), machine_info=records.machine(), load_info=load_info,
        notes=f"spec overrides: {board.get('overrides') or 'none'}; torch threads {board.get('threads')}"
        + "".join(f"; {sub['pings']} pings: " + "; ".join(sub.get("checks", [])) for sub in board["subsets"]
                  if sub.get("checks")))
    return records.write_record(rec)


def _stage_log(t0: float):
    """A pipeline progress callback that prints each new stage (warm start, fit, ...) with the
    seconds since ``t0`` to stderr: where a long run's time goes."""
    last: list[str] = [""]

    def progress(fraction: float, stage: str, metrics: dict) -> None:
        if stage != last[0]:
            last[0] = stage
            print(f"[{time.perf_counter() - t0:8.1f} s] {stage}", file=sys.stderr, flush=True)

    return progress


def scoreboard(out: Path, angle_steps: list[int], overrides: dict, yaw_starts: int) -> dict:
    """Every method through the pipeline (the defaults, but for ``overrides``) on every
    ``angle_step``-th turntable step of every level, each scored by :func:`score_folder`."""
    from shsas_core.pipeline.job import run as run_pipeline
    from shsas_core.spec.job import ReconstructionSpec

    spec = ReconstructionSpec(**overrides)
    full = load_survey(FOLDER)
    per = int(full.meta.attrs.get("pings_per_level", 360))
    board: dict = {"spec": spec.model_dump(mode="json"), "subsets": []}
    for step in angle_steps:
        idx = np.arange(full.num_pings).reshape(-1, per)[:, ::step].ravel()
        t = time.perf_counter()
        res = run_pipeline(spec, full.subset(idx), out / f"angle_step_{step}", progress=_stage_log(t))
        wall = time.perf_counter() - t
        rows = score_folder(out / f"angle_step_{step}", yaw_starts)
        for r in rows:
            r["seconds"] = res.metrics.get(r["method"], {}).get("seconds")
        checks = goal_checks(rows)
        for c in checks:
            print(f"{len(idx)} pings: {c}", flush=True)
        board["subsets"].append({"angle_step": step, "pings": len(idx), "wall_s": round(wall, 1),
                                 "timings": res.timings, "device": res.device, "methods": rows,
                                 "checks": checks})
    return board


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--survey", default=str(FOLDER))
    ap.add_argument("--grid", type=int, default=64, help="voxels along the box's longest axis")
    ap.add_argument("--angle-step", type=int, default=2)
    ap.add_argument("--level-step", type=int, default=1)
    ap.add_argument("--backend", default="auto", choices=["auto", "compiled", "eager"])
    ap.add_argument("--yaw-starts", type=int, default=12)
    ap.add_argument("--pictures", default=None, help="folder for the PNGs")
    ap.add_argument("--tag", default="bp")
    ap.add_argument("--save-volume", default=None, help="write |image| here (.npy + .json grid sidecar, the reconstruct volume format)")
    ap.add_argument("--volumes", default=None,
                    help="score the *_volume.npy of a `shsas reconstruct` output folder instead (one line each)")
    ap.add_argument("--scoreboard", default=None, metavar="DIR",
                    help="run every method at the defaults through the pipeline into DIR, on each --angle-steps "
                    "subset, score them and write a JSON record under benchmarks/results/")
    ap.add_argument("--angle-steps", default="2,4", help="scoreboard subsets: every k-th turntable step")
    ap.add_argument("--methods", default=None, help="scoreboard: methods (default: all)")
    ap.add_argument("--iters", type=int, default=None, help="scoreboard: override the default iterations")
    ap.add_argument("--spec-grid", type=int, default=None, help="scoreboard: override the default grid")
    ap.add_argument("--spec", default=None, metavar="JSON",
                    help='scoreboard: override any spec field, e.g. \'{"normal_window": 1}\' (named in the record)')
    args = ap.parse_args()
    import torch
    import trimesh

    if args.volumes:
        score_folder(Path(args.volumes), args.yaw_starts)
        return
    if args.scoreboard:
        overrides: dict = {}
        if args.methods:
            overrides["methods"] = args.methods.split(",")
        if args.iters:
            overrides["iters"] = args.iters
        if args.spec_grid:
            overrides["grid"] = args.spec_grid
        if args.spec:
            overrides.update(json.loads(args.spec))
        load_info = records.load()
        board = scoreboard(Path(args.scoreboard), [int(k) for k in args.angle_steps.split(",")], overrides,
                           args.yaw_starts)
        board["overrides"] = overrides
        board["threads"] = torch.get_num_threads()
        print(json.dumps({"record": str(write_board_record(board, load_info))}))
        return

    t = time.perf_counter()
    s = load_survey(args.survey)
    t_load = time.perf_counter() - t
    per = int(s.meta.attrs.get("pings_per_level", 360))
    levels = s.num_pings // per
    idx = np.arange(s.num_pings).reshape(levels, per)[:: args.level_step, :: args.angle_step].ravel()
    sub = s.subset(idx)
    grid = Grid.over(sub.meta.scene_box, args.grid)
    t = time.perf_counter()
    vol = backproject_survey(sub, grid, sub.samples, config=BackprojectionConfig(backend=args.backend))
    t_bp = time.perf_counter() - t
    mag = Volume(grid, np.abs(vol.values).astype(np.float32), name="backprojection")
    if args.save_volume:
        write_volume_npy(mag, args.save_volume)
    mesh = trimesh.load(MESH, force="mesh")
    t = time.perf_counter()
    scores, best = aligned_scores(mag, np.asarray(mesh.vertices), np.asarray(mesh.faces), yaw_starts=args.yaw_starts)
    t_align = time.perf_counter() - t
    out = {"survey": Path(args.survey).name, "autofocus": "autofocus" in s.meta.attrs,
           "sound_speed": s.meta.sound_speed, "pings": len(idx), "grid": list(grid.shape),
           "angle_step": args.angle_step, "level_step": args.level_step,
           "seconds": {"load": round(t_load, 1), "backprojection": round(t_bp, 1), "align": round(t_align, 1)},
           **{k: (round(v, 7) if isinstance(v, float) else v) for k, v in scores.items()},
           "start_yaw_deg": best.start_yaw_deg, "threads": torch.get_num_threads(),
           "cpu": platform.processor() or platform.machine()}
    if args.pictures:
        out["pictures"] = pictures(mag.values, best, np.asarray(mesh.vertices), np.asarray(mesh.faces),
                                   Path(args.pictures), args.tag)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
