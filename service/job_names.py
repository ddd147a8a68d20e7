"""What a job is called: the operator's label, given at submission, and the names its files
get when downloaded (the uploaded survey's file name first, so that files of several jobs
saved in one folder stay apart)."""

from __future__ import annotations

import re
from pathlib import PurePath
from urllib.parse import quote

from .uploads import UploadError

#: Longest label kept (the job table's column holds this many characters).
MAX_LABEL = 200


def job_label(raw: str | None) -> str | None:
    """The label to store: trimmed, None when empty. Raises UploadError 422 naming the problem
    for control characters or a label over :data:`MAX_LABEL` characters."""
    if raw is None or not raw.strip():
        return None
    label = raw.strip()
    if len(label) > MAX_LABEL:
        raise UploadError(422, f"label: {len(label)} characters, over the limit of {MAX_LABEL} "
                               "(fix: give a shorter name)")
    if not label.isprintable():
        raise UploadError(422, "label: contains control characters such as line breaks "
                               "(fix: give a label on one line)")
    return label


def download_name(client_name: str | None, artifact: str) -> str:
    """``<survey stem>_<artifact>`` (``scan 42.h5`` -> ``scan 42_shsas_mesh.glb``), or the artifact's
    own name for jobs whose file name was not kept."""
    stem = PurePath((client_name or "").replace("\\", "/")).stem.strip(" .")
    return f"{stem}_{artifact}" if stem else artifact


def content_disposition(name: str, disposition: str = "inline") -> str:
    """A Content-Disposition header for ``name``: an ASCII fallback plus the UTF-8 name (RFC 6266)."""
    ascii_name = re.sub(r'[^A-Za-z0-9 ._()+-]', "_", name)
    return f"{disposition}; filename=\"{ascii_name}\"; filename*=UTF-8''{quote(name, safe='')}"
