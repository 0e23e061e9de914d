"""The pinhole camera (SPEC §2, §8): specification, intrinsics and per-pixel rays.

Camera frame (OpenCV): x right (image columns grow), y down (rows grow), z forward
along the gaze. Pixel (u, v) is seen along ((u+0.5-W/2)/fx, (v+0.5-H/2)/fy, 1); with
z = 1 the ray parameter t of a hit *is* its depth along the optical axis.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import cached_property
from typing import Any, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from vpp_core.errors import SensorError


def _midpoint(a: float, b: float) -> float:
    """(a + b) / 2, also where a + b overflows (near_mm, far_mm close to the float range)."""
    mid = (a + b) / 2
    return mid if math.isfinite(mid) else a / 2 + b / 2


class Sensor(BaseModel):
    """A pinhole camera; lengths in mm, angles in degrees; defaults are the paper's camera."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    width_px: int = Field(1920, ge=1, le=20_000, description="image width in pixels")
    height_px: int = Field(1200, ge=1, le=20_000, description="image height in pixels")
    fov_x_deg: float = Field(38.7, gt=0, lt=180, description="horizontal field of view")
    fov_y_deg: float = Field(24.75, gt=0, lt=180, description="vertical field of view")
    near_mm: float = Field(300.0, gt=0, description="depth of field, near limit (depth on z)")
    far_mm: float = Field(700.0, gt=0, description="depth of field, far limit (depth on z)")
    max_incidence_deg: float = Field(75.0, gt=0, le=90, description="largest angle ray/normal")
    working_distance_mm: float | None = Field(
        None, gt=0, description="camera-to-target distance of generated candidates; default mid DOF"
    )

    @model_validator(mode="after")
    def _check(self) -> Sensor:
        if self.near_mm >= self.far_mm:
            raise ValueError(f"near_mm ({self.near_mm}) must be less than far_mm ({self.far_mm})")
        wd = self.working_distance_mm
        if wd is not None and not self.near_mm <= wd <= self.far_mm:
            raise ValueError(f"working_distance_mm ({wd}) must lie in [near_mm, far_mm]")
        if wd is None:
            object.__setattr__(self, "working_distance_mm", _midpoint(self.near_mm, self.far_mm))
        return self

    @property
    def working_distance(self) -> float:
        """Working distance in mm (filled in by validation)."""
        return float(self.working_distance_mm or _midpoint(self.near_mm, self.far_mm))

    @property
    def fx(self) -> float:
        """Focal length in pixels along x."""
        return (self.width_px / 2) / math.tan(math.radians(self.fov_x_deg) / 2)

    @property
    def fy(self) -> float:
        """Focal length in pixels along y."""
        return (self.height_px / 2) / math.tan(math.radians(self.fov_y_deg) / 2)

    @property
    def half_tangents(self) -> tuple[float, float]:
        """tan of half the field of view along x and y: the frame's half-width and
        half-height per mm of depth."""
        return self.width_px / (2 * self.fx), self.height_px / (2 * self.fy)

    def frame_mm(self, depth_mm: float) -> tuple[float, float]:
        """Width and height (mm) of the frame on a plane facing the camera `depth_mm` away."""
        tx, ty = self.half_tangents
        return 2 * depth_mm * tx, 2 * depth_mm * ty

    @property
    def n_pixels(self) -> int:
        """Rays per view."""
        return self.width_px * self.height_px

    def pixel_pitch_mm(self, depth_mm: float) -> float:
        """Footprint of one pixel along x at a given depth (mm), SPEC §7."""
        return 2 * depth_mm * math.tan(math.radians(self.fov_x_deg) / 2) / self.width_px

    def model_copy(self, *, update: Mapping[str, Any] | None = None, deep: bool = False) -> Self:
        """A copy; with `update`, a new Sensor validated from the changed fields, so that the
        pixel rays cached on this one (cached_property) are not carried over to another
        image size or field of view."""
        if not update:
            return super().model_copy(deep=deep)
        return type(self).model_validate({**self.model_dump(), **update})

    @cached_property
    def pixel_x(self) -> np.ndarray:
        """(W,) float32 camera-frame x of each pixel column's ray at z = 1."""
        u = (np.arange(self.width_px) + 0.5 - self.width_px / 2) / self.fx
        return u.astype(np.float32)

    @cached_property
    def pixel_y(self) -> np.ndarray:
        """(H,) float32 camera-frame y of each pixel row's ray at z = 1."""
        v = (np.arange(self.height_px) + 0.5 - self.height_px / 2) / self.fy
        return v.astype(np.float32)

    @cached_property
    def camera_rays(self) -> np.ndarray:
        """(H*W, 3) float32 ray directions in the camera frame, z = 1, row-major over (v, u)."""
        rays = np.empty((self.height_px, self.width_px, 3), dtype=np.float32)
        rays[..., 0] = self.pixel_x[None, :]
        rays[..., 1] = self.pixel_y[:, None]
        rays[..., 2] = 1.0
        return rays.reshape(-1, 3)

    @cached_property
    def camera_ray_norms(self) -> np.ndarray:
        """(H, W) float32 lengths of `camera_rays`."""
        norms = np.linalg.norm(self.camera_rays, axis=1).reshape(self.height_px, self.width_px)
        return np.asarray(norms, dtype=np.float32)


def make_sensor(spec: dict[str, object] | None = None) -> Sensor:
    """Validate a sensor specification (a JSON object) into a Sensor, or raise SensorError."""
    try:
        return Sensor.model_validate(spec or {})
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "sensor"
        raise SensorError(f"{where}: {first['msg']}") from None
