"""The AirSAS raw CSV export (a scan folder, or a .zip of one) as a registered format.

The accepted CSV layout follows the files the AirSAS acquisition software writes (see
docs/formats.md, "AirSAS raw CSV" for the full rules):

* ``Coordinates.csv``: one header row, then per ping ``flight, angle_deg, height_mm, temp_C,
  waveform`` (the waveform column may be absent: waveform 0). Flights must be 1, 2, ... in order.
* ``SysParams.csv``: ``name,value`` rows; needed: ``Speaker x/y/z``, ``Mic1 x/y/z``,
  ``Center x/y/z`` (metres), ``Group Delay`` (samples), ``Fs`` (Hz). Other rows are ignored.
* ``WaveformParams.csv``: one row per waveform, first cell an underscore-separated string:
  either the acquisition form ``NAME_<f_start>Hz_<f_stop>Hz_<dur>s_<x>_<y>_<tukey>`` or the short
  form ``<f_start>_<f_stop>_<dur>_<tukey>``.
* ``Waveforms.csv``: the transmitted waveform(s) at Fs, one column per waveform.
* ``Flight-000001.csv`` ...: one column of real samples per ping.
* optional ``background/`` subfolder (or ``background=`` path) with an empty-scene scan in the
  same layout, subtracted ping by ping.

Conversions: ``tx = Rz(angle)·speaker − center + (0, 0, height/1000)``, the same with the mic
for ``rx``; ``c = 331.4 + 0.6·mean(T)``; the group delay ``gd`` (samples) is removed exactly by
dropping ``ceil(gd)`` leading samples and setting ``t0 = (ceil(gd) − gd)/fs``.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from shsas_core.common.errors import SurveyValidationError
from shsas_core.common.progress import ProgressFn, no_progress
from shsas_core.data.survey import (
    PulseParams,
    SceneBox,
    Survey,
    check_sizes,
    default_pulse,
)
from shsas_core.formats.airsas_rig import airsas_meta, sound_speed_air
from shsas_core.formats.canonical import STORED_NAME
from shsas_core.formats.options import ImportOptions
from shsas_core.formats.probe import Probe
from shsas_core.formats.registry import Claim, Format
from shsas_core.formats.tree import Node, open_tree

#: Parameter files are small; refuse anything absurd before reading it.
MAX_PARAM_FILE_BYTES = 64 * 1024**2
MAX_FLIGHT_FILE_BYTES = 256 * 1024**2

_REQUIRED_FILES = ("Coordinates.csv", "SysParams.csv", "WaveformParams.csv")
_NUM = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


@dataclass
class _Scan:
    """The metadata of one scan folder (before waveform selection)."""

    folder: Node
    sys: dict[str, float]
    flight: np.ndarray  # (M,) int
    angle_deg: np.ndarray  # (M,)
    height_mm: np.ndarray  # (M,)
    temp_c: np.ndarray  # (M,)
    waveform: np.ndarray  # (M,) int


# ---------------------------------------------------------------------------------------------
# small readers


def _read_text(path: Node, limit: int = MAX_PARAM_FILE_BYTES) -> str:
    return path.read_text(limit)


def _rows(path: Node) -> list[list[str]]:
    return [[c.strip() for c in row] for row in csv.reader(_read_text(path).splitlines())]


def _is_num(s: str) -> bool:
    return bool(_NUM.match(s.strip()))


def _need(folder: Node, name: str) -> Node:
    p = folder / name
    if not p.is_file():
        raise SurveyValidationError(name, f"is missing from the scan folder '{folder.name}'",
                                    "an AirSAS scan folder needs " + ", ".join(_REQUIRED_FILES)
                                    + ", Waveforms.csv and Flight-000001.csv ...")
    return p


_SYS_FIELDS = ("speaker x", "speaker y", "speaker z", "center x", "center y", "center z",
               "group delay", "fs")


def read_sys_params(path: Node) -> dict[str, float]:
    """``SysParams.csv`` as {lower-case name: value}; required names are checked by the caller."""
    out: dict[str, float] = {}
    for i, row in enumerate(_rows(path), start=1):
        if not row or not row[0]:
            continue
        name = " ".join(row[0].split()).lower()
        known = name in _SYS_FIELDS or re.fullmatch(r"mic\d+ [xyz]", name) is not None
        value = row[1] if len(row) > 1 else ""
        if not _is_num(value):
            if known:
                raise SurveyValidationError(f"SysParams.csv: '{row[0]}'", f"row {i} has value {value!r}, not a number")
            continue  # header row or a descriptive field
        if known and name in out:
            raise SurveyValidationError(f"SysParams.csv: '{row[0]}'", f"appears twice (again in row {i})")
        v = float(value)
        if known and not math.isfinite(v):
            raise SurveyValidationError(f"SysParams.csv: '{row[0]}'", f"is {value}, not finite")
        out[name] = v
    return out


def _sys_vector(sys: dict[str, float], prefix: str) -> np.ndarray:
    missing = [f"{prefix} {a}" for a in "xyz" if f"{prefix.lower()} {a}" not in sys]
    if missing:
        raise SurveyValidationError("SysParams.csv", f"is missing {', '.join(repr(m) for m in missing)}",
                                    "add the row as 'Name,value' (metres)")
    return np.array([sys[f"{prefix.lower()} {a}"] for a in "xyz"])


def _sys_scalar(sys: dict[str, float], name: str) -> float:
    if name.lower() not in sys:
        raise SurveyValidationError("SysParams.csv", f"is missing '{name}'", "add the row as 'Name,value'")
    return sys[name.lower()]


def read_coordinates(path: Node) -> tuple[np.ndarray, ...]:
    """``Coordinates.csv`` -> (flight, angle_deg, height_mm, temp_c, waveform), each (M,)."""
    rows = [r for r in _rows(path) if any(r)]
    if rows and not _is_num(rows[0][0]):
        rows = rows[1:]  # the header row the acquisition software writes
    if not rows:
        raise SurveyValidationError("Coordinates.csv", "has no pings (0 data rows)",
                                    "a scan needs at least one ping")
    cols = []
    for i, r in enumerate(rows, start=1):
        if len(r) < 4:
            raise SurveyValidationError("Coordinates.csv", f"data row {i} has {len(r)} columns; expected "
                                        "flight, angle (deg), height (mm), temperature (C)[, waveform]")
        vals = r[:5]
        for name, v in zip(("flight", "angle", "height", "temperature", "waveform"), vals, strict=False):
            if not _is_num(v) or not math.isfinite(float(v)):
                raise SurveyValidationError(f"Coordinates.csv: {name}", f"data row {i} has {v!r}, not a finite number")
        cols.append([float(v) for v in vals] + [0.0] * (5 - len(vals)))
    a = np.asarray(cols, dtype=np.float64)
    flight = a[:, 0].astype(np.int64)
    expect = np.arange(1, len(a) + 1)
    if not np.array_equal(flight, expect) or not np.array_equal(a[:, 0], expect):
        bad = int(np.argmax(a[:, 0] != expect))
        raise SurveyValidationError("Coordinates.csv: flight", f"data row {bad + 1} has flight {a[bad, 0]:g}, "
                                    f"expected {bad + 1} (flights must be 1, 2, 3, ... in order)")
    wf = a[:, 4]
    if np.any(wf != np.round(wf)) or np.any(wf < 0):
        raise SurveyValidationError("Coordinates.csv: waveform", "waveform indices must be integers >= 0")
    return flight, a[:, 1], a[:, 2], a[:, 3], wf.astype(np.int64)


def parse_waveform_params(text: str, row: int) -> PulseParams:
    """One ``WaveformParams.csv`` string -> :class:`PulseParams` (Tukey window)."""
    field = f"WaveformParams.csv: row {row}"
    parts = [p.strip() for p in text.split("_")]

    def num(tok: str, unit: str) -> float | None:
        tok = tok.strip()
        if unit and tok.lower().endswith(unit.lower()):
            tok = tok[: -len(unit)]
        return float(tok) if _is_num(tok) else None

    if len(parts) >= 7 and not _is_num(parts[0]):
        vals = [num(parts[1], "Hz"), num(parts[2], "Hz"), num(parts[3], "s"), num(parts[6], "")]
    elif len(parts) == 4:
        vals = [num(parts[0], "Hz"), num(parts[1], "Hz"), num(parts[2], "s"), num(parts[3], "")]
    elif len(parts) == 5 and not _is_num(parts[0]):
        vals = [num(parts[1], "Hz"), num(parts[2], "Hz"), num(parts[3], "s"), num(parts[4], "")]
    else:
        vals = [None]
    if any(v is None or not math.isfinite(v) for v in vals):
        raise SurveyValidationError(field, f"cannot parse {text!r}; expected "
                                    "'NAME_<f_start>Hz_<f_stop>Hz_<duration>s_<x>_<y>_<tukey ratio>' or "
                                    "'<f_start>_<f_stop>_<duration>_<tukey ratio>'")
    f0, f1, dur, ratio = (float(v) for v in vals)  # type: ignore[arg-type]
    if f0 <= 0 or f1 <= 0 or not (0 < dur <= 1) or not (0 <= ratio <= 1):
        raise SurveyValidationError(field, f"f_start={f0:g} Hz, f_stop={f1:g} Hz, duration={dur:g} s, "
                                    f"tukey={ratio:g} are out of range (frequencies > 0, 0 < duration <= 1 s, "
                                    "0 <= tukey <= 1)")
    return PulseParams(f_start=f0, f_stop=f1, duration=dur, window="tukey", window_param=ratio)


def read_waveform_column(path: Node, column: int) -> np.ndarray:
    """Column ``column`` of ``Waveforms.csv`` (empty cells of shorter columns skipped), (P,)."""
    vals: list[float] = []
    for i, row in enumerate(_rows(path), start=1):
        if column >= len(row) or row[column] == "":
            if i == 1 and not vals:
                break
            continue
        if not _is_num(row[column]):
            if i == 1:
                continue  # header
            raise SurveyValidationError(f"Waveforms.csv: column {column}", f"row {i} has {row[column]!r}, not a number")
        vals.append(float(row[column]))
    w = np.asarray(vals, dtype=np.float64)
    if not np.any(w != 0):
        raise SurveyValidationError(f"Waveforms.csv: column {column}", "has no non-zero samples")
    return w


def read_flight(path: Node) -> np.ndarray:
    """One ``Flight-NNNNNN.csv`` (first column; an optional text header) -> (T,) float64."""
    text = _read_text(path, MAX_FLIGHT_FILE_BYTES)
    cells = [ln.split(",", 1)[0].strip() for ln in text.splitlines() if ln.strip()]
    if cells and not _is_num(cells[0]):
        cells = cells[1:]
    try:
        out = np.array(cells, dtype=np.float64)
    except ValueError:
        bad = next(i for i, c in enumerate(cells) if not _is_num(c))
        raise SurveyValidationError(path.name, f"sample {bad + 1} is {cells[bad]!r}, not a number") from None
    if out.size == 0:
        raise SurveyValidationError(path.name, "has no samples")
    if not np.all(np.isfinite(out)):
        raise SurveyValidationError(path.name, "contains NaN or inf samples")
    return out


def _flight_path(folder: Node, flight: int) -> Node:
    p = folder / f"Flight-{flight:06d}.csv"
    if not p.is_file():
        raise SurveyValidationError(p.name, f"is missing from the scan folder '{folder.name}' "
                                    "(Coordinates.csv lists this flight)")
    return p


def _read_scan(folder: Node) -> _Scan:
    for name in _REQUIRED_FILES:
        _need(folder, name)
    sys = read_sys_params(folder / "SysParams.csv")
    fl, ang, h, t, wf = read_coordinates(folder / "Coordinates.csv")
    return _Scan(folder, sys, fl, ang, h, t, wf)


# ---------------------------------------------------------------------------------------------
# folder / zip resolution


def _find_scan_root(top: Node) -> Node:
    """The shallowest folder under ``top`` holding Coordinates.csv (not a background scan)."""
    if (top / "Coordinates.csv").is_file() or (top / "SysParams.csv").is_file():
        return top
    cands = sorted((p.parent for p in top.rglob("Coordinates.csv")
                    if "background" not in [q.lower() for q in p.relative_parts(top)[:-1]]),
                   key=lambda p: len(p.parts))
    if not cands:
        if top.rglob("Flight-*.csv"):
            raise SurveyValidationError("Coordinates.csv", f"is missing from the scan folder '{top.name}'")
        raise SurveyValidationError("file", f"'{top.name}' holds no AirSAS scan (no Coordinates.csv found)")
    same = [c for c in cands if len(c.parts) == len(cands[0].parts)]
    if len(same) > 1:
        raise SurveyValidationError("file", f"'{top.name}' holds several scans ({', '.join(c.name for c in same)}); "
                                    "import one folder at a time")
    return cands[0]


def _background_folder(root: Node) -> Node | None:
    for p in root.iterdir():
        if p.is_dir() and p.name.lower() == "background":
            return p
    return None


# ---------------------------------------------------------------------------------------------
# raw CSV importer


def read_airsas_csv(
    path: str | os.PathLike,
    *,
    background: str | os.PathLike | bool | None = True,
    waveform: int | None = None,
    mic: int = 1,
    pulse: str = "file",
    scene_box: SceneBox | None = None,
    load_samples: bool = True,
    progress: ProgressFn = no_progress,
) -> Survey:
    """Import a raw AirSAS scan (folder or .zip of one) as a :class:`Survey`.

    Args:
        path: the scan folder, a folder holding exactly one scan, or a .zip of either.
        background: True (default) subtracts a ``background/`` subfolder when present; a path
            names the background scan folder (or .zip); False/None disables subtraction.
        waveform: index of the interleaved waveform to keep (0-based, as in Coordinates.csv and
            the row/column of WaveformParams.csv/Waveforms.csv). Default: the first ping's.
        mic: which receiver (``Mic<k> x/y/z`` in SysParams.csv).
        pulse: "file" takes the pulse from Waveforms.csv, "analytic" samples the LFM described
            by WaveformParams.csv.
        scene_box: default the AirSAS turntable box x, y in [-0.125, 0.125], z in [0, 0.2] m.
        load_samples: False reads only the header (geometry and one flight for the length).

    Returns:
        Survey with samples (N, T) float32, t0 (N,) s, tx/rx (N, 3) m in the turntable frame.
    """
    if pulse not in ("file", "analytic"):
        raise SurveyValidationError("pulse", f"must be 'file' or 'analytic', got {pulse!r}")
    # A zip is read member by member (only the files the scan needs), never extracted.
    with open_tree(path) as top, contextlib.ExitStack() as stack:
        root = _find_scan_root(top)
        scan = _read_scan(root)
        bg_folder: Node | None = None
        if background is True:
            bg_folder = _background_folder(root)
        elif background not in (None, False):
            bg_folder = _find_scan_root(stack.enter_context(open_tree(background)))  # type: ignore[arg-type]
        return _build(scan, bg_folder, waveform, mic, pulse, scene_box, load_samples, progress,
                      source=Path(path).name)


def _build(scan: _Scan, bg_folder: Node | None, waveform: int | None, mic: int, pulse: str,
           scene_box: SceneBox | None, load_samples: bool, progress: ProgressFn, source: str) -> Survey:
    sys = scan.sys
    speaker = _sys_vector(sys, "Speaker")
    mic_pos = _sys_vector(sys, f"Mic{mic}")
    center = _sys_vector(sys, "Center")
    gd = _sys_scalar(sys, "Group Delay")
    fs = _sys_scalar(sys, "Fs")
    if not fs > 0:
        raise SurveyValidationError("SysParams.csv: 'Fs'", f"is {fs:g}; the sample rate must be > 0 Hz")

    wf = int(scan.waveform[0]) if waveform is None else int(waveform)
    sel = np.flatnonzero(scan.waveform == wf)
    if sel.size == 0:
        raise SurveyValidationError("waveform", f"index {wf} does not occur in Coordinates.csv "
                                    f"(present: {sorted(set(scan.waveform.tolist()))})")
    wf_rows = [r for r in _rows(scan.folder / "WaveformParams.csv") if r and r[0]]
    if wf >= len(wf_rows):
        raise SurveyValidationError("WaveformParams.csv", f"has {len(wf_rows)} waveform rows; waveform {wf} "
                                    "is used in Coordinates.csv")
    pparams = parse_waveform_params(wf_rows[wf][0], wf + 1)
    temps = scan.temp_c[sel]
    c = sound_speed_air(float(np.mean(temps)))
    if not 300.0 <= c <= 1600.0:
        raise SurveyValidationError("Coordinates.csv: temperature", f"mean {np.mean(temps):g} C gives a sound "
                                    f"speed of {c:g} m/s, outside 300..1600", "temperatures are degrees Celsius")
    meta = airsas_meta(fs, c, pparams, scene_box, {
        "source": "airsas-csv", "file": source, "waveform": wf, "mic": mic,
        "group_delay_samples": gd, "temperature_mean_c": float(np.mean(temps)),
        "background_subtracted": bg_folder is not None, "pings_in_scan": len(scan.flight),
    })
    if pulse == "file":
        pulse_samples = read_waveform_column(_need(scan.folder, "Waveforms.csv"), wf)
        expect = round(pparams.duration * fs)
        if not (0.5 * expect <= pulse_samples.size <= 2 * expect):
            raise SurveyValidationError(
                f"Waveforms.csv: column {wf}", f"has {pulse_samples.size} samples but WaveformParams.csv "
                f"gives duration x Fs = {expect}", "check Fs, or import with pulse='analytic'")
    else:
        pulse_samples = default_pulse(meta)

    ang = np.deg2rad(scan.angle_deg[sel])[:, None]
    lift = np.stack([np.zeros(sel.size), np.zeros(sel.size), scan.height_mm[sel] / 1000.0], 1)

    def place(p: np.ndarray) -> np.ndarray:
        rot = np.concatenate([np.cos(ang) * p[0] - np.sin(ang) * p[1],
                              np.sin(ang) * p[0] + np.cos(ang) * p[1],
                              np.full_like(ang, p[2])], 1)
        return rot - center + lift

    tx, rx = place(speaker), place(mic_pos)
    # exact group-delay removal: drop the samples recorded before transmit, keep t0 >= 0
    k0 = max(math.ceil(gd - 1e-9), 0)
    t0 = np.full(sel.size, (k0 - gd) / fs)
    flights = [_flight_path(scan.folder, int(f)) for f in scan.flight[sel]]
    first = read_flight(flights[0])
    t_raw = first.size
    if t_raw <= k0:
        raise SurveyValidationError(flights[0].name, f"has {t_raw} samples, not more than the group delay {gd:g}")
    check_sizes(sel.size, t_raw - k0, pulse_samples.size)

    bg = None
    if bg_folder is not None:
        bg = _background_for(bg_folder, scan, sel, wf, fs)
    samples = None
    if load_samples:
        samples = np.empty((sel.size, t_raw - k0), dtype=np.float32)
        step = max(sel.size // 100, 1)
        for i, fp in enumerate(flights):
            x = first if i == 0 else read_flight(fp)
            if x.size != t_raw:
                raise SurveyValidationError(fp.name, f"has {x.size} samples; {flights[0].name} has {t_raw} "
                                            "(all flights must have the same length)")
            if bg is not None:
                y = read_flight(bg[i])
                if y.size != t_raw:
                    raise SurveyValidationError(f"background/{bg[i].name}", f"has {y.size} samples, the scan "
                                                f"has {t_raw}")
                x = x - y
            samples[i] = x[k0:]
            if i % step == 0:
                progress(i / sel.size, "import:airsas", {})
        progress(1.0, "import:airsas", {})
    return Survey(tx=tx, rx=rx, samples=samples, t0=t0, meta=meta, pulse=pulse_samples,
                  shape=(sel.size, t_raw - k0))


def _background_for(folder: Node, scan: _Scan, sel: np.ndarray, wf: int, fs: float) -> list[Node]:
    """Flight files of the background scan matched ping by ping to the selected pings."""
    bg = _read_scan(folder)
    bsel = np.flatnonzero(bg.waveform == wf)
    where = f"background scan '{folder.name}'"
    if bsel.size < sel.size:
        raise SurveyValidationError("background", f"{where} has {bsel.size} pings of waveform {wf}; "
                                    f"the scan has {sel.size}")
    bsel = bsel[: sel.size]
    if "fs" in bg.sys and bg.sys["fs"] != fs:
        raise SurveyValidationError("background", f"{where} has Fs={bg.sys['fs']:g} Hz, the scan {fs:g} Hz")
    dang = np.abs((bg.angle_deg[bsel] - scan.angle_deg[sel] + 180.0) % 360.0 - 180.0)
    dh = np.abs(bg.height_mm[bsel] - scan.height_mm[sel])
    if np.any(dang > 0.5) or np.any(dh > 1.0):
        i = int(np.argmax((dang > 0.5) | (dh > 1.0)))
        raise SurveyValidationError(
            "background", f"{where} ping {i + 1} is at angle {bg.angle_deg[bsel][i]:g} deg, height "
            f"{bg.height_mm[bsel][i]:g} mm; the scan ping is at {scan.angle_deg[sel][i]:g} deg, "
            f"{scan.height_mm[sel][i]:g} mm", "the background must be taken at the same positions")
    return [_flight_path(folder, int(f)) for f in bg.flight[bsel]]


# ---------------------------------------------------------------------------------------------
# the registered format

#: File names (lower case) that mark an AirSAS scan, besides ``Flight-*.csv``.
MARKER_NAMES = frozenset({"coordinates.csv", "sysparams.csv", "waveformparams.csv", "waveforms.csv"})


class AirSASCSVOptions(ImportOptions):
    """Options of :func:`read_airsas_csv` (its docstring gives their meaning)."""

    background: Path | bool | None = Field(
        True, description="True: subtract a background/ subfolder when present; a path: the background "
        "scan folder or .zip; False/None: no subtraction")
    waveform: int | None = Field(None, ge=0, description="interleaved waveform to keep; None: the first ping's")
    mic: int = Field(1, ge=1, description="receiver k (Mic<k> x/y/z in SysParams.csv)")
    pulse: Literal["file", "analytic"] = Field("file", description="pulse from Waveforms.csv, or the analytic LFM")


def sniff(probe: Probe) -> Claim:
    if probe.kind not in ("folder", "zip"):
        return Claim.NO
    if any(n.lower() in MARKER_NAMES or n.startswith("Flight-") for n in probe.names) or \
            probe.holds_anywhere("Coordinates.csv"):
        return Claim.YES
    # an unrecognised zip: this reader names the files a scan needs
    return Claim.FALLBACK if probe.kind == "zip" else Claim.NO


def read(path: Path, options: AirSASCSVOptions, load_samples: bool, progress: ProgressFn) -> Survey:
    return read_airsas_csv(path, **options.values(), load_samples=load_samples, progress=progress)


FORMAT = Format(name="airsas-csv", summary="an AirSAS CSV scan folder or .zip", sniff=sniff, read=read,
                options=AirSASCSVOptions, stored_name=STORED_NAME)
