"""What every job submission does around the job itself: check its callback URL and reserve
one of the caller's job slots (fair use) before anything is queued, then index the job under
its caller (the listing) and register the callback (webhooks), telling it at once when the job
has already ended."""

from __future__ import annotations

from collections.abc import Callable

from fastapi import Request

from service import fairuse
from service.callers import caller
from service.jobmodels import Callback
from vpp_core.errors import NotFoundError
from worker import joblist, metrics, webhooks
from worker import queue as jobs
from worker.settings import Settings


def submit(
    request: Request,
    kind: joblist.Kind,
    callback: Callback | None,
    enqueue: Callable[[], tuple[str, str | None]],
) -> str:
    """Submit a job of `kind`: `enqueue()` queues it and gives (job id, mesh id), within one of
    the caller's job slots (429 when none is free; freed again when `enqueue` raises)."""
    check_callback(request, callback)
    token = fairuse.reserve(request)
    try:
        job_id, mesh_id = enqueue()
    except BaseException:
        fairuse.release(request, token)
        raise
    fairuse.hold(request, token, job_id)
    register(request, job_id, kind, mesh_id, callback)
    return job_id


def check_callback(request: Request, callback: Callback | None) -> None:
    """VppError (422) for a callback URL that is not http(s) or points inside (SSRF)."""
    if callback is not None:
        settings: Settings = request.app.state.settings
        webhooks.check_url(str(callback.url), settings.callback_allow_private)


def register(
    request: Request,
    job_id: str,
    kind: joblist.Kind,
    mesh_id: str | None,
    callback: Callback | None,
) -> None:
    """Index the submitted job under its caller and register its callback."""
    state = request.app.state
    who = caller(request)
    joblist.record(state.redis, state.settings, job_id, kind, mesh_id, who.owner)
    metrics.inc(state.redis, "jobs_submitted_total", {"kind": kind})
    if callback is None:
        return
    webhooks.register(state.redis, state.settings, job_id, str(callback.url), callback.secret)
    try:  # ended before the callback was registered: nothing else will tell it
        ended = jobs.state(state.redis, state.store, job_id).status in webhooks.TERMINAL
    except NotFoundError:
        ended = False
    if ended:
        webhooks.notify(state.redis, state.settings.queue, job_id)
