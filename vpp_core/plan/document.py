"""The plan request and the plan document (SPEC §8): the contract clients and checks read."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import standoff_for
from vpp_core.cell.setup import Setup
from vpp_core.cover.access import DIRECTIONS
from vpp_core.plan.cycle import Objective, TourOut
from vpp_core.plan.diagnostics import Diagnostics
from vpp_core.plan.metrics import Metrics
from vpp_core.plan.regions import Region, check_regions, finest
from vpp_core.plan.robotdoc import RobotCounts, RobotOut
from vpp_core.trace.rays import DEFAULT_BACKEND, BackendName

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]

Profile = Literal["default", "paper"]
PROFILES: dict[str, dict[str, object]] = {
    "default": {
        "tilt_deg": 30.0,
        "retry_tilt_deg": 60.0,
        "standoff": "target",
        "rows": "patches",
        "min_coverage": 0.99,
        "adaptive": True,
        "sphere": 200,
        "roll": "fitted",
        "tiles": True,
    },
    "paper": {
        "tilt_deg": 0.0,
        "retry_tilt_deg": 0.0,
        "standoff": "working",
        "rows": "faces",
        "min_coverage": 1.0,
        "adaptive": False,
        "sphere": 0,
        "roll": "world",
        "tiles": False,
    },
}
"""What each profile fills in where a request leaves a field out (docs/quality.md): `default`,
the project's best by bench/quality.py; `paper`, SPEC §2-4 as the paper wrote them."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Target(_Strict):
    """Required spatial resolution r̄ (mm) and the covering formulation."""

    resolution_mm: float = Field(0.18, gt=0, le=1e4)
    formulation: Literal["density", "visibility"] = "density"
    min_coverage: float | None = Field(
        None,
        gt=0,
        le=1,
        description="fraction of the coverable area to cover; 1 = every coverable row "
        "(SPEC §3-4); below 1 a partial cover may leave small areas out, listed in the plan's "
        "`partial.left_out`, and seen by some view; default: the profile's (0.99; paper: 1)",
    )

    @property
    def fraction(self) -> float:
        """min_coverage, 1 where left out (a request fills it from its profile)."""
        return 1.0 if self.min_coverage is None else self.min_coverage

    rows: Literal["patches", "faces"] | None = Field(
        None,
        description="what a row of the cover is: `patches` (faces grouped into connected "
        "pieces of surface about 32 r̄ across, 5 r̄ in regions with their own target; R and "
        "area summed: coverage of sampled area, whatever the tessellation) or `faces` (one "
        "row per face, SPEC §3); default: the profile's",
    )
    open_min: int = Field(
        0,
        ge=0,
        le=DIRECTIONS,
        description=f"patch rows: a patch open along fewer of {DIRECTIONS} directions over the "
        "sensor's incidence cone (rays from it that leave the part and the setup) is recessed, "
        "seen if at all through a clearance or a slot, a slice per view: a partial cover gives "
        "it no weight (it may stay unmet, listed in the plan's `cover_rows.recessed`); 0 "
        "(default): no patch is recessed; 4 keeps the inside of a closed housing from driving "
        "the count, and leaves out some of what a view sphere sees (docs/quality.md, "
        '"Recessed patches")',
    )


class CandidateGenerator(_Strict):
    """Settings of the default generator (SPEC §2)."""

    count: int = Field(500, ge=1, description="candidates wanted (fewer if some are dropped)")
    seed: int = Field(0, ge=0)
    decimate: float | None = Field(None, gt=0, le=1, description="fraction of faces kept")
    clearance_mm: float = Field(20.0, ge=0, description="least camera distance to the part")
    tilt_deg: float | None = Field(
        None,
        ge=0,
        lt=90,
        description="gazes drawn within this angle of the smoothed normal (0: along it, SPEC §2); "
        "default: the profile's (30, which lets holes and pocket walls be seen by many "
        "candidates; paper: 0)",
    )
    retry_tilt_deg: float | None = Field(
        None,
        ge=0,
        lt=90,
        description="a sample whose gazes are all blocked tries directions within this wider "
        "angle before it is dropped (0: dropped); default: the profile's (60; paper: 0)",
    )
    standoff_mm: float | None = Field(
        None,
        gt=0,
        description="camera-sample distance, within the depth of field; default: the profile's "
        "(the distance where a pixel's footprint is r̄ / 1.2, at most the working distance; "
        "paper: the working distance)",
    )
    adaptive: bool | None = Field(
        None,
        description="after a quick cover, add candidates aimed at the rows that force views, "
        "trace only those and cover again, while the count improves (docs/quality.md); "
        "default: the profile's (on; paper: off)",
    )
    sphere: int | None = Field(
        None,
        ge=0,
        le=1000,
        description="viewpoints on view spheres around the part (looking at its centre) traced "
        "after the generated ones; those sampling surface no generated candidate samples (an "
        "inside seen through a window, a gap between gears) join the pool "
        "(docs/quality.md); at most 1 000, the baseline's count; default: the profile's (200; "
        "paper: 0)",
    )
    roll: Literal["fitted", "world"] | None = Field(
        None,
        description="the cameras' roll about their gazes: `fitted` turns a camera where that "
        "frames at least 10 % more of the surface facing it than world +Z as image-up does, "
        "so that a long part gets as few views whichever way it lies in its file; `world` "
        "keeps the default up (world +Z on the image plane); default: the profile's (fitted; "
        "paper: world)",
    )
    tiles: bool | None = Field(
        None,
        description="also lay head-on cameras side by side over each flat face that no frame "
        "holds whole, in one orientation (at most a quarter of `count`, the largest faces "
        "first), so that a large flat face is covered by frames that tile it; default: the "
        "profile's (on; paper: off)",
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
    time_limit_s: float = Field(
        60.0,
        gt=0,
        le=86_400,
        description="wall seconds for the whole plan after loading the mesh: candidates, "
        "tracing, the adaptive rounds and the covers; the final cover gets what the stages "
        "before it left (at least 15 %), less 17 % kept for the tour, metrics, diagnostics "
        "and the document",
    )
    mip_rel_gap: float = Field(0.0, ge=0, lt=1)


class PlanRequest(_Strict):
    """Everything a plan depends on besides the mesh; fields left out take the profile's."""

    profile: Profile = Field(
        "default",
        description="`default`: the project's best plans (tilted gazes, retries, stand-off from "
        "the target, patch rows; docs/quality.md); `paper`: the paper's method as SPEC §2-4 "
        "first wrote it (gazes along the normal at the working distance, face rows)",
    )
    sensor: Sensor = Sensor()
    target: Target = Target()
    candidates: Candidates = Field(default_factory=CandidateGenerator)
    solver: SolverSettings = SolverSettings()
    objective: Objective = Objective()
    setup: Setup | None = Field(
        None,
        description="the part in its cell (SETUP.json, docs/cell.md): part_to_cell, floor, "
        "fixtures (uploaded mesh ids), workspace, keep_out; none: the part alone in space",
    )
    regions: list[Region] = Field(
        [],
        description="regions of interest, in order (later ones win where they overlap): each "
        "selects faces by `faces` (ids), `box` or `sphere` (centroid inside, part frame, mm) or "
        "`label` (the mesh's face labels) and has its own `resolution_mm`, or `ignore: true` "
        "(not counted anywhere); faces no region selects take target.resolution_mm",
    )
    labels_id: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{64}$",
        description="service: the face labels that `label` regions select from, by the id "
        "POST /v1/meshes answered for them (labels read from the file or uploaded as `labels`); "
        "the mesh id names the geometry only, so two label sets of one mesh never clash",
    )
    backend: BackendName = Field(
        DEFAULT_BACKEND,
        description="ray backend that computes R: `raster` (z-buffer of face ids at pixel "
        "centres, the fastest; views with more faces than pixels go to `packets`), `packets` "
        "(Embree packets of 4 × 4 pixel rays) or `embree` (one Embree ray per pixel); they "
        "agree but for pixel centres on triangle edges",
    )

    @model_validator(mode="after")
    def _fill_profile(self) -> PlanRequest:
        """Fill the fields left out (None) with the profile's values."""
        check_regions(self.regions)
        chosen = PROFILES[self.profile]
        fill = {k: chosen[k] for k in ("rows", "min_coverage") if getattr(self.target, k) is None}
        self.target = self.target.model_copy(update=fill)
        spec = self.candidates
        if isinstance(spec, CandidateGenerator):
            s = self.sensor
            if spec.standoff_mm is not None and not s.near_mm <= spec.standoff_mm <= s.far_mm:
                raise ValueError(
                    f"candidates.standoff_mm ({spec.standoff_mm}) must lie in the depth of field "
                    f"[{s.near_mm}, {s.far_mm}] mm"
                )
            by_target = standoff_for(self.sensor, finest(self.target.resolution_mm, self.regions))
            standoff = by_target if chosen["standoff"] == "target" else None
            update = {
                "tilt_deg": chosen["tilt_deg"] if spec.tilt_deg is None else spec.tilt_deg,
                "retry_tilt_deg": spec.retry_tilt_deg
                if spec.retry_tilt_deg is not None
                else chosen["retry_tilt_deg"],
                "standoff_mm": spec.standoff_mm or standoff or self.sensor.working_distance,
                "adaptive": chosen["adaptive"] if spec.adaptive is None else spec.adaptive,
                "sphere": chosen["sphere"] if spec.sphere is None else spec.sphere,
                "roll": chosen["roll"] if spec.roll is None else spec.roll,
                "tiles": chosen["tiles"] if spec.tiles is None else spec.tiles,
            }
            self.candidates = spec.model_copy(update=update)
        return self


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


class CellPose(BaseModel):
    """A viewpoint's pose in the cell frame (setup.part_to_cell applied), mm."""

    position: list[float]
    gaze: list[float]
    up: list[float]
    camera_to_world: list[list[float]]


class ViewpointOut(CandidateOut):
    """A selected pose with its 4×4 camera-to-world matrix (columns x, y, z, position)."""

    camera_to_world: list[list[float]]
    cell: CellPose | None = Field(None, description="the pose in the cell frame (with a setup)")
    joints: list[float] | None = None
    """With a robot or turntable in the setup: its joint values at this view (deg; mm for
    prismatic joints; a turntable's table angle, linear axis offset and camera roll)."""


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
    retry_tilt_deg: float | None = None
    standoff_mm: float | None = None
    roll: Literal["fitted", "world"] | None = None
    """How the cameras' roll was chosen (CandidateGenerator.roll)."""
    tiles: int = 0
    """Of the generated candidates, the head-on cameras tiling large flat faces
    (CandidateGenerator.tiles); their ids follow the other generated ones."""
    sphere: int = 0
    """View-sphere candidates that joined the pool: they sample surface no generated one
    does (their ids follow the generated ones)."""
    sphere_traced: int = 0
    """View-sphere candidates traced to find them (scouted with a quarter of the sensor's
    pixels; those that joined are traced again at full resolution)."""
    added: int = 0
    """Candidates added by the adaptive rounds (their ids follow the generated and the
    view-sphere ones)."""
    robot: RobotCounts | None = None
    """With a robot or turntable: the poses its reach was computed for (generator and
    adaptive rounds) and those dropped by reason (no_ik, joint_limit, collision)."""


class AdaptiveRound(BaseModel):
    """One round of adaptive candidates: the quick cover of the pool, and what it added."""

    round: int
    candidates: int
    """Candidates in the pool the quick cover chose from."""
    views: int
    bound: float | None
    status: str
    added: int
    """Candidates aimed at this cover's forcing rows and added to the pool."""
    removed: int = 0
    """The previous round's candidates taken out of the pool again: with them this quick cover
    needed more views than the previous one (a patch asks for its best candidate's share, so
    candidates can make it ask for more)."""
    seconds: float


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


class CoverRows(BaseModel):
    """What the rows of the cover were: faces, or patches of faces (target.rows)."""

    kind: Literal["patches", "faces"]
    count: int
    """Distinct rows: patches with at least one counted face, or counted faces."""
    edge_mm: float | None = None
    """The patch size asked for (mm): 32 r̄ (5 r̄ at least on small parts, larger on very
    large ones)."""
    element_mm2: float | None = None
    """Where set, the faces larger than this (mm², half a patch's area) were split into area
    elements and traced as such (vpp_core.mesh.refine bisects each on its longest edge until
    no piece is larger; the pieces of a face follow each other, in face order), and the
    patches are made of the pieces (docs/quality.md, stage 3c)."""
    sampled_area: float | None = None
    """Share of the counted area in patches the selected views sample (3 rays or more)."""
    max_sampled_area: float | None = None
    """The same with every candidate: what the candidates reach."""
    met_area: float | None = None
    """Share of the counted area in patches whose rows the selected views meet, Σ_j S_pj ≥ 1
    with S_pj = min(1, f_pj / u_p · min(1, r̄ sqrt(R_pj / (f_pj A_p)))): f_pj the share of
    patch p that view j samples (its rays against the pinhole's ray density on the patch's
    plane at its centre and mean normal), u_p the largest share any candidate samples
    (docs/quality.md, stage 3b)."""
    patch_of_face: list[int] | None = None
    """Per face (per element where `element_mm2` is set), its patch (-1: not counted): R and
    area summed over a patch give its row; the patch's centre and mean normal are its faces'
    area-weighted means."""
    unsampled: Uncoverable | None = None
    """Counted faces that rays of some candidate hit, but in patches that no candidate samples
    with STRAY_RAYS (3) rays or more (grazing rays only): not in the cover."""
    recessed: Uncoverable | None = None
    """Faces of recessed patches (open along fewer than `target.open_min` of 64 directions:
    vpp_core.cover.access) whose rows the selected views do not meet: a partial cover gives
    them no weight, so they are neither in its coverable area nor in `partial.left_out`."""
    recessed_area: float | None = None
    """Share of the counted area in recessed patches, met or not."""


class SetupOccluded(Uncoverable):
    """Uncoverable faces the setup hides (docs/cell.md, vpp_core.plan.cellplan): touching the
    floor or a fixture, seen by a candidate without them, or by a candidate of the generator
    without a setup (the setup forbids or blocks where it stands)."""

    touching: int = Field(0, description="faces within 0.05 mm of the floor or a fixture")
    blocked: int = Field(0, description="others a candidate sees without the floor and fixtures")
    unreachable: int = Field(
        0, description="others seen by a candidate the generator places without a setup"
    )


class RegionsInfo(BaseModel):
    """The request's regions as applied: which face has which target."""

    regions: list[Region]
    """The regions, normalised (in order; later ones won where they overlapped)."""
    default_resolution_mm: float
    """The target of the faces no region selects (target.resolution_mm)."""
    face_region: list[int]
    """Run-length code of each face's region, in face order: [region, run, region, run, ...],
    region = index into `regions`, -1 = default target (expand with numpy.repeat)."""
    ignored: Uncoverable
    """Counted faces of ignored regions: in no row and no coverage denominator."""
    labels: dict[str, object] | None = None
    """Where the mesh's face labels came from: {source, names} (None: the mesh had none)."""
    warnings: list[str] = []


class LeftOut(Uncoverable):
    """Coverable faces a partial cover leaves out."""


class PointsInfo(BaseModel):
    """The plan judged at points spread uniformly by area over the counted faces (seeded;
    vpp_core.plan.pointseen): a point is seen by a view when it lies in its image and depth of
    field, within the incidence limit, and the line from the camera reaches it first."""

    points: int
    seen_fraction: float
    """Share of the points some selected view sees."""
    reach_fraction: float
    """Share of the points some candidate sees."""
    added: list[int]
    """Candidates added because each saw at least 0.1 % of the points more than the plan did
    (by three Poisson deviations), in the order added (ids of `candidates`; in `viewpoints`
    too)."""


class PartialInfo(BaseModel):
    """What a partial cover (target.min_coverage < 1) covers of the coverable area: the area
    of its rows less the recessed patches' (`cover_rows.recessed`); a patch row counts the
    share of its area its best candidate samples (docs/quality.md, stage 6)."""

    min_coverage: float
    coverable_area_mm2: float
    covered_area_mm2: float
    covered_fraction: float
    left_out: LeftOut
    seen_area_mm2: float | None = None
    """The coverable area in rows some selected view samples, at whatever density (3 rays or
    more on a patch): at least 0.999 of it where the cover may leave more short of r̄ (density
    rows; vpp_core.plan.pipeline.SEEN_SHARE)."""
    seen_fraction: float | None = None
    points: PointsInfo | None = None
    """The selected views judged at surface points, and the views added for what they see
    that the patch rows missed (None: a cover that is not the default's partial cover)."""


class Timings(BaseModel):
    """Wall seconds per stage."""

    load: float = 0.0
    """Before planning: reading the mesh (the CLI: since the command started, imports too)."""
    compiling: float = 0.0
    """numba compiling the trace and cover kernels, on a fresh install only (then cached); not
    counted in the solver's time limit."""
    candidates: float = 0.0
    trace: float = 0.0
    adaptive: float = 0.0
    matrices: float = 0.0
    solve: float = 0.0
    metrics: float = 0.0
    diagnostics: float = 0.0
    setup: float = 0.0  # what the setup hides (setup_occluded), with a setup only
    robot: float = 0.0  # joints of the views and the joint-space tour, with a robot only


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
    setup: Setup | None = None
    setup_occluded: SetupOccluded | None = None
    regions: RegionsInfo | None = None
    """The regions of interest as applied (None: the request had none)."""
    cover_rows: CoverRows | None = None
    adaptive: list[AdaptiveRound] = []
    partial: PartialInfo | None = None
    diagnostics: Diagnostics | None = None
    robot: RobotOut | None = None
    """With a robot or turntable in the setup: what its reach dropped and its joint tour."""
    rays: RaysInfo
    timings_s: Timings
