"""Request and response bodies of the HTTP API (the plan document itself is vpp_core's)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.jobmodels import Callback, Delivery
from vpp_core.plan.document import PlanRequest
from vpp_core.report.studies import DEFAULT_RATIOS, DEFAULT_RESOLUTIONS


class LabelValue(BaseModel):
    """One label of a label set: its value, name (groups, materials), faces and area."""

    label: int
    name: str | None = None
    faces: int
    area_mm2: float


class LabelsSummary(BaseModel):
    """Face labels stored with a mesh: pass `id` as a plan's `labels_id`."""

    id: str
    mesh_id: str
    source: str = Field(description="upload, ply:<property>, obj:groups|materials|objects, ...")
    labelled_faces: int
    values: list[LabelValue]


class MeshSummary(BaseModel):
    """An uploaded mesh: content id (SHA-256 of the canonical geometry) and what it holds."""

    id: str
    faces: int
    vertices: int
    counted_faces: int
    area_mm2: float
    bounds_mm: list[list[float]] = Field(description="[[xmin, ymin, zmin], [xmax, ymax, zmax]]")
    units: str = Field(description="units of the uploaded file; the mesh is stored in mm")
    warnings: list[str]
    labels: LabelsSummary | None = Field(
        None,
        description="the face labels of this upload (uploaded, or read from the file); "
        "None when it had none",
    )


class PlanSubmit(PlanRequest):
    """A plan request: the uploaded mesh's id plus the plan settings (defaults as `vpp plan`)."""

    model_config = ConfigDict(extra="forbid")

    mesh_id: str = Field(pattern=r"^[0-9a-f]{64}$")
    callback: Callback | None = None
    """Where to POST the job's terminal event (not part of the plan: identical requests with
    other callbacks share the job, and each callback is told)."""


class StudySubmit(PlanRequest):
    """A study of an uploaded mesh: `resolution` sweeps `resolutions` (mm) from one trace;
    `decimation` plans on copies decimated to `ratios` of the faces, judged on the original.
    The rest as in a plan request (the target's resolution is the decimation study's)."""

    model_config = ConfigDict(extra="forbid")

    mesh_id: str = Field(pattern=r"^[0-9a-f]{64}$")
    callback: Callback | None = None
    kind: Literal["resolution", "decimation"]
    resolutions: list[float] = Field(
        default=DEFAULT_RESOLUTIONS,
        min_length=1,
        max_length=100,
        description="target resolutions of a `resolution` study, mm",
    )
    ratios: list[float] = Field(
        default=DEFAULT_RATIOS,
        min_length=1,
        max_length=100,
        description="face ratios of a `decimation` study, each in (0, 1]",
    )


class StudyPlots(BaseModel):
    """Links to a study's (or a point cloud's) PNG plots."""

    plots: list[str]


class JobAccepted(BaseModel):
    """The job computing a plan; poll its Location."""

    id: str
    status: Literal["queued", "running", "succeeded", "failed", "canceled"]


class Progress(BaseModel):
    """Where the job is: stage (candidates, trace, matrices, solve, metrics, done), done/total."""

    stage: str | None = None
    done: int | None = None
    total: int | None = None


class JobError(BaseModel):
    """Why a job failed."""

    type: str
    title: str
    detail: str


class Chunk(BaseModel):
    """A ray-tracing chunk of the job: its candidates, state and the worker that took it."""

    model_config = ConfigDict(extra="allow")

    index: int
    views: int
    status: str
    worker: str | None = None
    done: int | None = None


class JobOut(BaseModel):
    """A plan job as clients poll it; `result_url` is set once the plan is ready."""

    id: str
    status: Literal["queued", "running", "succeeded", "failed", "canceled"]
    progress: Progress
    error: JobError | None = None
    result_url: str | None = None
    chunks: list[Chunk] = []
    created_at: datetime | None = None
    started_at: datetime | None = None
    ended_at: datetime | None = None
    kind: Literal["plan", "study", "point-cloud"] | None = None
    deliveries: list[Delivery] = []
    """The attempts to deliver the job's webhooks (its `callback`), oldest first."""


class Problem(BaseModel):
    """RFC 9457 problem details (application/problem+json)."""

    model_config = ConfigDict(extra="allow")

    type: str = "about:blank"
    title: str
    status: int
    detail: str | None = None
    instance: str | None = None
    errors: list[dict[str, Any]] | None = None
    """422: the first validation errors (at most 20), each {loc, msg, type}."""
    error_count: int | None = None
    """422: how many validation errors were found."""
    error_count_exact: bool | None = None
    """422: false when validation stopped at the first items in error, before the body's end
    (a long list is checked in steps): `error_count` then counts the items checked."""


class RelatedPlan(BaseModel):
    """The plan of the same request under one formulation, and whether it is computed."""

    formulation: Literal["density", "visibility"]
    id: str
    available: bool
    view_url: str
    request: PlanSubmit
    """The body that POST /v1/plans takes to compute it."""


class RelatedPlans(BaseModel):
    """The `density` and `visibility` plans of one request (the viewer's toggle)."""

    plans: list[RelatedPlan]
