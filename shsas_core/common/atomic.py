"""Atomic file writes: the one temporary-name scheme of the package.

Every file a job writes (artifacts, checkpoints, caches, surveys) is written to a temporary name
beside its target and renamed onto it (``os.replace``, atomic on one file system), so a reader
never sees half a file and a killed run leaves no partial artifact under the real name. What a
killed run does leave is a temporary file; :func:`is_partial` recognises one and
:func:`remove_partials` clears them before a job is resumed (the worker calls it and need not
know the names).
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

#: Temporary names: ``.{name}.{pid}.tmp`` (hidden, per process, so two writers never share one).
#: Also matched: ``{name}.tmp`` and ``{name}.tmp{pid}``, the names earlier versions used, so a job
#: folder left by one of them is cleaned too.
_PARTIAL = re.compile(r"\.tmp\d*$")


def temporary_name(path: Path) -> Path:
    """The temporary file beside ``path`` that :func:`atomic_path` writes first."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def is_partial(name: str) -> bool:
    """Whether a file name is a temporary one (a write that did not finish, or is running)."""
    return bool(_PARTIAL.search(name))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (parent folders created); on success rename it
    onto ``path``; on error remove it. Write the whole file to the yielded path (by name, or
    through ``open(tmp, "wb")`` for writers that append a suffix to names, such as ``np.save``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def remove_partials(folder: str | os.PathLike) -> None:
    """Delete the temporary files a killed run left under ``folder`` (recursively); keep the rest."""
    root = Path(folder)
    if not root.is_dir():
        return
    for p in root.rglob("*.tmp*"):
        if p.is_file() and is_partial(p.name):
            p.unlink(missing_ok=True)
