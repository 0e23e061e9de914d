"""The cameras' roll (vpp_core.candidates.roll): the image's long side along the surface."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import GeneratorSettings, generate
from vpp_core.candidates.roll import fitted, surface_samples
from vpp_core.candidates.sphere import view_sphere
from vpp_core.mesh.part import part_from_arrays
from vpp_core.plan.document import PlanRequest

SENSOR = Sensor()
AXIS = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)  # a bar lying neither level nor upright


def bar(axis=AXIS, length=600.0, width=30.0):
    """A square bar (mm) centred at the origin along `axis`, longer than the frames' width."""
    m = trimesh.creation.box((length, width, width))
    z = np.cross([1.0, 0.0, 0.0], axis)
    angle = np.arccos(np.clip(axis[0], -1, 1))
    m.apply_transform(trimesh.transformations.rotation_matrix(angle, z))
    return part_from_arrays(m.vertices, m.faces)


def framed(views, part, sensor=SENSOR):
    """(N,) surface samples of `part` facing each view inside its frame: pinhole projection."""
    points, normals = surface_samples(part, 20_000)
    rot = views.rotations()
    cam = np.einsum("nij,nki->nkj", rot, points[None, :, :] - views.positions[:, None, :])
    facing = np.einsum("kj,nj->nk", normals, views.gazes) < 0
    z = np.maximum(cam[..., 2], 1e-9)
    tx, ty = np.tan(np.radians([sensor.fov_x_deg, sensor.fov_y_deg]) / 2)
    inside = (np.abs(cam[..., 0] / z) <= tx) & (np.abs(cam[..., 1] / z) <= ty)
    return (facing & inside & (cam[..., 2] > 0)).sum(axis=1)


@pytest.mark.parametrize("axis", [AXIS, np.array([0.0, 0.0, 1.0])])
def test_a_long_part_is_framed_whichever_way_it_lies(axis):
    part = bar(axis)
    settings = GeneratorSettings(count=80, seed=0, tilt_deg=30.0, standoff_mm=450.0)
    world = generate(part, SENSOR, settings).views
    turned = generate(part, SENSOR, GeneratorSettings(**{**settings.__dict__, "fit_roll": True}))
    before, after = framed(world, part), framed(turned.views, part)
    assert (after >= 0.97 * before).all()  # no view frames less (up to the samples' noise)
    across = np.abs(world.gazes @ axis) < 0.5  # a level frame across a bar standing up
    assert np.median(after[across] / before[across]) > (1.4 if axis[2] == 1 else 1.05)
    # the same cameras, only turned about their gazes
    assert np.array_equal(world.positions, turned.views.positions)
    assert np.allclose(world.gazes, turned.views.gazes, atol=1e-12)
    # of the two rolls that frame the same, the more upright one
    assert (np.einsum("ij,ij->i", turned.views.ups, world.ups) >= 0).all()


def test_a_surface_that_fills_the_frame_either_way_keeps_the_world_up():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=60.0)  # inside every frame
    part = part_from_arrays(ball.vertices, ball.faces)
    views = view_sphere(part, SENSOR, 60, fit_roll=False)
    assert np.array_equal(view_sphere(part, SENSOR, 60, fit_roll=True).ups, views.ups)  # to the bit
    plate = trimesh.creation.box((3000.0, 3000.0, 10.0))  # larger than every frame
    part = part_from_arrays(plate.vertices, plate.faces)
    rng = np.random.default_rng(2)
    aims = np.column_stack([rng.uniform(-900, 900, (20, 2)), np.full(20, 5.0)])
    gazes = np.array([0.3, -0.2, -1.0]) + rng.normal(scale=0.1, size=(20, 3))
    gazes /= np.linalg.norm(gazes, axis=1)[:, None]
    views = make_viewpoints(aims - 450.0 * gazes, gazes)
    same = fitted(views, SENSOR, surface_samples(part, 40_000), 450.0)
    assert np.array_equal(same.ups, views.ups)  # the views tile with one orientation


def test_a_long_thin_bar_is_framed_along_the_diagonal():
    part = bar(np.array([0.0, 0.0, 1.0]))  # 600 mm standing, in a 316 × 202 mm frame
    views = make_viewpoints([[-450.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])
    turned = fitted(views, SENSOR, surface_samples(part), 450.0)
    diagonal = np.degrees(np.arctan2(SENSOR.height_px, SENSOR.width_px))  # 32°: the longest line
    along = np.degrees(np.arccos(abs(turned.rotations()[0, :, 0] @ [0.0, 0.0, 1.0])))
    assert abs(along - diagonal) <= 7.5  # the nearest of the turns tried every 15°


def test_a_square_sensor_has_no_long_side():
    square = SENSOR.model_copy(update={"width_px": 1000, "height_px": 1000})
    views = make_viewpoints([[0.0, -450.0, 0.0]], [[0.0, 1.0, 0.0]])
    assert fitted(views, square, surface_samples(bar()), 450.0) is views


@pytest.mark.parametrize(("profile", "roll"), [("default", "fitted"), ("paper", "world")])
def test_the_profile_chooses_the_roll_and_a_request_may_say(profile, roll):
    assert PlanRequest(profile=profile).candidates.roll == roll
    other = "world" if roll == "fitted" else "fitted"
    asked = PlanRequest(profile=profile, candidates={"roll": other})
    assert asked.candidates.roll == other
