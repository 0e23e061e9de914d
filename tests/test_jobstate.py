"""worker.queue.state against a job that ends while its state is read (real Redis, real RQ)."""

from __future__ import annotations

from typing import Any

from rq import Queue
from rq.job import JobStatus
from rq.registry import StartedJobRegistry

from worker import artifacts as art
from worker import queue as jobs
from worker.store import MemoryStore


def test_a_plan_that_finishes_during_the_running_sweep_is_succeeded(
    redis_db: Any, monkeypatch: Any
) -> None:
    """Read as running, not yet in the store; it finishes (document stored, status finished)
    while the started registry is swept: the state is succeeded, not 'result missing'."""
    plan = "a" * 64
    store = MemoryStore()
    job = Queue("vpp-jobstate-test", connection=redis_db).enqueue(print, job_id=plan)
    job.set_status(JobStatus.STARTED)

    def finishes(self: StartedJobRegistry, *args: Any, **kwargs: Any) -> None:
        store.put(art.plan_key(plan), b"{}")
        job.set_status(JobStatus.FINISHED)

    monkeypatch.setattr(StartedJobRegistry, "cleanup", finishes)
    assert jobs.state(redis_db, store, plan).status == "succeeded"


def test_the_start_time_does_not_move_when_rq_finishes_the_job(
    redis_db: Any, monkeypatch: Any
) -> None:
    """RQ writes `started_at` when the work horse takes a job and again when it finalizes it;
    a state read after the document is stored but before RQ's finalizing gave the first time,
    a later read the second (test_service_jobs failed on it once). The start is the job
    body's own, recorded in its meta."""
    from datetime import timedelta

    from worker import jobs as bodies

    plan = "b" * 64
    store = MemoryStore()
    job = Queue("vpp-jobstate-test", connection=redis_db).enqueue(print, job_id=plan)
    with redis_db.pipeline() as pipe:
        job.prepare_for_execution("w", pipe)  # RQ: the horse takes it (started_at T1)
        pipe.execute()
    monkeypatch.setattr(bodies, "get_current_job", lambda: job)
    bodies.run_job(lambda ctx, _: store.put(art.plan_key(plan), b"{}") or {}, plan)
    before = jobs.state(redis_db, store, plan)
    job.started_at = job.started_at + timedelta(milliseconds=4)  # RQ: finalized (T2)
    job.set_status(JobStatus.FINISHED)
    job.save()
    after = jobs.state(redis_db, store, plan)
    assert before.status == after.status == "succeeded"
    assert before.started_at is not None and before.started_at == after.started_at
