"""Backprojection throughput: shsas kernel vs a plain PyTorch reference, side by side.

Prints voxel-pings per second (one voxel-ping = one ping's sample added into one voxel) for

* ``reference``: plain PyTorch — broadcast (voxels x pings) distances, gather, interpolate, sum
  (the approach of the public baseline; :mod:`shsas_core.imaging._backprojection_reference`),
* ``eager``: the shsas block kernel run op by op,
* ``compiled``: the same kernel through ``torch.compile`` (compile time printed separately),

plus the largest relative difference of each from the reference. ``--full`` times the
AirSAS-scale case (150 x 150 x 120 voxels x 43,200 pings) with peak memory; without it that case
is extrapolated from a measured subset of its pings and labelled as such.

    python benchmarks/bench_backprojection.py [--device cpu|cuda] [--grid 48] [--pings 256]
        [--no-phase] [--full] [--repeats 3] [--record]

``--record`` writes the figures as a result record, ``benchmarks/results/backprojection-<device>[-full].json``
(the scoreboard's source).

Never asserts: speed is reported, not tested.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import resource
import sys
import time
import types

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from shsas_core.imaging._backprojection_reference import reference_backproject
from shsas_core.imaging.backprojection import BackprojectionConfig, backproject

FS, C, FC = 100e3, 343.0, 20e3
RECORD_COLUMNS = (("case", "case", ""), ("method", "implementation", ""), ("seconds", "s", "{:.3f}"),
                  ("rate", "M voxel-pings/s", "{:,.1f}"), ("speedup", "vs reference", "{:.1f}x"),
                  ("max_rel_diff", "max rel. diff", "{:.1e}"), ("peak_rss_gb", "peak RSS GB", "{:.2f}"),
                  ("peak_gpu_gb", "peak GPU GB", "{:.2f}"))


def records_module() -> types.ModuleType:
    """``benchmarks/records.py`` (imported on demand: the benchmarks folder is no package)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import records

    return records


def case(n_pings: int, grid: tuple[int, int, int], samples: int, seed: int = 0):
    """Circular AirSAS-like geometry around a 0.3 m box; random complex signals (the speed does
    not depend on their content)."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0, 2 * np.pi, n_pings, endpoint=False)
    z = 0.2 + 0.2 * (np.arange(n_pings) % 10) / 10  # several heights, as in AirSAS scans
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), z], 1)
    rx = np.stack([0.863 * np.cos(ang), 0.863 * np.sin(ang), z - 0.038], 1)
    t0 = np.full(n_pings, 3.0e-3)
    sig = np.empty((n_pings, samples), np.complex64)  # filled in place: no complex128 copy
    sig.real = rng.standard_normal((n_pings, samples), dtype=np.float32)
    sig.imag = rng.standard_normal((n_pings, samples), dtype=np.float32)
    axes = [np.linspace(-0.15, 0.15, g) for g in grid[:2]] + [np.linspace(0.0, 0.3, grid[2])]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return sig, tx, rx, t0, pts


def timed(fn, repeats: int) -> tuple[float, np.ndarray]:
    best, out = math.inf, None
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        t = time.perf_counter()
        out = fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t)
    return best, out


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # Linux: KiB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--grid", type=int, default=48, help="voxels per axis of the side-by-side case")
    ap.add_argument("--pings", type=int, default=256)
    ap.add_argument("--samples", type=int, default=1200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-phase", action="store_true", help="analytic passband (no carrier phase term)")
    ap.add_argument("--voxel-block", type=int, default=None)
    ap.add_argument("--ping-chunk", type=int, default=None)
    ap.add_argument("--skip-reference", action="store_true")
    ap.add_argument("--full", action="store_true", help="run the AirSAS-scale case for real")
    ap.add_argument("--subset-pings", type=int, default=512,
                    help="pings of the AirSAS-scale grid measured for the extrapolation")
    ap.add_argument("--record", action="store_true", help="write a result record into benchmarks/results/")
    args = ap.parse_args()
    records = records_module() if args.record else None
    load = records.load() if records else None

    dev = torch.device(args.device)
    gpu = dev.type == "cuda"
    vb, pc = args.voxel_block, args.ping_chunk  # None: the library's per-device defaults
    carrier = None if args.no_phase else FC
    print(f"machine: {platform.machine()} {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {dev}"
          + (f" ({torch.cuda.get_device_name(dev)})" if gpu else ""))
    print(f"mode: {'passband, no phase term' if carrier is None else 'baseband + carrier phase term'}, "
          f"linear interpolation, float32; blocks (voxels, pings): eager "
          f"{BackprojectionConfig(voxel_block=vb, ping_chunk=pc).blocks(dev, 'eager')}, compiled "
          f"{BackprojectionConfig(voxel_block=vb, ping_chunk=pc).blocks(dev, 'compiled')}"
          + (f", triton {BackprojectionConfig(voxel_block=vb, ping_chunk=pc).blocks(dev, 'triton')}"
             if gpu else ""))

    g = args.grid
    sig, tx, rx, t0, pts = case(args.pings, (g, g, g), args.samples)
    work = len(pts) * args.pings
    print(f"\nside-by-side case: {g}^3 = {len(pts)} voxels x {args.pings} pings x {args.samples} "
          f"samples = {work / 1e6:.1f} M voxel-pings")
    rows = []
    ref = None
    if not args.skip_reference:
        dt, ref = timed(lambda: reference_backproject(sig, tx, rx, t0, FS, C, pts, carrier_hz=carrier,
                                                      ping_chunk=64, device=dev), args.repeats)
        rows.append(("reference (plain PyTorch)", dt, ref))
    eager = BackprojectionConfig(backend="eager", voxel_block=vb, ping_chunk=pc)
    dt, out = timed(lambda: backproject(sig, tx, rx, t0, FS, C, pts, carrier_hz=carrier, config=eager,
                                        device=dev), args.repeats)
    rows.append(("shsas eager", dt, out))
    comp = BackprojectionConfig(backend="compiled", voxel_block=vb, ping_chunk=pc)
    t = time.perf_counter()
    cvb, cpc = comp.blocks(dev, "compiled")
    backproject(sig[:cpc], tx[:cpc], rx[:cpc], t0[:cpc], FS, C, pts[:cvb], carrier_hz=carrier,
                config=comp, device=dev)
    warm = time.perf_counter() - t
    print(f"compile warm-up (first call, not counted below): {warm:.1f} s")
    dt, out = timed(lambda: backproject(sig, tx, rx, t0, FS, C, pts, carrier_hz=carrier, config=comp,
                                        device=dev), args.repeats)
    rows.append(("shsas compiled", dt, out))
    fastest = comp
    if gpu:  # the hand-written Triton kernel (CUDA only)
        tri = BackprojectionConfig(backend="triton", voxel_block=vb, ping_chunk=pc)
        t = time.perf_counter()
        backproject(sig[:8], tx[:8], rx[:8], t0[:8], FS, C, pts[:64], carrier_hz=carrier, config=tri,
                    device=dev)
        print(f"triton warm-up (first call, not counted below): {time.perf_counter() - t:.1f} s")
        dt, out = timed(lambda: backproject(sig, tx, rx, t0, FS, C, pts, carrier_hz=carrier,
                                            config=tri, device=dev), args.repeats)
        rows.append(("shsas triton", dt, out))
        fastest = tri
    base = rows[0][1] if ref is not None else None
    print(f"{'method':28s} {'time s':>9s} {'M voxel-pings/s':>16s} {'speed-up':>9s} {'max rel diff':>13s}")
    table: list[dict[str, object]] = []
    for name, dt, out in rows:
        rel = None if ref is None else float(np.abs(out - ref).max() / np.abs(ref).max())
        diff = "" if rel is None else f"{rel:.1e}"
        sp = "" if base is None else f"{base / dt:.1f}x"
        print(f"{name:28s} {dt:9.3f} {work / dt / 1e6:16.1f} {sp:>9s} {diff:>13s}")
        table.append({"case": f"{g}³ voxels x {args.pings} pings", "method": name, "seconds": dt,
                      "rate": work / dt / 1e6, "speedup": None if base is None else base / dt,
                      "max_rel_diff": rel})
    rate = work / rows[-1][1]

    # ---- AirSAS scale: 150 x 150 x 120 voxels x 43,200 pings
    shape, n_full = (150, 150, 120), 43_200
    v_full = math.prod(shape)
    n_sub = n_full if args.full else min(args.subset_pings, n_full)
    print(f"\nAirSAS-scale case: {shape[0]}x{shape[1]}x{shape[2]} = {v_full} voxels x {n_full} pings "
          f"= {v_full * n_full / 1e9:.1f} G voxel-pings, 1200 samples/ping")
    sig, tx, rx, t0, pts = case(n_sub, shape, 1200, seed=1)
    calls = []
    t = time.perf_counter()
    if gpu:
        torch.cuda.reset_peak_memory_stats(dev)
    backproject(sig, tx, rx, t0, FS, C, pts, carrier_hz=carrier, config=fastest, device=dev,
                progress=lambda f, s, m: calls.append(f))
    dt = time.perf_counter() - t
    mem = peak_rss_gb()
    gpu_mem = torch.cuda.max_memory_allocated(dev) / 1024**3 if gpu else 0.0
    sub_rate = v_full * n_sub / dt
    if args.full:
        print(f"measured: {dt:.1f} s ({sub_rate / 1e6:.1f} M voxel-pings/s), peak RSS {mem:.2f} GB"
              + (f", peak GPU memory {gpu_mem:.2f} GB" if gpu else ""))
    else:
        sig_gb = n_full * 1200 * 8 / 1024**3
        print(f"measured subset: {n_sub} pings in {dt:.1f} s ({sub_rate / 1e6:.1f} M voxel-pings/s), "
              f"peak RSS {mem:.2f} GB" + (f", peak GPU memory {gpu_mem:.2f} GB" if gpu else ""))
        print(f"EXTRAPOLATION (not measured): all {n_full} pings would take about "
              f"{dt * n_full / n_sub / 60:.1f} min at the subset's rate; memory is bounded by the "
              f"blocks, plus {sig_gb:.2f} GB for holding all 43,200 complex64 pings "
              f"-> about {mem + sig_gb:.2f} GB peak")
    print(f"AirSAS-scale case ran the {fastest.backend} kernel")
    table.append({"case": "AirSAS scale, 150 x 150 x 120 voxels x " + (
                      "43,200 pings" if args.full else f"{n_sub} of the 43,200 pings (a subset)"),
                  "method": f"shsas {fastest.backend}", "seconds": dt, "rate": sub_rate / 1e6,
                  "peak_rss_gb": mem, "peak_gpu_gb": gpu_mem if gpu else None})
    print(f"\nsummary: {fastest.backend} {rate / 1e6:.1f} M voxel-pings/s on the side-by-side case"
          + (f", {rate * rows[0][1] / work:.1f}x the plain reference" if base else ""))
    if records is not None and load is not None:
        record = records.make_record(
            "backprojection", f"backprojection-{dev.type}" + ("-full" if args.full else "") + (
                "" if (g, args.pings, args.samples, carrier) == (48, 256, 1200, FC)
                else f"-{g}x{args.pings}x{args.samples}" + ("-nophase" if carrier is None else "")),
            f"Backprojection throughput on {dev.type.upper()}"
            + (" (AirSAS scale measured in full)" if args.full else ""),
            "python " + " ".join(["benchmarks/bench_backprojection.py", *sys.argv[1:]]), RECORD_COLUMNS, table,
            machine_info=records.machine(torch.cuda.get_device_name(dev) if gpu else None), load_info=load,
            notes=f"{args.samples} samples per ping, "
                  + ("passband, no phase term" if carrier is None else "baseband with the carrier phase term")
                  + ", linear interpolation, float32; speed-up and max rel. diff against the plain reference.")
        print(f"record: {records.write_record(record)}")


if __name__ == "__main__":
    main()
