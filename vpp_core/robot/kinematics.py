"""Inverse kinematics of a chain: roboticstoolbox-python's compiled Levenberg-Marquardt.

The chain is handed to roboticstoolbox as an elementary transform sequence (ETS) in metres:
each joint's fixed origin as a static SE3, then its motion about (along) the joint axis (a
principal axis directly, any other axis conjugated by a rotation taking z onto it). One
solve is one `ETS.ik_LM` search from a given start (about 0.15 ms for a UR5, docs/robot.md);
the answer is then brought into the joint limits by whole turns of the revolute joints and
re-checked with the numpy forward kinematics of `urdf.py` (0.01 mm, 0.01°), so a reported
joint vector is never the solver's word alone.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from vpp_core.robot.model import Robot
from vpp_core.robot.urdf import M_TO_MM, Chain, flange_frames

TOL = 1e-12
"""ik_LM's residual bound E = ½ eᵀe (m, rad): about 1.4 µm and 1.4 µrad."""
ITERATIONS = 40
"""LM iterations per search."""
CHECK_MM, CHECK_DEG = 0.01, 0.01
"""The numpy FK of an accepted joint vector is within this of the target."""


def _axis_ets(axis: np.ndarray, prismatic: bool) -> list[Any]:
    """The ETs of one joint's motion: [Rx|Ry|Rz|tx|ty|tz(flip)] or conjugated about Rz/tz."""
    import roboticstoolbox as rtb

    ET: Any = rtb.ET
    principal = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[principal]) - 1.0) < 1e-12:
        make = (ET.tx, ET.ty, ET.tz) if prismatic else (ET.Rx, ET.Ry, ET.Rz)
        return [make[principal](flip=bool(axis[principal] < 0))]
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, axis), float(axis @ z)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    r = np.eye(4)
    r[:3, :3] = np.eye(3) + k + k @ k / (1.0 + c) if c > -1 + 1e-12 else np.diag([1, -1, -1])
    return [ET.SE3(r), ET.tz() if prismatic else ET.Rz(), ET.SE3(r.T)]


def make_ets(chain: Chain) -> Any:
    """The chain as a roboticstoolbox ETS in metres (root link → tip link)."""
    import roboticstoolbox as rtb

    ET: Any = rtb.ET
    items: list[Any] = []
    for origin, axis, prismatic in zip(chain.origins, chain.axes, chain.prismatic, strict=True):
        metres = origin.copy()
        metres[:3, 3] /= M_TO_MM
        if not np.allclose(metres, np.eye(4)):
            items.append(ET.SE3(metres))
        items += _axis_ets(axis, bool(prismatic))
    tip = chain.tip.copy()
    tip[:3, 3] /= M_TO_MM
    if not np.allclose(tip, np.eye(4)):
        items.append(ET.SE3(tip))
    make: Any = rtb.ETS
    return make(items)


@lru_cache(maxsize=8)
def _cached_ets(chain: Chain) -> Any:
    """make_ets, once per chain object (hashed by identity)."""
    return make_ets(chain)


def ets_of(robot: Robot) -> Any:
    """The robot's ETS (cached per loaded chain)."""
    return _cached_ets(robot.chain)


def solve(ets: Any, target_m: np.ndarray, start: np.ndarray) -> np.ndarray | None:
    """One LM search from `start` for the tip pose `target_m` (root frame, metres):
    the joint vector (rad, m) or None when it does not converge."""
    sol = ets.ik_LM(target_m, q0=start, ilimit=ITERATIONS, slimit=1, tol=TOL, joint_limits=False)
    return np.asarray(sol.q, dtype=np.float64) if sol.success else None


def into_limits(robot: Robot, q: np.ndarray, near: np.ndarray) -> np.ndarray | None:
    """`q` (rad, mm) with revolute joints moved by whole turns into [lower, upper] (closest
    to `near`); None where a joint cannot be brought into its limits."""
    turns = np.round((near - q) / (2 * np.pi))
    shifted = np.where(robot.chain.prismatic, q, q + 2 * np.pi * turns)
    for _ in range(2):  # at most one more turn either way brings a wide joint inside
        shifted = np.where(
            (shifted > robot.upper) & ~robot.chain.prismatic, shifted - 2 * np.pi, shifted
        )
        shifted = np.where(
            (shifted < robot.lower) & ~robot.chain.prismatic, shifted + 2 * np.pi, shifted
        )
    inside = (shifted >= robot.lower - 1e-9) & (shifted <= robot.upper + 1e-9)
    return shifted if inside.all() else None


def pose_error(robot: Robot, q: np.ndarray, target_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position error mm, rotation error deg) of the tip at joint vectors q (N, n) against
    tip targets (N, 4, 4) in the root frame, by the numpy forward kinematics."""
    got = flange_frames(robot.chain, q)
    dp = np.linalg.norm(got[:, :3, 3] - target_mm[:, :3, 3], axis=1)
    rel = np.swapaxes(got[:, :3, :3], 1, 2) @ target_mm[:, :3, :3]
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return dp, np.degrees(np.arccos(cos))


def max_reach_mm(chain: Chain) -> float:
    """An upper bound of the tip's distance from the first joint's origin (mm)."""
    lengths = [np.linalg.norm(o[:3, 3]) for o in chain.origins[1:]]
    slide = float(np.abs(np.stack([chain.lower, chain.upper])[:, chain.prismatic]).max(initial=0))
    return float(sum(lengths) + np.linalg.norm(chain.tip[:3, 3]) + slide * chain.prismatic.sum())


def seeds(robot: Robot, count: int) -> np.ndarray:
    """(count, n) deterministic starts: the limits' middle (wide revolute joints: 0), then a
    Halton sequence over the limits clipped to ±π (rad, mm)."""
    lo = np.where(robot.chain.prismatic, robot.lower, np.maximum(robot.lower, -np.pi))
    hi = np.where(robot.chain.prismatic, robot.upper, np.minimum(robot.upper, np.pi))
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37][: robot.n]
    u = np.array([[_halton(i + 1, p) for p in primes] for i in range(count)])
    u[0] = 0.5
    return np.asarray(lo + u * (hi - lo))


def _halton(i: int, base: int) -> float:
    """The i-th element of the van der Corput sequence in `base`."""
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r
