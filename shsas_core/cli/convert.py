"""`shsas convert IN OUT.h5`: import any supported survey format into the canonical file."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from shsas_core.formats import all_formats

    formats = all_formats()
    p = sub.add_parser(
        "convert", help="import a survey in any format shsas reads into canonical HDF5",
        description="Convert a survey into the canonical shsas HDF5 file (docs/formats.md). "
        "The input format is detected from its contents; the formats: "
        + "; ".join(f"{f.name}: {f.summary}" for f in formats) + ".")
    p.add_argument("input", help="input survey: file or folder")
    p.add_argument("output", help="output .h5 path")
    p.add_argument("--format", default="auto", choices=("auto", *(f.name for f in formats)),
                   help="force the input format (default auto: detected from the contents)")
    p.add_argument("--compression", choices=["none", "gzip", "lzf"], default="none",
                   help="compress sample arrays (default none: fastest to read)")
    p.add_argument("--background", default=None,
                   help="AirSAS: empty-scene scan folder/.zip to subtract (default: a background/ "
                   "subfolder when present)")
    p.add_argument("--waveform", type=int, default=None,
                   help="AirSAS: index of the interleaved waveform to keep (default: the first ping's)")
    p.add_argument("--image-number", type=int, default=None,
                   help="SVSS: image number N when the track folder holds several")
    p.add_argument("--geometry", default=None,
                   help="AirSAS deconvolved pings (weights_trans_*.npy): JSON file of the geometry fields "
                   "(docs/formats.md, 'AirSAS deconvolved pings'; default: the 2022 SysParams, 5 mm levels)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.formats import load_survey
    from shsas_core.formats.hdf5 import write_survey

    options = {}
    if args.background is not None:
        options["background"] = args.background
    if args.waveform is not None:
        options["waveform"] = args.waveform
    if args.image_number is not None:
        options["image_number"] = args.image_number
    if args.geometry is not None:
        options["geometry"] = args.geometry
    import sys

    from shsas_core.common.progress import TqdmProgress

    # the bar goes to stderr; keep stderr to the one-line error when it is not a terminal
    bar = TqdmProgress(disable=not sys.stderr.isatty())
    try:
        survey = load_survey(args.input, fmt=args.format, progress=bar, **options)
    finally:
        bar.close()
    out = write_survey(survey, args.output, compression=None if args.compression == "none" else args.compression)
    print(f"wrote {out} ({survey.num_pings} pings x {survey.num_samples} samples)")
    return 0
