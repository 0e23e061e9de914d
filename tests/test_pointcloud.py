"""The simulated point cloud (SPEC §5, paper Fig. 4) against the pinhole camera and R."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tests.conftest import plate_part
from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.report.pointcloud import neighbour_counts, simulate, write_ply
from vpp_core.trace.raytrace import make_backend, trace_counts

PAPER = Sensor()


@pytest.mark.parametrize("backend", ["raster", "embree"])
@pytest.mark.parametrize("depth", [400.0, 500.0])
def test_flat_plate_spacing_is_the_pixel_footprint(backend: str, depth: float) -> None:
    part = plate_part(side=30.0)
    views = make_viewpoints(np.array([[0.0, 0.0, depth]]), np.array([[0.0, 0.0, -1.0]]))
    cloud, counts, stats = simulate(
        part, PAPER, views, make_backend(part, backend), 0.18, max_points=10**7
    )
    footprint = PAPER.pixel_pitch_mm(depth)  # SPEC §7: 2 d tan(fov/2) / pixels
    assert stats.spacing_mean_mm == pytest.approx(footprint, rel=0.02)
    # all points on the plate, one per pixel centre inside it
    assert np.abs(cloud.points[:, 2]).max() < 1e-3
    assert np.abs(cloud.points[:, :2]).max() <= 15.0 + 1e-3
    assert stats.points == int(trace_counts(part, PAPER, views).counts.sum())
    # a regular grid of pitch p: within r = 0.18 < p no neighbours at 500 mm, 4 at 400 mm
    # (0.146 < 0.18 < 0.146·√2) except on the border
    inner = np.abs(cloud.points[:, :2]).max(axis=1) < 14.0
    expected = 4 if footprint < 0.18 < footprint * math.sqrt(2) else 0
    assert (counts[inner] == expected).all()


def test_points_per_view_equal_r_column_sums() -> None:
    part = plate_part(side=40.0, n=6, tilt_deg=30.0)
    pos = np.array([[0.0, 0.0, 500.0], [80.0, 0.0, 480.0], [0.0, -120.0, 450.0]])
    views = make_viewpoints(pos, -pos / np.linalg.norm(pos, axis=1, keepdims=True))
    for name in ("raster", "embree"):
        backend = make_backend(part, name)
        r = trace_counts(part, PAPER, views, backend=backend).counts
        cloud, _, stats = simulate(part, PAPER, views, backend, 0.18, max_points=10**7)
        assert stats.per_view == np.asarray(r.sum(axis=0)).ravel().tolist()
        # every point lies on the face the backend says it hit: on the plate's plane
        normal = part.normals[0]
        assert np.abs((cloud.points - part.vertices[0]) @ normal).max() < 1e-3


def test_neighbour_counts_match_a_brute_force_kdtree_across_slabs(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    rng = np.random.default_rng(3)
    pts = (rng.random((20_000, 3)) * [10.0, 3.0, 1.0]).astype(np.float32)
    monkeypatch.setattr("vpp_core.report.pointcloud.SLAB_POINTS", 1_500)  # many slabs
    counts, nearest = neighbour_counts(pts, 0.12)
    tree = cKDTree(pts.astype(np.float64))
    truth = tree.query_ball_point(pts.astype(np.float64), 0.12, return_length=True) - 1
    assert np.array_equal(counts, truth)
    d, _ = tree.query(pts.astype(np.float64), k=2)
    reach = d[:, 1] <= 0.36
    assert np.allclose(nearest[reach], d[reach, 1])
    assert np.isinf(nearest[~reach]).all()


def test_ply_is_read_back_by_trimesh() -> None:
    import trimesh

    part = plate_part(side=10.0)
    views = make_viewpoints(np.array([[0.0, 0.0, 500.0]]), np.array([[0.0, 0.0, -1.0]]))
    cloud, counts, _ = simulate(part, PAPER, views, make_backend(part), 0.2, max_points=10**6)
    buf = io.BytesIO()
    write_ply(buf, cloud, counts)
    back = trimesh.load(io.BytesIO(buf.getvalue()), file_type="ply")
    assert np.allclose(back.vertices, cloud.points)
    assert np.array_equal(back.metadata["_ply_raw"]["vertex"]["data"]["neighbours"], counts)


def test_point_limit_is_refused() -> None:
    from vpp_core.errors import LimitError

    part = plate_part(side=30.0)
    views = make_viewpoints(np.array([[0.0, 0.0, 500.0]]), np.array([[0.0, 0.0, -1.0]]))
    with pytest.raises(LimitError, match="point cloud"):
        simulate(part, PAPER, views, make_backend(part), 0.18, max_points=1000)
