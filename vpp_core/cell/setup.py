"""The `setup` of a plan request (SETUP.json), validated strictly: every number finite,
transforms rigid, boxes with min < max; every key optional, and no setup plans as before.

Frames: `part_to_cell` maps the part's (mesh) frame into the cell frame; every other
coordinate here is in the cell frame, mm.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from vpp_core.robot.model import LIMIT_MM, Coord, Matrix4, RobotSpec, TurntableSpec, Vec3

TRANSFORM_TOL = 1e-6
"""Largest |RᵀR - I| entry and |last row - (0, 0, 0, 1)| of a rigid 4×4 transform."""
IDENTITY: list[list[float]] = np.eye(4).tolist()

Vec2 = Annotated[list[Coord], Field(min_length=2, max_length=2)]
Units = Literal["mm", "cm", "m", "in"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def check_rigid(matrix: list[list[float]], name: str) -> list[list[float]]:
    """`matrix` when it is a rigid 4×4 transform (rotation, det +1, translation), else
    ValueError naming `name`."""
    m = np.asarray(matrix, dtype=np.float64)
    if not np.isfinite(m).all():
        raise ValueError(f"{name} holds a non-finite number")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > TRANSFORM_TOL or np.linalg.det(r) <= 0:
        raise ValueError(
            f"{name} is not rigid: its 3×3 block must be a rotation (|RᵀR - I| = {err:.3g}, "
            f"det = {np.linalg.det(r):.6g})"
        )
    if np.abs(m[3] - [0.0, 0.0, 0.0, 1.0]).max() > TRANSFORM_TOL:
        raise ValueError(f"{name}: the last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    return matrix


class Floor(_Strict):
    """The plane z = z_mm of the cell (a table top): it blocks rays, and camera centres stay
    at least clearance_mm above it."""

    z_mm: Coord = 0.0
    clearance_mm: float = Field(50.0, ge=0, le=1e6)


class Box(_Strict):
    """An axis-aligned box of the cell frame, mm."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if not all(a < b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {self.min} must be below max {self.max} on every axis")
        return self


class Cylinder(_Strict):
    """A vertical cylinder of the cell frame: axis through (x, y) = centre, mm."""

    centre: Vec2
    radius_mm: float = Field(gt=0, le=LIMIT_MM)
    z_min_mm: Coord
    z_max_mm: Coord

    @model_validator(mode="after")
    def _ordered(self) -> Cylinder:
        if not self.z_min_mm < self.z_max_mm:
            raise ValueError(f"cylinder z_min_mm {self.z_min_mm} must be below z_max_mm")
        return self


class BoxShape(_Strict):
    """{"box": {min, max}}."""

    box: Box


class CylinderShape(_Strict):
    """{"cylinder": {centre, radius_mm, z_min_mm, z_max_mm}}."""

    cylinder: Cylinder


class MeshShape(_Strict):
    """A mesh placed in the cell: a file path (the CLI: relative to SETUP.json) or an uploaded
    mesh id (the service); `units` of the file (a mesh id is stored in mm: leave it mm)."""

    mesh: str = Field(min_length=1, max_length=4096)
    units: Units = "mm"
    to_cell: Matrix4 = Field(default_factory=lambda: [r[:] for r in IDENTITY])

    @field_validator("to_cell")
    @classmethod
    def _rigid(cls, value: list[list[float]]) -> list[list[float]]:
        return check_rigid(value, "to_cell")


class Fixture(MeshShape):
    """A fixture: it blocks rays, is never part surface, and camera centres keep clearance_mm
    from it (and are never inside it)."""

    clearance_mm: float = Field(50.0, ge=0, le=1e6)


Workspace = BoxShape | CylinderShape
KeepOut = BoxShape | MeshShape


class Setup(_Strict):
    """The part in its cell (issue 35): all keys optional; the defaults are no cell at all."""

    part_to_cell: Matrix4 = Field(
        default_factory=lambda: [r[:] for r in IDENTITY],
        description="rigid 4×4 transform from the part (mesh) frame to the cell frame, mm",
    )
    floor: Floor | None = Field(None, description="the plane z = z_mm of the cell")
    fixtures: list[Fixture] = Field(default_factory=list, max_length=64)
    workspace: Workspace | None = Field(
        None, description="where camera centres may be (cell frame); none: anywhere"
    )
    keep_out: list[KeepOut] = Field(
        default_factory=list, max_length=256, description="volumes camera centres may not enter"
    )
    robot: RobotSpec | None = Field(
        None,
        description="the arm that carries the camera: a bundled arm or URDF, its base in the "
        "cell, the camera on its flange (docs/robot.md); every view is one it can reach",
    )
    turntable: TurntableSpec | None = Field(
        None,
        description="or the part on a rotary table in front of a fixed camera (docs/robot.md): "
        "the candidates are its (table angle, station) grid",
    )

    @field_validator("part_to_cell")
    @classmethod
    def _rigid(cls, value: list[list[float]]) -> list[list[float]]:
        return check_rigid(value, "part_to_cell")

    @model_validator(mode="after")
    def _one_carrier(self) -> Setup:
        if self.robot is not None and self.turntable is not None:
            raise ValueError("give a robot or a turntable, not both")
        return self

    def meshes(self) -> list[MeshShape]:
        """Every mesh the setup references: fixtures, then keep-out meshes."""
        return [*self.fixtures, *(k for k in self.keep_out if isinstance(k, MeshShape))]
