"""The canonical survey file: HDF5, schema version 1 (documented field by field in docs/formats.md).

Reading is defensive because uploads come from strangers: external links, external dataset
storage and virtual datasets (which make the HDF5 library open other files on the server) are
refused, every declared shape and dtype is checked before any data is read, and every problem
raises :class:`~shsas_core.common.errors.SurveyValidationError` naming the field.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from shsas_core import __version__
from shsas_core.common.atomic import atomic_path
from shsas_core.common.errors import SurveyValidationError, UnsafeFileError
from shsas_core.common.progress import StopFn, check_stop
from shsas_core.data.geometry import elevation_info
from shsas_core.data.survey import (
    MAX_MESH_ELEMENTS,
    Survey,
    check_sizes,
    parse_meta,
    pulse_disagreement,
)
from shsas_core.formats.canonical import FORMAT_ATTRIBUTE

FORMAT_NAME = FORMAT_ATTRIBUTE
SCHEMA_VERSION = 1

_FLOAT = (np.float32, np.float64)
_COMPLEX = (np.complex64, np.complex128)
#: Samples are read in blocks of about this many bytes, checking ``should_stop`` between blocks.
READ_BLOCK_BYTES = 64 * 1024**2


def write_survey(survey: Survey, path: str | os.PathLike, *, compression: str | None = None) -> Path:
    """Write ``survey`` to ``path`` atomically (temporary file, then rename).

    Args:
        compression: None (fastest, default), "gzip" or "lzf" for the sample arrays.

    Returns:
        The path written.
    """
    if survey.samples is None:
        raise ValueError("cannot write a survey whose samples were not loaded")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        # track_order keeps group iteration stable so repeated writes are byte-identical.
        with h5py.File(tmp, "w", track_order=True) as f:
            f.attrs["format"] = FORMAT_NAME
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["created_by"] = f"shsas {__version__}"
            f.attrs["meta"] = survey.meta.model_dump_json()
            pings = f.create_group("pings", track_order=True)
            pings.create_dataset("tx", data=survey.tx)
            pings.create_dataset("rx", data=survey.rx)
            pings.create_dataset("t0", data=survey.t0)
            chunks = (min(survey.num_pings, 256), survey.num_samples) if compression else None
            pings.create_dataset("samples", data=survey.samples, chunks=chunks, compression=compression)
            for name in ("tx_dir", "rx_dir"):
                v = getattr(survey, name)
                if v is not None:
                    pings.create_dataset(name, data=v)
            f.create_group("pulse").create_dataset("samples", data=survey.pulse)
            if survey.has_ground_truth:
                gt = f.create_group("ground_truth")
                gt.create_dataset("vertices", data=survey.gt_vertices)
                gt.create_dataset("faces", data=survey.gt_faces)
            if survey.extras:
                ex = f.create_group("extras", track_order=True)
                for k, v in survey.extras.items():
                    ex.create_dataset(k, data=v, compression=compression if v.ndim == 2 else None)
    return path


def write_extra(path: str | os.PathLike, name: str, data: np.ndarray) -> None:
    """Add or replace one array under ``/extras`` of an existing survey file."""
    if not name.replace("_", "").isalnum():
        raise ValueError(f"extras name must be alphanumeric/underscore, got {name!r}")
    with h5py.File(path, "a") as f:
        ex = f.require_group("extras")
        if name in ex:
            del ex[name]
        ex.create_dataset(name, data=data)


def check_hdf5_safety(f: h5py.File) -> None:
    """Refuse links and storage that make HDF5 read anything outside this file."""

    def visit(group: h5py.Group, prefix: str) -> None:
        for key in group:
            link = group.get(key, getlink=True)
            where = f"{prefix}{key}"
            if isinstance(link, h5py.ExternalLink):
                raise UnsafeFileError(where, f"is an HDF5 external link to '{link.filename}'",
                                      "store the data inside the file (h5repack can flatten it)")
            if isinstance(link, h5py.SoftLink):
                raise UnsafeFileError(where, f"is a soft link to '{link.path}'; links are not accepted",
                                      "store the dataset itself at this path")
            obj = group.get(key)
            if isinstance(obj, h5py.Dataset):
                if obj.is_virtual:
                    raise UnsafeFileError(where, "is a virtual dataset (it maps other files)",
                                          "materialise it, e.g. with h5repack, before upload")
                if obj.external:
                    raise UnsafeFileError(where, "uses external raw storage in other files",
                                          "store the data inside the file")
            elif isinstance(obj, h5py.Group):
                visit(obj, where + "/")

    visit(f, "")


def _dataset(f: h5py.File, name: str, required: bool = True) -> h5py.Dataset | None:
    if name not in f:
        if required:
            raise SurveyValidationError(name, "is missing", "see docs/formats.md for the required layout")
        return None
    ds = f[name]
    if not isinstance(ds, h5py.Dataset):
        raise SurveyValidationError(name, "must be a dataset, found a group",
                                    "store the array itself at this path (docs/formats.md, Datasets)")
    return ds


def _check_stored(ds: h5py.Dataset, name: str) -> None:
    """Refuse a dataset whose data was never (fully) written: it reads as its fill value, so a
    small file could declare gigabytes that a reader would allocate for nothing."""
    if ds.size == 0:
        return
    if ds.chunks is None:
        if ds.id.get_storage_size() == 0:
            raise SurveyValidationError(name, f"declares shape {ds.shape} but the file stores none of its data",
                                        "write the data into the dataset")
        return
    total = int(np.prod([-(-d // c) for d, c in zip(ds.shape, ds.chunks, strict=True)]))
    stored = ds.id.get_num_chunks()
    if stored < total:
        raise SurveyValidationError(
            name, f"declares shape {ds.shape} ({ds.size * ds.dtype.itemsize / 1e9:.3g} GB) but the file stores "
            f"only {stored} of its {total} chunks; the rest were never written",
            "write every ping's samples (a file cut short by its writer is not a survey)")


def _read_samples(ds: h5py.Dataset, should_stop: StopFn | None) -> np.ndarray:
    """The samples as float32/complex64, read block by block so a cancel lands within a block."""
    n, t = ds.shape
    out = np.empty((n, t), dtype=np.complex64 if ds.dtype.type in _COMPLEX else np.float32)
    rows = max(1, READ_BLOCK_BYTES // max(t * ds.dtype.itemsize, 1))
    for start in range(0, n, rows):
        check_stop(should_stop)
        out[start:start + rows] = ds[start:start + rows]  # converts float64/complex128 per block
    return out


def _check(ds: h5py.Dataset | None, name: str, shape: tuple[int | None, ...], kinds: tuple) -> None:
    if ds is None:
        return
    if len(ds.shape) != len(shape) or any(s is not None and s != d for s, d in zip(shape, ds.shape, strict=True)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise SurveyValidationError(name, f"has shape {ds.shape}, expected {want}",
                                    f"store it with shape {want}, N = number of pings (docs/formats.md, Datasets)")
    if ds.dtype.type not in kinds:
        names = [k.__name__ for k in kinds]
        raise SurveyValidationError(name, f"has dtype {ds.dtype}, expected one of {names}",
                                    f"convert it to one of {names} before writing")


def read_survey(path: str | os.PathLike, *, load_samples: bool = True, load_extras: bool = True,
                should_stop: StopFn | None = None) -> Survey:
    """Read and validate a canonical survey file.

    Args:
        load_samples: False reads only metadata and geometry (fast for ``shsas info``);
            ``survey.samples`` is then None and ``survey.shape`` still holds (N, T).
        load_extras: also read ``/extras``.
        should_stop: polled between blocks of samples; True raises ``Cancelled``.

    Raises:
        SurveyValidationError: any problem, with the field named.
    """
    path = Path(path)
    if not path.is_file():
        raise SurveyValidationError("file", f"'{path}' does not exist or is not a file", "check the path")
    if not h5py.is_hdf5(path):
        raise SurveyValidationError("file", f"'{path.name}' is not an HDF5 file",
                                    "convert it first with `shsas convert`")
    try:
        with h5py.File(path, "r") as f:
            return _read_open(f, load_samples, load_extras, should_stop)
    except (SurveyValidationError, UnsafeFileError):
        raise
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise SurveyValidationError(
            "file", f"'{path.name}' could not be read as HDF5 ({str(exc).splitlines()[0][:160]}); "
            "the file may be truncated or corrupt", "copy or upload the whole file again; check its size") from None


def _read_open(f: h5py.File, load_samples: bool, load_extras: bool, should_stop: StopFn | None) -> Survey:
    check_hdf5_safety(f)
    fmt = f.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    if fmt != FORMAT_NAME:
        raise SurveyValidationError("format", f"attribute is {fmt!r}, not '{FORMAT_NAME}'",
                                    "import other formats with `shsas convert`")
    version = f.attrs.get("schema_version")
    if isinstance(version, np.generic):
        version = version.item()
    if not isinstance(version, int | float) or version != SCHEMA_VERSION:
        raise SurveyValidationError("schema_version", f"is {version!r}; this build reads version {SCHEMA_VERSION}",
                                    f"write the integer root attribute schema_version = {SCHEMA_VERSION} "
                                    "(docs/formats.md), or read the file with the shsas that wrote it")
    meta_raw = f.attrs.get("meta")
    if meta_raw is None:
        raise SurveyValidationError("meta", "attribute is missing",
                                    "add the root attribute 'meta', a JSON object string (docs/formats.md)")
    meta = parse_meta(meta_raw.decode() if isinstance(meta_raw, bytes) else str(meta_raw))

    samples = _dataset(f, "pings/samples")
    assert samples is not None
    if samples.ndim != 2:
        raise SurveyValidationError("pings/samples", f"must be 2-D (pings, samples), got shape {samples.shape}",
                                    "store one row of samples per ping")
    if samples.dtype.type not in _FLOAT + _COMPLEX:
        raise SurveyValidationError("pings/samples", f"has dtype {samples.dtype}, expected float32 or complex64",
                                    "convert the samples to float32 (real) or complex64 before writing")
    n, t = (int(s) for s in samples.shape)
    check_sizes(n, t, 1)  # before the storage check, which walks the chunk index
    _check_stored(samples, "pings/samples")
    pulse = _dataset(f, "pulse/samples")
    assert pulse is not None
    _check(pulse, "pulse/samples", (None,), _FLOAT + _COMPLEX)
    check_sizes(n, t, int(pulse.shape[0]))
    tx, rx, t0 = (_dataset(f, f"pings/{k}") for k in ("tx", "rx", "t0"))
    _check(tx, "pings/tx", (n, 3), _FLOAT)
    _check(rx, "pings/rx", (n, 3), _FLOAT)
    _check(t0, "pings/t0", (n,), _FLOAT)
    dirs = {k: _dataset(f, f"pings/{k}", required=False) for k in ("tx_dir", "rx_dir")}
    for k, ds in dirs.items():
        _check(ds, f"pings/{k}", (n, 3), _FLOAT)
    verts = faces = None
    if "ground_truth" in f:
        vds, fds = _dataset(f, "ground_truth/vertices"), _dataset(f, "ground_truth/faces")
        _check(vds, "ground_truth/vertices", (None, 3), _FLOAT)
        _check(fds, "ground_truth/faces", (None, 3), (np.int32, np.int64, np.uint32, np.uint64))
        assert vds is not None and fds is not None
        if vds.shape[0] > MAX_MESH_ELEMENTS or fds.shape[0] > MAX_MESH_ELEMENTS:
            raise SurveyValidationError("ground_truth", f"mesh larger than {MAX_MESH_ELEMENTS} elements",
                                        "decimate the mesh, or leave /ground_truth out")
        verts, faces = vds[()], fds[()]
    extras: dict[str, np.ndarray] = {}
    if load_extras and "extras" in f:
        grp = f["extras"]
        if not isinstance(grp, h5py.Group):
            raise SurveyValidationError("extras", "must be a group",
                                        "store named arrays under the group /extras, or leave it out")
        for k in grp:
            ds = _dataset(f, f"extras/{k}")
            assert ds is not None
            if ds.size > 4 * max(n * t, 1):
                raise SurveyValidationError(f"extras/{k}", f"declares {ds.size} elements, too large for this survey",
                                            "extras hold at most 4 x pings x samples elements; drop this one")
            _check_stored(ds, f"extras/{k}")
            extras[k] = ds[()]
    assert tx is not None and rx is not None and t0 is not None
    return Survey(
        tx=tx[()], rx=rx[()], t0=t0[()], meta=meta, pulse=pulse[()],
        samples=_read_samples(samples, should_stop) if load_samples else None,
        tx_dir=None if dirs["tx_dir"] is None else dirs["tx_dir"][()],
        rx_dir=None if dirs["rx_dir"] is None else dirs["rx_dir"][()],
        gt_vertices=verts, gt_faces=faces, extras=extras, shape=(n, t),
    )


def declared_parts(path: str | os.PathLike) -> dict[str, Any]:
    """What a canonical file declares beside its samples, read from shapes only (no data):
    ``{"ground_truth_elements": vertices + faces, "extras": {name: bytes}}``.

    For checking caps before :func:`read_survey` reads the mesh or the extras.
    """
    out: dict[str, Any] = {"ground_truth_elements": 0, "extras": {}}
    with h5py.File(path, "r") as f:
        check_hdf5_safety(f)
        for name in ("ground_truth/vertices", "ground_truth/faces"):
            obj = f.get(name)
            if isinstance(obj, h5py.Dataset) and obj.ndim >= 1:
                out["ground_truth_elements"] += int(obj.shape[0])
        grp = f.get("extras")
        if isinstance(grp, h5py.Group):
            for k in grp:
                obj = grp.get(k)
                if isinstance(obj, h5py.Dataset):
                    out["extras"][k] = int(obj.size) * int(obj.dtype.itemsize)
    return out


def summarize(survey: Survey) -> dict[str, Any]:
    """A JSON-able summary (pings, samples, band, geometry extent, scene box) for `shsas info`."""
    m = survey.meta
    both = np.concatenate([survey.tx, survey.rx])
    duration = survey.num_samples / m.fs
    return {
        "platform": m.platform,
        "pings": survey.num_pings,
        "samples_per_ping": survey.num_samples,
        "signal_kind": m.signal_kind,
        # pre-deconvolved samples: no stage deconvolves them again (docs/formats.md, meta table)
        "pulse_deconvolved": m.pulse_deconvolved,
        "fs_hz": m.fs,
        "sound_speed_m_s": m.sound_speed,
        "band_hz": [m.pulse.f_start, m.pulse.f_stop],
        "pulse_duration_s": m.pulse.duration,
        # what processing correlates with, beside meta.pulse's description (docs/formats.md)
        "pulse_samples": int(survey.pulse.size),
        "window": f"{m.pulse.window}({m.pulse.window_param:g})",
        "range_resolution_m": m.range_resolution,
        "record_s": [float(survey.t0.min()), float(survey.t0.max() + duration)],
        "sensor_extent_m": {"min": both.min(0).round(4).tolist(), "max": both.max(0).round(4).tolist()},
        "tx_rx_baseline_m": float(np.median(np.linalg.norm(survey.tx - survey.rx, axis=1))),
        "scene_box_m": {"min": list(m.scene_box.min), "max": list(m.scene_box.max)},
        "ground_truth": None if not survey.has_ground_truth else {
            "vertices": len(survey.gt_vertices), "faces": len(survey.gt_faces)},  # type: ignore[arg-type]
        "extras": sorted(survey.extras),
        "attrs": dict(m.attrs),
        # whether images are 3-D or should be read in one plane (single-height scans)
        "elevation": elevation_info(survey).model_dump(),
        "warnings": [w for w in (pulse_disagreement(m, survey.pulse),) if w],
    }

