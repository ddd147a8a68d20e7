"""AirSAS pulse-deconvolved ping folders: ``weights_trans_{first}_{last}.npy`` files.

The public AirSAS bunny (awreed/Neural-Volumetric-Reconstruction-for-Coherent-SAS,
``scenes/airsas/bunny_20k/example_outputs/``) ships only the output of the authors' neural
pulse deconvolution: one float16 ``(360, T)`` file per height level, one real row per 1°
turntable step, on a *two-way path-length* axis. Their geometry (``system_data.pik``) is not
public, so it comes in as :class:`DeconvolvedGeometry` (defaults: the 2022 AirSAS SysParams,
docs/formats.md "AirSAS deconvolved pings") and is then refined by ``shsas autofocus``.

Conversions (the authors' ``airsas/utils.py`` and backprojection, as the data README states):

* ``tx = Rz(angle)·speaker − center + (0, 0, height)``; ``rx`` the same with the mic;
* ``c = 331.4 + 0.6·T`` (T in °C) unless ``sound_speed`` is given;
* sample ``i`` of ``T`` lies at two-way path ``MIN_DIST + i/(T−1)·(MAX_DIST − MIN_DIST)``, with
  MIN/MAX_DIST the nearest/farthest two-way *corner* distance of the scene box over all pings,
  each widened by ``widen_m`` and by ``widen_samples/raw_fs·c``. On our time axis that is
  ``t0 = MIN_DIST / c`` and ``fs = (T−1)·c / (MAX_DIST − MIN_DIST)``;
* the rows are made complex by a Hilbert transform (``signal_kind = "analytic"``) and the
  survey is marked ``pulse_deconvolved``, so no stage deconvolves them again.
"""

from __future__ import annotations

import io
import itertools
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pydantic
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import SurveyValidationError, pydantic_fix
from shsas_core.common.progress import ProgressFn, no_progress
from shsas_core.data.survey import (
    PulseParams,
    SceneBox,
    Survey,
    check_sizes,
    default_pulse,
    parse_meta,
)
from shsas_core.formats.airsas_rig import sound_speed_air
from shsas_core.formats.canonical import STORED_NAME
from shsas_core.formats.options import ImportOptions
from shsas_core.formats.probe import Probe
from shsas_core.formats.registry import Claim, Format
from shsas_core.formats.tree import Node, open_tree, shallowest

#: ``weights_trans_{first ping}_{last ping}.npy``: one file per height level.
FILE_NAME = re.compile(r"^weights_trans_(\d+)_(\d+)\.npy$")
#: The measured waveform the authors deconvolved with (its first ``PULSE_SAMPLES`` were used).
WAVEFORM_FILE = "20khz_bw_lfm.npy"
PULSE_SAMPLES = 100
MAX_FILE_BYTES = 64 * 1024**2

Vec3 = tuple[float, float, float]


class DeconvolvedGeometry(BaseModel):
    """What the ping files do not say: positions, heights, sound speed, the range mapping.

    Defaults: the 2022 AirSAS SysParams (the cut-out scan's), heights at 5 mm steps from 0,
    1° turntable steps from 0°, and the authors' range-window rule.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    speaker_m: Vec3 = Field((0.0, -0.8485, 0.285), description="speaker position at angle 0, m")
    mic_m: Vec3 = Field((0.0, -0.8615, 0.247), description="microphone position at angle 0, m")
    center_m: Vec3 = Field((0.0, 0.0, 0.1775), description="turntable centre, subtracted, m")
    height_start_m: float = Field(0.0, ge=-10, le=10, description="height of the first level, m")
    height_step_m: float = Field(0.005, gt=0, le=1, description="height step between levels, m")
    angle_start_deg: float = Field(0.0, description="turntable angle of each level's first row")
    angle_step_deg: float = Field(1.0, gt=0, le=360, description="turntable step between rows")
    temperature_c: float = Field(21.6, ge=-40, le=60, description="air temperature, °C")
    sound_speed: float | None = Field(None, ge=300, le=1600, description="m/s; None: from temperature_c")
    raw_fs: float = Field(100e3, gt=0, description="the recording's sample rate, Hz (range-window widening)")
    widen_m: float = Field(0.05, ge=0, description="range window widening on each side, m")
    widen_samples: float = Field(100.0, ge=0, description="... and this many raw samples of path, each side")
    min_dist_m: float | None = Field(None, gt=0, description="two-way path of sample 0; None: the rule above")
    max_dist_m: float | None = Field(None, gt=0, description="two-way path of the last sample; None: the rule")
    scene_box: SceneBox = SceneBox(min=(-0.125, -0.125, 0.0), max=(0.125, 0.125, 0.2))

    @property
    def c(self) -> float:
        return float(self.sound_speed if self.sound_speed is not None else sound_speed_air(self.temperature_c))


def load_geometry(path: str | os.PathLike | None) -> DeconvolvedGeometry:
    """A :class:`DeconvolvedGeometry` from a JSON file (None: the defaults)."""
    if path is None:
        return DeconvolvedGeometry()
    p = Path(path)
    if not p.is_file():
        raise SurveyValidationError("geometry", f"'{p}' is not a file", "give a JSON file of geometry fields "
                                    "(docs/formats.md, 'AirSAS deconvolved pings')")
    try:
        return DeconvolvedGeometry.model_validate_json(p.read_text(encoding="utf-8"))
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(x) for x in err["loc"]) or "geometry"
        raise SurveyValidationError(f"geometry.{field}", f"{err['msg']} (got {err.get('input')!r})"[:300],
                                    pydantic_fix(err, list(DeconvolvedGeometry.model_fields),
                                                 "docs/formats.md, 'AirSAS deconvolved pings'")) from None


def holds_pings(folder: Node) -> bool:
    """True when ``folder`` holds ping files (``weights_trans_*_*.npy``)."""
    return any(FILE_NAME.match(q.name) for q in folder.iterdir())


def ping_files(folder: Node) -> list[Node]:
    """The folder's ping files in ping order; they must tile 0..N−1 with equal-sized levels."""
    found = []
    for q in folder.iterdir():
        m = FILE_NAME.match(q.name)
        if m:
            found.append((int(m.group(1)), int(m.group(2)), q))
    if not found:
        raise SurveyValidationError("file", f"folder '{folder.name}' holds no weights_trans_*_*.npy files",
                                    "give the folder of the deconvolved ping files")
    found.sort()
    per = found[0][1] - found[0][0] + 1
    expect = 0
    for first, last, q in found:
        if first != expect or last - first + 1 != per:
            raise SurveyValidationError(q.name, f"covers pings {first}..{last}; expected {expect}.."
                                        f"{expect + per - 1} (the files must tile the pings, one level each)",
                                        "give the complete folder, one file per height level")
        expect = last + 1
    return [q for _, _, q in found]


def sensor_positions(geo: DeconvolvedGeometry, levels: int, per_level: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) TX and RX positions, level-major (ping ``k·per_level + j`` is level k, row j)."""
    ang = np.deg2rad(geo.angle_start_deg + geo.angle_step_deg * np.arange(per_level))
    z = geo.height_start_m + geo.height_step_m * np.arange(levels)
    centre = np.asarray(geo.center_m)

    def place(p: Vec3) -> np.ndarray:
        ring = np.stack([np.cos(ang) * p[0] - np.sin(ang) * p[1], np.sin(ang) * p[0] + np.cos(ang) * p[1],
                         np.full(per_level, p[2])], 1) - centre
        return (ring[None, :, :] + np.stack([0 * z, 0 * z, z], 1)[:, None, :]).reshape(-1, 3)

    return place(geo.speaker_m), place(geo.mic_m)


def range_window(geo: DeconvolvedGeometry, tx: np.ndarray, rx: np.ndarray) -> tuple[float, float]:
    """(MIN_DIST, MAX_DIST) two-way path of the first and last sample, m (the authors' rule)."""
    box = geo.scene_box
    corners = np.array(list(itertools.product(*zip(box.min, box.max, strict=True))))
    d = (np.linalg.norm(tx[:, None, :] - corners[None], axis=2)
         + np.linalg.norm(rx[:, None, :] - corners[None], axis=2))
    pad = geo.widen_m + geo.widen_samples / geo.raw_fs * geo.c
    lo = geo.min_dist_m if geo.min_dist_m is not None else float(d.min()) - pad
    hi = geo.max_dist_m if geo.max_dist_m is not None else float(d.max()) + pad
    if not hi > lo > 0:
        raise SurveyValidationError("geometry", f"range window {lo:.4f}..{hi:.4f} m is empty or negative",
                                    "check min_dist_m / max_dist_m and the positions")
    return lo, hi


def _load_npy(path: Node) -> np.ndarray:
    """A plain .npy array from a file or zip member (at most :data:`MAX_FILE_BYTES`)."""
    try:
        return np.load(io.BytesIO(path.read_bytes(MAX_FILE_BYTES)), allow_pickle=False)
    except (ValueError, EOFError) as exc:
        raise SurveyValidationError(path.name, f"is not a plain .npy array ({exc})"[:200],
                                    "give the deconvolved ping files unchanged") from None


def _read_level(path: Node, per_level: int | None) -> np.ndarray:
    a = _load_npy(path)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.floating) or (per_level and a.shape[0] != per_level):
        raise SurveyValidationError(path.name, f"holds {a.dtype} {a.shape}; expected real ({per_level}, T)",
                                    "give the deconvolved ping files unchanged")
    return a


def read_deconvolved_folder(path: str | os.PathLike, *, geometry: DeconvolvedGeometry | str | os.PathLike |
                            None = None, scene_box: SceneBox | None = None, load_samples: bool = True,
                            progress: ProgressFn = no_progress) -> Survey:
    """Read a folder of ``weights_trans_*_*.npy`` files as a survey (module docstring).

    Args:
        geometry: a :class:`DeconvolvedGeometry`, a JSON file of its fields, or None (defaults).
        scene_box: overrides ``geometry.scene_box`` (the box the range window was cut for).
    """

    geo = geometry if isinstance(geometry, DeconvolvedGeometry) else load_geometry(geometry)
    if scene_box is not None:
        geo = geo.model_copy(update={"scene_box": scene_box})
    # A zip of the folder is read member by member, never extracted.
    with open_tree(path) as top:
        return _read(shallowest(top, holds_pings), geo, load_samples, progress)


def _read(folder: Node, geo: DeconvolvedGeometry, load_samples: bool, progress: ProgressFn) -> Survey:
    from shsas_core.signal.chain import analytic_signal

    files = ping_files(folder)
    first = _read_level(files[0], None)
    per_level, t = first.shape
    n = per_level * len(files)
    check_sizes(n, t, PULSE_SAMPLES)
    if t < 2:
        raise SurveyValidationError(files[0].name, f"has {t} samples per ping", "need at least two")
    tx, rx = sensor_positions(geo, len(files), per_level)
    lo, hi = range_window(geo, tx, rx)
    c = geo.c
    fs = (t - 1) * c / (hi - lo)
    t0 = np.full(n, lo / c)
    attrs: dict[str, Any] = {
        "source": "airsas-deconvolved", "file": folder.name, "pulse_deconvolved_by":
        "the AirSAS authors' neural deconvolution (data README); not deconvolved again here",
        "geometry": geo.model_dump_json(), "range_min_dist_m": lo, "range_max_dist_m": hi,
        "sound_speed_rule": "given" if geo.sound_speed is not None else "331.4 + 0.6 temperature_c",
        "height_levels": len(files), "pings_per_level": per_level}
    meta = parse_meta({"fs": fs, "sound_speed": c, "signal_kind": "analytic", "platform": "airsas",
                       "pulse_deconvolved": True,
                       "pulse": PulseParams(f_start=30e3, f_stop=10e3, duration=PULSE_SAMPLES / geo.raw_fs,
                                            window="tukey", window_param=0.1).model_dump(),
                       "scene_box": geo.scene_box.model_dump(), "attrs": attrs})
    wf = folder / WAVEFORM_FILE
    if wf.is_file():
        pulse = _load_npy(wf).astype(np.float64)[:PULSE_SAMPLES]
        meta = meta.model_copy(update={"attrs": {**attrs, "pulse_file": WAVEFORM_FILE}})
    else:
        pulse = default_pulse(meta)
    samples = None
    if load_samples:
        samples = np.empty((n, t), np.complex64)
        for k, q in enumerate(files):
            a = first if k == 0 else _read_level(q, per_level)
            if a.shape[1] != t:
                raise SurveyValidationError(q.name, f"has {a.shape[1]} samples per ping; {files[0].name} has {t}")
            samples[k * per_level:(k + 1) * per_level] = analytic_signal(a.astype(np.float32))
            progress((k + 1) / len(files), "import:airsas-deconvolved", {})
    return Survey(tx=tx, rx=rx, samples=samples, t0=t0, meta=meta, pulse=pulse, shape=(n, t))


# ---------------------------------------------------------------------------------------------
# the registered format


class DeconvolvedOptions(ImportOptions):
    """Options of :func:`read_deconvolved_folder`."""

    geometry: DeconvolvedGeometry | Path | None = Field(
        None, description="the geometry, or a JSON file of its fields; None: the defaults")


def sniff(probe: Probe) -> Claim:
    if probe.kind not in ("folder", "zip"):
        return Claim.NO
    return Claim.YES if any(FILE_NAME.match(n) for n in probe.names) else Claim.NO


def read(path: Path, options: DeconvolvedOptions, load_samples: bool, progress: ProgressFn) -> Survey:
    return read_deconvolved_folder(path, **options.values(), load_samples=load_samples, progress=progress)


FORMAT = Format(name="airsas-deconvolved", summary="an AirSAS deconvolved-ping folder or .zip (weights_trans_*_*.npy)",
                sniff=sniff, read=read, options=DeconvolvedOptions, stored_name=STORED_NAME)
