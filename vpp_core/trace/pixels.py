"""SPEC §3 on a window of pixel rays whose first hits are known.

The pixel backends (`vpp_core.trace.raster`, `vpp_core.trace.packets`) find the first face hit
through each pixel centre of a window and its depth; the checks and the counting per face are the
same for both, and compiled here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vpp_core.jit import inline, kernel
from vpp_core.trace.rays import Block, Hits, PixelHits

Triple = tuple[float, float, float]


@dataclass(frozen=True)
class FirstHits:
    """The first face hit through each pixel of a block's window, and at what depth."""

    block: Block
    ids: np.ndarray  # (h, w) int32 face id, -1 = none within far
    inv_z: np.ndarray  # (h, w) float64 1 / depth (1/mm)

    def counts(self, normals: np.ndarray) -> Hits:
        """Faces (k,) int32 of the valid rays (SPEC §3) and their counts (k,) int32;
        normals (M, 3) float64 unit face normals."""
        faces, counts, _ = self._check(normals, store=False)
        return faces, counts

    def valid(self, normals: np.ndarray) -> PixelHits:
        """The valid rays one by one: pixel within the window, face and depth (mm)."""
        pixels = np.flatnonzero(self._check(normals, store=True)[2])
        return PixelHits(pixels, self.ids.reshape(-1)[pixels], 1.0 / self.inv_z.reshape(-1)[pixels])

    def _check(self, normals: np.ndarray, store: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_check` on these hits with the block's camera and sensor."""
        sensor = self.block.sensor
        return _check(
            self.ids,
            self.inv_z,
            normals,
            np.ascontiguousarray(self.block.rotation, dtype=np.float64),
            sensor.pixel_x,
            sensor.pixel_y,
            window_of(self.block),
            sensor.near_mm,
            math.cos(math.radians(sensor.max_incidence_deg)),
            store,
        )


def window_of(block: Block) -> np.ndarray:
    """(4,) int64 rows v0, v1 and columns u0, u1 of the block."""
    return np.array([*block.rows, *block.cols], dtype=np.int64)


@inline
def _is_valid(
    f: int,
    inv_z: float,
    normals: np.ndarray,
    rotation: np.ndarray,
    row: Triple,
    x: float,
    y: float,
    near: float,
    cos2: float,
) -> bool:
    """SPEC §3 on one pixel ray (x, y, 1) that first hits face f at 1/depth inv_z: depth >= near
    and |cos incidence| >= cos_min (cos2 = cos_min²); row = rotation @ (0, y, 1)."""
    if f < 0 or inv_z * near > 1.0:
        return False
    dot = (
        normals[f, 0] * (rotation[0, 0] * x + row[0])
        + normals[f, 1] * (rotation[1, 0] * x + row[1])
        + normals[f, 2] * (rotation[2, 0] * x + row[2])
    )
    return bool(dot * dot >= cos2 * (x * x + y * y + 1.0))


@inline
def row_direction(rotation: np.ndarray, y: float) -> Triple:
    """rotation @ (0, y, 1): the part of a pixel ray's world direction shared by its row."""
    return (
        rotation[0, 1] * y + rotation[0, 2],
        rotation[1, 1] * y + rotation[1, 2],
        rotation[2, 1] * y + rotation[2, 2],
    )


@kernel
def _check(
    ids: np.ndarray,
    inv_z: np.ndarray,
    normals: np.ndarray,
    rotation: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    window: np.ndarray,
    near: float,
    cos_min: float,
    store: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces (k,) int32 whose pixels are valid (depth >= near, incidence) and their counts
    (k,); with `store` also the (h, w) bool mask of the valid pixels, else an empty one."""
    counts = np.zeros(normals.shape[0], np.int32)
    h, w = ids.shape
    mask = np.zeros((h, w) if store else (0, 0), np.bool_)
    cos2 = cos_min * cos_min
    for i in range(h):
        y = float(py[window[0] + i])
        row = row_direction(rotation, y)
        for j in range(w):
            x = float(px[window[2] + j])
            if _is_valid(ids[i, j], inv_z[i, j], normals, rotation, row, x, y, near, cos2):
                counts[ids[i, j]] += 1
                if store:
                    mask[i, j] = True
    faces = np.flatnonzero(counts).astype(np.int32)
    return faces, counts[faces], mask
