"""Do the defaults hold on surveys unlike the simulator's? Every method, every variant, one table.

Simulates the demo's survey of one mesh (20 heights x 90 pings, seed 0) as the reference and as
each variant of ``shsas_core.simulation.variants`` (records from transmit, a large box, another
sample rate, 5 dB, a narrow band), runs the pipeline at the default spec (``ReconstructionSpec()``
with only ``methods`` and ``seed`` set) on each, and prints per variant and method the surface
F1 of the cloud and the mesh, F@5mm, the cloud's size against the surface's (its area over the
voxel face), the mesh checks (pieces, area ratio, normal consistency) and the wall time. A
default tuned to the reference survey shows here as a variant far below it.

Usage::

    python benchmarks/bench_variants.py                           # the bunny, all methods, every variant
    python benchmarks/bench_variants.py --methods backprojection  # seconds, not half an hour
    python benchmarks/bench_variants.py --variants reference,narrowband --record

Output: ``--out`` (default ``benchmarks/out/variants/``, git-ignored) holds each variant's survey
and pipeline artifacts; a re-run resumes finished fits. ``--record`` writes
``benchmarks/results/variants-<scene>.json`` (the scoreboard of ``docs/results.md``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import records
import scoreboard

sys.path.insert(0, str(records.ROOT))
from shsas_core.cli.demo import DEMO_ANGLES, DEMO_HEIGHTS
from shsas_core.spec.catalogue import LABELS
from shsas_core.spec.job import METHODS, ReconstructionSpec

DEFAULT_MESH = records.SHARED_MESHES / "bunny.obj"
COLUMNS = (("row", "variant / method", ""),
           ("pc_surface_f1", "surface F1 cloud ↑", "{:.3f}"), ("mesh_surface_f1", "surface F1 mesh ↑", "{:.3f}"),
           ("pc_fscore", "F@5mm cloud ↑", "{:.3f}"), ("cloud_share", "cloud / surface voxels", "{:.2f}"),
           ("mesh_pieces", "pieces", "{:.0f}"), ("mesh_area_ratio", "area ratio", "{:.2f}"),
           ("mesh_normal_consistency", "normal cons.", "{:.3f}"), ("resolution_mm", "c/2B mm", "{:.1f}"),
           ("seconds", "s", "{:.0f}"))


def simulate_variant(name: str, mesh: str, out: Path) -> Any:
    """The variant's survey, simulated once and kept as ``out/survey.h5``."""
    from shsas_core.formats.hdf5 import read_survey, write_survey
    from shsas_core.simulation.shapes import load_mesh
    from shsas_core.simulation.simulate import simulate_shape
    from shsas_core.simulation.variants import variant_overrides

    path = out / "survey.h5"
    if path.exists():
        return read_survey(path)
    kw = variant_overrides(name, load_mesh(mesh).bounds)
    snr = kw.pop("snr_db", 20.0)
    survey = simulate_shape(mesh, heights=DEMO_HEIGHTS, angles=DEMO_ANGLES, snr_db=snr, seed=0, **kw)
    out.mkdir(parents=True, exist_ok=True)
    write_survey(survey, path)
    return survey


def measure(name: str, mesh: str, methods: list[str], out: Path,
            overrides: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """One row per method of the pipeline's default run on variant ``name`` (the default spec but
    for ``overrides``)."""
    from shsas_core.data.volume import DEFAULT_VOXEL_M
    from shsas_core.pipeline.job import run

    survey = simulate_variant(name, mesh, out)
    gt = survey.ground_truth_mesh()
    rows = []
    for method in methods:
        t = time.perf_counter()
        res = run(ReconstructionSpec(**{"seed": 0, **(overrides or {}), "methods": [method]}), survey, out / method)
        m = res.metrics[method]
        points = m.get("pc_points")
        rows.append({"row": f"{name} / {LABELS.get(method, method)}", "variant": name, "method": method,
                     **{k: m.get(k) for k, _, _ in COLUMNS[1:] if k not in ("cloud_share", "resolution_mm", "seconds")},
                     "cloud_share": None if points is None else points / (gt.area / DEFAULT_VOXEL_M**2),
                     "resolution_mm": 1e3 * survey.meta.range_resolution, "seconds": m.get("seconds"),
                     "wall_s": time.perf_counter() - t})
        print("\n".join(scoreboard.table(COLUMNS, rows[-1:])[2:]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    from shsas_core.simulation.variants import VARIANTS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default=str(DEFAULT_MESH), help="mesh to simulate (default the bunny of ../shared)")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list (default all: {','.join(VARIANTS)})")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"comma list (default {','.join(METHODS)})")
    ap.add_argument("--out", default=str(records.ROOT / "benchmarks" / "out" / "variants"), help="artifacts folder")
    ap.add_argument("--record", action="store_true", help="write benchmarks/results/variants-<scene>.json")
    ap.add_argument("--spec", default=None, metavar="JSON",
                    help='override spec fields, e.g. \'{"sparsity": 0}\' (the record is named after them; '
                    "--out should then be another folder: finished fits are resumed)")
    args = ap.parse_args(argv)
    try:
        overrides = json.loads(args.spec) if args.spec else {}
        ReconstructionSpec(**overrides)
    except (ValueError, TypeError) as exc:
        ap.error(f"--spec: {exc}")
    names = [v for v in args.variants.split(",") if v]
    methods = [m for m in args.methods.split(",") if m]
    unknown = [v for v in names if v not in VARIANTS] + [m for m in methods if m not in METHODS]
    if unknown:
        ap.error(f"unknown variant or method: {', '.join(unknown)}")
    if not Path(args.mesh).exists():
        ap.error(f"--mesh {args.mesh}: no such file")
    scene = Path(args.mesh).stem
    machine, load = records.machine(), records.load()
    t = time.perf_counter()
    rows = [r for v in names for r in measure(v, args.mesh, methods, Path(args.out) / scene / v, overrides)]
    wall = time.perf_counter() - t
    print("\n".join(scoreboard.table(COLUMNS, rows)))
    print(f"variants wall time {wall:.0f} s")
    if args.record:
        what = "; ".join(f"{v}: {VARIANTS[v]}" for v in names)
        record = records.make_record(
            "variants", f"variants-{scene}" + records.override_suffix(overrides),
            f"default spec on surveys unlike the simulator's defaults ({scene}, {DEMO_HEIGHTS} x {DEMO_ANGLES} pings)",
            "python " + " ".join(["benchmarks/bench_variants.py", *(argv if argv is not None else sys.argv[1:])]),
            COLUMNS, rows, machine_info=machine, load_info=load, scene=scene,
            notes=f"spec overrides: {overrides or 'none'}. Variants ({what}). cloud / surface voxels: the cloud's points over the true area / "
                  f"(2.5 mm)². s: each method's pipeline time; the run took {wall:.0f} s wall.")
        print(f"record: {records.write_record(record)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
