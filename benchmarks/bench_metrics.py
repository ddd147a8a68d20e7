"""Ground-truth scoring: time and peak memory of ``GroundTruth`` construction, old vs new search;
and (``--protocol``) what the surface and solid protocols score for ideal predictions.

For each case, in the simulator's default scene box (mesh bounds + 2 cm) on 5 mm voxels, builds
``metrics.GroundTruth`` (surface sample + occupancy; the occupancy's band test is the cost) with

* ``reference``: the global-radius band search kept in :mod:`shsas_core.evaluation.metrics_reference`
  (every lookup uses the largest triangle's bounding radius), and
* ``shsas``: :func:`shsas_core.evaluation.metrics.within_distance_of_mesh` (per-triangle cells),

each in a fresh subprocess, so that its peak RSS is its own, under an address-space cap
(``--cap-gb``) so that a search that would exhaust a shared machine fails with MemoryError
instead. Prints wall and CPU time, peak RSS, RSS before construction, the number of exact
point-triangle candidates, and whether the occupancy equals the reference's bit for bit.

Cases: ``bunny`` and ``armadillo`` (../shared/data/meshes, or ``--meshes DIR``), ``cone`` (a
7,264-face trimesh cone, 5 cm radius, 15 cm high: 3,632 side slivers 15.8 cm long and 0.09 mm
wide at the rim, and 3,632 base slivers 5 cm long) and ``cone-large`` (the same faces on an 8 cm
radius, 20 cm high cone).

    PYTHONPATH=. python benchmarks/bench_metrics.py [--cases bunny,armadillo,cone,cone-large]
        [--algorithms reference,shsas] [--cap-gb 12] [--meshes DIR]

``--protocol`` prints, for the sphere, the cube and the bunny in the simulator's scene box, the
surface F1 (primary) beside the solid F1 (the paper code's convention), F@5mm and the mesh
quality of: the GT mesh itself; a perfectly placed surface sample (20,000 points, another seed);
a perfect ±5 mm shell (the points of a 64³ grid over the box within 5 mm of the surface, what a
thresholded volume that is right to 5 mm keeps); and a double sheet (the mesh plus a copy moved
7.5 mm outward along the vertex normals).

    PYTHONPATH=. python benchmarks/bench_metrics.py --protocol [--record]

``--record`` writes the protocol table as a result record (``benchmarks/results/metrics-protocol.json``,
the scoreboard's source). Prints figures only; never asserts.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import records  # noqa: E402

CASES = ("bunny", "armadillo", "cone", "cone-large")
CONES = {"cone": (0.05, 0.15), "cone-large": (0.08, 0.20)}  # radius, height, m
CONE_SECTIONS = 3632  # 7,264 faces, the cone that once took 44 s and 8.4 GB


def find_meshes(arg: str | None) -> Path:
    here = ROOT
    for c in ([Path(arg)] if arg else []) + [here.parent / "shared" / "data" / "meshes",
                                            here / "shared" / "data" / "meshes",
                                            Path(os.environ.get("SHSAS_SHARED", "shared")) / "data" / "meshes"]:
        if (c / "bunny.obj").exists():
            return c
    sys.exit("bunny.obj not found: pass --meshes DIR")


def load_case(case: str, meshes: Path):
    """(vertices (V, 3) m, faces (F, 3)) of a case."""
    import trimesh

    from shsas_core.simulation.shapes import load_mesh

    if case in CONES:
        radius, height = CONES[case]
        m = trimesh.creation.cone(radius=radius, height=height, sections=CONE_SECTIONS)
    else:
        m = load_mesh(meshes / f"{case}.obj")
    return m.vertices, m.faces


def rss_gb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024**3


def child(case: str, algorithm: str, cap_gb: float, meshes: Path) -> None:
    """Build one GroundTruth and print one JSON line of figures."""
    if cap_gb > 0:
        cap = int(cap_gb * 1024**3)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    import hashlib

    import numpy as np

    from shsas_core.evaluation import metrics
    from shsas_core.evaluation.metrics_reference import (
        reference_candidate_count,
        reference_within_distance_of_mesh,
    )
    from shsas_core.simulation.simulate import default_scene_box

    v, f = load_case(case, meshes)
    box = default_scene_box(np.stack([v.min(0), v.max(0)]), 0.02)
    if algorithm == "reference":
        # GroundTruth -> ScoringGrid.from_mesh looks the function up in the module at call time
        metrics.within_distance_of_mesh = reference_within_distance_of_mesh
    before = rss_gb()
    t, c = time.perf_counter(), time.process_time()
    try:
        gt = metrics.GroundTruth(v, f, box)
        status = "ok"
    except MemoryError:
        gt, status = None, f"MemoryError under the {cap_gb:g} GB cap"
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # Linux: KiB
    out = {"case": case, "algorithm": algorithm, "faces": len(f), "status": status, "wall_s": wall,
           "cpu_s": cpu, "peak_gb": peak, "before_gb": before}
    grid = metrics.ScoringGrid(box)
    out["grid_points"] = int(np.prod(grid.shape))
    if gt is not None:
        # counted after the peak was read: these do not change it
        out["occupied"] = int(gt.solid.sum())
        out["digest"] = hashlib.sha1(np.packbits(gt.solid)).hexdigest()
        centres = grid.centres()
        if algorithm == "reference":
            out["candidates"] = reference_candidate_count(centres, v, f, grid.voxel)
        else:
            out["candidates"] = len(metrics.mesh_candidate_pairs(centres, v, f, grid.voxel)[0])
    print(json.dumps(out), flush=True)


def machine() -> str:
    cpu = platform.processor() or "?"
    try:
        for line in subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines():
            if line.startswith("Model name:"):
                cpu = line.split(":", 1)[1].strip()
    except OSError:
        pass
    import numpy
    import scipy

    return (f"{os.cpu_count()} CPUs ({cpu}), Python {platform.python_version()}, numpy {numpy.__version__}, "
            f"scipy {scipy.__version__}")


PROTOCOL_CASES = ("sphere", "cube", "bunny")


PROTOCOL_COLUMNS = (("scene", "scene", ""), ("prediction", "prediction", ""),
                    ("surface_f1", "surface F1 (primary)", "{:.3f}"), ("solid_f1", "solid F1 (paper code)", "{:.3f}"),
                    ("fscore", "F@5mm", "{:.3f}"), ("fscore_2_5mm", "F@2.5mm", "{:.3f}"), ("pieces", "pieces", "{:.0f}"),
                    ("area_ratio", "area ratio", "{:.2f}"), ("normal_consistency", "normal cons.", "{:.3f}"))


def protocol(meshes: Path) -> list[dict[str, Any]]:
    """Print the surface and solid scores of ideal predictions side by side (module doc); return
    them as rows keyed like ``PROTOCOL_COLUMNS``."""
    import numpy as np
    import trimesh

    from shsas_core.evaluation.metrics import (
        GroundTruth,
        sample_surface,
        score_mesh,
        score_points,
        within_distance_of_mesh,
    )
    from shsas_core.simulation.shapes import load_mesh
    from shsas_core.simulation.simulate import default_scene_box

    table: list[dict[str, Any]] = []
    print("| scene | prediction | surface F1 (primary) | solid F1 (paper code) | F@5mm | F@2.5mm | pieces | area ratio | normal cons. |")
    print("|---|---|---|---|---|---|---|---|---|")
    for case in PROTOCOL_CASES:
        m = load_mesh(meshes / f"{case}.obj" if case == "bunny" else case)
        v, f = np.asarray(m.vertices), np.asarray(m.faces)
        box = default_scene_box(np.stack([v.min(0), v.max(0)]), 0.02)
        gt = GroundTruth(v, f, box)
        axes = [np.linspace(lo + 0.5 * (hi - lo) / 64, hi - 0.5 * (hi - lo) / 64, 64)
                for lo, hi in zip(box.min, box.max, strict=True)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        outer = trimesh.Trimesh(v + 0.0075 * m.vertex_normals, f, process=False)
        double = trimesh.util.concatenate([m, outer])
        rows = {"the GT mesh": score_mesh(v, f, gt),
                "surface sample (20,000 points)": score_points(sample_surface(v, f, 20_000, seed=7), gt),
                "±5 mm shell (64³ grid points)": score_points(grid[within_distance_of_mesh(grid, v, f, 0.005)], gt),
                "double sheet 7.5 mm apart (mesh)": score_mesh(double.vertices, double.faces, gt)}
        for name, s in rows.items():
            q = {k: s.get(k) for k in ("pieces", "area_ratio", "normal_consistency")}
            table.append({"scene": case, "prediction": name, **q,
                          **{k: float(s[k]) for k in ("surface_f1", "solid_f1", "fscore", "fscore_2_5mm")}})
            cells = [f"{s['surface_f1']:.3f}", f"{s['solid_f1']:.3f}", f"{s['fscore']:.3f}", f"{s['fscore_2_5mm']:.3f}",
                     "–" if q["pieces"] is None else f"{q['pieces']:.0f}",
                     "–" if q["area_ratio"] is None else f"{q['area_ratio']:.2f}",
                     "–" if q["normal_consistency"] is None else f"{q['normal_consistency']:.3f}"]
            print(f"| {case} | {name} | " + " | ".join(cells) + " |", flush=True)
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", action="store_true", help="print the surface vs solid scores of ideal predictions")
    ap.add_argument("--cases", default="bunny,armadillo,cone", help=f"comma list of {', '.join(CASES)}")
    ap.add_argument("--algorithms", default="reference,shsas")
    ap.add_argument("--cap-gb", type=float, default=12.0, help="address-space cap per run, GB (0: none)")
    ap.add_argument("--meshes", default=None, help="folder with bunny.obj and armadillo.obj")
    ap.add_argument("--record", action="store_true",
                    help="with --protocol: write benchmarks/results/metrics-protocol.json")
    ap.add_argument("--child", nargs=2, metavar=("CASE", "ALGORITHM"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    meshes = find_meshes(args.meshes)
    if args.protocol:
        machine_info, load_info = records.machine(), records.load()
        rows = protocol(meshes)
        if args.record:
            record = records.make_record(
                "metrics", "metrics-protocol",
                "The scores of ideal predictions under the surface and the solid protocol",
                "PYTHONPATH=. python " + " ".join(["benchmarks/bench_metrics.py", *sys.argv[1:]]),
                PROTOCOL_COLUMNS, rows, machine_info=machine_info, load_info=load_info, protocol="surface",
                notes="Shell: the points of a 64³ grid over the scene box within 5 mm of the surface. Double "
                      "sheet: the mesh plus a copy moved 7.5 mm outward along its vertex normals. The figures "
                      "are deterministic.")
            print(f"record: {records.write_record(record)}")
        return
    if args.child:
        child(args.child[0], args.child[1], args.cap_gb, meshes)
        return
    print(f"machine: {machine()}")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("GroundTruth construction, simulator scene box (bounds + 2 cm), 5 mm voxels; one fresh process per row")
    head = ("case", "faces", "grid pts", "algorithm", "wall s", "CPU s", "peak RSS GB", "RSS before GB",
            "candidates", "occupied", "same as reference")
    print(" | ".join(head))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    for case in args.cases.split(","):
        ref_digest = None
        for algorithm in args.algorithms.split(","):
            cmd = [sys.executable, __file__, "--child", case, algorithm, "--cap-gb", str(args.cap_gb),
                   "--meshes", str(meshes)]
            run = subprocess.run(cmd, capture_output=True, text=True, env=env)
            lines = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
            if run.returncode != 0 or not lines:
                print(f"{case} | | | {algorithm} | failed (exit {run.returncode}): {run.stderr.strip()[-300:]}")
                continue
            r = json.loads(lines[-1])
            if algorithm == "reference":
                ref_digest = r.get("digest")
            same = "—" if algorithm == "reference" or ref_digest is None or "digest" not in r else (
                "yes" if r["digest"] == ref_digest else "NO")
            if r["status"] != "ok":
                print(f"{case} | {r['faces']} | {r['grid_points']} | {algorithm} | {r['status']} after "
                      f"{r['wall_s']:.1f} s (CPU {r['cpu_s']:.1f} s, peak {r['peak_gb']:.2f} GB)")
                continue
            print(f"{case} | {r['faces']} | {r['grid_points']} | {algorithm} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | "
                  f"{r['peak_gb']:.2f} | {r['before_gb']:.2f} | {r['candidates']:,} | {r['occupied']} | {same}",
                  flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
