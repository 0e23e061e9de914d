"""The plan judged at surface points (vpp_core.plan.pointseen), against geometry by hand."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import Part, part_from_arrays
from vpp_core.plan.pointseen import MIN_GAIN, fill, least_gain, sees, surface_points
from vpp_core.trace.embree import EmbreeBackend

SMALL = Sensor(width_px=320, height_px=200, fov_x_deg=38.7, fov_y_deg=24.75)


def squares(corners: list[tuple[float, float, float, float]], z: float = 0.0) -> trimesh.Trimesh:
    """Squares facing +z at height z, each (x0, y0, x1, y1) mm, two triangles each."""
    v, f = [], []
    for x0, y0, x1, y1 in corners:
        k = len(v)
        v += [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
        f += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    return trimesh.Trimesh(np.array(v, dtype=float), np.array(f), process=False)


def part_of(*meshes: trimesh.Trimesh) -> Part:
    """The meshes as one part."""
    mesh = trimesh.util.concatenate(list(meshes))
    return part_from_arrays(mesh.vertices, mesh.faces)


def looking_down(xy: list[tuple[float, float]], height: float = 400.0):
    """Cameras `height` mm above the points (x, y, 0), looking down, image-up +y."""
    n = len(xy)
    pos = np.array([(x, y, height) for x, y in xy], dtype=float)
    gaze = np.tile([0.0, 0.0, -1.0], (n, 1))
    return make_viewpoints(pos, gaze, np.tile([0.0, 1.0, 0.0], (n, 1)))


def one(views):
    """The first view's position and camera-to-world rotation, as `sees` takes them."""
    return views.positions[0], views.rotations()[0]


def test_points_are_uniform_by_area_on_the_wanted_faces():
    part = part_of(squares([(0, 0, 10, 10), (20, 0, 40, 30), (50, 0, 60, 10)]))
    wanted = np.array([True, True, True, True, False, False])  # the third square is not
    pts = surface_points(part, wanted, 20_000)
    assert set(np.unique(pts.faces)) == {0, 1, 2, 3}
    on_big = np.isin(pts.faces, [2, 3]).mean()
    assert on_big == pytest.approx(600 / 700, abs=4 * np.sqrt(0.14 * 0.86 / 20_000))
    x, y = pts.xyz[:, 0], pts.xyz[:, 1]
    small = pts.faces < 2
    assert np.all((x[small] >= 0) & (x[small] <= 10) & (y[small] >= 0) & (y[small] <= 10))
    assert np.all((x[~small] >= 20) & (x[~small] <= 40) & (y[~small] <= 30))
    assert np.all(pts.xyz[:, 2] == 0) and np.allclose(pts.normals, [0, 0, 1])
    # within the big square, uniform: each half by x holds half its points
    assert (x[~small] < 30).mean() == pytest.approx(0.5, abs=0.03)
    again = surface_points(part, wanted, 20_000)
    assert np.array_equal(again.xyz, pts.xyz)  # seeded: the CLI and the service judge the same


def test_a_point_is_seen_unless_a_blocker_hides_it_or_it_lies_outside_the_frame():
    plate = squares([(-150, -150, 150, 150)])
    lid = squares([(-20, -20, 20, 20)], z=50.0)
    lid.faces = lid.faces[:, ::-1]  # facing down at the plate
    part = part_of(plate, lid)
    pts = surface_points(part, np.arange(part.n_faces) < 2, 20_000)
    view = looking_down([(0.0, 0.0)])
    got = sees(SMALL, *one(view), pts, EmbreeBackend(part))
    # by hand: the line from (0, 0, 400) to (x, y, 0) crosses z = 50 at 7/8 of (x, y)
    x, y = pts.xyz[:, 0], pts.xyz[:, 1]
    hidden = (np.abs(x) * 7 / 8 < 20) & (np.abs(y) * 7 / 8 < 20)
    half_w = 400 * SMALL.width_px / 2 / SMALL.fx  # the frame's half width at the plate, mm
    half_h = 400 * SMALL.height_px / 2 / SMALL.fy
    framed = (np.abs(x) < half_w) & (np.abs(y) < half_h)
    edge = (np.abs(np.abs(x) - half_w) < 0.5) | (np.abs(np.abs(y) - half_h) < 0.5)
    edge |= (np.abs(np.abs(x) * 7 / 8 - 20) < 0.1) | (np.abs(np.abs(y) * 7 / 8 - 20) < 0.1)
    assert hidden.sum() > 300 and (~framed).sum() > 300  # both cases are exercised
    assert np.array_equal(got[~edge], (framed & ~hidden)[~edge])


def test_a_point_beyond_the_incidence_limit_or_the_depth_of_field_is_not_seen():
    part = part_of(squares([(-50, -50, 50, 50)]))
    pts = surface_points(part, np.ones(2, bool), 2_000)
    backend = EmbreeBackend(part)
    steep = np.radians(SMALL.max_incidence_deg + 5)  # the gaze beyond the limit off the normal
    pos = 400 * np.array([[np.sin(steep), 0, np.cos(steep)]])
    grazing = make_viewpoints(pos, -pos / 400, np.array([[0.0, 0.0, 1.0]]))
    far, near = looking_down([(0, 0)], SMALL.far_mm + 20), looking_down([(0, 0)])
    assert not sees(SMALL, *one(grazing), pts, backend).any()
    assert not sees(SMALL, *one(far), pts, backend).any()
    assert sees(SMALL, *one(near), pts, backend).all()


def test_fill_adds_the_views_that_see_area_in_bulk_not_slivers():
    # squares 1 m apart, one camera above each; the third holds MIN_GAIN of the area, which
    # 20 000 points cannot tell from noise, the fourth three times as much
    small, bulk = (np.sqrt(k * MIN_GAIN * 2 * 100**2) for k in (1.0, 3.0))
    part = part_of(
        squares(
            [
                (0, 0, 100, 100),
                (1000, 0, 1100, 100),
                (2000, 0, 2000 + small, small),
                (3000, 0, 3000 + bulk, bulk),
            ]
        )
    )
    pts = surface_points(part, np.ones(part.n_faces, bool), 20_000)
    views = looking_down([(50, 50), (1050, 50), (2000, 0), (3000, 0)])
    on = [np.isin(pts.faces, [2 * k, 2 * k + 1]) for k in range(4)]
    assert least_gain(20_000) > on[2].sum() and on[3].sum() > least_gain(20_000)
    seen = fill(SMALL, views, np.array([0]), pts, EmbreeBackend(part))
    assert seen.added == [1, 3]  # the most first
    assert seen.points == 20_000
    assert seen.seen == on[0].sum() + on[1].sum() + on[3].sum()
    assert seen.reach == 20_000
    expected = np.column_stack([on[0], on[1], np.zeros(20_000, bool), on[3]])  # 2: not added
    assert np.array_equal(seen.matrix.toarray() > 0, expected)
    nothing = fill(SMALL, views, np.arange(4), pts, EmbreeBackend(part))
    assert nothing.added == [] and nothing.seen == nothing.reach == 20_000
