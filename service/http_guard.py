"""Connection hygiene at the HTTP layer: what uvicorn does not bound by itself.

uvicorn closes idle keep-alive connections (``timeout_keep_alive``) but has no deadline for a
request's head and no cap on the head's size or on connections, so a client trickling header
bytes (slowloris) or sending an endless header line holds a socket, a file descriptor and
memory for as long as it likes. :class:`GuardedHttpToolsProtocol` is uvicorn's httptools
protocol plus, per API process (``SHSAS_HTTP_*`` settings, :class:`jobs.settings.Settings`):

- a head deadline: a connection whose request line and headers are not complete within
  ``http_header_timeout_s`` of its first byte (or of its opening) is answered 408 and closed;
- a head size cap: past ``http_max_header_bytes`` the answer is 431 and the connection closes,
  before more of the head is buffered;
- a connection cap per process (``http_max_connections``) and per client address
  (``http_max_connections_per_client``): past them a new connection is answered 503 with
  ``Retry-After`` and closed at once, so it holds no descriptor.

These run before the ASGI app sees anything (an ASGI middleware is only called once the head
is complete), so they are a protocol class, given to uvicorn as ``http=``.
"""

from __future__ import annotations

import asyncio
import json
from collections import Counter
from functools import lru_cache

from uvicorn.protocols.http.httptools_impl import STATUS_LINE, HttpToolsProtocol

from jobs.settings import Settings, get_settings

from .deps import RETRY_AFTER_S

#: Open connections per client address in this process.
_per_client: Counter[str] = Counter()


@lru_cache(maxsize=1)
def _limits() -> Settings:
    # Read once per API process (uvicorn's worker processes each read the environment).
    return get_settings()


def _answer(status: int, detail: str, extra: bytes = b"") -> bytes:
    body = json.dumps({"detail": detail}).encode()
    return b"".join([STATUS_LINE[status], b"content-type: application/json\r\n",
                     b"content-length: ", str(len(body)).encode(), b"\r\n", extra,
                     b"connection: close\r\n\r\n", body])


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a head deadline, a head size cap and connection caps."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        limits = _limits()
        self._host = self.client[0] if self.client else ""
        self._counted = False
        self._head_timer: asyncio.TimerHandle | None = None
        self._in_head = True
        self._head_bytes = 0
        if len(self.connections) > limits.http_max_connections:
            self._refuse("this API process is at its connection limit (SHSAS_HTTP_MAX_CONNECTIONS)")
            return
        if _per_client[self._host] >= limits.http_max_connections_per_client:
            self._refuse("too many open connections from this address "
                         "(SHSAS_HTTP_MAX_CONNECTIONS_PER_CLIENT)")
            return
        _per_client[self._host] += 1
        self._counted = True
        self._arm_head_timer()

    def _refuse(self, detail: str) -> None:
        self.transport.write(_answer(503, f"{detail}; retry later",
                                     f"retry-after: {RETRY_AFTER_S}\r\n".encode()))
        self.transport.close()

    def _arm_head_timer(self) -> None:
        self._cancel_head_timer()
        self._head_timer = self.loop.call_later(_limits().http_header_timeout_s, self._head_too_slow)

    def _cancel_head_timer(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_too_slow(self) -> None:
        self._head_timer = None
        if self._in_head and not self.transport.is_closing():
            self.transport.write(_answer(408, "the request's headers did not arrive in time "
                                              "(SHSAS_HTTP_HEADER_TIMEOUT_S)"))
            self.transport.close()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        if self._counted:
            self._counted = False
            _per_client[self._host] -= 1
            if _per_client[self._host] <= 0:
                del _per_client[self._host]
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.transport.is_closing():
            return
        super().data_received(data)
        if self._in_head and not self.transport.is_closing():
            self._head_bytes += len(data)
            if self._head_bytes > _limits().http_max_header_bytes:
                self._in_head = False
                self._cancel_head_timer()
                self.transport.write(_answer(431, "request line and headers over "
                                             f"{_limits().http_max_header_bytes} bytes "
                                             "(SHSAS_HTTP_MAX_HEADER_BYTES)"))
                self.transport.close()

    # Parser callbacks: a request's head runs from its first byte to the end of its headers.
    def on_message_begin(self) -> None:
        super().on_message_begin()
        if not self._in_head:  # the next request on a kept-alive connection
            self._in_head = True
            self._head_bytes = 0
            self._arm_head_timer()

    def on_headers_complete(self) -> None:
        self._in_head = False
        self._head_bytes = 0
        self._cancel_head_timer()
        super().on_headers_complete()


def raise_fd_limit(settings: Settings) -> int:
    """Raise this process's open-file limit (soft, up to the hard one) so that the connection cap,
    not the descriptor limit, is what a flood of connections meets first. Returns the soft limit."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    # every connection is one descriptor; the job store, logs, uploads and libraries need more
    want = settings.http_max_connections + 256
    if soft != resource.RLIM_INFINITY and soft < want:
        new = want if hard == resource.RLIM_INFINITY else min(want, hard)
        if new > soft:
            resource.setrlimit(resource.RLIMIT_NOFILE, (new, hard))
            soft = new
    return soft
