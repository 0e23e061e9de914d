"""The paper's studies (SPEC §5, Fig. 3): viewpoints against the target resolution from one R,
and plans made on decimated meshes judged on the original.

Each row is what `vpp plan` would report for that resolution or planning mesh: the same
candidates, the same solver, the selection in visiting order (`poses`), so a row can be
checked against a fresh plan or an independent re-trace of its poses.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from vpp_core.camera.pose import Viewpoints
from vpp_core.candidates.generator import planning_mesh
from vpp_core.cell.geometry import Cell
from vpp_core.cover.density import Cameras, CoverModel, Formulation
from vpp_core.cover.partial import PartialCover
from vpp_core.errors import RegionError, VppError
from vpp_core.mesh.part import Part, part_from_arrays
from vpp_core.plan.cellplan import cell_of, setup_backend
from vpp_core.plan.document import (
    CandidateGenerator,
    MeshInfo,
    PlanDocument,
    PlanRequest,
    Timings,
    ViewpointOut,
)
from vpp_core.plan.metrics import Histogram, RegionMetrics, evaluate, region_metrics
from vpp_core.plan.pipeline import (
    Limits,
    candidates_for,
    check_limits,
    check_request,
    document,
    elements_of,
    mesh_info,
    rows_model,
    rows_of,
    solve,
    targets_of,
    tracer_of,
)
from vpp_core.plan.regions import FaceTargets
from vpp_core.plan.regionsdoc import region_members
from vpp_core.trace.raytrace import Trace, trace_counts

DEFAULT_RESOLUTIONS = [0.1, 0.12, 0.14, 0.16, 0.18, 0.2, 0.25, 0.3, 0.4, 0.5]
"""Target resolutions (mm) of a resolution sweep when none are given."""
DEFAULT_RATIOS = [1.0, 0.5, 0.2, 0.1, 0.05]
"""Face ratios of a decimation study when none are given."""
DEFAULT_LIMITS = Limits()
FORMULATIONS: tuple[Formulation, ...] = ("density", "visibility")
Progress = Callable[[str, int, int], None]
"""progress(stage, done, total)."""


class RowCoverage(BaseModel):
    """Fractions of the (original) part's counted faces and area seen by ≥ 1 selected view."""

    faces: float
    area: float


class RowResolution(BaseModel):
    """Fractions of counted faces and area whose achieved resolution meets the target."""

    met_faces: float
    met_area: float


class RowSolver(BaseModel):
    """How the cover was solved: `optimal` means the count is proven minimal."""

    status: str
    gap: float | None


class StudyRow(BaseModel):
    """One (resolution or ratio, formulation) of a study; figures on the original mesh."""

    formulation: Formulation
    viewpoints: int = Field(description="number of selected viewpoints (#OVP)")
    coverage: RowCoverage
    resolution: RowResolution
    solver: RowSolver
    histogram: Histogram
    poses: list[ViewpointOut] = Field(description="the selected viewpoints, in visiting order")
    regions: list[RegionMetrics] = Field(
        [], description="per region of the request (each against its own target), then default"
    )


class SweepRow(StudyRow):
    """A row of the resolution sweep."""

    resolution_mm: float


class DecimationRow(StudyRow):
    """A row of the decimation study: candidates, R and cover on the decimated mesh."""

    ratio: float
    resolution_mm: float
    planning_faces: int = Field(description="faces of the decimated mesh planned on")


class StudyTimings(BaseModel):
    """Wall seconds: tracing (all of it) and each solve, in row order."""

    trace_s: float
    solve_s: list[float]
    total_s: float


class Study(BaseModel):
    """A study's document: `{kind, rows}` plus what it was run on."""

    format: Literal["vpp-study/1"] = "vpp-study/1"
    kind: Literal["resolution", "decimation"]
    mesh: MeshInfo
    request: PlanRequest
    rows: list[SweepRow] | list[DecimationRow]
    timings_s: StudyTimings


def _row_fields(doc: PlanDocument) -> dict[str, object]:
    """The common row fields of a plan document's selection."""
    m = doc.metrics
    return dict(
        formulation=doc.target.formulation,
        viewpoints=len(doc.viewpoints),
        coverage=RowCoverage(faces=m.coverage.faces, area=m.coverage.area),
        resolution=RowResolution(met_faces=m.resolution.met_faces, met_area=m.resolution.met_area),
        solver=RowSolver(status=doc.solver.status, gap=doc.solver.gap),
        histogram=m.resolution.histogram,
        poses=doc.viewpoints,
        regions=m.regions,
    )


def _study(
    kind: Literal["resolution", "decimation"],
    part: Part,
    request: PlanRequest,
    rows: list[SweepRow] | list[DecimationRow],
    trace_s: float,
    solve_s: list[float],
    start: float,
) -> Study:
    """The study document, its timings rounded as the plan document's are."""
    return Study(
        kind=kind,
        mesh=mesh_info(part),
        request=request,
        rows=rows,
        timings_s=StudyTimings(
            trace_s=round(trace_s, 4),
            solve_s=solve_s,
            total_s=round(time.perf_counter() - start, 4),
        ),
    )


class _Solver:
    """Covers of one R at a resolution and formulation, as `plan` solves them (in the setup
    `cell`), timed."""

    def __init__(
        self, part: Part, views: Viewpoints, trace: Trace, threads: int | None, cell: Cell | None
    ) -> None:
        self.part, self.views, self.trace, self.threads = part, views, trace, threads
        self.cell = cell
        self.seconds: list[float] = []
        self._visibility: dict[tuple[float, float | None], PartialCover] = {}

    def cover(self, request: PlanRequest) -> tuple[PartialCover, CoverModel, FaceTargets]:
        """The cover for `request.target` on this R (visibility solved once per row set: V has
        no r̄, but patch rows are sized by it)."""
        t = request.target
        start = time.perf_counter()
        rows = rows_of(self.part, request, self.trace, self.cell)  # regions keep their targets
        own = rows_model(rows, request, self.trace, Cameras(self.views, request.sensor))
        key = (t.fraction, rows.patches.edge_mm if rows.patches else None)
        if t.formulation == "visibility" and key in self._visibility:
            cover = self._visibility[key]
        else:
            must = rows.targets.region_rows(own.face_row, own.faces, own.matrix.shape[0])
            cover = solve(own, t, request.solver, self.threads, None, must)
            if t.formulation == "visibility":
                self._visibility[key] = cover
        self.seconds.append(round(time.perf_counter() - start, 4))
        model = own if rows.elements is None else own.lifted(rows.elements.parent)
        return cover, model, targets_of(self.part, request)


def _with_target(request: PlanRequest, resolution: float, formulation: Formulation) -> PlanRequest:
    target = request.target.model_copy(
        update={"resolution_mm": resolution, "formulation": formulation}
    )
    return request.model_copy(update={"target": target})


def resolution_sweep(
    part: Part,
    request: PlanRequest,
    resolutions: Sequence[float],
    *,
    limits: Limits = DEFAULT_LIMITS,
    threads: int | None = None,
    progress: Progress | None = None,
    cell: Cell | None = None,
) -> Study:
    """#OVP against r̄ (mm) for both formulations from one trace (paper Fig. 3 right; one per
    set of area elements the rows' targets split the faces into), in the setup `cell` (else
    the request's)."""
    start = time.perf_counter()
    check_study("resolution", resolutions, request, limits)
    cell = cell_of(request, cell)
    backend = setup_backend(part, request, cell)
    views, info = candidates_for(part, request, backend, cell)
    check_limits(len(views), request.sensor.n_pixels, limits)
    _report(progress, "trace", 0, len(views))
    solvers: dict[float | None, _Solver] = {}  # one R per set of elements the rows ask for
    rows: list[SweepRow] = []
    seconds: list[float] = []
    for formulation in FORMULATIONS:
        for r in resolutions:
            _report(progress, "solve", len(rows), 2 * len(resolutions))
            req = _with_target(request, r, formulation)
            split = elements_of(part, req)
            key = split.max_area_mm2 if split else None
            if key not in solvers:
                tracer = tracer_of(split, request, cell, backend)
                trace = trace_counts(
                    part, request.sensor, views, backend=tracer, threads=threads, elements=split
                )
                solvers[key] = _Solver(part, views, trace, threads, cell)
            solver = solvers[key]
            cover, model, targets = solver.cover(req)
            seconds.append(solver.seconds[-1])
            doc = document(
                targets.part, req, views, info, solver.trace, model, cover, Timings(), None, targets
            )
            rows.append(SweepRow(resolution_mm=r, **_row_fields(doc)))
    traced = sum(s.trace.seconds for s in solvers.values())
    return _study("resolution", part, request, rows, traced, seconds, start)


def decimated_part(part: Part, ratio: float) -> Part:
    """The part quadric-decimated to about `ratio` of its faces (itself at ratio 1)."""
    if ratio >= 1:
        return part
    mesh = planning_mesh(part, ratio)
    return part_from_arrays(mesh.vertices, mesh.faces)


def decimation_study(
    part: Part,
    request: PlanRequest,
    ratios: Sequence[float],
    *,
    limits: Limits = DEFAULT_LIMITS,
    threads: int | None = None,
    progress: Progress | None = None,
    cell: Cell | None = None,
) -> Study:
    """Plans made entirely on decimated copies (candidates, R, cover), their selections
    re-traced on the original mesh and judged there (paper Fig. 3 left), in the setup `cell`
    (else the request's)."""
    start = time.perf_counter()
    check_study("decimation", ratios, request, limits)
    assert isinstance(request.candidates, CandidateGenerator)
    plain = request.model_copy(
        update={"candidates": request.candidates.model_copy(update={"decimate": None})}
    )
    cell = cell_of(request, cell)
    original = setup_backend(part, request, cell)
    rows: list[DecimationRow] = []
    traced = 0.0
    seconds: list[float] = []
    for k, ratio in enumerate(ratios):
        _report(progress, "ratio", k, len(ratios))
        planning = decimated_part(part, ratio)
        split = elements_of(planning, plain)
        backend = setup_backend(planning, request, cell)
        views, info = candidates_for(planning, plain, backend, cell)
        check_limits(len(views), request.sensor.n_pixels, limits)
        tracer = tracer_of(split, request, cell, backend)
        trace = trace_counts(
            planning, request.sensor, views, backend=tracer, threads=threads, elements=split
        )
        traced += trace.seconds
        solver = _Solver(planning, views, trace, threads, cell)
        for formulation in FORMULATIONS:
            req = _with_target(plain, request.target.resolution_mm, formulation)
            cover, model, targets = solver.cover(req)
            doc = document(
                targets.part, req, views, info, trace, model, cover, Timings(), None, targets
            )
            chosen = np.array([p.id for p in doc.viewpoints], dtype=np.int64)
            check = trace_counts(
                part, request.sensor, views.take(chosen), backend=original, threads=threads
            )
            traced += check.seconds
            judged = targets_of(part, req)  # the regions on the original
            doc.metrics = evaluate(
                check.counts,
                judged.part.areas,
                judged.part.counted,
                np.arange(len(chosen)),
                judged.resolution_mm,
                request.target.resolution_mm,
            )
            if req.regions:
                doc.metrics.regions = region_metrics(
                    check.counts,
                    part.areas,
                    part.counted,
                    np.arange(len(chosen)),
                    region_members(judged, req.regions, request.target.resolution_mm),
                )
            rows.append(
                DecimationRow(
                    ratio=ratio,
                    resolution_mm=request.target.resolution_mm,
                    planning_faces=planning.n_faces,
                    **_row_fields(doc),
                )
            )
        seconds += solver.seconds
    return _study("decimation", part, request, rows, traced, seconds, start)


def check_study(
    kind: str, values: Sequence[float], request: PlanRequest, limits: Limits = DEFAULT_LIMITS
) -> None:
    """Refuse, before any work, a study whose values or request are malformed or too big."""
    if kind == "decimation":
        _check_values(values, "ratios", upper=1.0)
        by_id = [r.name for r in request.regions if r.faces is not None or r.label is not None]
        if by_id:
            raise RegionError(
                f"a decimation study plans on new faces: regions by face ids or labels cannot "
                f"follow them ({', '.join(by_id)}); select by box or sphere"
            )
        if not isinstance(request.candidates, CandidateGenerator):
            raise VppError("the decimation study generates its candidates: give a count")
    else:
        _check_values(values, "resolutions", upper=None)
    check_request(request, limits)


MAX_STUDY_VALUES = 100
"""Most resolutions or ratios one study may ask for."""


def _check_values(values: Sequence[float], name: str, upper: float | None) -> None:
    """VppError unless 1..MAX_STUDY_VALUES finite positive values (≤ upper)."""
    if not 1 <= len(values) <= MAX_STUDY_VALUES:
        raise VppError(f"{name}: give 1 to {MAX_STUDY_VALUES} values, got {len(values)}")
    for v in values:
        if not (np.isfinite(v) and v > 0 and (upper is None or v <= upper)):
            bound = f"in (0, {upper:g}]" if upper is not None else "positive"
            raise VppError(f"{name}: every value must be {bound}, got {v:g}")


def _report(progress: Progress | None, stage: str, done: int, total: int) -> None:
    if progress:
        progress(stage, done, total)


def study_csv(study: Study) -> str:
    """The study's rows as CSV (one line per row, poses left out)."""
    head = ["ratio", "planning_faces"] if study.kind == "decimation" else []
    cols = [
        *head,
        "resolution_mm",
        "formulation",
        "viewpoints",
        "coverage_faces",
        "coverage_area",
        "met_faces",
        "met_area",
        "solver_status",
        "solver_gap",
    ]
    lines = [",".join(cols)]
    for row in study.rows:
        extra = [row.ratio, row.planning_faces] if isinstance(row, DecimationRow) else []
        values = [
            *extra,
            row.resolution_mm,
            row.formulation,
            row.viewpoints,
            row.coverage.faces,
            row.coverage.area,
            row.resolution.met_faces,
            row.resolution.met_area,
            row.solver.status,
            "" if row.solver.gap is None else row.solver.gap,
        ]
        lines.append(",".join(str(v) for v in values))
    return "\n".join(lines) + "\n"
