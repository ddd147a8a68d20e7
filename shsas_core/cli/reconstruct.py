"""`shsas reconstruct SURVEY [--out DIR]`: run the pipeline on a survey file."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from shsas_core.cli.spec_options import add_spec_options, spec_from_args

__all__ = ["add_spec_options", "console", "print_result", "spec_from_args"]

if TYPE_CHECKING:
    from shsas_core.evaluation.diagnostics import ResultWarning


#: What the default output folder's name adds to the survey's (so a bare re-run resumes).
OUT_SUFFIX = "_reconstruction"


def default_out_dir(survey: str | Path) -> Path:
    """The output folder of ``shsas reconstruct SURVEY`` without ``--out``: the survey's name
    without its suffix plus :data:`OUT_SUFFIX`, in the current folder (a file ``data/scan.h5``,
    a folder ``scan/`` or a zip ``scan.zip`` -> ``scan_reconstruction``)."""
    path = Path(survey)
    name = path.name if path.is_dir() else path.stem
    return Path((name or "survey") + OUT_SUFFIX)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reconstruct", help="reconstruct a survey with backprojection, Reed et al. (L=0) and SH-SAS",
        description="Reconstruct a survey: pulse deconvolution, then each method (time-domain "
        "backprojection; the isotropic neural field of Reed et al., SH degree 0; SH-SAS with SH "
        "degree L), extraction of the surface (its ridge points and a screened-Poisson mesh; --surface and --mesher "
        "choose the paper's threshold cloud and marching cubes instead), export (PLY, GLB, NPY), "
        "metrics when the survey carries a ground-truth mesh, and report.json + report.html. "
        "Re-running with the same --out resumes: finished methods are skipped.",
        epilog="Outputs in DIR: {method}_volume.npy/.json, {method}_pointcloud.ply (vertex property "
        "scalar_magnitude), {method}_mesh.ply, {method}_mesh.glb, report.json, report.html. "
        "A result that looks failed (collapsed volume, cloud filling the scene box, data loss that did "
        "not fall) prints one line 'warning: METHOD: ... (MEASURE vs limit LIMIT)' on stderr and is "
        "flagged in the report; the exit code stays 0, since the job ran (docs/usage.md, Warnings). "
        "Examples: shsas reconstruct survey.h5 (every method at the defaults, into survey"
        f"{OUT_SUFFIX}/); shsas reconstruct survey.h5 --methods backprojection,shsas --iters 2000 --out out/")
    p.add_argument("survey", help="survey file (canonical .h5, AirSAS folder/.zip/.pkl, SVSS .hdf5)")
    p.add_argument("--out", metavar="DIR", help="output folder (created; reused to resume); default: "
                   f"SURVEY's name without its suffix plus '{OUT_SUFFIX}', in the current folder "
                   f"(scan.h5 -> scan{OUT_SUFFIX}/)")
    add_spec_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.common.progress import TqdmProgress
    from shsas_core.pipeline.job import run as run_pipeline
    from shsas_core.spec.memory import memory_budget

    spec = spec_from_args(args)
    budget = memory_budget()
    bar = TqdmProgress(disable=args.quiet)
    try:
        out = Path(args.out) if args.out else default_out_dir(args.survey)
        result = run_pipeline(spec, args.survey, out, progress=bar, memory_budget=budget)
    finally:
        bar.close()
    print_result(result)
    return 0


def print_result(result) -> None:
    """The metrics table (when there are metrics), warnings about failed-looking results (stderr)
    and where the outputs are."""
    con = console()
    if any(k.startswith(("pc_", "fixed_", "mesh_")) for m in result.metrics.values() for k in m):
        con.print(metrics_table(result.metrics))
    if not any(k.startswith("pc_") for m in result.metrics.values() for k in m):
        con.print("no ground truth in the survey: no geometry scores (only the mesh's pieces)")
    print_warnings(result.warnings)
    out = Path(result.out_dir)
    con.print(f"outputs in [bold]{out}[/bold]: {', '.join(result.artifacts)}")
    con.print(f"report: [bold]{result.report_html}[/bold]")
    con.print("timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in result.timings.items()))


def print_warnings(warnings: Mapping[str, Sequence[ResultWarning]]) -> None:
    """One line ``warning: METHOD: MESSAGE (MEASURE vs limit LIMIT)`` per warning on stderr
    (plain text: a log or grep reads it as it is)."""
    sys.stdout.flush()  # keep the order of the table and the warnings when both go to one terminal
    for method, found in warnings.items():
        for w in found:
            print(f"warning: {w.line(method)}", file=sys.stderr)


def console():
    """A rich console; wide enough for the metrics table when output goes to a file or pipe."""
    from rich.console import Console

    con = Console()
    return con if con.is_terminal else Console(width=160)


def metrics_table(metrics: Mapping[str, Mapping[str, float]], title: str = "metrics"):
    """A rich table: one row per method and output (point cloud, mesh)."""
    from rich.table import Table

    from shsas_core.outputs.report import OUTPUT_ROWS, TABLE_COLUMNS

    table = Table(title=title)
    table.add_column("method")
    table.add_column("output")
    for _, head, _ in TABLE_COLUMNS:
        table.add_column(head, justify="right")
    for method, m in metrics.items():
        for rep, label in OUTPUT_ROWS:
            if not any(k.startswith(rep + "_") for k in m):
                continue
            cells = []
            for key, _, fmt in TABLE_COLUMNS:
                v = m.get(f"{rep}_{key}")
                cells.append("–" if v is None or not math.isfinite(v) else fmt.format(v))
            table.add_row(method, label, *cells)
    return table
