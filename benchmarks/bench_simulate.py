"""Throughput of the simulator on the Stanford bunny (prints figures, asserts nothing).

Default: 3,600 pings (10 heights x 360 angles). ``--full``: the paper-scale 54,000-ping survey
(150 heights x 360 angles, AirSAS 5 mm steps) with peak resident memory. ``--accuracy``: the
fractional-delay error against direct Fourier synthesis for several upsampling factors, and
the matched-filter peak error of random point geometries.

    PYTHONPATH=. python benchmarks/bench_simulate.py [--full] [--accuracy] [--mesh PATH] [--write OUT.h5]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np


def find_bunny() -> Path:
    here = Path(__file__).resolve().parents[1]
    for c in (here.parent / "shared", here / "shared", Path(os.environ.get("SHSAS_SHARED", "shared"))):
        p = c / "data" / "meshes" / "bunny.obj"
        if p.exists():
            return p
    sys.exit("bunny.obj not found: pass --mesh PATH")


def accuracy() -> None:
    """Print the delay accuracy figures quoted in docs/simulation.md."""
    from scipy import signal as ssig

    from shsas_core.data.pulse import lfm_pulse
    from shsas_core.simulation.scatterers import Scatterers
    from shsas_core.simulation.simulate import SimulationConfig, TrajectoryConfig, simulate

    c, fs = 343.0, 100e3
    pulse = lfm_pulse(10e3, 30e3, 1e-3, fs)
    x = np.array([[0.013, -0.021, 0.077]])
    tx, rx = np.array([[0.7, 0.3, 0.4]]), np.array([[0.71, 0.31, 0.36]])
    print("fractional delay vs direct Fourier synthesis (max |error| / peak):")
    for u in (4, 8, 16, 32, 64):
        cfg = SimulationConfig(trajectory=TrajectoryConfig(kind="explicit", tx=tx, rx=rx),
                               snr_db=None, upsample=u)
        s = simulate(None, cfg, scatterers=Scatterers(points=x))
        d = ((np.linalg.norm(x - tx) + np.linalg.norm(x - rx)) / c - s.t0[0]) * fs
        nref = 8192
        k = np.fft.rfftfreq(nref) * nref
        ref = np.fft.irfft(np.fft.rfft(pulse, nref) * np.exp(-2j * np.pi * k * d / nref), nref)
        ref = ref[: s.num_samples]
        print(f"  upsample {u:2d}: {np.max(np.abs(s.samples[0] - ref)) / np.max(np.abs(ref)):.2e}")
    rng = np.random.default_rng(1)
    n = 200
    ang, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.1, 0.8, n)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), z], 1)
    rx = np.stack([0.863 * np.cos(ang), 0.863 * np.sin(ang), z - 0.038], 1)
    x = np.array([[0.02, -0.03, 0.1]])
    cfg = SimulationConfig(trajectory=TrajectoryConfig(kind="explicit", tx=tx, rx=rx), snr_db=None)
    s = simulate(None, cfg, scatterers=Scatterers(points=x))
    want = ((np.linalg.norm(x - tx, axis=1) + np.linalg.norm(x - rx, axis=1)) / c - s.t0) * fs
    err = []
    for i in range(n):
        env = np.abs(ssig.hilbert(ssig.correlate(s.samples[i].astype(np.float64), pulse, "full")))
        k = int(np.argmax(env))
        a, b, cc = env[k - 1:k + 2]
        err.append(k + 0.5 * (a - cc) / (a - 2 * b + cc) - (len(pulse) - 1) - want[i])
    err = np.abs(err)
    print(f"matched-filter peak vs (|x-tx|+|x-rx|)/c over {n} geometries (upsample 8): "
          f"max {err.max():.4f} samples, mean {err.mean():.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="54,000 pings (150 x 360) instead of 3,600")
    ap.add_argument("--mesh", default=None, help="mesh file (default: shared bunny.obj)")
    ap.add_argument("--heights", type=int, default=None)
    ap.add_argument("--angles", type=int, default=360)
    ap.add_argument("--write", default=None, help="also write the survey here and time it")
    ap.add_argument("--accuracy", action="store_true", help="print delay accuracy figures and exit")
    args = ap.parse_args()
    if args.accuracy:
        accuracy()
        return

    import trimesh

    from shsas_core.simulation.shapes import load_mesh
    from shsas_core.simulation.simulate import SimulationConfig, TrajectoryConfig, simulate

    mesh = load_mesh(args.mesh or find_bunny())
    heights = args.heights or (150 if args.full else 10)
    # --full follows AirSAS: 5 mm steps from 0.11 m (0.11..0.855 m); otherwise spread over 0.11..0.86
    traj = TrajectoryConfig(heights=heights, angles=args.angles,
                            height_step=0.005 if args.full else None)
    cfg = SimulationConfig(trajectory=traj, snr_db=20.0, seed=0)
    n = heights * args.angles
    print(f"mesh: {len(mesh.faces)} faces, area {mesh.area:.4f} m²; pings: {n} "
          f"({heights} x {args.angles}); ray backend: {'embree' if trimesh.ray.has_embree else 'triangle'}")
    t, cpu = time.perf_counter(), time.process_time()
    s = simulate(mesh, cfg)
    dt, cpu = time.perf_counter() - t, time.process_time() - cpu
    a = s.meta.attrs
    pairs = a["num_scatterers"] * n
    print(f"survey: {s.num_pings} x {s.num_samples} samples, {a['num_scatterers']} surface points "
          f"(mean spacing {a['mean_spacing_m'] * 1e3:.2f} mm)")
    print(f"time: {dt:.1f} s   pings/s: {n / dt:.0f}   point-ping pairs/s: {pairs / dt / 1e6:.2f} M   "
          f"visible contributions/s: {a['visible_contributions'] / dt / 1e6:.2f} M "
          f"({a['visible_contributions'] / pairs:.1%} of pairs visible)")
    # CPU time (all threads) is less sensitive than wall time to other jobs on a shared machine
    print(f"cpu time: {cpu:.1f} s (all threads)   load average now: {os.getloadavg()[0]:.1f}")
    if args.write:
        t = time.perf_counter()
        from shsas_core.formats.hdf5 import write_survey

        write_survey(s, args.write)
        print(f"write: {time.perf_counter() - t:.1f} s -> {args.write}")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(f"peak RSS: {rss:.0f} MiB   samples array: {s.samples.nbytes / 2**20:.0f} MiB   "
          f"finite: {bool(np.all(np.isfinite(s.samples)))}")


if __name__ == "__main__":
    main()
