"""The job store: the relational table that is the source of truth for every job (docs/service.md).

SQLAlchemy 2 Core over SQLite (default, a file in the data dir) or PostgreSQL (psycopg 3).
Celery only delivers work; whoever holds a job's lease (``lease_owner`` + fresh
``heartbeat_at``) runs it, and every state change is a single conditional UPDATE so that two
workers, two API processes or two reconcilers can never both win the same transition.

One concern per module: ``records`` (tables, decoded rows, engine), ``base`` (connection),
``queries`` (the API's side), ``listing`` (pages of an owner's jobs), ``migrate`` (columns
added since a store was made), ``leases`` (the workers' side), ``keys`` (API keys);
:class:`JobStore` is all of them over one engine.
"""

from __future__ import annotations

from .keys import ApiKeys
from .leases import Leases
from .listing import ORDERS, JobListing
from .queries import JobQueries
from .records import (
    KEY_PREFIX,
    LOCAL_OWNER,
    STATUSES,
    TERMINAL,
    ApiKey,
    IdempotencyConflict,
    Job,
    decode_cursor,
    jobs,
    make_engine,
)

__all__ = ["KEY_PREFIX", "LOCAL_OWNER", "ORDERS", "STATUSES", "TERMINAL", "ApiKey", "IdempotencyConflict", "Job",
           "JobStore", "decode_cursor", "jobs", "make_engine"]


class JobStore(JobQueries, JobListing, Leases, ApiKeys):
    """All reads and writes of jobs and API keys."""
