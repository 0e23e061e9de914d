"""What a ray backend is: first hits of arbitrary rays, and the valid hits of blocks of pixels.

A pixel ray is valid on face i (SPEC §3) when i is its first hit, the hit depth lies in
[near, far] and the angle between ray and face normal is at most `max_incidence` (|cos|, so
orientation does not matter). Pixel rays are (x, y, 1) in the camera frame, so the hit
parameter t is the depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, get_args

import numpy as np

from vpp_core.camera.sensor import Sensor

BackendName = Literal["raster", "packets", "embree"]
"""The ray backends (vpp_core.trace.raytrace.make_backend); the first is the default."""

DEFAULT_BACKEND: BackendName = get_args(BackendName)[0]
"""The fastest backend (docs/raytrace.md): the CLI's and the plan request's default."""


@dataclass(frozen=True)
class Block:
    """A rectangle of one view's pixels and the camera that sees it: one tracing task."""

    sensor: Sensor
    position: np.ndarray  # (3,) float64 camera centre, mm
    rotation: np.ndarray  # (3, 3) float64 camera-to-world (columns = camera x, y, z)
    rows: tuple[int, int]  # image rows v0:v1
    cols: tuple[int, int]  # image columns u0:u1


Hits = tuple[np.ndarray, np.ndarray | None]
"""Face ids (k,) int32 of a block's valid rays, and per id its ray count (k,) int32 or None
(then each id stands for one ray and ids repeat)."""


@dataclass(frozen=True)
class PixelHits:
    """A block's valid pixel rays one by one (the point cloud's source)."""

    pixels: np.ndarray  # (h,) int64 row-major index of the pixel within the block
    faces: np.ndarray  # (h,) int32 face hit
    depth: np.ndarray  # (h,) float camera-frame z of the hit, mm (ray (x, y, 1): t = z)


class RayBackend(Protocol):
    """First hits over one mesh: of arbitrary rays, and of the pixel rays of a camera."""

    name: str
    block_rays: int  # a view is traced in blocks of whole rows of about this many pixels

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss) and hit parameter t (n,) float32 of rays from origin."""
        ...

    def valid_hits(self, block: Block) -> Hits:
        """The faces hit by valid pixel rays of the block (SPEC §3), before duplicate merging."""
        ...

    def pixel_hits(self, block: Block) -> PixelHits:
        """The valid pixel rays of the block one by one, the same rays `valid_hits` counts."""
        ...
