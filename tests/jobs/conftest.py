"""The store tests run on SQLite and on the real PostgreSQL the service tests use."""

from tests.service.conftest import pg_url  # noqa: F401 (the fixture: a fresh schema per run)
