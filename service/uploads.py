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
#: python-multipart refuses longer boundaries (RFC 2046 allows 70 characters).
MAX_BOUNDARY = 256
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

    @property
    def display_name(self) -> str:
        """The client's file name for messages (never the server's ``upload.part``)."""
        return self.filename or "(no filename given)"


def clean_filename(raw: bytes) -> str:
    """The client's file name, safe to echo in a message: no control characters, ≤ 200 chars."""
    name = raw.decode("utf-8", "replace")
    return "".join(ch for ch in name if ch.isprintable())[:200]


def expected_fields(file_field: str, text_fields: tuple[str, ...]) -> str:
    """What the form must hold, for messages: ``'survey' (the survey file) and 'spec' (...)``."""
    parts = [f"'{file_field}' (the survey file)"] + [f"'{t}' (the ReconstructionSpec as JSON)"
                                                     if t == "spec" else f"'{t}'" for t in text_fields]
    return " and ".join(parts)


class _Receiver:
    """python-multipart callbacks that route each part to a file or a text buffer."""

    def __init__(self, dest: Path, max_bytes: int, file_field: str, text_fields: tuple[str, ...]):
        self.dest, self.max_bytes, self.file_field = dest, max_bytes, file_field
        self.text_fields = text_fields
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
        name = clean_filename(params.get(b"name", b""))[:64]
        self._name = name
        # Refuse a misnamed part here, before its data arrives: `-F file=@scan.h5` must not be
        # read as an oversized text field, and `-F specs=...` must not run the default spec.
        expected = expected_fields(self.file_field, self.text_fields)
        if not name:
            raise UploadError(422, f"form part without a name (fix: send the form fields {expected})")
        if name != self.file_field and name not in self.text_fields:
            raise UploadError(422, f"{name}: unknown form field (fix: the form fields are {expected}; "
                                   "check the spelling)")
        if name == self.file_field:
            if self.result.path is not None:
                raise UploadError(422, f"{self.file_field}: more than one file part "
                                       "(fix: send one survey per request)")
            self.result.filename = clean_filename(params.get(b"filename", b"")) or None
            self.result.path = self.dest
            self._fh = open(self.dest, "wb")
        else:
            if name in self.result.fields:
                raise UploadError(422, f"{name}: form field given more than once (fix: send it once)")
            self._text = bytearray()

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        chunk = data[start:end]
        if self._fh is not None:
            self.result.size += len(chunk)
            if self.result.size > self.max_bytes:
                raise UploadError(413, f"{self.file_field} '{self.result.display_name}': upload is larger "
                                       f"than the limit of {self.max_bytes} bytes (SHSAS_MAX_UPLOAD_BYTES) "
                                       "(fix: upload a smaller survey, or ask the operator to raise "
                                       "the limit)")
            self._hash.update(chunk)
            self._fh.write(chunk)
        elif self._text is not None:
            self._text += chunk
            if len(self._text) > MAX_TEXT_FIELD:
                raise UploadError(413, f"{self._name}: form field larger than {MAX_TEXT_FIELD} bytes "
                                       "(fix: a spec is a small JSON object; drop unneeded keys)")

    def _part_end(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
            self.result.sha256 = self._hash.hexdigest()
        elif self._text is not None and self._name:
            try:
                self.result.fields[self._name] = self._text.decode("utf-8")
            except UnicodeDecodeError:
                raise UploadError(400, f"{self._name}: form field is not UTF-8 text "
                                       "(fix: send the spec as UTF-8 JSON)") from None
            self._text = None

    def _end(self) -> None:
        self.ended = True

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


async def receive_upload(request: Request, dest: Path, max_bytes: int, file_field: str = "survey",
                         text_fields: tuple[str, ...] = ("spec",)) -> Upload:
    """Parse a multipart/form-data body, writing part ``file_field`` to ``dest``.

    Only ``file_field`` and ``text_fields`` are accepted, as form fields; a part with any other
    name, or any query parameter, is refused: a misspelt field must not silently fall back to
    a default (a default spec is a long job nobody asked for).

    Raises:
        UploadError: 415 not multipart, 413 over ``max_bytes``, 400 malformed body, 422 an
            unknown or repeated field. The partial file is deleted before raising.
    """
    expected = expected_fields(file_field, text_fields)
    ctype, params = parse_options_header(request.headers.get("content-type"))
    if ctype != b"multipart/form-data" or not params.get(b"boundary"):
        raise UploadError(415, "request body must be multipart/form-data with a 'survey' file part and "
                               "an optional 'spec' JSON part (fix: curl -F survey=@scan.h5 "
                               "-F 'spec={...}')")
    boundary = params[b"boundary"]
    if len(boundary) > MAX_BOUNDARY:
        await _drain(request.stream())
        raise UploadError(400, f"Content-Type: the multipart boundary is {len(boundary)} characters, "
                               f"longer than {MAX_BOUNDARY} (fix: RFC 2046 allows at most 70; let the "
                               "HTTP client choose the boundary)")
    if request.query_params:
        names = ", ".join(clean_filename(k.encode())[:64] or "(empty name)"
                          for k in list(request.query_params)[:5])
        await _drain(request.stream())
        raise UploadError(422, f"{names}: query parameters are not read by this request (fix: send the "
                               f"form fields {expected} in the multipart body, e.g. "
                               "-F 'spec={...}')")
    clen = request.headers.get("content-length")
    if clen is not None and clen.isdigit() and len(clen) < 20 and int(clen) > max_bytes + DRAIN_LIMIT:
        raise UploadError(413, f"{file_field}: request of {clen} bytes is larger than the limit of "
                               f"{max_bytes} bytes (SHSAS_MAX_UPLOAD_BYTES) (fix: upload a smaller "
                               "survey, or ask the operator to raise the limit)")
    recv = _Receiver(dest, max_bytes, file_field, text_fields)
    stream = request.stream()
    try:
        parser = MultipartParser(boundary, recv.callbacks())
    except Exception as exc:  # python-multipart's own checks on the boundary
        await _drain(stream)
        raise UploadError(400, f"Content-Type: bad multipart boundary ({exc})") from None
    buf = bytearray()
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
    except UploadError:
        recv.close()
        dest.unlink(missing_ok=True)
        # Read (and drop) the rest so the client gets to read the answer instead of a reset
        # connection; a no-op when the body has been read to its end.
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
