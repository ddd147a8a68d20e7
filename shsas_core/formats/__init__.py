"""Survey formats: turn the files users bring into a :class:`~shsas_core.data.survey.Survey`.

A registry (:mod:`.registry`) of one :class:`~.registry.Format` per format, each declared in its
own module: the canonical HDF5 file (:mod:`.canonical`, read and written by :mod:`.hdf5`), an
SVSS track (:mod:`.svss`), a folder of AirSAS pulse-deconvolved pings
(:mod:`.airsas_deconvolved`), an AirSAS CSV scan folder (:mod:`.airsas_csv`) and an AirSAS
processed pickle (:mod:`.airsas_pickle`). ``load_survey(path, fmt="auto")`` detects the format
from the contents (not the extension) and validates the options against that format's model.
A .zip of a folder format is detected by its member names and read member by member, never
extracted (:mod:`.tree`). Layouts and conversions: docs/formats.md.
"""

from __future__ import annotations

from shsas_core.formats import airsas_csv, airsas_deconvolved, airsas_pickle, canonical, svss
from shsas_core.formats.options import FormatOptions, ImportOptions
from shsas_core.formats.registry import (
    Claim,
    Format,
    all_formats,
    detect_format,
    format_names,
    get_format,
    load_survey,
    register,
    stored_name,
    unregister,
)

# On equal claims the earlier wins: an SVSS file name beats a deconvolved ping, which beats an
# AirSAS marker file in the same folder.
for _fmt in (canonical.FORMAT, svss.FORMAT, airsas_deconvolved.FORMAT, airsas_csv.FORMAT, airsas_pickle.FORMAT):
    register(_fmt)

__all__ = ["Claim", "Format", "FormatOptions", "ImportOptions", "all_formats", "detect_format", "format_names",
           "get_format", "load_survey", "register", "stored_name", "unregister"]
