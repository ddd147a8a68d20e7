"""Keep the server's own file system out of what clients read.

Validators and importers name the files they read; for an upload those live in the server's
temporary and data folders (``/tmp/shsas-airsas-x1y2z3ab/...``, ``<data>/uploads/<random>/``),
whose names and layout are none of the client's business. :func:`redact_paths` rewrites them
in every error message the API sends: a path becomes the name of the file it ends in (the
member of the client's own archive), a bare temporary folder name becomes "the archive".
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Iterable

#: A folder name made by ``tempfile`` (a prefix, then 8 random characters of ``[a-z0-9_]``).
_TEMP_NAME = re.compile(r"\b(?:shsas-[a-z0-9]+-|tmp)[a-z0-9_]{8}\b")
#: What ends a path inside a message: whitespace, quotes and punctuation.
_PATH_TAIL = r"/[^\s'\"`,;:()\[\]{}]*"


def _last_part(root_len: int):
    def last(m: re.Match[str]) -> str:
        parts = [p for p in m.group(0)[root_len:].split("/") if p]
        return parts[-1] if len(parts) > 1 else "the archive"

    return last


def redact_paths(message: str, roots: Iterable[str] = ()) -> str:
    """``message`` without absolute paths under ``roots`` (plus the temp dir) or temp folder names."""
    for root in {tempfile.gettempdir(), *roots}:
        root = root.rstrip("/")
        if len(root) < 2:  # never treat "/" as a root: every path would go
            continue

        message = re.sub(re.escape(root) + _PATH_TAIL, _last_part(len(root)), message)
    return _TEMP_NAME.sub("the archive", message)
