"""`shsas autofocus SURVEY OUT.h5`: estimate wrong or unknown geometry from image sharpness."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "autofocus", help="estimate sound speed, range offset, level heights, radius by image sharpness",
        description="Search the survey parameters named by --params for the sharpest fast, "
        "low-resolution backprojection (image entropy or contrast; coarse grid per parameter, then a "
        "joint Powell refinement), repeat the search on disjoint ping subsets, and apply only the "
        "corrections the data identify (the image sharpens clearly over one resolution step and the "
        "subsets agree); the others keep their input values and the output says why. Writes the "
        "corrected survey as canonical HDF5 with the original values and every parameter's "
        "identifiability in meta.attrs['autofocus']. Single-height surveys are imaged in one plane "
        "(--plane-z, default the plane of best focus) and estimate the sound speed alone by default: "
        "on them sound speed, range offset and the plane's height trade off (docs/usage.md, "
        "'shsas autofocus').",
        epilog="Example: shsas autofocus scan.h5 focused.h5 --plane-z Z  (Z: the height of the plane "
        "the scene lies in, m)")
    p.add_argument("survey", help="survey file (canonical .h5 or any format `shsas convert` reads)")
    p.add_argument("output", help="output .h5 path for the corrected survey")
    p.add_argument("--params", default=None,
                   help="comma-separated: sound_speed, range_offset, level_z, radius (default: sound_speed "
                   "on single-height surveys, sound_speed,range_offset on 3-D ones)")
    p.add_argument("--measure", choices=["entropy", "contrast"], default="entropy",
                   help="sharpness measure (default entropy)")
    p.add_argument("--plane-z", type=float, default=None,
                   help="single-height surveys: height of the imaged plane, m (default: best focus "
                   "under the input geometry)")
    p.add_argument("--pixels", type=int, default=48, help="search image pixels along the longest axis")
    p.add_argument("--max-pings", type=int, default=360, help="evenly spaced pings used by the search")
    p.add_argument("--subsets", type=int, default=3,
                   help="disjoint interleaved ping subsets whose estimates give each parameter's spread")
    p.add_argument("--level-knots", type=int, default=None,
                   help="level_z as a piecewise-linear function of height with this many knots (2: a "
                   "wrong height step); default: every level's offset free")
    p.add_argument("--background", default=None,
                   help="AirSAS CSV input: empty-scene scan folder/.zip to subtract")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    import pydantic

    from shsas_core.common.errors import ShsasError, pydantic_fix
    from shsas_core.formats import load_survey
    from shsas_core.formats.hdf5 import write_survey
    from shsas_core.imaging.autofocus import PARAMETERS, AutofocusConfig, apply_result, autofocus

    params = None
    if args.params is not None:
        params = tuple(p.strip() for p in args.params.split(",") if p.strip())
        unknown = [p for p in params if p not in PARAMETERS]
        if unknown or not params:
            raise ShsasError(f"--params: {', '.join(unknown) or 'nothing'} is not a parameter (fix: use a "
                             f"comma-separated list of {', '.join(PARAMETERS)})")
    try:
        cfg = AutofocusConfig(parameters=params, measure=args.measure, plane_z=args.plane_z,
                              pixels=args.pixels, max_pings=args.max_pings, level_z_knots=args.level_knots,
                              subsets=args.subsets)
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        name = {"pixels": "--pixels", "max_pings": "--max-pings", "level_z_knots": "--level-knots",
                "subsets": "--subsets"}.get(str(err["loc"][0]), str(err["loc"][0]))
        raise ShsasError(f"{name}: {err['msg']} (fix: "
                         f"{pydantic_fix(err, list(AutofocusConfig.model_fields), 'shsas autofocus --help')})"
                         ) from None
    options = {"background": args.background} if args.background is not None else {}
    survey = load_survey(args.survey, **options)
    result = autofocus(survey, config=cfg)
    out = write_survey(apply_result(survey, result), args.output)
    # plain words first (stderr, one line per parameter), the machine-readable line on stdout
    for r in result.identifiability:
        print(r.message, file=sys.stderr)
    c = result.correction
    print(json.dumps({
        "out": str(out), "summary": result.summary, "parameters": result.parameters,
        "sound_speed_m_s": round(c.sound_speed, 4),
        "original_sound_speed_m_s": round(result.original_sound_speed, 4),
        "range_offset_m": round(c.range_offset_m, 6), "level_z_m": [round(v, 6) for v in c.level_z_m],
        "radius_offset_m": round(c.radius_offset_m, 6), "plane_z_m": result.plane_z,
        "identifiability": [r.model_dump() for r in result.identifiability],
        f"{result.measure}_before": round(result.cost_before, 5), f"{result.measure}_after":
        round(result.cost_after, 5), "evaluations": result.evaluations,
        "seconds": round(result.seconds, 2), "notes": result.notes}))
    return 0
