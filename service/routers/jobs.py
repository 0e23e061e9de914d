"""/v1/jobs: list jobs, poll one, follow it as Server-Sent Events, cancel it."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request, Response
from sse_starlette import EventSourceResponse

from service import events, listing, planning
from service.callers import caller
from service.deps import RedisDep, SettingsDep, StoreDep
from service.models import JobOut, Problem
from worker import webhooks

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
MAX_PAGE = 100
"""Most jobs on one page of the listing."""


@router.get("", response_model=listing.JobPage, responses={422: {"model": Problem}})
def list_jobs(
    request: Request,
    conn: RedisDep,
    store: StoreDep,
    status: Literal["queued", "running", "succeeded", "failed", "canceled"] | None = None,
    kind: Literal["plan", "study", "point-cloud"] | None = None,
    mesh_id: Annotated[str | None, Query(pattern=r"^[0-9a-f]{64}$")] = None,
    created_after: datetime | None = None,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = 20,
    cursor: Annotated[str | None, Query(max_length=200)] = None,
) -> listing.JobPage:
    """The caller's plan, study and point-cloud jobs (an admin key's or an open API's: all),
    newest first; pass `next_cursor` back as `cursor` for the next page."""
    filters = listing.Filters(status, kind, mesh_id, created_after)
    return listing.list_jobs(conn, store, caller(request), filters, limit, cursor)


@router.get("/{job_id}", response_model=JobOut, responses={404: {"model": Problem}})
def get_job(
    job_id: str, response: Response, conn: RedisDep, store: StoreDep, settings: SettingsDep
) -> JobOut:
    """Status, progress, error or result link of a plan job; Retry-After while it runs."""
    job = planning.job_out(conn, store, job_id)
    if job.status in ("queued", "running"):
        response.headers["Retry-After"] = str(settings.retry_after_s)
    return job


@router.get(
    "/{job_id}/events",
    response_class=EventSourceResponse,
    responses={
        200: {"content": {"text/event-stream": {}}, "description": events.DESCRIPTION},
        404: {"model": Problem},
    },
)
def job_events(job_id: str, request: Request, conn: RedisDep, store: StoreDep) -> Response:
    """The job as Server-Sent Events: `status` and `progress` on every change, then `done`
    (data: the job) at its end; reconnecting with `Last-Event-ID` skips what was seen."""
    first = planning.job_out(conn, store, job_id)  # 404 now, not inside the stream
    last_id = request.headers.get("last-event-id")
    return EventSourceResponse(events.stream(request, first, last_id), ping=events.PING_S)


@router.delete("/{job_id}", response_model=JobOut, responses={404: {"model": Problem}})
def cancel_job(job_id: str, conn: RedisDep, store: StoreDep, settings: SettingsDep) -> JobOut:
    """Cancel a queued or running job (a finished one is left as it is)."""
    job = planning.cancel_job(conn, store, job_id)
    if job.status == "canceled":
        webhooks.notify(conn, settings.queue, job_id)
    return job
