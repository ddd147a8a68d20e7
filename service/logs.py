"""The structured access log: one ``shsas.access`` line per request.

Fields: ``method``, ``path`` (without the query string), ``status``, ``duration_ms``,
``key_id`` (the API key's id, ``local`` for keyless loopback clients, null when the request
was not authenticated) and ``client``. The key's secret is never logged: only the id that
:func:`service.auth.owner_of` resolved, or, for a key that was refused, the id part the
client claimed (``claimed_key_id``).

A plain ASGI middleware rather than Starlette's ``BaseHTTPMiddleware``, which would add a task
and a memory stream to every request; this one only wraps ``send``.
"""

from __future__ import annotations

import logging
import time

access_log = logging.getLogger("shsas.access")

#: Where :func:`service.auth.owner_of` leaves what it found, in the request's ``scope["state"]``.
KEY_ID = "key_id"
CLAIMED_KEY_ID = "claimed_key_id"


class AccessLogMiddleware:
    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        status = 500  # what the client sees if the app raises before it answers

        async def send_status(message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            if access_log.isEnabledFor(logging.INFO):
                state = scope.get("state") or {}
                client = scope.get("client")
                extra = {"method": scope["method"], "path": scope["path"], "status": status,
                         "duration_ms": round((time.perf_counter() - t0) * 1000, 2),
                         "key_id": state.get(KEY_ID), "client": client[0] if client else None}
                if state.get(CLAIMED_KEY_ID):
                    extra["claimed_key_id"] = state[CLAIMED_KEY_ID]
                access_log.info("%s %s %d", scope["method"], scope["path"], status, extra=extra)
