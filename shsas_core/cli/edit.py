"""`shsas edit IN.h5 OUT.h5`: correct a survey's geometry or keep a subset of its pings."""

from __future__ import annotations

import argparse


def _numbers(text: str, what: str, count: int | None = None) -> list[float]:
    from shsas_core.common.errors import ShsasError

    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ShsasError(f"{what} {text!r}: give comma-separated numbers") from None
    if count is not None and len(values) != count:
        raise ShsasError(f"{what} {text!r}: give {count} comma-separated numbers, got {len(values)}")
    return values


def _indices(text: str) -> list[int]:
    """``"0,3,7"`` or a range ``"0:150:10"`` (start:stop[:step], stop excluded)."""
    from shsas_core.common.errors import ShsasError

    try:
        if ":" in text:
            parts = [int(p) if p else None for p in text.split(":")]
            if len(parts) not in (2, 3) or parts[1] is None:
                raise ValueError
            return list(range(parts[0] or 0, parts[1], parts[2] if len(parts) == 3 and parts[2] else 1))
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ShsasError(f"--levels {text!r}: give level indices (0,3,7) or a range (start:stop[:step])") from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "edit", help="correct a survey's sound speed, range offset, scene box or level heights, or keep a "
        "subset of its pings",
        description="Write a copy of a canonical survey with its geometry corrected or its pings "
        "subsampled (docs/usage.md, 'shsas edit'). Subsets are taken first (levels, then --every, then "
        "--count), then the level heights, sound speed, range offset and scene box are set. The samples "
        "are never resampled; metadata that counts pings (meta.attrs pings_per_level, height_levels) is "
        "made true for the pings kept, and every edit is appended to meta.attrs['edits'].")
    p.add_argument("input", help="canonical survey .h5 (see `shsas convert` for other formats)")
    p.add_argument("output", help="output .h5 path (written atomically; may be the input)")
    p.add_argument("--sound-speed", metavar="C",
                   help="sound speed: m/s (343.2), a change in m/s (+0.7, -0.7) or in percent (+2%%, -0.5%%); "
                   "write a value that starts with a minus sign as --sound-speed=-2%%")
    p.add_argument("--range-offset", type=float, metavar="DR",
                   help="one-way range offset to remove, m: echoes arrived 2 DR / c later than t0 says, so "
                   "t0 moves earlier by that time (leading samples are dropped if it would go below 0); "
                   "the sign of `shsas autofocus`'s range_offset")
    p.add_argument("--box", metavar="XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
                   help="scene box, m: six comma-separated numbers (min corner, then max corner); write it as "
                   "--box=-0.1,... when it starts with a minus sign")
    p.add_argument("--level-z", metavar="Z1,Z2,...",
                   help="TX height of each height level after the edit, m, lowest level first (one per level "
                   "kept); each level's TX and RX move together (--level-z=-0.1,... for a leading minus)")
    p.add_argument("--levels", metavar="LIST",
                   help="keep only these height levels: indices from 0 for the lowest (0,3,7) or a range "
                   "start:stop[:step] (0:150:10)")
    p.add_argument("--every", type=int, metavar="K",
                   help="keep every K-th ping of each level in recorded order (a turntable step K times as "
                   "large), the first of each level kept")
    p.add_argument("--count", type=int, metavar="N", help="keep N pings evenly spaced over the survey")
    p.add_argument("--compression", choices=["none", "gzip", "lzf"], default="none",
                   help="compress sample arrays in the output (default none)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.common.errors import ShsasError
    from shsas_core.data import edit
    from shsas_core.data.survey import SceneBox
    from shsas_core.formats.hdf5 import read_survey, write_survey

    edits = [args.sound_speed, args.range_offset, args.box, args.level_z, args.levels, args.every, args.count]
    if all(e is None for e in edits):
        raise ShsasError("nothing to edit: give at least one of --sound-speed, --range-offset, --box, "
                         "--level-z, --levels, --every, --count (see shsas edit --help)")
    survey = read_survey(args.input)
    if args.levels is not None:
        survey = edit.keep_levels(survey, _indices(args.levels))
    if args.every is not None:
        survey = edit.every_step(survey, args.every)
    if args.count is not None:
        survey = edit.keep_count(survey, args.count)
    if args.level_z is not None:
        survey = edit.set_level_heights(survey, _numbers(args.level_z, "--level-z"))
    if args.sound_speed is not None:
        survey = edit.set_sound_speed(survey, edit.parse_sound_speed(args.sound_speed, survey.meta.sound_speed))
    if args.range_offset is not None:
        survey = edit.shift_range(survey, args.range_offset)
    if args.box is not None:
        v = _numbers(args.box, "--box", 6)
        try:
            box = SceneBox(min=tuple(v[:3]), max=tuple(v[3:]))  # type: ignore[arg-type]
        except ValueError as exc:  # pydantic's error: say it in one line
            raise ShsasError(f"--box {args.box!r}: {exc.errors()[0]['msg']}") from None  # type: ignore[attr-defined]
        survey = edit.set_scene_box(survey, box)
    out = write_survey(survey, args.output, compression=None if args.compression == "none" else args.compression)
    print(f"wrote {out} ({survey.num_pings} pings x {survey.num_samples} samples): {survey.meta.attrs['edits']}")
    return 0
