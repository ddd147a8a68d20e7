"""`shsas reconstruct SURVEY --methods ... --out DIR`: run the pipeline on a survey file."""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping
from pathlib import Path

from ..errors import ShsasError

METHOD_HELP = "comma-separated: backprojection, reed (isotropic neural, SH degree 0), shsas (SH degree --sh-degree)"


def add_spec_options(p: argparse.ArgumentParser) -> None:
    """Options that map one-to-one onto :class:`~shsas_core.spec.ReconstructionSpec` fields."""
    g = p.add_argument_group("reconstruction spec (defaults: shsas_core.spec.ReconstructionSpec)")
    g.add_argument("--methods", default=None, help=METHOD_HELP + " (default: all three)")
    g.add_argument("--sh-degree", type=int, default=None, metavar="L", help="SH degree of method shsas, 0-3 (default 3)")
    g.add_argument("--iters", type=int, default=None, help="training iterations per neural method (default 1500)")
    g.add_argument("--grid", type=int, default=None, help="voxels along the longest scene-box axis (default 64)")
    g.add_argument("--device", default=None, help="auto, cpu, cuda or cuda:N (default auto)")
    g.add_argument("--threshold", type=float, default=None, metavar="TAU",
                   help="iso level on the [0,1]-normalised magnitude (default: Otsu rule, see docs/usage.md)")
    g.add_argument("--deconv", choices=["wiener", "neural", "none"], default=None,
                   help="pulse deconvolution (default wiener)")
    g.add_argument("--seed", type=int, default=None, help="seed of everything random (default 0)")
    g.add_argument("--bins", type=int, default=None, help="range bins rendered per ping per iteration (default 64)")
    g.add_argument("--rays", type=int, default=None, help="rays per ping per iteration (default 1024)")
    g.add_argument("--pings-per-batch", type=int, default=None, help="pings per training iteration (default 1)")
    g.add_argument("--lr", type=float, default=None, help="Adam learning rate of the neural methods (default 1e-3)")
    g.add_argument("--lr-final", type=float, default=None,
                   help="learning rate at the last iteration, decayed exponentially from --lr (default: constant lr)")
    g.add_argument("--encoding", choices=["cpu", "small", "paper_gpu"], default=None,
                   help="hash-encoding preset: cpu (default), small (fastest, short CPU runs), paper_gpu")
    g.add_argument("--target", choices=["coherent", "envelope"], default=None,
                   help="data term of the neural methods: coherent = complex s_PD as in the paper "
                   "(reconstruct's default), envelope = |s_PD| (converges at CPU budgets; the "
                   "demo's default; see docs/neural.md)")
    g.add_argument("--holdout", type=float, default=None, metavar="FRACTION",
                   help="share of pings held out for novel-view signal errors (default 0)")


def spec_from_args(args: argparse.Namespace, **defaults: object):
    """Build and validate the spec; ``defaults`` apply where an option was not given."""
    import pydantic

    from ..spec import ReconstructionSpec

    fields = {"methods": "methods", "sh_degree": "sh_degree", "iters": "iters", "grid": "grid",
              "device": "device", "threshold": "threshold", "deconv": "deconvolution", "seed": "seed",
              "bins": "num_bins", "rays": "num_rays", "pings_per_batch": "pings_per_batch",
              "holdout": "holdout_fraction", "lr": "lr", "lr_final": "lr_final", "encoding": "encoding",
              "target": "target"}
    kw: dict[str, object] = dict(defaults)
    for opt, field in fields.items():
        v = getattr(args, opt, None)
        if v is not None:
            kw[field] = v
    if isinstance(kw.get("methods"), str):
        kw["methods"] = [m.strip() for m in str(kw["methods"]).split(",") if m.strip()]
    try:
        return ReconstructionSpec(**kw)
    except pydantic.ValidationError as exc:
        e = exc.errors()[0]
        loc = ".".join(str(x) for x in e["loc"])
        opt = {v: k for k, v in fields.items()}.get(str(e["loc"][0]), loc).replace("_", "-")
        raise ShsasError(f"--{opt}: {e['msg']} (got {e.get('input')!r})") from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reconstruct", help="reconstruct a survey with backprojection, Reed et al. (L=0) and SH-SAS",
        description="Reconstruct a survey: pulse deconvolution, then each method (time-domain "
        "backprojection; the isotropic neural field of Reed et al., SH degree 0; SH-SAS with SH "
        "degree L), extraction of a point cloud and a marching-cubes mesh, export (PLY, GLB, NPY), "
        "metrics when the survey carries a ground-truth mesh, and report.json + report.html. "
        "Re-running with the same --out resumes: finished methods are skipped.",
        epilog="Outputs in DIR: {method}_volume.npy/.json, {method}_pointcloud.ply (vertex property "
        "scalar_magnitude), {method}_mesh.ply, {method}_mesh.glb, report.json, report.html. "
        "Example: shsas reconstruct survey.h5 --methods backprojection,shsas --iters 2000 --out out/")
    p.add_argument("survey", help="survey file (canonical .h5, AirSAS folder/.zip/.pkl, SVSS .hdf5)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created; reused to resume)")
    add_spec_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..memory import memory_budget
    from ..pipeline import run as run_pipeline
    from ..progress import TqdmProgress

    spec = spec_from_args(args)
    budget = memory_budget()
    bar = TqdmProgress(disable=args.quiet)
    try:
        result = run_pipeline(spec, args.survey, Path(args.out), progress=bar, memory_budget=budget)
    finally:
        bar.close()
    print_result(result)
    return 0


def print_result(result) -> None:
    """The metrics table (when there are metrics) and where the outputs are."""
    con = console()
    if any(k.startswith(("pc_", "mesh_")) for m in result.metrics.values() for k in m):
        con.print(metrics_table(result.metrics))
    else:
        con.print("no ground truth in the survey: no geometry metrics")
    out = Path(result.out_dir)
    con.print(f"outputs in [bold]{out}[/bold]: {', '.join(result.artifacts)}")
    con.print(f"report: [bold]{result.report_html}[/bold]")
    con.print("timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in result.timings.items()))


def console():
    """A rich console; wide enough for the metrics table when output goes to a file or pipe."""
    from rich.console import Console

    con = Console()
    return con if con.is_terminal else Console(width=160)


def metrics_table(metrics: Mapping[str, Mapping[str, float]], title: str = "metrics (design §5)"):
    """A rich table: one row per method and output (point cloud, mesh)."""
    from rich.table import Table

    from ..report import TABLE_COLUMNS

    table = Table(title=title)
    table.add_column("method")
    table.add_column("output")
    for _, head, _ in TABLE_COLUMNS:
        table.add_column(head, justify="right")
    for method, m in metrics.items():
        for rep, label in (("pc", "point cloud"), ("mesh", "mesh")):
            if not any(k.startswith(rep + "_") for k in m):
                continue
            cells = []
            for key, _, fmt in TABLE_COLUMNS:
                v = m.get(f"{rep}_{key}")
                cells.append("–" if v is None or not math.isfinite(v) else fmt.format(v))
            table.add_row(method, label, *cells)
    return table
