"""How soon a cancel lands inside the signal chain: Wiener deconvolution of long pings.

A survey of ``--pings`` x ``--samples`` random samples is deconvolved (analytic signal, then the
Wiener filter, as the pipeline's deconvolution step does) while another thread asks it to stop
``--after`` seconds in; prints the seconds from the request to the ``Cancelled`` exception.
Prints; never asserts.

    PYTHONPATH=$PWD python benchmarks/bench_cancel.py [--pings 60] [--samples 1000000] [--after 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from shsas_core.common.errors import Cancelled
from shsas_core.data.survey import Survey, SurveyMeta, default_pulse
from shsas_core.signal.deconv import deconvolve


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pings", type=int, default=60)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--after", type=float, default=1.0, help="seconds before the cancel is requested")
    args = ap.parse_args()
    n, t = args.pings, args.samples
    meta = SurveyMeta(platform="bench")
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(n, 0.3)], 1)
    samples = np.random.default_rng(0).standard_normal((n, t)).astype(np.float32)
    survey = Survey(tx=tx, rx=tx + np.array([0.0, 0.0, -0.038]), samples=samples, t0=np.full(n, 3e-3), meta=meta,
                    pulse=default_pulse(meta))
    asked: list[float] = []
    threading.Timer(args.after, lambda: asked.append(time.monotonic())).start()
    t0 = time.monotonic()
    try:
        deconvolve(survey, should_stop=lambda: bool(asked))
        print(f"finished in {time.monotonic() - t0:.1f} s before the cancel was asked")
    except Cancelled:
        print(f"{n} x {t} samples, load average {os.getloadavg()[0]:.1f}: cancel landed "
              f"{time.monotonic() - asked[0]:.2f} s after it was asked ({args.after:g} s in)")


if __name__ == "__main__":
    main()
