"""Milliseconds per training iteration: fast path vs eager reference, side by side.

fast  = FieldConfig.backend="native" (batched hash encoding + analytic normals, one first-order
        backward; on CPU the encoding runs in the C kernel of shsas_core/neural/fields/native.py) +
        RenderConfig.backend="fast" (focal closed-form intersection, cumsum transmittance)
eager = FieldConfig.backend="reference" (per-level encoding, normals by double backward) +
        RenderConfig.backend="reference" (ellipsoid-frame quadric, cumprod transmittance)

One iteration = sample bins and rays, render with normals (Lambertian) and two-way
transmittance, ToF loss, backward, Adam step — the body of ``shsas_core.neural.train.fit``. Each
configuration runs in its own subprocess so peak memory (CPU: max RSS; CUDA: max allocated) is
its own. Usage:

    python benchmarks/bench_train.py [--device cpu|cuda] [--cases cpu,paper] [--iters N]
        [--threads T] [--encoding cpu|paper_gpu] [--no-native] [--no-heap-cache]

Cases: ``cpu`` = 1 ping x 64 bins x 1024 rays, ``paper`` = 1 ping x 200 bins x 4800 rays,
``tiny`` = 1 ping x 8 bins x 32 rays (smoke runs); L = 3. ``--field-backend`` replaces the
field's backend of a mode (any of ``FieldConfig.backend``; ``benchmarks/bench_gpu.py`` times each).
``--renderer-only`` swaps the neural field for a cheap analytic one (a Gaussian shell with
autograd normals) to time the renderer's own part (intersection, transmittance, quadrature).
Prints a table; never asserts.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

CASES = {"cpu": (64, 1024), "paper": (200, 4800), "tiny": (8, 32)}


def _one(args: argparse.Namespace) -> dict:
    import numpy as np
    import torch

    torch.set_num_threads(args.threads)
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from shsas_core.data.survey import SceneBox, Survey, SurveyMeta, default_pulse
    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig
    from shsas_core.neural.render import RenderConfig
    from shsas_core.neural.train import TrainConfig
    from shsas_core.neural.train.data import iteration_generator, prepare_data, sample_batch
    from shsas_core.neural.train.losses import Amplitude, render_batch

    fast = args.mode == "fast"
    bins, rays = CASES[args.case]
    dev = torch.device(args.device)
    box = SceneBox(min=(-0.125, -0.125, 0.0), max=(0.125, 0.125, 0.2))
    meta = SurveyMeta(platform="bench", scene_box=box)
    n, t = 16, 1000
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(n, 0.3)], 1)
    rx = tx + np.array([0.0, 0.0, -0.038])
    rng = np.random.default_rng(0)
    sig = (rng.standard_normal((n, t)) + 1j * rng.standard_normal((n, t))).astype(np.complex64)
    survey = Survey(tx=tx, rx=rx, samples=sig.real.copy(), t0=np.full(n, 1.5 / 343), meta=meta,
                    pulse=default_pulse(meta))
    torch.manual_seed(0)
    if args.renderer_only:
        field = _ShellField().to(dev)
    else:
        field = SHField(FieldConfig(sh_degree=3, encoding=encoding_preset(args.encoding), scene_box=box,
                                    backend=args.field_backend or ("native" if fast else "reference"))).to(dev)
    # (render's uniform_fraction=1.0 was given here before, and TrainConfig replaced it with its own
    # 0.1 without a word; it is now an error, and the bench keeps measuring what it always measured)
    cfg = TrainConfig(num_bins=bins, num_rays=rays, device=args.device, render=RenderConfig(backend="fast" if fast else "reference"))
    data = prepare_data(survey, sig, None, cfg.uniform_fraction)
    amp = Amplitude().to(dev)
    from shsas_core.common import optim

    optim.FUSED = not args.single_tensor_adam
    opt = optim.adam([*list(field.parameters()), amp.log_amplitude], lr=1e-3)

    def step(i: int) -> None:
        gen = iteration_generator(0, i)
        _p, geom, radii, target = sample_batch(data, survey, gen, cfg, dev, torch.float32)
        out = render_batch(field, amp, geom, radii, cfg, gen)
        loss = (out["signal"].to(target.dtype) - target).abs().pow(2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    from shsas_core.common.heap import heap_cache

    times = []
    # as in fit(): freed CPU buffers stay in the heap (--no-heap-cache: glibc's default mmap/munmap)
    with heap_cache(dev.type == "cpu" and not args.no_heap_cache):
        for i in range(args.warmup):
            step(i)
        if dev.type == "cuda":
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
        for i in range(args.iters):
            t0 = time.perf_counter()
            step(args.warmup + i)
            if dev.type == "cuda":
                torch.cuda.synchronize()
            times.append(time.perf_counter() - t0)
    if dev.type == "cuda":
        peak = torch.cuda.max_memory_allocated() / 2**20
    else:
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"case": args.case, "mode": args.mode, "field_backend": None if args.renderer_only else field.cfg.backend,
            "points": bins * rays, "ms_median": 1e3 * float(np.median(times)),
            "ms_min": 1e3 * float(np.min(times)), "peak_mib": peak}


class _ShellField:
    """Cheap analytic stand-in with the field interface (renderer-only timing)."""

    def __new__(cls):
        import torch

        class Shell(torch.nn.Module):
            def __init__(self) -> None:
                super().__init__()
                self.amp = torch.nn.Parameter(torch.tensor(5.0))

            def forward(self, x, dirs, with_normals=True, create_graph=None):
                create_graph = torch.is_grad_enabled() if create_graph is None else create_graph
                with torch.enable_grad():
                    xg = x if x.requires_grad else x.detach().requires_grad_(True)
                    c = torch.tensor([0.0, 0.0, 0.1], device=x.device)
                    mag = self.amp * torch.exp(-0.5 * (((xg - c).norm(dim=-1) - 0.05) / 0.01) ** 2)
                    out = {"density": mag, "scattering": torch.polar(mag, 40.0 * xg[:, 0])}
                    if with_normals:
                        (g,) = torch.autograd.grad(mag.sum(), xg, create_graph=create_graph)
                        out["normals"] = -torch.nn.functional.normalize(g, dim=-1)
                return out

        return Shell()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--cases", default="cpu,paper")
    ap.add_argument("--iters", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--encoding", default=None, help="hash preset (default: cpu on CPU, paper_gpu on CUDA)")
    ap.add_argument("--modes", default="fast,eager", help="which paths to run (fast, eager or both)")
    ap.add_argument("--renderer-only", action="store_true", help="analytic field: time the renderer alone")
    ap.add_argument("--no-heap-cache", action="store_true",
                    help="leave glibc's malloc defaults (large buffers mmapped and unmapped every iteration)")
    ap.add_argument("--no-native", action="store_true",
                    help="fast path without the C encoding kernel (SHSAS_NATIVE=0: the PyTorch fused ops)")
    ap.add_argument("--field-backend", help="FieldConfig.backend of the timed mode (default: native for fast, "
                    "reference for eager)")
    ap.add_argument("--single-tensor-adam", action="store_true",
                    help="torch's default Adam for the device instead of the product's fused one")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--mode", help=argparse.SUPPRESS)
    ap.add_argument("--record", action="store_true",
                    help="write one result record per case into benchmarks/results/ (train-<device>-<case>)")
    args = ap.parse_args()
    args.encoding = args.encoding or ("paper_gpu" if args.device.startswith("cuda") else "cpu")
    if args.case:
        print(json.dumps(_one(args)))
        return
    import torch

    load = os.getloadavg()
    if args.no_native:
        os.environ["SHSAS_NATIVE"] = "0"  # inherited by the per-case subprocesses
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from shsas_core.neural.fields import native

    kernel = "PyTorch fused ops" if not native.available() else "C kernel (hashgrid_cpu.c)"
    print(f"bench_train: fast-path encoding on CPU: {kernel}"
          + (f" [{native._state['error']}]" if native._state.get("error") else ""))
    print(f"bench_train: device={args.device} threads={args.threads} encoding={args.encoding} "
          f"L=3 normals=on torch={torch.__version__} iters={args.iters} (median of timed iterations) "
          f"heap_cache={'off' if args.no_heap_cache else 'on'} load={os.getloadavg()[0]:.1f}"
          + (" RENDERER ONLY (analytic field)" if args.renderer_only else ""))
    print(f"{'case':<7}{'bins x rays':>14}{'points':>10}{'fast ms':>10}{'eager ms':>10}{'speed-up':>10}"
          f"{'fast MiB':>10}{'eager MiB':>11}{'fast min':>10}{'eager min':>11}")
    for case in args.cases.split(","):
        res = {}
        for mode in args.modes.split(","):
            cmd = [sys.executable, __file__, "--case", case, "--mode", mode, "--device", args.device,
                   "--iters", str(args.iters), "--warmup", str(args.warmup), "--threads", str(args.threads),
                   "--encoding", args.encoding] + (["--renderer-only"] if args.renderer_only else []) \
                + (["--field-backend", args.field_backend] if args.field_backend else []) \
                + (["--no-heap-cache"] if args.no_heap_cache else []) \
                + (["--single-tensor-adam"] if args.single_tensor_adam else [])
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode != 0:
                print(f"{case} {mode} failed: {out.stderr.strip().splitlines()[-1:]}")
                break
            res[mode] = json.loads(out.stdout.strip().splitlines()[-1])
        b, r = CASES[case]
        f, e = res.get("fast"), res.get("eager")

        def col(d: dict | None, key: str, fmt: str) -> str:
            return format(d[key], fmt) if d else "-"

        ratio = f"{e['ms_median'] / f['ms_median']:.2f}x" if f and e else "-"
        pts = (f or e or {"points": b * r})["points"]
        print(f"{case:<7}{f'{b} x {r}':>14}{pts:>10}{col(f, 'ms_median', '.0f'):>10}"
              f"{col(e, 'ms_median', '.0f'):>10}{ratio:>10}{col(f, 'peak_mib', '.0f'):>10}"
              f"{col(e, 'peak_mib', '.0f'):>11}{col(f, 'ms_min', '.0f'):>10}{col(e, 'ms_min', '.0f'):>11}")
        if args.record and (f or e):
            write_record(args, case, f, e, load, kernel, torch)


RECORD_COLUMNS = (("batch", "batch", ""), ("points", "points", "{:,.0f}"), ("fast_ms", "fast ms", "{:,.0f}"),
                  ("eager_ms", "eager ms", "{:,.0f}"), ("speedup", "speed-up", "{:.2f}x"),
                  ("fast_min_ms", "fast min ms", "{:,.0f}"), ("eager_min_ms", "eager min ms", "{:,.0f}"),
                  ("fast_peak_mib", "fast peak MiB", "{:,.0f}"), ("eager_peak_mib", "eager peak MiB", "{:,.0f}"))


def write_record(args: argparse.Namespace, case: str, f: dict | None, e: dict | None,
                 load: tuple[float, float, float], kernel: str, torch: object) -> None:
    """One case's figures as a result record (``benchmarks/records.py`` has the schema)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import records

    device = args.device.split(":")[0]
    variant = "".join(s for s, on in (("-no-native", args.no_native), ("-renderer-only", args.renderer_only),
                                      ("-no-heap-cache", args.no_heap_cache),
                                      (f"-{args.field_backend}", bool(args.field_backend))) if on)
    b, r = CASES[case]
    row = {"batch": f"{b} bins x {r} rays", "points": (f or e or {})["points"],
           "fast_ms": f and f["ms_median"], "eager_ms": e and e["ms_median"],
           "speedup": e["ms_median"] / f["ms_median"] if f and e else None,
           "fast_min_ms": f and f["ms_min"], "eager_min_ms": e and e["ms_min"],
           "fast_peak_mib": f and f["peak_mib"], "eager_peak_mib": e and e["peak_mib"]}
    gpu = torch.cuda.get_device_name(args.device) if device == "cuda" else None  # type: ignore[attr-defined]
    record = records.make_record(
        "train", f"train-{device}-{case}{variant}", f"Training iteration time, {b} bins x {r} rays, {device}",
        "python " + " ".join(["benchmarks/bench_train.py", *sys.argv[1:]]), RECORD_COLUMNS, [row],
        machine_info=records.machine(gpu), load_info={"loadavg": [round(x, 2) for x in load], "note": ""},
        notes=f"L = 3 with normals, {args.encoding} hash preset, {args.threads} threads, median of {args.iters} "
              f"timed iterations after {args.warmup} warm-up; fast path's CPU encoding: {kernel}.")
    print(f"record: {records.write_record(record)}")


if __name__ == "__main__":
    main()
