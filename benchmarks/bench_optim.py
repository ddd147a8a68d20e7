"""Adam on CPU: torch's single-tensor Adam against the product's fused one, side by side.

Two measurements:

* **Adam step** (always): one ``optimizer.step()`` over the parameters of the default field
  (``cpu`` hash preset, L = 3) with random gradients in place, per thread count: the optimiser
  alone.
* **whole job** (``--job SURVEY``): ``shsas reconstruct SURVEY --methods METHOD`` at the defaults,
  once per implementation and repeat, the two alternated so that a drift of the machine's speed
  falls on both alike; prints the method's seconds (the report's timing) and the process's CPU
  seconds. The implementation is chosen in the child by ``shsas_core.common.optim.FUSED``.

Usage:

    python benchmarks/bench_optim.py [--threads 1,2] [--steps 50]
        [--job SURVEY.h5 [--method shsas] [--repeats 1] [--seed 0]] [--record]

Prints tables; never asserts.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
IMPLEMENTATIONS = (("single", False), ("fused", True))

#: The child of a whole-job run: the product's CLI with the implementation set first.
_JOB = "import sys\nfrom shsas_core.common import optim\noptim.FUSED = {fused}\nfrom shsas_core.cli import main\nsys.exit(main())"


def adam_step_ms(fused: bool, steps: int) -> tuple[float, int]:
    """Median ms of one Adam step over the default field's parameters; and their float count."""
    import torch

    from shsas_core.common import optim
    from shsas_core.data.survey import SceneBox
    from shsas_core.neural.fields import SHField, encoding_preset
    from shsas_core.neural.fields.config import FieldConfig

    box = SceneBox(min=(-0.125, -0.125, 0.0), max=(0.125, 0.125, 0.2))
    field = SHField(FieldConfig(sh_degree=3, encoding=encoding_preset("cpu"), scene_box=box))
    params = list(field.parameters())
    gen = torch.Generator().manual_seed(0)
    for p in params:
        p.grad = torch.randn(p.shape, generator=gen, dtype=p.dtype)
    optim.FUSED = fused
    opt = optim.adam(params, lr=1e-3)
    times = []
    for i in range(steps + 3):
        t0 = time.perf_counter()
        opt.step()
        if i >= 3:  # the first steps allocate the moments
            times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times), sum(p.numel() for p in params)


def job_seconds(survey: str, method: str, seed: int, fused: bool) -> tuple[float, float]:
    """(the method's seconds in the job's report, the job process's CPU seconds)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([sys.executable, "-c", _JOB.format(fused=fused), "reconstruct", survey, "--methods", method,
                        "--seed", str(seed), "--out", out, "--quiet"], cwd=ROOT, check=True,
                       stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(ROOT)})
        report = json.loads((Path(out) / "report.json").read_text())
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return float(report["timings"][method]), cpu


STEP_COLUMNS = (("threads", "threads", ""), ("floats", "parameters", "{:,.0f}"),
                ("single_ms", "single-tensor Adam step ms", "{:.1f}"), ("fused_ms", "fused Adam step ms", "{:.1f}"))
JOB_COLUMNS = (("implementation", "Adam", ""), ("seconds", "method s (median)", "{:.1f}"),
               ("cpu_s", "job CPU s (median)", "{:.0f}"), ("runs", "runs, method s", ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", default="1,2", help="torch thread counts for the Adam step")
    ap.add_argument("--steps", type=int, default=50, help="timed Adam steps per figure")
    ap.add_argument("--job", help="a survey file: also time shsas reconstruct on it under each implementation")
    ap.add_argument("--method", default="shsas", help="the job's method (default shsas)")
    ap.add_argument("--seed", type=int, default=0, help="the job's seed")
    ap.add_argument("--repeats", type=int, default=1, help="job runs per implementation, alternated")
    ap.add_argument("--record", action="store_true", help="write benchmarks/results/optim-cpu[-job].json")
    args = ap.parse_args()
    import torch

    load = os.getloadavg()
    print(f"bench_optim: torch={torch.__version__} load={load[0]:.1f} (Adam step: median of {args.steps})")
    print(f"{'threads':>8}{'parameters':>12}{'single ms':>11}{'fused ms':>10}")
    steps = []
    for threads in [int(t) for t in args.threads.split(",")]:
        torch.set_num_threads(threads)
        row: dict = {"threads": str(threads)}
        for key, fused in IMPLEMENTATIONS:
            row[f"{key}_ms"], row["floats"] = adam_step_ms(fused, args.steps)
        steps.append(row)
        print(f"{threads:>8}{row['floats']:>12,}{row['single_ms']:>11.1f}{row['fused_ms']:>10.1f}")
    jobs = []
    if args.job:
        runs: dict[str, list[tuple[float, float]]] = {key: [] for key, _ in IMPLEMENTATIONS}
        for _ in range(args.repeats):
            for key, fused in IMPLEMENTATIONS:
                runs[key].append(job_seconds(args.job, args.method, args.seed, fused))
        print(f"\nshsas reconstruct {args.job} --methods {args.method} --seed {args.seed} (defaults), "
              f"{args.repeats} run(s) each, alternated")
        print(f"{'Adam':<8}{'method s':>10}{'CPU s':>8}  runs")
        for key, res in runs.items():
            row = {"implementation": key, "seconds": statistics.median(s for s, _ in res),
                   "cpu_s": statistics.median(c for _, c in res), "runs": ", ".join(f"{s:.1f}" for s, _ in res)}
            jobs.append(row)
            print(f"{key:<8}{row['seconds']:>10.1f}{row['cpu_s']:>8.0f}  {row['runs']}")
    if args.record:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        import records

        command = "python " + " ".join(["benchmarks/bench_optim.py", *sys.argv[1:]])
        info = {"loadavg": [round(x, 2) for x in load], "note": ""}
        tables = [("optim-cpu", "Adam step on CPU: single-tensor against fused", STEP_COLUMNS, steps,
                   "The default field's parameters (cpu preset, L = 3) with random gradients. The product uses fused Adam.")]
        if jobs:
            tables.append(("optim-cpu-job", f"A whole {args.method} job on CPU: single-tensor against fused Adam",
                           JOB_COLUMNS, jobs, f"shsas reconstruct {Path(args.job).name} --methods {args.method} --seed "
                           f"{args.seed} at the defaults; {args.repeats} run(s) each, alternated."))
        for name, title, columns, rows, notes in tables:
            record = records.make_record("optim", name, title, command, columns, rows,
                                         machine_info=records.machine(None), load_info=info, notes=notes)
            print(f"record: {records.write_record(record)}")


if __name__ == "__main__":
    main()
