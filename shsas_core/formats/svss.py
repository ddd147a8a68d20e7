"""SVSS (Sediment Volume Search Sonar) importer: one track image of basebanded HDF5 data.

Accepted layout (docs/formats.md, "SVSS"): a track folder holding, for image number N,

* ``unpack float - LF - down - N.hdf5``: ``DataReal``, ``DataImag`` of shape (P·R, T): row
  ``p·R + r`` is receiver r of TX firing p; complex baseband samples at 125 kHz, carrier 27.5 kHz,
  first sample at transmit.
* ``motion solution - LF - down - N.hdf5``: ``Position`` (≥P, 3) m (or a compound with x, y, z
  first) and ``Attitude/Roll``, ``Attitude/Pitch``, ``Attitude/Yaw`` (≥P,) radians.
* one track ``.xml`` file: the array in the body frame, the first ``<tx>`` block's ``<x>``,
  ``<y>``, ``<z>`` (one per TX element) and the first ``<rx>`` block's (one per receiver), and
  optionally ``<kernel>`` blocks of ``<real>``/``<imag>`` samples (the basebanded pulse).
* optionally a sound-speed table ``*.csv`` (header row, then ``track id, temperature °F``).

The path given may be that folder (with one image, or pick ``image_number``), the unpack file
or the motion-solution file. TX firings cycle through the TX elements (firing p uses element
p mod T). Element positions are placed with the reference code's attitude matrix ``A(roll,
pitch, yaw)``: ``world = A·body + Position``; both beams point along ``A·(0, 0, 1)``, i.e. down
toward the lake bed, where the reference code puts its scene (0.5 to 2 m deeper than the
array). The SVSS
frame (x along track, y cross track, z depth down) is turned into the shsas frame (z up) by a
180° rotation about x: ``(x, y, z) -> (x, −y, −z)``.
"""

from __future__ import annotations

import csv
import math
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from shsas_core.common.errors import SurveyValidationError, UnsafeFileError
from shsas_core.common.progress import ProgressFn
from shsas_core.data.survey import PulseParams, SceneBox, Survey, check_sizes, parse_meta
from shsas_core.formats.canonical import STORED_NAME
from shsas_core.formats.options import ImportOptions
from shsas_core.formats.probe import Probe
from shsas_core.formats.registry import Claim, Format
from shsas_core.formats.safe_zip import is_zip
from shsas_core.formats.tree import Node, open_tree, shallowest

if TYPE_CHECKING:
    import h5py

FS_HZ = 125e3
CARRIER_HZ = 27.5e3
TX_BEAMWIDTH_DEG = 25.0
RX_BEAMWIDTH_DEG = 50.0
DEFAULT_TEMPERATURE_F = 55.0
#: LFM 35 -> 20 kHz, 255 µs, Taylor window (the reference code uses nbar 5, -40 dB).
PULSE = PulseParams(f_start=35e3, f_stop=20e3, duration=255e-6, window="taylor", window_param=40.0)
MAX_XML_BYTES = 32 * 1024**2
#: An HDF5 file of a zipped track is copied out of the zip to be read; at most this large.
MAX_HDF5_MEMBER_BYTES = 8 * 1024**3

_UNPACK = re.compile(r"^unpack float - LF - down - (\d+)\.hdf5$")
_MOTION = re.compile(r"^motion solution - LF - down - (\d+)\.hdf5$")
#: SVSS (x along, y across, z down) -> shsas (z up): 180° about x keeps the frame right-handed.
FLIP = np.diag([1.0, -1.0, -1.0])


def sound_speed_fresh_water(temperature_f: float) -> float:
    """Sound speed in m/s from the water temperature in °F (converted to °C first, as the
    reference code does): ``c = 1404.3 + 4.7·T − 0.04·T²`` with ``T = (F − 32)·5/9``."""
    t = (temperature_f - 32.0) * 5.0 / 9.0
    return 1404.3 + 4.7 * t - 0.04 * t * t


def attitude_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(K, 3, 3) attitude matrices of the reference code (angles in radians)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack([
        np.stack([cp * cy, cp * sy, -sp], -1),
        np.stack([sp * cy * sr - sy * cr, sp * sy * sr + cy * cr, cp * sr], -1),
        np.stack([sp * cy * cr + sy * sr, sp * sy * cr - cy * sr, cp * cr], -1),
    ], -2)


def _holds_image(folder: Node) -> bool:
    return any(_UNPACK.match(p.name) for p in folder.iterdir())


def _image_of(folder: Node, image_number: int | None) -> int:
    """The image number N to read from a track folder (the only one, or ``image_number``)."""
    nums = sorted(int(m.group(1)) for p in folder.iterdir() if (m := _UNPACK.match(p.name)))
    if image_number is not None:
        if image_number not in nums:
            raise SurveyValidationError("image_number", f"{image_number} has no 'unpack float - LF - down - "
                                        f"{image_number}.hdf5' in '{folder.name}' (found {nums})")
        return image_number
    if not nums:
        raise SurveyValidationError("file", f"'{folder.name}' holds no 'unpack float - LF - down - N.hdf5'")
    if len(nums) > 1:
        raise SurveyValidationError("image_number", f"'{folder.name}' holds images {nums}; choose one")
    return nums[0]


def _track_of(path: Path) -> tuple[Path, int | None]:
    """(track folder or zip, image number when ``path`` names one file of the track)."""
    if path.is_dir() or is_zip(path):
        return path, None
    m = _UNPACK.match(path.name) or _MOTION.match(path.name)
    if not m:
        raise SurveyValidationError(
            "file", f"'{path.name}' is not named 'unpack float - LF - down - N.hdf5' or "
            "'motion solution - LF - down - N.hdf5'", "keep the SVSS file names; the sibling files are found by N")
    return path.parent, int(m.group(1))


def _open(path: Path) -> h5py.File:
    import h5py

    from shsas_core.formats.hdf5 import check_hdf5_safety

    if not h5py.is_hdf5(path):
        raise SurveyValidationError(path.name, "is not an HDF5 file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise SurveyValidationError(path.name, f"could not be read as HDF5 ({str(exc)[:120]}); "
                                    "the file may be truncated") from None
    try:
        check_hdf5_safety(f)
    except UnsafeFileError as exc:
        f.close()
        raise UnsafeFileError(f"{path.name}: {exc.field}", exc.problem, exc.fix) from None
    return f


def _ds(f: h5py.File, name: str, fname: str) -> h5py.Dataset:
    import h5py

    obj = f.get(name)
    if not isinstance(obj, h5py.Dataset):
        raise SurveyValidationError(f"{fname}: {name}", "is missing" if obj is None else "must be a dataset")
    return obj


def _floats(text: str, tag: str) -> np.ndarray:
    vals = re.findall(rf"<{tag}>\s*([^<]*?)\s*</{tag}>", text)
    try:
        return np.array([float(v) for v in vals], dtype=np.float64)
    except ValueError:
        raise SurveyValidationError(f"xml: <{tag}>", "holds a value that is not a number") from None


def read_track_xml(path: Node) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(tx_body (T,3), rx_body (R,3), kernel (K,) complex or None) from the track XML.

    Parsed with regular expressions on the text: no entity expansion, no external references.
    """
    text = path.read_bytes(MAX_XML_BYTES).decode("utf-8", errors="replace")
    out = []
    for tag in ("tx", "rx"):
        m = re.search(rf"<{tag}\b[^>]*>(.*?)</{tag}>", text, re.S)
        if not m:
            raise SurveyValidationError(f"{path.name}: <{tag}>", "is missing (the array geometry)")
        xyz = [_floats(m.group(1), a) for a in "xyz"]
        if not (len(xyz[0]) == len(xyz[1]) == len(xyz[2]) > 0):
            raise SurveyValidationError(f"{path.name}: <{tag}>", f"has {[len(a) for a in xyz]} x/y/z values; "
                                        "expected the same number (>0) of each")
        pos = np.stack(xyz, 1)
        if not np.all(np.isfinite(pos)):
            raise SurveyValidationError(f"{path.name}: <{tag}>", "holds non-finite positions")
        out.append(pos)
    kernels = re.findall(r"<kernel\b[^>]*>(.*?)</kernel>", text, re.S)
    kernel = None
    if kernels:
        # the reference code uses the second kernel block when there are several
        block = kernels[1] if len(kernels) > 1 else kernels[0]
        re_, im = _floats(block, "real"), _floats(block, "imag")
        if re_.size != im.size or re_.size == 0 or not np.all(np.isfinite(re_ + im)):
            raise SurveyValidationError(f"{path.name}: <kernel>", f"has {re_.size} <real> and {im.size} <imag> "
                                        "values; expected the same number of finite values")
        kernel = re_ + 1j * im
    return out[0], out[1], kernel


def _track_xml(folder: Node) -> Node:
    xmls = [p for p in folder.iterdir() if p.suffix.lower() == ".xml" and p.is_file()]
    named = [p for p in xmls if p.stem == folder.name]
    if named:
        return named[0]
    if len(xmls) != 1:
        raise SurveyValidationError("xml", f"expected one track .xml file in '{folder.name}' (array geometry), "
                                    f"found {len(xmls)}")
    return xmls[0]


def _temperature_from_table(folder: Node) -> float | None:
    for p in folder.iterdir():
        if p.suffix != ".csv" or not p.is_file() or p.size() > MAX_XML_BYTES:
            continue
        rows = list(csv.reader(p.read_bytes(MAX_XML_BYTES).decode("utf-8", errors="replace").splitlines()))
        for row in rows[1:]:
            if len(row) >= 2 and row[0].strip() == folder.name:
                try:
                    return float(row[1])
                except ValueError:
                    raise SurveyValidationError(f"{p.name}: {folder.name}", f"temperature {row[1]!r} is not a number") from None
    return None


def baseband_pulse(fs: float = FS_HZ, carrier: float = CARRIER_HZ) -> np.ndarray:
    """The analytic SVSS pulse, basebanded: ``hilbert(p)(t)·exp(−2πi·carrier·t)``, (P,) complex."""
    from scipy.signal import hilbert

    from shsas_core.data.pulse import lfm_pulse

    p = lfm_pulse(PULSE.f_start, PULSE.f_stop, PULSE.duration, fs, PULSE.window, PULSE.window_param)
    t = np.arange(p.size) / fs
    return hilbert(p) * np.exp(-2j * np.pi * carrier * t)


def read_svss(
    path: str | os.PathLike,
    *,
    image_number: int | None = None,
    temperature_f: float | None = None,
    scene_box: SceneBox | None = None,
    load_samples: bool = True,
) -> Survey:
    """Import one SVSS track image as a baseband :class:`Survey`.

    Args:
        path: track folder (or a .zip of it), unpack file or motion-solution file.
        image_number: which image N when the folder holds several.
        temperature_f: water temperature in °F; default from the sound-speed table, else 55 °F.
        scene_box: default x over the sensor track, y = mean ± 1 m, z from 2 m to 0.5 m below
            the mean sensor depth (the reference code's defaults).
        load_samples: False reads only shapes and geometry.

    Returns:
        Survey with N = P·R pings (one per TX firing and receiver), samples (N, T) complex64
        baseband, t0 = 0, tx/rx and tx_dir/rx_dir (N, 3).
    """
    where, named = _track_of(Path(path))
    # A zip of the track is read member by member; its two HDF5 files are copied out one at a
    # time (the HDF5 library opens files by name), into a temporary folder under TMPDIR.
    with open_tree(where) as top:
        folder = top if named is not None else shallowest(top, _holds_image)
        num = named if named is not None else _image_of(folder, image_number)
        return _read(folder, num, temperature_f, scene_box, load_samples)


def _member(folder: Node, name: str) -> Node:
    node = folder / name
    if not node.is_file():
        raise SurveyValidationError(name, "is missing (the SVSS track needs the unpack and motion files)")
    return node


def _read(folder: Node, num: int, temperature_f: float | None, scene_box: SceneBox | None,
          load_samples: bool) -> Survey:
    unpack = _member(folder, f"unpack float - LF - down - {num}.hdf5")
    motion = _member(folder, f"motion solution - LF - down - {num}.hdf5")
    tx_body, rx_body, kernel = read_track_xml(_track_xml(folder))
    n_tx, n_rx = len(tx_body), len(rx_body)

    with unpack.local_file(MAX_HDF5_MEMBER_BYTES) as local, _open(local) as f:
        re_ds, im_ds = _ds(f, "DataReal", unpack.name), _ds(f, "DataImag", unpack.name)
        for name, ds in (("DataReal", re_ds), ("DataImag", im_ds)):
            if ds.ndim != 2 or not np.issubdtype(ds.dtype, np.floating):
                raise SurveyValidationError(f"{unpack.name}: {name}", f"must be a 2-D float array (pings x receivers, "
                                            f"samples), got shape {ds.shape} dtype {ds.dtype}")
        if re_ds.shape != im_ds.shape:
            raise SurveyValidationError(f"{unpack.name}: DataImag", f"shape {im_ds.shape} differs from DataReal "
                                        f"{re_ds.shape}")
        rows, t = (int(s) for s in re_ds.shape)
        if rows % n_rx:
            raise SurveyValidationError(f"{unpack.name}: DataReal", f"has {rows} rows, not a multiple of the "
                                        f"{n_rx} receivers in the track XML")
        n_ping = rows // n_rx
        pulse = kernel if kernel is not None else baseband_pulse()
        check_sizes(rows, t, pulse.size)
        samples = None
        if load_samples:
            samples = np.empty((rows, t), np.complex64)
            samples.real = re_ds[()]
            samples.imag = im_ds[()]

    with motion.local_file(MAX_HDF5_MEMBER_BYTES) as local, _open(local) as f:
        pos_ds = _ds(f, "Position", motion.name)
        att = [_ds(f, f"Attitude/{k}", motion.name) for k in ("Roll", "Pitch", "Yaw")]
        if pos_ds.shape[0] < n_ping:
            raise SurveyValidationError(f"{motion.name}: Position", f"has {pos_ds.shape[0]} entries for "
                                        f"{n_ping} pings")
        raw = pos_ds[:n_ping]
        if raw.dtype.names:
            if len(raw.dtype.names) < 3:
                raise SurveyValidationError(f"{motion.name}: Position", "compound needs x, y, z fields")
            pos = np.stack([raw[k].astype(np.float64) for k in raw.dtype.names[:3]], 1)
        else:
            if raw.ndim != 2 or raw.shape[1] < 3:
                raise SurveyValidationError(f"{motion.name}: Position", f"must be (pings, 3), got {pos_ds.shape}")
            pos = raw[:, :3].astype(np.float64)
        angles = []
        for k, ds in zip(("Roll", "Pitch", "Yaw"), att, strict=True):
            if ds.ndim != 1 or ds.shape[0] < n_ping:
                raise SurveyValidationError(f"{motion.name}: Attitude/{k}", f"must be ({n_ping},) radians, got {ds.shape}")
            angles.append(ds[:n_ping].astype(np.float64))
    for name, arr in (("Position", pos), ("Attitude", np.stack(angles))):
        if not np.all(np.isfinite(arr)):
            raise SurveyValidationError(f"{motion.name}: {name}", "contains NaN or inf")

    mats = attitude_matrix(*angles)  # (P, 3, 3)
    tx_el = tx_body[np.arange(n_ping) % n_tx]  # (P, 3)
    tx_p = np.einsum("pij,pj->pi", mats, tx_el) + pos
    rx_p = np.einsum("pij,rj->pri", mats, rx_body) + pos[:, None, :]  # (P, R, 3)
    # the SVSS looks down: +z in its depth-positive frame (-z after the flip to z up)
    point = np.einsum("pij,j->pi", mats, np.array([0.0, 0.0, 1.0]))
    tx = np.repeat(tx_p, n_rx, axis=0) @ FLIP.T
    rx = rx_p.reshape(-1, 3) @ FLIP.T
    dirs = np.repeat(point, n_rx, axis=0) @ FLIP.T

    temp_source = "argument"
    if temperature_f is None:
        temperature_f = _temperature_from_table(folder)
        temp_source = "table"
        if temperature_f is None:
            temperature_f, temp_source = DEFAULT_TEMPERATURE_F, "default"
    c = sound_speed_fresh_water(float(temperature_f))
    if scene_box is None:
        both = np.concatenate([tx, rx])
        ym, zm = float(both[:, 1].mean()), float(both[:, 2].mean())
        scene_box = SceneBox(min=(float(both[:, 0].min()), ym - 1.0, zm - 2.0),
                             max=(float(both[:, 0].max()), ym + 1.0, zm - 0.5))
    meta = parse_meta({
        "fs": FS_HZ, "sound_speed": c, "pulse": PULSE.model_dump(), "signal_kind": "baseband",
        "carrier_hz": CARRIER_HZ, "tx_beamwidth_deg": TX_BEAMWIDTH_DEG, "rx_beamwidth_deg": RX_BEAMWIDTH_DEG,
        "platform": "svss", "scene_box": scene_box.model_dump(),
        "attrs": {"source": "svss", "track": folder.name, "image_number": num, "tx_elements": n_tx,
                  "rx_elements": n_rx, "firings": n_ping, "temperature_f": float(temperature_f),
                  "temperature_source": temp_source, "pulse_source": "xml" if kernel is not None else "analytic"},
    })
    if not math.isfinite(c):
        raise SurveyValidationError("temperature_f", f"{temperature_f} gives no valid sound speed")
    return Survey(tx=tx, rx=rx, samples=samples, t0=np.zeros(rows), meta=meta, pulse=pulse,
                  tx_dir=dirs, rx_dir=dirs.copy(), shape=(rows, t))


# ---------------------------------------------------------------------------------------------
# the registered format


class SVSSOptions(ImportOptions):
    """Options of :func:`read_svss` (its docstring gives their meaning)."""

    image_number: int | None = Field(None, ge=0, description="image N when the track folder holds several")
    temperature_f: float | None = Field(None, allow_inf_nan=False,
                                        description="water temperature, °F; None: the track's table, else 55 °F")


def sniff(probe: Probe) -> Claim:
    if probe.kind in ("folder", "zip"):
        return Claim.YES if any(_UNPACK.match(n) or _MOTION.match(n) for n in probe.names) else Claim.NO
    if probe.kind != "hdf5":
        return Claim.NO
    if _UNPACK.match(probe.name) or _MOTION.match(probe.name):
        return Claim.YES
    root = probe.hdf5_root
    return Claim.YES if root is not None and ("DataReal" in root.names or "Position" in root.names) else Claim.NO


def read(path: Path, options: SVSSOptions, load_samples: bool, progress: ProgressFn) -> Survey:
    return read_svss(path, **options.values(), load_samples=load_samples)


FORMAT = Format(name="svss", summary="an SVSS track folder, .zip or HDF5 file ('unpack float - LF - down - N.hdf5')",
                sniff=sniff, read=read, options=SVSSOptions, stored_name=STORED_NAME)
