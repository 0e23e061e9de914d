"""/v1/jobs: poll a plan job, cancel it."""

from __future__ import annotations

from fastapi import APIRouter, Response

from service import planning
from service.deps import RedisDep, SettingsDep, StoreDep
from service.models import JobOut, Problem

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])


@router.get("/{job_id}", response_model=JobOut, responses={404: {"model": Problem}})
def get_job(
    job_id: str, response: Response, conn: RedisDep, store: StoreDep, settings: SettingsDep
) -> JobOut:
    """Status, progress, error or result link of a plan job; Retry-After while it runs."""
    job = planning.job_out(conn, store, job_id)
    if job.status in ("queued", "running"):
        response.headers["Retry-After"] = str(settings.retry_after_s)
    return job


@router.delete("/{job_id}", response_model=JobOut, responses={404: {"model": Problem}})
def cancel_job(job_id: str, conn: RedisDep, store: StoreDep) -> JobOut:
    """Cancel a queued or running job (a finished one is left as it is)."""
    return planning.cancel_job(conn, store, job_id)
