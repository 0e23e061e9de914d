"""The request's robot and turntable (pydantic), and the loaded robot they describe.

Frames: the cell frame of the setup (mm). `base_to_cell` places the robot's root link,
`flange_to_camera` is the camera's optical frame (OpenCV: z along the gaze, y down) in the
flange (tip link) frame, mm. Joint limits and speeds are degrees and deg/s (mm and mm/s for
prismatic joints), one per moving joint, overriding the URDF's.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from vpp_core.errors import RobotError
from vpp_core.robot.arms import ARMS
from vpp_core.robot.urdf import Chain

LIMIT_MM = 1e7
"""Largest |coordinate| of a setup, mm (10 km): beyond any cell, far inside float range (a
norm or a product of such numbers cannot overflow)."""
Coord = Annotated[float, Field(ge=-LIMIT_MM, le=LIMIT_MM)]
Vec3 = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Row4 = Annotated[list[Coord], Field(min_length=4, max_length=4)]
Matrix4 = Annotated[list[Row4], Field(min_length=4, max_length=4)]
IDENTITY: list[list[float]] = np.eye(4).tolist()
MAX_JOINTS = 12
"""Moving joints a robot may have between its root and its flange."""


def check_rigid(m: list[list[float]]) -> list[list[float]]:
    """A 4x4 rigid transform (rotation orthonormal with det +1, last row 0 0 0 1), or
    ValueError (pydantic turns it into a 422)."""
    a = np.asarray(m, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError("transform has non-finite entries")
    r = a[:3, :3]
    if not np.allclose(a[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError("transform's last row must be 0 0 0 1")
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError("transform's rotation is not orthonormal with determinant +1")
    return m


class RobotSpec(BaseModel):
    """A six- (or seven-) axis arm carrying the camera: a bundled arm or a URDF."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: Literal["ur3", "ur5", "ur10", "panda"] | None = Field(
        None, description="bundled arm (example-robot-data's URDFs)"
    )
    urdf: str | None = Field(
        None, max_length=2_000_000, description="URDF text of another arm (metres, radians)"
    )
    tip_link: str | None = Field(
        None, description="the flange link (bundled arms: theirs; a URDF: its only leaf link)"
    )
    base_to_cell: Matrix4 = Field(IDENTITY, description="root link frame in the cell, mm")
    flange_to_camera: Matrix4 = Field(
        IDENTITY, description="camera frame (z = gaze, y = image down) in the flange frame, mm"
    )
    joint_limits: list[Annotated[list[float], Field(min_length=2, max_length=2)]] | None = Field(
        None, description="[lower, upper] per moving joint, deg (mm if prismatic); none: URDF's"
    )
    joint_speeds: list[Annotated[float, Field(gt=0)]] | None = Field(
        None, description="speed limit per moving joint, deg/s (mm/s); none: URDF's velocity"
    )
    roll_free_deg: float = Field(
        0.0, ge=0, le=180, description="the camera may turn about its optical axis by ± this"
    )
    roll_steps: int = Field(7, ge=1, le=73, description="rolls tried within ±roll_free_deg")
    ik_seeds: int = Field(4, ge=1, le=64, description="IK starts per pose and roll")
    link_radius_mm: float = Field(
        50.0, gt=0, le=1000, description="capsule radius of links without collision geometry"
    )
    camera_box_mm: (
        Annotated[list[Annotated[float, Field(gt=0, le=5000)]], Field(min_length=3, max_length=3)]
        | None
    ) = Field(
        None,
        description="the camera's body [width, height, depth] mm, from its optical centre back "
        "(-z): checked like a link; none: the camera is not in the collision model",
    )
    home_deg: list[float] | None = Field(
        None, description="start and end joint vector of the tour, deg (mm); none: open path"
    )
    path_step_deg: float = Field(
        2.0, ge=0, le=90, description="joint step of the sampled path check (0: no check)"
    )

    @field_validator("base_to_cell", "flange_to_camera")
    @classmethod
    def _rigid(cls, m: list[list[float]]) -> list[list[float]]:
        return check_rigid(m)

    @model_validator(mode="after")
    def _one_source(self) -> RobotSpec:
        if (self.name is None) == (self.urdf is None):
            raise ValueError("give exactly one of `name` (a bundled arm) and `urdf`")
        for lo, hi in self.joint_limits or []:
            if not lo < hi:
                raise ValueError(f"joint limit [{lo}, {hi}]: lower must be below upper")
        return self

    def key(self) -> str:
        """Content hash of everything that decides reachability (sha256 hex)."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


class LinearAxis(BaseModel):
    """The camera's linear axis: it moves along `direction` (cell frame) by min..max mm."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    direction: Vec3 = [0.0, 0.0, 1.0]
    min_mm: float = Field(0.0, ge=-1e5, le=1e5)
    max_mm: float = Field(0.0, ge=-1e5, le=1e5)
    steps: int = Field(1, ge=1, le=100, description="camera stations the generator uses")
    speed_mm_s: float = Field(200.0, gt=0, le=1e5)

    @model_validator(mode="after")
    def _range(self) -> LinearAxis:
        if self.max_mm < self.min_mm or np.linalg.norm(self.direction) < 1e-9:
            raise ValueError("linear axis: max_mm < min_mm or zero direction")
        return self


class TurntableSpec(BaseModel):
    """The part on a rotary table (axis through `axis_point` along `axis`, cell frame) in
    front of a fixed camera (`camera_to_cell`), optionally on a linear axis."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    axis_point: Vec3 = [0.0, 0.0, 0.0]
    axis: Vec3 = [0.0, 0.0, 1.0]
    camera_to_cell: Matrix4 = Field(description="the camera frame at the linear axis' zero")
    linear_axis: LinearAxis | None = None
    angle_limits_deg: Annotated[list[float], Field(min_length=2, max_length=2)] = [-180.0, 180.0]
    angle_step_deg: float = Field(15.0, gt=0, le=360, description="generator's table step")
    speed_deg_s: float = Field(90.0, gt=0, le=1e4, description="table speed")
    roll_free_deg: float = Field(0.0, ge=0, le=180)
    tolerance_mm: float = Field(0.5, gt=0, le=100, description="match of a required pose")
    tolerance_deg: float = Field(0.5, gt=0, le=45)

    @field_validator("camera_to_cell")
    @classmethod
    def _rigid(cls, m: list[list[float]]) -> list[list[float]]:
        return check_rigid(m)

    @model_validator(mode="after")
    def _axis(self) -> TurntableSpec:
        if np.linalg.norm(self.axis) < 1e-9:
            raise ValueError("turntable axis is the zero vector")
        lo, hi = self.angle_limits_deg
        if not lo < hi:
            raise ValueError("turntable angle limits: lower must be below upper")
        return self


@dataclass(frozen=True)
class Robot:
    """A loaded robot: the chain with the request's limits, speeds and placement (mm, rad)."""

    spec: RobotSpec
    chain: Chain
    base_to_cell: np.ndarray  # (4, 4)
    flange_to_camera: np.ndarray  # (4, 4)
    lower: np.ndarray  # (n,)
    upper: np.ndarray  # (n,)
    speed: np.ndarray  # (n,) rad/s or mm/s

    @property
    def n(self) -> int:
        """Number of moving joints."""
        return self.chain.n


def load_robot(spec: RobotSpec) -> Robot:
    """Parse the arm's URDF and apply the request's overrides (degrees → radians)."""
    from vpp_core.robot.arms import arm_urdf
    from vpp_core.robot.urdf import parse_chain

    if spec.name is not None:
        text, tip, base_dir = arm_urdf(spec.name)
        chain = parse_chain(text, spec.tip_link or tip, base_dir)
    else:
        assert spec.urdf is not None
        chain = parse_chain(spec.urdf, spec.tip_link or _leaf(spec.urdf), None)
    if chain.n > MAX_JOINTS:
        raise RobotError(
            f"the chain to {chain.links[-1]!r} has {chain.n} moving joints (at most {MAX_JOINTS})"
        )
    unit = np.where(chain.prismatic, 1.0, np.pi / 180)
    lower, upper, speed = chain.lower.copy(), chain.upper.copy(), chain.speed.copy()
    if spec.joint_limits is not None:
        _count(spec.joint_limits, chain, "joint_limits")
        lower, upper = (np.asarray(spec.joint_limits, dtype=np.float64) * unit[:, None]).T
    if spec.home_deg is not None:
        _count(spec.home_deg, chain, "home_deg")
    if spec.joint_speeds is not None:
        _count(spec.joint_speeds, chain, "joint_speeds")
        speed = np.asarray(spec.joint_speeds, dtype=np.float64) * unit
    base, mount = np.asarray(spec.base_to_cell), np.asarray(spec.flange_to_camera)
    return Robot(spec, chain, base, mount, lower, upper, speed)


def _count(values: list[Any], chain: Chain, what: str) -> None:
    """RobotError unless `values` has one entry per moving joint."""
    if len(values) != chain.n:
        raise RobotError(f"{what}: {len(values)} entries for {chain.n} joints {chain.names}")


def _leaf(text: str) -> str:
    """The only leaf link of a URDF (a link no joint has as parent), else RobotError."""
    import xml.etree.ElementTree as ET

    try:
        doc = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotError(f"URDF is not XML: {exc}") from exc
    parents = {p.get("link") for p in doc.iter("parent")}
    leaves = [str(e.get("name")) for e in doc.findall("link") if e.get("name") not in parents]
    if len(leaves) != 1:
        raise RobotError(f"URDF has {len(leaves)} leaf links {leaves[:8]}: give `tip_link`")
    return leaves[0]


__all__ = ["ARMS", "LinearAxis", "Robot", "RobotSpec", "TurntableSpec", "load_robot"]
