"""The GPU record: paper-batch iteration time per field backend, the paper's 50k-iteration fit
of the dense bunny (resumed across calls), and its scores beside the CPU defaults.

Steps (``--steps``, default all, in this order; a finished step is not run again, and all of
them share the ``--budget-s`` seconds of one call, so a call fits the device tool's 10 minutes):

- ``time``: ms per training iteration at the paper's batch (1 ping x 200 bins x 4,800 rays,
  L = 3 with normals, the paper's hash grid) for every ``FieldConfig.backend``, each in its own
  process (``benchmarks/bench_train.py --field-backend B``): the median goes into the record as
  ``paper_batch_ms[B]``. A backend that cannot run on the device (``triton`` on a CPU without
  Triton's interpreter) is recorded with the reason instead. Backends already timed in an earlier
  call are not timed again.
- ``fit``: ``shsas_core.pipeline.job.run`` of SH-SAS on the scoreboard's dense bunny
  (``bench_fidelity``'s dense regime, seed 0) with the paper's settings (``PAPER_SETTINGS``:
  50,000 iterations). The run stops itself ``--budget-s`` seconds into this call (a checkpoint
  is written on the way out) and the next call resumes it from the checkpoints in ``--work``:
  call the script again until the record says ``"finished": true``. The wall time of the fit
  is summed over calls.
- ``defaults``: the same survey through ``ReconstructionSpec()`` defaults (the CPU defaults the
  scoreboard judges), method shsas, on the same device.
- the record: ``--out/gpu-<card>.json`` (default ``benchmarks/results/``) names the card, the
  driver, CUDA, torch and Triton, and holds ``paper_batch_ms``, the fit (iterations, wall time,
  calls, finished) and the scoreboard's metrics of both fits side by side (pc F1, mesh F1,
  Chamfer-L2, F@5mm, seconds). It is rewritten after every step, so a partial record shows what
  is owed. The script never asserts a speed; it prints the figures.

``--smoke`` shrinks everything so the whole path runs on a CPU in about a minute (the tests run
it): the tiny batch (8 bins x 32 rays), the small hash grid, a 24-ping sphere instead of the
bunny, 10 iterations, the defaults without their warm start; ``triton`` runs under the
interpreter; ``compiled`` is left out (20-60 s to compile on a CPU). Its record is named
``smoke-<card>.json`` and its figures mean nothing.

Usage (``benchmarks/run_gpu.sh paper`` calls it on a lent GPU machine)::

    python benchmarks/bench_gpu.py [--device cuda] [--steps time,fit,defaults] [--budget-s 500]
    python benchmarks/bench_gpu.py --smoke --device cpu --out /tmp/rec --work /tmp/work
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_fidelity as fid  # noqa: E402

from shsas_core.common.errors import Cancelled  # noqa: E402
from shsas_core.neural.fields.encoding import BACKENDS  # noqa: E402
from shsas_core.outputs.export import write_json  # noqa: E402
from shsas_core.simulation.simulate import SimulationConfig, TrajectoryConfig  # noqa: E402
from shsas_core.spec.job import PAPER_SETTINGS, ReconstructionSpec  # noqa: E402

STEPS = ("time", "fit", "defaults")
#: The scoreboard's metrics, in its order (bench_fidelity.COLUMNS) and the pipeline's names.
SCORES = ("pc_f1", "mesh_f1", "pc_chamfer_l2", "pc_fscore", "seconds")
#: What --smoke changes (every step small enough for a CPU in a minute or two).
SMOKE_SPEC: dict[str, Any] = {"iters": 10, "num_bins": 8, "num_rays": 32, "encoding": "small", "grid": 24}
#: ... and for the defaults' fit: no warm start (its 300 distillation steps are most of a CPU smoke run)
SMOKE_DEFAULTS: dict[str, Any] = {"init": "none"}
SMOKE_TRAJECTORY = TrajectoryConfig(heights=2, angles=12)
#: Per-backend timing limit, s (a compiled backend compiles in its warm-up).
TIME_LIMIT_S = 400


def machine(device: str) -> dict[str, Any]:
    """Card, driver, CUDA, torch and Triton versions, and the CPU (bench_fidelity.machine_info)."""
    import torch

    info = fid.machine_info(device)
    info["cuda"] = torch.version.cuda
    try:
        import triton

        info["triton"] = triton.__version__
    except ImportError:
        info["triton"] = None
    info["card"] = info.get("gpu") or f"cpu: {info['cpu']}"
    info["driver"] = None
    if info["device"].startswith("cuda"):
        try:
            out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                 capture_output=True, text=True, timeout=30)
            info["driver"] = out.stdout.strip().splitlines()[0] if out.returncode == 0 else None
        except (OSError, IndexError, subprocess.TimeoutExpired):
            pass
    return info


def time_backends(device: str, smoke: bool, res: dict[str, Any], deadline: float) -> dict[str, Any]:
    """Time the field backends on ``device`` (resolved: ``cpu``, ``cuda``, ``cuda:N``) that
    ``res`` does not hold yet, while ``time.perf_counter()`` is before ``deadline``; ``res``
    becomes ``{backend: {"ms": median, "ms_min", "peak_mib"} or {"skipped"/"error": why}}``."""
    case, enc = ("tiny", "small") if smoke else ("paper", "paper_gpu")
    iters, warmup = (1, 0) if smoke else (20, 5)
    on_cpu = not device.startswith("cuda")
    for backend in BACKENDS:
        if backend in res:
            continue
        left = deadline - time.perf_counter()
        if left < 30:
            print(f"  time {backend}: no time left in this call (call again)", flush=True)
            break
        env = dict(os.environ)
        if backend == "compiled" and smoke:
            res[backend] = {"skipped": "--smoke leaves torch.compile out (20-60 s to compile on a CPU)"}
            continue
        if backend == "triton" and on_cpu:
            if not smoke:
                res[backend] = {"skipped": "CPU: the Triton kernels run there only under the interpreter"}
                continue
            env["TRITON_INTERPRET"] = "1"
        cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_train.py"), "--case", case, "--mode", "fast",
               "--field-backend", backend, "--device", device, "--encoding", enc, "--iters", str(iters),
               "--warmup", str(warmup)]
        print(f"  time {backend}: {case} batch, {iters} iterations after {warmup} ...", flush=True)
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=min(TIME_LIMIT_S, left))
        except subprocess.TimeoutExpired:
            if left < TIME_LIMIT_S:  # cut by this call's budget: try again in the next call
                print(f"  time {backend}: stopped at the end of this call's budget (call again)", flush=True)
                break
            res[backend] = {"error": f"over {TIME_LIMIT_S} s"}
            continue
        if out.returncode != 0:
            res[backend] = {"error": (out.stderr.strip().splitlines() or ["?"])[-1][:300]}
        else:
            r = json.loads(out.stdout.strip().splitlines()[-1])
            res[backend] = {"ms": r["ms_median"], "ms_min": r["ms_min"], "peak_mib": r["peak_mib"]}
        print(f"  time {backend}: {res[backend]}", flush=True)
    return {"case": case, "encoding": enc, "iters": iters, "warmup": warmup, "backends": res}


def survey(smoke: bool, args: argparse.Namespace):
    """The dense bunny of the scoreboard (seed 0), or the smoke run's 24-ping sphere."""
    if smoke:
        cfg = SimulationConfig(trajectory=SMOKE_TRAJECTORY, seed=0)
        sim, _ = fid.cached_survey("sphere", "sphere", cfg, Path(args.work) / "surveys")
        return sim
    regime = fid.REGIMES["dense"]
    source = fid.scene_source("bunny", fid.mesh_dir(args.meshes))
    sim, _ = fid.cached_survey("bunny", source, regime.simulation_config(0), fid.cache_dir(args.cache_dir))
    return regime.select(sim)


def fit(name: str, spec: ReconstructionSpec, data, work: Path, state: dict[str, Any],
        budget_s: float, call_iters: int | None = None) -> dict[str, Any]:
    """Run (or resume) one pipeline fit for at most ``budget_s`` s (and ``call_iters``
    training iterations) of this call.

    ``state`` (this fit's entry, updated in place) sums wall time and iterations over calls.
    """
    from shsas_core.pipeline.job import run

    t0 = time.perf_counter()
    seen = {"iters": 0, "it_s": None}

    def progress(_f: float, stage: str, m: dict[str, float]) -> None:
        if stage.startswith("fit:"):
            seen["iters"] += 1
            seen["it_s"] = m.get("it/s", seen["it_s"])

    def should_stop() -> bool:
        return time.perf_counter() - t0 > budget_s or (call_iters is not None and seen["iters"] >= call_iters)

    print(f"  {name}: {spec.iters} iterations, {state.get('iters_done', 0)} done before, "
          f"budget {budget_s:.0f} s in this call ...", flush=True)
    finished, result = False, None
    try:
        result = run(spec, data, work / name, progress, should_stop)
        finished = True
    except Cancelled:
        pass
    state["calls"] = state.get("calls", 0) + 1
    state["wall_s"] = state.get("wall_s", 0.0) + time.perf_counter() - t0
    state["iters_done"] = spec.iters if finished else state.get("iters_done", 0) + seen["iters"]
    state["iters_target"] = spec.iters
    state["iters_per_call"] = [*state.get("iters_per_call", []), seen["iters"]]
    state["last_it_per_s"] = seen["it_s"]
    state["finished"] = finished
    state["spec"] = spec.model_dump(mode="json")
    if result is not None:
        m = result.metrics["shsas"]
        state["scores"] = {k: fid._finite(m.get(k)) for k in SCORES}
        state["device"] = result.device
    print(f"  {name}: {state['iters_done']}/{spec.iters} iterations, {state['wall_s']:.0f} s over "
          f"{state['calls']} call(s)" + ("" if finished else " (call again to resume)"), flush=True)
    return state


def record_path(out: Path, card: str, smoke: bool) -> Path:
    slug = re.sub(r"[^a-z0-9]+", "-", card.lower()).strip("-")[:60]
    return out / f"{'smoke' if smoke else 'gpu'}-{slug}.json"


def print_record(rec: dict[str, Any]) -> None:
    m = rec["machine"]
    print(f"\n{m['card']} (driver {m['driver']}, CUDA {m['cuda']}, torch {m['torch']}, triton {m['triton']})")
    t = rec.get("time")
    if t:
        print(f"ms per iteration, {t['case']} batch ({t['encoding']} grid, median of {t['iters']}):")
        for b, r in t["backends"].items():
            print(f"  {b:<10} " + (f"{r['ms']:9.1f} ms" if "ms" in r else r.get("skipped") or f"ERROR {r['error']}"))
    fits = {k: rec[k] for k in ("fit", "defaults") if k in rec}
    if fits:
        print(f"\n{'':<10}{'iters':>14}{'wall s':>9}" + "".join(f"{k:>15}" for k in SCORES))
        for k, f in fits.items():
            sc = f.get("scores") or {}
            print(f"{k:<10}{str(f['iters_done']) + '/' + str(f['iters_target']):>14}{f['wall_s']:9.0f}"
                  + "".join(f"{fid._fmt(sc.get(s), '{:.4g}'):>15}" for s in SCORES))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto", help="auto, cpu or cuda[:N] (default auto)")
    ap.add_argument("--steps", default=",".join(STEPS), help=f"comma list of {', '.join(STEPS)}")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (a CPU in about a minute; figures mean nothing)")
    ap.add_argument("--budget-s", type=float, default=500.0,
                    help="seconds of this call the fits may use before they checkpoint and stop (default 500)")
    ap.add_argument("--call-iters", type=int, help="at most this many training iterations per fit in this call "
                    "(then checkpoint and stop, as at the end of --budget-s)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"), help="folder of the JSON record")
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "out" / "gpu"),
                    help="pipeline outputs and checkpoints, kept between calls (default benchmarks/out/gpu)")
    ap.add_argument("--meshes", help="folder with bunny.obj (default as bench_fidelity)")
    ap.add_argument("--cache-dir", help="simulated-survey cache (default as bench_fidelity)")
    args = ap.parse_args(argv)
    bad = [s for s in args.steps.split(",") if s not in STEPS]
    if bad:
        ap.error(f"--steps: unknown {bad} (use {', '.join(STEPS)})")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    work, out = Path(args.work), Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    info = machine(args.device)
    state_path = work / ("smoke-state.json" if args.smoke else "state.json")
    rec: dict[str, Any] = json.loads(state_path.read_text()) if state_path.is_file() else {}
    rec.update({"machine": info, "smoke": args.smoke, "code": fid.code_version(),
                "updated": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")})
    path = record_path(out, info["card"], args.smoke)

    def save() -> None:
        bb = (rec.get("time") or {}).get("backends", {})
        rec["paper_batch_ms"] = {b: r.get("ms") for b, r in bb.items()}
        write_json(rec, state_path)
        write_json(rec, path)

    steps = args.steps.split(",")
    t_call = time.perf_counter()
    if "time" in steps:
        tm = rec.setdefault("time", {"backends": {}})
        tm.update(time_backends(info["device"], args.smoke, tm["backends"], t_call + args.budget_s))
        tm["finished"] = set(tm["backends"]) == set(BACKENDS)
        save()
    data = None
    for name, base in (("fit", dict(PAPER_SETTINGS)), ("defaults", {})):
        extra = ({**SMOKE_SPEC, **(SMOKE_DEFAULTS if name == "defaults" else {})} if args.smoke else {})
        if name not in steps or rec.get(name, {}).get("finished"):
            continue
        left = args.budget_s - (time.perf_counter() - t_call)
        if left <= 0:
            print(f"  {name}: no time left in this call (call again)", flush=True)
            continue
        data = data if data is not None else survey(args.smoke, args)
        spec = ReconstructionSpec(**{**base, **extra, "methods": ["shsas"], "seed": 0, "device": info["device"]})
        rec[name] = fit(name, spec, data, work, rec.get(name, {}), left, args.call_iters)
        save()
    save()
    print_record(rec)
    print(f"\nrecord: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
