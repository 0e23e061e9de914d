"""The default candidate generator (SPEC §2)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import GeneratorSettings, generate, spaced_samples
from vpp_core.mesh.part import load_mesh, part_from_arrays

SENSOR = Sensor()


def box_part(extents=(80.0, 60.0, 40.0)):
    m = trimesh.creation.box(extents)
    return part_from_arrays(m.vertices, m.faces)


def test_cameras_sit_at_working_distance_looking_back_at_the_surface():
    part = box_part()
    gen = generate(part, SENSOR, GeneratorSettings(count=60, seed=1))
    v = gen.views
    assert 50 <= len(v) <= 60
    targets = v.positions + SENSOR.working_distance * v.gazes
    # the target lies on the box surface: on one face plane, inside the others
    half = np.array([40.0, 30.0, 20.0])
    on_face = np.isclose(np.abs(targets), half, atol=1e-6).any(axis=1)
    assert on_face.all() and (np.abs(targets) <= half + 1e-6).all()
    # outward: the camera is outside the box, farther than the working distance minus the box
    assert (np.abs(v.positions) > half).any(axis=1).all()
    assert np.linalg.norm(v.gazes, axis=1) == pytest.approx(1.0)


def test_seeded_and_deterministic():
    part = box_part()
    a = generate(part, SENSOR, GeneratorSettings(count=40, seed=7)).views
    b = generate(part, SENSOR, GeneratorSettings(count=40, seed=7)).views
    c = generate(part, SENSOR, GeneratorSettings(count=40, seed=8)).views
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.gazes, b.gazes)
    assert not np.array_equal(a.positions, c.positions)


def test_samples_are_spaced_and_area_weighted():
    m = trimesh.creation.box((100.0, 100.0, 1.0))
    points, faces, spacing = spaced_samples(m, 200, seed=0)
    assert len(points) == 200
    d, _ = cKDTree(points).query(points, k=2)
    assert d[:, 1].min() >= spacing - 1e-9
    # the two big faces hold ~all the area, hence ~all the samples
    big = np.abs(m.face_normals[faces][:, 2]) > 0.9
    assert big.mean() > 0.9


def test_inverted_cube_still_gets_outside_cameras():
    from tests.conftest import MESHES, shared_dir

    data = (shared_dir(MESHES / "bad") / "cube_inverted_winding.stl").read_bytes()
    part = load_mesh(data, "stl")
    v = generate(part, SENSOR, GeneratorSettings(count=20, seed=0, clearance_mm=5)).views
    centre = part.vertices.mean(axis=0)
    assert len(v) >= 15
    to_centre = centre - v.positions
    assert (np.einsum("ij,ij->i", to_centre, v.gazes) > 0).all()
    assert (np.linalg.norm(to_centre, axis=1) > 400).all()


def test_candidates_that_cannot_see_their_target_or_are_too_close_are_dropped():
    # a hollow box: 300 mm outside, a closed 200 mm cavity inside (walls 50 mm thick)
    outer = trimesh.creation.box((300.0, 300.0, 300.0))
    cavity = trimesh.creation.box((200.0, 200.0, 200.0))
    cavity.invert()
    mesh = trimesh.util.concatenate([outer, cavity])
    part = part_from_arrays(mesh.vertices, mesh.faces)
    gen = generate(part, SENSOR, GeneratorSettings(count=60, seed=0))
    targets = gen.views.positions + SENSOR.working_distance * gen.views.gazes
    # every kept camera looks at the outside; every cavity sample (~30 % of area) was dropped
    assert np.allclose(np.abs(targets).max(axis=1), 150.0)
    assert (np.abs(gen.views.positions).max(axis=1) > 150.0).all()
    assert 0.15 * 60 <= gen.dropped <= 0.45 * 60
    none = generate(part, SENSOR, GeneratorSettings(count=20, seed=0, clearance_mm=600.0))
    assert len(none.views) == 0 and none.dropped == 20


def test_decimated_planning_mesh():
    m = trimesh.creation.icosphere(subdivisions=4, radius=50.0)
    part = part_from_arrays(m.vertices, m.faces)
    gen = generate(part, SENSOR, GeneratorSettings(count=30, seed=0, decimate=0.1))
    assert gen.planning_faces == pytest.approx(0.1 * part.n_faces, rel=0.1)
    assert len(gen.views) == 30
    dist = np.linalg.norm(gen.views.positions, axis=1)
    assert dist == pytest.approx(np.full(30, 550.0), rel=0.01)


def test_tilt_draws_directions_uniformly_by_solid_angle_within_the_cone():
    from scipy.stats import kstest

    from vpp_core.candidates.generator import tilt

    rng = np.random.default_rng(3)
    normals = rng.normal(size=(4000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[:10] = [1.0, 0.0, 0.0]  # the helper-axis switch
    d = tilt(normals, 30.0, rng)
    assert np.linalg.norm(d, axis=1) == pytest.approx(1.0)
    cos_t = np.einsum("ij,ij->i", d, normals)
    lo = np.cos(np.radians(30.0))
    assert cos_t.min() >= lo - 1e-12
    # uniform by solid angle: cos θ is uniform on [cos 30°, 1]
    assert kstest(cos_t, "uniform", args=(lo, 1 - lo)).pvalue > 1e-3
    # and no preferred azimuth: around +z, the side components average out
    up = tilt(np.tile([0.0, 0.0, 1.0], (4000, 1)), 30.0, rng)
    assert np.abs(up[:, :2].mean(axis=0)).max() < 0.02


def test_tilted_cameras_look_at_their_sample_from_within_the_cone():
    part = box_part()
    wd = SENSOR.working_distance
    v = generate(part, SENSOR, GeneratorSettings(count=60, seed=1, tilt_deg=30.0)).views
    targets = v.positions + wd * v.gazes
    half = np.array([40.0, 30.0, 20.0])
    assert (np.abs(targets) <= half + 1e-6).all()  # the central ray aims at the surface
    on_face = np.isclose(np.abs(targets), half, atol=1e-6)
    normal = np.where(on_face, np.sign(targets), 0.0)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)  # edge samples: smoothed normals
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", -v.gazes, normal), -1, 1)))
    flat = on_face.sum(axis=1) == 1
    assert angle[flat].max() <= 30.0 + 1e-6
    assert np.median(angle[flat]) > 12.0  # spread over the cone, not along the normal


def test_tilted_candidates_see_hole_and_pocket_walls_from_more_than_one_pose():
    """featuretype.STL: along the normals, ~5 % of its faces are seen by one candidate only."""
    from tests.conftest import MESHES, shared_dir
    from vpp_core.trace.raytrace import trace_counts

    data = (shared_dir(MESHES) / "featuretype.STL").read_bytes()
    part = load_mesh(data, "stl", units="in")
    single = {}
    for deg in (0.0, 30.0):
        views = generate(part, SENSOR, GeneratorSettings(count=300, seed=0, tilt_deg=deg)).views
        seen_by = np.diff(trace_counts(part, SENSOR, views).counts.tocsr().indptr)
        single[deg] = int((seen_by == 1).sum())
    assert single[0.0] > 50 and single[30.0] < single[0.0] / 5, single


def _box(*extents: float):
    """A box part of `extents` mm centred at the origin."""
    mesh = trimesh.creation.box(list(extents))
    return part_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))


def _tiles(part, **kw):
    from vpp_core.candidates.generator import STANDOFF_MARGIN, _surface_tree
    from vpp_core.candidates.tiles import tiles
    from vpp_core.trace.raytrace import make_backend

    args = (part, SENSOR, 410.0, make_backend(part), lambda: _surface_tree(part), 20.0)
    return tiles(*args, STANDOFF_MARGIN**2, **kw)


def test_tiles_lay_head_on_frames_side_by_side_over_a_large_flat_face():
    # a 1 200 × 800 × 5 mm plate: each 288 × 180 mm frame at 410 mm looks straight at a face,
    # and every point of the top face lies in the frame of a camera above it; the 5 mm edges
    # 1 200 mm long are tiled too (longer than two frames stretched 1.44 times: 829 mm), the
    # 800 mm ones are not
    views = _tiles(_box(1200.0, 800.0, 5.0))
    normals = np.array([[0, 0, 1], [0, 0, -1], [0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0]])
    facing = np.abs(views.gazes @ normals.T).max(axis=1)
    assert len(views) > 0 and np.allclose(facing, 1.0)  # head-on
    top = views.take(np.flatnonzero(views.gazes[:, 2] < -0.99))
    side = np.abs(views.gazes[:, 1]) > 0.99
    assert np.allclose(top.positions[:, 2], 2.5 + 410.0)
    assert len(top) == (len(views) - side.sum()) // 2  # top, bottom and the long edges
    assert not (np.abs(views.gazes[:, 0]) > 0.99).any()  # the 800 mm edges get none
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-600, 600, 5000), rng.uniform(-400, 400, 5000)])
    on_top = np.column_stack([points, np.full(5000, 2.5)])
    cam = np.einsum("kji,pkj->pki", top.rotations(), on_top[:, None] - top.positions)
    u = SENSOR.fx * cam[..., 0] / cam[..., 2] + SENSOR.width_px / 2
    v = SENSOR.fy * cam[..., 1] / cam[..., 2] + SENSOR.height_px / 2
    inside = (u >= 0) & (u < SENSOR.width_px) & (v >= 0) & (v < SENSOR.height_px)
    assert inside.any(axis=1).all()  # the frames tile the face
    frame = (410.0 * SENSOR.width_px / SENSOR.fx) * (410.0 * SENSOR.height_px / SENSOR.fy)
    assert len(top) * frame < 1.5 * 1200 * 800  # side by side, not piled up


def test_faces_two_tilted_frames_span_get_no_tiles_and_tiles_stay_clear_and_allowed():
    assert len(_tiles(_box(300.0, 200.0, 3.0))) == 0  # tilted views cover it as well
    assert len(_tiles(_box(60.0, 60.0, 40.0))) == 0
    part = _box(1200.0, 800.0, 5.0)
    above = _tiles(part, allowed=lambda cams: cams[:, 2] > 0)
    assert len(above) > 0 and (above.positions[:, 2] > 0).all()
    some = _tiles(part, limit=30)  # the largest faces first, each whole or not at all
    assert 24 <= len(some) <= 30 and (np.abs(some.gazes[:, 2]) > 0.99).sum() == 24
    cube = trimesh.creation.box([1e5, 1e5, 1e5])  # 100 m: 213 000 cells a face, none laid
    huge = part_from_arrays(np.asarray(cube.vertices), np.asarray(cube.faces))
    assert len(_tiles(huge, limit=125)) == 0


def test_generated_candidates_end_with_the_tiles_and_only_the_default_profile_asks():
    from vpp_core.plan.document import CandidateGenerator, PlanRequest

    part = _box(1200.0, 800.0, 5.0)
    settings = GeneratorSettings(count=60, standoff_mm=410.0, tiles=True)
    gen = generate(part, SENSOR, settings)
    plain = generate(part, SENSOR, GeneratorSettings(count=60, standoff_mm=410.0))
    assert gen.tiles > 0 and plain.tiles == 0 and len(gen.views) == len(plain.views) + gen.tiles
    assert np.allclose(gen.views.positions[: len(plain.views)], plain.views.positions)
    assert gen.tiles <= 60 // 4
    fill = {"candidates": CandidateGenerator()}
    assert PlanRequest(**fill).candidates.tiles is True
    assert PlanRequest(profile="paper", **fill).candidates.tiles is False
