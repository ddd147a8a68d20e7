"""A short Reed fit's iterations per second: threads sized for the machine vs for the CPUs owned.

Each case runs the pipeline's Reed method (SH degree 0) on a small simulated sphere in a fresh
subprocess whose CPU affinity is ``--cpus`` (default: every CPU this process may use):

- ``machine``: torch's pool sized to the machine's core count (``os.cpu_count()``), what a
  worker gets from a library that looks at the machine (the job's threads outnumber its CPUs
  whenever it owns fewer than all of them);
- ``owned``: ``shsas_core.common.threads.size_thread_pools()``, what the workers do: the affinity set,
  capped by the cgroup CPU quota;
- ``1``: one thread, for reference.

The it/s is the median of the pipeline's own ``it/s`` progress readings after the first fifth of
the fit. Usage:

    python benchmarks/bench_threads.py [--cpus 0] [--iters 150] [--repeats 1]

Prints a table; never asserts. On a shared machine say what else was running.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _child(args: argparse.Namespace) -> dict:
    os.sched_setaffinity(0, {int(c) for c in args.cpus.split(",")})
    import torch

    sys.path.insert(0, str(REPO))
    from shsas_core.common.threads import size_thread_pools
    from shsas_core.formats.hdf5 import write_survey
    from shsas_core.pipeline.job import run
    from shsas_core.simulation.simulate import simulate_shape
    from shsas_core.spec.job import ReconstructionSpec

    if args.case == "machine":
        torch.set_num_threads(os.cpu_count() or 1)
    elif args.case == "owned":
        size_thread_pools()
    else:
        torch.set_num_threads(int(args.case))
    rates: list[float] = []

    def progress(fraction: float, stage: str, metrics) -> None:
        if stage.startswith("fit") and "it/s" in metrics and fraction > 0.2:
            rates.append(float(metrics["it/s"]))

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sphere.h5"
        write_survey(simulate_shape("sphere", heights=10, angles=90, snr_db=20.0, seed=0), path)
        spec = ReconstructionSpec(methods=["reed"], iters=args.iters, grid=32, device="cpu")
        t0 = time.perf_counter()
        run(spec, path, Path(tmp) / "out", progress=progress)
        wall = time.perf_counter() - t0
    return {"threads": torch.get_num_threads(), "it_s": statistics.median(rates) if rates else float("nan"),
            "wall_s": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cpus", default=",".join(map(str, sorted(os.sched_getaffinity(0)))),
                    help="CPU ids the fit may run on (default: all this process may use)")
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--repeats", type=int, default=1, help="runs per case, interleaved")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(_child(args)))
        return
    cases = ["machine", "owned", "1"]
    rows: dict[str, list[dict]] = {c: [] for c in cases}
    for _ in range(args.repeats):
        for case in cases:
            out = subprocess.run([sys.executable, __file__, "--case", case, "--cpus", args.cpus,
                                  "--iters", str(args.iters)], capture_output=True, text=True,
                                 env={**os.environ, "PYTHONPATH": str(REPO)})
            if out.returncode != 0:
                sys.exit(f"case {case} failed:\n{out.stderr[-2000:]}")
            rows[case].append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"machine: {os.cpu_count()} CPUs, fit on CPUs {args.cpus}; load average "
          f"{os.getloadavg()[0]:.1f}; Reed fit, {args.iters} iterations, grid 32, 10 x 90 pings")
    print(f"{'threads':>24} {'n':>3} {'it/s (median)':>14} {'wall s':>8}")
    names = {"machine": "machine (os.cpu_count)", "owned": "owned (affinity/quota)", "1": "one"}
    for case in cases:
        r = rows[case]
        print(f"{names[case]:>24} {r[0]['threads']:>3} {statistics.median(x['it_s'] for x in r):>14.2f} "
              f"{statistics.median(x['wall_s'] for x in r):>8.1f}")


if __name__ == "__main__":
    main()
