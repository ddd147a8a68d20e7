"""The store's connection: engine, tables, transactions; the concerns build on it."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Self

import sqlalchemy as sa
from sqlalchemy.engine import Connection

from .migrate import add_missing_columns
from .records import make_engine, metadata


class StoreBase:
    """The engine and one transaction helper; every concern of :class:`~jobs.store.JobStore` uses them."""

    def __init__(self, url: str, schema: str | None = None, *, create: bool = True):
        self.url = url
        self.engine = make_engine(url, schema)
        # A pooled connection must never be shared across fork (Celery's prefork pool):
        # the child drops the parent's pool without closing the parent's sockets.
        engine = self.engine
        os.register_at_fork(after_in_child=lambda: engine.dispose(close=False))
        if create:
            self._create_tables()

    def _create_tables(self) -> None:
        with self.engine.begin() as conn:
            if conn.dialect.name == "postgresql":
                # API replicas and workers start together: serialise CREATE TABLE IF NOT EXISTS.
                conn.execute(sa.text("SELECT pg_advisory_xact_lock(7274201)"))
            metadata.create_all(conn)
            add_missing_columns(conn, metadata)  # a store made by an older release

    @classmethod
    def from_settings(cls, settings) -> Self:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        return cls(settings.db_url, settings.database_schema)

    def dispose(self) -> None:
        self.engine.dispose()

    @contextmanager
    def _tx(self) -> Iterator[Connection]:
        with self.engine.begin() as conn:
            yield conn

    def ping(self) -> None:
        """Raise if the database cannot answer a trivial query."""
        with self.engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))
