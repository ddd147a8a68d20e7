"""API-key authentication: every job belongs to the key that submitted it.

Keys are sent as ``Authorization: Bearer shsas_<id>_<secret>`` (or ``X-API-Key``) and stored
only as a hash (``shsas keys create|list|revoke``). While no key is active the service runs
as the embedded single-user default and answers loopback clients only, as owner ``local``.
"""

from __future__ import annotations

import ipaddress
import time

from fastapi import HTTPException, Request

from jobs.store import KEY_PREFIX, LOCAL_OWNER, JobStore


def _token(request: Request) -> str | None:
    auth = request.headers.get("authorization")
    if auth:
        scheme, _, value = auth.partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    key = request.headers.get("x-api-key")
    return key.strip() if key else None


def is_loopback(host: str | None) -> bool:
    if not host:
        return False
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


#: How long a "keys are active" answer is remembered. Only that answer is cached: it can only
#: make the server stricter (a key is still required for a moment after the last one is revoked),
#: while "no keys" is re-read on every request so keyless loopback access ends the moment the
#: first key is created. A key's own validity (revocation) is checked on every request.
KEYS_CACHE_S = 1.0
_keys_cache: dict[int, tuple[float, bool]] = {}


def _has_active_keys(store: JobStore) -> bool:
    now = time.monotonic()
    hit = _keys_cache.get(id(store))
    if hit is not None and now - hit[0] < KEYS_CACHE_S:
        return hit[1]
    value = store.has_active_keys()
    if value:
        _keys_cache[id(store)] = (now, value)
    else:
        _keys_cache.pop(id(store), None)
    return value


def _claimed_id(token: str) -> str | None:
    """The key id part of a token (``shsas_<id>_<secret>``), for the access log: never the secret."""
    if not token.startswith(KEY_PREFIX):
        return None
    key_id = token[len(KEY_PREFIX):].partition("_")[0]
    return key_id[:32] if key_id.isalnum() else None


def owner_of(request: Request, store: JobStore) -> str:
    """The job owner for this request, or HTTPException 401. Leaves the key id for the access log."""
    owner = _owner_of(request, store)
    request.state.key_id = owner
    return owner


def _owner_of(request: Request, store: JobStore) -> str:
    token = _token(request)
    if token:
        owner = store.verify_key(token)
        if owner is None:
            request.state.claimed_key_id = _claimed_id(token)
            raise HTTPException(401, "invalid or revoked API key", headers={"WWW-Authenticate": "Bearer"})
        return owner
    if _has_active_keys(store):
        raise HTTPException(401, "API key required (Authorization: Bearer <key>)",
                            headers={"WWW-Authenticate": "Bearer"})
    if is_loopback(request.client.host if request.client else None):
        return LOCAL_OWNER
    raise HTTPException(401, "no API keys are configured, so only loopback clients are served; "
                             "create one with `shsas keys create NAME` and send it as a Bearer token",
                        headers={"WWW-Authenticate": "Bearer"})
