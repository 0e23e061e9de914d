"""Diagnostics (vpp_core.plan.diagnostics): each figure against a direct, independent count."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from tests.conftest import look_down, plate
from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import part_from_arrays
from vpp_core.mesh.refine import refine
from vpp_core.plan.diagnostics import (
    WELL_SEEN_RAYS,
    _element_hint,
    _hint,
    _size_hint,
    _tilt_hint,
    back_to_back,
    enclosed_faces,
    private_rows,
    sampled_area,
    undersampled,
)
from vpp_core.plan.document import CandidateGenerator, PlanRequest, Target
from vpp_core.trace.raytrace import make_backend, trace_counts

SMALL = Sensor(width_px=320, height_px=200, fov_x_deg=38.7, fov_y_deg=24.75)


def test_faces_inside_a_closed_box_are_enclosed_and_outer_faces_not():
    outer = trimesh.creation.box([100, 100, 100])
    inner = trimesh.creation.box([20, 20, 20])
    mesh = trimesh.util.concatenate([outer, inner])
    part = part_from_arrays(mesh.vertices, mesh.faces)
    faces = np.arange(part.n_faces)
    got = enclosed_faces(part, faces, make_backend(part))
    inside = np.abs(part.vertices[part.faces].mean(axis=1)).max(axis=1) < 15
    assert inside.sum() == 12 and np.array_equal(got, inside)


def test_an_opening_lets_faces_escape_except_those_that_face_the_floor():
    box = trimesh.creation.box([100, 100, 100])
    lid = np.flatnonzero(box.face_normals[:, 2] > 0.9)  # remove the top: an open box
    keep = np.setdiff1d(np.arange(len(box.faces)), lid)
    open_box = trimesh.Trimesh(box.vertices, box.faces[keep], process=False)
    inner = trimesh.creation.box([20, 20, 20])
    mesh = trimesh.util.concatenate([open_box, inner])
    part = part_from_arrays(mesh.vertices, mesh.faces)
    got = enclosed_faces(part, np.arange(part.n_faces), make_backend(part))
    centre = part.vertices[part.faces].mean(axis=1)
    under_inner = (np.abs(centre).max(axis=1) < 15) & (part.normals[:, 2] < -0.9)
    assert under_inner.sum() == 2 and np.array_equal(got, under_inner)  # the rest see the sky


def test_back_to_back_faces_are_found():
    box = trimesh.creation.box([10, 10, 10])
    flipped = box.faces[:1, ::-1]
    part = part_from_arrays(box.vertices, np.vstack([box.faces, flipped]))
    got = back_to_back(part)
    assert got.sum() == 2 and got[0] and got[-1]
    assert not back_to_back(part_from_arrays(box.vertices, box.faces)).any()


def test_private_rows_match_a_direct_count():
    rng = np.random.default_rng(1)
    dense = rng.choice([0.0, 0.4, 0.6, 1.0], size=(40, 8), p=[0.6, 0.15, 0.1, 0.15])
    A = sp.csr_array(dense)
    sel = np.array([0, 2, 3, 5, 7])
    got = private_rows(A, sel).toarray()
    cov = dense[:, sel].sum(axis=1)
    for k, j in enumerate(sel):
        want = (dense[:, j] > 0) & (cov >= 1 - 1e-9) & (cov - dense[:, j] < 1 - 1e-9)
        assert np.array_equal(got[:, k], want)


def test_hint_names_the_largest_fraction_that_leaves_the_faces_out():
    assert _hint(0, 5, 1.0, 100.0) is None
    assert "--min-coverage 0.999" in _hint(2, 9, 0.05, 100.0)
    assert "--min-coverage 0.99," in _hint(2, 9, 0.6, 100.0)
    assert _hint(2, 9, 30.0, 100.0) is None  # more than 5 % of the area: not a nuisance


def test_tilt_hint_only_when_a_view_is_forced_by_a_well_seen_face():
    assert _tilt_hint(0, 9) is None
    assert "--tilt 30" in _tilt_hint(3, 9) and "3 of 9" in _tilt_hint(3, 9)


@pytest.fixture(scope="module")
def plate_with_sliver():
    """A 100 mm plate, and a sub-pixel sliver standing on it that few candidates see."""
    plate = trimesh.creation.box([100, 100, 4])
    sliver = trimesh.Trimesh(
        [[30, 30, 2.0], [30.05, 30, 2.0], [30, 30.0, 2.3]], [[0, 1, 2]], process=False
    )
    mesh = trimesh.util.concatenate([plate, sliver])
    return part_from_arrays(mesh.vertices, mesh.faces)


def test_plan_diagnostics_agree_with_direct_counts(plate_with_sliver):
    from vpp_core.cover.density import cover_model
    from vpp_core.plan.pipeline import candidates_for, finish
    from vpp_core.trace.raytrace import trace_counts

    part = plate_with_sliver
    request = PlanRequest(
        sensor=SMALL,
        target=Target(resolution_mm=1.2, formulation="visibility"),
        candidates=CandidateGenerator(count=40, seed=1),
    )
    backend = make_backend(part)
    views, info = candidates_for(part, request, backend)
    trace = trace_counts(part, SMALL, views, backend=backend)
    doc = finish(part, request, views, info, trace, backend=backend)
    d = doc.diagnostics
    p = SMALL.pixel_pitch_mm(SMALL.working_distance)
    assert d.pixel_footprint_mm == pytest.approx(p)
    small = part.counted & (part.areas < p * p)
    assert d.subpixel.faces == small.sum() >= 1
    r = trace.counts.toarray()
    seen_by = (r > 0).sum(axis=1)
    single = part.counted & (seen_by == 1)
    assert d.single_candidate.faces == single.sum()
    assert d.single_candidate.one_ray == int(((r[single] > 0) & (r[single] == 1)).any(1).sum())
    model = cover_model(trace.counts, part.areas, part.counted, 1.2, "visibility")
    chosen = sorted(v.id for v in doc.viewpoints)
    V = model.matrix.toarray()[:, chosen]
    for cause in d.viewpoints:
        k = chosen.index(cause.id)
        mine = model.faces[(V[:, k] > 0) & (V.sum(axis=1) == 1)]
        assert cause.private_faces == len(mine)
        weak = small[mine] | single[mine]
        assert cause.driven == (len(mine) > 0 and bool(weak.all()))
    assert d.driven_views == sum(c.driven for c in d.viewpoints)
    well = single & (r.max(axis=1) >= WELL_SEEN_RAYS)
    forced = set(r[well].argmax(axis=1).tolist()) & set(chosen)
    assert d.single_candidate.forced_views == len(forced)
    assert ("--min-coverage" in (d.hint or "")) == (d.driven_views > 0)
    assert ("--tilt" in (d.hint or "")) == (len(forced) > 0)
    u = d.undersampled
    assert u.element_mm2 == pytest.approx(30 * p * p, rel=0.05)
    coverable = part.areas[model.faces].sum()
    assert ("--max-face-area" in (d.hint or "")) == (u.unsampled_mm2 >= 1e-3 * coverable)


def shaded_plate(bar_to_x: float) -> trimesh.Trimesh:
    """A 20 mm plate of two faces at z = 0 under a bar over x in [-10, bar_to_x] at z = 5."""
    v, f = plate(side=20.0)
    b = bar_to_x
    bar = np.array([[-10.0, -10, 5], [b, -10, 5], [b, 10, 5], [-10, 10, 5]])
    return trimesh.Trimesh(np.vstack([v, bar]), np.vstack([f, [[4, 5, 6], [4, 6, 7]]]))


@pytest.mark.parametrize("tilt", [0.0, 50.0])
def test_sampled_area_of_a_plate_in_full_view_is_its_area(tilt):
    part = part_from_arrays(*plate(side=20.0, tilt_deg=tilt))
    view = look_down((40.0, 0.0, 500.0))
    r = trace_counts(part, Sensor(), view).counts
    sampled = sampled_area(part, Sensor(), view, sp.csr_array(r), np.array([0]))
    assert sampled == pytest.approx(part.areas, rel=0.02)


@pytest.mark.parametrize("bar_to_x", [0.0, 6.0])
def test_sampled_area_agrees_with_the_elements_that_get_rays(bar_to_x):
    """The footprint estimate per face against an independent count: the area of its 0.2 mm²
    elements that some ray lands on."""
    mesh = shaded_plate(bar_to_x)
    part = part_from_arrays(mesh.vertices, mesh.faces)
    view = look_down((0.0, 0.0, 500.0))
    r = sp.csr_array(trace_counts(part, Sensor(), view).counts)
    sampled = sampled_area(part, Sensor(), view, r, np.array([0]))
    fine = refine(part, 0.2)
    hit = trace_counts(fine, Sensor(), view).counts.toarray()[:, 0] > 0
    centres = fine.vertices[fine.faces].mean(axis=1)
    parent = [part_face_of(part, c) for c in centres]
    by_elements = np.bincount(parent, weights=fine.areas * hit, minlength=part.n_faces)
    on_plate = np.arange(2)
    assert sampled[on_plate] == pytest.approx(by_elements[on_plate], rel=0.05, abs=2.0)
    assert sampled[on_plate].sum() == pytest.approx(20.0 * (10.0 - bar_to_x), rel=0.05)


def test_sampled_area_stays_positive_when_the_face_centre_is_behind_the_camera():
    """A 3 m long triangle seen at 60° from its normal around its wide end: its centre lies
    behind the camera's plane, yet the rays landing near the camera's target make a positive
    area, well under half the face's (it is undersampled)."""
    part = part_from_arrays(
        np.array([[-50.0, 50, 0], [0, -3000, 0], [50, 50, 0]]), np.array([[0, 1, 2]])
    )
    camera = np.array([[0.0, -433.0, 250.0]])
    view = make_viewpoints(camera, -camera / np.linalg.norm(camera))
    assert (part.vertices[part.faces].mean(axis=1) - camera) @ view.gazes[0] < 0
    r = sp.csr_array(trace_counts(part, Sensor(), view).counts)
    assert r.nnz == 1
    sampled = sampled_area(part, Sensor(), view, r, np.array([0]))
    assert 0 < sampled[0] < part.areas[0] / 2
    assert undersampled(part, Sensor(), view, r, np.array([0]), 1.0).faces == 1


def part_face_of(part, point: np.ndarray) -> int:
    """The face of `part` whose triangle holds `point` (mm)."""
    tri = part.vertices[part.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inside = np.ones(len(tri), dtype=bool)
    for k in range(3):
        edge = tri[:, (k + 1) % 3] - tri[:, k]
        inside &= np.einsum("ij,ij->i", np.cross(edge, point - tri[:, k]), n) >= -1e-9
    plane = np.abs(np.einsum("ij,ij->i", n, point - tri[:, 0])) <= 1e-6 * np.linalg.norm(n, axis=1)
    return int(np.flatnonzero(inside & plane)[0])


def test_element_hint_when_big_faces_are_seen_by_a_sliver_of_rays_and_not_after_refining():
    mesh = shaded_plate(6.0)  # 80 of the plate's 400 mm² in view
    part = part_from_arrays(mesh.vertices, mesh.faces)
    view = look_down((0.0, 0.0, 500.0))
    r = sp.csr_array(trace_counts(part, Sensor(), view).counts)
    under = undersampled(part, Sensor(), view, r, np.array([0]), 1.0)
    assert under.faces == 2 and under.area_mm2 == pytest.approx(400.0)
    assert under.unsampled_mm2 == pytest.approx(320.0, rel=0.05)
    coverable = part.area_mm2
    hint = _element_hint(under, coverable) or ""
    assert "--max-face-area 1," in hint and "--remesh 1," in hint
    fine = refine(part, 1.0)
    r = sp.csr_array(trace_counts(fine, Sensor(), view).counts)
    under = undersampled(fine, Sensor(), view, r, np.array([0]), 1.0)
    assert under.faces == 0 and under.unsampled_mm2 == 0.0
    assert _element_hint(under, fine.area_mm2) is None


@pytest.fixture(scope="module")
def huge_cube_hint():
    """The hint of a plan of a 100 m cube at 0.18 mm (30 candidates, a 320 × 200 sensor)."""
    from vpp_core.plan.document import CandidateGenerator, PlanRequest, SolverSettings
    from vpp_core.plan.pipeline import plan

    box = trimesh.creation.box(extents=[1e5, 1e5, 1e5])
    request = PlanRequest(
        sensor=Sensor(width_px=320, height_px=200),
        candidates=CandidateGenerator(count=30),
        solver=SolverSettings(name="greedy", time_limit_s=10),
    )
    return plan(part_from_arrays(box.vertices, box.faces), request).diagnostics.hint or ""


def test_the_element_hint_states_a_share_of_the_area_the_candidates_reach(huge_cube_hint):
    """A 100 m cube at 0.18 mm: its 12 faces are each hit by a ray, and nearly all of their
    area by none; the hint's share is of the faces the candidates reach (so at most 100 %),
    not of the area in sampled patches (1 % of it here, which gave 164 525 %)."""
    import re

    share = re.search(r"\(([\d.]+)% of the area the candidates reach\)", huge_cube_hint)
    assert share is not None, huge_cube_hint
    assert 99.0 <= float(share.group(1)) <= 100.0


def test_a_part_larger_than_its_candidates_can_frame_is_told_to_check_its_units(huge_cube_hint):
    """6e10 mm² against 30 frames of 492 × 307 mm at the far end of the depth of field (700 mm):
    the hint comes first and names the part's size, the ratio and --units."""
    assert huge_cube_hint.startswith("the part (1e+05 × 1e+05 × 1e+05 mm, 6e+10 mm²) has ")
    framed = 30 * 2 * 700 * np.tan(np.radians(38.7 / 2)) * 2 * 700 * np.tan(np.radians(24.75 / 2))
    ratio = float(huge_cube_hint.split(" has ")[1].split(" times")[0])
    assert ratio == pytest.approx(6e10 / framed, rel=5e-3)  # printed to 3 digits
    assert "(492 × 307 mm each at 700 mm): check its units (--units" in huge_cube_hint
    plate = trimesh.creation.box(extents=[2000.0, 1000.0, 5.0])  # 4.0e6 mm², 30 frames 4.5e6
    part = part_from_arrays(plate.vertices, plate.faces)
    assert _size_hint(part, Sensor(), 30) is None
    assert _size_hint(part, Sensor(), 26) is not None  # 26 frames: 3.9e6 mm²
