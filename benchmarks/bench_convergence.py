"""Does training fit the data? Data-loss reduction and surface concentration on simulated scenes.

For each scene: simulate a 20 dB survey (4 circles x 90 pings), Wiener-deconvolve it, train a
neural field, and print

* the whole-ping data loss (``shsas_core.neural.train.evaluate_data_loss``: every 15th ping, 1024 rays,
  least-squares best scale, so an untrained field is not handicapped by its amplitude) before
  and after training, and their ratio (the goal is >= 10x);
* the surface concentration (``shsas_core.evaluation.metrics.surface_concentration``): mean |σ_DC| within
  1 cm of the true mesh over the mean outside it, on a 48³ grid (1 = flat);
* the mean training data loss of the first 10 and last 100 iterations, and the wall time.

Usage (the figures in docs/notebook/2026-11-lab-notebook.md):

    python benchmarks/bench_convergence.py --scenes sphere --degree 0 --iters 6000 --lr-final 1e-4
    python benchmarks/bench_convergence.py --scenes bunny --degree 0 --iters 12000 --lr-final 1e-4 \\
        --bins 64 --rays 256 --encoding cpu

Prints a table; never asserts.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="sphere,bunny", help="built-in shapes or meshes of ../shared/data/meshes")
    ap.add_argument("--degree", type=int, default=0, help="SH degree L (0 = Reed et al.)")
    ap.add_argument("--iters", type=int, default=6000)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--lr-final", type=float, default=1e-4)
    ap.add_argument("--bins", type=int, default=32)
    ap.add_argument("--rays", type=int, default=128)
    ap.add_argument("--encoding", default="small", choices=["small", "cpu", "paper_gpu"])
    ap.add_argument("--target", default="envelope", choices=["envelope", "coherent"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()

    import numpy as np
    import torch

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from shsas_core.common.progress import TqdmProgress
    from shsas_core.data.volume import Grid
    from shsas_core.evaluation.metrics import surface_concentration
    from shsas_core.neural.fields import SHField
    from shsas_core.neural.fields import encoding_preset as encoding_config
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.fields.volume import field_volume
    from shsas_core.neural.train import TrainConfig, evaluate_data_loss, fit
    from shsas_core.signal.deconv import deconvolve
    from shsas_core.simulation.simulate import simulate_shape

    torch.set_num_threads(args.threads)
    print(f"bench_convergence: L={args.degree} iters={args.iters} lr={args.lr}->{args.lr_final} "
          f"bins={args.bins} rays={args.rays} encoding={args.encoding} target={args.target} "
          f"threads={args.threads} device={args.device} load={os.getloadavg()[0]:.1f}")
    rows = []
    for scene in args.scenes.split(","):
        mesh = str(MESHES / f"{scene}.obj") if (MESHES / f"{scene}.obj").exists() else scene
        survey = simulate_shape(mesh, heights=4, angles=90, snr_db=20.0, seed=0)
        spd = deconvolve(survey)
        pings = np.arange(0, survey.num_pings, 15)
        torch.manual_seed(0)
        field = SHField(FieldConfig(sh_degree=args.degree, encoding=encoding_config(args.encoding),
                                    scene_box=survey.meta.scene_box))
        cfg = TrainConfig(iters=args.iters, lr=args.lr, lr_final=args.lr_final, num_bins=args.bins,
                          num_rays=args.rays, target=args.target, device=args.device, seed=0)

        def measure(field=field, survey=survey, spd=spd, pings=pings) -> tuple[float, float]:
            vol = field_volume(field, Grid.over(survey.meta.scene_box, 48))
            return (evaluate_data_loss(field, survey, spd, pings, target=args.target, num_rays=1024),
                    surface_concentration(vol, survey.gt_vertices, survey.gt_faces, shell=0.01))

        before, c0 = measure()
        t0 = time.perf_counter()
        bar = TqdmProgress()
        res = fit(field, survey, spd, cfg, progress=bar, stage=f"fit {scene}")
        bar.close()
        wall = time.perf_counter() - t0
        after, c1 = measure()
        h = np.asarray(res.data_loss_history)
        rows.append((scene, before, after, before / after, c0, c1, h[:10].mean(), h[-100:].mean(), wall))
    print(f"{'scene':<8}{'loss init':>10}{'loss end':>10}{'ratio':>8}{'conc init':>10}{'conc end':>10}"
          f"{'batch first10':>15}{'batch last100':>15}{'fit s':>8}")
    for r in rows:
        print(f"{r[0]:<8}{r[1]:>10.4f}{r[2]:>10.4f}{r[3]:>7.2f}x{r[4]:>10.2f}{r[5]:>10.2f}{r[6]:>15.4f}"
              f"{r[7]:>15.4f}{r[8]:>8.0f}")


if __name__ == "__main__":
    main()
