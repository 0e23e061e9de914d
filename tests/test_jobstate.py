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
