"""Benchmark the SH field: ms per forward + backward with normals (create_graph).

One training-like step: ``out = field(x, dirs)`` (density, scattering, normals with
``create_graph=True``), a loss that uses all three, ``loss.backward()`` to the parameters.

Modes: ``eager`` (reference: Python loop over levels, normals by double backward), ``fused``
(batched encoding in PyTorch ops + analytic normals, ``FieldConfig(backend="fused")``),
``fast`` (the default, ``backend="native"``: ``fused`` with the encoding in the C kernel on a
float32 CPU, else the same as ``fused``), ``compiled`` (``backend="compiled"``: the fused
encoding kernels through torch.compile), and by name only ``triton`` (``backend="triton"``: the
encoding in the Triton kernel; on CUDA ``fast`` is the same).

Timing: all modes live in one process and their steps are interleaved round by round, so a
load spike on a shared machine hits every mode alike; min and median over the rounds are
printed. ``first ms`` is the first call (for ``compiled`` it includes compiling). Peak memory
comes from a separate subprocess per mode: on CUDA ``torch.cuda.max_memory_allocated``, on CPU
the growth of the process's peak RSS over one warm-up + one step.

    PYTHONPATH=. python benchmarks/bench_fields.py                   # CPU preset, both sizes
    PYTHONPATH=. python benchmarks/bench_fields.py --preset paper_gpu --device cuda
    PYTHONPATH=. python benchmarks/bench_fields.py --points 65536 --rounds 5 --modes fast compiled
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

from shsas_core.common.device import resolve_device
from shsas_core.neural.fields import SHField, encoding_preset
from shsas_core.neural.fields.config import FieldConfig

SIZES = (64 * 1024, 200 * 4800)
MODES = ("eager", "fused", "fast", "compiled")
#: Modes asked for by name only: ``triton`` runs on CUDA (on a CPU only under TRITON_INTERPRET=1).
EXTRA_MODES = ("triton",)


def _rss_mb() -> float:
    # ru_maxrss is KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _make(mode: str, preset: str, degree: int, dev: torch.device) -> SHField:
    torch.manual_seed(0)  # same parameters in every mode
    backend = {"eager": "reference", "fused": "fused", "fast": "native", "compiled": "compiled",
               "triton": "triton"}[mode]
    cfg = FieldConfig(sh_degree=degree, encoding=encoding_preset(preset), backend=backend)
    return SHField(cfg).to(dev)


def _inputs(field: SHField, points: int, dev: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator(device="cpu").manual_seed(1)
    box = field.cfg.scene_box
    lo = torch.tensor(box.min, dtype=torch.float32)
    size = torch.tensor(box.size, dtype=torch.float32)
    x = lo + torch.rand(points, 3, generator=g) * size
    dirs = torch.nn.functional.normalize(torch.randn(points, 3, generator=g), dim=1)
    return x.to(dev), dirs.to(dev)


def _step(field: SHField, x: torch.Tensor, dirs: torch.Tensor) -> float:
    """One forward + backward; returns milliseconds (synchronised on CUDA)."""
    t0 = time.perf_counter()
    field.zero_grad(set_to_none=True)
    out = field(x, dirs, with_normals=True, create_graph=True)
    lam = torch.tensor([0.3, -0.5, 0.8], device=x.device)
    g = (out["normals"] @ lam).clamp_min(0)  # a Lambertian-like use of the normals
    loss = (out["scattering"] * g).abs().sum() + out["density"].sum()
    loss.backward()
    if x.device.type == "cuda":
        torch.cuda.synchronize(x.device)
    return (time.perf_counter() - t0) * 1e3


def peak_memory(points: int, mode: str, preset: str, degree: int, device: str) -> dict:
    """Warm-up + one step of one mode; peak memory growth in MB (run in a fresh process)."""
    dev = resolve_device(device)
    field = _make(mode, preset, degree, dev)
    x, dirs = _inputs(field, points, dev)
    base = _rss_mb()
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    _step(field, x, dirs)
    _step(field, x, dirs)
    peak = torch.cuda.max_memory_allocated(dev) / 2**20 if dev.type == "cuda" else _rss_mb() - base
    return {"points": points, "mode": mode, "peak_mb": peak}


def timings(points: int, modes: list[str], preset: str, degree: int, device: str, rounds: int) -> dict:
    dev = resolve_device(device)
    fields = {m: _make(m, preset, degree, dev) for m in modes}
    x, dirs = _inputs(next(iter(fields.values())), points, dev)
    first = {m: _step(f, x, dirs) for m, f in fields.items()}
    times: dict[str, list[float]] = {m: [] for m in modes}
    for _ in range(rounds):
        for m, f in fields.items():
            times[m].append(_step(f, x, dirs))
    res = {}
    for m in modes:
        t = sorted(times[m])
        res[m] = {"first_ms": first[m], "min_ms": t[0], "median_ms": t[len(t) // 2]}
    return res


def _subprocess(args: list[str]) -> dict | str:
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
        return f"failed: {tail[0][:120]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, nargs="*", default=list(SIZES))
    ap.add_argument("--preset", default="cpu", help="encoding preset: cpu or paper_gpu")
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--modes", nargs="*", choices=[*MODES, *EXTRA_MODES], default=list(MODES))
    ap.add_argument("--no-memory", action="store_true", help="skip the per-mode memory subprocesses")
    ap.add_argument("--memory-one", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--timing-one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.memory_one:
        print(json.dumps(peak_memory(args.points[0], args.modes[0], args.preset, args.degree, args.device)))
        return
    if args.timing_one:
        print(json.dumps(timings(args.points[0], args.modes, args.preset, args.degree, args.device, args.rounds)))
        return
    common = ["--preset", args.preset, "--degree", str(args.degree), "--device", args.device]
    print(f"SHField forward+backward with normals (create_graph), L={args.degree}, preset={args.preset}, "
          f"device={resolve_device(args.device)}, torch {torch.__version__}, threads {torch.get_num_threads()}")
    print(f"{'points':>9} {'mode':>8} {'first ms':>10} {'min ms':>10} {'median ms':>10} {'peak MB':>9}")
    for p in args.points:
        tim = _subprocess(["--timing-one", "--points", str(p), "--rounds", str(args.rounds),
                           "--modes", *args.modes, *common])
        for mode in args.modes:
            mem = "-" if args.no_memory else _subprocess(["--memory-one", "--points", str(p), "--modes", mode, *common])
            mem_s = f"{mem['peak_mb']:>9.0f}" if isinstance(mem, dict) else f"{mem!s:>9}"
            if isinstance(tim, dict):
                r = tim[mode]
                print(f"{p:>9} {mode:>8} {r['first_ms']:>10.1f} {r['min_ms']:>10.1f} {r['median_ms']:>10.1f} {mem_s}",
                      flush=True)
            else:
                print(f"{p:>9} {mode:>8} timing {tim} {mem_s}", flush=True)
        if isinstance(tim, dict) and "eager" in tim:
            for mode in ("fused", "fast", "compiled"):
                if mode in tim and "eager" in tim:
                    sp = tim["eager"]["median_ms"] / tim[mode]["median_ms"]
                    print(f"{p:>9} speedup eager/{mode} (median): {sp:.2f}x")


if __name__ == "__main__":
    main()
