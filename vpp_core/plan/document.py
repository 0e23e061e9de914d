"""The plan request and the plan document (SPEC §8): the contract clients and checks read."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from vpp_core.camera.sensor import Sensor
from vpp_core.plan.cycle import Objective, TourOut
from vpp_core.plan.diagnostics import Diagnostics
from vpp_core.plan.metrics import Metrics
from vpp_core.trace.rays import DEFAULT_BACKEND, BackendName

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Target(_Strict):
    """Required spatial resolution r̄ (mm) and the covering formulation."""

    resolution_mm: float = Field(0.18, gt=0, le=1e4)
    formulation: Literal["density", "visibility"] = "density"
    min_coverage: float = Field(
        1.0,
        gt=0,
        le=1,
        description="fraction of the coverable area to cover; 1 = every coverable face "
        "(SPEC §3-4); below 1 a partial cover may leave small faces out",
    )


class CandidateGenerator(_Strict):
    """Settings of the default generator (SPEC §2)."""

    count: int = Field(500, ge=1, description="candidates wanted (fewer if some are dropped)")
    seed: int = Field(0, ge=0)
    decimate: float | None = Field(None, gt=0, le=1, description="fraction of faces kept")
    clearance_mm: float = Field(20.0, ge=0, description="least camera distance to the part")
    tilt_deg: float = Field(
        0.0,
        ge=0,
        lt=90,
        description="gazes drawn within this angle of the smoothed normal (0: along it, SPEC §2); "
        "30 lets holes and pocket walls be seen by many candidates (docs/cad-meshes.md)",
    )


class ViewpointIn(_Strict):
    """An explicit candidate: camera centre and gaze (mm, mesh frame); `up` optional."""

    position: Vec3
    gaze: Vec3
    up: Vec3 | None = None


class ExplicitCandidates(_Strict):
    """An explicit candidate list; a bare JSON list of viewpoints is read as this."""

    viewpoints: list[ViewpointIn] = Field(min_length=1)


def _wrap_list(value: object) -> object:
    """A bare list of viewpoints means {"viewpoints": list}."""
    return {"viewpoints": value} if isinstance(value, list) else value


Candidates = Annotated[CandidateGenerator | ExplicitCandidates, BeforeValidator(_wrap_list)]
"""Generator settings or an explicit list of viewpoints."""


class SolverSettings(_Strict):
    """Set-cover solver: exact MILP (HiGHS) or greedy with redundancy removal."""

    name: Literal["milp", "greedy"] = "milp"
    time_limit_s: float = Field(60.0, gt=0, le=86_400)
    mip_rel_gap: float = Field(0.0, ge=0, lt=1)


class PlanRequest(_Strict):
    """Everything a plan depends on besides the mesh."""

    sensor: Sensor = Sensor()
    target: Target = Target()
    candidates: Candidates = Field(default_factory=CandidateGenerator)
    solver: SolverSettings = SolverSettings()
    objective: Objective = Objective()
    backend: BackendName = Field(
        DEFAULT_BACKEND,
        description="ray backend that computes R: `raster` (z-buffer of face ids at pixel "
        "centres, the fastest; views with more faces than pixels go to `packets`), `packets` "
        "(Embree packets of 4 × 4 pixel rays) or `embree` (one Embree ray per pixel); they "
        "agree but for pixel centres on triangle edges",
    )


class MeshInfo(BaseModel):
    """The planned mesh: content id, faces, area of counted faces (mm²)."""

    id: str
    faces: int
    area_mm2: float
    counted_faces: int
    warnings: list[str]


class CandidateOut(BaseModel):
    """A candidate pose (mm)."""

    id: int
    position: list[float]
    gaze: list[float]
    up: list[float]


class ViewpointOut(CandidateOut):
    """A selected pose with its 4×4 camera-to-world matrix (columns x, y, z, position)."""

    camera_to_world: list[list[float]]


class CandidateInfo(BaseModel):
    """Where the candidates came from."""

    source: Literal["generated", "explicit"]
    requested: int
    generated: int
    dropped: int = 0
    spacing_mm: float | None = None
    planning_faces: int | None = None
    seed: int | None = None
    decimate: float | None = None
    tilt_deg: float | None = None


class SolverOut(BaseModel):
    """How the cover was found and how good it is proven to be."""

    name: str
    status: str
    objective: float
    bound: float | None
    gap: float | None
    time_s: float
    rows: int
    cols: int


class Uncoverable(BaseModel):
    """Counted faces that no candidate sees."""

    faces: int
    area_mm2: float
    ids: list[int]


class LeftOut(Uncoverable):
    """Coverable faces a partial cover leaves out."""


class PartialInfo(BaseModel):
    """What a partial cover (target.min_coverage < 1) covers of the coverable area."""

    min_coverage: float
    coverable_area_mm2: float
    covered_area_mm2: float
    covered_fraction: float
    left_out: LeftOut


class Timings(BaseModel):
    """Wall seconds per stage."""

    load: float = 0.0
    candidates: float = 0.0
    trace: float = 0.0
    matrices: float = 0.0
    solve: float = 0.0
    metrics: float = 0.0
    diagnostics: float = 0.0


class RaysInfo(BaseModel):
    """Ray tracing figures: pixel rays of all candidates, rays actually cast, valid hits."""

    backend: BackendName
    per_view: int
    pixels: int
    cast: int
    valid: int
    cast_per_s: float
    trace_s: float = 0.0
    reused: bool = False
    """True when R came from an earlier plan with the same mesh, sensor and candidates."""


class PlanDocument(BaseModel):
    """The plan (SPEC §8); extra fields beyond the spec's are welcome, its names are fixed."""

    format: Literal["vpp-plan/1"] = "vpp-plan/1"
    mesh: MeshInfo
    sensor: Sensor
    target: Target
    candidates: list[CandidateOut]
    candidate_info: CandidateInfo
    viewpoints: list[ViewpointOut]
    tour_length_mm: float
    """Length of the path through the viewpoints in order (mm), no legs to or from home."""
    tour: TourOut | None = None
    """The visiting order, its length and cycle time from home (request.objective)."""
    solver: SolverOut
    metrics: Metrics
    uncoverable: Uncoverable
    partial: PartialInfo | None = None
    diagnostics: Diagnostics | None = None
    rays: RaysInfo
    timings_s: Timings
