"""/v1/plans: submit a plan request (202 + job), fetch a finished plan document."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Response

from service import planning
from service.deps import QueueDep, SettingsDep, StoreDep
from service.models import JobAccepted, PlanSubmit, Problem
from vpp_core.document import PlanDocument

router = APIRouter(prefix="/v1/plans", tags=["plans"])
IMMUTABLE = "public, max-age=31536000, immutable"
"""Cache-Control of plan documents: a plan id names one document forever."""


@router.post(
    "",
    status_code=202,
    response_model=JobAccepted,
    responses={422: {"model": Problem}},
)
def submit_plan(
    body: PlanSubmit,
    response: Response,
    store: StoreDep,
    queue: QueueDep,
    settings: SettingsDep,
) -> JobAccepted:
    """Plan a mesh; identical requests share one job and one result (the plan id is their hash)."""
    plan = planning.submit_plan(store, queue, settings, body)
    job = planning.job_out(queue.connection, store, plan)
    response.headers["Location"] = f"/v1/jobs/{plan}"
    if job.status in ("queued", "running"):
        response.headers["Retry-After"] = str(settings.retry_after_s)
    return JobAccepted(id=plan, status=job.status)


@router.get(
    "/{plan_id}",
    response_model=PlanDocument,
    responses={304: {"description": "Not modified"}, 404: {"model": Problem}},
)
def get_plan(
    plan_id: str,
    store: StoreDep,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """The plan document (SPEC §8) once its job has succeeded; immutable."""
    etag = f'"{plan_id}"'
    headers = {"ETag": etag, "Cache-Control": IMMUTABLE}
    data = planning.plan_json(store, plan_id)
    if if_none_match and etag in [t.strip() for t in if_none_match.split(",")]:
        return Response(status_code=304, headers=headers)
    return Response(data, media_type="application/json", headers=headers)
