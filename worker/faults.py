"""What the jobs do about faults: worker deaths are retried, errors are not, and both are
reported in words.

A job whose worker died under it (work horse killed, e.g. by the OOM killer; worker process
killed; Redis lost mid-job) is put back on the queue by RQ up to `job_retries` times (`Retry`):
at once when only the horse died (its worker sees it), else by the sweep that finds the job's
heartbeat older than `dead_worker_s` (worker maintenance, plan jobs, the API's job polls). A
job that raises fails at once (`fail_fast`): bad input, a timeout or a full store would fail
again.
"""

from __future__ import annotations

from redis.exceptions import RedisError
from rq.job import Job

WORKER_DIED = ("Work-horse terminated unexpectedly", "AbandonedJobError")
"""What RQ records when a job's work horse or worker died under it."""


def fail_fast(job: Job, exc: BaseException) -> None:
    """No retry for a job that raised, unless it lost Redis: only worker deaths are retried."""
    if not isinstance(exc, RedisError):
        job.retries_left = 0  # RQ's handle_job_failure reads it from this very object


def failure_reason(job: Job) -> str:
    """The last line of a failed job's exception, or its status; worker deaths said so."""
    result = job.latest_result()
    text = (result.exc_string or "") if result else ""
    lines = [line for line in text.strip().splitlines() if line.strip()]
    reason = lines[-1] if lines else str(job.get_status(refresh=False))
    if any(mark in reason for mark in WORKER_DIED):
        return f"its worker died under it (killed, out of memory, or lost Redis): {reason}"
    return reason


def delete_job(job: Job, remove_from_queue: bool = True) -> None:
    """Delete a job's records. RQ 3.0's `Job.delete` raises ValueError when the job ran on a
    worker that died (the execution expired, its id is still listed): drop that list first."""
    job.connection.delete(job.execution_registry.key)
    job.delete(remove_from_queue=remove_from_queue)
