"""Read an uploaded .zip member by member, without extracting it and within a budget.

The importers of folder formats read a zip through :class:`~shsas_core.formats.tree.Node`
(module ``tree``), which asks this module for one member at a time: nothing is written to disk
and only the members a scan needs are ever decompressed. Before any member is read, the
archive is checked from its central directory:

* at most :data:`MAX_ZIP_MEMBERS` entries, counted from the end-of-central-directory record
  before the directory itself is parsed (a directory of millions of entries would cost
  gigabytes of memory to parse);
* at most :data:`MAX_ZIP_BYTES` uncompressed in all, the sum of the declared member sizes
  (``zipfile`` never returns more bytes than a member declares, and checks its CRC);
* no absolute names, ``..`` components, drive letters, NUL bytes, symbolic links or repeated
  names: such an archive was not made by zipping a scan folder.
"""

from __future__ import annotations

import os
import stat
import struct
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from shsas_core.common.errors import SurveyValidationError, UnsafeFileError

#: Cap on the total declared uncompressed size (a full AirSAS scan plus background is ~2 GB of CSV).
MAX_ZIP_BYTES = 16 * 1024**3
#: 54,000 flights + 54,000 background flights + parameter files, with room to spare.
MAX_ZIP_MEMBERS = 500_000

_EOCD = b"PK\x05\x06"
_EOCD64_LOCATOR = b"PK\x06\x07"
_EOCD64 = b"PK\x06\x06"
#: The end record is 22 bytes plus a comment of at most 65,535.
_TAIL = 22 + 65535


def declared_entries(path: str | os.PathLike) -> int:
    """The entry count the zip's end-of-central-directory record declares (zip64 included).

    Raises:
        SurveyValidationError: no end record (not a zip, or cut short).
    """
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        start = max(0, size - _TAIL)
        fh.seek(start)
        tail = fh.read()
        at = tail.rfind(_EOCD)
        if at < 0 or len(tail) - at < 22:
            raise SurveyValidationError("zip", "has no end-of-central-directory record (not a zip, or cut "
                                        "short)", "upload the whole .zip file")
        entries = struct.unpack_from("<H", tail, at + 10)[0]
        loc = start + at - 20
        if entries == 0xFFFF and loc >= 0:
            fh.seek(loc)
            locator = fh.read(20)
            if locator[:4] == _EOCD64_LOCATOR:
                fh.seek(struct.unpack_from("<Q", locator, 8)[0])
                rec = fh.read(56)
                if rec[:4] == _EOCD64 and len(rec) == 56:
                    entries = struct.unpack_from("<Q", rec, 32)[0]
    return int(entries)


def member_path(name: str) -> PurePosixPath:
    """The member's path inside the archive; refuses names that would point outside it."""
    if not name or "\x00" in name:
        raise UnsafeFileError("zip", f"member name {name!r} is empty or contains NUL")
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or (p.parts and ":" in p.parts[0]):
        raise UnsafeFileError(
            "zip", f"member '{name}' points outside the archive's folder (path traversal)",
            "zip the scan folder with relative paths only")
    return p


class SafeZip:
    """An opened, checked zip: ``files`` maps each member's path parts to its ``ZipInfo``."""

    def __init__(self, path: str | os.PathLike, *, max_bytes: int = MAX_ZIP_BYTES,
                 max_members: int = MAX_ZIP_MEMBERS):
        self.path = Path(path)
        entries = declared_entries(self.path)
        if entries > max_members:
            raise UnsafeFileError("zip", f"has {entries} members, over the limit of {max_members}",
                                  "zip only the scan folder")
        try:
            self.zf = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError, OSError) as exc:
            raise SurveyValidationError("zip", f"'{self.path.name}' is not a readable zip ({str(exc)[:120]})") from None
        try:
            self.files: dict[tuple[str, ...], zipfile.ZipInfo] = {}
            self.dirs: set[tuple[str, ...]] = {()}
            declared = 0
            for info in self.zf.infolist()[:max_members + 1]:
                parts = tuple(q for q in member_path(info.filename).parts if q not in ("", "."))
                if stat.S_ISLNK(info.external_attr >> 16):
                    raise UnsafeFileError("zip", f"member '{info.filename}' is a symbolic link; links are refused")
                for k in range(len(parts)):
                    self.dirs.add(parts[:k])
                if info.is_dir():
                    self.dirs.add(parts)
                    continue
                if parts in self.files:
                    raise UnsafeFileError("zip", f"member '{info.filename}' appears twice")
                declared += info.file_size
                if declared > max_bytes:
                    raise UnsafeFileError("zip", f"declares more than {max_bytes} bytes uncompressed (zip bomb?)",
                                          "zip only the scan folder")
                self.files[parts] = info
            if len(self.files) + len(self.dirs) - 1 > max_members:
                raise UnsafeFileError("zip", f"has more than {max_members} members")
        except BaseException:
            self.zf.close()
            raise

    def read(self, parts: tuple[str, ...], limit: int) -> bytes:
        """One member's bytes; refused from its declared size when over ``limit``."""
        info = self.files[parts]
        if info.file_size > limit:
            raise SurveyValidationError("/".join(parts), f"is {info.file_size} bytes, over the limit of {limit}")
        try:
            with self.zf.open(info) as src:
                return src.read(limit + 1)
        except (zipfile.BadZipFile, EOFError, NotImplementedError, RuntimeError, zlib.error, OSError) as exc:
            raise SurveyValidationError("/".join(parts), f"could not be read from the zip ({str(exc)[:120]})",
                                        "zip the scan folder again") from None

    def copy_to(self, parts: tuple[str, ...], dest: Path, limit: int) -> None:
        """Stream one member into the file ``dest`` (refused from its declared size over ``limit``)."""
        info = self.files[parts]
        if info.file_size > limit:
            raise SurveyValidationError("/".join(parts), f"is {info.file_size} bytes, over the limit of {limit}")
        try:
            with self.zf.open(info) as src, open(dest, "wb") as dst:
                while chunk := src.read(1 << 20):
                    dst.write(chunk)
        except (zipfile.BadZipFile, EOFError, NotImplementedError, RuntimeError, zlib.error) as exc:
            raise SurveyValidationError("/".join(parts), f"could not be read from the zip ({str(exc)[:120]})",
                                        "zip the scan folder again") from None

    def close(self) -> None:
        self.zf.close()


def is_zip(path: str | os.PathLike) -> bool:
    """True when ``path`` is a file starting with a zip signature."""
    p = Path(path)
    if not p.is_file():
        return False
    with open(p, "rb") as fh:
        return fh.read(4) in (b"PK\x03\x04", b"PK\x05\x06")
