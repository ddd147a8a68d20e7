"""The processed AirSAS pickle (``system_data.pik``) as a registered format.

Read through the restricted unpickler (:mod:`.safe_pickle`): no code in the file runs. The
raw samples ``wfm_data`` are already group-delay corrected and background-subtracted by the
processing script; the SVSS processing code writes pickles of the same layout (cropped, basebanded).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.common.errors import SurveyValidationError
from shsas_core.common.progress import ProgressFn
from shsas_core.data.survey import PulseParams, SceneBox, Survey, default_pulse
from shsas_core.formats import safe_pickle
from shsas_core.formats.airsas_rig import airsas_meta, sound_speed_air
from shsas_core.formats.canonical import STORED_NAME
from shsas_core.formats.options import ImportOptions
from shsas_core.formats.probe import Probe
from shsas_core.formats.registry import Claim, Format

#: Extensions a pickle is recognised by when its first byte is not the protocol-2+ marker.
SUFFIXES = (".pkl", ".pik", ".pickle")

def _get(obj: Any, key: str, field: str, required: bool = True) -> Any:
    if isinstance(obj, safe_pickle.Record):
        obj = obj.data()
    if not isinstance(obj, dict):
        raise SurveyValidationError(field, f"must be a dictionary-like record, got {type(obj).__name__}")
    v = obj.get(key)
    if v is None and required:
        raise SurveyValidationError(f"pickle: {key}", "is missing or None" + (
            " (a geometry-only pickle has no samples)" if key == "wfm_data" else ""))
    return v


def _array(v: Any, field: str, ndim: int, complex_ok: bool = False) -> np.ndarray:
    if not isinstance(v, np.ndarray):
        v = np.asarray(v) if isinstance(v, list | tuple) else v
    if not isinstance(v, np.ndarray) or v.ndim != ndim:
        raise SurveyValidationError(field, f"must be a {ndim}-D numpy array, got "
                                    f"{getattr(v, 'shape', type(v).__name__)}")
    ok = np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer) or (
        complex_ok and np.iscomplexobj(v))
    if not ok:
        raise SurveyValidationError(field, f"has dtype {v.dtype}, expected numbers")
    return v


def _scalar(v: Any, field: str) -> float:
    try:
        out = float(np.asarray(v).reshape(()))
    except (TypeError, ValueError):
        raise SurveyValidationError(field, f"must be a number, got {type(v).__name__}") from None
    if not math.isfinite(out):
        raise SurveyValidationError(field, f"is {out}, not finite")
    return out


def read_airsas_pickle(path: str | os.PathLike, *, scene_box: SceneBox | None = None,
                       load_samples: bool = True) -> Survey:
    """Import the processed AirSAS pickle (``system_data.pik``) through the restricted unpickler.

    Uses the raw samples ``wfm_data`` (already group-delay corrected and background-subtracted
    by the processing script, so ``t0 = 0``; for SVSS-made pickles, which are cropped, ``t0 =
    min_sample / fs``). Complex ``wfm_data`` is basebanded at ``sys_params.center_frequency``.
    """
    root = safe_pickle.safe_load(path)
    samples = _array(_get(root, "wfm_data", "pickle"), "pickle: wfm_data", 2, complex_ok=True)
    n, t = samples.shape
    tx = _array(_get(root, "tx_coords", "pickle"), "pickle: tx_coords", 2)
    rx = _array(_get(root, "rx_coords", "pickle"), "pickle: rx_coords", 2)
    sysp = _get(root, "sys_params", "pickle")
    fs = _scalar(_get(sysp, "sampling_frequency", "pickle: sys_params"), "pickle: sys_params.sampling_frequency")
    wp = _get(root, "wfm_params", "pickle", required=False)
    if wp is not None:
        pparams = PulseParams(
            f_start=_scalar(_get(wp, "f_start", "pickle: wfm_params"), "pickle: wfm_params.f_start"),
            f_stop=_scalar(_get(wp, "f_stop", "pickle: wfm_params"), "pickle: wfm_params.f_stop"),
            duration=_scalar(_get(wp, "t_dur", "pickle: wfm_params"), "pickle: wfm_params.t_dur"),
            window="tukey",
            window_param=_scalar(_get(wp, "win_ratio", "pickle: wfm_params"), "pickle: wfm_params.win_ratio"))
    else:
        pparams = PulseParams()
    c_raw = _get(root, "speed_of_sound", "pickle", required=False)
    temps = _get(root, "temps", "pickle", required=False)
    if c_raw is not None:
        c = _scalar(c_raw, "pickle: speed_of_sound")
    elif temps is not None:
        c = sound_speed_air(float(np.mean(_array(temps, "pickle: temps", np.asarray(temps).ndim))))
    else:
        raise SurveyValidationError("pickle: speed_of_sound", "is missing and there are no temps to derive it")
    kw: dict[str, Any] = {}
    if np.iscomplexobj(samples):
        fc = _get(sysp, "center_frequency", "pickle: sys_params", required=False)
        if fc is None:
            raise SurveyValidationError("pickle: sys_params.center_frequency",
                                        "is needed for complex (basebanded) wfm_data")
        kw = {"signal_kind": "baseband", "carrier_hz": _scalar(fc, "pickle: sys_params.center_frequency")}
    for key, name in (("tx_bandwidth", "tx_beamwidth_deg"), ("rx_bandwidth", "rx_beamwidth_deg")):
        v = _get(sysp, key, "pickle: sys_params", required=False)
        if v is not None:
            kw[name] = math.degrees(_scalar(v, f"pickle: sys_params.{key}"))
    box = scene_box
    geo = _get(root, "geometry", "pickle", required=False)
    if box is None and geo is not None:
        corners = _get(geo, "corners", "pickle: geometry", required=False)
        if corners is not None:
            cr = _array(corners, "pickle: geometry.corners", 2)
            box = SceneBox(min=tuple(cr.min(0).tolist()), max=tuple(cr.max(0).tolist()))
    t0 = 0.0
    crop = _get(root, "crop_settings", "pickle", required=False)
    if crop is not None and _get(root, "same_tx_per_k_rx", "pickle", required=False) is not None:
        t0 = _scalar(_get(crop, "min_sample", "pickle: crop_settings"), "pickle: crop_settings.min_sample") / fs
    meta = airsas_meta(fs, c, pparams, box, {"source": "airsas-pickle", "file": Path(path).name},
                 **({"platform": "svss"} if kw.get("signal_kind") == "baseband" and t0 > 0 else {}), **kw)
    wfm = _get(root, "wfm", "pickle", required=False)
    pulse = default_pulse(meta) if wfm is None else _array(wfm, "pickle: wfm", 1, complex_ok=True)
    dirs = {}
    for key, name in (("tx_vectors", "tx_dir"), ("rx_vectors", "rx_dir")):
        v = _get(root, key, "pickle", required=False)
        if v is not None:
            dirs[name] = _array(v, f"pickle: {key}", 2)
    return Survey(tx=tx, rx=rx, samples=samples if load_samples else None, t0=np.full(n, t0),
                  meta=meta, pulse=pulse, shape=(n, t), **dirs)


# ---------------------------------------------------------------------------------------------
# the registered format


class AirSASPickleOptions(ImportOptions):
    """The pickle takes only the scene box (default: the pickle's ``geometry.corners``, else the turntable's)."""


def sniff(probe: Probe) -> Claim:
    if probe.kind != "file":
        return Claim.NO
    return Claim.YES if probe.head[:1] == b"\x80" or probe.path.suffix.lower() in SUFFIXES else Claim.NO


def read(path: Path, options: AirSASPickleOptions, load_samples: bool, progress: ProgressFn) -> Survey:
    return read_airsas_pickle(path, **options.values(), load_samples=load_samples)


FORMAT = Format(name="airsas-pickle", summary="an AirSAS processed pickle (.pik, .pkl)", sniff=sniff, read=read,
                options=AirSASPickleOptions, stored_name=STORED_NAME)
