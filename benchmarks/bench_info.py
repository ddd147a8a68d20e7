"""How fast is `shsas info` on a full-size survey (54,000 pings x 1,500 samples)?

Writes the survey once to a cache folder ($SHSAS_BENCH_CACHE, default
``$TMPDIR/shsas-bench``), then prints the wall time of

* ``shsas info FILE`` run as a subprocess (goal: < 2 s; it must not load the samples), and
* the in-process header read ``read_survey(FILE, load_samples=False)`` plus ``summarize``,
* for reference, the full in-process read with samples.

Prints figures only; never asserts. Usage: ``python benchmarks/bench_info.py [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from shsas_core.data.survey import Survey, SurveyMeta, default_pulse  # noqa: E402
from shsas_core.formats.hdf5 import read_survey, summarize, write_survey  # noqa: E402

N_PINGS, N_SAMPLES = 54_000, 1_500


def build(path: Path) -> None:
    """AirSAS-like geometry: 150 heights x 360 angles, TX/RX 13 mm / 38 mm apart."""
    ang = np.deg2rad(np.tile(np.arange(360.0), 150))
    z = np.repeat(0.11 + 0.005 * np.arange(150), 360)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), z], 1)
    rx = np.stack([0.863 * np.cos(ang), 0.863 * np.sin(ang), z - 0.038], 1)
    meta = SurveyMeta(platform="bench")
    rng = np.random.default_rng(0)
    samples = rng.standard_normal((N_PINGS, N_SAMPLES), dtype=np.float32)
    s = Survey(tx=tx, rx=rx, samples=samples, t0=np.full(N_PINGS, 3e-3), meta=meta, pulse=default_pulse(meta))
    write_survey(s, path)


def timed(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def fmt(ts: list[float]) -> str:
    return f"median {statistics.median(ts):.3f} s  (min {min(ts):.3f}, max {max(ts):.3f}, n={len(ts)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    cache = Path(os.environ.get("SHSAS_BENCH_CACHE", Path(tempfile.gettempdir()) / "shsas-bench"))
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"survey_{N_PINGS}x{N_SAMPLES}.h5"
    if not path.exists():
        t = time.perf_counter()
        build(path)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.1f} s")
    print(f"file: {path} ({path.stat().st_size / 1e6:.0f} MB), {N_PINGS} pings x {N_SAMPLES} samples")

    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = [sys.executable, "-m", "shsas_core.cli", "info", "--json", str(path)]

    def cli() -> None:
        subprocess.run(cmd, check=True, capture_output=True, env=env)

    def cli_table() -> None:
        subprocess.run([*cmd[:-2], str(path)], check=True, capture_output=True, env=env)

    def noop() -> None:
        subprocess.run([sys.executable, "-c", "pass"], check=True, capture_output=True)

    def header() -> None:
        summarize(read_survey(path, load_samples=False))

    def full() -> None:
        read_survey(path)

    print(f"shsas info (subprocess)        : {fmt(timed(cli, args.repeat))}   goal < 2 s")
    print(f"shsas info, table (subprocess) : {fmt(timed(cli_table, args.repeat))}")
    print(f"  python start-up alone        : {fmt(timed(noop, args.repeat))}")
    print(f"header read + summary (in-proc): {fmt(timed(header, args.repeat))}")
    print(f"full read with samples (ref.)  : {fmt(timed(full, max(1, args.repeat // 2)))}")


if __name__ == "__main__":
    main()
