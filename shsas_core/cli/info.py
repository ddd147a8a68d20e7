"""`shsas info FILE`: summary of a survey without loading its samples."""

from __future__ import annotations

import argparse
import json
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info", help="summarise a survey file (pings, samples, band, geometry, scene box)",
        description="Print a summary of a survey: number of pings and samples, signal band, "
        "sensor extent and scene box. Reads only metadata and geometry, so it is fast on "
        "large files. Accepts any format `shsas convert` reads.")
    p.add_argument("file", help="survey file (canonical .h5, AirSAS folder/.zip/.pkl, SVSS .hdf5)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.formats import load_survey
    from shsas_core.formats.hdf5 import summarize

    survey = load_survey(args.file, load_samples=False)
    s = summarize(survey)
    # A file that loads but will not process well (its two pulse descriptions disagree) is
    # still shown, with the reason on stderr; the service refuses such an upload.
    for warning in s["warnings"]:
        print(f"shsas info: warning: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    s = {k: v for k, v in s.items() if k != "warnings"}
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"survey: {args.file}", show_header=False)
    for k, v in s.items():
        if k == "elevation":  # the sentence says what the numbers mean for imaging
            v = v["message"]
        table.add_row(k, json.dumps(v) if isinstance(v, dict | list) else str(v))
    Console().print(table)
    return 0
