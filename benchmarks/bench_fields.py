"""Benchmark the SH field: ms per forward + backward with normals (create_graph).

Modes: ``eager`` (reference: Python loop over levels, normals by double backward), ``fast``
(fused batched encoding + forward-mode normals, ``FieldConfig(fast=True)``), ``compiled``
(``fast`` plus ``FieldConfig(compile=True)``: encoding kernels through torch.compile; its
``first ms`` includes the compile).

One training-like step: ``out = field(x, dirs)`` (density, scattering, normals with
``create_graph=True``), a loss that uses all three, ``loss.backward()`` to the parameters.
Each configuration runs in its own subprocess so peak memory is per configuration: on CUDA
``torch.cuda.max_memory_allocated``, on CPU the growth of the process's peak RSS.

    PYTHONPATH=. python benchmarks/bench_fields.py                   # CPU preset, both sizes
    PYTHONPATH=. python benchmarks/bench_fields.py --preset paper_gpu --device cuda
    PYTHONPATH=. python benchmarks/bench_fields.py --points 65536 --repeats 5 --modes fast compiled
    OMP_NUM_THREADS=1 ...   # pin threads on a shared machine (oversubscribed OpenMP spins)
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import torch

from shsas_core.device import resolve_device
from shsas_core.fields import FieldConfig, SHField, encoding_preset

SIZES = (64 * 1024, 200 * 4800)
MODES = ("eager", "fast", "compiled")


def _rss_mb() -> float:
    # ru_maxrss is KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(points: int, mode: str, preset: str, degree: int, device: str, repeats: int) -> dict:
    dev = resolve_device(device)
    torch.manual_seed(0)
    cfg = FieldConfig(sh_degree=degree, encoding=encoding_preset(preset), fast=mode != "eager",
                      compile=mode == "compiled")
    field = SHField(cfg).to(dev)
    box = field.cfg.scene_box
    lo = torch.tensor(box.min, dtype=torch.float32, device=dev)
    size = torch.tensor(box.size, dtype=torch.float32, device=dev)
    x = lo + torch.rand(points, 3, device=dev) * size
    dirs = torch.nn.functional.normalize(torch.randn(points, 3, device=dev), dim=1)
    lam = torch.tensor([0.3, -0.5, 0.8], device=dev)

    def step() -> None:
        field.zero_grad(set_to_none=True)
        out = field(x, dirs, with_normals=True, create_graph=True)
        g = (out["normals"] @ lam).clamp_min(0)
        loss = (out["scattering"] * g).abs().sum() + out["density"].sum()
        loss.backward()

    def sync() -> None:
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    base_rss = _rss_mb()
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    t0 = time.perf_counter()
    step()  # warm-up (allocator, sphericart, caches)
    sync()
    first_ms = (time.perf_counter() - t0) * 1e3
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step()
        sync()
        times.append((time.perf_counter() - t0) * 1e3)
    peak = torch.cuda.max_memory_allocated(dev) / 2**20 if dev.type == "cuda" else _rss_mb() - base_rss
    times.sort()
    return {
        "points": points, "mode": mode, "preset": preset, "degree": degree, "device": str(dev),
        "first_ms": first_ms, "min_ms": times[0], "median_ms": times[len(times) // 2], "peak_mb": peak,
        "threads": torch.get_num_threads(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, nargs="*", default=list(SIZES))
    ap.add_argument("--preset", default="cpu", help="encoding preset: cpu or paper_gpu")
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", nargs="*", choices=list(MODES), default=list(MODES))
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        res = run_one(args.points[0], args.modes[0], args.preset, args.degree, args.device, args.repeats)
        print(json.dumps(res))
        return
    modes = args.modes
    print(f"SHField forward+backward with normals (create_graph), L={args.degree}, preset={args.preset}, "
          f"device={resolve_device(args.device)}, torch {torch.__version__}")
    print(f"threads: {torch.get_num_threads()}")
    print(f"{'points':>9} {'mode':>8} {'first ms':>10} {'min ms':>10} {'median ms':>10} {'peak MB':>9}")
    rows = {}
    for p in args.points:
        for mode in modes:
            cmd = [sys.executable, __file__, "--one", "--points", str(p), "--modes", mode, "--preset", args.preset,
                   "--degree", str(args.degree), "--device", args.device, "--repeats", str(args.repeats)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{p:>9} {mode:>8} failed: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            rows[(p, mode)] = r
            print(f"{p:>9} {mode:>8} {r['first_ms']:>10.1f} {r['min_ms']:>10.1f} {r['median_ms']:>10.1f} "
                  f"{r['peak_mb']:>9.0f}", flush=True)
        for mode in ("fast", "compiled"):
            if (p, "eager") in rows and (p, mode) in rows:
                sp = rows[(p, "eager")]["median_ms"] / rows[(p, mode)]["median_ms"]
                print(f"{p:>9} speedup eager/{mode} (median): {sp:.2f}x")


if __name__ == "__main__":
    main()
