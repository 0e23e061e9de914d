"""Due retries are moved onto their queue by the workers' sweep (worker.scheduled), on a real
Redis: a job retried with an interval waits in RQ's scheduled registry until its second comes,
then one sweep enqueues it; two sweeps at once enqueue it once."""

from __future__ import annotations

import threading
from datetime import timedelta
from typing import Any

from rq import Queue, Retry
from rq.registry import ScheduledJobRegistry
from rq.utils import current_timestamp

from worker.scheduled import enqueue_due


def test_a_job_scheduled_for_later_is_enqueued_once_when_due(redis_db: Any) -> None:
    queue = Queue("vpp-test-scheduled", connection=redis_db)
    job = queue.enqueue_in(timedelta(seconds=60), print, "x")
    registry = ScheduledJobRegistry(queue=queue)
    assert job.id in registry.get_job_ids() and queue.count == 0
    now = current_timestamp()
    assert enqueue_due(redis_db, [queue], now + 59) == 0  # not due yet
    assert queue.count == 0
    # many sweeps at once, a minute later: exactly one of them moves it
    moved: list[int] = []
    sweeps = [
        threading.Thread(target=lambda: moved.append(enqueue_due(redis_db, [queue], now + 61)))
        for _ in range(8)
    ]
    for t in sweeps:
        t.start()
    for t in sweeps:
        t.join()
    assert sorted(moved) == [0] * 7 + [1]
    assert queue.get_job_ids() == [job.id] and registry.get_job_ids() == []
    assert job.get_status(refresh=True) == "queued"


def test_a_failed_job_with_retry_intervals_waits_for_its_interval(redis_db: Any) -> None:
    queue = Queue("vpp-test-scheduled", connection=redis_db)
    job = queue.enqueue(print, "x", retry=Retry(max=2, interval=[5, 10]))
    queue.pop_job_id()  # as if a worker took it, then it failed:
    with redis_db.pipeline() as pipe:
        job.retry(queue, pipe)
        pipe.execute()
    registry = ScheduledJobRegistry(queue=queue)
    due_at = registry.get_scheduled_time(job.id).timestamp()
    assert abs(due_at - (current_timestamp() + 5)) <= 1
    assert enqueue_due(redis_db, [queue]) == 0 and queue.count == 0
    assert enqueue_due(redis_db, [queue], due_at) == 0  # its second has not passed yet
    assert enqueue_due(redis_db, [queue], due_at + 1) == 1
    assert queue.get_job_ids() == [job.id]
