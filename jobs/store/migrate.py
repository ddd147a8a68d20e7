"""Bring a store made by an older release up to the present tables.

``create_all`` makes missing tables but never touches an existing one, so a column added to a
table later is added here with ``ALTER TABLE ... ADD COLUMN``. Only nullable columns without a
server default are added this way (old rows read as NULL); anything else needs a real
migration and is refused loudly rather than half-done.
"""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.engine import Connection


def add_missing_columns(conn: Connection, metadata: sa.MetaData) -> list[str]:
    """Add to each existing table of ``metadata`` the columns it lacks; returns ``table.column``
    of each one added. Runs inside the caller's transaction (PostgreSQL: under its advisory
    lock, so concurrent starts add a column once)."""
    inspector = sa.inspect(conn)
    added = []
    for table in metadata.sorted_tables:
        if not inspector.has_table(table.name):
            continue
        have = {c["name"] for c in inspector.get_columns(table.name)}
        for col in table.columns:
            if col.name in have:
                continue
            if not col.nullable or col.primary_key:
                raise RuntimeError(f"the job store's table {table.name} lacks column {col.name}, which "
                                   "cannot be added in place (not nullable); migrate it by hand")
            kind = col.type.compile(dialect=conn.dialect)
            prep = conn.dialect.identifier_preparer
            conn.execute(sa.text(f"ALTER TABLE {prep.quote(table.name)} ADD COLUMN {prep.quote(col.name)} {kind}"))
            added.append(f"{table.name}.{col.name}")
    return added
