"""Does a short neural fit end no worse than the backprojection image it starts from?

The pipeline starts each neural method from the job's backprojection image (distilled into the
field, ``shsas_core.neural.warmstart``) and then fits it to the time-of-flight data. This benchmark runs
that chain, as ``pipeline._fit_neural`` does with the spec defaults, on a small survey and scores
three clouds against the ground truth with the scoreboard's rule (Otsu level, the metrics of
``shsas_core.evaluation.metrics``): the backprojection image, the started field and the fitted field (the
two fields inside the occupancy mask the fit uses, as the pipeline extracts them). It prints
them side by side per scene and seed: the surface F1 (the primary score) with its precision /
recall, the paper code's solid F1, F@5mm, and the fit's data-loss ratio (mean of the last 15
iterations over the first 15). "end ≥ start" and "end ≥ image" are given on both F1s.

The small survey is a circle of ``--heights`` x ``--angles`` pings at 20 dB, scored on a
``--grid`` voxel grid, fitted for ``--iters`` iterations (L = 3, SH-SAS). Scenes: ``bunny``
and ``armadillo`` (as in ``bench_fidelity.py``) and the built-in shapes. The seed is the survey's
and the training's, as in the fidelity benchmark.

``tests/core/neural/test_warmstart.py`` runs :func:`warm_start_case` on the bunny at seed 0 (its
guarantee was measured on the solid F1; the bunny's mesh is open underneath, so its solid
occupancy is its one-voxel surface band, filled only where the band closes).

Usage::

    python benchmarks/bench_warmstart.py                        # bunny and sphere, seeds 0-4
    python benchmarks/bench_warmstart.py --scenes bunny --seeds 0,1,2 --iters 150 --heights 4 --angles 60
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fidelity as fid


@dataclasses.dataclass(frozen=True)
class Case:
    """One small warm-start run: ``metrics.score_points`` of the image's, the started field's and
    the fitted field's point clouds (``surface_f1``, ``solid_f1``, ``fscore``, ...)."""

    scene: str
    seed: int
    image: dict[str, float]
    start: dict[str, float]
    end: dict[str, float]
    loss_ratio: float
    seconds: float


def warm_start_case(source: str, seed: int = 0, heights: int = 6, angles: int = 90, grid: int = 48,
                    iters: int = 300, scene: str = "") -> Case:
    """Simulate ``source`` (a shape name or mesh path), backproject it, start SH-SAS from the
    image as the pipeline does and fit it for ``iters`` iterations at the spec defaults; score
    the image, the started field and the fitted field against the ground truth."""
    import torch

    from shsas_core.data.volume import Grid, Volume
    from shsas_core.evaluation.extract import extract
    from shsas_core.evaluation.metrics import GroundTruth, score_points
    from shsas_core.imaging.backprojection import backproject_survey
    from shsas_core.methods.neural import train_config
    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.fields.occupancy import OccupancyConfig, OccupancyGrid, within
    from shsas_core.neural.fields.volume import field_volume
    from shsas_core.neural.train import coarse_start_levels, fit
    from shsas_core.neural.warmstart import WarmStartConfig, distill
    from shsas_core.signal.deconv import deconvolve, point_spread
    from shsas_core.signal.sources import deconv_config
    from shsas_core.simulation.simulate import simulate_shape
    from shsas_core.spec.job import ReconstructionSpec

    spec = ReconstructionSpec(iters=iters, seed=seed)
    survey = simulate_shape(source, heights=heights, angles=angles, snr_db=20.0, seed=seed)
    s_pd = np.asarray(deconvolve(survey, deconv_config(spec)), dtype=np.complex64)
    box = survey.meta.scene_box
    vox = Grid.over(box, grid)
    image = backproject_survey(survey, vox, s_pd)
    gt = GroundTruth.from_survey(survey)

    def score(volume: Volume) -> dict[str, float]:
        _tau, cloud, _mesh = extract(volume)
        return score_points(cloud.points, gt)

    t0 = time.perf_counter()
    torch.manual_seed(spec.seed)
    fcfg = FieldConfig(sh_degree=spec.sh_degree, scene_box=box, encoding=encoding_preset(spec.encoding))
    field = SHField(fcfg)
    if spec.coarse_to_fine is not None:  # as the pipeline: the start holds the levels the fit starts with
        field.set_active_levels(coarse_start_levels(fcfg.encoding))
    distill(field, image, WarmStartConfig(seed=spec.seed))
    assert spec.occupancy is not None
    occupancy = OccupancyGrid.from_volume(image, OccupancyConfig(level=spec.occupancy))
    model = within(field, occupancy)
    start = score(field_volume(model, vox))
    result = fit(field, survey, s_pd, train_config(spec), psf=point_spread(survey, deconv_config(spec)),
                 occupancy=occupancy)
    end = score(field_volume(model, vox))
    dl = np.asarray(result.data_loss_history, dtype=np.float64)
    k = min(15, len(dl) // 2)
    ratio = float(dl[-k:].mean() / dl[:k].mean()) if k else float("nan")
    return Case(scene or source, seed, score(image), start, end, ratio, time.perf_counter() - t0)


def row(c: Case) -> str:
    def f(s: dict[str, float]) -> str:
        return (f"{s['surface_f1']:.4f} ({s['surface_precision']:.3f}/{s['surface_recall']:.3f}), "
                f"{s['solid_f1']:.4f}, {s['fscore']:.3f}")

    def yes(a: dict[str, float], b: dict[str, float]) -> str:
        return " / ".join("yes" if a[k] >= b[k] else "NO" for k in ("surface_f1", "solid_f1"))

    gain = c.end["surface_f1"] - c.start["surface_f1"]
    return (f"| {c.scene} | {c.seed} | {f(c.image)} | {f(c.start)} | {f(c.end)} | {gain:+.4f} | "
            f"{yes(c.end, c.start)} | {yes(c.end, c.image)} | {c.loss_ratio:.2f} | {c.seconds:.0f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="bunny,sphere", help="comma list: bunny, armadillo or a built-in shape")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="comma list of seeds (survey and training)")
    ap.add_argument("--heights", type=int, default=6)
    ap.add_argument("--angles", type=int, default=90)
    ap.add_argument("--grid", type=int, default=48)
    ap.add_argument("--iters", type=int, default=300)
    ap.add_argument("--meshes", help="folder with bunny.obj and armadillo.obj "
                    "(default $SHSAS_MESH_DIR or ../shared/data/meshes)")
    args = ap.parse_args(argv)
    import torch

    print(f"# {args.heights} x {args.angles} pings, grid {args.grid}, {args.iters} iterations, "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, load {os.getloadavg()[0]:.2f}")
    print("| scene | seed | image: surface F1 (P/R), solid F1, F@5mm | started field | fitted field | "
          "surface F1 fit − start | end ≥ start (surface / solid) | end ≥ image (surface / solid) | "
          "data loss last/first | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    cases = []
    for scene in args.scenes.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            c = warm_start_case(fid.scene_source(scene, fid.mesh_dir(args.meshes)), seed, args.heights, args.angles,
                                args.grid, args.iters, scene=scene)
            cases.append(c)
            print(row(c), flush=True)
    for scene in dict.fromkeys(c.scene for c in cases):
        sel = [c for c in cases if c.scene == scene]

        def mean(stage: str, key: str, sel: list[Case] = sel) -> float:
            return float(np.mean([getattr(c, stage)[key] for c in sel]))

        for key, name in (("surface_f1", "surface F1"), ("solid_f1", "solid F1 (paper code)")):
            print(f"{scene}: {name} end >= start on {sum(c.end[key] >= c.start[key] for c in sel)}/{len(sel)} "
                  f"seeds, end >= image on {sum(c.end[key] >= c.image[key] for c in sel)}/{len(sel)}; mean "
                  f"image / start / end {mean('image', key):.4f} / {mean('start', key):.4f} / {mean('end', key):.4f}")
        print(f"{scene}: mean F@5mm image / start / end {mean('image', 'fscore'):.3f} / "
              f"{mean('start', 'fscore'):.3f} / {mean('end', 'fscore'):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
