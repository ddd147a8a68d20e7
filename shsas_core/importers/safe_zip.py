"""Extract an uploaded .zip without letting it write outside a given folder or fill the disk.

Refused: absolute member names, ``..`` components, drive letters, backslash tricks, symlink
members, more than :data:`MAX_ZIP_MEMBERS` members, and more than ``max_bytes`` of data. Sizes
are counted while streaming, so a member that lies about its size in the header cannot get
past the cap.
"""

from __future__ import annotations

import os
import shutil
import stat
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from ..errors import SurveyValidationError, UnsafeFileError

#: Cap on the total uncompressed size (a full AirSAS scan plus background is ~2 GB of CSV).
MAX_ZIP_BYTES = 16 * 1024**3
#: 54,000 flights + 54,000 background flights + parameter files, with room to spare.
MAX_ZIP_MEMBERS = 500_000
_CHUNK = 1 << 20


def _member_path(name: str) -> PurePosixPath:
    if not name or "\x00" in name:
        raise UnsafeFileError("zip", f"member name {name!r} is empty or contains NUL")
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or (p.parts and ":" in p.parts[0]):
        raise UnsafeFileError(
            "zip", f"member '{name}' would be written outside the extraction folder (path traversal)",
            "zip the scan folder with relative paths only")
    return p


def safe_extract(zip_path: str | os.PathLike, dest: str | os.PathLike, *,
                 max_bytes: int = MAX_ZIP_BYTES, max_members: int = MAX_ZIP_MEMBERS) -> Path:
    """Extract ``zip_path`` into the existing folder ``dest``; return ``dest``.

    Raises:
        UnsafeFileError: traversal, links or size over the cap (nothing outside ``dest`` is written).
        SurveyValidationError: the file is not a readable zip.
    """
    dest = Path(dest).resolve()
    try:
        with zipfile.ZipFile(zip_path) as zf:
            infos = zf.infolist()
            if len(infos) > max_members:
                raise UnsafeFileError("zip", f"has {len(infos)} members, over the limit of {max_members}")
            declared = 0
            paths = []
            # validate every name and the declared total before writing anything
            for info in infos:
                p = _member_path(info.filename)
                if stat.S_ISLNK(info.external_attr >> 16):
                    raise UnsafeFileError("zip", f"member '{info.filename}' is a symbolic link; links are refused")
                declared += info.file_size
                if declared > max_bytes:
                    raise UnsafeFileError("zip", f"declares more than {max_bytes} bytes uncompressed (zip bomb?)")
                paths.append(p)
            written = 0
            for info, p in zip(infos, paths, strict=True):
                target = dest.joinpath(*p.parts)
                if not target.resolve().is_relative_to(dest):
                    raise UnsafeFileError("zip", f"member '{info.filename}' resolves outside the extraction folder")
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(info) as src, open(target, "wb") as dst:
                    while chunk := src.read(_CHUNK):
                        written += len(chunk)
                        if written > max_bytes:
                            raise UnsafeFileError("zip", f"expands to more than {max_bytes} bytes (zip bomb?)")
                        dst.write(chunk)
    except SurveyValidationError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError, RuntimeError,
            zlib.error) as exc:
        raise SurveyValidationError("zip", f"'{Path(zip_path).name}' is not a readable zip ({str(exc)[:120]})") from None
    return dest


def clear(folder: str | os.PathLike) -> None:
    """Remove an extraction folder (ignoring errors: it lives in a temporary directory)."""
    shutil.rmtree(folder, ignore_errors=True)
