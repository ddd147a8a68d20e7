"""Stream a multipart upload to disk with a byte cap, hashing as it goes.

FastAPI's ``UploadFile`` would buffer the whole body into a temporary file before the handler
runs and knows no size limit, so the request body is parsed here with python-multipart's
streaming parser instead: the ``survey`` part goes straight to a file in the data dir (never
into memory), the small ``spec`` part into a bounded buffer. Past the cap the partial file is
deleted and :class:`UploadError` with status 413 is raised.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

from anyio import to_thread
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import Request

MAX_TEXT_FIELD = 64 * 1024
#: Raw bytes handed to the parser (in a thread) at a time: amortises the thread hop.
BATCH = 1024 * 1024
#: After the cap is passed the rest of the body is read and dropped up to this many bytes, so
#: the client gets to read the 413 instead of a reset connection.
DRAIN_LIMIT = 64 * 1024 * 1024


class UploadError(Exception):
    """A request body the service refuses; ``status`` is the HTTP status to answer."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass
class Upload:
    """What arrived: the survey file on disk and the text fields."""

    path: Path | None = None
    filename: str | None = None
    size: int = 0
    sha256: str = ""
    fields: dict[str, str] = field(default_factory=dict)


class _Receiver:
    """python-multipart callbacks that route each part to a file or a text buffer."""

    def __init__(self, dest: Path, max_bytes: int, file_field: str):
        self.dest, self.max_bytes, self.file_field = dest, max_bytes, file_field
        self.result = Upload()
        self._hash = hashlib.sha256()
        self._fh = None
        self._text: bytearray | None = None
        self._name: str | None = None
        self._hdr_field = bytearray()
        self._hdr_value = bytearray()
        self._headers: dict[str, bytes] = {}
        self.ended = False

    def callbacks(self) -> dict:
        return {
            "on_part_begin": self._part_begin, "on_header_field": self._header_field,
            "on_header_value": self._header_value, "on_header_end": self._header_end,
            "on_headers_finished": self._headers_finished, "on_part_data": self._part_data,
            "on_part_end": self._part_end, "on_end": self._end,
        }

    def _part_begin(self) -> None:
        self._headers = {}
        self._name = None

    def _header_field(self, data: bytes, start: int, end: int) -> None:
        self._hdr_field += data[start:end]

    def _header_value(self, data: bytes, start: int, end: int) -> None:
        self._hdr_value += data[start:end]

    def _header_end(self) -> None:
        self._headers[self._hdr_field.decode("latin-1").lower()] = bytes(self._hdr_value)
        self._hdr_field.clear()
        self._hdr_value.clear()

    def _headers_finished(self) -> None:
        _, params = parse_options_header(self._headers.get("content-disposition", b""))
        name = params.get(b"name", b"").decode("utf-8", "replace")
        self._name = name
        if name == self.file_field:
            if self.result.path is not None:
                raise UploadError(400, f"{self.file_field}: more than one file part")
            self.result.filename = params.get(b"filename", b"").decode("utf-8", "replace")[:200]
            self.result.path = self.dest
            self._fh = open(self.dest, "wb")
        else:
            self._text = bytearray()

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        chunk = data[start:end]
        if self._fh is not None:
            self.result.size += len(chunk)
            if self.result.size > self.max_bytes:
                raise UploadError(413, f"{self.file_field}: upload is larger than the limit of "
                                       f"{self.max_bytes} bytes (SHSAS_MAX_UPLOAD_BYTES)")
            self._hash.update(chunk)
            self._fh.write(chunk)
        elif self._text is not None:
            self._text += chunk
            if len(self._text) > MAX_TEXT_FIELD:
                raise UploadError(413, f"{self._name}: form field larger than {MAX_TEXT_FIELD} bytes")

    def _part_end(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
            self.result.sha256 = self._hash.hexdigest()
        elif self._text is not None and self._name:
            try:
                self.result.fields[self._name] = self._text.decode("utf-8")
            except UnicodeDecodeError:
                raise UploadError(400, f"{self._name}: form field is not UTF-8 text") from None
            self._text = None

    def _end(self) -> None:
        self.ended = True

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


async def receive_upload(request: Request, dest: Path, max_bytes: int, file_field: str = "survey") -> Upload:
    """Parse a multipart/form-data body, writing part ``file_field`` to ``dest``.

    Raises:
        UploadError: 415 not multipart, 413 over ``max_bytes``, 400 malformed body. The
            partial file is deleted before raising.
    """
    ctype, params = parse_options_header(request.headers.get("content-type"))
    if ctype != b"multipart/form-data" or not params.get(b"boundary"):
        raise UploadError(415, "request body must be multipart/form-data with a 'survey' file part and "
                               "an optional 'spec' JSON part")
    clen = request.headers.get("content-length")
    if clen is not None and clen.isdigit() and int(clen) > max_bytes + DRAIN_LIMIT:
        raise UploadError(413, f"{file_field}: request of {clen} bytes is larger than the limit of "
                               f"{max_bytes} bytes (SHSAS_MAX_UPLOAD_BYTES)")
    recv = _Receiver(dest, max_bytes, file_field)
    parser = MultipartParser(params[b"boundary"], recv.callbacks())
    buf = bytearray()
    stream = request.stream()
    try:
        async for chunk in stream:
            buf += chunk
            if len(buf) >= BATCH:
                data, buf = bytes(buf), bytearray()
                await to_thread.run_sync(parser.write, data)
        if buf:
            await to_thread.run_sync(parser.write, bytes(buf))
        parser.finalize()
        if not recv.ended:
            raise UploadError(400, "multipart body ended early (truncated upload or missing closing boundary)")
    except UploadError as exc:
        recv.close()
        dest.unlink(missing_ok=True)
        if exc.status == 413:
            await _drain(stream)
        raise
    except Exception as exc:
        recv.close()
        dest.unlink(missing_ok=True)
        if type(exc).__name__ == "ClientDisconnect":
            raise UploadError(400, "client disconnected during upload") from None
        raise UploadError(400, f"malformed multipart body: {exc}") from None
    return recv.result


async def _drain(stream) -> None:
    seen = 0
    try:
        async for chunk in stream:
            seen += len(chunk)
            if seen > DRAIN_LIMIT:
                break
    except Exception:  # the client may already have gone; nothing to do
        pass
