"""Zips of the real AirSAS recordings in ``../shared/data/airsas/``, made on the fly (a subset of
the pings, still a valid scan, keeps the tests fast). The recordings are read in place."""

from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

AIRSAS = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "airsas"
#: Turntable rows per level that keep the deconvolved folder's range window: the square box's
#: nearest and farthest corners face a sensor at 45° (and at 135°, 225°, 315°), so rows 0..45 reach
#: the whole scan's MIN_DIST and MAX_DIST and the samples keep their ranges.
WINDOW_ROWS = 46


def need(name: str) -> Path:
    folder = AIRSAS / name
    if not folder.is_dir():
        pytest.skip(f"real AirSAS data not found at {folder}")
    return folder


def _scan_into(zf: zipfile.ZipFile, folder: Path, prefix: str, flights: int) -> None:
    """The parameter files of ``folder`` and its first ``flights`` flights, with Coordinates.csv
    cut to those flights (its header row kept)."""
    lines = (folder / "Coordinates.csv").read_text().splitlines()
    zf.writestr(f"{prefix}Coordinates.csv", "\n".join(lines[:flights + 1]) + "\n")
    for name in ("SysParams.csv", "WaveformParams.csv", "Waveforms.csv"):
        zf.write(folder / name, prefix + name)
    for i in range(1, flights + 1):
        zf.write(folder / f"Flight-{i:06d}.csv", f"{prefix}Flight-{i:06d}.csv")


def cutout_zip(dest: Path, flights: int = 60, background: bool = True, junk_bytes: int = 0) -> Path:
    """``cutout_20k/`` (first ``flights`` pings) with ``bg_20k/`` as its ``background/``; with
    ``junk_bytes``, one more member of that many zeros (deflated about a thousandfold)."""
    with zipfile.ZipFile(dest, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        _scan_into(zf, need("cutout_20k"), "cutout_20k/", flights)
        if background:
            _scan_into(zf, need("bg_20k"), "cutout_20k/background/", flights)
        if junk_bytes:
            block = bytes(1 << 24)
            with zf.open("cutout_20k/notes/zeros.bin", "w", force_zip64=True) as out:
                for _ in range(junk_bytes // len(block)):
                    out.write(block)
    return dest


def deconvolved_zip(dest: Path, rows: int | None = None) -> Path:
    """``bunny_20k_deconvolved/`` (stored, not deflated: float16 barely shrinks): whole, or with
    ``rows`` the first rows (turntable steps) of every level, files renamed to tile the pings.

    No subset of the *levels* is a valid scan: each level's range axis is cut from the scene
    box's nearest and farthest corners over all levels, so fewer levels would map the samples to
    other ranges. The first :data:`WINDOW_ROWS` rows of every level keep that window."""
    folder = need("bunny_20k_deconvolved")
    with zipfile.ZipFile(dest, "w", compression=zipfile.ZIP_STORED) as zf:
        for p in sorted(folder.iterdir()):
            m = re.match(r"^weights_trans_(\d+)_\d+\.npy$", p.name)
            if rows is None or not m:
                zf.write(p, f"bunny_20k_deconvolved/{p.name}")
                continue
            level = int(m.group(1)) // 360
            buf = io.BytesIO()
            np.save(buf, np.load(p)[:rows])
            zf.writestr(f"bunny_20k_deconvolved/weights_trans_{level * rows}_{level * rows + rows - 1}.npy",
                        buf.getvalue())
    return dest
