"""The plane of focus of single-height scans, by each sharpness measure, side by side.

For the real AirSAS cut-out scan (``../shared/data/airsas/cutout_20k`` less ``bg_20k``), the
same recording filtered to 5 kHz around 20 kHz (``tests/core/narrowband.py``) and a simulated
narrowband single-height scan of points in one plane (``tests/core/focus_scenes.py``), prints
what :func:`shsas_core.imaging.planar.find_focus` finds with each measure and each imaging backend
(eager, or the ``torch.compile``-d kernel): the height, whether it is a focus, the heights
searched, the range resolution and the seconds taken. Each backend runs in a fresh process, as a
report's search does in a worker, so the first search's seconds include any compilation.

    python benchmarks/bench_focus.py [--measures entropy,contrast] [--only filtered,simulated]
                                     [--backends eager,compiled]

Never asserts.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from shsas_core.imaging.planar import find_focus  # noqa: E402
from shsas_core.signal.deconv import deconvolve  # noqa: E402


def scans() -> list[tuple[str, object, float | None]]:
    """(name, survey, true plane height or None) for each scan that is available."""
    from tests.helpers.focus_scenes import NARROW_BAND_HZ, PLANE_Z, plane_scene
    from tests.helpers.narrowband import band_limited

    out: list[tuple[str, object, float | None]] = []
    data = ROOT / ".." / "shared" / "data" / "airsas"
    if (data / "cutout_20k").is_dir():
        from shsas_core.formats import load_survey

        real = load_survey(data / "cutout_20k", background=data / "bg_20k")
        out += [("AirSAS cut-out, 10-30 kHz", real, None),
                ("AirSAS cut-out filtered to 17.5-22.5 kHz", band_limited(real, 20e3, 5e3), None)]
    else:
        print(f"(no {data}: real scans left out)")
    out.append(("simulated points, 17.5-22.5 kHz, 20 dB", plane_scene(band_hz=NARROW_BAND_HZ, snr_db=20.0),
                PLANE_Z))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--measures", default="entropy,contrast")
    ap.add_argument("--only", default="", help="comma-separated words: only the scans whose name holds one")
    ap.add_argument("--backends", default="eager,compiled", help="imaging backends, each in a fresh process")
    ap.add_argument("--backend", choices=("eager", "compiled"), help=argparse.SUPPRESS)  # one child's
    args = ap.parse_args()
    if args.backend is None:
        print(f"host {os.uname().nodename}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
        print(f"{'scan':44s} {'measure':9s} {'backend':9s} {'z (mm)':>8s} {'true':>6s} {'found':>6s} "
              f"{'searched (m)':>15s} {'c/2B (mm)':>9s} {'s':>6s}")
        for backend in args.backends.split(","):
            subprocess.run([sys.executable, __file__, "--backend", backend, "--measures", args.measures,
                            "--only", args.only], check=True)
        return
    words = [w for w in args.only.split(",") if w]
    for name, survey, truth in scans():
        if words and not any(w in name for w in words):
            continue
        sig = deconvolve(survey)
        for measure in args.measures.split(","):
            t = time.perf_counter()
            f = find_focus(survey, sig, measure=measure, compiled=args.backend == "compiled")  # type: ignore[arg-type]
            lo, hi = f.z_range
            true = "-" if truth is None else f"{1e3 * truth:.1f}"
            print(f"{name:44s} {measure:9s} {args.backend:9s} {1e3 * f.z:8.1f} {true:>6s} {f.found!s:>6s} "
                  f"{lo:+.3f}..{hi:+.3f} {1e3 * f.range_resolution_m:9.1f} {time.perf_counter() - t:6.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
