"""Good plans by default (issue 33): stand-off, patch rows, stray rays, profiles, adaptive
candidates and the view-sphere baseline, each against a direct computation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from tests.conftest import bench_module, look_down
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import STANDOFF_MARGIN, standoff_for
from vpp_core.candidates.sphere import fibonacci_directions, view_sphere
from vpp_core.cover.density import STRAY_RAYS, Cameras, cover_model, stray_free
from vpp_core.cover.patches import make_patches
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays
from vpp_core.plan.document import CandidateGenerator, PlanRequest, SolverSettings, Target
from vpp_core.samples import sample_stl
from vpp_core.trace.raytrace import trace_counts

PAPER = Sensor()
SMALL = Sensor(width_px=320, height_px=200, fov_x_deg=38.7, fov_y_deg=24.75)
QUICK_GAP = 0.5
"""Relative gap at which the final cover may stop, where a test is about the adaptive rounds
and not the final cover: it then ends at its first cover within half its bound."""


def test_the_standoff_puts_a_pixel_at_the_target_over_the_margin():
    d = standoff_for(PAPER, 0.18)
    assert PAPER.near_mm < d < PAPER.working_distance
    assert PAPER.pixel_pitch_mm(d) == pytest.approx(0.18 / STANDOFF_MARGIN, rel=1e-9)
    assert standoff_for(PAPER, 5.0) == PAPER.working_distance  # coarse: the preference
    unreachable = standoff_for(PAPER, 0.01)  # finer than any depth allows: as near as DOF lets
    assert unreachable == pytest.approx(PAPER.near_mm + 0.1 * (PAPER.far_mm - PAPER.near_mm))


def thin_plate() -> Part:
    """A 40 × 30 × 0.5 mm plate: its two large sides face away from each other 0.5 mm apart."""
    box = trimesh.creation.box([40, 30, 0.5])
    vertices, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=1.2)
    return part_from_arrays(vertices, faces)


def patches_of(part: Part, edge: float):
    centres = part.vertices[part.faces].mean(axis=1)
    return make_patches(centres, part.normals, part.areas, part.counted, edge)


def test_patches_partition_the_surface_and_never_join_opposite_sides():
    part = thin_plate()
    patches = patches_of(part, 3.0)
    counted = part.counted
    assert (patches.of_face[counted] >= 0).all() and (patches.of_face[~counted] == -1).all()
    assert patches.areas.sum() == pytest.approx(part.areas[counted].sum())
    for p in range(patches.count):
        faces = np.flatnonzero(patches.of_face == p)
        normals = part.normals[faces]
        assert (normals @ normals[0] > 0).all()  # one side of the plate only
        centres = part.vertices[part.faces[faces]].mean(axis=1)
        assert np.ptp(centres, axis=0).max() <= 4 * 3.0  # about one edge across
    top = part.normals[:, 2] > 0.9
    assert patches.areas.sum() / patches.count == pytest.approx(3.0**2, rel=0.4)  # edge²
    assert len(np.unique(patches.of_face[top])) >= (40 * 30) / (2 * 3.0) ** 2


def test_patch_rows_sum_r_and_area_and_drop_stray_rays():
    part = thin_plate()
    patches = patches_of(part, 3.0)
    rng = np.random.default_rng(0)
    r = rng.integers(0, 6, (part.n_faces, 7)) * (rng.random((part.n_faces, 7)) < 0.3)
    summed = patches.sum_rows(sp.csc_array(r)).toarray()
    for p in range(0, patches.count, 7):
        assert (summed[p] == r[patches.of_face == p].sum(axis=0)).all()
    clean = stray_free(sp.csr_array(summed)).toarray()
    assert (clean == np.where(summed >= STRAY_RAYS, summed, 0)).all()
    model = cover_model(sp.csc_array(r), part.areas, part.counted, 0.5, "density", patches)
    areas = model.row_areas()
    assert areas.sum() == pytest.approx(part.areas[model.faces].sum())
    delta = np.sqrt(clean / patches.areas[:, None])  # the patch density, written out
    rows = np.flatnonzero(clean.any(axis=1))
    dense = delta[rows].sum(axis=1) >= 1 / 0.5
    s = np.where(dense[:, None], np.minimum(1, delta[rows] * 0.5), clean[rows] > 0)
    assert np.allclose(model.matrix.toarray(), s)
    assert set(model.uncoverable) == set(np.flatnonzero(~clean.any(axis=1)[patches.of_face]))


def test_the_paper_profile_is_spec_2_and_the_default_fills_its_own():
    paper = PlanRequest(profile="paper")
    spec = paper.candidates
    assert isinstance(spec, CandidateGenerator)
    assert (spec.tilt_deg, spec.retry_tilt_deg, spec.adaptive) == (0, 0, False)
    assert spec.standoff_mm == PAPER.working_distance and paper.target.rows == "faces"
    default = PlanRequest()
    spec = default.candidates
    assert isinstance(spec, CandidateGenerator)
    assert spec.tilt_deg == 30 and spec.retry_tilt_deg == 60 and spec.adaptive
    assert spec.standoff_mm == pytest.approx(standoff_for(PAPER, 0.18))
    assert default.target.rows == "patches"
    mixed = PlanRequest(profile="paper", candidates={"tilt_deg": 20}, target={"rows": "patches"})
    assert mixed.candidates.tilt_deg == 20 and mixed.target.rows == "patches"  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="depth of field"):
        PlanRequest(candidates={"standoff_mm": 900})
    assert (default.candidates.sphere, paper.candidates.sphere) == (200, 0)  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="less than or equal to 1000"):
        PlanRequest(candidates={"sphere": 1001})  # the tracing stays bounded


def test_paper_candidates_stand_at_the_working_distance_along_the_normal():
    from vpp_core.plan.pipeline import candidates_for
    from vpp_core.trace.raytrace import make_backend

    part = load_mesh(sample_stl(), "stl")
    request = PlanRequest(profile="paper", candidates={"count": 60})
    backend = make_backend(part)
    views, _ = candidates_for(part, request, backend)
    for c, g in zip(views.positions, views.gazes, strict=True):
        prim, t = backend.first_hits(c, g[None, :].astype(np.float32), 1e4)
        assert prim[0] >= 0 and t[0] == pytest.approx(PAPER.working_distance, rel=0.05)
        normal = part.normals[prim[0]]
        assert abs(normal @ g) > np.cos(np.radians(60))  # looking back along a smoothed normal


def test_default_candidates_reach_what_the_view_sphere_reaches():
    from vpp_core.plan.metrics import evaluate
    from vpp_core.plan.pipeline import candidates_for
    from vpp_core.trace.raytrace import make_backend

    part = load_mesh(sample_stl(), "stl")
    backend = make_backend(part)
    request = PlanRequest(sensor=SMALL, target={"resolution_mm": 1.2}, candidates={"count": 150})
    views, info = candidates_for(part, request, backend)
    sphere = view_sphere(part, SMALL, 1000)
    reach = []
    for v in (views, sphere):
        counts = trace_counts(part, SMALL, v, backend=backend).counts
        every = np.arange(len(v))
        reach.append(evaluate(counts, part.areas, part.counted, every, 1.2).coverage.max_area)
    assert reach[0] >= reach[1] - 0.005, reach
    assert info.dropped == 0  # retries instead of drops


def test_view_sphere_directions_are_even_and_look_at_the_part():
    d = fibonacci_directions(500)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert np.abs(d.mean(axis=0)).max() < 0.01
    part = load_mesh(sample_stl(), "stl")
    views = view_sphere(part, PAPER, 100)
    centre = part.bounds.mean(axis=0)
    to_centre = centre - views.positions
    to_centre /= np.linalg.norm(to_centre, axis=1, keepdims=True)
    assert np.allclose(np.einsum("ij,ij->i", to_centre, views.gazes), 1)


def toy_model(areas: list[float], entries: list[tuple[int, int]]):
    """A CoverModel with one face per row (rows' areas `areas`, mm²) and columns sampling rows
    as (row, col) `entries`."""
    from vpp_core.cover.density import CoverModel

    rows, cols = zip(*entries, strict=True)
    shape = (len(areas), max(cols) + 1)
    matrix = sp.csr_array((np.full(len(entries), 0.5), (rows, cols)), shape=shape)
    ids = np.arange(len(areas))
    return CoverModel(matrix, ids, ids, np.ones(len(areas), bool), ids[:0], np.array(areas))


def test_sphere_views_join_for_the_rows_the_pool_does_not_sample_greedily():
    from vpp_core.plan.spherereach import new_reach

    # the pool (columns 0-1) samples rows 0-1; rows 2-4 are new; median row area 10 mm²
    areas = [10.0, 10.0, 10.0, 12.0, 3.0]
    pool = [(0, 0), (1, 1)]
    # new column 2 sees a known row only, 3 row 2, 4 rows 2-3, 5 row 4 alone (3 mm² < 10)
    sphere = [(0, 2), (2, 3), (2, 4), (3, 4), (4, 5)]
    assert new_reach(toy_model(areas, pool + sphere), 2).tolist() == [2]  # column 4: 22 mm²
    # once column 4 is in, column 3 adds nothing; column 5 joins for 30 mm², first
    bigger = toy_model([10.0, 10.0, 10.0, 12.0, 30.0], pool + sphere)
    assert new_reach(bigger, 2).tolist() == [2, 3]
    everything = [(0, 0), (1, 1), (2, 1), (3, 0), (4, 0)]  # a pool that samples every row
    assert new_reach(toy_model(areas, everything + sphere), 2).size == 0


def test_sphere_views_are_scouted_at_a_quarter_of_the_pixels_and_counted_as_whole_images():
    from vpp_core.plan.spherereach import SCOUT_SCALE, as_full_image, scout_sensor

    part = load_mesh(sample_stl(), "stl")
    views = view_sphere(part, SMALL, 12)
    assert SMALL.camera_rays.shape[0] == SMALL.n_pixels  # cached: the scout needs its own
    scout = scout_sensor(SMALL)
    assert (scout.width_px, scout.height_px) == (320 // SCOUT_SCALE, 200 // SCOUT_SCALE)
    assert scout.camera_rays.shape[0] == scout.n_pixels == SMALL.n_pixels // SCOUT_SCALE**2
    assert (scout.fov_x_deg, scout.near_mm, scout.far_mm) == (38.7, SMALL.near_mm, SMALL.far_mm)
    full = trace_counts(part, SMALL, views).counts.toarray().astype(float)
    scouted = as_full_image(trace_counts(part, scout, views), SCOUT_SCALE**2)
    coarse = scouted.counts.toarray().astype(float)
    # each view's rays on the part, and on each eighth of it (octants about its centre) that
    # it sees well, agree within 5 and 10 %
    np.testing.assert_allclose(coarse.sum(axis=0), full.sum(axis=0), rtol=0.05)
    centres = part.vertices[part.faces].mean(axis=1)
    side = (centres > centres.mean(axis=0)) @ np.array([1, 2, 4])
    eighths = sp.csr_array((np.ones(len(side)), (side, np.arange(len(side)))), shape=(8, len(side)))
    whole, scout_eighths = eighths @ full, eighths @ coarse
    big = whole > 500
    assert big.sum() >= 20
    np.testing.assert_allclose(scout_eighths[big], whole[big], rtol=0.1)


def test_a_default_plans_pool_gains_the_sphere_views_that_see_what_it_does_not():
    # six generated candidates leave most of the bushing unseen: the sphere views that sample
    # surface none of them samples join, after them and before the adaptive rounds' views
    from vpp_core.plan.pipeline import explicit_viewpoints, plan

    part = load_mesh(sample_stl(), "stl")
    spec = CandidateGenerator(count=6, seed=2, adaptive=False)
    request = PlanRequest(sensor=SMALL, target=Target(resolution_mm=1.2), candidates=spec)
    doc = plan(part, request)
    info = doc.candidate_info
    assert info.sphere_traced == 200 and 0 < info.sphere < 200
    assert len(doc.candidates) == info.generated + info.sphere
    counts = trace_counts(part, SMALL, explicit_viewpoints(doc.candidates)).counts.toarray()
    hit = counts > 0
    known = hit[:, : info.generated].any(axis=1)
    for j in range(info.generated, len(doc.candidates)):  # each samples faces the pool does not
        assert part.areas[hit[:, j] & ~known].sum() > 0, j
    none = plan(
        part, request.model_copy(update={"candidates": spec.model_copy(update={"sphere": 0})})
    )
    assert none.candidate_info.sphere == none.candidate_info.sphere_traced == 0
    assert len(none.candidates) == info.generated
    assert doc.metrics.coverage.max_area > none.metrics.coverage.max_area


def bushing_request(time_limit_s: float, adaptive: bool = True, gap: float = 0.0) -> PlanRequest:
    """A plan of the sample bushing under SMALL at 1.2 mm from 30 candidates (seed 2); the
    final cover stops within `gap` (relative) of its bound."""
    return PlanRequest(
        sensor=SMALL,
        target=Target(resolution_mm=1.2),
        candidates=CandidateGenerator(count=30, seed=2, adaptive=adaptive),
        solver=SolverSettings(time_limit_s=time_limit_s, mip_rel_gap=gap),
    )


def test_adaptive_rounds_add_traced_candidates_and_are_reported():
    from vpp_core.plan.pipeline import plan

    part = load_mesh(sample_stl(), "stl")
    request = bushing_request(2)
    doc = plan(part, request)
    info = doc.candidate_info
    assert doc.adaptive and doc.adaptive[0].candidates == info.generated + info.sphere
    assert len(doc.candidates) == info.generated + info.sphere + info.added
    assert info.added == sum(r.added - r.removed for r in doc.adaptive)
    for before, after in zip(doc.adaptive, doc.adaptive[1:], strict=False):
        assert after.candidates == before.candidates + before.added
    fixed = CandidateGenerator(count=30, seed=2, adaptive=False)
    off = plan(part, PlanRequest(**{**request.model_dump(), "candidates": fixed.model_dump()}))
    assert not off.adaptive
    assert len(off.candidates) == off.candidate_info.generated + off.candidate_info.sphere


def script_quick_counts(monkeypatch: pytest.MonkeyPatch, counts: list[int]) -> list[int]:
    """The adaptive rounds' quick covers (greedy) answer `counts` views in turn, the rest of
    the plan runs as it is; returns the pool sizes they were asked about, filled as they are."""
    from dataclasses import replace

    from vpp_core.plan import pipeline

    real, pools, views = pipeline.solve, [], iter(counts)

    def scripted(model, target, settings, *args, **kwargs):
        out = real(model, target, settings, *args, **kwargs)
        if settings.name != "greedy":
            return out
        pools.append(model.matrix.shape[1])
        return replace(out, result=replace(out.result, selected=np.arange(next(views))))

    monkeypatch.setattr(pipeline, "solve", scripted)
    return pools


@pytest.mark.parametrize("last", [12, 9])
def test_a_round_whose_candidates_raise_the_quick_count_is_undone(monkeypatch, last):
    # new candidates can raise what a patch asks for (its best candidate's share), so a grown
    # pool can need more views: a round that raises the count is taken back, one that leaves
    # it (10, 9, 9) is kept. The quick covers' counts are scripted; the rest of the plan is real
    from vpp_core.plan import pipeline

    pools = script_quick_counts(monkeypatch, [10, 9, last])
    doc = pipeline.plan(load_mesh(sample_stl(), "stl"), bushing_request(12, gap=QUICK_GAP))
    first, second, third = doc.adaptive
    assert first.added > 0 and second.added > 0 and third.added == 0
    assert third.candidates == pools[2] == pools[1] + second.added
    kept = pools[1] if last > 9 else pools[2]
    assert third.removed == (second.added if last > 9 else 0)
    info = doc.candidate_info
    assert info.added == kept - info.generated - info.sphere
    assert len(doc.candidates) == kept
    assert doc.viewpoints and max(v.id for v in doc.viewpoints) < kept


@pytest.mark.parametrize("counts", [[10, 12], [10, 9], [10, 9, 8, 7]])
def test_the_last_rounds_candidates_are_judged_when_no_more_rounds_fit(monkeypatch, counts):
    # the deadline (two counts: no round after the first) or ROUNDS (four) stops the rounds;
    # the last round's candidates are still judged by a quick cover: taken back if they raised
    # the count, kept if they lowered it. Quick counts scripted, the rest of the plan real
    from vpp_core.plan import adaptive, pipeline

    pools = script_quick_counts(monkeypatch, counts)
    real_round_s, calls = adaptive.round_s, []

    def round_s(*args):  # with two counts, the time runs out after the first round
        calls.append(True)
        return real_round_s(*args) if len(counts) > 2 or len(calls) == 1 else float("inf")

    monkeypatch.setattr(adaptive, "round_s", round_s)
    doc = pipeline.plan(load_mesh(sample_stl(), "stl"), bushing_request(12, gap=QUICK_GAP))
    *traced, judged = doc.adaptive
    assert len(traced) == len(counts) - 1 <= adaptive.ROUNDS and judged.added == 0
    assert all(r.added > 0 for r in traced) and judged.views == counts[-1]
    raised = counts[-1] > counts[-2]
    assert judged.removed == (traced[-1].added if raised else 0)
    kept = pools[-2] if raised else pools[-1]
    assert len(doc.candidates) == kept and judged.candidates == pools[-1]


def test_the_time_limit_is_the_whole_plans_budget(monkeypatch):
    """The final cover gets what loading, candidates, trace and adaptive rounds left of the
    limit (less the share kept for the stages after it, at least the floor); no round starts
    past half. Compiling (a fresh install's numba, 35 s once on a 2-core Xeon) is reported and
    not counted: it cut the crankshaft stand-in's first plan to no round and 9 s of cover."""
    from vpp_core.plan import pipeline

    part = load_mesh(sample_stl(), "stl")
    limits: list[float] = []
    real = pipeline.solve

    def spy(model, target, settings, *args, **kwargs):
        limits.append(settings.time_limit_s)
        return real(model, target, settings, *args, **kwargs)

    monkeypatch.setattr(pipeline, "solve", spy)
    budget = 20.0
    request = bushing_request(budget, adaptive=False)
    monkeypatch.setattr(pipeline, "warm", lambda *args: 3.0)  # seconds compiling, said
    doc = pipeline.plan(part, request, load_s=7.0)
    monkeypatch.setattr(pipeline, "warm", lambda *args: 0.0)
    t = doc.timings_s
    assert t.compiling == 3.0
    spent = t.load + t.candidates + t.trace + t.adaptive + t.matrices  # not t.compiling
    assert spent >= 7.0
    want = max(pipeline.FINAL_SHARE * budget, budget * (1 - pipeline.AFTER_SHARE) - spent)
    assert limits == [pytest.approx(want, abs=1e-3)]
    late = pipeline.plan(part, request, load_s=budget)  # nothing left: the floor
    assert late.solver.status in ("optimal", "heuristic")  # heuristic: grown to be seen
    assert late.partial is not None and late.partial.covered_fraction >= 0.99
    assert limits[-1] == pytest.approx(pipeline.FINAL_SHARE * budget)
    grown = PlanRequest(**{**request.model_dump(), "candidates": {"count": 30, "seed": 2}})
    assert pipeline.plan(part, grown).adaptive  # rounds when there is time
    assert not pipeline.plan(part, grown, load_s=budget * pipeline.ADAPT_SHARE).adaptive


def test_no_round_starts_that_its_tracing_or_the_rows_would_end_past_half(monkeypatch):
    # a pool traced slowly (the seconds a slow machine reports) predicts a slow round: none
    # starts, though the trace ended early; and the rows' grouping counts in the budget
    import time
    from dataclasses import replace

    from vpp_core.plan import pipeline

    part = load_mesh(sample_stl(), "stl")
    budget = 6.0
    request = bushing_request(budget, adaptive=False)
    grown = PlanRequest(**{**request.model_dump(), "candidates": {"count": 30, "seed": 2}})
    real_trace, real_rows = pipeline.trace_counts, pipeline.rows_of

    def slow_trace(*args, **kwargs):
        return replace(real_trace(*args, **kwargs), seconds=budget / 8)  # 30 views: 1/8 limit

    monkeypatch.setattr(pipeline, "trace_counts", slow_trace)
    assert not pipeline.plan(part, grown).adaptive  # a round of 160 views: 5/6 of the limit
    monkeypatch.setattr(pipeline, "trace_counts", real_trace)

    slept: list[bool] = []

    def slow_rows(*args, **kwargs):  # the first grouping (the rounds'), slowly
        if not slept:
            time.sleep(budget * pipeline.ADAPT_SHARE)
            slept.append(True)
        return real_rows(*args, **kwargs)

    monkeypatch.setattr(pipeline, "rows_of", slow_rows)
    assert not pipeline.plan(part, grown).adaptive


def test_smoothed_normals_are_the_area_weighted_means_of_near_faces_on_their_side():
    """patches.smoothed against the rule written plainly, face by face: the k nearest face
    centres within the radius (itself included), those whose normal points to the face's
    side, area-weighted, three passes; a face keeps its normal where the sum cancels."""
    from vpp_core.cover.patches import SMOOTH_NEIGHBOURS, SMOOTH_PASSES, smoothed

    rng = np.random.default_rng(4)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    sphere.vertices += rng.normal(0, 0.3, sphere.vertices.shape)  # a scan's noisy normals
    wall = trimesh.creation.box([12, 12, 1.0])  # a thin wall: its sides are within the radius
    wall = wall.subdivide().subdivide()
    wall.apply_translation([30, 0, 0])
    both = trimesh.util.concatenate([sphere, wall])
    part = part_from_arrays(both.vertices, both.faces)
    centres = part.vertices[part.faces].mean(axis=1)
    radius = 3.0
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    near = [np.argsort(d, kind="stable")[:SMOOTH_NEIGHBOURS] for d in dist]
    near = [n[dist[m, n] <= radius] for m, n in enumerate(near)]
    expected = part.normals.copy()
    for _ in range(SMOOTH_PASSES):
        last = expected.copy()
        for m, n in enumerate(near):
            side = n[last[n] @ last[m] > 0]
            total = (part.areas[side, None] * last[side]).sum(axis=0)
            if np.linalg.norm(total) > 1e-9 * part.areas.max():
                expected[m] = total / np.linalg.norm(total)
    got = smoothed(centres, part.normals, part.areas, radius)
    assert np.allclose(got, expected, atol=1e-9)
    assert np.abs(np.einsum("ij,ij->i", got, part.normals) - 1).max() > 1e-3  # it smoothed


def test_a_patch_is_one_connected_piece_of_surface():
    """Two coplanar 3 × 3 mm squares 1 mm apart face the same way within one 10 mm patch: by
    place and normal alone they share a row (the outer face and a hole's floor would); given
    the corners, each is its own patch, and a connected square stays one."""
    square = trimesh.creation.box([3, 3, 0.01])
    top = square.faces[square.face_normals[:, 2] > 0.9]
    vertices = np.vstack([square.vertices, square.vertices + [4.0, 0, 0]])
    faces = np.vstack([top, top + len(square.vertices)])
    part = part_from_arrays(vertices, faces)
    centres = part.vertices[part.faces].mean(axis=1)
    args = (centres, part.normals, part.areas, part.counted, 10.0)
    assert make_patches(*args).count == 1
    split = make_patches(*args, corners=part.faces)
    assert split.count == 2
    left = centres[:, 0] < 2.5
    assert len(np.unique(split.of_face[left])) == 1 and len(np.unique(split.of_face[~left])) == 1
    assert split.of_face[left][0] != split.of_face[~left][0]


def test_a_view_covers_no_more_of_a_patch_row_than_it_samples():
    # a 200 × 150 mm facet (two triangles, one patch) under cameras 410 mm away, their frames
    # 288 mm wide, a pixel of r̄ / 1.2: the centre one samples all of it, those at x = ±154
    # 45 % each. Averaged over the facet a side view's density would meet 80 % of the
    # target, and the two sides would "cover" it; a view covers the share it samples, so
    # the sides (90 % between them) do not, and the centre view alone does
    part = part_from_arrays(*plate_of(200.0, 150.0))
    views = look_down((-154.0, 0.0, 410.0), (154.0, 0.0, 410.0), (0.0, 0.0, 410.0))
    s, averaged = facet_rows(part, views)
    side = (100 - (154 - 144)) / 200  # each side frame's edge at ±(154 - 144) mm
    assert s == pytest.approx([side, side, 1.0], rel=0.02)
    assert s[0] + s[1] < 1 <= s[2]
    assert averaged[:2] == pytest.approx(np.sqrt(side * 1.44) * np.ones(2), rel=0.02)


def test_a_patch_no_view_samples_whole_asks_for_what_its_best_view_samples():
    # the same facet with its left half under a roof: no camera above samples more than the
    # right half, and the view that samples it (the centre one) covers the row; another
    # covers the share it samples of that half (95 %)
    roof = trimesh.creation.box([110.0, 170.0, 2.0])
    roof.apply_translation([-50.0, 0.0, 21.0])
    v, f = plate_of(200.0, 150.0)
    part = part_from_arrays(np.vstack([v, roof.vertices]), np.vstack([f, roof.faces + len(v)]))
    views = look_down((154.0, 0.0, 410.0), (0.0, 0.0, 410.0))
    s, _ = facet_rows(part, views)
    frame = 2 * 410.0 * np.tan(np.radians(SMALL.fov_x_deg) / 2)
    right = (100 - (154 - frame / 2)) / 200  # the right camera: x from its frame's edge
    centre = (100 - 5 / (1 - 22 / 410)) / 200  # the centre one: x past the roof's shadow
    assert s == pytest.approx([right / centre, 1.0], rel=0.02)


def facet_rows(part: Part, views) -> tuple[np.ndarray, np.ndarray]:
    """S of the patch holding face 0 (the facet) for `views` of the SMALL sensor, 410 mm
    away, r̄ = 1.2 pixels: (N,) with the sampled share, and (N,) averaged over the patch."""
    centres = part.vertices[part.faces].mean(axis=1)
    patches = make_patches(centres, part.normals, part.areas, part.counted, 1e3, None, part.faces)
    r = trace_counts(part, SMALL, views).counts
    target = SMALL.pixel_pitch_mm(410.0) * STANDOFF_MARGIN
    out = []
    for cameras in (Cameras(views, SMALL), None):
        args = (r, part.areas, part.counted, target, "density", patches, None, cameras)
        model = cover_model(*args)
        out.append(model.matrix.toarray()[model.face_row[list(model.faces).index(0)]])
    return out[0], out[1]


def plate_of(length: float, width: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a length × width mm rectangle at z = 0, normal +Z, two triangles."""
    x, y = length / 2, width / 2
    v = np.array([[-x, -y, 0], [x, -y, 0], [x, y, 0], [-x, y, 0]], dtype=float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_two_views_of_one_end_of_a_facet_do_not_cover_its_other_end():
    # one triangular facet 600 mm long, wider than any frame (288 mm at 410 mm): no view
    # samples it whole, so its own row asks only for what its best view samples, and the
    # view of its thick left end (73 % of it) covers that row alone. Traced on area elements
    # (the default rows), a view covers only the elements it samples: the left views A and
    # B meet 73 % of the facet, and the right end (23 %) needs its own view C
    from vpp_core.plan.pipeline import elements_of, rows_model, rows_of
    from vpp_core.trace.raytrace import make_backend

    v = np.array([[-300.0, -75.0, 0.0], [300.0, -75.0, 0.0], [-300.0, 75.0, 0.0]])
    part = part_from_arrays(v, np.array([[0, 1, 2]]))
    views = look_down((-154.0, 0.0, 410.0), (-150.0, 0.0, 410.0), (154.0, 0.0, 410.0))
    target = SMALL.pixel_pitch_mm(410.0) * STANDOFF_MARGIN
    request = PlanRequest(sensor=SMALL, target={"resolution_mm": target})
    split = elements_of(part, request)
    assert split is not None and len(split.parent) >= 1000
    met = {}
    for name, el in (("facet", None), ("elements", split)):
        backend = make_backend(el.part if el else part)
        trace = trace_counts(part, SMALL, views, backend=backend, elements=el)
        rows = rows_of(part, request, trace)
        model = rows_model(rows, request, trace, Cameras(views, SMALL))
        area = model.row_areas()
        s = model.matrix.toarray()
        met[name] = [
            area[s[:, cols].sum(axis=1) >= 1 - 1e-9].sum() / 45_000
            for cols in ([0], [0, 1], [0, 1, 2])
        ]
    assert met["facet"] == pytest.approx([1.0, 1.0, 1.0])
    left = (300 * 288 + (298**2 - 10**2) / 2) / 4 / 45_000  # x in [-298, -10] under A
    right = (300 * 288 - (298**2 - 10**2) / 2) / 4 / 45_000  # x in [10, 298] under C
    assert met["elements"][1] == pytest.approx(left, abs=0.03)
    assert met["elements"][2] == pytest.approx(left + right, abs=0.03)


def test_the_benchs_point_check_counts_area_a_camera_sees_and_meets():
    """The bench's re-check at random points (bench/quality.py point_check): a 40 × 30 × 0.5 mm
    plate seen from above sees its top (1 200 of 2 470 mm²: the bottom passes the incidence
    test and lies in the image, only the occlusion test removes it; the rims are beyond 75°).
    At 400 mm one view meets 0.18 mm (0.146 mm pixels); at 650 mm (0.238 mm) it does not,
    and two such views add up to it (4.2 + 4.2 ≥ 5.6 per mm)."""
    check = bench_module("quality").point_check
    box = trimesh.creation.box([40, 30, 0.5])
    part = part_from_arrays(box.vertices, box.faces)
    top = 1200 / 2470
    near = check(part, PAPER, look_down((0, 0, 400)), 0.18, 20_000)
    assert near["point_seen"] == pytest.approx(top, abs=0.015)
    assert near["point_met"] == near["point_seen"]
    far = check(part, PAPER, look_down((0, 0, 650)), 0.18, 20_000)
    assert far["point_seen"] == pytest.approx(top, abs=0.015) and far["point_met"] == 0
    two = check(part, PAPER, look_down((0, 0, 650), (1, 0, 650)), 0.18, 20_000)
    assert two["point_met"] == pytest.approx(top, abs=0.015)
