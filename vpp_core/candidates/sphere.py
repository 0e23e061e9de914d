"""The view-sphere baseline: cameras spread evenly on spheres around the part, looking at it.

What a generator has to reach (SPEC §2 amended): `count` viewpoints on Fibonacci spheres
centred on the part's bounding box, at the working distance from the centre (farther when
the part is larger than the near limit allows), looking at the centre; with `shells` > 1
the spheres are at distances spread over the depth of field, the views split among them.
"""

from __future__ import annotations

import numpy as np

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.roll import fitted, surface_samples
from vpp_core.cell.reach import Allowed
from vpp_core.mesh.part import Part


def fibonacci_directions(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * k / count)
    azimuth = np.pi * (1 + 5**0.5) * k
    return np.column_stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)]
    )


def view_sphere(
    part: Part,
    sensor: Sensor,
    count: int = 1000,
    shells: int = 2,
    allowed: Allowed | None = None,
    fit_roll: bool = False,
) -> Viewpoints:
    """`count` viewpoints on `shells` spheres around the part's box centre (mm, part frame),
    less those `allowed` (the setup's vpp_core.cell.reach predicate) refuses; with
    `fit_roll`, turned about their gazes as vpp_core.candidates.roll turns the generator's."""
    lo, hi = part.bounds
    centre = (lo + hi) / 2
    half = float(np.linalg.norm(hi - lo)) / 2
    radii = np.linspace(
        sensor.near_mm + half, max(sensor.working_distance, sensor.near_mm + half), shells
    )
    split = np.array_split(np.arange(count), shells)
    positions, gazes, depths = [], [], []
    for radius, ids in zip(radii, split, strict=True):
        d = fibonacci_directions(len(ids))
        positions.append(centre + radius * d)
        gazes.append(-d)
        depths.append(np.full(len(ids), radius))
    views, depth = make_viewpoints(np.vstack(positions), np.vstack(gazes)), np.concatenate(depths)
    if allowed is not None:  # the views a setup refuses are not turned
        kept = np.flatnonzero(allowed(views.positions))
        views, depth = views.take(kept), depth[kept]
    return fitted(views, sensor, surface_samples(part), depth) if fit_roll else views
