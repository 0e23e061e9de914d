"""What the plan document says about the robot or turntable that carries the camera (issue 36).

Joint values are degrees for revolute joints and mm for prismatic ones (a turntable's two
"joints": the table angle in degrees, the linear axis offset in mm).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel


class PathViolation(BaseModel):
    """A straight joint move between two consecutive views that touches something."""

    leg: int
    """Index of the leg in the tour (0: from home, or between the first two views)."""
    from_id: int | None
    """Candidate id the move starts at (None: home)."""
    to_id: int | None
    at: float
    """Fraction of the move where the first sample touches."""


class RobotTourOut(BaseModel):
    """The visiting order in joint space and its cycle time (s)."""

    order: list[int]
    """Candidate ids in visiting order."""
    travel_s: float
    """Sum of the legs: max over joints of |Δq| / speed limit each."""
    dwell_s: float
    cycle_time_s: float
    """dwell_s × views + travel_s."""
    legs_s: list[float]
    home: list[float] | None = None
    """Start and end joint vector (deg, mm); none: an open path."""
    solver: str
    path_step_deg: float
    """Sampling of the straight joint moves checked for collisions (0: not checked)."""
    path_violations: list[PathViolation] = []


class RobotCounts(BaseModel):
    """Candidate poses whose reach was computed, and those dropped by reason."""

    checked: int
    dropped: dict[str, int]


class RobotOut(BaseModel):
    """The carrier of the camera and what its reach did to the candidates."""

    kind: Literal["arm", "turntable"]
    name: str
    """The bundled arm's name, `urdf`, or `turntable`."""
    joints: list[str]
    units: list[str]
    """Per joint: `deg` or `mm`."""
    checked: int
    """Camera poses whose reach was computed (generator, retries, adaptive, explicit)."""
    dropped: dict[str, int]
    """Poses refused, by reason: no_ik, joint_limit, collision."""
    key: str
    """Content hash of the robot (or turntable) and the collision scene."""
    seconds: float
    tour: RobotTourOut | None = None
