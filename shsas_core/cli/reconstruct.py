"""`shsas reconstruct SURVEY --methods ... --out DIR`: run the pipeline on a survey file."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ShsasError

if TYPE_CHECKING:
    from ..diagnostics import ResultWarning

METHOD_HELP = "comma-separated: backprojection, reed (isotropic neural, SH degree 0), shsas (SH degree --sh-degree)"


def _default(field: str) -> str:
    """``(default X)`` from the spec itself, so the help cannot disagree with what runs."""
    from ..spec import ReconstructionSpec

    return f"(default {ReconstructionSpec.model_fields[field].default})"


def add_spec_options(p: argparse.ArgumentParser) -> None:
    """Options that map one-to-one onto :class:`~shsas_core.spec.ReconstructionSpec` fields."""
    from ..spec import PRESETS

    g = p.add_argument_group("reconstruction spec (defaults: shsas_core.spec.ReconstructionSpec)")
    g.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="start from a named setting: default (the best measured on a CPU) or paper "
                   "(the paper's: empty start, 200 bins x 4,800 rays, paper_gpu encoding, 50k "
                   "iterations; needs a GPU); other options override it")
    g.add_argument("--methods", default=None, help=METHOD_HELP + " (default: all three)")
    g.add_argument("--sh-degree", type=int, default=None, metavar="L",
                   help=f"SH degree of method shsas, 0-3 {_default('sh_degree')}")
    g.add_argument("--iters", type=int, default=None,
                   help=f"training iterations per neural method {_default('iters')}")
    g.add_argument("--grid", type=int, default=None,
                   help="voxels along the longest scene-box axis (default: voxels of at most 2.5 mm)")
    g.add_argument("--device", default=None, help=f"auto, cpu, cuda or cuda:N {_default('device')}")
    g.add_argument("--threshold", type=float, default=None, metavar="TAU",
                   help="iso level on the [0,1]-normalised magnitude (default: Otsu rule, see docs/usage.md)")
    g.add_argument("--deconv", choices=["wiener", "neural", "none"], default=None,
                   help=f"pulse deconvolution {_default('deconvolution')}")
    g.add_argument("--seed", type=int, default=None, help=f"seed of everything random {_default('seed')}")
    g.add_argument("--bins", type=int, default=None,
                   help=f"range bins rendered per ping per iteration {_default('num_bins')}")
    g.add_argument("--rays", type=int, default=None, help=f"rays per ping per iteration {_default('num_rays')}")
    g.add_argument("--pings-per-batch", type=int, default=None,
                   help=f"pings per training iteration {_default('pings_per_batch')}")
    g.add_argument("--lr", type=float, default=None,
                   help=f"Adam learning rate of the neural methods {_default('lr')}")
    g.add_argument("--lr-final", type=float, default=None,
                   help="learning rate at the last iteration, decayed exponentially from --lr (default: constant lr)")
    g.add_argument("--forward", choices=["psf", "impulse"], default=None,
                   help="forward model of the neural methods: psf = the rendered impulse response "
                   "convolved with the deconvolution's point-spread kernel, impulse = the paper's "
                   f"ideal-deconvolution model {_default('forward')}")
    g.add_argument("--init", choices=["backprojection", "none"], default=None,
                   help="start of the neural methods: backprojection = distil the backprojection image "
                   f"into the field first, none = the paper's empty field {_default('init')}")
    g.add_argument("--occupancy", type=_level_or_none, default=None, metavar="LEVEL",
                   help="occupancy grid of the neural methods: evaluate the field only where the "
                   "backprojection image's normalised magnitude exceeds LEVEL (dilated 2 voxels); "
                   f"'none' = the whole scene box {_default('occupancy')}")
    g.add_argument("--sparsity", type=float, default=None, metavar="WEIGHT",
                   help=f"weight of the L1 sparsity prior on the field's density, 0 = off {_default('sparsity')}")
    g.add_argument("--encoding", choices=["cpu", "small", "paper_gpu"], default=None,
                   help="hash-encoding preset: cpu, small (fastest, short CPU runs), paper_gpu "
                   f"{_default('encoding')}")
    g.add_argument("--target", choices=["coherent", "envelope"], default=None,
                   help="data term of the neural methods: coherent = complex s_PD as in the paper, "
                   f"envelope = |s_PD| (see docs/neural.md) {_default('target')}")
    g.add_argument("--holdout", type=float, default=None, metavar="FRACTION",
                   help=f"share of pings held out for novel-view signal errors {_default('holdout_fraction')}")


_NONE = "none"


def _level_or_none(text: str) -> float | str:
    """``--occupancy`` value: a float, or ``none`` (mapped to None below); anything else is left
    to the spec's validation, which names the option in its one-line error."""
    if text.strip().lower() == _NONE:
        return _NONE
    try:
        return float(text)
    except ValueError:
        return text


def spec_from_args(args: argparse.Namespace, **defaults: object):
    """Build and validate the spec; ``defaults`` apply where an option was not given."""
    import pydantic

    from ..spec import ReconstructionSpec

    fields = {"methods": "methods", "sh_degree": "sh_degree", "iters": "iters", "grid": "grid",
              "device": "device", "threshold": "threshold", "deconv": "deconvolution", "seed": "seed",
              "bins": "num_bins", "rays": "num_rays", "pings_per_batch": "pings_per_batch",
              "holdout": "holdout_fraction", "lr": "lr", "lr_final": "lr_final", "encoding": "encoding",
              "target": "target", "init": "init", "forward": "forward", "occupancy": "occupancy",
              "sparsity": "sparsity"}
    from ..spec import PRESETS

    kw: dict[str, object] = dict(defaults)
    kw.update(PRESETS[getattr(args, "preset", None) or "default"])
    for opt, field in fields.items():
        v = getattr(args, opt, None)
        if v is not None:
            kw[field] = None if v == _NONE else v
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
        "A result that looks failed (collapsed volume, cloud filling the scene box, data loss that did "
        "not fall) prints one line 'warning: METHOD: ... (MEASURE vs limit LIMIT)' on stderr and is "
        "flagged in the report; the exit code stays 0, since the job ran (docs/usage.md, Warnings). "
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
    """The metrics table (when there are metrics), warnings about failed-looking results (stderr)
    and where the outputs are."""
    con = console()
    if any(k.startswith(("pc_", "fixed_", "mesh_")) for m in result.metrics.values() for k in m):
        con.print(metrics_table(result.metrics))
    else:
        con.print("no ground truth in the survey: no geometry metrics")
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


def metrics_table(metrics: Mapping[str, Mapping[str, float]], title: str = "metrics (design §5)"):
    """A rich table: one row per method and output (point cloud, mesh)."""
    from rich.table import Table

    from ..report import OUTPUT_ROWS, TABLE_COLUMNS

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
