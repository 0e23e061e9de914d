"""`GET /v1/jobs`: the caller's jobs (every job for an admin key or an open API), newest
first, filtered, a page at a time (worker.joblist holds the index and the cursor)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

from pydantic import BaseModel
from redis import Redis

from service import planning
from service.callers import Caller
from service.models import JobOut
from vpp_core.errors import NotFoundError
from worker import joblist
from worker.store import Store


class JobPage(BaseModel):
    """A page of jobs, newest first; `next_cursor` fetches the next (null on the last)."""

    items: list[JobOut]
    next_cursor: str | None = None


@dataclass(frozen=True)
class Filters:
    """What the listing keeps: each given field must match."""

    status: str | None = None
    kind: str | None = None
    mesh_id: str | None = None
    created_after: datetime | None = None


def list_jobs(
    conn: Redis, store: Store, who: Caller, filters: Filters, limit: int, cursor: str | None
) -> JobPage:
    """One page of at most `limit` jobs past `cursor`, and the cursor of the next page."""
    after = joblist.Cursor.decode(cursor) if cursor else None
    owner = None if who.admin else who.owner
    created_after = filters.created_after
    if created_after is not None and created_after.tzinfo is None:
        created_after = created_after.replace(tzinfo=UTC)
    items: list[JobOut] = []
    last: joblist.Cursor | None = None
    more = False
    for job_id, score in joblist.scan(conn, owner, after, created_after):
        if len(items) == limit:
            more = True
            break
        job = _item(conn, store, job_id, filters)
        last = joblist.Cursor(score, job_id)
        if job is not None:
            items.append(job)
    return JobPage(items=items, next_cursor=last.encode() if more and last else None)


def _item(conn: Redis, store: Store, job_id: str, filters: Filters) -> JobOut | None:
    """The job as `GET /v1/jobs/{id}` gives it if it passes the filters (None if it expired)."""
    listed = joblist.entry(conn, job_id)
    if listed is None:
        return None
    if filters.kind and listed.kind != filters.kind:
        return None
    if filters.mesh_id and listed.mesh_id != filters.mesh_id:
        return None
    try:
        job = planning.job_out(conn, store, job_id)
    except NotFoundError:
        return None
    if filters.status and job.status != filters.status:
        return None
    return job
