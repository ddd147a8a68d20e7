"""Old against new extraction of the same backprojection image: points, mesh pieces, area, NC, F@5mm, time.

For each scene a small circular survey is simulated (``--heights`` x ``--angles`` pings, 20 dB),
deconvolved and backprojected onto a ``--grid`` voxel grid over the scene box; then the image is
extracted three ways:

* old: the paper's extraction (Otsu level, every voxel at or above it, marching cubes at it):
  ``ExtractConfig(surface="threshold", mesher="marching_cubes")``;
* fine-n: the default but with the ridge points' normals taken at the ridge's own smoothing
  (``normal_smoothing = smoothing``, the default before the normals came from a coarser one);
* new: the default (ridge points kept by the local-contrast test, normals toward the
  transmitters that see each point, screened Poisson without the range sidelobes, trimmed and
  simplified; its scales from the survey's range resolution, passed as ``resolution``).

Columns: points in the cloud; pieces = connected mesh components holding 95 % of its area; area =
mesh area / ground-truth area; NC = the mesh's normal consistency
(``shsas_core.evaluation.metrics.mesh_quality``, the mesh check asks >= 0.85); F@5mm of the point
cloud and of the mesh (20,000 area-weighted points of it) against the ground-truth surface sample
(``shsas_core.evaluation.metrics.fscore``); seconds of the extraction alone. Never asserts.

Usage::

    python benchmarks/bench_extract.py                      # bunny and sphere, 10 x 90 pings, 128³
    python benchmarks/bench_extract.py --scenes bunny --grid 96 --heights 6 --angles 60
    python benchmarks/bench_extract.py --record             # also write benchmarks/results/extract-<scene>.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fidelity as fid
import records

#: The scoreboard's names of the two extractions.
LABELS = {"old": "paper (Otsu + marching cubes)", "fine-n": "default, normals at the ridge's smoothing",
          "new": "default (ridge + Poisson)"}
COLUMNS = (("extraction", "extraction", ""), ("tau", "τ (Otsu)", "{:.3f}"), ("points", "points", "{:,.0f}"),
           ("faces", "faces", "{:,.0f}"), ("pieces", "pieces (95 % area)", "{:.0f}"),
           ("area", "area / GT", "{:.2f}"), ("nc", "normal consistency", "{:.3f}"),
           ("f5_cloud", "F@5mm cloud", "{:.3f}"),
           ("f5_mesh", "F@5mm mesh", "{:.3f}"), ("seconds", "s", "{:.1f}"))


def pieces95(mesh) -> int:
    """Connected components holding 95 % of the mesh's area (0 for an empty mesh)."""
    if len(mesh.faces) == 0:
        return 0
    areas = np.sort([p.area for p in mesh.split(only_watertight=False)])[::-1]
    return int(np.searchsorted(np.cumsum(areas), 0.95 * areas.sum()) + 1)


def run_scene(source: str, heights: int, angles: int, grid: int, seed: int) -> list[dict[str, float | str]]:
    """Simulate, backproject and extract ``source`` each way; one row per extraction."""
    from shsas_core.data.volume import Grid
    from shsas_core.evaluation.extract import ExtractConfig, extract
    from shsas_core.evaluation.metrics import GroundTruth, fscore, mesh_quality, sample_surface
    from shsas_core.imaging.backprojection import backproject_survey
    from shsas_core.signal.deconv import deconvolve
    from shsas_core.signal.sources import deconv_config
    from shsas_core.simulation.simulate import simulate_shape
    from shsas_core.spec.job import ReconstructionSpec

    survey = simulate_shape(source, heights=heights, angles=angles, snr_db=20.0, seed=seed)
    s_pd = np.asarray(deconvolve(survey, deconv_config(ReconstructionSpec())), dtype=np.complex64)
    vox = Grid.over(survey.meta.scene_box, grid)
    image = backproject_survey(survey, vox, s_pd)
    gt = survey.ground_truth_mesh()
    gt_pts = sample_surface(np.asarray(gt.vertices), np.asarray(gt.faces))
    truth = GroundTruth(np.asarray(gt.vertices), np.asarray(gt.faces), survey.meta.scene_box)
    rows = []
    default = ExtractConfig()
    for name, cfg in (("old", ExtractConfig(surface="threshold", mesher="marching_cubes")),
                      ("fine-n", ExtractConfig(normal_smoothing=default.smoothing)),
                      ("new", default)):
        t0 = time.perf_counter()
        tau, cloud, mesh = extract(image, cfg, sensors=survey.tx, resolution=survey.meta.range_resolution)
        seconds = time.perf_counter() - t0
        mesh_pts = (sample_surface(np.asarray(mesh.vertices), np.asarray(mesh.faces))
                    if len(mesh.faces) else np.zeros((0, 3)))
        rows.append({
            "extraction": name, "tau": tau, "points": float(len(cloud)), "faces": float(len(mesh.faces)),
            "pieces": float(pieces95(mesh)), "area": float(mesh.area / gt.area),
            "nc": mesh_quality(mesh.vertices, mesh.faces, truth)["normal_consistency"] if len(mesh.faces) else 0.0,
            "f5_cloud": fscore(cloud.points, gt_pts)["fscore"] if len(cloud) else 0.0,
            "f5_mesh": fscore(mesh_pts, gt_pts)["fscore"] if len(mesh_pts) else 0.0,
            "seconds": seconds,
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="bunny,sphere")
    ap.add_argument("--heights", type=int, default=10)
    ap.add_argument("--angles", type=int, default=90)
    ap.add_argument("--grid", type=int, default=128, help="voxels along the longest scene-box axis")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--meshes", default=None, help="folder of bunny.obj etc. (default ../shared/data/meshes)")
    ap.add_argument("--record", action="store_true",
                    help="write each scene's figures as a result record (benchmarks/results/extract-<scene>.json)")
    args = ap.parse_args()
    machine, load = records.machine(), records.load()
    meshes = fid.mesh_dir(args.meshes)
    print(f"{args.heights} x {args.angles} pings, 20 dB, grid {args.grid} (longest axis), seed {args.seed}")
    print(f"{'scene':8s} {'extraction':10s} {'tau':>6s} {'points':>8s} {'faces':>8s} {'pieces':>6s} "
          f"{'area':>6s} {'NC':>6s} {'F@5 pc':>7s} {'F@5 mesh':>8s} {'s':>6s}")
    for scene in args.scenes.split(","):
        rows = run_scene(fid.scene_source(scene, meshes), args.heights, args.angles, args.grid, args.seed)
        for r in rows:
            print(f"{scene:8s} {r['extraction']:10s} {r['tau']:6.3f} {r['points']:8.0f} {r['faces']:8.0f} "
                  f"{r['pieces']:6.0f} {r['area']:6.2f} {r['nc']:6.3f} {r['f5_cloud']:7.3f} {r['f5_mesh']:8.3f} "
                  f"{r['seconds']:6.1f}", flush=True)
        if args.record:
            default = (args.heights, args.angles, args.grid, args.seed) == (10, 90, 128, 0)
            name = f"extract-{scene}" if default else \
                f"extract-{scene}-{args.heights}x{args.angles}-grid{args.grid}-seed{args.seed}"
            record = records.make_record(
                "extract", name,
                f"Extraction of one backprojection image, paper vs default: {scene} ({args.heights} x "
                f"{args.angles} pings, 20 dB, grid {args.grid}, seed {args.seed})",
                "python " + " ".join(["benchmarks/bench_extract.py", *sys.argv[1:]]), COLUMNS,
                [{**r, "extraction": LABELS[str(r["extraction"])]} for r in rows],
                machine_info=machine, load_info=load, scene=scene, protocol="surface")
            print(f"record: {records.write_record(record)}", flush=True)


if __name__ == "__main__":
    main()
