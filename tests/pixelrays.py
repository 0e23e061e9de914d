"""Pixel-centre ray directions in the camera frame, written independently of vpp_core.trace
(SPEC §3: x right, y down, z along the gaze), for the tests that re-trace plans themselves."""

from __future__ import annotations

import math

import numpy as np

from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import Part


def camera_rays(sensor: Sensor) -> np.ndarray:
    """(H·W, 3) unnormalised directions (u, v, 1) through every pixel centre, row by row."""
    u = (np.arange(sensor.width_px) + 0.5 - sensor.width_px / 2) / sensor.fx
    v = (np.arange(sensor.height_px) + 0.5 - sensor.height_px / 2) / sensor.fy
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])


def valid_counts(
    part: Part, sensor: Sensor, m: np.ndarray, dirs: np.ndarray, hits: tuple
) -> np.ndarray:
    """(M,) valid rays per face of `part` (SPEC §3: depth within the depth of field along the
    gaze, incidence within the limit; duplicates counted on their representative) from the
    first hits (tri, ray, location) of the rays `dirs` (P, 3) cast from the camera at 4 × 4 m."""
    tri, ray, loc = hits
    depth = (loc - m[:3, 3]) @ m[:3, 2]
    unit = dirs[ray] / np.linalg.norm(dirs[ray], axis=1)[:, None]
    cos = np.abs(np.einsum("ij,ij->i", unit, part.normals[tri]))
    ok = (
        (depth >= sensor.near_mm)
        & (depth <= sensor.far_mm)
        & (cos >= math.cos(math.radians(sensor.max_incidence_deg)))
    )
    return np.bincount(part.representative[tri[ok]], minlength=part.n_faces)
