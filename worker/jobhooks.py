"""RQ's success, failure and stopped callbacks of plan, study and point-cloud jobs: count the
end in the metrics and enqueue the job's webhooks. Quick and never raising: they run in the
work horse (or the sweep) right after the job, and must not fail or hold it."""

from __future__ import annotations

import logging
from datetime import UTC, datetime
from typing import Any

from redis import Redis

from worker import joblist, metrics, webhooks

log = logging.getLogger("vpp.worker")


def job_succeeded(job: Any, connection: Redis, result: Any) -> None:
    """on_success."""
    _ended(job, connection, "succeeded")


def job_failed(job: Any, connection: Redis, *exc_info: Any) -> None:
    """on_failure (also for a failure that RQ retries: each counts)."""
    _ended(job, connection, "failed")


def job_stopped(job: Any, connection: Redis) -> None:
    """on_stopped (canceled while running)."""
    _ended(job, connection, "canceled")


def _ended(job: Any, conn: Redis, status: str) -> None:
    try:
        listed = joblist.entry(conn, job.id)
        labels = {"kind": listed.kind if listed else "plan", "status": status}
        if status == "succeeded" and labels["kind"] == "plan":
            _plan_metrics(conn, job.id)
        if job.started_at is not None:
            started = job.started_at.replace(tzinfo=job.started_at.tzinfo or UTC)
            seconds = (datetime.now(UTC) - started).total_seconds()
            metrics.observe(conn, "job_duration_seconds", seconds, labels)
        metrics.inc(conn, "jobs_finished_total", labels)  # last: the end is counted in full
        webhooks.notify(conn, job.origin, job.id)
    except Exception:  # a callback that raises would fail the job that just succeeded
        log.exception("end-of-job bookkeeping of %s failed", job.id)


def _plan_metrics(conn: Redis, plan: str) -> None:
    from worker import artifacts as art
    from worker.settings import get_settings
    from worker.store import open_store

    settings = get_settings()
    store = open_store(settings.store_url, conn, settings.s3_endpoint_url)
    if store.exists(art.plan_key(plan)):
        metrics.plan_finished(conn, art.get_plan(store, plan))
