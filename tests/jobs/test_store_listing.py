"""Listing and searching an owner's jobs (jobs/store/listing.py) and adding columns to a store
made by an older release (jobs/store/migrate.py), on real SQLite and PostgreSQL."""

from __future__ import annotations

import uuid

import pytest
import sqlalchemy as sa

from jobs.store import JobStore, jobs, make_engine

from .test_store import new_job, store  # noqa: F401 (the store fixture: SQLite and PostgreSQL)


def all_pages(store: JobStore, owner: str, limit: int, **kw) -> list:  # noqa: F811
    got, cursor, pages = [], None, 0
    while True:
        page, cursor = store.list_jobs(owner, cursor=cursor, limit=limit, **kw)
        got += page
        pages += 1
        assert pages < 100, "paging does not end"
        if cursor is None:
            return got


def test_active_order_running_then_queued_then_finished(store: JobStore) -> None:  # noqa: F811
    made = [new_job(store, client_name=f"scan{i}.h5")[0] for i in range(9)]
    assert store.claim(made[2].id, "w") and store.claim(made[7].id, "w")  # running: 2 and 7
    for j in (made[0], made[5]):
        assert store.claim(j.id, "w") and store.finish(j.id, "w", "succeeded")
    store.request_cancel(made[3].id, "alice")
    page = all_pages(store, "alice", limit=2, order="active")
    assert [j.id for j in page[:2]] == [made[7].id, made[2].id]  # running, newest first
    queued = [j for j in reversed(made) if j.id in {made[i].id for i in (1, 4, 6, 8)}]
    assert [j.id for j in page[2:6]] == [j.id for j in queued]
    assert {j.status for j in page[6:]} == {"succeeded", "cancelled"}
    assert sorted(j.id for j in page) == sorted(j.id for j in made)  # each once, none lost
    # the newest order is unchanged, and a cursor of one order is refused by the other
    newest = all_pages(store, "alice", limit=4)
    assert [j.id for j in newest] == [j.id for j in reversed(made)]
    _, active_cursor = store.list_jobs("alice", order="active", limit=2)
    with pytest.raises(ValueError):
        store.list_jobs("alice", cursor=active_cursor)


def test_text_search_and_several_statuses(store: JobStore) -> None:  # noqa: F811
    a, _ = new_job(store, client_name="Bunny_run.h5", label="harbour wall, pass 2")
    b, _ = new_job(store, client_name="sphere.h5")
    c, _ = new_job(store, client_name="100%_done.h5")
    new_job(store, owner="bob", client_name="bunny_of_bob.h5")
    assert [j.id for j in store.list_jobs("alice", text="bunny")[0]] == [a.id]  # any case, own jobs only
    assert [j.id for j in store.list_jobs("alice", text="HARBOUR")[0]] == [a.id]  # the label
    assert [j.id for j in store.list_jobs("alice", text=b.id[:6])[0]] == [b.id]  # the id's start
    assert [j.id for j in store.list_jobs("alice", text="100%")[0]] == [c.id]  # % is a character
    assert store.list_jobs("alice", text="_d")[0] == [c]  # and so is _
    assert store.get(a.id).client_name == "Bunny_run.h5" and store.get(a.id).label == "harbour wall, pass 2"
    assert store.claim(b.id, "w")
    both = store.list_jobs("alice", status=("queued", "running"))[0]
    assert {j.id for j in both} == {a.id, b.id, c.id}
    assert [j.id for j in store.list_jobs("alice", status="running")[0]] == [b.id]


@pytest.mark.parametrize("backend", ["sqlite", "postgres"])
def test_a_store_of_an_older_release_gets_the_new_columns(backend: str, tmp_path, request) -> None:
    """A job table made before ``client_name`` and ``label`` existed is migrated in place: old rows
    keep their data and read as having neither; new rows store both."""
    if backend == "sqlite":
        url, schema = f"sqlite:///{tmp_path / 'old.db'}", None
    else:
        url, base = request.getfixturevalue("pg_url").split("#")
        schema = f"{base}_{uuid.uuid4().hex[:6]}"
    old = sa.MetaData()
    sa.Table(jobs.name, old, *[c._copy() for c in jobs.columns if c.name not in ("client_name", "label")])
    engine = make_engine(url, schema)
    with engine.begin() as conn:
        old.create_all(conn)
        conn.execute(old.tables[jobs.name].insert().values(
            id="old1", owner="alice", spec="{}", input_digest="d", input_name="survey.h5", input_bytes=1,
            queue="cpu", status="succeeded", progress=1.0, attempts=1, cancel_requested=False,
            created_at=1.0, updated_at=1.0, artifacts="[]"))
    engine.dispose()
    s = JobStore(url, schema)
    try:
        was = s.get("old1")
        assert was is not None and was.status == "succeeded" and was.client_name is None and was.label is None
        job, _ = new_job(s, client_name="scan.h5", label="new")
        assert (s.get(job.id).client_name, s.get(job.id).label) == ("scan.h5", "new")
        JobStore(url, schema).dispose()  # a second start finds nothing left to add
    finally:
        s.dispose()
