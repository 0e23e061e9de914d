"""The plan jobs as the service sees them: submit once, read a stable state, cancel.

RQ's eleven job statuses map to five (queued, running, succeeded, failed, canceled); a plan
whose document is in the store has succeeded whatever Redis remembers, since Redis is the
queue and the store the record.

Faults: jobs are enqueued with `Retry(max=job_retries)` (see worker.faults: only worker deaths
are retried). Polling a running job sweeps its queue for abandoned jobs, so a job whose worker
died is reported (queued again, or failed with the reason) within `dead_worker_s` even when no
worker is left to sweep. A job Redis no longer knows (a Redis restart without persistence)
whose request is in the store is reported failed as lost: submitting it again resumes it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal

from redis import Redis
from rq import Callback, Queue, Retry
from rq.command import send_stop_job_command
from rq.exceptions import InvalidJobOperation, NoSuchJobError
from rq.job import Job, JobStatus
from rq.registry import StartedJobRegistry

from vpp_core.errors import NotFoundError
from worker import artifacts as art
from worker import jobhooks
from worker.faults import delete_job, failure_reason
from worker.jobs import STARTED_META, error_record, plan_job
from worker.settings import Settings
from worker.store import Store

Status = Literal["queued", "running", "succeeded", "failed", "canceled"]
STATUS: dict[JobStatus, Status] = {
    JobStatus.CREATED: "queued",
    JobStatus.QUEUED: "queued",
    JobStatus.DEFERRED: "queued",
    JobStatus.SCHEDULED: "queued",
    JobStatus.READY_TO_ENQUEUE: "queued",
    JobStatus.RATE_LIMITED: "queued",
    JobStatus.STARTED: "running",
    JobStatus.FINISHED: "succeeded",
    JobStatus.FAILED: "failed",
    JobStatus.STOPPED: "canceled",
    JobStatus.CANCELED: "canceled",
}
SUBMIT_LOCK_MS = 5_000
"""How long one submission may hold the per-plan submit lock."""
PROGRESS_KEYS = ("stage", "done", "total")
"""The job meta fields that make up `progress`."""
CANCEL_WAIT_S = 3.0
"""How long DELETE waits for a running job to stop before it answers."""
LOST = {
    "type": "JobLost",
    "title": "Job lost",
    "detail": "the job queue (Redis) no longer knows this job, which was accepted and has not "
    "finished: Redis restarted without its data, or the job's record expired. Submit the same "
    "request again: it resumes from what the store holds (ray-tracing chunks, R).",
}
"""The error of an accepted job that Redis forgot."""


@dataclass
class JobState:
    """What a client sees of a plan job."""

    id: str
    status: Status
    progress: dict[str, Any] = field(default_factory=dict)
    error: dict[str, str] | None = None
    chunks: list[dict[str, Any]] = field(default_factory=list)
    created_at: datetime | None = None
    started_at: datetime | None = None
    ended_at: datetime | None = None


def make_queue(conn: Redis, settings: Settings) -> Queue:
    """The queue the API fills and the workers take from."""
    return Queue(settings.queue, connection=conn)


def submit(
    queue: Queue,
    settings: Settings,
    store: Store,
    plan: str,
    func: Callable[[str], Any] = plan_job,
) -> None:
    """Enqueue `func(plan)` as job `plan` (a plan, study or point cloud id) unless it is queued
    or running (then the caller joins it) or its result is stored (it finished meanwhile)."""
    conn = queue.connection
    lock = f"vpp:submit-lock:{plan}"
    while not conn.set(lock, "1", nx=True, px=SUBMIT_LOCK_MS):
        time.sleep(0.01)
    try:
        job = _fetch(conn, plan)  # before the store: a job stores its result, then finishes
        if job is not None and _status(job) in ("queued", "running"):
            return
        if any(store.exists(key) for key in art.done_keys(plan)):
            return
        if job is not None:
            delete_job(job)
        queue.enqueue_call(
            func,
            args=(plan,),
            job_id=plan,
            timeout=settings.plan_timeout_s,
            result_ttl=settings.result_ttl_s,
            failure_ttl=settings.failure_ttl_s,
            description=f"{func.__name__.removesuffix('_job')} {plan[:12]}",
            retry=Retry(max=settings.job_retries) if settings.job_retries else None,
            on_success=Callback(jobhooks.job_succeeded),  # metrics, webhooks: nothing more
            on_failure=Callback(jobhooks.job_failed),
            on_stopped=Callback(jobhooks.job_stopped),
        )
    finally:
        conn.delete(lock)


def state(conn: Redis, store: Store, plan: str) -> JobState:
    """The job state of `plan`; NotFoundError when neither Redis nor the store knows it."""
    job = _fetch(conn, plan)
    # the status is read before the store: a job that ends in between is then found done
    status = _status(job) if job is not None else None
    if any(store.exists(key) for key in art.done_keys(plan)):
        return _from_job(plan, "succeeded", {"stage": "done"}, job)
    if job is not None and status == "running":  # its worker may have died: sweep, look again
        StartedJobRegistry(job.origin, connection=conn).cleanup()
        status = _status(job)
    if job is None or status is None:
        if store.exists(art.request_key(plan)):
            return JobState(id=plan, status="failed", error=LOST)
        raise NotFoundError(f"no job {plan!r}")
    meta = job.meta
    progress: dict[str, Any] = {k: meta[k] for k in PROGRESS_KEYS if k in meta} or {"stage": status}
    result = _from_job(plan, status, progress, job)
    if status == "failed":
        result.error = meta.get("error") or _worker_error(job)
    elif status == "succeeded":  # finished since the look in the store (the re-read above)?
        if any(store.exists(key) for key in art.done_keys(plan)):
            return _from_job(plan, "succeeded", {"stage": "done"}, job)
        result.status = "failed"  # finished, yet the document is gone from the store
        result.error = error_record(NotFoundError("the job's result is missing from the store"))
    return result


def cancel(conn: Redis, store: Store, plan: str) -> JobState:
    """Cancel the plan job and its queued or running chunks; the state after it. The chunks
    are stopped once the plan has: a chunk canceled under the plan's live horse fails the plan
    instead ('ray-tracing chunk 4 failed: JobStatus.CANCELED'), and the worker whose horse the
    plan's stop killed takes the next job off the queue at once (with the chunks swept while
    the horse died, a chunk the sweep had not reached yet; a CI replica, session 56)."""
    job = _fetch(conn, plan)
    if job is None or _status(job) not in ("queued", "running"):
        return state(conn, store, plan)
    _stop(conn, job)
    deadline = time.monotonic() + CANCEL_WAIT_S
    while _status(job) == "running" and time.monotonic() < deadline:
        time.sleep(0.02)
    for rec in job.get_meta().get("chunks", []):  # read again: all the stopped plan enqueued
        chunk = _fetch(conn, rec["job"]) if rec.get("job") else None
        if chunk is not None:
            _stop(conn, chunk)
    return state(conn, store, plan)


def _stop(conn: Redis, job: Job) -> None:
    """Kill a running job's work horse, or take a queued job off the queue."""
    try:
        status = _status(job)
        if status == "running":
            send_stop_job_command(conn, job.id)
        elif status == "queued":
            job.cancel()
    except InvalidJobOperation:  # it just started or ended: look again
        if _status(job) == "running":
            send_stop_job_command(conn, job.id)


def _status(job: Job) -> Status | None:
    """The job's status in our terms; None when its record is gone (expired, deleted)."""
    try:
        return STATUS[job.get_status()]
    except (InvalidJobOperation, NoSuchJobError):
        return None


def _from_job(plan: str, status: Status, progress: dict[str, Any], job: Job | None) -> JobState:
    """The state of `plan` with the chunk records and times of its RQ job, if Redis has it."""
    if job is None:
        return JobState(id=plan, status=status, progress=progress)
    return JobState(
        id=plan,
        status=status,
        progress=progress,
        chunks=list(job.meta.get("chunks", [])),
        created_at=job.created_at,
        started_at=_started(job),
        ended_at=job.ended_at,
    )


def _started(job: Job) -> datetime | None:
    """When the job's body started (its meta, written once per run), else RQ's own time."""
    started = job.meta.get(STARTED_META)
    return datetime.fromisoformat(started) if started else job.started_at


def _worker_error(job: Job) -> dict[str, str]:
    """The reason RQ recorded (timeout, killed work horse, ...)."""
    return {"type": "JobFailed", "title": "Job failed", "detail": failure_reason(job)}


def _fetch(conn: Redis, job_id: str) -> Job | None:
    try:
        return Job.fetch(job_id, connection=conn)
    except NoSuchJobError:
        return None
