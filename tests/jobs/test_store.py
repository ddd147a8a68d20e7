"""The job store against real SQLite and PostgreSQL: leases, idempotency, paging, keys."""

from __future__ import annotations

import threading
import time
import uuid

import pytest

from jobs.store import IdempotencyConflict, JobStore


@pytest.fixture(params=["sqlite", "postgres"])
def store(request, tmp_path) -> JobStore:
    if request.param == "sqlite":
        s = JobStore(f"sqlite:///{tmp_path / 'jobs.db'}")
    else:
        pg = request.getfixturevalue("pg_url")
        url, schema = pg.split("#")
        s = JobStore(url, f"{schema}_{uuid.uuid4().hex[:6]}")
    yield s
    s.dispose()


def new_job(store: JobStore, owner: str = "alice", **kw):
    args = dict(owner=owner, spec={"methods": ["backprojection"]}, input_digest="d" * 64,
                input_name="survey.h5", input_bytes=10, queue="cpu")
    args.update(kw)
    return store.create_job(**args)


def test_claim_is_exclusive_under_concurrency(store: JobStore) -> None:
    job, _ = new_job(store)
    winners: list[str] = []

    def claim(name: str) -> None:
        if store.claim(job.id, name) is not None:
            winners.append(name)

    threads = [threading.Thread(target=claim, args=(f"w{i}",)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(winners) == 1
    got = store.get(job.id)
    assert got.status == "running" and got.attempts == 1 and got.lease_owner == winners[0]
    # Only the lease owner can report progress or finish.
    assert store.heartbeat(job.id, "intruder") == (False, False)
    assert not store.finish(job.id, "intruder", "succeeded")
    assert store.heartbeat(job.id, winners[0], progress=0.5, stage="fit") == (True, False)
    assert store.finish(job.id, winners[0], "succeeded", artifacts=["a.ply"], metrics={"m": {"x": 1.0}})
    done = store.get(job.id)
    assert done.status == "succeeded" and done.progress == 1.0 and done.artifacts == ["a.ply"]
    assert done.metrics == {"m": {"x": 1.0}} and done.lease_owner is None
    assert done.warnings == []  # a row finished without warnings (as every row before they existed)


def test_warnings_ride_with_the_metrics(store: JobStore) -> None:
    job, _ = new_job(store)
    assert store.claim(job.id, "w") is not None
    warn = {"method": "reed", "code": "box_filling", "message": "fills", "measure": 0.5, "limit": 0.4}
    assert store.finish(job.id, "w", "succeeded", metrics={"reed": {"points": 9.0}}, warnings=[warn])
    done = store.get(job.id)
    assert done.metrics == {"reed": {"points": 9.0}} and done.warnings == [warn]
    assert [j.warnings for j in store.list_jobs(job.owner)[0] if j.id == job.id] == [[warn]]


def test_the_device_rides_with_the_metrics(store: JobStore) -> None:
    job, _ = new_job(store)
    assert store.claim(job.id, "w") is not None
    assert store.get(job.id).device is None
    assert store.finish(job.id, "w", "succeeded", metrics={"reed": {"points": 9.0}}, device="cuda:0 (NVIDIA H100)")
    done = store.get(job.id)
    assert done.device == "cuda:0 (NVIDIA H100)" and done.metrics == {"reed": {"points": 9.0}}


def test_an_undefined_metric_is_null_end_to_end(store: JobStore) -> None:
    """None from the pipeline is JSON null in the table and None when read back (not NaN)."""
    job, _ = new_job(store)
    assert store.claim(job.id, "w") is not None
    assert store.finish(job.id, "w", "succeeded", metrics={"reed": {"pc_chamfer_l2": None, "points": 0.0}})
    assert store.get(job.id).metrics == {"reed": {"pc_chamfer_l2": None, "points": 0.0}}


def test_idempotency_same_body_same_job_different_body_conflict(store: JobStore) -> None:
    a, created_a = new_job(store, idempotency_key="k1", request_digest="r1")
    b, created_b = new_job(store, idempotency_key="k1", request_digest="r1")
    assert created_a and not created_b and a.id == b.id
    with pytest.raises(IdempotencyConflict):
        new_job(store, idempotency_key="k1", request_digest="r2")
    # Keys are per owner: another owner may reuse the same key string.
    c, created_c = new_job(store, owner="bob", idempotency_key="k1", request_digest="r2")
    assert created_c and c.id != a.id


def test_list_newest_first_with_cursor_and_status_filter(store: JobStore) -> None:
    ids = []
    for _ in range(7):
        ids.append(new_job(store)[0].id)
        time.sleep(0.002)
    new_job(store, owner="bob")
    seen, cursor = [], None
    while True:
        page, cursor = store.list_jobs("alice", cursor=cursor, limit=3)
        seen += [j.id for j in page]
        if cursor is None:
            break
    assert seen == ids[::-1]
    store.request_cancel(ids[0], "alice")
    cancelled, _ = store.list_jobs("alice", status="cancelled")
    assert [j.id for j in cancelled] == [ids[0]]
    assert store.request_cancel(ids[1], "bob") is None  # not bob's job
    assert store.get(ids[1]).status == "queued"


def test_reconciler_requeues_stale_then_fails_after_max_attempts(store: JobStore) -> None:
    job, _ = new_job(store)
    store.claim(job.id, "w1")
    assert store.requeue_stale(lease_timeout_s=60, max_attempts=2) == ([], [])  # fresh lease
    time.sleep(0.3)
    requeued, failed = store.requeue_stale(lease_timeout_s=0.2, max_attempts=2)
    assert [j.id for j in requeued] == [job.id] and failed == []
    assert store.get(job.id).status == "queued"
    assert store.claim(job.id, "w2").attempts == 2
    time.sleep(0.3)
    requeued, failed = store.requeue_stale(lease_timeout_s=0.2, max_attempts=2)
    assert requeued == [] and [j.id for j in failed] == [job.id]
    got = store.get(job.id)
    assert got.status == "failed" and "died 2 times" in got.error


def test_stale_queued_jobs_are_resent_by_one_reconciler_only(store: JobStore) -> None:
    first, _ = new_job(store)
    time.sleep(0.002)
    second, _ = new_job(store)
    running, _ = new_job(store)
    store.claim(running.id, "w1")
    assert store.queued_older_than(60) == []
    time.sleep(0.05)
    waiting = store.queued_older_than(0.01)
    assert [j.id for j in waiting] == [first.id, second.id]  # oldest first, queued only
    # Several reconcilers read the same rows; exactly one wins the right to re-send each.
    wins: list[str] = []
    threads = [threading.Thread(target=lambda j=j: store.mark_redispatched(j) and wins.append(j.id))
               for j in waiting for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(wins) == sorted([first.id, second.id])
    assert all(store.get(j.id).updated_at > j.updated_at for j in waiting)  # re-sent: its age starts again
    store.claim(first.id, "w2")
    assert not store.mark_redispatched(store.get(first.id))  # running now: nothing to re-send


def test_claim_next_takes_oldest_queued(store: JobStore) -> None:
    first, _ = new_job(store)
    time.sleep(0.002)
    second, _ = new_job(store)
    assert store.claim_next("w").id == first.id
    assert store.claim_next("w").id == second.id
    assert store.claim_next("w") is None


def test_api_keys_hashed_verify_revoke(store: JobStore) -> None:
    assert not store.has_active_keys()
    rec, token = store.create_key("alice")
    assert store.has_active_keys()
    assert store.verify_key(token) == rec.id
    assert store.verify_key(token[:-2] + "xx") is None
    assert store.verify_key("shsas_nope_secret") is None
    with store.engine.connect() as conn:
        stored = conn.exec_driver_sql("SELECT secret_hash FROM shsas_api_keys").scalar()
    assert token.split("_", 2)[2] not in stored  # only the hash is at rest
    assert store.revoke_key(rec.id) and not store.revoke_key(rec.id)
    assert store.verify_key(token) is None and not store.has_active_keys()


# ---- quota count, queue position and rate, deletion, retention ----------

def test_count_active_counts_queued_and_running_of_one_owner(store: JobStore) -> None:
    a1, _ = new_job(store, "alice")
    a2, _ = new_job(store, "alice")
    new_job(store, "bob")
    assert store.count_active("alice") == 2
    store.claim(a1.id, "w")
    assert store.count_active("alice") == 2  # running still counts
    store.finish(a1.id, "w", "succeeded", artifacts=[])
    store.request_cancel(a2.id, "alice")
    assert store.count_active("alice") == 0 and store.count_active("bob") == 1


def test_reserve_slot_is_atomic_counts_jobs_and_expires(store: JobStore) -> None:
    """Sixteen threads reserve at once against a limit of 3 with one queued job: exactly two win;
    a released slot is free again; a reservation older than the time to live is ignored."""
    new_job(store, "alice")
    won: list[str] = []
    barrier = threading.Barrier(16)

    def reserve() -> None:
        barrier.wait()
        rid, _ = store.reserve_slot("alice", 3, stale_after_s=600)
        if rid is not None:
            won.append(rid)

    threads = [threading.Thread(target=reserve) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(won) == 2
    assert store.reserve_slot("alice", 3, stale_after_s=600) == (None, 3)
    assert store.reserve_slot("bob", 1, stale_after_s=600)[0] is not None  # per owner
    store.release_slot(won[0])
    rid, in_use = store.reserve_slot("alice", 3, stale_after_s=600)
    assert rid is not None and in_use == 2
    time.sleep(0.05)
    rid, in_use = store.reserve_slot("alice", 3, stale_after_s=0.01)  # the others went stale
    assert rid is not None and in_use == 1


def test_queue_position_counts_every_owner_ahead_in_the_same_queue(store: JobStore) -> None:
    first, _ = new_job(store, "alice")
    new_job(store, "carol", queue="gpu")  # another queue: not ahead
    second, _ = new_job(store, "bob")
    third, _ = new_job(store, "alice")
    assert [store.queue_position(j) for j in (first, second, third)] == [0, 1, 2]
    store.claim(first.id, "w")  # left the queue
    assert store.queue_position(third) == 1


def test_queue_rate_is_the_mean_run_time_of_recent_jobs(store: JobStore) -> None:
    assert store.queue_rate("cpu") == (None, [])
    done = []
    for _ in range(2):
        job, _ = new_job(store)
        store.claim(job.id, "w")
        store.finish(job.id, "w", "succeeded", artifacts=[])
        done.append(store.get(job.id))
    running, _ = new_job(store)
    store.claim(running.id, "w")
    mean, busy = store.queue_rate("cpu")
    expected = sum(j.finished_at - j.started_at for j in done) / 2
    assert mean == pytest.approx(expected, abs=1e-6) and [j.id for j in busy] == [running.id]
    assert store.queue_rate("gpu") == (None, [])


def test_delete_is_owner_only_and_ends_the_lease(store: JobStore) -> None:
    job, _ = new_job(store, "alice")
    store.claim(job.id, "w")
    assert not store.delete(job.id, "bob") and store.exists(job.id)
    assert store.delete(job.id, "alice") and not store.exists(job.id)
    assert store.heartbeat(job.id, "w") == (False, False)  # the worker learns it lost the job
    assert not store.finish(job.id, "w", "succeeded", artifacts=[])


def test_finished_before_lists_only_finished_jobs_past_the_cutoff(store: JobStore) -> None:
    old, _ = new_job(store)
    store.claim(old.id, "w")
    store.finish(old.id, "w", "failed", error="x")
    cancelled, _ = new_job(store)
    store.request_cancel(cancelled.id, "alice")
    new_job(store)  # queued
    running, _ = new_job(store)
    store.claim(running.id, "w")
    cutoff = time.time() + 1
    assert [j.id for j in store.finished_before(cutoff)] == [old.id, cancelled.id]
    assert store.finished_before(time.time() - 3600) == []
