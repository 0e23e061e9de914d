"""What the routes do, without HTTP: upload a mesh, submit a plan, describe a job."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path, PurePath

from redis import Redis
from rq import Queue

from service.jobmodels import Delivery
from service.models import (
    JobOut,
    LabelsSummary,
    MeshSummary,
    PlanSubmit,
    RelatedPlan,
    RelatedPlans,
    StudySubmit,
)
from service.parsing import parse_upload
from vpp_core.errors import NotFoundError, RegionError, VppError
from vpp_core.mesh.part import Part
from vpp_core.plan.document import PlanRequest
from vpp_core.plan.pipeline import check_request
from vpp_core.plan.robotplan import check_request_reach
from vpp_core.report.scene import geometry_scene, plan_scene
from vpp_core.report.studies import check_study
from worker import artifacts as art
from worker import joblist, webhooks
from worker import queue as jobs
from worker.settings import Settings
from worker.store import Store
from worker.studies import cloud_job, study_job

CONTENT_ID = re.compile(r"^[0-9a-f]{64}$")
"""Mesh, plan and job ids are SHA-256 hex digests."""


def content_id(value: str, what: str) -> str:
    """`value` when it has the shape of a content id, else NotFoundError (never a store lookup)."""
    if not CONTENT_ID.match(value):
        raise NotFoundError(f"no {what} {value!r}: ids are 64 lowercase hex digits")
    return value


def upload_mesh(
    store: Store,
    settings: Settings,
    data: bytes | Path,
    filename: str | None,
    fmt: str | None,
    units: str,
    max_face_area_mm2: float | None = None,
    remesh_mm: float | None = None,
    labels: bytes | None = None,
) -> MeshSummary:
    """Check and store a mesh, given as bytes or (a big one, parsed in a child process) the
    path of a file (remeshed at `remesh_mm` and its faces split to `max_face_area_mm2`, each
    if given); the same geometry again gives the same id and stores nothing."""
    file_type = fmt or PurePath(filename or "").suffix.lstrip(".") or "stl"
    part = parse_upload(
        data,
        file_type,
        units,
        remesh_mm=remesh_mm,
        max_face_area_mm2=max_face_area_mm2,
        max_faces=settings.max_faces,
        labels=labels,
    )
    key = art.summary_key(part.id)
    if store.exists(key) and store.exists(art.mesh_key(part.id)):
        return _with_labels(store, MeshSummary.model_validate_json(store.get(key)), part)
    summary = MeshSummary(
        id=part.id,
        faces=part.n_faces,
        vertices=len(part.vertices),
        counted_faces=int(part.counted.sum()),
        area_mm2=part.area_mm2,
        bounds_mm=part.bounds.tolist(),
        units=units,
        warnings=list(part.warnings),
    )
    art.put_part(store, part)
    store.put(key, summary.model_dump_json().encode())
    return _with_labels(store, summary, part)


def _with_labels(store: Store, summary: MeshSummary, part: Part) -> MeshSummary:
    """The upload's summary with its face labels, stored under their own id (if any)."""
    if part.labels is None:
        return summary
    art.put_labels(store, part)
    return summary.model_copy(update={"labels": LabelsSummary(**art.labels_summary(part))})


def get_labels(store: Store, mesh_id: str, labels_id: str) -> LabelsSummary:
    """The summary of a label set of the mesh (NotFoundError when unknown or another mesh's)."""
    content_id(mesh_id, "mesh")
    found = LabelsSummary(**art.get_labels_summary(store, content_id(labels_id, "labels")))
    if found.mesh_id != mesh_id:
        raise NotFoundError(f"no labels {labels_id} for mesh {mesh_id}")
    return found


def check_regions(store: Store, mesh_id: str, request: PlanRequest) -> None:
    """RegionError now, before a job, where the request's regions cannot fit the mesh: face ids
    out of range, labels without (or not in) the label set `labels_id`, another mesh's labels."""
    labels = None
    if request.labels_id:
        try:
            labels = art.get_labels_summary(store, request.labels_id)
        except NotFoundError:
            raise RegionError(
                f"labels_id {request.labels_id}: no such labels; upload them with the mesh"
            ) from None
        if labels["mesh_id"] != mesh_id:
            raise RegionError(f"labels_id {request.labels_id} labels another mesh")
    if not request.regions:
        return
    faces = MeshSummary.model_validate_json(store.get(art.summary_key(mesh_id))).faces
    for r in request.regions:
        if r.faces and max(r.faces) >= faces:
            raise RegionError(
                f"region {r.name!r}: face id {max(r.faces)} out of range (the mesh has {faces} "
                f"faces, ids 0..{faces - 1})"
            )
        if r.label is not None and labels is None:
            raise RegionError(
                f"region {r.name!r} selects label {r.label!r} but the request names no labels: "
                "pass labels_id (POST /v1/meshes answers it for labels uploaded or in the file)"
            )
        if r.label is not None and labels is not None:
            known = {v["label"] for v in labels["values"]} | {v["name"] for v in labels["values"]}
            if r.label not in known:
                raise RegionError(f"region {r.name!r}: unknown label {r.label!r}")


def get_mesh(store: Store, mesh_id: str) -> MeshSummary:
    """The summary of an uploaded mesh (NotFoundError when unknown)."""
    return MeshSummary.model_validate_json(store.get(art.summary_key(content_id(mesh_id, "mesh"))))


def needs_job(conn: Redis, store: Store, job_id: str) -> bool:
    """False when job `job_id` is done (its result stored), queued or running: the request joins
    it and writes nothing. `jobs.state` reads the RQ record before the store, and a job stores
    its result before RQ marks it finished, so a job that ends meanwhile is seen done; reading
    the store first let a request that saw no result, then a finished job, enqueue it again."""
    try:
        return jobs.state(conn, store, job_id).status not in ("queued", "running", "succeeded")
    except NotFoundError:
        return True


def submit_plan(store: Store, queue: Queue, settings: Settings, body: PlanSubmit) -> str:
    """Check the request, store it and enqueue its job unless the plan exists; the plan id."""
    check_request(body, settings.limits())  # LimitError, ViewpointError now, before any copy
    request = PlanRequest.model_validate(body.model_dump(exclude={"mesh_id", "callback"}))
    if not store.exists(art.mesh_key(body.mesh_id)):
        raise VppError(f"mesh_id {body.mesh_id}: no such mesh; upload it with POST /v1/meshes")
    if request.setup is not None:  # its meshes exist; explicit viewpoints clear of fixtures
        cell = art.get_cell(store, request.setup)
        check_request(request, settings.limits(), cell)
        if request.setup.robot is not None or request.setup.turntable is not None:
            part = art.get_part(store, body.mesh_id)  # explicit viewpoints the arm can take
            check_request_reach(part, request, cell)
    check_regions(store, body.mesh_id, request)
    plan = art.plan_id(body.mesh_id, request)
    if needs_job(queue.connection, store, plan):
        if not store.exists(art.request_key(plan)):
            art.put_request(store, plan, body.mesh_id, request)
        jobs.submit(queue, settings, store, plan)
    return plan


def submit_study(store: Store, queue: Queue, settings: Settings, body: StudySubmit) -> str:
    """Check the study request, store it and enqueue its job unless done; the study id."""
    request = PlanRequest.model_validate(body.model_dump(include=set(PlanRequest.model_fields)))
    if not store.exists(art.mesh_key(body.mesh_id)):
        raise VppError(f"mesh_id {body.mesh_id}: no such mesh; upload it with POST /v1/meshes")
    check_regions(store, body.mesh_id, request)
    values = body.resolutions if body.kind == "resolution" else body.ratios
    check_study(body.kind, values, request, settings.limits())
    if request.setup is not None:  # its meshes exist; explicit viewpoints clear of fixtures
        cell = art.get_cell(store, request.setup)
        check_request(request, settings.limits(), cell)
        if request.setup.robot is not None or request.setup.turntable is not None:
            check_request_reach(art.get_part(store, body.mesh_id), request, cell)
    study = art.study_id(body.mesh_id, request, body.kind, values)
    if needs_job(queue.connection, store, study):
        if not store.exists(art.request_key(study)):
            art.put_study_request(store, study, body.mesh_id, request, body.kind, values)
        jobs.submit(queue, settings, store, study, study_job)
    return study


def submit_cloud(store: Store, queue: Queue, settings: Settings, plan: str) -> str:
    """Enqueue the point cloud of a finished plan unless done; the cloud (job) id."""
    if not store.exists(art.plan_key(content_id(plan, "plan"))):
        raise NotFoundError(f"no finished plan {plan!r}: its point cloud needs the plan first")
    cloud = art.cloud_id(plan)
    if needs_job(queue.connection, store, cloud):
        if not store.exists(art.request_key(cloud)):
            art.put_cloud_request(store, cloud, plan)
        jobs.submit(queue, settings, store, cloud, cloud_job)
    return cloud


def job_out(conn: Redis, store: Store, job_id: str) -> JobOut:
    """The job resource of a plan, study or point cloud job."""
    state = jobs.state(conn, store, content_id(job_id, "job"))
    out = JobOut.model_validate(asdict(state))
    listed = joblist.entry(conn, job_id)
    out.kind = listed.kind if listed else None  # type: ignore[assignment]
    out.created_at = out.created_at or (listed.created_at if listed else None)
    out.deliveries = [Delivery.model_validate(a) for a in webhooks.attempts(conn, job_id)]
    if state.status == "succeeded":
        out.result_url = result_url(store, job_id)
    return out


def result_url(store: Store, job_id: str) -> str:
    """Where the finished job's result is served."""
    if store.exists(art.study_key(job_id)):
        return f"/v1/studies/{job_id}"
    if store.exists(art.cloud_key(job_id)):
        return f"/v1/plans/{art.get_cloud_plan(store, job_id)}/point-cloud"
    return f"/v1/plans/{job_id}"


def stored(store: Store, key: str, what: str) -> bytes:
    """A stored result (NotFoundError naming `what` while it is not computed)."""
    try:
        return store.get(key)
    except NotFoundError:
        raise NotFoundError(f"no {what} (not computed, or still running)") from None


PLAN_PLOTS = ("histogram.png", "cameras.png", "regions.png")
"""The plots a plan job stores (regions.png only for a plan with regions)."""


def plot_name(name: str, names: Sequence[str]) -> str:
    """`name` if it is one of `names`, else NotFoundError listing them (never a store lookup)."""
    if name not in names:
        raise NotFoundError(f"no plot {name!r}; there are: {', '.join(names)}")
    return name


def study_plot_names(store: Store, study: str) -> list[str]:
    """The names of a finished study's plots."""
    key = art.plot_key(f"studies/{content_id(study, 'study')}", "plots.json")
    return list(json.loads(stored(store, key, f"study {study}")))


def cancel_job(conn: Redis, store: Store, plan: str) -> JobOut:
    """Cancel the job of plan `plan`; its resource afterwards."""
    jobs.cancel(conn, store, content_id(plan, "job"))
    return job_out(conn, store, plan)


def plan_json(store: Store, plan: str) -> bytes:
    """The stored plan document (NotFoundError while it is not computed)."""
    return store.get(art.plan_key(content_id(plan, "plan")))


def mesh_geometry(store: Store, mesh_id: str) -> bytes:
    """The packed geometry of an uploaded mesh, for the viewer (vpp_core.report.scene)."""
    return geometry_scene(art.get_part(store, content_id(mesh_id, "mesh")))


def mesh_ply(store: Store, mesh_id: str) -> bytes:
    """The stored mesh as exact binary PLY (doubles; it loads back to the same id)."""
    return art.get_part(store, content_id(mesh_id, "mesh")).ply()


def scene_gz(store: Store, plan: str) -> bytes:
    """The gzipped packed per-face results of a finished plan; built from R when not stored."""
    key = art.scene_key(content_id(plan, "plan"))
    if store.exists(key):
        return store.get(key)
    doc = art.get_plan(store, plan)
    mesh_id, request = art.get_request(store, plan)
    counts = art.get_trace(store, art.plan_trace_id(mesh_id, request, doc)).counts
    cell = art.get_cell(store, request.setup)
    return art.put_scene(store, plan, plan_scene(art.get_part(store, mesh_id), doc, counts, cell))


def related_plans(store: Store, plan: str) -> RelatedPlans:
    """The same request under both formulations: ids, whether computed, and how to submit."""
    mesh_id, request = art.get_request(store, content_id(plan, "plan"))
    out = []
    for formulation in ("density", "visibility"):
        target = request.target.model_copy(update={"formulation": formulation})
        other = request.model_copy(update={"target": target})
        other_id = art.plan_id(mesh_id, other)
        submit = PlanSubmit.model_validate({**other.model_dump(), "mesh_id": mesh_id})
        out.append(
            RelatedPlan(
                formulation=formulation,
                id=other_id,
                available=store.exists(art.plan_key(other_id)),
                view_url=f"/v1/plans/{other_id}/view",
                request=submit,
            )
        )
    return RelatedPlans(plans=out)
