"""A job's Server-Sent Events (sse-starlette): the job is read every POLL_S and each change is
sent, `status` when its status changes and `progress` when its progress does; `done`, with the
job as `GET /v1/jobs/{id}` gives it, ends the stream.

Event ids name the state they report (a hash of status and progress), so a client that
reconnects with `Last-Event-ID` is sent nothing until the job moves past what it saw; `done`
is always sent once the job has ended.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import AsyncIterator

from anyio import sleep, to_thread
from fastapi import Request
from sse_starlette import ServerSentEvent

from service import planning
from service.models import JobOut

POLL_S = 0.25
"""Seconds between two reads of the job while it runs."""
PING_S = 15
"""Seconds between keep-alive comments on a quiet stream."""
TERMINAL = ("succeeded", "failed", "canceled")
DESCRIPTION = (
    "text/event-stream: `status` (data: {id, status}), `progress` (data: {stage, done, total}),"
    " and a final `done` (data: the job)"
)


def state_id(job: JobOut) -> str:
    """The event id of a job state: 16 hex digits of the hash of its status and progress."""
    key = json.dumps([job.status, job.progress.model_dump()], sort_keys=True)
    return hashlib.sha256(key.encode()).hexdigest()[:16]


async def stream(
    request: Request, job: JobOut, last_id: str | None
) -> AsyncIterator[ServerSentEvent]:
    """The events of `job` until it ends (or the client goes)."""
    conn, store = request.app.state.redis, request.app.state.store
    seen = last_id
    status, progress = (job.status, job.progress) if last_id == state_id(job) else (None, None)
    while True:
        sid = state_id(job)
        if job.status in TERMINAL:
            yield ServerSentEvent(job.model_dump_json(), event="done", id=sid)
            return
        if sid != seen:
            if job.status != status:
                data = json.dumps({"id": job.id, "status": job.status})
                yield ServerSentEvent(data, event="status", id=sid)
            if job.progress != progress:
                yield ServerSentEvent(job.progress.model_dump_json(), event="progress", id=sid)
            seen, status, progress = sid, job.status, job.progress
        if await request.is_disconnected():
            return
        await sleep(POLL_S)
        job = await to_thread.run_sync(planning.job_out, conn, store, job.id)
