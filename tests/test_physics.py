"""SPEC §7: ray counts and densities against the pinhole camera, computed independently."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from tests.conftest import look_down, plate_part
from vpp_core.camera.sensor import Sensor
from vpp_core.cover.density import Cameras, density_sum
from vpp_core.mesh.part import part_from_arrays
from vpp_core.trace.raytrace import trace_counts

PAPER = Sensor()


@pytest.fixture(autouse=True, params=["raster", "embree"])
def backend(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Every physics check runs with each ray backend as the default."""
    monkeypatch.setattr("vpp_core.trace.raytrace.DEFAULT_BACKEND", request.param)
    return str(request.param)


def counts(*args, **kw):
    """R of a trace (M, N) int32."""
    return trace_counts(*args, **kw).counts


def analytic_plate_count(sensor: Sensor, depth: float, side: float) -> int:
    """Pixels whose centre ray hits an axis-aligned square of `side` centred on the axis."""
    u = (np.arange(sensor.width_px) + 0.5 - sensor.width_px / 2) / sensor.fx * depth
    v = (np.arange(sensor.height_px) + 0.5 - sensor.height_px / 2) / sensor.fy * depth
    return int((np.abs(u) < side / 2).sum() * (np.abs(v) < side / 2).sum())


def test_pixel_pitch_matches_spec_figure():
    assert PAPER.pixel_pitch_mm(500) == pytest.approx(0.183, abs=5e-4)


@pytest.mark.parametrize("depth", [350.0, 500.0, 650.0])
def test_plate_count_and_density_match_pinhole(depth):
    side = 20.0
    part = plate_part(side=side)
    r = counts(part, PAPER, look_down((0, 0, depth)))
    total = int(r.sum())
    # exact pixel-centre count, and the SPEC §7 approximation (L/p)² within 2 %
    assert abs(total - analytic_plate_count(PAPER, depth, side)) <= 2
    p_x, p_y = (
        PAPER.pixel_pitch_mm(depth),
        2 * depth * math.tan(math.radians(PAPER.fov_y_deg) / 2) / PAPER.height_px,
    )
    assert total == pytest.approx(side**2 / (p_x * p_y), rel=0.02)
    delta = density_sum(sp.csc_array(r)[:, [0]], part.areas)
    assert delta == pytest.approx(np.full(2, 1 / math.sqrt(p_x * p_y)), rel=0.02)


def analytic_tilted_count(sensor: Sensor, depth: float, side: float, tilt_deg: float) -> int:
    """Pixel-centre rays from (0, 0, depth) looking down that hit the plate tilted about X."""
    a = math.radians(tilt_deg)
    normal = np.array([0.0, -math.sin(a), math.cos(a)])
    axis_y = np.array([0.0, math.cos(a), math.sin(a)])
    u = (np.arange(sensor.width_px) + 0.5 - sensor.width_px / 2) / sensor.fx
    v = (np.arange(sensor.height_px) + 0.5 - sensor.height_px / 2) / sensor.fy
    uu, vv = np.meshgrid(u, v)
    # gaze -Z, default up +Y: camera x = world +X, camera y = world -Y, camera z = world -Z
    dirs = np.stack([uu, -vv, -np.ones_like(uu)], axis=-1)
    origin = np.array([0.0, 0.0, depth])
    t = -(origin @ normal) / (dirs @ normal)
    hit = origin + t[..., None] * dirs
    inside = (np.abs(hit[..., 0]) < side / 2) & (np.abs(hit @ axis_y) < side / 2)
    return int(inside.sum())


@pytest.mark.parametrize("tilt", [20.0, 45.0, 70.0])
def test_tilt_scales_count_by_cos(tilt):
    side = 40.0
    flat = counts(plate_part(side=side), PAPER, look_down((0, 0, 500))).sum()
    tilted = counts(plate_part(side=side, tilt_deg=tilt), PAPER, look_down((0, 0, 500))).sum()
    assert abs(tilted - analytic_tilted_count(PAPER, 500.0, side, tilt)) <= 4
    assert tilted / flat == pytest.approx(math.cos(math.radians(tilt)), rel=0.02)


def test_nothing_beyond_max_incidence():
    part = plate_part(side=20.0, tilt_deg=80.0)
    assert counts(part, PAPER, look_down((0, 0, 500))).sum() == 0
    wide = Sensor(max_incidence_deg=85.0)
    assert counts(part, wide, look_down((0, 0, 500))).sum() > 0


@pytest.mark.parametrize("depth", [250.0, 299.0, 701.0, 800.0])
def test_nothing_outside_depth_of_field(depth):
    assert counts(plate_part(side=20.0), PAPER, look_down((0, 0, depth))).sum() == 0


def test_occluded_face_gets_nothing():
    from tests.conftest import plate

    back_v, back_f = plate(side=10.0, z=0.0)
    front_v, front_f = plate(side=30.0, z=100.0)
    part = part_from_arrays(
        np.vstack([back_v, front_v]), np.vstack([back_f, front_f + len(back_v)])
    )
    r = counts(part, PAPER, look_down((0, 0, 500))).toarray()[:, 0]
    back = np.isin(np.arange(4), [0, 1])  # face order: back plate first
    assert r[back].sum() == 0 and r[~back].sum() > 0


def test_incidence_uses_abs_cos_so_winding_does_not_matter():
    v, f = plate_part(side=20.0).vertices, plate_part(side=20.0).faces
    flipped = part_from_arrays(v, f[:, ::-1])
    views = look_down((0, 0, 500))
    assert counts(flipped, PAPER, views).sum() == counts(plate_part(side=20.0), PAPER, views).sum()


def test_counts_independent_of_threads_and_are_int32():
    part = plate_part(side=20.0, n=8)
    views = look_down((0, 0, 500), (5, 0, 450), (0, -7, 600))
    one = counts(part, PAPER, views, threads=1)
    two = counts(part, PAPER, views, threads=2)
    full = counts(part, PAPER, views, threads=2, cull=False)
    assert one.dtype == np.int32 and one.shape == (part.n_faces, 3)
    assert (one != two).nnz == 0 and (one != full).nnz == 0


def test_culling_traces_only_the_parts_image():
    part = plate_part(side=20.0)
    trace = trace_counts(part, PAPER, look_down((0, 0, 500)))
    # the 20 mm plate spans ~110 × 110 of 1920 × 1200 pixels at 500 mm
    assert trace.pixels == PAPER.n_pixels and trace.rays_cast < 0.01 * trace.pixels
    assert trace.counts.sum() == counts(part, PAPER, look_down((0, 0, 500)), cull=False).sum()


def test_camera_inside_the_hull_traces_everything():
    from tests.conftest import plate

    v, f = plate(side=400.0, n=2)
    part = part_from_arrays(np.vstack([v, v + [0, 0, 900]]), np.vstack([f, f + len(v)]))
    trace = trace_counts(part, PAPER, look_down((0, 0, 500)))
    assert trace.rays_cast == trace.pixels and trace.counts.sum() > 0


def test_culling_hull_contains_the_part():
    import trimesh
    from scipy.spatial import Delaunay

    from vpp_core.trace.raytrace import _hull_points

    mesh = trimesh.creation.torus(major_radius=60, minor_radius=15)
    mesh.apply_translation([10, -300, 40])
    hull = Delaunay(_hull_points(mesh.vertices))
    assert (hull.find_simplex(mesh.vertices) >= 0).all()


@pytest.mark.parametrize("tilt", [0.0, 50.0])
def test_expected_ray_density_matches_the_traced_rays_per_area(tilt):
    # a 20 mm plate seen 18.5° off-axis, flat or tilted: R / A against the pinhole
    # density Cameras.ray_density gives at its centre, the patch rows' sampled share
    part = plate_part(side=20.0, tilt_deg=tilt)
    views = look_down((120.0, 60.0, 400.0))
    traced = counts(part, PAPER, views).sum() / part.areas.sum()
    normal = part.normals[:1]
    expected = Cameras(views, PAPER).ray_density(np.zeros((1, 3)), normal, np.zeros(1, int))
    assert traced == pytest.approx(expected[0], rel=0.02)


def test_views_that_hold_a_patch_whole_cover_its_row_whatever_the_pixel_grid():
    # a 61 mm plate of 6.1 mm square patches (two triangles each) under two head-on cameras
    # at 410 mm (0.15 mm pixels, 40.7 pixels a patch side), 1.6 mm apart: each puts 40 or 41
    # rows and columns of rays on a patch, so one may count 40² where the other counts 41²
    # (3 % fewer) on a patch both frames hold whole. Both cover its row whole. A third camera
    # whose frame's edge halves a column of patches covers half of their rows, and nothing
    # of those beyond the edge
    from vpp_core.cover.density import cover_model
    from vpp_core.cover.patches import Patches

    part = plate_part(side=61.0, n=10)
    quads = np.tile(np.arange(100), 2)  # faces k and k + 100 make quad k (plate())
    centres = np.zeros((100, 3))
    np.add.at(centres, quads, part.vertices[part.faces].mean(axis=1) * part.areas[:, None] / 6.1**2)
    normals = np.tile([0.0, 0.0, 1.0], (100, 1))
    patches = Patches(quads, np.full(100, 6.1**2), 6.1, centres, normals)
    frame = 410.0 * PAPER.width_px / PAPER.fx
    views = look_down((0.37, 0.61, 410.0), (2.0, 1.3, 410.0), (3.05 - frame / 2, 0.0, 410.0))
    r = trace_counts(part, PAPER, views).counts
    rays = patches.sum_rows(r).toarray()
    assert (rays[:, 0] != rays[:, 1]).sum() > 20 and rays[:, :2].min() <= 0.97 * rays.max()
    res = PAPER.pixel_pitch_mm(410.0) * 1.2
    args = (part.areas, part.counted, res, "density", patches, None, Cameras(views, PAPER))
    model = cover_model(r, *args)
    assert (model.faces[:100] == np.arange(100)).all()  # every patch is seen
    s = model.matrix.toarray()[model.face_row[:100]]
    assert (s[:, :2] == 1.0).all()
    half, beyond = np.isclose(centres[:, 0], 3.05), centres[:, 0] > 6.1
    assert s[half, 2] == pytest.approx(0.5, rel=0.05) and (s[beyond, 2] == 0).all()
