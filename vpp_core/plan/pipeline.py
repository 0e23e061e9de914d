"""The pipeline, stage by stage: part → candidates → R → S (or V) → cover → plan document."""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import GeneratorSettings, generate
from vpp_core.cell.geometry import Cell, resolve
from vpp_core.cover.access import openness
from vpp_core.cover.density import (
    Cameras,
    CoverModel,
    cover_model,
    meets,
)
from vpp_core.cover.partial import (
    PartialCover,
    grown,
    prune_seen,
    seen_columns,
    solve_partial,
)
from vpp_core.cover.patches import (
    MAX_PATCHES,
    MIN_PATCH_TARGETS,
    SMOOTH_TARGETS,
    Patches,
    make_patches,
    patch_edge,
)
from vpp_core.cover.problem import coverage
from vpp_core.errors import LimitError
from vpp_core.mesh.part import Part
from vpp_core.mesh.refine import Elements, elements
from vpp_core.plan.adaptive import adapt
from vpp_core.plan.cellplan import (
    allowed,
    annotate,
    cell_of,
    check_explicit,
    scene_occluders,
    setup_backend,
)
from vpp_core.plan.cycle import TourOut, make_tour
from vpp_core.plan.diagnostics import diagnose
from vpp_core.plan.document import (
    AdaptiveRound,
    CandidateGenerator,
    CandidateInfo,
    CandidateOut,
    CoverRows,
    LeftOut,
    MeshInfo,
    PartialInfo,
    PlanDocument,
    PlanRequest,
    RaysInfo,
    SolverOut,
    SolverSettings,
    Target,
    Timings,
    Uncoverable,
    ViewpointIn,
    ViewpointOut,
)
from vpp_core.plan.metrics import evaluate, region_metrics
from vpp_core.plan.objective import by_objective
from vpp_core.plan.pointseen import PointJudge, surface_points
from vpp_core.plan.regions import FaceTargets, Region, face_targets, mandatory_weights
from vpp_core.plan.regionsdoc import region_members, regions_info
from vpp_core.plan.robotplan import (
    annotate_robot,
    check_reachable,
    counted,
    reachable_candidates,
    reachable_filter,
    table_candidates,
)
from vpp_core.plan.spherereach import sphere_reach
from vpp_core.plan.tour import path_length
from vpp_core.plan.warm import warm
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import Trace, trace_counts

FINAL_SHARE = 0.15
"""The final cover gets at least this share of the plan's time limit."""
AFTER_SHARE = 0.17
"""Share of the time limit kept for what follows the final cover (tour, metrics, diagnostics,
writing the document): at 0.08 turbineblade's plan ended at 61.9 s of a 60 s limit on an idle
2-core machine (4.3 s of metrics and diagnostics, 2 s writing its 199 k-face document); at
0.12 a 238 k-face coupling's at 66.5 s (4.2 s of metrics, 4.4 s of diagnostics); at 0.15
turbineblade's at 60.2 s (3.7 s of metrics, 2.2 s of diagnostics, its document, and the
interpreter's start before the clock)."""
ELEMENTS_PER_PATCH = 2.0
"""The default cover's rows are made of area elements: faces larger than a patch's area /
ELEMENTS_PER_PATCH, or longer than a patch's diagonal (vpp_core.mesh.refine.ELEMENT_LENGTH),
are split and traced as such, so that a CAD facet larger or longer than a patch is grouped
into patches like any surface and a view covers only the pieces it samples (docs/quality.md,
stage 3c)."""
MAX_ELEMENTS = 1_000_000
"""Elements at most: the element area doubles until the split stays within this."""
SEEN_SHARE = 0.999
"""A partial cover below this share of the area (target.min_coverage; density patch rows,
the default profile's) still has this share of it sampled by some selected view, at whatever
density (3 rays or more on a patch; a patch weighing what can be sampled of it, as in the
cover: the document's partial.seen_fraction). Views are added for it where the cover left
more out, then views both rules can spare dropped (vpp_core.cover.partial.seen_columns,
prune_seen; docs/quality.md, stage 6). Patches counted whole, the counter's 23 views took
15 more for patches that every candidate sees a sliver of."""
ADAPT_SHARE = 0.5
"""No adaptive round starts once the plan has spent this share of its time limit."""

Progress = Callable[[str, int, int], None]
"""progress(stage, done, total): called as stages start and as viewpoints are traced."""


@dataclass(frozen=True)
class Limits:
    """Caps on the work one plan may ask for."""

    max_candidates: int = 5_000
    max_rays: int = 20_000_000_000


def candidates_for(
    part: Part, request: PlanRequest, backend: RayBackend, cell: Cell | None = None
) -> tuple[Viewpoints, CandidateInfo]:
    """The request's candidates: generated (default generator) or the explicit list, where
    the setup (`cell`, else the request's) lets cameras be."""
    cell = cell_of(request, cell)
    spec = request.candidates
    if isinstance(spec, CandidateGenerator):
        settings = GeneratorSettings(
            spec.count,
            spec.seed,
            spec.decimate,
            spec.clearance_mm,
            spec.tilt_deg or 0.0,
            spec.retry_tilt_deg or 0.0,
            spec.standoff_mm,
            spec.roll == "fitted",
            bool(spec.tiles),
        )
        table = table_candidates(
            part,
            cell,
            CandidateInfo(source="generated", requested=spec.count, generated=0, seed=spec.seed),
        )
        if table is not None:  # a turntable: its grid of (angle, station) views
            return table
        gen = generate(part, request.sensor, settings, backend, allowed(cell))
        info = CandidateInfo(
            source="generated",
            requested=spec.count,
            generated=len(gen.views),
            dropped=gen.dropped,
            spacing_mm=gen.spacing_mm,
            planning_faces=gen.planning_faces,
            seed=spec.seed,
            decimate=spec.decimate,
            tilt_deg=spec.tilt_deg,
            retry_tilt_deg=spec.retry_tilt_deg,
            standoff_mm=gen.standoff_mm,
            roll=spec.roll,
            tiles=gen.tiles,
        )
        return reachable_candidates(part, cell, gen.views, info)  # the robot's, turned
    n = len(spec.viewpoints)
    info = CandidateInfo(source="explicit", requested=n, generated=n)
    views = explicit_viewpoints(spec.viewpoints)
    check_explicit(cell, views)
    check_reachable(part, cell, views)
    return views, info


def explicit_viewpoints(items: Sequence[ViewpointIn | CandidateOut]) -> Viewpoints:
    """Viewpoints from {position, gaze, up?} items (mm): a request's, or a plan's poses."""
    nan = [np.nan] * 3
    return make_viewpoints(
        np.array([v.position for v in items]).reshape(-1, 3),
        np.array([v.gaze for v in items]).reshape(-1, 3),
        np.array([v.up if v.up is not None else nan for v in items]).reshape(-1, 3),
    )


def check_limits(n_candidates: int, n_pixels: int, limits: Limits) -> None:
    """Raise LimitError when the candidates or the rays exceed the limits."""
    if n_candidates > limits.max_candidates:
        raise LimitError(f"{n_candidates} candidates exceed the limit of {limits.max_candidates}")
    if n_candidates * n_pixels > limits.max_rays:
        raise LimitError(
            f"{n_candidates} candidates × {n_pixels} pixels = {n_candidates * n_pixels} rays "
            f"exceed the limit of {limits.max_rays}"
        )


def check_request(request: PlanRequest, limits: Limits, cell: Cell | None = None) -> None:
    """Refuse, before any work, a request over the limits or with malformed explicit viewpoints
    or explicit viewpoints the setup forbids (`cell`; None: what needs no mesh of it)."""
    spec = request.candidates
    if isinstance(spec, CandidateGenerator):
        check_limits(spec.count, request.sensor.n_pixels, limits)
    else:
        check_limits(len(spec.viewpoints), request.sensor.n_pixels, limits)
        views = explicit_viewpoints(spec.viewpoints)  # ViewpointError now
        check_explicit(cell or resolve(request.setup, meshes=False), views)


def spent_s(timings: Timings) -> float:
    """Wall seconds the plan spent before its final cover (load, candidates, trace, adaptive,
    the cover's matrices). Not numba compiling the kernels on a fresh install (`compiling`,
    reported): a one-time cost of the machine, which would otherwise make a fresh install's
    first plan a worse one (the crankshaft stand-in: 34 s compiling left no adaptive round and
    9 s of cover, 29 views against 28; docs/quality.md)."""
    t = timings
    return t.load + t.candidates + t.trace + t.adaptive + t.matrices


def _left(settings: SolverSettings, timings: Timings) -> SolverSettings:
    """The solver settings for the final cover: the plan's time limit (the budget of the whole
    plan after loading) less what the stages before it spent and AFTER_SHARE for the stages
    after it; at least FINAL_SHARE of the limit."""
    limit = settings.time_limit_s
    left = limit * (1.0 - AFTER_SHARE) - spent_s(timings)
    return settings.model_copy(update={"time_limit_s": max(FINAL_SHARE * limit, left)})


def solve(
    model: CoverModel,
    target: Target,
    settings: SolverSettings,
    threads: int | None = None,
    costs: np.ndarray | None = None,
    mandatory: np.ndarray | None = None,
    points: PointJudge | None = None,
) -> PartialCover:
    """Cover the rows (all, or target.min_coverage of their area) as `settings` ask,
    columns at `costs` (N,) (None: one each); `mandatory` (rows,) rows (regions with their own
    target) are covered whatever min_coverage, which then applies to the other rows' area;
    with `points`, grown where it sees area the cover's views do not (pointseen.fill)."""
    area = model.row_weights()
    strict = np.zeros(len(area), bool) if mandatory is None else mandatory
    weights, fraction = mandatory_weights(area, strict, target.fraction)
    cover = solve_partial(
        model.matrix,
        weights,
        fraction,
        costs,
        method=settings.name,
        time_limit=settings.time_limit_s,
        mip_rel_gap=settings.mip_rel_gap,
        threads=threads,
    )
    if (
        target.formulation == "density"
        and target.rows == "patches"
        and target.fraction < SEEN_SHARE
    ):
        cover = seen_too(model, weights, cover, costs)  # what it leaves short is still seen
    if points is not None:
        cover = points.grow(model, weights, cover, costs)
    if weights is area:
        return cover
    required = target.fraction * float(area[~strict].sum()) + float(area[strict].sum())
    return replace(cover, required=required, achieved=float(area[cover.satisfied].sum()))


def seen_too(
    model: CoverModel, weights: np.ndarray, cover: PartialCover, costs: np.ndarray | None
) -> PartialCover:
    """`cover` (of model's rows, weighing `weights`) grown until SEEN_SHARE of the area is
    seen (vpp_core.cover.partial.seen_columns), then pruned of views both rules can spare."""
    c = np.ones(model.matrix.shape[1]) if costs is None else costs
    seen = (model.seen_rows(), model.row_weights(), SEEN_SHARE)
    more = seen_columns(*seen[:2], cover.result.selected, SEEN_SHARE, c)
    if len(more) == len(cover.result.selected):
        return cover
    kept = prune_seen(model.matrix, weights, cover.required, seen, more, c)
    return grown(model.matrix, weights, cover, kept, c)


def point_judge(
    part: Part, request: PlanRequest, rows: Rows, views: Viewpoints, backend: RayBackend
) -> PointJudge | None:
    """The judge of the default cover (density patch rows, a partial cover that is then seen
    whole: seen_too's), on the counted faces outside recessed patches; None otherwise."""
    t = request.target
    if t.formulation != "density" or t.rows != "patches" or t.fraction >= SEEN_SHARE:
        return None
    wanted = part.counted.copy()
    if rows.recessed is not None:
        wanted[_faces_of_patches(rows, rows.recessed)] = False
    if not (wanted & (part.areas > 0)).any():
        return None
    pts = surface_points(part, wanted)
    return PointJudge(request.sensor, views, pts, backend, SEEN_SHARE)


class _Clock:
    """Wall time per stage, reported to an optional progress callback."""

    def __init__(self, progress: Progress | None, timings: Timings | None = None) -> None:
        self.timings = timings or Timings()
        self.progress = progress

    @contextmanager
    def stage(self, name: str, total: int = 1) -> Iterator[None]:
        if self.progress:
            self.progress(name, 0, total)
        start = time.perf_counter()
        yield
        setattr(self.timings, name, round(time.perf_counter() - start, 4))


def plan(
    part: Part,
    request: PlanRequest,
    *,
    limits: Limits = Limits(),
    threads: int | None = None,
    progress: Progress | None = None,
    load_s: float = 0.0,
    cell: Cell | None = None,
) -> PlanDocument:
    """Plan the fewest viewpoints covering `part` as `request` asks (the whole pipeline), in
    the setup `cell` (its meshes read; else the request's setup, which must name none)."""
    clock = _Clock(progress)
    clock.timings.load = round(load_s, 4)
    cell = cell_of(request, cell)
    split = elements_of(part, request)
    backend = setup_backend(part, request, cell)  # candidates see the faces
    tracer = tracer_of(split, request, cell, backend)
    check_request(request, limits, cell)
    # stage `compiling` while numba compiles, on a fresh install; not counted in the budget
    clock.timings.compiling = round(warm(request.backend, progress), 4)
    with clock.stage("candidates"):
        views, info = candidates_for(part, request, backend, cell)
    check_limits(len(views), request.sensor.n_pixels, limits)
    with clock.stage("trace", len(views)):
        done = _counter(progress, "trace", len(views))
        trace = trace_counts(
            part,
            request.sensor,
            views,
            backend=tracer,
            threads=threads,
            progress=done,
            elements=split,
        )
    with clock.stage("adaptive"):
        spent = spent_s(clock.timings)
        views, info, trace, rounds = grow(
            part, request, views, info, trace, tracer, threads, cell=cell, spent_s=spent
        )
    return finish(
        part,
        request,
        views,
        info,
        trace,
        timings=clock.timings,
        threads=threads,
        progress=progress,
        backend=backend,
        rounds=rounds,
        cell=cell,
    )


def finish(
    part: Part,
    request: PlanRequest,
    views: Viewpoints,
    info: CandidateInfo,
    trace: Trace,
    *,
    timings: Timings | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
    reused: bool = False,
    backend: RayBackend | None = None,
    rounds: Sequence[AdaptiveRound] = (),
    cell: Cell | None = None,
) -> PlanDocument:
    """From R on: matrices, cover, visiting order, metrics, diagnostics and the document
    (with the setup `cell`, else the request's)."""
    clock = _Clock(progress, timings)
    cell = cell_of(request, cell)
    targets = targets_of(part, request)
    part = targets.part  # ignored faces not counted
    cameras = Cameras(views, request.sensor)
    with clock.stage("matrices"):
        rows = rows_of(targets.whole, request, trace, cell)
        own = rows_model(rows, request, trace, cameras)
    backend = backend or setup_backend(part, request, cell, trace.backend)
    with clock.stage("solve"):
        settings = _left(request.solver, clock.timings)
        must = rows.targets.region_rows(own.face_row, own.faces, own.matrix.shape[0])
        judge = point_judge(part, request, rows, views, backend)
        cover = solve(own, request.target, settings, threads, None, must, judge)
        cover, tour = by_objective(
            cover,
            request.objective,
            views.positions,
            lambda c: solve(own, request.target, settings, threads, c, must, judge),
        )
        model = own if rows.elements is None else own.lifted(rows.elements.parent)
    with clock.stage("metrics"):
        doc = document(
            part, request, views, info, trace, model, cover, clock.timings, tour, targets
        )
        doc.cover_rows = _cover_rows(part, rows, own, model, trace, cover.result.selected)
        if judge is not None and doc.partial is not None:
            doc.partial.points = judge.info(cover.result.selected)
    with clock.stage("diagnostics"):
        doc.diagnostics = diagnose(
            part,
            request.sensor,
            views,
            trace.counts,
            model,
            cover.result.selected,
            backend,
            partial=request.target.fraction < 1,
            normal_candidates=info.source == "generated" and not info.tilt_deg,
        )
    doc.timings_s = clock.timings
    doc.rays.reused = reused
    doc.adaptive = list(rounds)
    if cell is not None:
        free = request.model_copy(update={"setup": None})
        with clock.stage("setup"):
            annotate(doc, part, request, cell, views, trace, _generate(part, free))
        with clock.stage("robot"):
            annotate_robot(doc, part, request, cell)
    return doc


def _generate(part: Part, request: PlanRequest) -> Callable[[RayBackend], Viewpoints]:
    """backend -> the request's candidates traced on `backend`."""
    return lambda backend: candidates_for(part, request, backend)[0]


def grow(
    part: Part,
    request: PlanRequest,
    views: Viewpoints,
    info: CandidateInfo,
    trace: Trace,
    backend: RayBackend | None = None,
    threads: int | None = None,
    cell: Cell | None = None,
    *,
    spent_s: float = 0.0,
) -> tuple[Viewpoints, CandidateInfo, Trace, list[AdaptiveRound]]:
    """The candidate pool grown by the view sphere's views that reach new rows
    (vpp_core.plan.spherereach) and the adaptive rounds (vpp_core.plan.adaptive), its R and
    the rounds; unchanged when the request asks for neither. `backend`: over the part,
    or over its elements where `trace` is of them (made here when None). New cameras only where
    the setup (`cell`, else the request's) lets them be. `spent_s`: wall seconds the plan
    spent before (no round starts whose tracing would end past ADAPT_SHARE of the time
    limit, the rows' grouping here counted)."""
    began = time.perf_counter()  # the rows' grouping counts in the rounds' budget
    cell = cell_of(request, cell)
    rows = rows_of(part, request, trace, cell)
    split = rows.elements
    geometry = split.part if split else part

    def model_of(vs: Viewpoints, tr: Trace) -> CoverModel:
        return rows_model(rows, request, tr, Cameras(vs, request.sensor))

    def quick(model: CoverModel, seconds: float) -> PartialCover:
        settings = request.solver.model_copy(update={"name": "greedy", "time_limit_s": seconds})
        must = rows.targets.region_rows(model.face_row, model.faces, model.matrix.shape[0])
        return solve(model, request.target, settings, threads, None, must)

    def trace_at(vs: Viewpoints, sensor: Sensor) -> Trace:
        return trace_counts(part, sensor, vs, backend=backend, threads=threads, elements=split)

    def trace_of(vs: Viewpoints) -> Trace:
        return trace_at(vs, request.sensor)

    backend = backend or setup_backend(geometry, request, cell, trace.backend)
    tally: Counter[str] = Counter()  # the robot's drops in the rounds
    deadline = began + ADAPT_SHARE * request.solver.time_limit_s - spent_s
    keep, cameras_allowed = reachable_filter(part, cell, tally), allowed(cell)
    spec = request.candidates
    sphere = (spec.sphere or 0) if isinstance(spec, CandidateGenerator) else 0
    reached = sphere_reach(
        part,
        request.sensor,
        views,
        trace,
        sphere,
        model_of,
        trace_at,
        allowed=cameras_allowed,
        keep=keep,
        deadline=deadline,
        fit_roll=isinstance(spec, CandidateGenerator) and spec.roll == "fitted",
    )
    info = info.model_copy(update={"sphere": reached.added, "sphere_traced": reached.traced})
    views, trace = reached.views, reached.trace
    pool = adapt(
        geometry,
        request,
        views,
        trace,
        backend,
        model_of,
        quick,
        trace_of,
        allowed=cameras_allowed,
        deadline=deadline,
        keep=keep,
    )
    added = len(pool.views) - len(views)
    info = counted(info.model_copy(update={"added": added}), tally)
    return pool.views, info, pool.trace, pool.rounds


def _cover_rows(
    part: Part, rows: Rows, own: CoverModel, model: CoverModel, trace: Trace, chosen: np.ndarray
) -> CoverRows:
    """What the cover's rows were, what the plan samples of the patches' area (met: Σ S ≥ 1
    over the chosen views, S as the cover's rows count it), and the faces hit only by rays
    too few to sample them: `own` the cover's model in the rows' ids, `model` in face ids."""
    patches = rows.patches
    if patches is None:
        return CoverRows(kind="faces", count=int(part.counted.sum()))
    unsampled = np.setdiff1d(model.uncoverable, spec_uncoverable(part, trace))
    patch_of_row = np.zeros(own.matrix.shape[0], dtype=np.int64)
    patch_of_row[own.face_row] = patches.of_face[own.faces]
    mine = sp.csr_array(own.matrix[:, chosen])
    met = np.zeros(patches.count, dtype=bool)  # a row short of δ̄ holds V: never met
    met[patch_of_row] = own.density_rows & meets(mine.sum(axis=1), 1.0)
    sampled = np.zeros(patches.count, dtype=bool)
    sampled[patch_of_row] = np.diff(mine.indptr) > 0
    by_any = np.zeros(patches.count, dtype=bool)
    by_any[patch_of_row] = True
    total = patches.areas.sum()
    recessed = np.zeros(patches.count, dtype=bool) if rows.recessed is None else rows.recessed
    return CoverRows(
        kind="patches",
        count=patches.count,
        edge_mm=patches.edge_mm,
        element_mm2=None if rows.elements is None else rows.elements.max_area_mm2,
        sampled_area=float(patches.areas[sampled].sum() / total),
        max_sampled_area=float(patches.areas[by_any].sum() / total),
        met_area=float(patches.areas[met].sum() / total),
        patch_of_face=patches.of_face.tolist(),
        unsampled=_uncoverable(part, unsampled),
        recessed=_uncoverable(part, _faces_of_patches(rows, recessed & by_any & ~met)),
        recessed_area=float(patches.areas[recessed].sum() / total),
    )


def _faces_of_patches(rows: Rows, chosen: np.ndarray) -> np.ndarray:
    """Ascending faces of the part in the patches `chosen` (P,) bool (the faces the elements
    of those patches belong to, where the rows are elements)."""
    assert rows.patches is not None
    faces = rows.patches.faces_of(np.flatnonzero(chosen))
    return faces if rows.elements is None else np.unique(rows.elements.parent[faces])


def spec_uncoverable(part: Part, trace: Trace) -> np.ndarray:
    """Counted faces that no candidate's ray hits (SPEC §3), ascending."""
    seen = np.diff(sp.csr_array(trace.counts).indptr) > 0
    return np.flatnonzero(part.counted & ~seen)


@dataclass(frozen=True, eq=False)
class Rows:
    """What the cover's rows are made of: the part's faces or, where the trace is of its area
    elements, the elements; each with its target, grouped into patches (None: face rows)."""

    targets: FaceTargets  # of the faces, or of the elements
    patches: Patches | None
    elements: Elements | None
    recessed: np.ndarray | None = None  # (P,) bool recessed patches (vpp_core.cover.access)

    def counts(self, trace: Trace) -> sp.csc_array:
        """R of the rows' faces or elements."""
        return trace.counts if self.elements is None else sp.csc_array(trace.elements)


def rows_of(part: Part, request: PlanRequest, trace: Trace, cell: Cell | None = None) -> Rows:
    """The rows of `request`'s cover of `part` (as loaded) for R `trace`: patches of the
    elements it was traced on (Trace.element_mm2), else of the faces, or the faces; the
    recessed patches among them, with the setup `cell`'s floor and fixtures."""
    targets = targets_of(part, request)
    split = None
    patches = request.target.rows == "patches"
    if patches and trace.elements is not None and trace.element_mm2 is not None:
        split = _elements(part, trace.element_mm2)
        targets = _element_targets(targets, split)
    grouped = cover_patches(targets.part, request.target, targets)
    if grouped is None or not request.target.open_min:
        return Rows(targets, grouped, split)
    open_min = request.target.open_min
    counts = _openness(targets.part, grouped, request.sensor, cell, open_min)
    return Rows(targets, grouped, split, counts < open_min)


def rows_model(rows: Rows, request: PlanRequest, trace: Trace, cameras: Cameras) -> CoverModel:
    """The cover model of `rows` for R `trace` of the `cameras` (in element ids where the
    rows are elements: CoverModel.lifted gives it in face ids)."""
    t = rows.targets
    return cover_model(
        rows.counts(trace),
        t.part.areas,
        t.part.counted,
        t.resolution_mm,
        request.target.formulation,
        rows.patches,
        t.ignored,
        cameras,
        recessed=rows.recessed,
    )


def elements_of(part: Part, request: PlanRequest) -> Elements | None:
    """The area elements `request`'s rows are made of (patch rows): the faces of `part` larger
    than element_area split; None for face rows or where no face is that large."""
    if request.target.rows != "patches":
        return None
    split = _elements(part, element_area(part, request.target.resolution_mm))
    return split if len(split.parent) > part.n_faces else None


def tracer_of(
    split: Elements | None, request: PlanRequest, cell: Cell | None, backend: RayBackend
) -> RayBackend:
    """The backend the trace casts into: over the elements `split` (and the setup's floor and
    fixtures) where the rows are made of them, else `backend`, the faces'."""
    return setup_backend(split.part, request, cell) if split else backend


def element_area(part: Part, resolution_mm: float) -> float:
    """The largest element area (mm²) for target r̄ (mm): a patch's area / ELEMENTS_PER_PATCH,
    doubled until the split gives at most MAX_ELEMENTS (or the part's own faces)."""
    area = float(part.areas[part.counted].sum())
    limit = patch_edge(resolution_mm, area) ** 2 / ELEMENTS_PER_PATCH
    while True:
        try:
            _elements(part, limit)  # the split that fits is cached for elements_of
        except LimitError:
            limit *= 2
        else:
            return limit


@lru_cache(maxsize=2)
def _elements(part: Part, max_area_mm2: float) -> Elements:
    """`part` split into elements of at most `max_area_mm2`, at most MAX_ELEMENTS (or the
    part's own faces; LimitError past them, found while splitting), cached: element_area,
    the trace, the adaptive rounds and the final cover ask for the same."""
    return elements(part, max_area_mm2, max_faces=max(MAX_ELEMENTS, part.n_faces))


@lru_cache(maxsize=2)
def _element_targets(targets: FaceTargets, split: Elements) -> FaceTargets:
    """The face `targets` on the elements `split` (cached, so that their patches are too)."""
    return targets.of_elements(split)


def cover_patches(part: Part, target: Target, targets: FaceTargets | None = None) -> Patches | None:
    """The patches the cover's rows are made of, or None for one row per face (target.rows);
    with regions (`targets`), faces of different targets never share a patch and each
    region's patches are sized by its own target."""
    if target.rows == "faces":
        return None
    area = float(part.areas[part.counted].sum())
    edge = patch_edge(target.resolution_mm, area)
    smooth = SMOOTH_TARGETS * target.resolution_mm
    if targets is None or targets.uniform:
        return _patches(part, edge, smooth, None)
    return _patches(part, edge, smooth, targets)


@lru_cache(maxsize=2)
def _openness(
    part: Part, patches: Patches, sensor: Sensor, cell: Cell | None, enough: int
) -> np.ndarray:
    """vpp_core.cover.access.openness with the setup `cell`'s floor and fixtures, cached: the
    adaptive rounds and the final cover ask for the same."""
    occluders = scene_occluders(part, sensor, cell)
    return openness(part, patches, sensor.max_incidence_deg, occluders, enough)


@lru_cache(maxsize=2)
def _patches(part: Part, edge_mm: float, smooth_mm: float, targets: FaceTargets | None) -> Patches:
    """The part's patches of `edge_mm` (per region with `targets`), normals smoothed within
    `smooth_mm`, split into connected pieces, grouped once: the adaptive rounds, the final
    cover and each row of a study ask for the same ones (3.7 s on turbineblade's 199 k faces)."""
    centres = part.vertices[part.faces].mean(axis=1)
    args = (centres, part.normals, part.areas, part.counted, edge_mm, smooth_mm, part.faces)
    if targets is None:
        return make_patches(*args)
    groups = targets.groups()
    area = float(part.areas[part.counted].sum())
    first = np.unique(groups, return_index=True)[1]
    edges = np.array([_region_edge(targets, f, area) for f in first])
    return make_patches(*args, groups=groups, group_edges=edges)


def _region_edge(targets: FaceTargets, face: int, area_mm2: float) -> float:
    """Patch edge (mm) of the group of `face`: the default target's patch_edge; a region with
    its own target the smallest patches, MIN_PATCH_TARGETS · r̄ (its target is met face by
    face about as well as patches allow: plate_holes' bore at 0.1 mm on 32 r̄ patches was met
    on 90 % of its area, on 5 r̄ patches on 100 %), within MAX_PATCHES."""
    r = float(targets.resolution_mm[face])
    if targets.region[face] < 0:
        return patch_edge(r, area_mm2)
    return float(max(MIN_PATCH_TARGETS * r, np.sqrt(area_mm2 / MAX_PATCHES)))


def targets_of(part: Part, request: PlanRequest) -> FaceTargets:
    """Each face's target and region for `request` (cached: grow and finish ask alike)."""
    regions = json.dumps([r.model_dump(mode="json") for r in request.regions])
    return _targets(part, request.target.resolution_mm, regions)


@lru_cache(maxsize=4)
def _targets(part: Part, default_mm: float, regions: str) -> FaceTargets:
    """face_targets for the regions given as JSON (hashable, for the cache)."""
    return face_targets(part, default_mm, [Region.model_validate(r) for r in json.loads(regions)])


def _counter(progress: Progress | None, stage: str, total: int) -> Callable[[int], None]:
    """A per-viewpoint callback that forwards running totals to `progress`."""
    state = [0]

    def advance(n: int) -> None:
        state[0] += n
        if progress:
            progress(stage, state[0], total)

    return advance


def document(
    part: Part,
    request: PlanRequest,
    views: Viewpoints,
    info: CandidateInfo,
    trace: Trace,
    model: CoverModel,
    cover: PartialCover,
    timings: Timings,
    tour: TourOut | None = None,
    targets: FaceTargets | None = None,
) -> PlanDocument:
    """Assemble the plan document from the stages' results (`tour`: the cover's, else made;
    `targets`: each face's target, with regions)."""
    result = cover.result
    tour = tour or make_tour(views.positions, result.selected, request.objective)
    chosen = np.asarray(tour.order, dtype=np.int64)
    default = request.target.resolution_mm
    per_face = default if targets is None else targets.resolution_mm
    metrics = evaluate(trace.counts, part.areas, part.counted, chosen, per_face, default)
    info_regions = None
    if targets is not None and request.regions:
        members = region_members(targets, request.regions, default)
        metrics.regions = region_metrics(
            trace.counts, part.areas, targets.whole.counted, chosen, members
        )
        info_regions = regions_info(targets, request)
    return PlanDocument(
        mesh=mesh_info(part if targets is None else targets.whole),
        regions=info_regions,
        sensor=request.sensor,
        target=request.target,
        candidates=_poses(views, np.arange(len(views)), CandidateOut),
        candidate_info=info,
        viewpoints=_poses(views, chosen, ViewpointOut),
        tour_length_mm=path_length(views.positions, chosen),
        tour=tour,
        solver=SolverOut(
            name=result.solver,
            status=result.status,
            objective=result.objective,
            bound=result.bound,
            gap=result.gap,
            time_s=result.time_s,
            rows=result.rows,
            cols=result.cols,
        ),
        metrics=metrics,
        uncoverable=_uncoverable(part, spec_uncoverable(part, trace)),
        partial=_partial_info(model, cover, request.target.fraction),
        rays=RaysInfo(
            backend=trace.backend,
            per_view=request.sensor.n_pixels,
            pixels=trace.pixels,
            cast=trace.rays_cast,
            valid=int(trace.counts.sum()),
            cast_per_s=trace.rays_cast / max(trace.seconds, 1e-9),
            trace_s=round(trace.seconds, 4),
        ),
        timings_s=timings,
    )


def _uncoverable(part: Part, faces: np.ndarray) -> Uncoverable:
    """The document's record of the faces `faces`."""
    return Uncoverable(
        faces=len(faces), area_mm2=float(part.areas[faces].sum()), ids=faces.tolist()
    )


def mesh_info(part: Part) -> MeshInfo:
    """The document's summary of the part planned on."""
    return MeshInfo(
        id=part.id,
        faces=part.n_faces,
        area_mm2=part.area_mm2,
        counted_faces=int(part.counted.sum()),
        warnings=list(part.warnings),
    )


def _partial_info(model: CoverModel, cover: PartialCover, fraction: float) -> PartialInfo | None:
    """The partial cover's figures, or None for the strict cover (`model` in face ids: a
    face is left out where some row it lies in is)."""
    if fraction >= 1.0:
        return None
    weights = model.row_weights()
    left_rows = ~cover.satisfied & (weights > 0)
    left = model.faces_of(left_rows)
    total = float(weights.sum())
    left_area = float(weights[left_rows].sum())
    seen = float(weights[coverage(model.seen_rows(), cover.result.selected) > 0].sum())
    return PartialInfo(
        min_coverage=fraction,
        coverable_area_mm2=total,
        covered_area_mm2=cover.achieved,
        covered_fraction=cover.achieved / total if total > 0 else 1.0,
        left_out=LeftOut(faces=len(left), area_mm2=left_area, ids=left.tolist()),
        seen_area_mm2=seen,
        seen_fraction=seen / total if total > 0 else 1.0,
    )


def _poses(views: Viewpoints, index: np.ndarray, cls: type) -> list:  # type: ignore[type-arg]
    """Pose records for the views at `index` (ids are candidate indices)."""
    c2w = views.camera_to_world()
    out = []
    for j in index:
        rec = dict(
            id=int(j),
            position=views.positions[j].tolist(),
            gaze=views.gazes[j].tolist(),
            up=views.ups[j].tolist(),
        )
        if cls is ViewpointOut:
            rec["camera_to_world"] = c2w[j].tolist()
        out.append(cls(**rec))
    return out
