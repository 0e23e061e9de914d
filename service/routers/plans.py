"""/v1/plans: submit a plan request (202 + job), fetch a finished plan document."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Header, Request, Response

from service import planning, submissions
from service.deps import QueueDep, SettingsDep, StoreDep
from service.jobmodels import CloudSubmit
from service.models import JobAccepted, PlanSubmit, Problem
from vpp_core.plan.document import PlanDocument
from vpp_core.report.export import Frame, Unit, poses_csv, poses_json
from vpp_core.report.pointcloud import CloudStats
from worker import artifacts as art

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
    request: Request,
    response: Response,
    store: StoreDep,
    queue: QueueDep,
    settings: SettingsDep,
) -> JobAccepted:
    """Plan a mesh; identical requests share one job and one result (the plan id is their hash)."""
    plan = submissions.submit(
        request,
        "plan",
        body.callback,
        lambda: (planning.submit_plan(store, queue, settings, body), body.mesh_id),
    )
    return accepted(plan, response, store, queue, settings)


def accepted(
    job_id: str, response: Response, store: StoreDep, queue: QueueDep, settings: SettingsDep
) -> JobAccepted:
    """The 202 body and headers of a submitted job: Location, Retry-After while it runs."""
    job = planning.job_out(queue.connection, store, job_id)
    response.headers["Location"] = f"/v1/jobs/{job_id}"
    if job.status in ("queued", "running"):
        response.headers["Retry-After"] = str(settings.retry_after_s)
    return JobAccepted(id=job_id, status=job.status)


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
    return named_forever(
        (plan_id, "plan"), if_none_match, lambda: planning.plan_json(store, plan_id)
    )


def named_forever(
    content: tuple[str, str],
    if_none_match: str | None,
    body: Callable[[], bytes],
    media_type: str = "application/json",
) -> Response:
    """An answer that the content id (id, what it names) names forever: its ETag, immutable
    caching, and 304 on a matching If-None-Match (then `body` is never read)."""
    etag = f'"{planning.content_id(*content)}"'
    headers = {"ETag": etag, "Cache-Control": IMMUTABLE}
    if if_none_match and etag in [t.strip() for t in if_none_match.split(",")]:
        return Response(status_code=304, headers=headers)
    return Response(body(), media_type=media_type, headers=headers)


PNG: dict[int | str, dict[str, Any]] = {
    200: {"content": {"image/png": {}}},
    404: {"model": Problem},
}


@router.get("/{plan_id}/plots/{name}", response_class=Response, responses=PNG)
def get_plan_plot(plan_id: str, name: str, store: StoreDep) -> Response:
    """A PNG plot of the plan: histogram.png (resolution per face), cameras.png (frusta) or,
    for a plan with regions, regions.png (resolution per face, a histogram per region)."""
    planning.content_id(plan_id, "plan")
    name = planning.plot_name(name, planning.PLAN_PLOTS)
    data = planning.stored(store, art.plot_key(f"plans/{plan_id}", name), f"plot {name}")
    return Response(data, media_type="image/png", headers={"Cache-Control": IMMUTABLE})


def _poses(
    plan_id: str, store: StoreDep, body: Callable[[PlanDocument], str], media: str
) -> Response:
    """The stored plan's poses written by `body` (404 while the plan is not computed)."""
    doc = PlanDocument.model_validate_json(planning.plan_json(store, plan_id))
    return Response(body(doc), media_type=media, headers={"Cache-Control": IMMUTABLE})


@router.get(
    "/{plan_id}/poses.csv",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}, 404: {"model": Problem}},
)
def get_poses_csv(
    plan_id: str, store: StoreDep, unit: Unit = "mm", frame: Frame = "cell"
) -> Response:
    """The poses in visiting order for the cell: CSV `index,x,y,z,qw,qx,qy,qz` in `unit`
    (quaternion of camera_to_world). Frame `cell`: setup.part_to_cell applied (without a
    setup: the part frame)."""
    return _poses(plan_id, store, lambda doc: poses_csv(doc, unit, frame), "text/csv")


@router.get(
    "/{plan_id}/poses.json",
    response_class=Response,
    responses={200: {"content": {"application/json": {}}}, 404: {"model": Problem}},
)
def get_poses_json(
    plan_id: str, store: StoreDep, unit: Unit = "mm", frame: Frame = "cell"
) -> Response:
    """The poses in visiting order as {position {x,y,z}, orientation {w,x,y,z}} in `unit`,
    with home and cycle time. Frame `cell`: setup.part_to_cell applied (without a setup: the
    part frame)."""
    return _poses(plan_id, store, lambda doc: poses_json(doc, unit, frame), "application/json")


@router.post(
    "/{plan_id}/point-cloud",
    status_code=202,
    response_model=JobAccepted,
    responses={404: {"model": Problem}},
)
def submit_point_cloud(
    plan_id: str,
    request: Request,
    response: Response,
    store: StoreDep,
    queue: QueueDep,
    settings: SettingsDep,
    body: CloudSubmit | None = None,
) -> JobAccepted:
    """Simulate the plan's point cloud (one point per valid ray of its viewpoints) as a job."""
    callback = body.callback if body else None

    def enqueue() -> tuple[str, str | None]:
        cloud = planning.submit_cloud(store, queue, settings, plan_id)
        return cloud, art.get_request(store, plan_id)[0]

    cloud = submissions.submit(request, "point-cloud", callback, enqueue)
    return accepted(cloud, response, store, queue, settings)


@router.get(
    "/{plan_id}/point-cloud",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}, 404: {"model": Problem}},
)
def get_point_cloud(plan_id: str, store: StoreDep) -> Response:
    """The point cloud as binary PLY: x, y, z (float32 mm), neighbours within r̄, view."""
    key = art.cloud_key(art.cloud_id(planning.content_id(plan_id, "plan")), "ply")
    data = planning.stored(store, key, f"point cloud of plan {plan_id}")
    headers = {
        "Cache-Control": IMMUTABLE,
        "Content-Disposition": 'attachment; filename="cloud.ply"',
    }
    return Response(data, media_type="application/octet-stream", headers=headers)


@router.get(
    "/{plan_id}/point-cloud/stats", response_model=CloudStats, responses={404: {"model": Problem}}
)
def get_point_cloud_stats(plan_id: str, store: StoreDep) -> Response:
    """Summary of the point cloud: points per view, neighbour counts, spacing."""
    key = art.cloud_key(art.cloud_id(planning.content_id(plan_id, "plan")))
    data = planning.stored(store, key, f"point cloud of plan {plan_id}")
    return Response(data, media_type="application/json", headers={"Cache-Control": IMMUTABLE})


@router.get("/{plan_id}/point-cloud/neighbours.png", response_class=Response, responses=PNG)
def get_point_cloud_plot(plan_id: str, store: StoreDep) -> Response:
    """Distribution of the neighbour counts within r̄ (PNG)."""
    owner = f"clouds/{art.cloud_id(planning.content_id(plan_id, 'plan'))}"
    data = planning.stored(store, art.plot_key(owner, "neighbours.png"), "point cloud plot")
    return Response(data, media_type="image/png", headers={"Cache-Control": IMMUTABLE})
