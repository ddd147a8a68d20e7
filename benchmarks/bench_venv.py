"""Seconds to fill a fresh venv with the project: pip's recipe against uv's, side by side.

pip: ``pip install torch==2.13.0`` then ``pip install -e .[fast,service,dev]`` (the recipe the
Makefile had); uv: ``pip install uv`` then one ``uv pip install --compile-bytecode -e
.[fast,service,dev]`` with the wheel folders of pip's configuration (the Makefile's recipe). Each
runs in a new venv under a temporary folder; the package caches stay as they are (run it twice
to see warm caches). Also says whether the two venvs hold the same packages at the same versions
(pip and uv themselves aside).

Usage: ``python benchmarks/bench_venv.py [--python python3.11]``. Prints a table; never asserts.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = ".[fast,service,dev]"
QUIET = ["-q", "--disable-pip-version-check"]


def run(*cmd: str) -> None:
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def find_links(python: str) -> list[str]:
    out = subprocess.run([python, "-m", "pip", "config", "get", "global.find-links"], capture_output=True, text=True)
    return out.stdout.split() if out.returncode == 0 else []


def packages(venv: Path) -> set[str]:
    out = subprocess.run([str(venv / "bin" / "pip"), "list", "--format", "freeze", *QUIET[1:]],
                         capture_output=True, text=True, check=True).stdout
    return {line for line in out.splitlines() if line.split("==")[0] not in ("pip", "uv")}


def pip_recipe(python: str, venv: Path) -> dict[str, float]:
    t0 = time.perf_counter()
    run(python, "-m", "venv", str(venv))
    pip = str(venv / "bin" / "pip")
    t1 = time.perf_counter()
    run(pip, "install", *QUIET, "torch==2.13.0")
    t2 = time.perf_counter()
    run(pip, "install", *QUIET, "-e", EXTRAS)
    t3 = time.perf_counter()
    return {"venv": t1 - t0, "torch": t2 - t1, "project": t3 - t2, "total": t3 - t0}


def uv_recipe(python: str, venv: Path) -> dict[str, float]:
    t0 = time.perf_counter()
    run(python, "-m", "venv", str(venv))
    t1 = time.perf_counter()
    run(str(venv / "bin" / "pip"), "install", *QUIET, "uv")
    t2 = time.perf_counter()
    links = [a for f in find_links(python) for a in ("--find-links", f)]
    run(str(venv / "bin" / "uv"), "pip", "install", "-q", "--python", str(venv / "bin" / "python"),
        "--compile-bytecode", *links, "-e", EXTRAS)
    t3 = time.perf_counter()
    return {"venv": t1 - t0, "torch": t2 - t1, "project": t3 - t2, "total": t3 - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--python", default="python3.11")
    args = ap.parse_args()
    print(f"bench_venv: {args.python}, find-links {find_links(args.python) or 'none'}, "
          f"load {os.getloadavg()[0]:.1f}, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory() as tmp:
        res = {"pip": pip_recipe(args.python, Path(tmp) / "pip"), "uv": uv_recipe(args.python, Path(tmp) / "uv")}
        same = packages(Path(tmp) / "pip") == packages(Path(tmp) / "uv")
    print(f"{'recipe':<8}{'venv s':>8}{'step 1 s':>10}{'step 2 s':>10}{'total s':>9}")
    for name, t in res.items():
        print(f"{name:<8}{t['venv']:>8.1f}{t['torch']:>10.1f}{t['project']:>10.1f}{t['total']:>9.1f}")
    print("step 1: pip installs torch (pip) or uv (uv); step 2: the project and the rest")
    print(f"same packages and versions in both venvs: {'yes' if same else 'NO'}")
    sys.exit(0)


if __name__ == "__main__":
    main()
