"""Serve artifact files with ETag / If-None-Match (304) and single byte ranges (206, 416)."""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

from starlette.responses import Response, StreamingResponse

MEDIA_TYPES = {
    ".glb": "model/gltf-binary",
    ".ply": "application/octet-stream",
    ".npy": "application/octet-stream",
    ".json": "application/json",
    ".html": "text/html; charset=utf-8",
    ".png": "image/png",
}
CHUNK = 256 * 1024
_RANGE = re.compile(r"^bytes=([0-9]*)-([0-9]*)$")


def media_type(name: str) -> str:
    return MEDIA_TYPES.get(Path(name).suffix.lower(), "application/octet-stream")


def etag_of(path: Path) -> str:
    """A strong validator from inode, size and mtime (artifacts are replaced, never edited)."""
    st = path.stat()
    raw = f"{st.st_ino}-{st.st_size}-{st.st_mtime_ns}".encode()
    return '"' + hashlib.sha256(raw).hexdigest()[:32] + '"'


def _matches(header: str, etag: str) -> bool:
    if header.strip() == "*":
        return True
    tags = [t.strip().removeprefix("W/") for t in header.split(",")]
    return etag in tags


def _read(path: Path, start: int, length: int) -> Iterator[bytes]:
    with open(path, "rb") as fh:
        fh.seek(start)
        left = length
        while left > 0:
            block = fh.read(min(CHUNK, left))
            if not block:
                break
            left -= len(block)
            yield block


def _position(digits: str, size: int) -> int | None:
    """A byte position from a Range header (None when empty); past ``size`` it is ``size``.

    Any value at or beyond the file's size means the same thing (past the end), so it is
    clamped before conversion: the number can be as long as the header.
    """
    if not digits:
        return None
    digits = digits.lstrip("0") or "0"
    if len(digits) > len(str(size)):
        return size
    return min(int(digits), size)


def _send(path: Path, start: int, length: int, status: int, mtype: str, headers: dict[str, str],
          head: bool) -> Response:
    headers = {**headers, "Content-Length": str(length)}
    if head:  # the same status and headers, no body (RFC 9110 §9.3.2)
        return Response(status_code=status, media_type=mtype, headers=headers)
    return StreamingResponse(_read(path, start, length), status_code=status, media_type=mtype, headers=headers)


def file_response(path: Path, headers_in, download_name: str, *, head: bool = False) -> Response:
    """200 / 206 / 304 / 416 for ``path`` following RFC 9110 for one range; ``head``: headers only."""
    size = path.stat().st_size
    etag = etag_of(path)
    base = {
        "ETag": etag, "Accept-Ranges": "bytes", "Cache-Control": "private, max-age=0, must-revalidate",
        "Content-Disposition": f'inline; filename="{download_name}"',
        "X-Content-Type-Options": "nosniff",
        # Reports are HTML made from user data: never let them run script on this origin.
        "Content-Security-Policy": "sandbox; default-src 'none'; img-src data:; style-src 'unsafe-inline'",
    }
    inm = headers_in.get("if-none-match")
    if inm is not None and _matches(inm, etag):
        return Response(status_code=304, headers={k: v for k, v in base.items() if k in ("ETag", "Cache-Control")})
    mtype = media_type(download_name)
    rng = headers_in.get("range")
    if_range = headers_in.get("if-range")
    if rng and (if_range is None or if_range.strip() == etag):
        m = _RANGE.match(rng.strip())
        if m and (m.group(1) or m.group(2)):
            # Digits of any length are legal (RFC 9110); compare them with the size before
            # int(), which refuses strings over 4300 digits.
            first, last = _position(m.group(1), size), _position(m.group(2), size)
            if first is not None:
                start = first
                end = min(last, size - 1) if last is not None else size - 1
            else:  # suffix range: the last N bytes
                assert last is not None
                start, end = max(size - last, 0), size - 1
            if start >= size or end < start or (first is None and last == 0):
                return Response(status_code=416, headers={**base, "Content-Range": f"bytes */{size}"})
            return _send(path, start, end - start + 1, 206, mtype,
                         {**base, "Content-Range": f"bytes {start}-{end}/{size}"}, head)
        # Multiple or malformed ranges: RFC 9110 lets us ignore Range and send the whole file.
    return _send(path, 0, size, 200, mtype, base, head)


def safe_artifact_path(out_dir: Path, name: str, allowed: list[str]) -> Path | None:
    """The path of artifact ``name`` if the job lists it; names never come from the client as paths."""
    if name not in allowed or os.sep in name or name.startswith("."):
        return None
    p = out_dir / name
    return p if p.is_file() else None
