"""Importers: turn the formats users bring into a :class:`~shsas_core.data.survey.Survey`.

``load_survey(path, fmt="auto")`` detects the format from the contents (not the extension):
canonical HDF5 (``format`` attribute), SVSS HDF5 (``DataReal``/``Position`` datasets, or a
folder of ``unpack float - LF - down - N.hdf5`` files), an AirSAS CSV folder, an AirSAS
processed pickle, or a folder of AirSAS pulse-deconvolved pings (``weights_trans_*.npy``).
A .zip of any of the three folder formats is detected by its member names and read member by
member, never extracted (:mod:`.tree`). Layouts and conversions: docs/formats.md.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from shsas_core.common.errors import ShsasError, SurveyValidationError, UnsupportedFormatError
from shsas_core.common.progress import ProgressFn
from shsas_core.data.survey import Survey

FORMATS = ("shsas", "airsas-csv", "airsas-pickle", "svss", "airsas-deconvolved")

_AIRSAS_NAMES = {"coordinates.csv", "sysparams.csv", "waveformparams.csv", "waveforms.csv"}
_SVSS_NAME = re.compile(r"^(unpack float|motion solution) - LF - down - \d+\.hdf5$")
_DECONVOLVED_NAME = re.compile(r"^weights_trans_\d+_\d+\.npy$")


def _detect_dir(p: Path) -> str:
    names = [q.name for q in p.iterdir()]
    if any(_SVSS_NAME.match(n) for n in names):
        return "svss"
    if any(_DECONVOLVED_NAME.match(n) for n in names):
        return "airsas-deconvolved"
    if any(n.lower() in _AIRSAS_NAMES or n.startswith("Flight-") for n in names) or any(
            p.rglob("Coordinates.csv")):
        return "airsas-csv"
    raise UnsupportedFormatError(
        f"file: folder '{p.name}' is neither an AirSAS scan (Coordinates.csv, SysParams.csv, "
        "Flight-*.csv ...), an AirSAS deconvolved-ping folder (weights_trans_*_*.npy) nor an SVSS "
        "track ('unpack float - LF - down - N.hdf5') "
        "(fix: give the scan or track folder itself; layouts in docs/formats.md)")


def _detect_zip(p: Path) -> str:
    """The format of a zipped folder, from its member names (read from the central directory)."""
    from shsas_core.formats.tree import open_tree

    with open_tree(p) as top:
        names = [q.name for q in top.rglob("*")]
    if any(_SVSS_NAME.match(n) for n in names):
        return "svss"
    if any(_DECONVOLVED_NAME.match(n) for n in names):
        return "airsas-deconvolved"
    return "airsas-csv"  # its reader names what is missing


def detect_format(path: str | os.PathLike) -> str:
    """Return one of :data:`FORMATS` for ``path`` or raise UnsupportedFormatError."""
    p = Path(path)
    if not p.exists():
        raise SurveyValidationError("file", f"'{p}' does not exist", "check the path")
    if p.is_dir():
        return _detect_dir(p)
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        if _SVSS_NAME.match(p.name):
            return "svss"
        import h5py

        try:
            with h5py.File(p, "r") as f:
                if f.attrs.get("format") in ("shsas-survey", b"shsas-survey"):
                    return "shsas"
                if "DataReal" in f or "Position" in f:
                    return "svss"
        except (OSError, RuntimeError, KeyError):
            return "shsas"  # let the canonical reader report the corruption precisely
        return "shsas"
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        return _detect_zip(p)
    if head[:1] == b"\x80" or p.suffix.lower() in (".pkl", ".pik", ".pickle"):
        return "airsas-pickle"
    raise UnsupportedFormatError(
        f"file: '{p.name}' is not a recognised survey (expected canonical HDF5, an AirSAS CSV folder "
        "or .zip, an AirSAS processed pickle, or SVSS HDF5) (fix: check that this is the survey file; "
        "write other data as a canonical HDF5 survey, docs/formats.md)")


def load_survey(path: str | os.PathLike, fmt: str = "auto", *, load_samples: bool = True,
                progress: ProgressFn | None = None, **options: Any) -> Survey:
    """Load a survey of any supported format.

    Args:
        fmt: "auto" or one of :data:`FORMATS`.
        load_samples: False reads only metadata and geometry where the format allows.
        progress: ``progress(fraction, stage, metrics)`` for importers that read many files
            (AirSAS CSV); ignored by the others.
        options: importer keywords, e.g. ``background=``, ``waveform=`` (AirSAS CSV),
            ``image_number=``, ``temperature_f=`` (SVSS), ``geometry=`` (AirSAS deconvolved),
            ``scene_box=`` (all importers).
    """
    try:
        fmt = detect_format(path) if fmt == "auto" else fmt
        if progress is not None and fmt in ("airsas-csv", "airsas-deconvolved"):
            options = {**options, "progress": progress}
        return _load(path, fmt, load_samples, options)
    except ShsasError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, UnicodeError, EOFError) as exc:
        # safety net: a library error on a malformed file becomes a one-line, named problem
        raise SurveyValidationError(
            "file", f"'{Path(path).name}' could not be read ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0][:160] if str(exc) else 'no detail'})",
            "check that the file is complete and in one of the layouts of docs/formats.md") from None


def _load(path: str | os.PathLike, fmt: str, load_samples: bool, options: dict[str, Any]) -> Survey:
    if fmt == "shsas":
        from shsas_core.formats.hdf5 import read_survey

        if options:
            raise SurveyValidationError("options", f"{sorted(options)} do not apply to canonical files",
                                        "drop these options for .h5 survey files")
        return read_survey(path, load_samples=load_samples)
    if fmt == "airsas-csv":
        from shsas_core.formats.airsas import read_airsas_csv

        return read_airsas_csv(path, load_samples=load_samples, **options)
    if fmt == "airsas-pickle":
        from shsas_core.formats.airsas import read_airsas_pickle

        return read_airsas_pickle(path, load_samples=load_samples, **options)
    if fmt == "svss":
        from shsas_core.formats.svss import read_svss

        return read_svss(path, load_samples=load_samples, **options)
    if fmt == "airsas-deconvolved":
        from shsas_core.formats.airsas_deconvolved import read_deconvolved_folder

        return read_deconvolved_folder(path, load_samples=load_samples, **options)
    raise UnsupportedFormatError(f"format: unknown format '{fmt}' (fix: use auto or one of {', '.join(FORMATS)})")
