"""The robot (or turntable) of a setup in a plan: which camera poses it can take, the joint
values of the chosen views, and the visiting order in joint space (issue 36, docs/robot.md).

A `RobotGate` is made from the robot spec, the part in the cell and the collision scene.
Every source of candidates asks it before tracing: the generated pool and the adaptive rounds
(`filter`: unreachable poses dropped, with counts by reason; reachable ones turned to the
roll the arm takes), explicit viewpoints (`check_explicit`: a ViewpointError naming the
viewpoint and the reason). Results are kept per pose, so a pose is solved once per gate;
`report` gives the joint-space tour of the selected views and what was dropped and why.
"""

from __future__ import annotations

import time
from collections import Counter, OrderedDict
from collections.abc import Callable

import numpy as np

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.cell.geometry import Cell
from vpp_core.errors import ViewpointError
from vpp_core.mesh.part import Part
from vpp_core.plan.document import CandidateGenerator, CandidateInfo, PlanDocument, PlanRequest
from vpp_core.plan.robotdoc import PathViolation, RobotCounts, RobotOut, RobotTourOut
from vpp_core.plan.route import solve_route
from vpp_core.robot.collision import Checker, Scene
from vpp_core.robot.jointtour import joint_tour, path_violations
from vpp_core.robot.model import Robot, RobotSpec, TurntableSpec, load_robot
from vpp_core.robot.reach import REASONS, reachability
from vpp_core.robot.turntable import turntable_solve, turntable_views

EXACT_SEEDS = 16
"""IK starts per pose when a pose is solved again exactly (explicit viewpoints, the joints of
the chosen views in a process that did not filter them)."""
Keep = Callable[[Viewpoints], Viewpoints]
"""keep(views) -> the views a carrier can take (turned to its roll)."""
Found = tuple[int, np.ndarray | None, float]
"""(reason index, joint vector in rad/mm or None, roll deg) of one pose."""


def pose_key(camera_to_part: np.ndarray) -> bytes:
    """Cache key of a 4x4 pose: its entries rounded to 1e-6."""
    return bytes(np.round(np.asarray(camera_to_part, dtype=np.float64), 6).tobytes())


def rolled(views: Viewpoints, roll_deg: np.ndarray) -> Viewpoints:
    """The views turned about their gazes by roll_deg (camera · Rz(roll)): up' = cos·up +
    sin·x, x the image's right (x = -up × gaze)."""
    a = np.radians(np.nan_to_num(roll_deg))[:, None]
    x = np.cross(-views.ups, views.gazes)
    return make_viewpoints(views.positions, views.gazes, np.cos(a) * views.ups + np.sin(a) * x)


class RobotGate:
    """A robot or turntable of a setup, with the part placed in its cell (mm)."""

    def __init__(
        self,
        robot: RobotSpec | None,
        turntable: TurntableSpec | None,
        part_to_cell: np.ndarray,
        scene: Scene,
    ) -> None:
        self.spec, self.table = robot, turntable
        self.part_to_cell = np.asarray(part_to_cell, dtype=np.float64)
        self.scene = scene
        self.robot: Robot | None = load_robot(robot) if robot is not None else None
        self._checker: Checker | None = None
        self._exact: RobotGate | None = None
        self.found: dict[bytes, Found] = {}
        self.seconds = 0.0

    @property
    def checker(self) -> Checker:
        """The collision checker of the arm in the scene (built on first use)."""
        if self._checker is None:
            assert self.robot is not None
            self._checker = Checker(self.robot, self.scene)
        return self._checker

    def solve(self, camera_to_part: np.ndarray) -> list[Found]:
        """Reach of (N, 4, 4) part-frame camera poses, solved once per pose and plan."""
        keys = [pose_key(m) for m in camera_to_part]
        todo = [i for i, k in enumerate(keys) if k not in self.found]
        if todo:
            start = time.perf_counter()
            for i, found in zip(todo, self._compute(camera_to_part[todo]), strict=True):
                self.found[keys[i]] = found
            self.seconds += time.perf_counter() - start
        return [self.found[k] for k in keys]

    def _compute(self, camera_to_part: np.ndarray) -> list[Found]:
        """Reach of poses not solved yet: the arm's IK and collisions, or the turntable."""
        if self.robot is not None:
            r = reachability(
                self.robot, self.scene, self.part_to_cell @ camera_to_part, self.checker
            )
            return [
                (int(r.reason[i]), r.joints[i], float(r.roll_deg[i])) for i in range(len(r.reason))
            ]
        assert self.table is not None
        t = turntable_solve(self.table, self.part_to_cell, camera_to_part)
        # the fixed camera turns by the roll itself: the pose is met exactly, nothing to roll
        joints = np.column_stack([np.radians(t.angle_deg), t.offset_mm, np.radians(t.roll_deg)])
        return [(int(t.reason[i]), joints[i], 0.0) for i in range(len(t.reason))]

    def table_views(self) -> Viewpoints:
        """The turntable's candidates: every (table angle, station) of its grid, as the camera
        pose each is in the part frame (their joints known)."""
        assert self.table is not None
        grid = turntable_views(self.table, self.part_to_cell)
        m = grid.camera_to_part
        views = make_viewpoints(m[:, :3, 3], m[:, :3, 2], -m[:, :3, 1])
        self.solve(views.camera_to_world())  # the solver recovers each (angle, station)
        return views

    def filter(self, views: Viewpoints) -> tuple[Viewpoints, np.ndarray, Counter[str]]:
        """(the reachable views turned to their rolls, their indices into `views`, how many
        were dropped for each reason)."""
        found = self.solve(views.camera_to_world())
        dropped = Counter(REASONS[f[0]] for f in found if f[0])
        keep = np.array([f[0] == 0 for f in found], dtype=bool)
        idx = np.flatnonzero(keep)
        out = rolled(views.take(idx), np.array([found[i][2] for i in idx]))
        for i, m in zip(idx, out.camera_to_world(), strict=True):
            self.found[pose_key(m)] = (0, found[i][1], 0.0)
        return out, idx, dropped

    def check_explicit(self, views: Viewpoints) -> None:
        """ViewpointError naming the first explicit viewpoint the carrier cannot take as given
        (an arm's roll freedom is not used: an explicit pose is not turned) and why."""
        for i, f in enumerate(self.solve_exact(views.camera_to_world())):
            if f[0]:
                why = REASONS[f[0]]
                raise ViewpointError(
                    f"viewpoint {i} at {np.round(views.positions[i], 3).tolist()} (part frame, "
                    f"mm): the {self.name()} cannot take it ({why})"
                )

    def name(self) -> str:
        """The bundled arm's name, `urdf` or `turntable`."""
        if self.spec is None:
            return "turntable"
        return self.spec.name or "urdf"

    def solve_exact(self, camera_to_part: np.ndarray) -> list[Found]:
        """Reach of poses as given: an arm's answers that turned the camera, or found none,
        are solved again without roll freedom from EXACT_SEEDS starts (a pose this gate
        passed is in its cache with roll 0; another process's gate searches wider)."""
        found = self.solve(camera_to_part)
        redo = [i for i, f in enumerate(found) if self.robot is not None and (f[0] or f[2])]
        if redo and self.robot is not None:
            seeds = max(self.robot.spec.ik_seeds, EXACT_SEEDS)  # few poses: search wider
            spec = self.robot.spec.model_copy(update={"roll_free_deg": 0.0, "ik_seeds": seeds})
            if self._exact is None:
                self._exact = RobotGate(spec, None, self.part_to_cell, self.scene)
                self._exact._checker = self.checker
            for i, f in zip(redo, self._exact.solve(camera_to_part[redo]), strict=True):
                found[i] = f
                if not f[0]:
                    self.found[pose_key(camera_to_part[i])] = f
        return [(f[0] or (REASONS.index("joint_limit") if f[2] else 0), f[1], f[2]) for f in found]

    def joints_deg(self, views: Viewpoints) -> np.ndarray:
        """(K, n) joint values (deg, mm) that put the camera at each view exactly (NaN where
        the carrier cannot)."""
        found = self.solve_exact(views.camera_to_world())
        n = self.robot.n if self.robot is not None else 3
        out = np.full((len(views), n), np.nan)
        for i, f in enumerate(found):
            if f[1] is not None and not f[0]:
                out[i] = self._to_deg(f[1])
        return out

    def _to_deg(self, q: np.ndarray) -> np.ndarray:
        """Joint values in the document's units (deg for revolute, mm for prismatic)."""
        if self.robot is None:
            return np.array([np.degrees(q[0]), q[1], np.degrees(q[2])])
        return np.where(self.robot.chain.prismatic, q, np.degrees(q))

    def describe(self) -> tuple[list[str], list[str]]:
        """(joint names, units)."""
        if self.robot is None:
            return ["table", "linear_axis", "camera_roll"], ["deg", "mm", "deg"]
        units = ["mm" if p else "deg" for p in self.robot.chain.prismatic]
        return list(self.robot.chain.names), units

    def speeds(self) -> np.ndarray:
        """Per joint speed limit (rad/s, mm/s)."""
        if self.robot is not None:
            return self.robot.speed
        assert self.table is not None
        linear = self.table.linear_axis.speed_mm_s if self.table.linear_axis else 1.0
        turn = np.radians(self.table.speed_deg_s)
        return np.array([turn, linear, turn])

    def home(self) -> np.ndarray | None:
        """The home joint vector (rad, mm), or None."""
        if self.spec is None or self.spec.home_deg is None or self.robot is None:
            return None
        return np.where(
            self.robot.chain.prismatic, self.spec.home_deg, np.radians(self.spec.home_deg)
        )

    def report(
        self, ids: list[int], views: Viewpoints, dwell_s: float, checked: int, dropped: Counter[str]
    ) -> RobotOut:
        """The document's `robot`: the poses checked and dropped (by reason), the content key,
        and the joint-space tour of `views` (the selected ones, candidate `ids`)."""
        names, units = self.describe()
        tour = self._tour(ids, views, dwell_s) if len(views) else None
        key = self.spec.key() if self.spec is not None else self.table.model_dump_json()  # type: ignore[union-attr]
        return RobotOut(
            kind="arm" if self.robot is not None else "turntable",
            name=self.name(),
            joints=names,
            units=units,
            checked=checked,
            dropped={r: int(dropped[r]) for r in REASONS[1:]},
            key=_hash(key + self.scene.key()),
            seconds=round(self.seconds, 3),
            tour=tour,
        )

    def _tour(self, ids: list[int], views: Viewpoints, dwell_s: float) -> RobotTourOut:
        """Visiting order by joint-space travel time, from and to home, and its path check."""
        found = self.solve(views.camera_to_world())
        q = np.array([f[1] for f in found], dtype=np.float64)
        home = self.home()
        tour = joint_tour(q, self.speeds(), home, solve_route)
        step = 0.0 if self.spec is None else self.spec.path_step_deg
        bad: list[PathViolation] = []
        if self.robot is not None and step > 0:
            ordered = [ids[i] for i in tour.order]
            for v in path_violations(self.checker, q[tour.order], np.radians(step), home):
                a, b = int(v["from"]), int(v["to"])  # type: ignore[call-overload]
                bad.append(PathViolation(
                    leg=int(v["leg"]), from_id=ordered[a] if a >= 0 else None,  # type: ignore[call-overload]
                    to_id=ordered[b] if b >= 0 else None, at=float(v["at"]),  # type: ignore[arg-type]
                ))  # fmt: skip
        return RobotTourOut(
            order=[ids[i] for i in tour.order],
            travel_s=round(tour.travel_s, 4),
            dwell_s=dwell_s,
            cycle_time_s=round(dwell_s * len(views) + tour.travel_s, 4),
            legs_s=np.round(tour.legs_s, 4).tolist(),
            home=None if home is None else self._to_deg(home).tolist(),
            solver=tour.solver,
            path_step_deg=step,
            path_violations=bad,
        )


def _hash(text: str) -> str:
    """SHA-256 hex of a text."""
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()


# --- the setup's carrier in the pipeline (pipeline.py and adaptive.py call these) ----------

GATES: OrderedDict[tuple[str, str], RobotGate] = OrderedDict()
KEEP_GATES = 2
"""Gates kept per process (a worker's next plan of the same part and setup reuses one)."""


def robot_scene(part: Part, cell: Cell) -> Scene:
    """The arm's collision scene in the cell frame (mm): the part placed, the fixtures, the
    keep-out meshes and boxes (nothing of the arm enters them either), the floor."""
    import trimesh

    meshes = [(cell.to_cell(part.vertices), np.asarray(part.faces))]
    names = ["part"]
    for solid in (*cell.fixtures, *cell.keep_out_meshes):
        meshes.append((solid.vertices, solid.faces))
        names.append(solid.name)
    for name, box in cell.keep_out_boxes:
        b = trimesh.creation.box(bounds=box)
        meshes.append((np.asarray(b.vertices), np.asarray(b.faces)))
        names.append(name)
    floor = cell.setup.floor
    return Scene(meshes, None if floor is None else floor.z_mm, names)


def gate_of(part: Part, cell: Cell | None) -> RobotGate | None:
    """The gate of the setup's robot or turntable (None: neither), cached per part and setup."""
    setup = None if cell is None else cell.setup
    if cell is None or setup is None or (setup.robot is None and setup.turntable is None):
        return None
    key = (part.id, setup.model_dump_json())
    gate = GATES.pop(key, None)
    if gate is None:
        scene = robot_scene(part, cell) if setup.robot is not None else Scene()
        gate = RobotGate(setup.robot, setup.turntable, cell.part_to_cell, scene)
    GATES[key] = gate
    while len(GATES) > KEEP_GATES:
        GATES.popitem(last=False)
    return gate


def table_candidates(
    part: Part, cell: Cell | None, info: CandidateInfo
) -> tuple[Viewpoints, CandidateInfo] | None:
    """A turntable's candidates instead of the generator's (None: no turntable)."""
    gate = gate_of(part, cell)
    if gate is None or gate.table is None:
        return None
    views = gate.table_views()
    counts = RobotCounts(checked=len(views), dropped={r: 0 for r in REASONS[1:]})
    return views, info.model_copy(update={"generated": len(views), "robot": counts})


def reachable_candidates(
    part: Part, cell: Cell | None, views: Viewpoints, info: CandidateInfo
) -> tuple[Viewpoints, CandidateInfo]:
    """The generated candidates the arm can take, turned to its roll; the others dropped
    and counted in info.robot (unchanged without a robot)."""
    gate = gate_of(part, cell)
    if gate is None or gate.robot is None:
        return views, info
    kept, _, dropped = gate.filter(views)
    counts = RobotCounts(checked=len(views), dropped={r: dropped[r] for r in REASONS[1:]})
    update = {
        "generated": len(kept),
        "dropped": info.dropped + len(views) - len(kept),
        "robot": counts,
    }
    return kept, info.model_copy(update=update)


def reachable_filter(part: Part, cell: Cell | None, tally: Counter[str]) -> Keep | None:
    """The adaptive rounds' filter: new views the carrier can take (turned to its roll),
    with the drops added to `tally` (None without a robot or turntable)."""
    gate = gate_of(part, cell)
    if gate is None:
        return None

    def keep(views: Viewpoints) -> Viewpoints:
        kept, _, dropped = gate.filter(views)
        tally.update(dropped)
        tally["checked"] += len(views)
        return kept

    return keep


def counted(info: CandidateInfo, tally: Counter[str]) -> CandidateInfo:
    """info with the adaptive rounds' robot drops added."""
    if info.robot is None or not tally:
        return info
    dropped = {r: info.robot.dropped.get(r, 0) + tally[r] for r in REASONS[1:]}
    counts = RobotCounts(checked=info.robot.checked + tally["checked"], dropped=dropped)
    return info.model_copy(update={"robot": counts})


def check_reachable(part: Part, cell: Cell | None, views: Viewpoints) -> None:
    """ViewpointError naming the first explicit viewpoint the carrier cannot take, and why."""
    gate = gate_of(part, cell)
    if gate is not None:
        gate.check_explicit(views)


def annotate_robot(doc: PlanDocument, part: Part, request: PlanRequest, cell: Cell | None) -> None:
    """Each selected viewpoint's joints and doc.robot (drops, joint-space tour; nothing
    without a robot or turntable)."""
    gate = gate_of(part, cell)
    if gate is None:
        return
    vps = doc.viewpoints
    views = make_viewpoints(
        np.array([v.position for v in vps]).reshape(-1, 3),
        np.array([v.gaze for v in vps]).reshape(-1, 3),
        np.array([v.up for v in vps]).reshape(-1, 3),
    )
    joints = gate.joints_deg(views)
    for v, q in zip(vps, joints, strict=True):
        v.joints = None if np.isnan(q).any() else np.round(q, 6).tolist()
    counts = doc.candidate_info.robot or RobotCounts(checked=len(doc.candidates), dropped={})
    ok = ~np.isnan(joints).any(axis=1)
    ids = [v.id for v, good in zip(vps, ok, strict=True) if good]
    doc.robot = gate.report(
        ids, views.take(np.flatnonzero(ok)), request.objective.dwell_s,
        counts.checked, Counter(counts.dropped),
    )  # fmt: skip


def check_request_reach(part: Part, request: PlanRequest, cell: Cell | None) -> None:
    """Before any work: ViewpointError naming the first explicit viewpoint of `request` the
    setup's robot or turntable cannot take, and why (nothing to check otherwise)."""
    spec = request.candidates
    if isinstance(spec, CandidateGenerator) or gate_of(part, cell) is None:
        return
    nan = [np.nan] * 3
    views = make_viewpoints(
        np.array([v.position for v in spec.viewpoints]).reshape(-1, 3),
        np.array([v.gaze for v in spec.viewpoints]).reshape(-1, 3),
        np.array([v.up if v.up is not None else nan for v in spec.viewpoints]).reshape(-1, 3),
    )
    check_reachable(part, cell, views)
