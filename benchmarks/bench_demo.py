"""`make demo`'s figures as a result record: run ``shsas demo`` and record its report's metrics.

Runs ``shsas demo --quiet --out OUT [--mesh MESH]`` (the same command ``make demo`` runs, without
building the venv) in a subprocess, then reads ``OUT/report.json`` and prints, per method, the
scoreboard's columns. With ``--record`` it writes ``benchmarks/results/demo-<scene>.json``.

Usage::

    python benchmarks/bench_demo.py                          # the bunny of ../shared, else the sphere
    python benchmarks/bench_demo.py --mesh "" --record       # the built-in sphere, recorded
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import records

sys.path.insert(0, str(records.ROOT))
from shsas_core.spec.catalogue import LABELS

ROOT = records.ROOT
DEFAULT_MESH = records.SHARED_MESHES / "bunny.obj"
COLUMNS = (("method", "method", ""),
           ("mesh_surface_f1", "surface F1 mesh", "{:.3f}"), ("pc_surface_f1", "surface F1 cloud", "{:.3f}"),
           ("mesh_fscore", "F@5mm mesh", "{:.3f}"), ("pc_fscore", "F@5mm cloud", "{:.3f}"),
           ("mesh_fscore_2_5mm", "F@2.5mm mesh", "{:.3f}"),
           ("mesh_chamfer_l2", "Chamfer-L2 mesh (m²)", "{:.2e}"), ("pc_solid_f1", "solid F1 cloud", "{:.3f}"),
           ("mesh_pieces", "pieces", "{:.0f}"), ("mesh_area_ratio", "area ratio", "{:.2f}"),
           ("mesh_normal_consistency", "normal cons.", "{:.3f}"), ("seconds", "s", "{:.0f}"))


def rows_from_report(report: dict) -> list[dict[str, float | str | None]]:
    """One row per method of a ``report.json``: its metrics under the scoreboard's keys."""
    rows = []
    for m in report["methods"]:
        metrics = m.get("metrics", {})
        # the method's wall time is the report's own field, not a metric
        rows.append({"method": LABELS.get(m["method"], m["method"]),
                     **{k: metrics.get(k) for k, _, _ in COLUMNS[1:] if k != "seconds"},
                     "seconds": m.get("seconds")})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default=str(DEFAULT_MESH) if DEFAULT_MESH.exists() else "",
                    help="mesh to simulate ('' for the built-in sphere; default the bunny of ../shared)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "demo"), help="the demo's output folder")
    ap.add_argument("--record", action="store_true", help="write benchmarks/results/demo-<scene>.json")
    args = ap.parse_args(argv)
    scene = Path(args.mesh).stem if args.mesh else "sphere"
    machine, load = records.machine(), records.load()
    cmd = [sys.executable, "-m", "shsas_core.cli", "demo", "--quiet", "--out", args.out,
           *(["--mesh", args.mesh] if args.mesh else [])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    t = time.perf_counter()
    if subprocess.run(cmd, cwd=ROOT, env=env).returncode != 0:
        print("bench_demo: shsas demo failed", file=sys.stderr)
        return 1
    wall = time.perf_counter() - t
    report = json.loads((Path(args.out) / "report.json").read_text())
    rows = rows_from_report(report)
    for r in rows:
        print(" | ".join(f"{k}={r[k]}" for k, _, _ in COLUMNS))
    print(f"demo wall time {wall:.0f} s")
    if args.record:
        record = records.make_record(
            "demo", f"demo-{scene}", f"shsas demo on the {scene} (the make demo survey, default spec)",
            "python " + " ".join(["benchmarks/bench_demo.py", *(argv if argv is not None else sys.argv[1:])]),
            COLUMNS, rows, machine_info=machine, load_info=load, scene=scene,
            protocol=report.get("metrics_protocol", ""),
            notes=f"The demo took {wall:.0f} s wall; s is each method's pipeline time.")
        print(f"record: {records.write_record(record)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
