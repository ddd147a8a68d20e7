"""Importers: turn the formats users bring into a :class:`~shsas_core.survey.Survey`.

``load_survey(path, fmt="auto")`` detects the format from the contents (not the extension).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import SurveyValidationError, UnsupportedFormatError
from ..survey import Survey

FORMATS = ("shsas", "airsas-csv", "airsas-pickle", "svss")


def detect_format(path: str | os.PathLike) -> str:
    """Return one of :data:`FORMATS` for ``path`` or raise UnsupportedFormatError."""
    p = Path(path)
    if not p.exists():
        raise SurveyValidationError("file", f"'{p}' does not exist")
    if p.is_dir():
        return "airsas-csv"
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        import h5py

        try:
            with h5py.File(p, "r") as f:
                if f.attrs.get("format") in ("shsas-survey", b"shsas-survey"):
                    return "shsas"
                if "DataReal" in f or "Position" in f:
                    return "svss"
        except OSError:
            return "shsas"  # let the canonical reader report the corruption precisely
        return "shsas"
    if head.startswith(b"PK\x03\x04"):
        return "airsas-csv"
    if head[:1] == b"\x80":
        return "airsas-pickle"
    raise UnsupportedFormatError(
        f"file: '{p.name}' is not a recognised survey (expected canonical HDF5, an AirSAS CSV folder "
        "or .zip, an AirSAS processed pickle, or SVSS HDF5)")


def load_survey(path: str | os.PathLike, fmt: str = "auto", *, load_samples: bool = True) -> Survey:
    """Load a survey of any supported format."""
    fmt = detect_format(path) if fmt == "auto" else fmt
    if fmt == "shsas":
        from ..io import read_survey

        return read_survey(path, load_samples=load_samples)
    if fmt == "airsas-csv":
        from .airsas import read_airsas_csv

        return read_airsas_csv(path)
    if fmt == "airsas-pickle":
        from .airsas import read_airsas_pickle

        return read_airsas_pickle(path)
    if fmt == "svss":
        from .svss import read_svss

        return read_svss(path)
    raise UnsupportedFormatError(f"format: unknown format '{fmt}' (use auto or one of {', '.join(FORMATS)})")
