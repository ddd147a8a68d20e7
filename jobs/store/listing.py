"""Listing an owner's jobs a page at a time: filtered by status and by text, newest first or
with the active jobs (running, then queued) ahead of the finished ones.

Keyset paging: a cursor names the last row of a page by its sort key, so a page never skips or
repeats a row when jobs are added or finish between two requests of an operator's list (a
job that changes rank under the ``active`` order moves, as it should, but the rows that keep
their rank do not).
"""

from __future__ import annotations

import base64
from typing import Literal

import sqlalchemy as sa

from .base import StoreBase
from .records import Job, decode_cursor, encode_cursor, jobs

Order = Literal["newest", "active"]
ORDERS: tuple[Order, ...] = ("newest", "active")

#: Sort rank of each status under the ``active`` order: running first, then queued, then the rest.
_RANK = sa.case((jobs.c.status == "running", 0), (jobs.c.status == "queued", 1), else_=2)
_RANK_OF = {"running": 0, "queued": 1}
#: Marks an ``active``-order cursor (the ``newest`` cursor is the one the API always gave).
_ACTIVE_MARK = "a."


def _encode_active(rank: int, created_at: float, job_id: str) -> str:
    raw = base64.urlsafe_b64encode(f"{rank}|{created_at!r}|{job_id}".encode()).decode().rstrip("=")
    return _ACTIVE_MARK + raw


def _decode_active(cursor: str) -> tuple[int, float, str]:
    """Inverse of :func:`_encode_active`; ValueError on anything else."""
    if not cursor.startswith(_ACTIVE_MARK):
        raise ValueError("not a cursor of the active order")
    raw = cursor[len(_ACTIVE_MARK):]
    rank, created, job_id = base64.urlsafe_b64decode(raw + "=" * (-len(raw) % 4)).decode().split("|", 2)
    if rank not in ("0", "1", "2") or not job_id.isalnum() or len(job_id) > 32:
        raise ValueError("bad cursor")
    return int(rank), float(created), job_id


def _after(created: float, job_id: str) -> sa.ColumnElement[bool]:
    """Rows after (older than) the row (created, job_id) in newest-first order."""
    return sa.or_(jobs.c.created_at < created, sa.and_(jobs.c.created_at == created, jobs.c.id < job_id))


class JobListing(StoreBase):
    """The owner's jobs, one page at a time."""

    def list_jobs(self, owner: str, *, status: str | tuple[str, ...] | None = None, text: str | None = None,
                  order: Order = "newest", cursor: str | None = None, limit: int = 50) -> tuple[list[Job], str | None]:
        """One page of the owner's jobs; returns (page, next_cursor or None on the last page).

        ``status``: one status or several (any of them). ``text``: a case-insensitive part of the
        client's file name or the label, or the start of the job id. ``order``: ``newest``
        (created, newest first) or ``active`` (running, then queued, then finished; each newest
        first). ``cursor`` must come from the same order, else ValueError.
        """
        q = jobs.select().where(jobs.c.owner == owner)
        if status:
            q = q.where(jobs.c.status.in_((status,) if isinstance(status, str) else tuple(status)))
        if text and text.strip():
            t = text.strip().lower()
            q = q.where(sa.or_(sa.func.lower(jobs.c.client_name).contains(t, autoescape=True),
                               sa.func.lower(jobs.c.label).contains(t, autoescape=True),
                               jobs.c.id.startswith(t, autoescape=True)))
        if order == "active":
            if cursor:
                rank, created, jid = _decode_active(cursor)
                q = q.where(sa.or_(_RANK > rank, sa.and_(_RANK == rank, _after(created, jid))))
            q = q.order_by(_RANK, jobs.c.created_at.desc(), jobs.c.id.desc())
        else:
            if cursor:
                if cursor.startswith(_ACTIVE_MARK):
                    raise ValueError("a cursor of the active order")
                q = q.where(_after(*decode_cursor(cursor)))
            q = q.order_by(jobs.c.created_at.desc(), jobs.c.id.desc())
        with self.engine.connect() as conn:
            rows = [Job.from_row(r) for r in conn.execute(q.limit(limit + 1))]
        nxt = None
        if len(rows) > limit:
            last = rows[limit - 1]
            nxt = (_encode_active(_RANK_OF.get(last.status, 2), last.created_at, last.id) if order == "active"
                   else encode_cursor(last.created_at, last.id))
        return rows[:limit], nxt
