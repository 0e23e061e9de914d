"""Due scheduled jobs back onto their queues, moved by each worker's sweep (no scheduler process).

RQ puts a job retried after an interval (`Retry(interval=...)`: webhook deliveries, worker.webhooks)
in its queue's ScheduledJobRegistry, a sorted set scored by the Unix second it is due. RQ's own
scheduler is a forked process per worker that outlived a SIGKILLed worker and held the queues'
scheduler locks (a killed plan then no longer resumed, tests/test_faults.py), so the workers run
without it and `enqueue_due` does its work at every sweep (`sweep_s`). Each due job is claimed with
ZREM before it is enqueued: of the workers that sweep at once, only the one whose ZREM removed it
enqueues it, so no lock is held and none is left behind by a killed worker.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable

from redis import Redis
from rq import Queue
from rq.exceptions import NoSuchJobError
from rq.job import Job
from rq.registry import ScheduledJobRegistry


def enqueue_due(conn: Redis, queues: Iterable[Queue], now_s: float | None = None) -> int:
    """Enqueue the jobs of `queues` that were due before `now_s` (Unix s; default now); how many
    this call moved. RQ stores the due time floored to the second, so a job is moved once that
    whole second has passed: never before its interval is over, at most a second after."""
    cutoff = math.floor(time.time() if now_s is None else now_s) - 1
    moved = 0
    for queue in queues:
        registry = ScheduledJobRegistry(queue=queue)  # type: ignore[no-untyped-call]
        due = registry.get_jobs_to_schedule(cutoff)
        for job_id in due:
            if not conn.zrem(registry.key, job_id):
                continue  # another worker's sweep took it
            try:
                job = Job.fetch(job_id, connection=conn, serializer=queue.serializer)
            except NoSuchJobError:
                continue  # expired meanwhile: nothing to run
            queue.enqueue_job(job, at_front=job.should_enqueue_at_front())
            moved += 1
    return moved
