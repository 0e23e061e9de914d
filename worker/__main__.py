"""`python -m worker --url REDIS_URL [--burst]`: one RQ worker, numerical stack preloaded."""

from __future__ import annotations

import argparse
import itertools
import logging
import os
import time
from types import FrameType
from typing import Any

# Before numpy loads: one BLAS thread per process (a spinning helper thread slows forked horses).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import embreex.rtcore_scene  # noqa: E402,F401  (preloaded: each forked horse reuses them)
import highspy  # noqa: E402,F401
import numpy  # noqa: E402,F401
import scipy.sparse  # noqa: E402,F401
import trimesh  # noqa: E402,F401
from redis import Redis  # noqa: E402
from redis.exceptions import ConnectionError, TimeoutError  # noqa: E402
from rq import Queue, Worker  # noqa: E402
from rq.job import Job  # noqa: E402

import vpp_core.report.plots  # noqa: E402,F401  (matplotlib: each plan job draws plots)
import worker.jobs  # noqa: E402,F401
from worker import logs, scheduled, webhooks  # noqa: E402
from worker.jobs import connect  # noqa: E402
from worker.pool import follow_parent  # noqa: E402
from worker.settings import Settings, get_settings  # noqa: E402

RECONNECT_S = 1.0
"""Seconds between two pings of a Redis that went away, before the worker starts again."""
DEQUEUE_SLACK_S = 15
"""RQ blocks on an empty queue for worker_ttl - 15 s before it sweeps again."""
log = logging.getLogger("vpp.worker")


class VppWorker(Worker):
    """RQ's forking worker with a heartbeat of a third of `dead_worker_s`: a job whose worker died
    is seen as abandoned after `dead_worker_s`, not RQ's 90 s (`job_monitoring_interval` + 60)."""

    dead_worker_s = 30
    stopping = False
    """Whether a stop was asked for (SIGTERM, SIGINT): then an end of `work` is no error."""

    def request_stop(self, signum: int, frame: FrameType | None) -> None:
        """RQ's warm stop, which raises StopRequested from the signal handler when idle, and
        also the flag its loop checks: a signal that lands inside a library's `except
        Exception: pass` (redis-py has several) lost the exception, and the worker, idle,
        outlived its parent (seen once in the suite)."""
        self.stopping = True
        self._stop_requested = True
        super().request_stop(signum, frame)  # type: ignore[no-untyped-call]

    def run_maintenance_tasks(self) -> None:
        """RQ's sweep, then the due retries of webhook deliveries back onto their queue, here in
        the worker instead of RQ's forked scheduler: a SIGKILLed worker's scheduler process
        outlived it, holding the queues' scheduler locks, and a plan whose worker was killed no
        longer resumed from its stored chunks (tests/test_faults.py). Idle workers sweep every
        `sweep_s` (they block on the queues for that long at most)."""
        super().run_maintenance_tasks()  # type: ignore[no-untyped-call]
        moved = scheduled.enqueue_due(self.connection, self.queues)
        if moved:
            log.info("worker %s: %d due retries back on their queues", self.name, moved)

    def perform_job(self, job: Job, *args: Any) -> bool:
        """RQ's perform_job (in the work horse) with the job id on every line logged meanwhile."""
        token = logs.JOB_ID.set(job.id)
        try:
            return bool(super().perform_job(job, *args))
        finally:
            logs.JOB_ID.reset(token)

    def get_heartbeat_ttl(self, job: Job, working_time: float = 0.0) -> int:
        if job.timeout and job.timeout > 0 and working_time >= job.timeout:
            return super().get_heartbeat_ttl(job, working_time)  # RQ kills it at timeout + 60
        return self.dead_worker_s


def make_worker(conn: Redis, settings: Settings, name: str | None) -> VppWorker:
    """One worker on the webhooks queue (first: deliveries are short) and the plan queue,
    beating and sweeping as the settings say."""
    worker = VppWorker(
        [Queue(q, connection=conn) for q in (webhooks.queue_name(settings.queue), settings.queue)],
        connection=conn,
        name=name,
        maintenance_interval=settings.sweep_s,
        job_monitoring_interval=max(1, settings.dead_worker_s // 3),
        worker_ttl=settings.sweep_s + DEQUEUE_SLACK_S,  # an idle worker wakes every sweep_s
    )
    worker.dead_worker_s = settings.dead_worker_s
    return worker


def main(argv: list[str] | None = None) -> None:
    """Run one worker on the plan queue until stopped (or until empty with --burst)."""
    follow_parent()
    parser = argparse.ArgumentParser(prog="python -m worker")
    parser.add_argument("--url", help="Redis URL (default: VPP_REDIS_URL)")
    parser.add_argument("--name", help="worker name (default: RQ's)")
    parser.add_argument("--burst", action="store_true", help="exit when the queue is empty")
    args = parser.parse_args(argv)
    settings = get_settings()
    url = args.url or settings.redis_url
    if not url:
        parser.error("no Redis: pass --url or set VPP_REDIS_URL")
    logs.configure(settings.log_format)
    conn = connect(url)
    for attempt in itertools.count():
        # a worker that lost Redis quits (RQ); start another (new name: the old one may still be
        # registered) once Redis answers again, until stopped on request or done (--burst)
        name = args.name and (f"{args.name}.{attempt}" if attempt else args.name)
        worker = make_worker(conn, settings, name)
        try:
            worker.work(burst=args.burst, with_scheduler=False)
            if args.burst or worker.stopping:
                return
            log.warning("worker %s stopped on an error; starting again", worker.name)
        except (ConnectionError, TimeoutError) as exc:
            log.warning("worker %s lost Redis (%s); starting again when it answers", name, exc)
        wait_for_redis(conn)


def wait_for_redis(conn: Redis) -> None:
    """Return once Redis answers a PING."""
    while True:
        try:
            conn.ping()
            return
        except (ConnectionError, TimeoutError):
            time.sleep(RECONNECT_S)


if __name__ == "__main__":
    main()
