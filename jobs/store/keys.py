"""API keys: made, listed, revoked and verified; stored only as hashes."""

from __future__ import annotations

import hmac
import secrets
import time

import sqlalchemy as sa

from .base import StoreBase
from .records import (
    KEY_PREFIX,
    ApiKey,
    api_keys,
    hash_secret,
)


class ApiKeys(StoreBase):
    """The API-key table."""

    def create_key(self, name: str) -> tuple[ApiKey, str]:
        """Make a key; returns (record, token). The token is shown once and stored only hashed."""
        key_id = secrets.token_hex(6)
        secret = secrets.token_urlsafe(32)
        rec = ApiKey(id=key_id, name=name[:100], created_at=time.time(), revoked_at=None)
        with self._tx() as conn:
            conn.execute(api_keys.insert().values(id=rec.id, name=rec.name, created_at=rec.created_at,
                                                  secret_hash=hash_secret(secret)))
        return rec, f"{KEY_PREFIX}{key_id}_{secret}"

    def list_keys(self) -> list[ApiKey]:
        with self.engine.connect() as conn:
            rows = conn.execute(sa.select(api_keys.c.id, api_keys.c.name, api_keys.c.created_at,
                                          api_keys.c.revoked_at).order_by(api_keys.c.created_at))
            return [ApiKey(*r) for r in rows]

    def revoke_key(self, key_id: str) -> bool:
        with self._tx() as conn:
            res = conn.execute(api_keys.update().where(api_keys.c.id == key_id, api_keys.c.revoked_at.is_(None))
                               .values(revoked_at=time.time()))
        return res.rowcount == 1

    def has_active_keys(self) -> bool:
        with self.engine.connect() as conn:
            return conn.execute(sa.select(api_keys.c.id).where(api_keys.c.revoked_at.is_(None)).limit(1)).first() is not None

    def verify_key(self, token: str) -> str | None:
        """The key id (= job owner) for a valid, unrevoked token, else None."""
        if not token.startswith(KEY_PREFIX):
            return None
        key_id, _, secret = token[len(KEY_PREFIX):].partition("_")
        if not key_id or not secret:
            return None
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(api_keys.c.secret_hash).where(
                api_keys.c.id == key_id, api_keys.c.revoked_at.is_(None))).first()
        if row is None:
            return None
        return key_id if hmac.compare_digest(row[0], hash_secret(secret)) else None
