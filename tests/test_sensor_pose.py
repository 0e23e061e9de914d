"""Sensor validation and intrinsics; pose convention (SPEC §8)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor, make_sensor
from vpp_core.errors import SensorError, ViewpointError


def test_defaults_are_the_paper_camera():
    s = make_sensor()
    assert (s.width_px, s.height_px, s.fov_x_deg, s.fov_y_deg) == (1920, 1200, 38.7, 24.75)
    assert (s.near_mm, s.far_mm, s.max_incidence_deg, s.working_distance_mm) == (300, 700, 75, 500)


@pytest.mark.parametrize(
    "bad, where",
    [
        ({"fov_x_deg": 180}, "fov_x_deg"),
        ({"fov_y_deg": 0}, "fov_y_deg"),
        ({"near_mm": 700, "far_mm": 300}, "near_mm"),
        ({"width_px": 0}, "width_px"),
        ({"height_px": -3}, "height_px"),
        ({"max_incidence_deg": 95}, "max_incidence_deg"),
        ({"working_distance_mm": 900}, "working_distance_mm"),
        ({"pixels": 3}, "pixels"),
        ({"near_mm": "abc"}, "near_mm"),
    ],
)
def test_nonsense_sensor_is_rejected_with_a_clear_message(bad, where):
    with pytest.raises(SensorError, match=where):
        make_sensor(bad)


def test_pixel_rays_follow_the_opencv_intrinsics():
    s = Sensor(width_px=4, height_px=2, fov_x_deg=90, fov_y_deg=60)
    assert s.fx == pytest.approx(2.0) and s.fy == pytest.approx(1 / math.tan(math.radians(30)))
    rays = s.camera_rays.reshape(2, 4, 3)
    # pixel (u=0, v=0) is top-left: x < 0 (left), y < 0 (up), z = 1
    assert rays[0, 0].tolist() == pytest.approx([(0.5 - 2) / 2, (0.5 - 1) / s.fy, 1.0])
    assert rays[1, 3].tolist() == pytest.approx([(3.5 - 2) / 2, (1.5 - 1) / s.fy, 1.0])


def test_a_copy_with_changed_fields_computes_its_own_pixel_rays_and_is_validated():
    sensor = Sensor(width_px=64, height_px=40)
    assert sensor.camera_rays.shape == (64 * 40, 3)  # cached on the original
    half = sensor.model_copy(update={"width_px": 32, "height_px": 20})
    assert half.camera_rays.shape == (32 * 20, 3) and half.pixel_x.shape == (32,)
    np.testing.assert_allclose(half.pixel_x[-1], (31.5 - 16) / half.fx)
    assert half.working_distance == sensor.working_distance
    assert sensor.model_copy() == sensor
    with pytest.raises(ValueError):
        sensor.model_copy(update={"near_mm": 800.0})  # beyond far_mm


def test_default_up_is_world_z_projected_and_frame_is_right_handed():
    v = make_viewpoints([[500, 0, 0]], [[-1, 0, 0]])
    m = v.camera_to_world()[0]
    x, y, z = m[:3, 0], m[:3, 1], m[:3, 2]
    assert z.tolist() == pytest.approx([-1, 0, 0])
    assert (-y).tolist() == pytest.approx([0, 0, 1])  # image up = world +Z
    assert np.cross(x, y).tolist() == pytest.approx(z.tolist())
    assert x.tolist() == pytest.approx([0, 1, 0])  # looking along -X with Z up, right is +Y


def test_up_falls_back_to_y_when_gaze_is_vertical():
    v = make_viewpoints([[0, 0, 500]], [[0, 0, -1]])
    assert v.ups[0].tolist() == pytest.approx([0, 1, 0])


def test_given_up_is_orthogonalised_and_parallel_up_is_rejected():
    v = make_viewpoints([[0, 0, 0]], [[1, 0, 0]], [[0.3, 0, 2]])
    assert v.ups[0].tolist() == pytest.approx([0, 0, 1])
    with pytest.raises(ViewpointError, match="parallel"):
        make_viewpoints([[0, 0, 0]], [[1, 0, 0]], [[2, 0, 0]])
    with pytest.raises(ViewpointError, match="zero"):
        make_viewpoints([[0, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ViewpointError, match="finite"):
        make_viewpoints([[np.nan, 0, 0]], [[1, 0, 0]])
