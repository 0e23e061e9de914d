"""Reachability of N camera poses (cell frame, mm): a joint vector within the limits whose
arm touches nothing, with the camera turned about its optical axis within ±roll_free_deg.

Per pose the rolls are tried from 0 outwards (0, +δ, −δ, +2δ, ...), and per roll the IK
starts: the last accepted joint vector (neighbouring candidates are usually close), then
`ik_seeds` fixed starts. A converged answer is brought into the limits by whole turns,
re-checked by forward kinematics and then for collisions; the first that passes is taken.
When the camera's optical axis lies on the last revolute joint's axis (a camera centred on
the flange), a roll is that joint's turn: one IK per start serves every roll.

The reason of a pose no joint vector serves: `no_ik` (no start converged: out of reach or
orientation), `joint_limit` (converged only outside the limits), `collision` (every
solution within the limits touches the part, a fixture or the floor).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from vpp_core.robot import kinematics as kin
from vpp_core.robot.collision import Checker, Scene
from vpp_core.robot.model import Robot

REASONS = ("ok", "no_ik", "joint_limit", "collision")


@dataclass(frozen=True)
class Reach:
    """Per pose: reachable, reason (index into REASONS), joints (rad, mm; NaN where not
    reachable) and the roll used (deg; NaN where not reachable); `key` the content hash."""

    reachable: np.ndarray  # (N,) bool
    reason: np.ndarray  # (N,) int8 index into REASONS
    joints: np.ndarray  # (N, n) float64
    roll_deg: np.ndarray  # (N,) float64
    key: str

    def reasons(self) -> list[str]:
        """The reason of each pose as a name."""
        return [REASONS[int(r)] for r in self.reason]

    def dropped(self) -> dict[str, int]:
        """How many poses each failure reason dropped."""
        return {name: int((self.reason == i).sum()) for i, name in enumerate(REASONS) if i}


def reach_key(robot: Robot, scene: Scene, camera_to_cell: np.ndarray) -> str:
    """Content address of a reachability result: robot spec, scene and poses (sha256 hex)."""
    h = hashlib.sha256(robot.spec.key().encode())
    h.update(scene.key().encode())
    h.update(np.round(np.ascontiguousarray(camera_to_cell, dtype=np.float64), 6).tobytes())
    return h.hexdigest()


def rolls_deg(robot: Robot) -> np.ndarray:
    """The rolls tried, deg: 0, then outwards in alternating sign within ±roll_free_deg."""
    theta, k = robot.spec.roll_free_deg, robot.spec.roll_steps
    if theta == 0 or k == 1:
        return np.zeros(1)
    side = np.linspace(0, theta, k // 2 + 1)[1:]
    return np.concatenate([[0.0], np.ravel(np.column_stack([side, -side]))])


def _roll(angle_deg: float) -> np.ndarray:
    """4x4 rotation about z (the optical axis) by angle_deg."""
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return m


def roll_on_last_joint(robot: Robot) -> float:
    """+1 or -1 when turning the last (revolute) joint by a turns the camera about its optical
    axis by ±a (optical axis on that joint's axis), else 0."""
    chain = robot.chain
    if chain.prismatic[-1]:
        return 0.0
    cam = chain.tip @ robot.flange_to_camera  # camera in the last joint's moving frame
    axis, z, p = chain.axes[-1], cam[:3, 2], cam[:3, 3]
    on_axis = np.linalg.norm(p - (p @ axis) * axis) < 1e-6
    cos = float(z @ axis)
    return float(np.sign(cos)) if on_axis and abs(abs(cos) - 1) < 1e-9 else 0.0


def flange_targets(robot: Robot, camera_to_cell: np.ndarray, roll: float) -> np.ndarray:
    """(N, 4, 4) tip link poses in the root frame (mm) putting the camera at each pose turned
    by `roll` deg about its optical axis."""
    inv_base = np.linalg.inv(robot.base_to_cell)
    return np.asarray(
        inv_base @ camera_to_cell @ _roll(roll) @ np.linalg.inv(robot.flange_to_camera)
    )


def reachability(
    robot: Robot, scene: Scene, camera_to_cell: np.ndarray, checker: Checker | None = None
) -> Reach:
    """Reachability of (N, 4, 4) camera-to-cell poses (mm) for `robot` in `scene` (`checker`:
    a Checker of this robot and scene to reuse; its BVHs are built once)."""
    camera_to_cell = np.asarray(camera_to_cell, dtype=np.float64).reshape(-1, 4, 4)
    n_pose = len(camera_to_cell)
    solver = _Solver(robot, checker or Checker(robot, scene))
    reason = np.full(n_pose, REASONS.index("no_ik"), dtype=np.int8)
    joints = np.full((n_pose, robot.n), np.nan)
    roll_used = np.full(n_pose, np.nan)
    rolls = rolls_deg(robot)
    sign = roll_on_last_joint(robot)
    targets = [flange_targets(robot, camera_to_cell, r) for r in ([0.0] if sign else rolls)]
    for i in range(n_pose):
        found = solver.pose([t[i] for t in targets], rolls, sign)
        reason[i] = found[0]
        if found[1] is not None:
            joints[i], roll_used[i] = found[1], found[2]
    return Reach(reason == 0, reason, joints, roll_used, reach_key(robot, scene, camera_to_cell))


class _Solver:
    """The per-pose search, with the last accepted joint vector as the first start."""

    def __init__(self, robot: Robot, checker: Checker) -> None:
        self.robot, self.checker = robot, checker
        self.ets = kin.ets_of(robot)
        self.starts = kin.seeds(robot, robot.spec.ik_seeds)
        self.reach = kin.max_reach_mm(robot.chain)
        self.shoulder = robot.chain.origins[0][:3, 3]
        self.last: np.ndarray | None = None

    def pose(
        self, targets: list[np.ndarray], rolls: np.ndarray, sign: float
    ) -> tuple[int, np.ndarray | None, float]:
        """(reason index, joint vector or None, roll deg) for one pose's tip targets (one
        per roll, or one when the roll is the last joint's turn)."""
        saw = {"joint_limit": False, "collision": False}
        n = self.robot.n
        floor = self.checker.scene.floor_z
        for k, target in enumerate(targets):
            if np.linalg.norm(target[:3, 3] - self.shoulder) > self.reach:
                continue
            if floor is not None and (self.robot.base_to_cell @ target)[2, 3] < floor:
                saw["collision"] = True  # the flange itself below the floor
                continue
            for q in self._solutions(target):
                if sign and self.checker.colliding(q[None], range(n))[0]:
                    saw["collision"] = True  # the links before the last do not roll
                    continue
                variants = [(q, rolls[k])] if not sign else self._rolled(q, rolls, sign)
                links = range(n, n + 1) if sign else None
                for qv, roll in variants:
                    limited = kin.into_limits(self.robot, qv, qv)
                    if limited is None:
                        saw["joint_limit"] = True
                        continue
                    if self.checker.colliding(limited[None], links)[0]:
                        saw["collision"] = True
                        continue
                    self.last = limited
                    return 0, limited, float(roll)
        if saw["collision"]:
            return REASONS.index("collision"), None, np.nan
        return REASONS.index("joint_limit" if saw["joint_limit"] else "no_ik"), None, np.nan

    def _solutions(self, target_mm: np.ndarray) -> Iterator[np.ndarray]:
        """Converged IK answers (rad, mm; turned towards the limits where whole turns bring
        them in) from each start in turn, verified by FK, without repeats."""
        target_m = target_mm.copy()
        target_m[:3, 3] /= 1000.0
        starts = self.starts if self.last is None else np.vstack([self.last, self.starts])
        out: list[np.ndarray] = []
        for start in starts:
            metric = np.where(self.robot.chain.prismatic, start / 1000.0, start)
            q = kin.solve(self.ets, target_m, metric)
            if q is None:
                continue
            q = np.where(self.robot.chain.prismatic, q * 1000.0, q)
            dp, da = kin.pose_error(self.robot, q[None], target_mm[None])
            if dp[0] > kin.CHECK_MM or da[0] > kin.CHECK_DEG:
                continue
            near = kin.into_limits(self.robot, q, start)
            q = q if near is None else near
            if not any(np.abs(q - o).max() < 1e-4 for o in out):
                out.append(q)
                yield q

    def _rolled(
        self, q: np.ndarray, rolls: np.ndarray, sign: float
    ) -> list[tuple[np.ndarray, float]]:
        """The joint vector q (roll 0) turned on its last joint for each roll (deg)."""
        out = []
        for r in rolls:
            v = q.copy()
            v[-1] += sign * np.radians(r)
            out.append((v, float(r)))
        return out
