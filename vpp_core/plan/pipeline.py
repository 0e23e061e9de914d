"""The pipeline, stage by stage: part → candidates → R → S (or V) → cover → plan document."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.candidates.generator import GeneratorSettings, generate
from vpp_core.cover.density import CoverModel, cover_model
from vpp_core.cover.partial import PartialCover, solve_partial
from vpp_core.errors import LimitError
from vpp_core.mesh.part import Part
from vpp_core.plan.cycle import TourOut, make_tour
from vpp_core.plan.diagnostics import diagnose
from vpp_core.plan.document import (
    CandidateGenerator,
    CandidateInfo,
    CandidateOut,
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
from vpp_core.plan.metrics import evaluate
from vpp_core.plan.objective import by_objective
from vpp_core.plan.tour import path_length
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import Trace, make_backend, trace_counts

Progress = Callable[[str, int, int], None]
"""progress(stage, done, total): called as stages start and as viewpoints are traced."""


@dataclass(frozen=True)
class Limits:
    """Caps on the work one plan may ask for."""

    max_candidates: int = 5_000
    max_rays: int = 20_000_000_000


def candidates_for(
    part: Part, request: PlanRequest, backend: RayBackend
) -> tuple[Viewpoints, CandidateInfo]:
    """The request's candidates: generated (default generator) or the explicit list."""
    spec = request.candidates
    if isinstance(spec, CandidateGenerator):
        settings = GeneratorSettings(
            spec.count, spec.seed, spec.decimate, spec.clearance_mm, spec.tilt_deg
        )
        gen = generate(part, request.sensor, settings, backend)
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
        )
        return gen.views, info
    n = len(spec.viewpoints)
    info = CandidateInfo(source="explicit", requested=n, generated=n)
    return explicit_viewpoints(spec.viewpoints), info


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


def check_request(request: PlanRequest, limits: Limits) -> None:
    """Refuse, before any work, a request over the limits or with malformed explicit viewpoints."""
    spec = request.candidates
    if isinstance(spec, CandidateGenerator):
        check_limits(spec.count, request.sensor.n_pixels, limits)
    else:
        check_limits(len(spec.viewpoints), request.sensor.n_pixels, limits)
        explicit_viewpoints(spec.viewpoints)  # ViewpointError now


def solve(
    model: CoverModel,
    areas: np.ndarray,
    target: Target,
    settings: SolverSettings,
    threads: int | None = None,
    costs: np.ndarray | None = None,
) -> PartialCover:
    """Cover the rows (all, or target.min_coverage of their area (M,) mm²) as `settings` ask,
    columns at `costs` (N,) (None: one each)."""
    return solve_partial(
        model.matrix,
        areas[model.faces],
        target.min_coverage,
        costs,
        method=settings.name,
        time_limit=settings.time_limit_s,
        mip_rel_gap=settings.mip_rel_gap,
        threads=threads,
    )


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
    backend: RayBackend | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
    load_s: float = 0.0,
) -> PlanDocument:
    """Plan the fewest viewpoints covering `part` as `request` asks (the whole pipeline)."""
    clock = _Clock(progress)
    clock.timings.load = round(load_s, 4)
    backend = backend or make_backend(part, request.backend)
    check_request(request, limits)
    with clock.stage("candidates"):
        views, info = candidates_for(part, request, backend)
    check_limits(len(views), request.sensor.n_pixels, limits)
    with clock.stage("trace", len(views)):
        done = _counter(progress, "trace", len(views))
        trace = trace_counts(
            part, request.sensor, views, backend=backend, threads=threads, progress=done
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
) -> PlanDocument:
    """From R on: matrices, cover, visiting order, metrics, diagnostics and the document."""
    clock = _Clock(progress, timings)
    with clock.stage("matrices"):
        model = cover_model(
            trace.counts,
            part.areas,
            part.counted,
            request.target.resolution_mm,
            request.target.formulation,
        )
    with clock.stage("solve"):
        cover = solve(model, part.areas, request.target, request.solver, threads)
        cover, tour = by_objective(
            cover,
            request.objective,
            views.positions,
            lambda c: solve(model, part.areas, request.target, request.solver, threads, c),
        )
    with clock.stage("metrics"):
        doc = document(part, request, views, info, trace, model, cover, clock.timings, tour)
    with clock.stage("diagnostics"):
        doc.diagnostics = diagnose(
            part,
            request.sensor,
            views,
            trace.counts,
            model.matrix,
            model.faces,
            cover.result.selected,
            backend or make_backend(part, trace.backend),
            partial=request.target.min_coverage < 1,
            normal_candidates=info.source == "generated" and not info.tilt_deg,
        )
    doc.timings_s = clock.timings
    doc.rays.reused = reused
    return doc


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
) -> PlanDocument:
    """Assemble the plan document from the stages' results (`tour`: the cover's, else made)."""
    result = cover.result
    tour = tour or make_tour(views.positions, result.selected, request.objective)
    chosen = np.asarray(tour.order, dtype=np.int64)
    metrics = evaluate(trace.counts, part.areas, part.counted, chosen, request.target.resolution_mm)
    return PlanDocument(
        mesh=mesh_info(part),
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
        uncoverable=Uncoverable(
            faces=len(model.uncoverable),
            area_mm2=float(part.areas[model.uncoverable].sum()),
            ids=model.uncoverable.tolist(),
        ),
        partial=_partial_info(part, model, cover, request.target.min_coverage),
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


def mesh_info(part: Part) -> MeshInfo:
    """The document's summary of the part planned on."""
    return MeshInfo(
        id=part.id,
        faces=part.n_faces,
        area_mm2=part.area_mm2,
        counted_faces=int(part.counted.sum()),
        warnings=list(part.warnings),
    )


def _partial_info(
    part: Part, model: CoverModel, cover: PartialCover, fraction: float
) -> PartialInfo | None:
    """The partial cover's figures, or None for the strict cover."""
    if fraction >= 1.0:
        return None
    areas = part.areas[model.faces]
    left = model.faces[~cover.satisfied]
    total = float(areas.sum())
    return PartialInfo(
        min_coverage=fraction,
        coverable_area_mm2=total,
        covered_area_mm2=cover.achieved,
        covered_fraction=cover.achieved / total if total > 0 else 1.0,
        left_out=LeftOut(
            faces=len(left), area_mm2=float(part.areas[left].sum()), ids=left.tolist()
        ),
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
