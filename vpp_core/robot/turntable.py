"""The part on a rotary table in front of a fixed camera (optionally on a linear axis).

At table angle φ (deg, right-handed about the table axis `axis` through `axis_point`) the part
sits at Rot(φ) · part_to_cell. The camera is `camera_to_cell` moved by s mm along the linear
axis (s = 0 without one), turned about its optical axis by ρ with |ρ| ≤ roll_free_deg.

`turntable_views` generates the (table angle, station) pairs on a grid and the camera pose
each one is in the part frame: those are the candidates. `turntable_solve` maps part-frame
camera poses (any candidate, an explicit viewpoint) onto the table: the angle that turns the
required gaze onto the camera's, then the station along the linear axis and the roll. A pose
is reachable when the gaze and position match within the tolerances (else `no_ik`) and the
angle, station and roll lie within their limits (else `joint_limit`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from vpp_core.robot.model import TurntableSpec
from vpp_core.robot.reach import REASONS


def table_rotation(spec: TurntableSpec, angle_deg: np.ndarray) -> np.ndarray:
    """(N, 4, 4) rotations of the cell by the table angles (deg) about the table axis."""
    a = np.asarray(spec.axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    c = np.asarray(spec.axis_point, dtype=np.float64)
    t = np.radians(np.atleast_1d(angle_deg))[:, None, None]
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    r = np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)
    out = np.zeros((len(t), 4, 4))
    out[:, :3, :3], out[:, 3, 3] = r, 1.0
    out[:, :3, 3] = c - r @ c
    return out


def camera_at(spec: TurntableSpec, offset_mm: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-cell at linear-axis offsets (mm)."""
    cam = np.asarray(spec.camera_to_cell, dtype=np.float64)
    out = np.repeat(cam[None], len(np.atleast_1d(offset_mm)), axis=0)
    if spec.linear_axis is not None:
        d = np.asarray(spec.linear_axis.direction, dtype=np.float64)
        out[:, :3, 3] += np.atleast_1d(offset_mm)[:, None] * d / np.linalg.norm(d)
    return out


@dataclass(frozen=True)
class TableViews:
    """Generated candidates: table angle (deg), station offset (mm) and the camera pose in the
    part frame (camera-to-part, mm) of each."""

    angle_deg: np.ndarray  # (N,)
    offset_mm: np.ndarray  # (N,)
    camera_to_part: np.ndarray  # (N, 4, 4)


def turntable_views(spec: TurntableSpec, part_to_cell: np.ndarray) -> TableViews:
    """Every (angle, station) on the generator's grid: angles every angle_step_deg within the
    limits (a full turn counted once), stations evenly along the linear axis."""
    lo, hi = spec.angle_limits_deg
    angles = np.arange(lo, hi + 1e-9, spec.angle_step_deg)
    if hi - lo >= 360 - 1e-9:
        angles = angles[angles < lo + 360 - 1e-9]
    axis = spec.linear_axis
    offsets = np.linspace(axis.min_mm, axis.max_mm, axis.steps) if axis else np.zeros(1)
    aa, oo = (g.ravel() for g in np.meshgrid(angles, offsets, indexing="ij"))
    part_at = table_rotation(spec, aa) @ np.asarray(part_to_cell, dtype=np.float64)
    return TableViews(aa, oo, np.linalg.inv(part_at) @ camera_at(spec, oo))


@dataclass(frozen=True)
class TableReach:
    """Per part-frame pose: reachable, reason (index into REASONS), table angle (deg),
    linear-axis offset (mm) and camera roll (deg); NaN where not reachable."""

    reachable: np.ndarray
    reason: np.ndarray
    angle_deg: np.ndarray
    offset_mm: np.ndarray
    roll_deg: np.ndarray
    key: str

    def dropped(self) -> dict[str, int]:
        """How many poses each failure reason dropped."""
        return {name: int((self.reason == i).sum()) for i, name in enumerate(REASONS) if i}


def _signed_angle(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(N,) angle (rad) turning u onto v about `axis` (rows of u, v perpendicular to it)."""
    return np.asarray(np.arctan2((np.cross(u, v) * axis).sum(axis=-1), (u * v).sum(axis=-1)))


def _perp(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Rows of v without their component along the unit vector a."""
    return np.asarray(v - (v @ a)[:, None] * a)


def turntable_solve(
    spec: TurntableSpec, part_to_cell: np.ndarray, camera_to_part: np.ndarray
) -> TableReach:
    """The table angle, station and roll that bring the camera to each part-frame pose."""
    a = np.asarray(spec.axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    c = np.asarray(spec.axis_point, dtype=np.float64)
    cam = np.asarray(spec.camera_to_cell, dtype=np.float64)
    p0 = np.asarray(part_to_cell, dtype=np.float64) @ np.asarray(camera_to_part).reshape(-1, 4, 4)
    g0, g = p0[:, :3, 2], cam[:3, 2]
    tol = np.radians(spec.tolerance_deg)
    elevation_ok = (
        np.abs(np.arcsin(np.clip(g0 @ a, -1, 1)) - np.arcsin(np.clip(g @ a, -1, 1))) <= tol
    )
    gp, cp = _perp(g0, a), _perp(np.broadcast_to(g, g0.shape), a)
    along = np.linalg.norm(gp, axis=1) < 1e-6  # gaze on the table axis: position decides
    rel, cam_rel = _perp(p0[:, :3, 3] - c, a), _perp(np.broadcast_to(cam[:3, 3] - c, g0.shape), a)
    phi = np.where(along, _signed_angle(rel, cam_rel, a), _signed_angle(gp, cp, a))
    angle = _into_range(np.degrees(phi), spec.angle_limits_deg)
    moved = table_rotation(spec, np.where(np.isnan(angle), np.degrees(phi), angle)) @ p0
    offset, miss = _station(spec, moved[:, :3, 3])
    roll = np.degrees(
        _signed_angle(np.broadcast_to(cam[:3, 0], g0.shape), moved[:, :3, 0], moved[:, :3, 2])
    )
    gaze_miss = np.degrees(np.arccos(np.clip(moved[:, :3, 2] @ g, -1, 1))) > spec.tolerance_deg
    on_set = elevation_ok & ~gaze_miss & (miss <= spec.tolerance_mm)
    lin = spec.linear_axis
    lo, hi = (lin.min_mm, lin.max_mm) if lin else (0.0, 0.0)
    in_limits = ~np.isnan(angle) & (offset >= lo - 1e-9) & (offset <= hi + 1e-9)
    in_limits &= np.abs(roll) <= spec.roll_free_deg + spec.tolerance_deg
    reason = np.where(
        ~on_set, REASONS.index("no_ik"), np.where(in_limits, 0, REASONS.index("joint_limit"))
    )
    ok = reason == 0
    nan = np.full(len(p0), np.nan)
    key = hashlib.sha256(spec.model_dump_json().encode() + np.round(p0, 6).tobytes()).hexdigest()
    return TableReach(
        ok,
        reason.astype(np.int8),
        np.where(ok, angle, nan),
        np.where(ok, offset, nan),
        np.where(ok, roll, nan),
        key,
    )


def _into_range(angle_deg: np.ndarray, limits: list[float]) -> np.ndarray:
    """Angles moved by whole turns into [lo, hi] (NaN where none fits)."""
    lo, hi = limits
    shifted = lo + np.mod(angle_deg - lo, 360.0)
    return np.where(shifted <= hi + 1e-9, shifted, np.nan)


def _station(spec: TurntableSpec, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(offset mm along the linear axis, distance mm of the required position from it)."""
    origin = np.asarray(spec.camera_to_cell, dtype=np.float64)[:3, 3]
    rel = position - origin
    if spec.linear_axis is None:
        return np.zeros(len(position)), np.linalg.norm(rel, axis=1)
    d = np.asarray(spec.linear_axis.direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    s = rel @ d
    return s, np.linalg.norm(rel - s[:, None] * d, axis=1)
