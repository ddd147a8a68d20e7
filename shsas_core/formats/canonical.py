"""The canonical shsas survey file (HDF5, schema in docs/formats.md section 1) as a registered format.

Any HDF5 file no other format recognises falls back to this one, so that the canonical reader
(:mod:`.hdf5`) names what the file lacks or why it cannot be read.
"""

from __future__ import annotations

from pathlib import Path

from shsas_core.common.progress import ProgressFn
from shsas_core.data.survey import Survey
from shsas_core.formats.options import FormatOptions
from shsas_core.formats.probe import Probe
from shsas_core.formats.registry import Claim, Format

#: The value of the root ``format`` attribute (``hdf5.FORMAT_NAME``, kept here free of h5py).
FORMAT_ATTRIBUTE = "shsas-survey"
#: The name the service stores a job's input under: every upload is kept as a canonical file.
STORED_NAME = "survey.h5"


class CanonicalOptions(FormatOptions):
    """The canonical file takes no options: it says everything itself."""


def sniff(probe: Probe) -> Claim:
    if probe.kind != "hdf5":
        return Claim.NO
    root = probe.hdf5_root
    return Claim.YES if root is not None and root.format == FORMAT_ATTRIBUTE else Claim.FALLBACK


def read(path: Path, options: CanonicalOptions, load_samples: bool, progress: ProgressFn) -> Survey:
    from shsas_core.formats.hdf5 import read_survey

    return read_survey(path, load_samples=load_samples)


FORMAT = Format(name="shsas", summary="canonical shsas HDF5", sniff=sniff, read=read,
                options=CanonicalOptions, stored_name=STORED_NAME)
