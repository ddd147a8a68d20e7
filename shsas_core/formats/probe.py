"""What a format's ``sniff`` sees of a path: its kind, its first bytes, its member names.

One :class:`Probe` is made per detection and handed to every registered format, so the costly
looks (listing a zip's central directory, opening an HDF5 file, searching a folder tree) are
made at most once, and only when a format asks for them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Literal

from shsas_core.common.errors import SurveyValidationError

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")

Kind = Literal["folder", "zip", "hdf5", "file"]


@dataclass(frozen=True)
class Hdf5Root:
    """The root of an HDF5 file: its ``format`` attribute (None when absent) and its top-level names."""

    format: str | None
    names: frozenset[str]


class Probe:
    """A path as the formats' ``sniff`` functions see it.

    Attributes:
        path: the path given.
        kind: ``folder``, ``zip`` or ``hdf5`` (from the first bytes, not the extension), else ``file``.
        head: the first 8 bytes of a file (empty for a folder).

    Raises:
        SurveyValidationError: ``path`` does not exist.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.exists():
            raise SurveyValidationError("file", f"'{self.path}' does not exist", "check the path")
        self.head = b""
        if self.path.is_dir():
            self.kind: Kind = "folder"
            return
        with open(self.path, "rb") as fh:
            self.head = fh.read(8)
        self.kind = ("hdf5" if self.head.startswith(HDF5_MAGIC) else
                     "zip" if self.head.startswith(ZIP_MAGICS) else "file")

    @property
    def name(self) -> str:
        return self.path.name

    @cached_property
    def names(self) -> frozenset[str]:
        """Entry names: a folder's entries directly inside it; every member's name (any depth) of a
        zip, read from its central directory (:mod:`.safe_zip` checks it); nothing for a file."""
        if self.kind == "folder":
            return frozenset(q.name for q in self.path.iterdir())
        if self.kind == "zip":
            from shsas_core.formats.tree import open_tree

            with open_tree(self.path) as top:
                return frozenset(q.name for q in top.rglob("*"))
        return frozenset()

    def holds_anywhere(self, name: str) -> bool:
        """Whether a file called ``name`` lies anywhere under a folder (or in a zip)."""
        if self.kind == "folder":
            return any(p.is_file() for p in self.path.rglob(name))
        return name in self.names

    @cached_property
    def hdf5_root(self) -> Hdf5Root | None:
        """The root of an HDF5 file; None when this is no HDF5 file or the library cannot open it."""
        if self.kind != "hdf5":
            return None
        import h5py

        try:
            with h5py.File(self.path, "r") as f:
                fmt = f.attrs.get("format")
                if isinstance(fmt, bytes):
                    fmt = fmt.decode("utf-8", "replace")
                return Hdf5Root(fmt if isinstance(fmt, str) else None, frozenset(f.keys()))
        except (OSError, RuntimeError, KeyError):
            return None
