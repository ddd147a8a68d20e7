"""Throughput of the simulator on the Stanford bunny (prints figures, asserts nothing).

Default: 3,600 pings (10 heights x 360 angles). ``--full``: the paper-scale 54,000-ping survey
(150 heights x 360 angles, AirSAS 5 mm steps) with peak resident memory.

    PYTHONPATH=. python benchmarks/bench_simulate.py [--full] [--mesh PATH] [--write OUT.h5]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np


def find_bunny() -> Path:
    here = Path(__file__).resolve().parents[1]
    for c in (here.parent / "shared", here / "shared", Path("/work/shared")):
        p = c / "data" / "meshes" / "bunny.obj"
        if p.exists():
            return p
    sys.exit("bunny.obj not found: pass --mesh PATH")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="54,000 pings (150 x 360) instead of 3,600")
    ap.add_argument("--mesh", default=None, help="mesh file (default: shared bunny.obj)")
    ap.add_argument("--heights", type=int, default=None)
    ap.add_argument("--angles", type=int, default=360)
    ap.add_argument("--write", default=None, help="also write the survey here and time it")
    args = ap.parse_args()

    import trimesh

    from shsas_core.shapes import load_mesh
    from shsas_core.simulate import SimulationConfig, TrajectoryConfig, simulate

    mesh = load_mesh(args.mesh or find_bunny())
    heights = args.heights or (150 if args.full else 10)
    # --full follows AirSAS: 5 mm steps from 0.11 m (0.11..0.855 m); otherwise spread over 0.11..0.86
    traj = TrajectoryConfig(heights=heights, angles=args.angles,
                            height_step=0.005 if args.full else None)
    cfg = SimulationConfig(trajectory=traj, snr_db=20.0, seed=0)
    n = heights * args.angles
    print(f"mesh: {len(mesh.faces)} faces, area {mesh.area:.4f} m²; pings: {n} "
          f"({heights} x {args.angles}); ray backend: {'embree' if trimesh.ray.has_embree else 'triangle'}")
    t = time.perf_counter()
    s = simulate(mesh, cfg)
    dt = time.perf_counter() - t
    a = s.meta.attrs
    pairs = a["num_scatterers"] * n
    print(f"survey: {s.num_pings} x {s.num_samples} samples, {a['num_scatterers']} surface points "
          f"(mean spacing {a['mean_spacing_m'] * 1e3:.2f} mm)")
    print(f"time: {dt:.1f} s   pings/s: {n / dt:.0f}   point-ping pairs/s: {pairs / dt / 1e6:.2f} M   "
          f"visible contributions/s: {a['visible_contributions'] / dt / 1e6:.2f} M "
          f"({a['visible_contributions'] / pairs:.1%} of pairs visible)")
    if args.write:
        t = time.perf_counter()
        from shsas_core.io import write_survey

        write_survey(s, args.write)
        print(f"write: {time.perf_counter() - t:.1f} s -> {args.write}")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(f"peak RSS: {rss:.0f} MiB   samples array: {s.samples.nbytes / 2**20:.0f} MiB   "
          f"finite: {bool(np.all(np.isfinite(s.samples)))}")


if __name__ == "__main__":
    main()
