"""The real AirSAS bunny end to end: import, (optional) autofocus result, backprojection, rigid
alignment to the reference mesh, aligned Chamfer-L2 (docs/notebook/2026-11-lab-notebook.md, "Real AirSAS bunny").

    python benchmarks/bench_real_bunny.py [--survey FILE.h5] [--grid 64] [--angle-step 2]
        [--level-step 1] [--pictures docs/img] [--backend compiled]

``--survey`` takes a canonical file (e.g. written by ``shsas autofocus``); by default the
deconvolved-ping folder is imported with the default geometry. The pings used are every
``angle-step``-th turntable step of every ``level-step``-th level. Prints one JSON line: the
settings, seconds per stage, the extraction threshold, Chamfer-L2 before and after alignment.
``--volumes DIR`` instead scores every ``*_volume.npy`` of a ``shsas reconstruct`` output
folder (Reed, SH-SAS, backprojection) the same way. ``--pictures`` writes the MIPs, the centre slice beside the authors' reference slice, and the
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

SHARED = Path(__file__).resolve().parents[2] / "shared"
FOLDER = SHARED / "data" / "airsas" / "bunny_20k_deconvolved"
MESH = SHARED / "data" / "meshes" / "bunny.obj"


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


def score_folder(folder: Path, yaw_starts: int) -> None:
    """Aligned scores of every method's volume in a `shsas reconstruct` output folder."""
    import trimesh

    from shsas_core.data.survey import SceneBox

    mesh = trimesh.load(MESH, force="mesh")
    for f in sorted(folder.glob("*_volume.npy")):
        info = json.loads(f.with_suffix(".json").read_text())
        grid = Grid.over(SceneBox(min=tuple(info["box_min"]), max=tuple(info["box_max"])), max(info["shape"]))
        if list(grid.shape) != list(info["shape"]):
            raise SystemExit(f"{f.name}: grid {info['shape']} is not a cubic-voxel grid over its box")
        vol = Volume(grid, np.abs(np.load(f)).astype(np.float32), name=f.stem)
        scores, best = aligned_scores(vol, np.asarray(mesh.vertices), np.asarray(mesh.faces), yaw_starts=yaw_starts)
        print(json.dumps({"volume": f.name, "grid": info["shape"], "start_yaw_deg": best.start_yaw_deg,
                          **{k: round(v, 7) for k, v in scores.items()}}), flush=True)


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
    args = ap.parse_args()
    import torch
    import trimesh

    if args.volumes:
        score_folder(Path(args.volumes), args.yaw_starts)
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
