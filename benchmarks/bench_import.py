"""How fast does the AirSAS CSV importer read a scan?

Writes (once, to $SHSAS_BENCH_CACHE or ``$TMPDIR/shsas-bench``) a synthetic AirSAS scan folder of
``--pings`` flights x 1,500 samples in the acquisition layout, then prints the wall time of the
header-only read (what `shsas info` does) and of the full import, with pings per second and the
extrapolated time for a full 54,000-ping scan. Prints figures only; never asserts.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from shsas_core.data.pulse import lfm_pulse  # noqa: E402
from shsas_core.formats.airsas_csv import read_airsas_csv  # noqa: E402

FS, T = 100e3, 1_500


def build(folder: Path, n: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    ang = np.arange(n) % 360
    h = 5.0 * (np.arange(n) // 360)
    (folder / "Coordinates.csv").write_text(
        "Flight,Angle,Height,Temperature,Waveform\n"
        + "".join(f"{i + 1},{a:.1f},{z:.1f},21.0,0\n" for i, (a, z) in enumerate(zip(ang, h, strict=True))))
    (folder / "SysParams.csv").write_text(
        "Speaker x,0.85\nSpeaker y,0\nSpeaker z,0.11\nMic1 x,0.863\nMic1 y,0\nMic1 z,0.072\n"
        "Center x,0\nCenter y,0\nCenter z,0\nGroup Delay,12\nFs,100000\n")
    (folder / "WaveformParams.csv").write_text("LFM_1.000E+4Hz_3.000E+4Hz_1.000E-3s_1_1_1.000E-1\n")
    pulse = lfm_pulse(10e3, 30e3, 1e-3, FS, "tukey", 0.1)
    (folder / "Waveforms.csv").write_text("".join(f"{v!r}\n" for v in pulse.tolist()))
    rng = np.random.default_rng(0)
    for i in range(n):
        x = rng.standard_normal(T) * 1e-3
        (folder / f"Flight-{i + 1:06d}.csv").write_text("\n".join(f"{v:.6e}" for v in x) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pings", type=int, default=3_600)
    args = ap.parse_args()
    cache = Path(os.environ.get("SHSAS_BENCH_CACHE", Path(tempfile.gettempdir()) / "shsas-bench"))
    folder = cache / f"airsas_{args.pings}"
    if not (folder / f"Flight-{args.pings:06d}.csv").exists():
        t = time.perf_counter()
        build(folder, args.pings)
        print(f"wrote {folder} in {time.perf_counter() - t:.1f} s")
    t = time.perf_counter()
    h = read_airsas_csv(folder, load_samples=False)
    th = time.perf_counter() - t
    t = time.perf_counter()
    s = read_airsas_csv(folder)
    tf = time.perf_counter() - t
    print(f"scan: {args.pings} flights x {T} samples -> survey {s.shape}")
    print(f"header-only read : {th:.3f} s  (shape {h.shape})")
    print(f"full import      : {tf:.2f} s  = {args.pings / tf:.0f} pings/s "
          f"-> ~{54_000 / (args.pings / tf):.0f} s for a 54,000-ping scan")


if __name__ == "__main__":
    main()
