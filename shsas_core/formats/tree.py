"""A read-only folder for the importers of folder formats: a folder on disk, or a .zip of one.

The AirSAS CSV, deconvolved-ping and SVSS readers walk a :class:`Node` rather than a ``Path``,
so a zip is read member by member and never extracted: a member is decompressed only when a
reader asks for its bytes, and its size is checked from the zip's central directory first
(:mod:`.safe_zip`). HDF5 members (SVSS), which the HDF5 library opens as files, are the one
exception: :meth:`Node.local_file` copies that one member into a temporary folder made with
:mod:`tempfile` (so under ``TMPDIR``; the service points it into the upload's own folder) and
removes it when the read ends.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from shsas_core.common.errors import SurveyValidationError
from shsas_core.formats.safe_zip import SafeZip, is_zip


class Node:
    """A file or folder inside a tree; ``parts`` is its path from the tree's top."""

    def __init__(self, disk: Path | None, archive: SafeZip | None, parts: tuple[str, ...], label: str):
        self._disk, self._zip, self.parts, self._label = disk, archive, parts, label

    # -- naming -------------------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The last path part; for the top of a tree, the folder's (or zip's, without .zip) name."""
        return self.parts[-1] if self.parts else self._label

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix

    @property
    def stem(self) -> str:
        return Path(self.name).stem

    def __truediv__(self, name: str) -> Node:
        return Node(self._disk, self._zip, (*self.parts, name), self._label)

    @property
    def parent(self) -> Node:
        return Node(self._disk, self._zip, self.parts[:-1], self._label)

    def relative_parts(self, top: Node) -> tuple[str, ...]:
        return self.parts[len(top.parts):]

    def __repr__(self) -> str:
        return f"Node({'/'.join((self._label, *self.parts))!r})"

    # -- what is there ------------------------------------------------------------------------

    def _path(self) -> Path:
        assert self._disk is not None
        return self._disk.joinpath(*self.parts)

    def is_file(self) -> bool:
        return self._path().is_file() if self._zip is None else self.parts in self._zip.files

    def is_dir(self) -> bool:
        return self._path().is_dir() if self._zip is None else self.parts in self._zip.dirs

    def iterdir(self) -> list[Node]:
        """The entries directly inside this folder, by name."""
        if self._zip is None:
            names = {p.name for p in self._path().iterdir()}
        else:
            n = len(self.parts)
            names = {k[n] for k in (*self._zip.files, *self._zip.dirs) if len(k) > n and k[:n] == self.parts}
        return [self / name for name in sorted(names)]

    def rglob(self, pattern: str) -> list[Node]:
        """Every file under this folder (at any depth) whose name matches ``pattern``."""
        if self._zip is None:
            root = self._path()
            return [self._from_path(p, root) for p in sorted(root.rglob(pattern)) if p.is_file()]
        n = len(self.parts)
        return [Node(None, self._zip, k, self._label) for k in sorted(self._zip.files)
                if len(k) > n and k[:n] == self.parts and fnmatch.fnmatchcase(k[-1], pattern)]

    def _from_path(self, p: Path, root: Path) -> Node:
        return Node(self._disk, None, (*self.parts, *p.relative_to(root).parts), self._label)

    # -- reading ------------------------------------------------------------------------------

    def size(self) -> int:
        """Bytes of this file: from the file system, or declared by the zip's central directory."""
        return self._path().stat().st_size if self._zip is None else self._zip.files[self.parts].file_size

    def read_bytes(self, limit: int) -> bytes:
        """The file's bytes, refused when its size is over ``limit``."""
        size = self.size()
        if size > limit:
            raise SurveyValidationError(self.name, f"is {size} bytes, over the limit of {limit}")
        if self._zip is None:
            return self._path().read_bytes()
        return self._zip.read(self.parts, limit)

    def read_text(self, limit: int) -> str:
        """The file as UTF-8 text (a byte-order mark is dropped)."""
        try:
            return self.read_bytes(limit).decode("utf-8-sig")
        except UnicodeDecodeError:
            raise SurveyValidationError(self.name, "is not a UTF-8/ASCII text file") from None

    @contextlib.contextmanager
    def local_file(self, limit: int) -> Iterator[Path]:
        """A path on disk holding this file, for libraries that open files by name (HDF5).

        On disk, the file itself; inside a zip, a copy in a fresh temporary folder (under
        ``TMPDIR``), removed on exit. The copy keeps the member's name, so messages name it.
        """
        if self._zip is None:
            yield self._path()
            return
        with tempfile.TemporaryDirectory(prefix="shsas-member-") as tmp:
            dest = Path(tmp) / self.name
            self._zip.copy_to(self.parts, dest, limit)
            yield dest


@contextlib.contextmanager
def open_tree(path: str | os.PathLike) -> Iterator[Node]:
    """The top of the tree at ``path``: a folder, or a .zip (checked by :class:`.SafeZip`).

    Raises:
        SurveyValidationError: ``path`` does not exist, or is neither a folder nor a zip.
        UnsafeFileError: the zip breaks one of :mod:`.safe_zip`'s rules.
    """
    p = Path(path)
    if p.is_dir():
        yield Node(p, None, (), p.name)
        return
    if not p.exists():
        raise SurveyValidationError("file", f"'{p}' does not exist")
    if not is_zip(p):
        raise SurveyValidationError("file", f"'{p.name}' is neither a folder nor a .zip of one",
                                    "give the scan folder, or a .zip of it")
    archive = SafeZip(p)
    try:
        yield Node(None, archive, (), p.stem)
    finally:
        archive.close()


def shallowest(top: Node, holds) -> Node:
    """The shallowest folder under ``top`` (``top`` included) for which ``holds(folder)`` is
    true; ``top`` itself when none does (the reader then names what is missing).

    Raises:
        SurveyValidationError: several at the same depth (ambiguous).
    """
    if holds(top):
        return top
    level = [d for d in top.iterdir() if d.is_dir()]
    while level:
        found = [d for d in level if holds(d)]
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise SurveyValidationError("file", f"'{top.name}' holds several scans ({', '.join(d.name for d in found)}); "
                                        "import one folder at a time")
        level = [e for d in level for e in d.iterdir() if e.is_dir()]
    return top
